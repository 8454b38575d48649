"""Landmark selection weights (W^r, W^g, W^h, 2D weights) and weighted subset sampling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from posetrack import Intrinsics
from posetrack._observe import Landmarks
from posetrack._select import (
    gaussian_weight,
    geometry_distance,
    sample_subset,
    temporal_distance,
)

INTR = Intrinsics.create(fx=100.0, fy=100.0, cx=39.5, cy=29.5, width=80, height=60)


def _landmarks(points, has_depth=None):
    points = jnp.asarray(points, jnp.float32)
    n = points.shape[0]
    uv = jnp.stack(
        [points[:, 0] / points[:, 2] * 100 + 39.5, points[:, 1] / points[:, 2] * 100 + 29.5], -1
    )
    has = jnp.ones(n, bool) if has_depth is None else jnp.asarray(has_depth)
    return Landmarks(
        keypoints2d=uv,
        confidence=jnp.ones(n),
        points3d=points,
        detected=jnp.ones(n, bool),
        has_depth=has,
    )


def test_gaussian_weight_is_the_papers_formula():
    d = jnp.array([0.0, 0.5, 1.0])
    np.testing.assert_allclose(
        np.asarray(gaussian_weight(d, 0.5)), np.exp(-np.array([0, 0.5, 1]) / 0.5), rtol=1e-6
    )


def test_temporal_distance_is_truncated_and_normalised():
    prev = jnp.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])
    lm = _landmarks([[0.05, 0.0, 2.0], [0.0, 0.3, 2.0], [0.0, 2.0, 2.0]])
    d3, d2 = temporal_distance(lm, prev, INTR, d_hmax=0.2)
    np.testing.assert_allclose(np.asarray(d3), [0.25, 1.0, 1.0], atol=1e-6)
    # The 2D counterpart measures the same lateral offsets in metres at the keypoint's depth.
    np.testing.assert_allclose(np.asarray(d2), [0.25, 1.0, 1.0], atol=1e-5)


def _wall(z=2.0):
    return jnp.full((60, 80), z, jnp.float32)


def test_geometry_distance_zero_for_a_consistent_bone():
    """A 0.3 m bone lying on a surface 5 cm in front of its axis (radius 5 cm): d_g = 0."""
    partner = jnp.array([[0.0, -0.15, 2.05]])
    lm = _landmarks([[0.0, 0.15, 2.05]])
    d = geometry_distance(
        lm, partner, jnp.ones(1, bool), jnp.array([0.3]), jnp.array([0.05]), _wall(2.0), INTR
    )
    np.testing.assert_allclose(np.asarray(d), [0.0], atol=1e-5)


def test_geometry_distance_length_and_line_terms():
    partner = jnp.array([[0.0, -0.15, 2.05]] * 3)
    lm = _landmarks([
        [0.0, 0.45, 2.05],   # bone 0.6 m instead of 0.3: length term saturates (1), line 0
        [0.0, 0.15, 2.05],   # right length, but the observed surface is 1 m behind: line = 1
        [0.0, 0.15, 2.05],   # right length, no depth along the line at all: line = 1
    ])  # fmt: skip
    rest, radius = jnp.full(3, 0.3), jnp.full(3, 0.05)
    d0 = geometry_distance(
        lm, partner, jnp.ones(3, bool), rest, radius, _wall(2.0), INTR, length_tolerance=0.35
    )
    d1 = geometry_distance(lm, partner, jnp.ones(3, bool), rest, radius, _wall(3.0), INTR)
    d2 = geometry_distance(lm, partner, jnp.ones(3, bool), rest, radius, jnp.zeros((60, 80)), INTR)
    assert float(d0[0]) == pytest.approx(0.5, abs=1e-5)
    assert float(d1[1]) == pytest.approx(0.5, abs=1e-5)
    assert float(d2[2]) == pytest.approx(0.5, abs=1e-5)
    # A landmark without depth gets the maximal distance.
    lm_nodepth = _landmarks([[0.0, 0.15, 2.05]], has_depth=[False])
    d3 = geometry_distance(
        lm_nodepth, partner[:1], jnp.ones(1, bool), rest[:1], radius[:1], _wall(2.0), INTR
    )
    assert float(d3[0]) == 1.0


@pytest.fixture(scope="module")
def sampler():
    return jax.jit(jax.vmap(sample_subset, in_axes=(0, None, None)))


def test_subset_size_is_floor_of_the_weight_sum(sampler):
    w = jnp.array([1.0, 1.0, 0.9, 0.5, 0.3, 0.0, 0.8])
    avail = jnp.array([True, True, True, True, True, True, False])
    keys = jax.random.split(jax.random.PRNGKey(0), 200)
    sel = np.asarray(sampler(keys, w, avail))
    assert (sel.sum(1) == 3).all()  # floor(1 + 1 + 0.9 + 0.5 + 0.3) = 3, item 6 unavailable
    assert not sel[:, 5].any() and not sel[:, 6].any()  # zero weight / unavailable: never drawn
    # all-ones weights select everything available (MHT_r with r = R = 0 equals LVM)
    allsel = np.asarray(sampler(keys[:5], jnp.ones(7), avail))
    assert (allsel == np.asarray(avail)).all()


def test_subset_sampling_follows_the_weights(sampler):
    """Drawing one of three by weight: frequencies match w / sum(w) (sequential sampling)."""
    w = jnp.array([0.6, 0.3, 0.15])  # floor(sum) = 1
    keys = jax.random.split(jax.random.PRNGKey(1), 4000)
    sel = np.asarray(sampler(keys, w, jnp.ones(3, bool)))
    freq = sel.mean(0)
    np.testing.assert_allclose(freq, np.asarray(w) / float(w.sum()), atol=0.03)


def test_different_keys_give_different_subsets(sampler):
    w = jnp.full(18, 0.7)
    sel = np.asarray(sampler(jax.random.split(jax.random.PRNGKey(2), 5), w, jnp.ones(18, bool)))
    assert len({tuple(s) for s in sel}) > 1
