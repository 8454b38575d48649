"""Delta of Eq. (3): hand-computed cases, the literal formula, gradients, fused render+score."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posetrack._camera import Intrinsics
from posetrack._render import Capsules, render_and_score, render_depth
from posetrack._score import delta, delta_batch

jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(scope="module", autouse=True)
def _x64():
    """float64 for this module's references and finite differences, restored afterwards (the
    library computes in the dtype of its inputs, so float32 inputs still test float32)."""
    prev = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", prev)


D_M = 0.15


@pytest.fixture(scope="module")
def delta_jit():
    return jax.jit(delta)


def eq3_literal(z_d, z_fg, r_d, r_fg, d_m):
    """Eq. (3) of the paper as printed, on binary maps, with its 0/0 cases spelled out."""
    p_i, p_u = z_fg & r_fg, z_fg | r_fg
    if p_u.sum() == 0:
        return 1.0
    lam = p_i.sum() / p_u.sum()
    if p_i.sum() == 0:
        return 1.0  # lambda = 0: the depth term has weight 0
    return lam * np.minimum(np.abs(z_d - r_d), d_m)[p_i].sum() / (d_m * p_i.sum()) + 1 - lam


def block(h=20, w=20, rows=slice(None), cols=slice(None)):
    m = np.zeros((h, w), bool)
    m[rows, cols] = True
    return m


def test_identical_maps_give_zero(delta_jit):
    fg = block(rows=slice(3, 15), cols=slice(4, 9))
    depth = np.where(fg, np.linspace(2, 3, 400).reshape(20, 20), 0.0)
    assert float(delta_jit(depth, fg * 1.0, depth, fg * 1.0, d_M=D_M)) == 0.0


def test_disjoint_maps_give_one(delta_jit):
    z_fg, r_fg = block(rows=slice(0, 5)), block(rows=slice(10, 15))
    d = np.full((20, 20), 3.0)
    assert float(delta_jit(d, z_fg * 1.0, d, r_fg * 1.0, d_M=D_M)) == 1.0


@pytest.mark.parametrize("offset, expected", [(0.05, 0.05 / 0.15), (-0.03, 0.2), (0.4, 1.0)])
def test_constant_offset_on_full_overlap(delta_jit, offset, expected):
    fg = block(rows=slice(2, 12)) * 1.0
    z_d = np.full((20, 20), 3.0)
    got = delta_jit(z_d, fg, z_d + offset, fg, d_M=D_M)
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_half_overlap(delta_jit):
    # z_fg rows 0-9, r_fg rows 5-14: |P_i| = 5 rows, |P_u| = 15 rows, lambda = 1/3; a 3 cm
    # offset on the overlap: Delta = (1/3) * (0.03 / 0.15) + 2/3.
    z_fg, r_fg = block(rows=slice(0, 10)) * 1.0, block(rows=slice(5, 15)) * 1.0
    z_d = np.full((20, 20), 2.5)
    got = delta_jit(z_d, z_fg, z_d + 0.03, r_fg, d_M=D_M)
    np.testing.assert_allclose(got, (1 / 3) * 0.2 + 2 / 3, rtol=1e-12)
    # Equal depths: Delta = 1 - lambda.
    np.testing.assert_allclose(delta_jit(z_d, z_fg, z_d, r_fg, d_M=D_M), 2 / 3, rtol=1e-12)


def test_soft_memberships_product_and_probabilistic_or(delta_jit):
    # Pixel A: z_fg 1, r_fg 0.5, depth off by d_M / 2 -> i = 0.5, u = 1, match 0.5.
    # Pixel B: z_fg 0.5, r_fg 0.5, same depth -> i = 0.25, u = 0.75, match 1.
    # Delta = 1 - (0.5 * 0.5 + 0.25 * 1) / (1 + 0.75) = 1 - 0.5 / 1.75.
    z_fg, r_fg = np.array([[1.0, 0.5]]), np.array([[0.5, 0.5]])
    z_d, r_d = np.array([[3.0, 2.0]]), np.array([[3.075, 2.0]])
    np.testing.assert_allclose(delta_jit(z_d, z_fg, r_d, r_fg, d_M=D_M), 1 - 0.5 / 1.75,
                               rtol=1e-12)


def test_no_foreground_anywhere_is_one_not_nan(delta_jit):
    zeros = np.zeros((6, 7))
    assert float(delta_jit(zeros, zeros, zeros, zeros, d_M=D_M)) == 1.0
    grads = jax.jit(jax.grad(delta, argnums=(2, 3)))(zeros, zeros, zeros + 2.0, zeros)
    for g in grads:
        assert bool(jnp.all(jnp.isfinite(g)))


def test_invalid_observed_depth_does_not_leak_nan(delta_jit):
    z_fg = block(rows=slice(0, 10)) * 1.0
    z_d = np.where(z_fg > 0, 3.0, np.nan)  # NaN off the foreground (as a sensor gives it)
    got = delta_jit(z_d, z_fg, np.full((20, 20), 3.0), z_fg, d_M=D_M)
    assert float(got) == 0.0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), d_m=st.sampled_from([0.05, 0.15, 0.3]))
def test_matches_literal_eq3_on_binary_maps(delta_jit, seed, d_m):
    rng = np.random.default_rng(seed)
    h, w = 6, 7  # one shape: one compilation
    z_fg, r_fg = rng.random((h, w)) < rng.random(), rng.random((h, w)) < rng.random()
    z_d, r_d = rng.uniform(1, 4, (h, w)), rng.uniform(1, 4, (h, w))
    r_d = np.where(rng.random((h, w)) < 0.5, z_d + rng.normal(0, 0.1, (h, w)), r_d)
    got = delta_jit(z_d, z_fg * 1.0, r_d, r_fg * 1.0, d_M=d_m)
    np.testing.assert_allclose(got, eq3_literal(z_d, z_fg, r_d, r_fg, d_m), rtol=1e-12,
                               atol=1e-14)


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    z_fg = (rng.random((8, 9)) < 0.6) * 1.0
    z_d = rng.uniform(2, 3, (8, 9))
    # Depth differences away from the kinks of |.| (0) and of min(., d_M).
    r_d = z_d + rng.choice([-1, 1], (8, 9)) * rng.uniform(0.02, 0.12, (8, 9))
    r_fg = rng.uniform(0.05, 0.95, (8, 9))
    f = jax.jit(lambda rd, rf: delta(z_d, z_fg, rd, rf, d_M=D_M))
    g_d, g_fg = jax.grad(f, argnums=(0, 1))(r_d, r_fg)
    assert np.all(np.isfinite(g_d)) and np.all(np.isfinite(g_fg))
    eps = 1e-6
    for _ in range(5):
        dd, df = rng.normal(size=(8, 9)), rng.normal(size=(8, 9))
        fd = (f(r_d + eps * dd, r_fg + eps * df) - f(r_d - eps * dd, r_fg - eps * df)) / (2 * eps)
        np.testing.assert_allclose(np.sum(g_d * dd) + np.sum(g_fg * df), fd, rtol=1e-6)


def test_delta_batch_equals_loop(delta_jit):
    rng = np.random.default_rng(1)
    z_d, z_fg = rng.uniform(2, 3, (7, 5)), (rng.random((7, 5)) < 0.5) * 1.0
    r_d, r_fg = rng.uniform(2, 3, (4, 7, 5)), rng.random((4, 7, 5))
    got = jax.jit(delta_batch)(z_d, z_fg, r_d, r_fg, d_M=D_M)
    assert got.shape == (4,)
    for i in range(4):
        np.testing.assert_allclose(got[i], delta_jit(z_d, z_fg, r_d[i], r_fg[i], d_M=D_M),
                                   rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# Fused render + score.

# 44 x 30 is not a multiple of the 8-pixel tiles: exercises the padding.
K = Intrinsics.create(fx=36.0, fy=36.0, cx=21.5, cy=14.5, width=44, height=30)


def body(center, rng=None, jitter=0.0):
    """A 10-capsule figure (3 spheres) around ``center``, camera frame."""
    c = np.asarray(center, float)
    a = np.array([[0, 0, 0], [0, -0.5, 0], [0, -0.7, 0], [0.2, -0.45, 0], [0.25, -0.2, -0.2],
                  [-0.2, -0.45, 0], [-0.3, -0.2, 0.1], [0.1, 0, 0], [-0.1, 0, 0],
                  [0.3, 0.0, -0.35]]) + c
    b = np.array([[0, -0.5, 0], [0, -0.5, 0], [0, -0.7, 0], [0.25, -0.2, -0.2],
                  [0.3, 0.0, -0.35], [-0.3, -0.2, 0.1], [-0.35, 0.05, 0.1], [0.12, 0.85, 0],
                  [-0.12, 0.85, 0.05], [0.3, 0.0, -0.35]]) + c
    r = np.array([0.14, 0.08, 0.11, 0.05, 0.04, 0.05, 0.04, 0.07, 0.07, 0.05])
    if rng is not None:
        a, b = a + rng.normal(0, jitter, a.shape), b + rng.normal(0, jitter, b.shape)
    return a, b, r


def stack(bodies, dtype=jnp.float64) -> Capsules:
    return Capsules(*(jnp.asarray(np.stack(v), dtype) for v in zip(*bodies)))


@pytest.fixture(scope="module")
def scorer():
    return jax.jit(render_and_score, static_argnames=(
        "cull", "tile", "chunk", "group", "batch_size", "dtype", "vectorize"))


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(3)
    truth = body((0.05, 0.0, 3.0))
    a, b, r = (jnp.asarray(v) for v in truth)
    z_d, z_fg = render_depth(Capsules(a, b, r), K, sharpness=None)
    z_d = np.where(np.asarray(z_fg) > 0, np.asarray(z_d), np.nan)  # sensor-like NaN
    hyps = [truth] + [body((0.05, 0.0, 3.0), rng, j) for j in (0.02, 0.05, 0.1, 0.2)]
    hyps += [
        body((0.0, 0.1, 1.0)),  # close: fills most tiles, several chunks
        body((1.1, 0.3, 3.0)),  # partly outside the image
        body((0.0, 0.0, -3.0)),  # behind the camera
        body((9.0, 0.0, 3.0)),  # nothing in view
    ]
    return z_d, np.asarray(z_fg), hyps


@pytest.mark.parametrize("sharpness", [100.0, None])
def test_render_and_score_culled_equals_full_and_unfused(scorer, scene, sharpness):
    z_d, z_fg, hyps = scene
    caps = stack(hyps)
    culled = scorer(caps, z_d, z_fg, K, sharpness=sharpness, dtype=jnp.float64)
    # Hypotheses one after another (lax.map) or together (vmap, loops run to the longest).
    one_by_one = scorer(caps, z_d, z_fg, K, sharpness=sharpness, dtype=jnp.float64,
                        vectorize=False)
    np.testing.assert_allclose(one_by_one, culled, atol=1e-12)
    full = scorer(caps, z_d, z_fg, K, sharpness=sharpness, cull=False, batch_size=3,
                  dtype=jnp.float64)
    unfused = []
    render_and_delta = jax.jit(lambda c, s: delta(z_d, z_fg, *render_depth(c, K, sharpness=s)))
    for a, b, r in hyps:
        unfused.append(render_and_delta(Capsules(*(jnp.asarray(v) for v in (a, b, r))),
                                        sharpness))
    np.testing.assert_allclose(full, np.array(unfused), atol=1e-12)
    # Culling drops soft coverage below sigmoid(-10) per pixel and capsule only.
    np.testing.assert_allclose(culled, full, atol=1e-12 if sharpness is None else 1e-4)
    assert float(full[0]) < float(full[2]) < float(full[4])  # further off, worse
    np.testing.assert_allclose(full[-2:], 1.0, atol=1e-6)  # nothing of it in view
    if sharpness is None:
        assert float(full[0]) == 0.0  # the truth explains its own rendering exactly


def test_render_and_score_float32_close_to_float64(scorer, scene):
    z_d, z_fg, hyps = scene
    s64 = scorer(stack(hyps), z_d, z_fg, K, dtype=jnp.float64)
    s32 = scorer(stack(hyps), z_d, z_fg, K)
    assert s32.dtype == jnp.float32
    np.testing.assert_allclose(s32, s64, atol=2e-4)


def test_render_and_score_forward_mode_through_culling(scene):
    # Jittered hypotheses: at the truth itself |z_d - r_d| sits on the kink of |.| at 0.
    z_d, z_fg, hyps = scene
    caps = stack(hyps[1:4])
    tangent = jax.tree.map(jnp.ones_like, caps)
    culled = jax.jit(lambda c: render_and_score(c, z_d, z_fg, K, dtype=jnp.float64))
    full = jax.jit(lambda c: render_and_score(c, z_d, z_fg, K, cull=False, dtype=jnp.float64))
    _, deriv = jax.jvp(culled, (caps,), (tangent,))
    _, deriv_full = jax.jvp(full, (caps,), (tangent,))
    eps = 1e-6
    fd = (full(jax.tree.map(lambda v, t: v + eps * t, caps, tangent))
          - full(jax.tree.map(lambda v, t: v - eps * t, caps, tangent))) / (2 * eps)
    np.testing.assert_allclose(deriv_full, fd, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(deriv, deriv_full, rtol=1e-5, atol=1e-5)
    assert np.all(np.abs(fd) > 0.05)


def test_render_and_score_rejects_bad_arguments(scene):
    z_d, z_fg, hyps = scene
    with pytest.raises(ValueError, match="batch_size"):
        render_and_score(stack(hyps[:2]), z_d, z_fg, K, batch_size=2)
    with pytest.raises(ValueError, match="z_fg"):
        render_and_score(stack(hyps[:2]), z_d, z_fg[:-1], K)
