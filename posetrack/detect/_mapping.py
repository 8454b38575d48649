"""BlazePose's 33 landmarks -> OpenPose COCO-18 keypoints, in image pixels (NumPy, no MediaPipe).

Kept apart from the MediaPipe wrapper so the mapping, the pixel convention and the crop
arithmetic can be used and tested without the optional dependency.
"""

from __future__ import annotations

import numpy as np

NUM_BLAZEPOSE = 33
"""Landmarks of MediaPipe BlazePose (full-body topology)."""

NECK = -1
"""Marker in :data:`BLAZEPOSE_TO_COCO18`: COCO's neck has no BlazePose landmark; it is the
midpoint of the shoulders (BlazePose 11 and 12)."""

#: The BlazePose landmark of each COCO-18 keypoint (``posetrack.KEYPOINT_NAMES`` order);
#: ``NECK`` (-1) = midpoint of BlazePose 11 (left shoulder) and 12 (right shoulder).
#: Eyes are BlazePose's eye centres (2, 5), not the inner/outer corners.
BLAZEPOSE_TO_COCO18 = (0, NECK, 12, 14, 16, 11, 13, 15, 24, 26, 28, 23, 25, 27, 5, 2, 8, 7)

_LEFT_SHOULDER, _RIGHT_SHOULDER = 11, 12


def check_crop(crop, image_shape: tuple[int, ...], where: str) -> tuple[int, int, int, int]:
    """Validate a ``(top, bottom, left, right)`` pixel box against an (H, W, ...) image.

    ``crop=None`` means the whole image. Bounds are half-open (NumPy slicing:
    ``image[top:bottom, left:right]``).

    Raises:
        ValueError: naming ``where`` and the offending value when the box is not four integers,
            is empty, or does not lie inside the image.
    """
    H, W = int(image_shape[0]), int(image_shape[1])
    if crop is None:
        return 0, H, 0, W
    try:
        values = [v for v in crop]
    except TypeError:
        values = None
    if values is None or len(values) != 4:
        raise ValueError(f"{where}: crop must be (top, bottom, left, right), got {crop!r}")
    box = []
    for name, v in zip(("top", "bottom", "left", "right"), values):
        try:
            integral = not isinstance(v, (bool, str)) and float(v).is_integer()
        except (TypeError, ValueError):
            integral = False
        if not integral:
            raise ValueError(f"{where}: crop {name} must be an integer pixel index, got {v!r}")
        box.append(int(v))
    top, bottom, left, right = box
    if not (0 <= top < bottom <= H and 0 <= left < right <= W):
        raise ValueError(
            f"{where}: crop (top={top}, bottom={bottom}, left={left}, right={right}) must satisfy "
            f"0 <= top < bottom <= {H} and 0 <= left < right <= {W} (the image is {W}x{H})"
        )
    return top, bottom, left, right


def blazepose_to_coco18(
    landmarks: np.ndarray,
    region: tuple[int, int, int, int],
    *,
    min_confidence: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Map one person's 33 BlazePose landmarks to COCO-18 keypoints in full-image pixels.

    Pixel convention (posetrack's, see ``posetrack._camera``): (0, 0) is the centre of the top-left
    pixel. MediaPipe's normalised coordinates span the image edges (0 = left edge of the first
    pixel, 1 = right edge of the last), so ``u = left + x * (right - left) - 0.5``.

    A keypoint is reported missing (pixels (0, 0), confidence 0, OpenPose's convention) when its
    landmark is not finite, its confidence is below ``min_confidence``, or it lies outside
    ``region``: the detector only saw the region, so a landmark beyond it is an extrapolation
    (MediaPipe predicts landmarks past the image border for a person cut by it). The neck is the
    midpoint of the shoulders with the smaller of their two confidences, so it is missing when
    either shoulder is.

    Args:
        landmarks: (33, 3) ``[x, y, confidence]`` per BlazePose landmark: x, y normalised to the
            region the detector saw, confidence in [0, 1] (MediaPipe's ``visibility``).
        region: ``(top, bottom, left, right)`` full-image pixel box (half-open) that the
            detector was run on: the crop, or ``(0, H, 0, W)`` for the whole image.
        min_confidence: landmarks below this confidence are reported missing.

    Returns:
        ``(keypoints2d, confidence)``: (18, 2) float32 pixels (u, v) in the full image and
        (18,) float32 in [0, 1], COCO-18 order (``posetrack.KEYPOINT_NAMES``).

    Raises:
        ValueError: ``landmarks`` is not (33, 3).
    """
    lm = np.asarray(landmarks, dtype=np.float64)
    if lm.shape != (NUM_BLAZEPOSE, 3):
        raise ValueError(
            f"blazepose_to_coco18: landmarks must have shape (33, 3) [x, y, confidence], got "
            f"{lm.shape}"
        )
    top, bottom, left, right = (int(v) for v in region)
    u = left + lm[:, 0] * (right - left) - 0.5
    v = top + lm[:, 1] * (bottom - top) - 0.5
    c = np.clip(lm[:, 2], 0.0, 1.0)
    # Same inside test as posetrack.lift_keypoints: the point rounds to a pixel of the region.
    inside = (u > left - 0.5) & (u < right - 0.5) & (v > top - 0.5) & (v < bottom - 0.5)
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(lm[:, 2]) & inside
    ok &= c >= min_confidence
    uv = np.stack([u, v], axis=-1)
    conf = np.where(ok, c, 0.0)

    kp = np.zeros((len(BLAZEPOSE_TO_COCO18), 2))
    cf = np.zeros(len(BLAZEPOSE_TO_COCO18))
    for i, j in enumerate(BLAZEPOSE_TO_COCO18):
        if j == NECK:
            a, b = _LEFT_SHOULDER, _RIGHT_SHOULDER
            if ok[a] and ok[b]:
                kp[i] = 0.5 * (uv[a] + uv[b])
                cf[i] = min(conf[a], conf[b])
        elif ok[j]:
            kp[i] = uv[j]
            cf[i] = conf[j]
    return kp.astype(np.float32), cf.astype(np.float32)
