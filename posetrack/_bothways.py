"""The offline recording tracked both ways: forwards and backwards, the two tracks fused.

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
smooths each pass, and fuses the two smoothed tracks (:func:`fuse_smoothed`): their
keypoints averaged in the frames both have an estimate of the same person (the backward
pass's weight ramping in and out next to frames they do not share, :func:`fuse_weights`),
the pose fitted to the average. The cost is the second pass's steps and a second smoother
pass.

A first version averaged the two passes' per-frame poses (keypoints, half-way joint
rotations) and smoothed once: on the clips the idea was found on it was worse than one way
(50.1 -> 51.8 mm; a clean squat 35 -> 74 mm, where the half-way pose of two passes reaching
the same keypoints with different joint twists was far from both). What each version
measured: benchmarks/README.md, "Offline: the recording tracked both ways" and "Offline both
ways, second fusion".
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import _body as body
from ._programs import program
from ._smooth import pose_from_keypoints

#: Frames fitted per call of :func:`fit_poses` (padded: one compiled program for any length).
FUSE_BLOCK = 64

#: Gauss-Newton steps of the pose fitted to the fused keypoints. On a tuning squat (seed 136,
#: 2026-12-02) 3 steps left the fit 3.6 mm off the fused keypoints' D with 2.5x their
#: acceleration error; 10 steps came within 1.3 mm, 30 no closer.
FUSE_ITERATIONS = 10

#: Frames over which the backward pass's weight rises from 0 to one half next to a frame of
#: the forward pass's alone (so the fused track does not jump where fusing starts or stops).
FUSE_RAMP = 5


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


@program("fit_poses", static_argnums=(0,))
def fit_poses(
    iterations: int,
    shape: body.BodyShape,
    starts: Float[Array, "frame 43"],
    targets: Float[Array, "frame kpt 3"],
) -> tuple[Float[Array, "frame 43"], Float[Array, "frame kpt 3"]]:
    """Each frame's pose near ``starts`` whose keypoints best match ``targets``
    (:func:`posetrack._smooth.pose_from_keypoints`), with the keypoints of those poses."""
    poses = jax.vmap(lambda p, x: pose_from_keypoints(shape, p, x, iterations))(starts, targets)
    return poses, jax.vmap(lambda p: body.keypoints(shape, p))(poses)


def fuse_smoothed(
    shape: body.BodyShape,
    params_a: np.ndarray,
    params_b: np.ndarray,
    keypoints_a: np.ndarray,
    keypoints_b: np.ndarray,
    weight_b: np.ndarray | float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """The two passes' smoothed tracks of the same frames fused: their keypoints averaged
    (``weight_b`` on the second, per frame or for all) and the pose fitted to the average
    (:data:`FUSE_ITERATIONS` steps) from each pass's pose, the closer fit kept frame by frame.
    (Not from the half-way pose of the two, each rotation by slerp: two passes can reach the
    same keypoints with different joint twists, and half-way between them was 81 mm off on
    the squat that showed it.)

    Returns:
        ``(params, keypoints)``: ``(T, 43)`` float32 and ``(T, 18, 3)``, the fitted poses
        and their keypoints (the model's, so ``params`` and ``keypoints`` agree).
    """
    w = np.broadcast_to(np.asarray(weight_b, np.float64), (len(params_a),))[:, None, None]
    targets = (1 - w) * np.asarray(keypoints_a, np.float64) + w * np.asarray(
        keypoints_b, np.float64
    )
    fits = [_fit_blocks(shape, np.asarray(p, np.float64), targets) for p in (params_a, params_b)]
    (pa, ka), (pb, kb) = fits
    a_closer = np.linalg.norm(ka - targets, axis=-1).mean(-1) <= np.linalg.norm(
        kb - targets, axis=-1
    ).mean(-1)
    return np.where(a_closer[:, None], pa, pb), np.where(a_closer[:, None, None], ka, kb)


def _fit_blocks(
    shape: body.BodyShape, starts: np.ndarray, targets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_poses` over any number of frames, in padded blocks of :data:`FUSE_BLOCK`."""
    T = len(starts)
    params, kps = np.zeros((T, 43), np.float32), np.zeros((T, 18, 3), np.float32)
    for i in range(0, T, FUSE_BLOCK):
        n = min(FUSE_BLOCK, T - i)
        pad = ((0, FUSE_BLOCK - n),)
        s = np.pad(starts[i : i + n], pad + ((0, 0),), mode="edge")
        x = np.pad(targets[i : i + n], pad + ((0, 0), (0, 0)), mode="edge")
        p, k = fit_poses(
            FUSE_ITERATIONS, shape, jnp.asarray(s, jnp.float32), jnp.asarray(x, jnp.float32)
        )
        params[i : i + n], kps[i : i + n] = np.asarray(p)[:n], np.asarray(k)[:n]
    return params, kps


def fuse_weights(shared: np.ndarray, forward: np.ndarray, ramp: int = FUSE_RAMP) -> np.ndarray:
    """The backward pass's weight in each frame (:func:`fuse_smoothed`'s ``weight_b``): one
    half in the frames both passes share (``shared``, (T,) bool), rising linearly over
    ``ramp`` frames from 0 next to each frame the forward pass alone estimates (``forward``
    and not ``shared``); 0 where not shared. Next to a frame without any estimate there is
    no ramp: the track is broken there either way, and a ramp between two passes that
    disagree by half a metre shook the fused track by 50 mm/frame^2 at its ends."""
    shared = np.asarray(shared, bool)
    T = len(shared)
    off = np.flatnonzero(np.asarray(forward, bool) & ~shared)
    if len(off) == 0:
        return np.where(shared, 0.5, 0.0)
    t = np.arange(T)
    # Distance in frames to the nearest frame of the forward pass alone.
    i = np.clip(np.searchsorted(off, t), 1, len(off)) - 1
    near = np.minimum(np.abs(t - off[i]), np.abs(t - off[np.minimum(i + 1, len(off) - 1)]))
    return np.where(shared, 0.5 * np.minimum(1.0, near / ramp), 0.0)
