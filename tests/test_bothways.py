"""The two passes' average (``_bothways.py``): poses half-way, the reversed view's reads.

The tracker-level behaviour of ``SmoothSettings(both_ways=True)`` is checked in
``test_smooth.py`` beside the other modes (it reuses that module's tracked clip).
"""

import numpy as np
import pytest

import posetrack as pt
from posetrack._bothways import Reindexed, average_poses
from posetrack._so3 import axis_angle, matrix_to_quat, quat_to_matrix


def _params(root, angles_z):
    """Poses with the root at ``root`` and every quaternion a rotation about z."""
    T = len(angles_z)
    p = np.zeros((T, 43))
    p[:, :3] = root
    for t, a in enumerate(angles_z):
        q = matrix_to_quat(axis_angle(np.array([0.0, 0.0, 1.0]), a))
        p[t, 3:] = np.tile(q, 10)
    return p


def test_average_poses_halves_positions_and_rotations():
    a = _params([0.0, 0.0, 2.0], [0.0, 0.2])
    b = _params([0.2, -0.1, 3.0], [np.pi / 2, 0.6])
    b[1, 7:11] *= -1  # the same rotation written as -q: the shorter arc is still taken
    ka = np.random.default_rng(0).normal(size=(2, 18, 3))
    kb = np.random.default_rng(1).normal(size=(2, 18, 3))
    params, kps = average_poses(a, b, ka, kb)
    np.testing.assert_allclose(params[:, :3], [[0.1, -0.05, 2.5]] * 2)
    np.testing.assert_allclose(kps, (ka + kb) / 2)
    for t, want in enumerate([np.pi / 4, 0.4]):
        for j in range(10):
            R = quat_to_matrix(params[t, 3 + 4 * j : 7 + 4 * j])
            np.testing.assert_allclose(R, axis_angle(np.array([0.0, 0.0, 1.0]), want), atol=1e-9)
    # The inputs are not changed.
    np.testing.assert_array_equal(a[:, :3], [[0.0, 0.0, 2.0]] * 2)


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
