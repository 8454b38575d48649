"""Limb hypotheses (``_limbs.py``): the closed-form limb re-initialisation and the swapped
landmark variants, checked against poses whose keypoints are known."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import _limbs
from posetrack._observe import Landmarks
from posetrack._rotation import quat_to_matrix


@pytest.fixture(scope="module")
def poses():
    shape = pt.BodyShape.default(jnp.float32)
    rest = pt.facing_camera_params(2.5, jnp.float32)
    rng = np.random.default_rng(0)
    # A second pose: every limb joint turned by a random rotation of up to ~70 degrees.
    q = np.asarray(rest[3:]).reshape(10, 4).copy()
    for j in range(2, 10):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(0.4, 1.2)
        q[j] = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
    moved = jnp.concatenate([rest[:3], jnp.asarray(q.reshape(-1), jnp.float32)])
    return shape, rest, moved


def test_limb_ik_puts_each_limb_on_its_targets(poses):
    shape, rest, moved = poses
    targets = pt.keypoints(shape, moved)
    out = jax.jit(_limbs.limb_ik)(shape, rest, targets, jnp.ones(18, bool))
    got = np.asarray(pt.keypoints(shape, out))
    limb_kpts = [3, 4, 6, 7, 9, 10, 12, 13]
    np.testing.assert_allclose(got[limb_kpts], np.asarray(targets)[limb_kpts], atol=2e-3)
    # The torso and head did not move.
    torso = [0, 1, 2, 5, 8, 11]
    np.testing.assert_allclose(
        got[torso], np.asarray(pt.keypoints(shape, rest))[torso], atol=1e-5
    )


def test_limb_ik_leaves_limbs_without_targets_alone(poses):
    shape, rest, moved = poses
    valid = jnp.ones(18, bool).at[jnp.asarray([3, 4])].set(False)  # right arm unseen
    out = _limbs.limb_ik(shape, rest, pt.keypoints(shape, moved), valid)
    np.testing.assert_allclose(np.asarray(out[11:19]), np.asarray(rest[11:19]), atol=1e-6)
    assert np.abs(np.asarray(out[19:27]) - np.asarray(rest[19:27])).max() > 0.1


def test_quat_between_handles_opposite_directions():
    a = jnp.asarray([0.0, -1.0, 0.0])
    q = _limbs.quat_between(a, -a, jnp.asarray([0.0, 0.0, 1.0]))
    turned = np.asarray(quat_to_matrix(q)) @ np.asarray(a)
    np.testing.assert_allclose(turned, -np.asarray(a), atol=1e-6)


def test_swapped_variant_relabels_arm_landmarks(poses):
    shape, rest, moved = poses
    kps = pt.keypoints(shape, moved)
    lm = Landmarks(
        keypoints2d=jnp.zeros((18, 2)), confidence=jnp.ones(18), points3d=kps,
        detected=jnp.ones(18, bool), has_depth=jnp.ones(18, bool),
    )  # fmt: skip
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=160.0, cy=120.0, width=320, height=240)
    starts, lms, use3d, _ = _limbs.limb_hypotheses(shape, intr, rest, lm, count=3, distance=0.2)
    # Variant 0 takes the landmarks as labelled, variant 2 has the arms' exchanged.
    np.testing.assert_allclose(np.asarray(lms.points3d[0]), np.asarray(kps))
    np.testing.assert_allclose(
        np.asarray(lms.points3d[2])[[3, 4, 6, 7]], np.asarray(kps)[[6, 7, 3, 4]]
    )
    right_wrist = np.asarray(pt.keypoints(shape, starts[2]))[4]
    assert np.linalg.norm(right_wrist - np.asarray(kps)[7]) < 0.05  # reaches the left wrist
    assert bool(use3d[0, 4]) and bool(use3d[2, 4])


def test_config_limits_limb_hypotheses():
    with pytest.raises(ValueError, match="limb_hypotheses"):
        pt.TrackerConfig(num_hypotheses=4, limb_hypotheses=4)
    with pytest.raises(ValueError, match="limb_hypotheses"):
        pt.TrackerConfig(limb_hypotheses=5)
    assert pt.TrackerConfig.recommended("lvm", limb_hypotheses=2).num_limb_hypotheses == 0
    assert pt.TrackerConfig.paper("mht_h").limb_hypotheses == 0
