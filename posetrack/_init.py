"""Initialisation from observations alone: body dimensions and the first pose.

Everything here runs once per track (or after a track loss), on the host, in NumPy: it is not
on the per-frame hot path.

* :func:`estimate_shape` measures the segment lengths between lifted 3D landmarks over the first
  frames (robust medians, left and right pooled) and scales the default body to them. The paper
  fixes the body model and names shape estimation as future work; real users differ in size,
  and a wrong bone length is a bias no pose optimiser can remove.
* :func:`initial_pose` builds a pose from the landmark directions (root orientation from the
  hips, shoulders and spine; each limb rotated onto its observed direction), which the caller
  then refines with Levenberg-Marquardt on all landmarks.
"""

from __future__ import annotations

import numpy as np

from ._body import BodyShape
from ._so3 import matrix_to_quat, quat_between, quat_to_matrix

# (field, [(keypoint a, keypoint b), ...], divisor): segment lengths measured between landmarks.
_SEGMENTS = (
    ("upper_arm", [(2, 3), (5, 6)], 1.0),
    ("forearm", [(3, 4), (6, 7)], 1.0),
    ("thigh", [(8, 9), (11, 12)], 1.0),
    ("shin", [(9, 10), (12, 13)], 1.0),
    ("shoulder_width", [(2, 5)], 2.0),
    ("hip_width", [(8, 11)], 2.0),
)

#: Accepted range of each estimated dimension, as a multiple of the default adult's.
SHAPE_RANGE = (0.6, 1.5)


def estimate_shape(
    points3d: np.ndarray,
    has_depth: np.ndarray,
    *,
    base: BodyShape | None = None,
    min_samples: int = 3,
) -> tuple[BodyShape, dict[str, float]]:
    """Estimate body dimensions from lifted landmarks of several frames.

    Args:
        points3d: (frame, kpt, 3) lifted landmarks O_i, metres (see ``lift_keypoints``; use the
            surface-to-centre ``depth_offset`` so lengths are between joint centres).
        has_depth: (frame, kpt) the F_i flags.
        base: the shape whose unmeasured fields are kept (default adult if None).
        min_samples: a length needs at least this many measurements, else the default is kept
            (scaled by the overall size factor).

    Returns:
        (shape, report): the estimated shape, and per-field measured ratios to ``base``
        (NaN where not measured). Radii and head scale follow the median ratio of the measured
        lengths, clamped to ``SHAPE_RANGE``.
    """
    base = base or BodyShape.default()
    P = np.asarray(points3d, dtype=np.float64)
    F = np.asarray(has_depth, dtype=bool)
    if P.ndim != 3 or P.shape[1:] != (18, 3) or F.shape != P.shape[:2]:
        raise ValueError(
            f"estimate_shape: points3d must be (frame, 18, 3) and has_depth (frame, 18); got "
            f"{P.shape} and {F.shape}"
        )
    values = base.to_dict()
    ratios: dict[str, float] = {}
    for field, pairs, divisor in _SEGMENTS:
        lengths = []
        for a, b in pairs:
            ok = F[:, a] & F[:, b]
            lengths.append(np.linalg.norm(P[ok, a] - P[ok, b], axis=-1) / divisor)
        lengths = np.concatenate(lengths)
        ref = values[field]
        lengths = lengths[(lengths > SHAPE_RANGE[0] * ref) & (lengths < SHAPE_RANGE[1] * ref)]
        ratios[field] = float(np.median(lengths) / ref) if len(lengths) >= min_samples else np.nan
    # Torso: neck keypoint to the hips' midpoint.
    ok = F[:, 1] & F[:, 8] & F[:, 11]
    torso = np.linalg.norm(P[ok, 1] - 0.5 * (P[ok, 8] + P[ok, 11]), axis=-1)
    ref = values["torso"]
    torso = torso[(torso > SHAPE_RANGE[0] * ref) & (torso < SHAPE_RANGE[1] * ref)]
    ratios["torso"] = float(np.median(torso) / ref) if len(torso) >= min_samples else np.nan

    measured = np.array([r for r in ratios.values() if np.isfinite(r)])
    size = float(np.clip(np.median(measured), *SHAPE_RANGE)) if len(measured) else 1.0
    for field, ratio in ratios.items():
        r = ratio if np.isfinite(ratio) else size
        values[field] = values[field] * float(np.clip(r, *SHAPE_RANGE))
    for field in (
        "head_scale", "torso_radius", "upper_arm_radius", "forearm_radius", "thigh_radius",
        "shin_radius", "shoulder_drop",
    ):  # fmt: skip
        values[field] = values[field] * size
    ratios["size"] = size
    return BodyShape.create(**values), ratios


def _unit(v: np.ndarray) -> np.ndarray | None:
    n = np.linalg.norm(v)
    return v / n if n > 1e-6 else None


