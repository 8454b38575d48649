"""The lifting's surface offsets (``_geometry.py``): the radius-based ones and the posed
model's own, checked against an independent NumPy march along each joint's viewing ray."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import _body as B
from posetrack._geometry import posed_surface_offsets, surface_offsets
from posetrack._rotation import quat_multiply

SHAPE = pt.BodyShape.default(jnp.float32)
FACE = np.array([0, 14, 15, 16, 17])


def _turned(yaw_deg: float, elbow_deg: float = 0.0):
    """The rest pose at 2.5 m turned about the vertical by ``yaw_deg``, both elbows bent by
    ``elbow_deg`` about their local x axis (a forearm swung toward or away from the camera)."""
    p = pt.facing_camera_params(2.5, jnp.float32)
    half = np.deg2rad(yaw_deg) / 2
    yaw = jnp.asarray([np.cos(half), 0.0, np.sin(half), 0.0], jnp.float32)
    p = p.at[3:7].set(quat_multiply(yaw, p[3:7]))
    bend = np.deg2rad(elbow_deg) / 2
    q = jnp.asarray([np.cos(bend), np.sin(bend), 0.0, 0.0], jnp.float32)
    for j in B.JOINT_NAMES.index("right_elbow"), B.JOINT_NAMES.index("left_elbow"):
        s = 7 + 4 * (j - 1)
        p = p.at[s : s + 4].set(quat_multiply(p[s : s + 4], q))
    return B.normalize_params(p)


def _marched(shape, params, step=2e-4):
    """Distance along each keypoint's ray from the first point inside a capsule to the joint,
    metres (NaN where the ray meets no capsule before the joint): NumPy, by marching."""
    kp = np.asarray(pt.keypoints(shape, params), np.float64)
    a, b, r = (np.asarray(x, np.float64) for x in B.capsules(shape, params))
    out = np.full(len(kp), np.nan)
    for k, joint in enumerate(kp):
        ray = joint / np.linalg.norm(joint)
        s = np.arange(np.linalg.norm(joint) - 0.4, np.linalg.norm(joint) + step, step)
        pts = s[:, None, None] * ray  # (sample, 1, 3)
        d = b - a
        u = np.clip(np.sum((pts - a) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-12), 0, 1)
        dist = np.linalg.norm(pts - (a + u[..., None] * d), axis=-1)  # (sample, capsule)
        inside = np.any(dist < r, axis=1)
        if inside.any():
            out[k] = np.linalg.norm(joint) - s[np.argmax(inside)]
    return out


@pytest.fixture(scope="module")
def posed():
    return jax.jit(posed_surface_offsets, static_argnums=2)


@pytest.mark.parametrize("yaw, elbow", [(0.0, 0.0), (60.0, -70.0), (-90.0, 40.0)])
def test_posed_offsets_are_the_distance_behind_the_models_surface(posed, yaw, elbow):
    params = _turned(yaw, elbow)
    base = np.asarray(surface_offsets(SHAPE))
    full = np.asarray(posed(SHAPE, params, 1.0))
    marched = _marched(SHAPE, params)
    usable = np.isfinite(marched) & (marched <= 0.25)
    body = np.zeros(18, bool)
    body[list(B.BODY_JOINTS)] = True
    # Body keypoints whose ray meets the model within 25 cm: the model's own offset.
    assert np.sum(body & usable) >= 6  # a side view: the far limbs lie behind the torso
    np.testing.assert_allclose(full[body & usable], marched[body & usable], atol=1e-3)
    # Elsewhere, and for the face keypoints, the radius-based offset.
    np.testing.assert_array_equal(full[~(body & usable)], base[~(body & usable)])
    np.testing.assert_array_equal(full[FACE], base[FACE])
    # The weight blends the two; 0 is the radius-based offsets exactly.
    np.testing.assert_array_equal(np.asarray(posed(SHAPE, params, 0.0)), base)
    half = np.asarray(posed(SHAPE, params, 0.5))
    np.testing.assert_allclose(half, (base + full) / 2, atol=1e-6)


def test_a_turned_body_moves_the_offsets(posed):
    """The model's offsets follow the pose, where the radius-based ones cannot: turned side-on,
    a hip lies behind the pelvis' width, not its depth, and an elbow bent toward the camera
    behind its forearm."""
    front = np.asarray(posed(SHAPE, _turned(0.0), 1.0))
    side = np.asarray(posed(SHAPE, _turned(90.0), 1.0))
    hips = [8, 11]
    near_hip = hips[int(np.argmin(np.asarray(pt.keypoints(SHAPE, _turned(90.0)))[hips, 2]))]
    assert side[near_hip] > front[near_hip] + 0.01


def test_config_weight_is_validated():
    for bad in (-0.1, 1.5, float("nan"), True, "0.5"):
        with pytest.raises(ValueError, match="surface_offset_posed"):
            pt.TrackerConfig(surface_offset_posed=bad)
