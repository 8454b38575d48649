"""Body model: forward kinematics against an independent NumPy reference, transforms,
and the analytic Jacobian against finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from posetrack import _body as B

# ---------------------------------------------------------------------------------------------
# An independent reference: named bones, explicit recursion, scipy rotations (xyzw).
# ---------------------------------------------------------------------------------------------


def _rot(q_wxyz):
    q = np.asarray(q_wxyz, dtype=np.float64)
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()  # scipy normalises


def reference_keypoints(shape: B.BodyShape, params: np.ndarray) -> np.ndarray:
    s = {k: float(v) for k, v in shape.to_dict().items()}
    p = np.asarray(params, dtype=np.float64)
    t, quats = p[:3], p[3:].reshape(10, 4)
    names = ["root", "neck", "rsh", "rel", "lsh", "lel", "rhip", "rkn", "lhip", "lkn"]
    R = {n: _rot(q) for n, q in zip(names, quats)}
    down = lambda length: np.array([0.0, -length, 0.0])  # noqa: E731
    sh_y = s["torso"] - s["shoulder_drop"]
    # (name, parent, offset of this joint in the parent's frame)
    tree = {
        "root": (None, np.zeros(3)),
        "neck": ("root", np.array([0.0, s["torso"], 0.0])),
        "rsh": ("root", np.array([-s["shoulder_width"], sh_y, 0.0])),
        "rel": ("rsh", down(s["upper_arm"])),
        "lsh": ("root", np.array([s["shoulder_width"], sh_y, 0.0])),
        "lel": ("lsh", down(s["upper_arm"])),
        "rhip": ("root", np.array([-s["hip_width"], 0.0, 0.0])),
        "rkn": ("rhip", down(s["thigh"])),
        "lhip": ("root", np.array([s["hip_width"], 0.0, 0.0])),
        "lkn": ("lhip", down(s["thigh"])),
    }

    def world(name):
        parent, off = tree[name]
        if parent is None:
            return R[name], t.copy()
        Rp, cp = world(parent)
        return Rp @ R[name], cp + Rp @ off

    def at(name, local=np.zeros(3)):
        Rw, c = world(name)
        return c + Rw @ np.asarray(local)

    h = s["head_scale"]
    return np.stack(
        [
            at("neck", h * np.array([0.0, 0.17, 0.11])),
            at("neck"),
            at("rsh"), at("rel"), at("rel", down(s["forearm"])),
            at("lsh"), at("lel"), at("lel", down(s["forearm"])),
            at("rhip"), at("rkn"), at("rkn", down(s["shin"])),
            at("lhip"), at("lkn"), at("lkn", down(s["shin"])),
            at("neck", h * np.array([-0.033, 0.205, 0.085])),
            at("neck", h * np.array([0.033, 0.205, 0.085])),
            at("neck", h * np.array([-0.075, 0.185, 0.0])),
            at("neck", h * np.array([0.075, 0.185, 0.0])),
        ]
    )  # fmt: skip


def random_params(rng: np.random.Generator, *, spread: float = 1.0) -> np.ndarray:
    t = rng.normal([0, 0, 3], 0.3)
    q = rng.normal(size=(10, 4)) * spread
    q[:, 0] += 1.0  # mostly moderate rotations, any norm
    return np.concatenate([t, q.reshape(-1)])


@pytest.fixture(scope="module")
def shape64():
    with jax.enable_x64(True):
        yield B.BodyShape.create(dtype=jnp.float64, thigh=0.47, forearm=0.24, head_scale=1.1)


def test_fk_matches_independent_reference(shape64):
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        for _ in range(20):
            p = random_params(rng)
            got = np.asarray(B.keypoints(shape64, jnp.asarray(p)))
            np.testing.assert_allclose(got, reference_keypoints(shape64, p), atol=1e-12)


def test_rest_pose_anatomy():
    """Facing the camera upright: head up (-y in the camera), subject's right on image left."""
    shape = B.BodyShape.default()
    kp = np.asarray(B.keypoints(shape, B.facing_camera_params(3.0)))
    assert kp[0, 1] < kp[1, 1] < kp[8, 1] < kp[9, 1] < kp[10, 1]  # nose above neck above hips...
    # Subject's right appears on the camera's left (smaller x) when facing the camera.
    assert kp[2, 0] < kp[5, 0] and kp[8, 0] < kp[11, 0] and kp[14, 0] < kp[15, 0]
    assert kp[0, 2] < kp[1, 2]  # the nose is nearer the camera than the neck
    np.testing.assert_allclose(np.linalg.norm(kp[3] - kp[2]), float(shape.upper_arm), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(kp[13] - kp[12]), float(shape.shin), atol=1e-6)


def test_capsules_follow_the_skeleton():
    rng = np.random.default_rng(1)
    shape = B.BodyShape.default()
    p = jnp.asarray(random_params(rng, spread=0.5), jnp.float32)
    kp = np.asarray(B.keypoints(shape, p))
    a, b, r = (np.asarray(x) for x in B.capsules(shape, p))
    i = B.CAPSULE_NAMES.index("right_upper_arm")
    np.testing.assert_allclose(a[i], kp[2], atol=1e-5)
    np.testing.assert_allclose(b[i], kp[3], atol=1e-5)
    i = B.CAPSULE_NAMES.index("left_shin")
    np.testing.assert_allclose(a[i], kp[12], atol=1e-5)
    np.testing.assert_allclose(b[i], kp[13], atol=1e-5)
    assert r.shape == (B.NUM_CAPSULES,) and np.all(r > 0)


