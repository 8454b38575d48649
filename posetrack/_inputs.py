"""The tracker's public boundary: one frame's depth and detections validated and converted,
with errors that name the frame, the field and the offending shape or dtype."""

from __future__ import annotations

import numpy as np

from ._camera import Intrinsics


def check_frame(
    intrinsics: Intrinsics, depth, keypoints2d, confidence, depth_scale: float, where: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate one frame at the public boundary and convert it.

    Args:
        intrinsics: the depth camera (its image size is checked against ``depth``).
        depth: (H, W) uint16 in sensor units, or float metres (0 / NaN invalid).
        keypoints2d: (18, 2) COCO-18 pixels; confidence: (18,), 0 = missing.
        depth_scale: sensor units per metre (uint16 depth only).
        where: what to call the frame in error messages.

    Returns:
        ``(depth_m, keypoints2d, confidence)`` as float32 NumPy arrays; non-finite keypoints
        become missing (confidence 0).

    Raises:
        ValueError: naming ``where``, the field and the offending shape or dtype.
    """
    depth_m = check_depth(intrinsics, depth, depth_scale, where)
    kp = np.asarray(keypoints2d, dtype=np.float64) if keypoints2d is not None else None
    if kp is None or kp.shape != (18, 2):
        raise ValueError(
            f"{where}: keypoints2d must have shape (18, 2) (COCO-18 pixels), got "
            f"{None if kp is None else kp.shape}"
        )
    conf = np.asarray(confidence, dtype=np.float64) if confidence is not None else None
    if conf is None or conf.shape != (18,):
        raise ValueError(
            f"{where}: confidence must have shape (18,), got {None if conf is None else conf.shape}"
        )
    kp, conf = check_people(kp, conf, where)
    return depth_m, kp[0], conf[0]


def check_people(keypoints2d, confidence, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Validate one frame's detections: one person ``(18, 2)`` / ``(18,)`` or P people
    ``(P, 18, 2)`` / ``(P, 18)`` (P may be 0). Returns ``(P, 18, 2)``, ``(P, 18)`` float32;
    non-finite keypoints become missing.

    Raises:
        ValueError: naming ``where``, the field and the offending shape.
    """
    kp = np.asarray(keypoints2d, dtype=np.float64) if keypoints2d is not None else None
    conf = np.asarray(confidence, dtype=np.float64) if confidence is not None else None
    if kp is None or kp.ndim not in (2, 3) or kp.shape[-2:] != (18, 2):
        raise ValueError(
            f"{where}: keypoints2d must have shape (18, 2) for one person or (P, 18, 2) for P "
            f"people (COCO-18 pixels), got {None if kp is None else kp.shape}"
        )
    if conf is None or conf.shape != kp.shape[:-1]:
        raise ValueError(
            f"{where}: confidence must have shape {kp.shape[:-1]} to match keypoints2d "
            f"{kp.shape}, got {None if conf is None else conf.shape}"
        )
    kp, conf = kp.reshape(-1, 18, 2), conf.reshape(-1, 18)
    bad = ~np.isfinite(kp).all(axis=-1) | ~np.isfinite(conf)
    conf = np.where(bad, 0.0, conf)  # non-finite keypoints are missing, never NaN poses
    kp = np.where(bad[..., None], 0.0, kp)
    return kp.astype(np.float32), conf.astype(np.float32)


def check_depth(intrinsics: Intrinsics, depth, depth_scale: float, where: str) -> np.ndarray:
    """Validate one depth image and convert it to float32 metres (see :func:`check_frame`)."""
    depth = np.asarray(depth)
    if depth.size == 0:
        raise ValueError(f"{where}: depth is empty (shape {depth.shape})")
    if depth.ndim != 2:
        raise ValueError(f"{where}: depth must be a 2D (H, W) array, got shape {depth.shape}")
    if depth.shape != intrinsics.shape:
        raise ValueError(
            f"{where}: depth shape {depth.shape} does not match the intrinsics' image "
            f"{intrinsics.height}x{intrinsics.width} (H x W)"
        )
    if depth.dtype == np.uint16:
        return depth.astype(np.float32) / np.float32(depth_scale)
    if np.issubdtype(depth.dtype, np.floating):
        return depth.astype(np.float32)
    raise ValueError(
        f"{where}: depth dtype must be uint16 (sensor units, see depth_scale) or float "
        f"(metres), got {depth.dtype}"
    )
