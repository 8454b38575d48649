"""The paper's accuracy metrics (section 3) and the naive-lifting floor.

* **D**: the mean 3D distance (reported in millimetres) between estimated and ground-truth
  joints over a sequence, and its standard deviation over frames (of the per-frame mean).
* **C_j(d)**: the joint success rate, the share of (frame, joint) pairs whose error is below d.

Both use the 13 body joints (neck, shoulders, elbows, wrists, hips, knees, ankles; COCO-18
keypoints 1..13), as the face keypoints have no motion-capture counterpart in most data sets.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ._body import BODY_JOINTS


@dataclasses.dataclass(frozen=True)
class Accuracy:
    """Accuracy of one method on one or more sequences (all distances in millimetres)."""

    mean_mm: float
    """D: mean joint error over all frames and body joints."""
    std_mm: float
    """Standard deviation over frames of the per-frame mean joint error."""
    success: dict[int, float]
    """C_j(d) for the requested thresholds d (mm) -> share in [0, 1]."""
    coverage: float
    """Share of (frame, joint) pairs that had an estimate (1.0 for a tracker)."""
    frames: int
    """Frames counted."""

    def row(self) -> dict[str, float]:
        """Flat dict for tables and JSON."""
        out = {"D_mean_mm": self.mean_mm, "D_std_mm": self.std_mm, "coverage": self.coverage}
        out.update({f"C_{d}mm": v for d, v in self.success.items()})
        return out


def joint_errors(
    estimate: np.ndarray, truth: np.ndarray, *, joints: tuple[int, ...] = BODY_JOINTS
) -> np.ndarray:
    """(frame, joint) Euclidean errors in metres; NaN where the estimate is NaN."""
    est = np.asarray(estimate, dtype=np.float64)[:, joints]
    gt = np.asarray(truth, dtype=np.float64)[:, joints]
    if est.shape != gt.shape:
        raise ValueError(f"joint_errors: estimate {est.shape} and truth {gt.shape} differ")
    return np.linalg.norm(est - gt, axis=-1)


def accuracy(
    estimate: np.ndarray,
    truth: np.ndarray,
    *,
    thresholds_mm: tuple[int, ...] = (50, 100, 150),
    joints: tuple[int, ...] = BODY_JOINTS,
) -> Accuracy:
    """D (mean and std over frames) and C_j(d) of ``estimate`` against ``truth``.

    Args:
        estimate: (frame, 18, 3) estimated keypoints, metres; NaN = not estimated (counted in
            ``coverage``, excluded from D and counted as a failure in C_j).
        truth: (frame, 18, 3) ground truth, metres.
        thresholds_mm: the d values of C_j(d).
        joints: keypoint indices to evaluate (the 13 body joints by default).
    """
    err = joint_errors(estimate, truth, joints=joints) * 1000.0
    have = np.isfinite(err)
    if not have.any():
        return Accuracy(np.nan, np.nan, {d: 0.0 for d in thresholds_mm}, 0.0, len(err))
    per_frame = np.array([e[h].mean() for e, h in zip(err, have) if h.any()])
    success = {d: float(np.mean(np.where(have, err, np.inf) < d)) for d in thresholds_mm}
    return Accuracy(
        mean_mm=float(err[have].mean()),
        std_mm=float(per_frame.std()),
        success=success,
        coverage=float(have.mean()),
        frames=len(err),
    )


def success_curve(estimate: np.ndarray, truth: np.ndarray, thresholds_mm: np.ndarray) -> np.ndarray:
    """C_j(d) for an array of thresholds (the paper's Fig. 3 curve)."""
    err = joint_errors(estimate, truth) * 1000.0
    err = np.where(np.isfinite(err), err, np.inf).reshape(-1)
    return np.array([np.mean(err < d) for d in np.asarray(thresholds_mm)])


def naive_lifting(points3d: np.ndarray, has_depth: np.ndarray, *, hold: bool = True) -> np.ndarray:
    """The floor every method must beat: each keypoint back-projected at its own depth.

    Args:
        points3d: (frame, 18, 3) lifted landmarks (plain lifting, no model).
        has_depth: (frame, 18) F_i flags.
        hold: where a keypoint has no lifted point, repeat its last one (a trivial tracker);
            NaN before its first. With ``hold=False`` such entries are NaN.

    Returns:
        (frame, 18, 3) metres, NaN where nothing is known.
    """
    P = np.asarray(points3d, dtype=np.float64).copy()
    F = np.asarray(has_depth, dtype=bool)
    P[~F] = np.nan
    if hold:
        last = np.full(P.shape[1:], np.nan)
        for t in range(len(P)):
            last = np.where(F[t][:, None], P[t], last)
            P[t] = last
    return P


def followed_identity(estimate: np.ndarray, people: np.ndarray) -> np.ndarray:
    """Whom the estimate follows in each frame: the index of the nearest person's truth.

    Args:
        estimate: (frame, 18, 3) estimated keypoints, metres; NaN = not estimated.
        people: (frame, Q, 18, 3) ground truth of the Q people in the scene (the followed one
            first, say), metres; NaN rows for a person not in the scene that frame.

    Returns:
        (frame,) int: argmin over people of the mean distance over the body joints; -1 where
        the frame has no estimate.
    """
    est = np.asarray(estimate, np.float64)[:, None, list(BODY_JOINTS)]
    truth = np.asarray(people, np.float64)[:, :, list(BODY_JOINTS)]
    with warnings.catch_warnings():  # all-NaN rows (not estimated, person absent) give NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        dist = np.nanmean(np.linalg.norm(est - truth, axis=-1), axis=-1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    ident = dist.argmin(axis=1)
    return np.where(np.isfinite(dist).any(axis=1), ident, -1)


def identity_jumps(identity: np.ndarray) -> int:
    """How often the followed person changes: consecutive estimated frames (frames without
    an estimate, ``-1``, skipped) whose identities (:func:`followed_identity`) differ."""
    ident = np.asarray(identity)
    ident = ident[ident >= 0]
    return int(np.sum(ident[1:] != ident[:-1]))