def test_quaternion_sign_and_scale_do_not_matter():
    rng = np.random.default_rng(2)
    shape = B.BodyShape.default()
    p = random_params(rng)
    flipped = p.copy()
    flipped[3:] = -flipped[3:]
    scaled = p.copy()
    scaled[3:] *= 3.7
    k0 = np.asarray(B.keypoints(shape, jnp.asarray(p, jnp.float32)))
    np.testing.assert_allclose(
        np.asarray(B.keypoints(shape, jnp.asarray(flipped, jnp.float32))), k0, atol=1e-5
    )
    np.testing.assert_allclose(
        np.asarray(B.keypoints(shape, jnp.asarray(scaled, jnp.float32))), k0, atol=1e-5
    )


def test_zero_quaternion_is_identity_with_finite_gradients():
    shape = B.BodyShape.default()
    p = B.facing_camera_params(3.0).at[7:11].set(0.0)  # neck quaternion zero
    kp = B.keypoints(shape, p)
    ref = B.keypoints(shape, B.facing_camera_params(3.0))
    np.testing.assert_allclose(np.asarray(kp), np.asarray(ref), atol=1e-6)
    J = jax.jacfwd(lambda x: B.keypoints(shape, x))(p)
    G = jax.grad(lambda x: jnp.sum(B.keypoints(shape, x) ** 2))(p)
    assert np.isfinite(np.asarray(J)).all() and np.isfinite(np.asarray(G)).all()


@pytest.fixture(scope="module")
def jitted_fk():
    return jax.jit(B.keypoints)


def test_eager_jit_and_vmap_agree(jitted_fk):
    rng = np.random.default_rng(3)
    shape = B.BodyShape.default()
    batch = jnp.asarray(np.stack([random_params(rng) for _ in range(6)]), jnp.float32)
    eager = np.stack([np.asarray(B.keypoints(shape, p)) for p in batch])
    jitted = np.stack([np.asarray(jitted_fk(shape, p)) for p in batch])
    vmapped = np.asarray(jax.vmap(B.keypoints, in_axes=(None, 0))(shape, batch))
    np.testing.assert_allclose(jitted, eager, atol=1e-5)
    np.testing.assert_allclose(vmapped, eager, atol=1e-5)


def _central_difference(f, x, eps=1e-6):
    cols = []
    for i in range(x.shape[0]):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


quat_strategy = st.sampled_from(["random", "near_identity", "negated"])

# Jitted once for the whole module (hypothesis calls the test a dozen times; eager tracing of
# jacfwd / jacrev and 86 eager FK calls per example cost ~40 s).
_kp_flat = jax.jit(lambda shape, x: B.keypoints(shape, x).reshape(-1))
_kp_jacfwd = jax.jit(jax.jacfwd(lambda shape, x: B.keypoints(shape, x).reshape(-1), argnums=1))
_kp_jacrev = jax.jit(jax.jacrev(lambda shape, x: B.keypoints(shape, x).reshape(-1), argnums=1))


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), kind=quat_strategy)
def test_jacobian_matches_finite_differences(seed, kind):
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    if kind == "near_identity":
        p[3:] = np.tile([1.0, 0.0, 0.0, 0.0], 10) + rng.normal(size=40) * 1e-4
    elif kind == "negated":
        p[3:] = -p[3:]
    with jax.enable_x64(True):
        shape = B.BodyShape.default(dtype=jnp.float64)
        fd = _central_difference(lambda x: np.asarray(_kp_flat(shape, jnp.asarray(x))), p)
        fwd = np.asarray(_kp_jacfwd(shape, jnp.asarray(p)))
        rev = np.asarray(_kp_jacrev(shape, jnp.asarray(p)))
    scale = np.abs(fd).max()
    np.testing.assert_allclose(fwd, fd, atol=1e-6 * max(scale, 1))
    np.testing.assert_allclose(rev, fwd, atol=1e-10)


def test_shape_jacobian_matches_finite_differences():
    rng = np.random.default_rng(5)
    p = random_params(rng)
    with jax.enable_x64(True):
        shape = B.BodyShape.default(dtype=jnp.float64)
        leaves, treedef = jax.tree.flatten(shape)
        x0 = np.array([float(v) for v in leaves])

        def f_jax(x):
            s = jax.tree.unflatten(treedef, [x[i] for i in range(x.shape[0])])
            a, b, r = B.capsules(s, jnp.asarray(p))
            return jnp.concatenate(
                [B.keypoints(s, jnp.asarray(p)).ravel(), a.ravel(), b.ravel(), r]
            )

        f = jax.jit(f_jax)  # one compile instead of eager FK per perturbed shape
        fd = _central_difference(lambda x: np.asarray(f(jnp.asarray(x))), x0)
        J = np.asarray(jax.jit(jax.jacfwd(f_jax))(jnp.asarray(x0)))
    np.testing.assert_allclose(J, fd, atol=1e-6)


def test_capsule_jacobian_wrt_pose_matches_finite_differences():
    rng = np.random.default_rng(6)
    p = random_params(rng)
    with jax.enable_x64(True):
        shape = B.BodyShape.default(dtype=jnp.float64)
        f = lambda x: np.asarray(jnp.concatenate(B.capsules(shape, jnp.asarray(x))[:2])).ravel()  # noqa: E731
        fd = _central_difference(f, p)
        J = np.asarray(
            jax.jacfwd(lambda x: jnp.concatenate(B.capsules(shape, x)[:2]).ravel())(jnp.asarray(p))
        )
    np.testing.assert_allclose(J, fd, atol=1e-6)


def test_bodyshape_validation():
    with pytest.raises(ValueError, match="thigh"):
        B.BodyShape.create(thigh=-0.4)
    with pytest.raises(ValueError, match="unknown field"):
        B.BodyShape.create(tail=0.3)
    with pytest.raises(ValueError, match="forearm"):
        B.BodyShape.create(forearm=float("nan"))
