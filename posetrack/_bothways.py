"""The offline recording tracked both ways: forwards and backwards, the two passes averaged.

Every per-frame track is one random walk among many the MHT could take: its landmark
subsets are drawn at random, and a wrong turn (a limb locked onto the other side, a
hypothesis set that lost a limb) lasts until the data pull it back. The same clip tracked
again differs by several mm (benchmarks/README.md, "How much the reported figures move with
the tracker's seed"), and where one track locks in an error another often does not. A
track run backwards, from the last frame, begins its errors elsewhere: on 20 tuning runs
(2026-12-02, a prototype) the mean of a forward and a backward smoothed track had D 47.1 mm
against 50.7 forwards alone; two forward tracks of different seeds averaged, 49.7.

:meth:`Tracker.run` offline with :attr:`SmoothSettings.both_ways` runs the per-frame
tracker a second time, from the last frame to the first (a fresh track of the person the
forward pass followed in each frame, with the left/right labels the forward pass fitted),
and averages the two passes' per-frame estimates (:func:`average_poses`: keypoints and root
position averaged, joint rotations half-way by slerp, confidences averaged) in the frames
both tracked with the same person; the motion model then smooths the average once. On 24
fresh tuning runs with three tracker seeds each, D fell by 2.5 mm (t -2.6), by 3.8-6.8 mm
a group under occlusion and within 0.4 mm clean (benchmarks/README.md, "Offline: the
recording tracked both ways"). The cost is the second pass's steps.

Opt-in (``SmoothSettings.both_ways`` is False by default): on the 24 runs it was found on it
was worse on average (50.1 -> 51.8 mm) and one clean clip went 35 -> 74 mm, where the
passes disagreed by 100+ mm over the first frames and the smoothed average of their poses
was worse than either. Averaging only where the passes agree did not help (clean clips lose
even where they agree on every frame); averaging the passes' *smoothed* keypoints (the
prototype) did not show the loss and is the next thing to build.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._so3 import slerp


class Reindexed(Sequence):
    """A read-only view of a sequence at given indices (lazy: a file reader stays lazy)."""

    def __init__(self, frames, indices: np.ndarray):
        self._frames, self._indices = frames, np.asarray(indices, np.int64)

    def __len__(self) -> int:
        return len(self._indices)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._frames[int(j)] for j in self._indices[i]]
        return self._frames[int(self._indices[i])]


def average_poses(
    params_a: np.ndarray, params_b: np.ndarray, keypoints_a: np.ndarray, keypoints_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The half-way pose of two estimates of the same frames.

    Args:
        params_a, params_b: ``(T, 43)`` poses (root xyz, root quaternion, 9 joint
            quaternions, wxyz).
        keypoints_a, keypoints_b: ``(T, 18, 3)`` their keypoints, metres.

    Returns:
        ``(params, keypoints)``: the root positions and keypoints averaged, each quaternion
        half-way along the shorter arc (:func:`posetrack._so3.slerp`).
    """
    a, b = np.asarray(params_a, np.float64), np.asarray(params_b, np.float64)
    out = a.copy()
    out[:, :3] = 0.5 * (a[:, :3] + b[:, :3])
    qa, qb = a[:, 3:].reshape(-1, 10, 4), b[:, 3:].reshape(-1, 10, 4)
    out[:, 3:] = slerp(qa, qb, 0.5).reshape(-1, 40)
    kps = 0.5 * (np.asarray(keypoints_a, np.float64) + np.asarray(keypoints_b, np.float64))
    return out, kps
