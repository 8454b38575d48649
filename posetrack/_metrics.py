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


#: Left/right pairs of limb keypoints (COCO-18) checked by :func:`swapped_limb_frames`:
#: elbows, wrists, knees, ankles.
LIMB_PAIRS: tuple[tuple[int, int], ...] = ((3, 6), (4, 7), (9, 12), (10, 13))
#: The knees and ankles, (right, left) keypoint indices (the legs' half of ``LIMB_PAIRS``; what
#: ``ResidualSettings.leg_labels_free`` lets the fits take whichever way round).
LEG_PAIRS: tuple[tuple[int, int], ...] = LIMB_PAIRS[2:]


def acceleration_error(
    estimate: np.ndarray, truth: np.ndarray, *, joints: tuple[int, ...] = BODY_JOINTS
) -> float:
    """Mean acceleration error, mm/frame^2: how much an estimate shakes that the truth does not.

    The mean over joints and frames t of ``||(p[t+1] - 2 p[t] + p[t-1]) - (g[t+1] - 2 g[t] +
    g[t-1])||``; a triple with a NaN (not estimated) is skipped. A per-frame estimator with
    independent errors of standard deviation s per coordinate scores about ``2.9 s`` here
    (``sqrt(6) s`` per coordinate, three coordinates) whatever its accuracy; a smooth estimate
    scores near 0 even when it is offset.

    Args:
        estimate, truth: (frame, 18, 3) metres.
        joints: keypoint indices (the 13 body joints by default).

    Returns:
        mm/frame^2; NaN if no triple of consecutive frames is estimated.
    """
    est = np.asarray(estimate, np.float64)[:, joints]
    gt = np.asarray(truth, np.float64)[:, joints]
    if est.shape != gt.shape:
        raise ValueError(f"acceleration_error: estimate {est.shape} and truth {gt.shape} differ")
    if len(est) < 3:
        return float("nan")
    acc = (est[2:] - 2 * est[1:-1] + est[:-2]) - (gt[2:] - 2 * gt[1:-1] + gt[:-2])
    err = np.linalg.norm(acc, axis=-1) * 1000.0
    have = np.isfinite(err)
    return float(err[have].mean()) if have.any() else float("nan")


def jitter(estimate: np.ndarray, *, joints: tuple[int, ...] = BODY_JOINTS) -> float:
    """Mean frame-to-frame displacement of the joints, mm/frame (NaN frames skipped).

    Meant for a subject standing still (the truth moves ~0): what is left is the estimate's
    shake. On moving subjects use :func:`acceleration_error`, which subtracts the truth.
    """
    est = np.asarray(estimate, np.float64)[:, joints]
    if len(est) < 2:
        return float("nan")
    step = np.linalg.norm(est[1:] - est[:-1], axis=-1) * 1000.0
    have = np.isfinite(step)
    return float(step[have].mean()) if have.any() else float("nan")


def swapped_limbs(
    estimate: np.ndarray,
    truth: np.ndarray,
    *,
    margin_mm: float = 100.0,
    pairs: tuple[tuple[int, int], ...] = LIMB_PAIRS,
) -> np.ndarray:
    """Which left/right limb pairs the estimate has swapped, per frame.

    A pair (``pairs`` of COCO-18 (right, left) indices; by default :data:`LIMB_PAIRS`: elbows,
    wrists, knees, ankles) counts as swapped when the estimate, with its left and right
    keypoints exchanged, is closer to the truth by more than ``margin_mm`` (sum of the two
    keypoints' errors).

    Returns:
        (frame, len(pairs)) bool; False where the estimate is NaN.
    """
    est = np.asarray(estimate, np.float64)
    gt = np.asarray(truth, np.float64)
    if est.shape != gt.shape:
        raise ValueError(f"swapped_limbs: estimate {est.shape} and truth {gt.shape} differ")
    right = [a for a, _ in pairs]  # COCO-18 lists the right side first
    left = [b for _, b in pairs]
    straight = np.linalg.norm(est[:, left] - gt[:, left], axis=-1) + np.linalg.norm(
        est[:, right] - gt[:, right], axis=-1
    )
    crossed = np.linalg.norm(est[:, left] - gt[:, right], axis=-1) + np.linalg.norm(
        est[:, right] - gt[:, left], axis=-1
    )
    with np.errstate(invalid="ignore"):
        return (straight - crossed) * 1000.0 > margin_mm


def swapped_limb_frames(
    estimate: np.ndarray, truth: np.ndarray, *, margin_mm: float = 100.0
) -> int:
    """Frames in which at least one limb pair is swapped (see :func:`swapped_limbs`)."""
    return int(swapped_limbs(estimate, truth, margin_mm=margin_mm).any(axis=1).sum())


def motion_metrics(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """The motion columns of every benchmark table: ``accel_mm`` (:func:`acceleration_error`)
    and ``swap_frames`` (:func:`swapped_limb_frames`)."""
    return {
        "accel_mm": acceleration_error(estimate, truth),
        "swap_frames": swapped_limb_frames(estimate, truth),
    }


def gaussian_smoothed(keypoints3d: np.ndarray, sigma: float = 2.0) -> np.ndarray:
    """A post-hoc Gaussian filter over time (``sigma`` in frames): the floor a motion model
    must beat.

    Each keypoint coordinate is convolved with a Gaussian of ``sigma`` frames (truncated at
    4 sigma); NaN frames are left out of the average (normalised convolution) and stay NaN;
    near the ends the kernel is renormalised over the frames that exist.
    """
    x = np.asarray(keypoints3d, np.float64)
    if sigma <= 0:
        return x.copy()
    r = int(np.ceil(4 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    have = np.isfinite(x).all(axis=-1)  # (T, kpt)
    val = np.where(have[..., None], x, 0.0)
    T = len(x)
    num = np.zeros_like(val)
    den = np.zeros(have.shape)
    for i, w in enumerate(k):
        off = i - r
        lo, hi = max(0, -off), min(T, T - off)
        num[lo:hi] += w * val[lo + off : hi + off]
        den[lo:hi] += w * have[lo + off : hi + off]
    out = num / np.maximum(den, 1e-12)[..., None]
    return np.where(have[..., None], out, np.nan)