def initial_pose(
    points3d: np.ndarray,
    has_depth: np.ndarray,
    shape: BodyShape,
    *,
    allow_partial: bool = False,
    axes: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray | None:
    """A first pose from one frame's lifted landmarks, or None if the torso is not seen.

    The root sits at the hips' midpoint (or below the neck along the spine); its orientation
    comes from the body's left-right axis (shoulders and/or hips) and its up axis (hips to
    neck). Each limb is rotated from its rest direction onto the observed bone direction where
    both ends have depth; other joints stay at rest. Quaternions wxyz.

    Args:
        points3d: (18, 3) landmarks, metres, camera frame.
        has_depth: (18,) F_i flags.
        shape: body dimensions.

        allow_partial: without a left-right pair (shoulders or hips) or a torso point, start
            from a person facing the camera placed by whatever landmarks are seen (at least 3)
            instead of giving up; for heavily occluded starts.
        axes: the body's left and up axes (unit, camera frame) known from elsewhere (a track
            lost a moment ago): without a left-right pair the body is oriented by them (the up
            axis only where the hips and neck give none) and placed as with ``allow_partial``
            (at least 3 landmarks with depth), instead of giving up or facing the camera.

    Returns:
        (43,) float64 parameters, or None when neither hips nor shoulders give an axis (and
        ``allow_partial`` is off, or fewer than 3 landmarks have depth).
    """
    P = np.asarray(points3d, dtype=np.float64)
    F = np.asarray(has_depth, dtype=bool)

    def mid(a, b):
        return 0.5 * (P[a] + P[b]) if F[a] and F[b] else None

    hips, shoulders = mid(8, 11), mid(2, 5)
    neck = P[1] if F[1] else shoulders
    lefts = []
    if F[5] and F[2]:
        lefts.append(P[5] - P[2])
    if F[11] and F[8]:
        lefts.append(P[11] - P[8])
    units = [u for u in (_unit(v) for v in lefts) if u is not None]
    left = _unit(np.sum(units, axis=0)) if units else None
    if left is None and axes is not None and F.sum() >= 3:
        left = _unit(np.asarray(axes[0], np.float64))
        allow_partial = True
    if left is None:
        if not allow_partial or F.sum() < 3:
            return None
        # No left-right pair seen (heavy occlusion): assume the person faces the camera, whose
        # +x is then the subject's left; LM on the landmarks that are seen corrects the rest.
        left = np.array([1.0, 0.0, 0.0])
    if hips is not None and neck is not None:
        up = neck - hips
    elif axes is not None:
        up = np.asarray(axes[1], np.float64)
    else:
        up = np.array([0.0, -1.0, 0.0])  # camera y is down: assume an upright person
    up = up - np.dot(up, left) * left
    up = _unit(up)
    if up is None:
        return None
    forward = np.cross(left, up)
    R0 = np.stack([left, up, forward], axis=1)  # columns: body x, y, z in the camera frame
    torso = float(shape.torso)
    hw, sw = float(shape.hip_width), float(shape.shoulder_width)
    if hips is not None:
        root = hips
    elif neck is not None:
        root = neck - torso * up
    elif not allow_partial:
        return None
    elif F[8] or F[11]:  # one hip: step half the hip width toward the middle
        root = P[8] + hw * left if F[8] else P[11] - hw * left
    elif F[2] or F[5]:  # one shoulder
        root = (P[2] + sw * left if F[2] else P[5] - sw * left) - torso * up
    else:  # only limbs or the head: their centroid, a rough start for LM
        root = P[F].mean(axis=0)
    q_root = matrix_to_quat(R0)

    joints = np.tile([1.0, 0.0, 0.0, 0.0], (9, 1))
    down = np.array([0.0, -1.0, 0.0])
    # (joint index among the 9, parent keypoint, child keypoint, grandchild keypoint)
    limbs = ((1, 2, 3, 4), (3, 5, 6, 7), (5, 8, 9, 10), (7, 11, 12, 13))
    for j, a, b, c in limbs:
        if not (F[a] and F[b]):
            continue
        d_upper = R0.T @ (P[b] - P[a])  # in the root frame
        q_upper = quat_between(down, d_upper)
        joints[j] = q_upper
        if F[c]:
            R_upper = quat_to_matrix(q_upper)
            d_lower = R_upper.T @ R0.T @ (P[c] - P[b])
            joints[j + 1] = quat_between(down, d_lower)
    return np.concatenate([root, q_root, joints.reshape(-1)])


def pose_moved_onto(
    params: np.ndarray, model_keypoints: np.ndarray, points3d: np.ndarray, has_depth: np.ndarray
) -> np.ndarray | None:
    """``params`` (43,) with its root moved by the mean offset from its ``model_keypoints``
    (18, 3) to the landmarks ``points3d`` (18, 3) that have depth; None without any. A restart
    from a known pose where the landmarks alone cannot orient the body (no left/right pair)."""
    F = np.asarray(has_depth, dtype=bool)
    if not F.any():
        return None
    P, K = np.asarray(points3d, np.float64), np.asarray(model_keypoints, np.float64)
    out = np.array(params, dtype=np.float64)
    out[:3] += np.mean(P[F] - K[F], axis=0)
    return out
