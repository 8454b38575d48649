"""The capsule depth renderer: exact hard limit, documented soft formula, gradients, batching."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from posetrack._camera import Intrinsics
from posetrack._render import Capsules, render_depth, render_depth_batch

jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(scope="module", autouse=True)
def _x64():
    """float64 for this module's references and finite differences, restored afterwards (the
    library computes in the dtype of its inputs, so float32 inputs still test float32)."""
    prev = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", prev)


W, H = 40, 30
# A 40x30 image of a Kinect-like camera (f ~ 525 px at 640x480): ~9 cm pixels at 3 m.
K = Intrinsics.create(fx=33.0, fy=33.0, cx=19.5, cy=14.5, width=W, height=H)
K80 = K.scaled(80, 60)  # 4.5 cm pixels at 3 m: a body is more than its silhouette band


# ---------------------------------------------------------------------------------------------
# Independent NumPy reference: unit-direction rays, dot-product quadratics (the library uses
# cross products and z = 1 rays), nearest hit over lateral cylinder + both end spheres.


def np_rays(k: Intrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    r = np.stack([(u - float(k.cx)) / float(k.fx), (v - float(k.cy)) / float(k.fy),
                  np.ones_like(u)], -1)
    return r / np.linalg.norm(r, axis=-1, keepdims=True)


def np_raycast(a, b, radius, k: Intrinsics):
    """Per-capsule entry depth (z, NaN where missed), shape (P, H, W), and the union's
    (depth, hit mask)."""
    d = np_rays(k)[None]  # (1, H, W, 3) unit directions from the origin
    a, b, rad = (np.asarray(v, float) for v in (a, b, radius))
    rad = rad[:, None, None]
    axis = b - a
    length = np.linalg.norm(axis, axis=-1)
    w = np.divide(axis, length[:, None], out=np.zeros_like(axis), where=length[:, None] > 0)
    w, a4, length4 = w[:, None, None, :], a[:, None, None, :], length[:, None, None]
    # Lateral surface: |(t d - a) - ((t d - a).w) w|^2 = R^2.
    dw = np.sum(d * w, -1)
    aw = np.sum(a4 * w, -1)
    dp = d - dw[..., None] * w
    ap = -a4 + aw[..., None] * w  # perpendicular part of (origin - a)
    qa = np.sum(dp * dp, -1)
    qb = 2 * np.sum(dp * ap, -1)
    qc = np.sum(ap * ap, -1) - rad**2
    disc = qb**2 - 4 * qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        t_cyl = (-qb - np.sqrt(disc)) / (2 * qa)
    axial = t_cyl * dw - aw
    ok = (length4 > 0) & (qa > 1e-12) & (disc >= 0) & (axial >= 0) & (axial <= length4)
    ts = [np.where(ok, t_cyl, np.inf)]
    for c in (a, b):
        c4 = c[:, None, None, :]
        dc = np.sum(d * c4, -1)
        disc_s = dc**2 - np.sum(c4 * c4, -1) + rad**2
        with np.errstate(invalid="ignore"):
            ts.append(np.where(disc_s >= 0, dc - np.sqrt(disc_s), np.inf))
    t = np.min(ts, axis=0)
    t = np.where(t > 0, t, np.inf)
    z_k = np.where(np.isfinite(t), t * d[..., 2], np.nan)  # depth = t * unit-ray z
    hit = np.isfinite(z_k).any(0)
    depth = np.where(hit, np.nanmin(np.where(np.isfinite(z_k), z_k, np.inf), 0), np.nan)
    return z_k, depth, hit


def np_ray_segment(a, b, k: Intrinsics, samples: int = 401):
    """Ray-to-segment distance and closest-approach depth by dense sampling of the segment
    (two refinement rounds), shapes (P, H, W). Independent of any closed form."""
    d = np_rays(k)
    dist_all, depth_all = [], []
    for ak, bk in zip(np.asarray(a, float), np.asarray(b, float)):
        lo, hi = np.zeros(d.shape[:2]), np.ones(d.shape[:2])
        for _ in range(3):
            s = lo[..., None] + (hi - lo)[..., None] * np.linspace(0, 1, samples)
            c = ak + s[..., None] * (bk - ak)  # (H, W, S, 3)
            along = np.sum(c * d[:, :, None], -1)
            dist = np.linalg.norm(c - along[..., None] * d[:, :, None], axis=-1)
            i = np.argmin(dist, -1)
            step = (hi - lo) / (samples - 1)
            s_best = np.take_along_axis(s, i[..., None], -1)[..., 0]
            lo, hi = np.clip(s_best - step, 0, 1), np.clip(s_best + step, 0, 1)
        dist_best = np.take_along_axis(dist, i[..., None], -1)[..., 0]
        along_best = np.take_along_axis(along, i[..., None], -1)[..., 0]
        dist_all.append(dist_best)
        depth_all.append(along_best * d[..., 2])
    return np.stack(dist_all), np.stack(depth_all)


def silhouette_band(mask: np.ndarray) -> np.ndarray:
    """Pixels within one pixel (8-neighbourhood) of a silhouette of ``mask``."""
    p = np.pad(mask, 1, mode="edge")
    shifted = [p[1 + i: 1 + i + mask.shape[0], 1 + j: 1 + j + mask.shape[1]]
               for i in (-1, 0, 1) for j in (-1, 0, 1)]
    return np.any([s != mask for s in shifted], axis=0)


def stick_body(center=(0.0, 0.1, 3.0)):
    """16 capsules of a standing person with one arm in front of the torso, camera frame."""
    c = np.asarray(center)
    j = {
        "pelvis": (0, 0, 0), "spine": (0, -0.25, 0.02), "neck": (0, -0.5, 0), "head": (0, -0.68, 0),
        "lsho": (0.18, -0.48, 0), "lelb": (0.25, -0.2, -0.1), "lwri": (0.3, 0.02, -0.3),
        "rsho": (-0.18, -0.48, 0), "relb": (-0.1, -0.3, -0.25), "rwri": (0.1, -0.2, -0.35),
        "lhip": (0.1, 0.02, 0), "lkne": (0.12, 0.45, -0.05), "lank": (0.12, 0.88, 0),
        "rhip": (-0.1, 0.02, 0), "rkne": (-0.14, 0.45, 0.02), "rank": (-0.15, 0.88, 0.05),
    }
    j = {name: np.asarray(p, float) + c for name, p in j.items()}
    segs = [("pelvis", "spine", 0.13), ("spine", "neck", 0.14), ("neck", "head", 0.09),
            ("head", "head", 0.11), ("lsho", "lelb", 0.05), ("lelb", "lwri", 0.04),
            ("rsho", "relb", 0.05), ("relb", "rwri", 0.04), ("lhip", "lkne", 0.07),
            ("lkne", "lank", 0.055), ("rhip", "rkne", 0.07), ("rkne", "rank", 0.055),
            ("lsho", "rsho", 0.06), ("lhip", "rhip", 0.09), ("lwri", "lwri", 0.045),
            ("rwri", "rwri", 0.045)]
    a = np.stack([j[s[0]] for s in segs])
    b = np.stack([j[s[1]] for s in segs])
    return a, b, np.array([s[2] for s in segs])


def as_caps(a, b, r, dtype=jnp.float64) -> Capsules:
    return Capsules(jnp.asarray(a, dtype), jnp.asarray(b, dtype), jnp.asarray(r, dtype))


def random_capsules(rng, n=6):
    """Capsules 2-4 m in front of the camera, random orientations, one of them a sphere."""
    a = rng.uniform([-0.6, -0.5, 2.0], [0.6, 0.5, 4.0], (n, 3))
    b = a + rng.normal(0, 0.3, (n, 3))
    b[0] = a[0]
    return a, b, rng.uniform(0.04, 0.2, n)


@pytest.fixture(scope="module")
def render():
    return jax.jit(render_depth)


@pytest.fixture(scope="module")
def render_hard():
    return jax.jit(lambda c: render_depth(c, K, sharpness=None))


# ---------------------------------------------------------------------------------------------
# Hard limit.


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hard_mode_equals_numpy_raycaster(render_hard, seed):
    a, b, r = random_capsules(np.random.default_rng(seed)) if seed else stick_body()
    _, ref_depth, ref_hit = np_raycast(a, b, r, K)
    depth, fg = (np.asarray(v) for v in render_hard(as_caps(a, b, r)))
    assert ref_hit.sum() > 50
    # Same mask: exact maths, only a pixel centre within rounding of a silhouette could differ.
    assert np.array_equal(fg > 0.5, ref_hit)
    np.testing.assert_allclose(depth[ref_hit], ref_depth[ref_hit], atol=1e-8)


@pytest.mark.parametrize("seed", [0, 3])
def test_soft_tends_to_exact_raycasting(render, seed):
    a, b, r = random_capsules(np.random.default_rng(seed)) if seed else stick_body()
    _, ref_depth, ref_hit = np_raycast(a, b, r, K80)
    depth, fg = (np.asarray(v) for v in render(as_caps(a, b, r), K80, sharpness=1e5))
    away = ~silhouette_band(ref_hit)
    assert np.array_equal((fg > 0.5)[away], ref_hit[away])
    assert np.all(np.abs(fg - ref_hit)[away] < 1e-3)
    both = ref_hit & (fg > 0.5) & away
    assert both.sum() > 50
    assert np.max(np.abs(depth - ref_depth)[both]) < 1e-3  # metres


def test_float32_close_to_float64(render):
    a, b, r = stick_body()
    d64, f64 = render(as_caps(a, b, r), K, sharpness=100.0)
    d32, f32 = render(as_caps(a, b, r, jnp.float32), K, sharpness=100.0)
    assert d32.dtype == jnp.float32 and d64.dtype == jnp.float64
    fg = np.asarray(f64) > 0.5
    assert np.max(np.abs(np.asarray(d32) - np.asarray(d64))[fg]) < 2e-4
    assert np.max(np.abs(np.asarray(f32) - np.asarray(f64))) < 1e-4


# ---------------------------------------------------------------------------------------------
# The soft formula, as documented, against NumPy reference fields.


def test_soft_render_matches_documented_formula(render):
    sigma, pushback = 50.0, 0.2
    a, b, r = stick_body()
    z_hit, _, _ = np_raycast(a, b, r, K)
    dist, z_close = np_ray_segment(a, b, K)
    delta = dist - r[:, None, None]
    z = np.where(np.isfinite(z_hit), z_hit, z_close)
    alpha = 1 / (1 + np.exp(sigma * delta))
    fg_ref = 1 - np.prod(1 - alpha, axis=0)
    score = -sigma * (z + pushback * np.logaddexp(0, sigma * delta))
    wgt = np.exp(score - score.max(0))
    depth_ref = np.sum(wgt * z, 0) / np.sum(wgt, 0)
    depth, fg = (np.asarray(v) for v in render(as_caps(a, b, r), K, sharpness=sigma))
    np.testing.assert_allclose(fg, fg_ref, atol=1e-5)
    np.testing.assert_allclose(depth, depth_ref, atol=1e-4)


def test_sharpness_unit_is_inverse_metres(render):
    # A sphere of radius R at depth Z on the optical axis; the ray through pixel u passes at
    # perpendicular distance e from its centre, coverage must be sigmoid(-sigma (e - R)).
    k = Intrinsics.create(fx=100.0, fy=100.0, cx=0.0, cy=0.0, width=40, height=1)
    rad, depth_c, sigma = 0.1, 2.0, 80.0
    c = np.array([[0.0, 0.0, depth_c]])
    _, fg = render(as_caps(c, c, [rad]), k, sharpness=sigma)
    x = np.arange(40) / 100.0
    e = depth_c * x / np.sqrt(1 + x**2)  # distance from the centre to the ray
    # atol: the distance is floored at 1e-5 m (gradient guard), which shows at the centre ray.
    np.testing.assert_allclose(np.asarray(fg)[0], 1 / (1 + np.exp(sigma * (e - rad))), atol=1e-6)


def test_arm_in_front_does_not_grow_in_depth_map(render):
    # The reason for the push-back: pixels of the torso next to (but outside) an arm that is
    # 30 cm closer must keep the torso's depth; plain alpha-weighted soft-min fails this.
    k = Intrinsics.create(fx=400.0, fy=400.0, cx=0.0, cy=0.0, width=60, height=1)
    torso = (np.array([0.0, -0.5, 3.0]), np.array([0.0, 0.5, 3.0]), 0.3)
    arm = (np.array([0.0, -0.5, 2.7]), np.array([0.0, 0.5, 2.7]), 0.03)
    caps = as_caps(np.stack([torso[0], arm[0]]), np.stack([torso[1], arm[1]]),
                   [torso[2], arm[2]])
    depth = np.asarray(render(caps, k, sharpness=100.0)[0])[0]
    x = np.arange(60) / 400.0
    arm_miss = 2.7 * x / np.sqrt(1 + x**2) - 0.03  # ray-to-arm distance
    # The arm may claim pixels up to depth_lead / (pushback * sigma) = 1.5 cm outside it (a
    # plain alpha-weighted soft-min: up to the depth lead, 30 cm); check at twice that.
    torso_px = (arm_miss > 0.03) & (x < 0.08)
    assert torso_px.sum() > 5
    # Entry depth into the torso's lateral surface (axis along y, so only x matters).
    torso_depth = (3.0 - np.sqrt(np.maximum(0.09 * (1 + x**2) - (3.0 * x) ** 2, 0))) / (1 + x**2)
    assert np.max(np.abs(depth - torso_depth)[torso_px]) < 1e-4
    # The arm's own surface 2.67 m, soft-min with the torso 3 cm behind (2.6735 m by the
    # documented formula: a 3 cm arm is only 95% opaque at sigma = 100 / m).
    assert abs(depth[0] - 2.6735) < 2e-4


def test_depth_continuous_across_silhouette():
    # Per-capsule depth along a fine sweep of rays crossing a capsule's silhouette: no jumps
    # beyond what the sqrt shape of a tangent allows.
    from posetrack._render import capsule_fields, capsule_params

    a, b, r = np.array([[0.1, -0.2, 3.0]]), np.array([[0.3, 0.4, 2.6]]), np.array([0.1])
    p = capsule_params(as_caps(a, b, r))
    p = {k_: v[0] for k_, v in p.items()}
    for y0 in (-0.075, 0.03, 0.16):  # crossings near end a, on the cylinder, near end b
        x = jnp.linspace(-0.2, 0.3, 200001)
        delta, z = capsule_fields(x, jnp.full_like(x, y0), p)
        delta, z = np.asarray(delta), np.asarray(z)
        assert (delta < 0).any() and (delta > 0).any()
        # Steepest admissible jump: z ~ sqrt(R * miss) near a tangent, miss per step ~ 3 * dx.
        # A tangent has z ~ sqrt(2 R miss); one step changes the miss by <= 3 m * dx.
        dx = 0.5 / 200000
        assert np.max(np.abs(np.diff(z))) < 3 * np.sqrt(2 * 0.1 * 3.0 * dx)


def test_capsule_behind_camera_is_not_rendered(render):
    a, b, r = np.array([[0.0, -0.3, -2.0]]), np.array([[0.0, 0.3, -2.0]]), np.array([0.2])
    depth, fg = render(as_caps(a, b, r), K, sharpness=100.0)
    assert float(jnp.max(fg)) < 1e-6
    assert bool(jnp.all(jnp.isfinite(depth)))


# ---------------------------------------------------------------------------------------------
# Gradients.


def _loss(caps: Capsules, weights, sharpness, k=K):
    depth, fg = render_depth(caps, k, sharpness=sharpness)
    return jnp.sum(weights[0] * fg) + jnp.sum(weights[1] * fg * depth)


@pytest.fixture(scope="module")
def grad_fns():
    loss = jax.jit(_loss, static_argnames=("k",))
    grad = jax.jit(jax.grad(_loss), static_argnames=("k",))

    @jax.jit
    def jvp(caps, direction, weights, sharpness):
        return jax.jvp(lambda c: _loss(c, weights, sharpness), (caps,), (direction,))[1]

    return loss, grad, jvp


@pytest.mark.parametrize("seed", [0, 1])
def test_gradient_matches_finite_differences_and_forward_mode(grad_fns, seed):
    loss, grad, jvp = grad_fns
    rng = np.random.default_rng(seed)
    a, b, r = stick_body() if seed == 0 else random_capsules(rng, n=16)
    caps = as_caps(a, b, r)
    weights = jnp.asarray(rng.uniform(-1, 1, (2, H, W)))
    sigma = 30.0  # soft enough at 9 cm pixels for finite differences to resolve
    g_rev = grad(caps, weights, sigma)
    eps = 1e-6
    sphere = np.all(a == b, axis=-1)[:, None]
    for _ in range(4):
        # Sphere capsules (a == b) stay spheres: the render is not differentiable in b - a
        # there (the entry depth is a min over the two ends), so move both ends together.
        da, db = rng.normal(size=a.shape), rng.normal(size=b.shape)
        direction = Capsules(jnp.asarray(da), jnp.asarray(np.where(sphere, da, db)),
                             jnp.asarray(rng.normal(size=r.shape)))
        plus = jax.tree.map(lambda v, d: v + eps * d, caps, direction)
        minus = jax.tree.map(lambda v, d: v - eps * d, caps, direction)
        fd = (loss(plus, weights, sigma) - loss(minus, weights, sigma)) / (2 * eps)
        rev = sum(jnp.sum(g * d) for g, d in zip(jax.tree.leaves(g_rev),
                                                 jax.tree.leaves(direction)))
        fwd = jvp(caps, direction, weights, sigma)
        np.testing.assert_allclose(fwd, rev, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(rev, fd, rtol=1e-4, atol=1e-6)
        assert abs(float(fd)) > 1e-3  # the check is not vacuous


def test_gradient_finite_in_degenerate_configurations(grad_fns, render):
    _, grad, _ = grad_fns
    x3 = (3.0 - float(K.cx)) / float(K.fx)  # pixel column 3: ray direction (x3, y, 1)
    y3 = (5.0 - float(K.cy)) / float(K.fy)
    ray = np.array([x3, y3, 1.0])
    perp = np.cross(ray, [0.0, 1.0, 0.0])
    perp /= np.linalg.norm(perp)
    configs = {
        # a sphere capsule (a == b) with pixel rays through its centre
        "sphere": ([3.0 * ray], [3.0 * ray], [0.2]),
        # a capsule whose axis lies along a pixel ray (end-on, parallel rays)
        "along_ray": ([2.5 * ray], [3.5 * ray], [0.1]),
        # a pixel ray exactly tangent to an end sphere
        "tangent": ([3.0 * ray + 0.1 * perp], [3.0 * ray + 0.1 * perp + [0, 0.5, 0]], [0.1]),
        # a capsule through which pixel rays pass the axis exactly
        "through_axis": ([3.0 * ray - [0, 0.4, 0]], [3.0 * ray + [0, 0.4, 0]], [0.1]),
        # zero radius, behind the camera, entirely off-image, touching the camera
        "zero_radius": ([[0.0, -0.4, 3.0]], [[0.1, 0.4, 3.0]], [0.0]),
        "behind": ([[0.0, -0.4, -1.0]], [[0.0, 0.4, -1.0]], [0.2]),
        "off_image": ([[30.0, 0.0, 3.0]], [[30.0, 1.0, 3.0]], [0.2]),
        "at_camera": ([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], [0.1]),
    }
    weights = jnp.ones((2, H, W))
    for name, (a, b, r) in configs.items():
        caps = as_caps(np.array(a, float), np.array(b, float), np.array(r, float))
        for sharpness in (30.0, None):
            for leaf in jax.tree.leaves(grad(caps, weights, sharpness)):
                assert bool(jnp.all(jnp.isfinite(leaf))), (name, sharpness)
            depth, fg = render(caps, K, sharpness=sharpness)
            assert bool(jnp.all(jnp.isfinite(depth)) & jnp.all(jnp.isfinite(fg))), name


def test_gradient_finite_in_float32(grad_fns):
    _, grad, _ = grad_fns
    a, b, r = stick_body()  # has three sphere capsules
    g = grad(as_caps(a, b, r, jnp.float32), jnp.ones((2, H, W), jnp.float32), 300.0)
    for leaf in jax.tree.leaves(g):
        assert leaf.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(leaf)))


# ---------------------------------------------------------------------------------------------
# Batching, jit.


@pytest.mark.parametrize("batch_size", [None, 2])
def test_batch_equals_loop(render, batch_size):
    rng = np.random.default_rng(5)
    bodies = [random_capsules(rng) for _ in range(3)]
    caps = Capsules(*(jnp.asarray(np.stack(v)) for v in zip(*bodies)))
    depth, fg = jax.jit(lambda c: render_depth_batch(c, K, batch_size=batch_size))(caps)
    assert depth.shape == fg.shape == (3, H, W)
    for i, (a, b, r) in enumerate(bodies):
        d_i, f_i = render(as_caps(a, b, r), K)
        np.testing.assert_allclose(depth[i], d_i, atol=1e-12)
        np.testing.assert_allclose(fg[i], f_i, atol=1e-12)


def test_eager_equals_jit(render):
    a, b, r = random_capsules(np.random.default_rng(6), n=3)
    k = Intrinsics.create(fx=8.0, fy=8.0, cx=4.5, cy=3.5, width=10, height=8)
    eager = render_depth(as_caps(a, b, r), k)
    jitted = render(as_caps(a, b, r), k)
    for e, j in zip(eager, jitted):
        np.testing.assert_allclose(e, j, atol=1e-12)


def test_bad_capsule_shapes_are_rejected_before_tracing():
    a = jnp.zeros((4, 3))
    with pytest.raises(ValueError, match="radius"):
        render_depth(Capsules(a, a, jnp.ones(5)), K)
    with pytest.raises(ValueError, match="hyp"):
        render_depth_batch(Capsules(a, a, jnp.ones(4)), K)
