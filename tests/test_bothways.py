"""The two passes' fusion (``_bothways.py``): smoothed keypoints averaged, the pose fitted to
them; the reversed view's reads.

The tracker-level behaviour of ``SmoothSettings(both_ways=True)`` is checked in
``test_smooth.py`` beside the other modes (it reuses that module's tracked clip).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import _body as body
from posetrack._bothways import FUSE_BLOCK, Reindexed, fuse_smoothed, fuse_weights
from posetrack._so3 import axis_angle, matrix_to_quat


def _bent_arms(angles: np.ndarray, shift: float = 0.0) -> np.ndarray:
    """(T, 43) poses facing the camera at 2.5 m, both elbows bent by ``angles`` (radians,
    about the body's x axis), the root moved sideways by ``shift`` metres."""
    p = np.tile(body.facing_camera_params_np(2.5), (len(angles), 1)).astype(np.float64)
    p[:, 0] += shift
    for t, a in enumerate(angles):
        q = matrix_to_quat(axis_angle(np.array([1.0, 0.0, 0.0]), a))
        p[t, 15:19] = q  # right elbow
        p[t, 23:27] = q  # left elbow
    return p


def _keypoints(shape, params):
    return np.asarray(
        jax.vmap(lambda x: body.keypoints(shape, x))(jnp.asarray(params, jnp.float32))
    )


def test_fuse_smoothed_fits_the_pose_to_the_average_of_the_two_tracks():
    """More frames than one block (padding, two calls of the compiled fit): the fused keypoints
    are the model keypoints of the fused poses and lie near the two tracks' average (not on it
    everywhere: the average of two bent arms' elbows and wrists is not an arm of the same
    bone lengths, so the fit compromises, by 12 mm at most here)."""
    shape = pt.BodyShape.default()
    T = FUSE_BLOCK + 6
    a = _bent_arms(np.linspace(0.2, 0.6, T))
    b = _bent_arms(np.linspace(0.8, 1.4, T), shift=0.02)
    ka, kb = _keypoints(shape, a), _keypoints(shape, b)
    params, kps = fuse_smoothed(shape, a, b, ka, kb)
    assert params.shape == (T, 43) and kps.shape == (T, 18, 3)
    np.testing.assert_allclose(kps, _keypoints(shape, params), atol=1e-5)
    target = 0.5 * (ka + kb)
    err = np.linalg.norm(kps - target, axis=-1)
    assert err.mean() < 0.003 and err.max() < 0.02, (err.mean(), err.max())  # metres
    # Not either input, nor their mean pose's keypoints the trivial way round.
    assert np.linalg.norm(kps - ka, axis=-1).max() > 0.05
    assert np.linalg.norm(kps - kb, axis=-1).max() > 0.05
    np.testing.assert_allclose(np.linalg.norm(params[:, 3:].reshape(T, 10, 4), axis=-1), 1.0,
                               atol=1e-5)  # fmt: skip


def test_fuse_smoothed_of_one_track_twice_is_that_track():
    shape = pt.BodyShape.default()
    a = _bent_arms(np.linspace(0.1, 1.2, 9))
    ka = _keypoints(shape, a)
    params, kps = fuse_smoothed(shape, a, a, ka, ka)
    np.testing.assert_allclose(kps, ka, atol=1e-4)


def test_fuse_smoothed_weighs_the_second_track_as_asked():
    """Weight 0 gives the first track, 1 the second; the weight is per frame."""
    shape = pt.BodyShape.default()
    a = _bent_arms(np.full(3, 0.3))
    b = _bent_arms(np.full(3, 0.9))
    ka, kb = _keypoints(shape, a), _keypoints(shape, b)
    _, kps = fuse_smoothed(shape, a, b, ka, kb, np.array([0.0, 1.0, 0.5]))
    np.testing.assert_allclose(kps[0], ka[0], atol=1e-4)
    np.testing.assert_allclose(kps[1], kb[1], atol=1e-4)
    wrist = 4  # right wrist: between the two, neither
    assert (
        0.3
        < np.linalg.norm(kps[2, wrist] - ka[2, wrist]) / np.linalg.norm(kb[2, wrist] - ka[2, wrist])
        < 0.7
    )


def test_fuse_weights_ramp_in_and_out_next_to_the_forward_pass_alone():
    shared = np.ones(14, bool)
    shared[[0, 7]] = False
    forward = np.ones(14, bool)
    w = fuse_weights(shared, forward, ramp=3)
    want = [0, 1 / 3, 2 / 3, 1, 1, 2 / 3, 1 / 3, 0, 1 / 3, 2 / 3, 1, 1, 1, 1]
    np.testing.assert_allclose(w, 0.5 * np.asarray(want))
    # Next to a frame nobody estimates (a broken track): no ramp.
    forward[7] = False
    want = [0, 1 / 3, 2 / 3, 1, 1, 1, 1, 0, 1, 1, 1, 1, 1, 1]
    np.testing.assert_allclose(fuse_weights(shared, forward, ramp=3), 0.5 * np.asarray(want))
    np.testing.assert_array_equal(fuse_weights(np.ones(4, bool), np.ones(4, bool)), 0.5)
    np.testing.assert_array_equal(fuse_weights(np.zeros(3, bool), np.ones(3, bool)), 0.0)
    # Shared frames between frames nobody estimates: one half, no ramp; the others 0.
    shared, forward = np.array([0, 1, 1, 0], bool), np.array([0, 1, 1, 0], bool)
    np.testing.assert_array_equal(fuse_weights(shared, forward), [0.0, 0.5, 0.5, 0.0])


def test_reindexed_reads_only_what_is_asked_in_the_order_given():
    class Counting(list):
        reads: list

        def __getitem__(self, i):
            self.reads.append(i)
            return super().__getitem__(i)

    frames = Counting(["f0", "f1", "f2", "f3"])
    frames.reads = []
    view = Reindexed(frames, np.arange(3, -1, -1))
    assert len(view) == 4 and frames.reads == []
    assert view[0] == "f3" and view[3] == "f0" and view[-1] == "f0"
    assert view[1:3] == ["f2", "f1"]
    assert frames.reads == [3, 0, 0, 2, 1]


def test_both_ways_is_a_bool_setting_of_the_motion_model():
    assert pt.SmoothSettings().both_ways is False  # opt-in (benchmarks/README.md)
    assert pt.SmoothSettings(both_ways=True).both_ways is True
    with pytest.raises(ValueError, match="both_ways"):
        pt.SmoothSettings(both_ways=1)
