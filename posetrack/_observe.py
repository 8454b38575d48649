"""Lifting 2D keypoints to 3D landmarks with the depth map (paper section 2.2).

For each detected 2D keypoint o_i the depth is read robustly around it (median of the valid
depths in a small window; zero, NaN and out-of-range depths ignored) and back-projected to the
3D landmark O_i. The paper's flags: f_i = keypoint detected (confidence above a threshold and
inside the image), F_i = f_i and valid depth was found.

``rule="nearest"`` reads the nearest surface of the window where the median read the
background: the median of the nearest cluster of depths (at least ``min_valid`` of them within
:data:`NEAREST_CLUSTER` of the nearest one) when the window's median lies more than
:data:`NEAREST_JUMP` behind it, the median elsewhere. A limb a few pixels wide (an arm at 3 m
in a 320x240 image) covers less than half of a 5x5 window when the keypoint is a pixel or two
off its axis, and the median is then the background, metres behind.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._body import BODY_JOINTS
from ._camera import Intrinsics, backproject

#: Metres: the depth span of the nearest cluster that ``lift_keypoints(rule="nearest")`` reads.
NEAREST_CLUSTER = 0.15
#: Metres: ``rule="nearest"`` reads the nearest cluster only where the window's median lies
#: this far behind it (the median read the background); elsewhere the median.
NEAREST_JUMP = 0.3
#: Depth reading rules of :func:`lift_keypoints`.
LIFT_RULES = ("median", "nearest")


class Landmarks(eqx.Module):
    """The observations of one frame that Eq. (1) compares the model with."""

    keypoints2d: Float[Array, "kpt 2"]
    """o_i: detected 2D keypoints, pixels (zeros where not detected)."""
    confidence: Float[Array, " kpt"]
    """Detector confidence in [0, 1] (0 where not detected)."""
    points3d: Float[Array, "kpt 3"]
    """O_i: lifted 3D landmarks, metres, camera frame. Where F_i is false: zeros, or a bound
    (:func:`as_bounds`): the lifted point of a keypoint whose pixels show a surface in front
    of the joint, which the fit keeps the joint behind (:func:`posetrack._residuals.
    landmark_residuals`)."""
    detected: Bool[Array, " kpt"]
    """f_i: the keypoint was detected (confidence above threshold, finite, inside the image)."""
    has_depth: Bool[Array, " kpt"]
    """F_i: detected and valid depth was found around it."""


def lift_keypoints(
    depth: Float[Array, "H W"],
    keypoints2d: Float[Array, "kpt 2"],
    confidence: Float[Array, " kpt"],
    intrinsics: Intrinsics,
    *,
    window: int = 5,
    confidence_threshold: float = 0.1,
    min_depth: float = 0.2,
    max_depth: Float[Array, ""] | float = 10.0,
    min_valid: int = 3,
    depth_offset: Float[Array, " kpt"] | float = 0.0,
    rule: str = "median",
) -> Landmarks:
    """Lift detected 2D keypoints to 3D with a depth map. Jittable; one frame.

    Args:
        depth: depth map in metres along the optical axis; 0, NaN and values outside
            [min_depth, max_depth] are invalid. Its size must match ``intrinsics``.
        keypoints2d: (kpt, 2) pixel coordinates (u, v); NaN or non-finite = not detected.
        confidence: (kpt,) detector confidences; <= ``confidence_threshold`` = not detected.
        intrinsics: the depth camera (depth registered to the keypoints' image).
        window: odd side length of the square window the depth median is taken over, pixels.
        confidence_threshold: f_i requires a confidence above this.
        min_depth, max_depth: valid depth range, metres (``max_depth`` may be traced: see
            :func:`body_depth_limit`).
        min_valid: F_i requires at least this many valid depths in the window.
        depth_offset: metres added along each keypoint's viewing ray after lifting. The depth
            sensor sees the body's surface, the model's keypoints are joint centres; pushing the
            lifted point back by the local body radius removes most of that bias. 0 = the
            paper's plain lifting.
        rule: "median": the median of the window's valid depths; "nearest": the median of
            its nearest cluster where the window's median lies more than NEAREST_JUMP behind
            it (module docstring).

    Returns:
        :class:`Landmarks` with f_i (``detected``) and F_i (``has_depth``).
    """
    if window % 2 != 1 or window < 1:
        raise ValueError(f"lift_keypoints: window must be a positive odd integer, got {window}")
    if rule not in LIFT_RULES:
        raise ValueError(f"lift_keypoints: rule must be one of {LIFT_RULES}, got {rule!r}")
    dtype = depth.dtype
    H, W = depth.shape
    half = window // 2
    uv = keypoints2d.astype(dtype)
    finite = jnp.all(jnp.isfinite(uv), axis=-1) & jnp.isfinite(confidence)
    # Pixel centres are at integer coordinates: (u, v) lies in the image if it rounds into it.
    inside = (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5)
    detected = finite & inside & (confidence > confidence_threshold)
    safe_uv = jnp.where(detected[:, None], uv, 0.0)
    col = jnp.clip(jnp.round(safe_uv[:, 0]).astype(jnp.int32), 0, W - 1)
    row = jnp.clip(jnp.round(safe_uv[:, 1]).astype(jnp.int32), 0, H - 1)

    padded = jnp.pad(depth, half, constant_values=0.0)

    def patch(r, c):
        return jax.lax.dynamic_slice(padded, (r, c), (window, window)).reshape(-1)

    patches = jax.vmap(patch)(row, col)  # (kpt, window*window); padding adds `half` offsets
    valid = jnp.isfinite(patches) & (patches >= min_depth) & (patches <= max_depth)
    n_valid = jnp.sum(valid, axis=-1)
    big = jnp.asarray(jnp.finfo(dtype).max, dtype)
    ordered = jnp.sort(jnp.where(valid, patches, big), axis=-1)

    def pick(start, i):  # the i-th of the sorted depths from ``start`` on
        return jnp.take_along_axis(ordered, (start + jnp.maximum(i, 0))[:, None], axis=-1)[:, 0]

    zero = jnp.zeros_like(n_valid)
    has_depth = detected & (n_valid >= min_valid)
    z = 0.5 * (pick(zero, (n_valid - 1) // 2) + pick(zero, n_valid // 2))
    if rule == "nearest":
        # In the sorted window, the cluster from k holds the depths in [d_k, d_k + span]:
        # n_k of them. The first k with n_k >= min_valid starts the nearest cluster; its
        # median replaces the window's where that lies more than NEAREST_JUMP behind it.
        span = jnp.asarray(NEAREST_CLUSTER, dtype)
        within = (ordered[:, None, :] >= ordered[:, :, None]) & (
            ordered[:, None, :] <= ordered[:, :, None] + span
        )  # (kpt, k, j)
        counts = jnp.sum(within, axis=-1)  # big entries (invalid) only count invalid ones
        ok = (counts >= min_valid) & (jnp.arange(ordered.shape[-1])[None, :] < n_valid[:, None])
        start = jnp.argmax(ok, axis=-1)
        n_near = jnp.take_along_axis(counts, start[:, None], axis=-1)[:, 0]
        z_near = 0.5 * (pick(start, (n_near - 1) // 2) + pick(start, n_near // 2))
        use = jnp.any(ok, axis=-1) & (z - z_near > jnp.asarray(NEAREST_JUMP, dtype))
        z = jnp.where(use, z_near, z)
    z = jnp.where(has_depth, z, 1.0)
    points = backproject(intrinsics, safe_uv, z)
    ray = points / jnp.linalg.norm(points, axis=-1, keepdims=True)
    offset = jnp.broadcast_to(jnp.asarray(depth_offset, dtype), has_depth.shape)
    points = points + offset[:, None] * ray
    points = jnp.where(has_depth[:, None], points, 0.0)
    conf = jnp.where(detected, confidence.astype(dtype), 0.0)
    return Landmarks(
        keypoints2d=jnp.where(detected[:, None], uv, 0.0),
        confidence=conf,
        points3d=points,
        detected=detected,
        has_depth=has_depth,
    )


def confident_depth(landmarks: Landmarks, ratio: Float[Array, "*kpt"] | float) -> Landmarks:
    """``landmarks`` with F_i cleared (and O_i zeroed) where the keypoint's confidence is below
    ``ratio`` times the median confidence of the frame's detected body keypoints (neck to
    ankles); the 2D detections stay (f_i). Jittable; ``ratio`` may be traced, and may be
    one per keypoint.

    A detector reports keypoints it infers behind an occluder at a lower confidence than the
    ones it sees, and the depth on such a keypoint's pixel belongs to the occluder. The median
    makes the rule follow the detector's own confidence scale. ``ratio = 0`` returns the
    landmarks unchanged; so does a frame with no body keypoint detected.
    """
    c = landmarks.confidence
    body = np.asarray(BODY_JOINTS)
    median = jnp.nanmedian(jnp.where(landmarks.detected[body], c[body], jnp.nan))
    median = jnp.where(jnp.isnan(median), 0.0, median)
    return without_depth(landmarks, ~(c >= ratio * median))


def without_depth(landmarks: Landmarks, drop: Bool[Array, " kpt"]) -> Landmarks:
    """``landmarks`` with F_i cleared (and O_i zeroed) where ``drop``: those keypoints are
    fitted by their 2D detections only (f_i stays). Jittable."""
    has_depth = landmarks.has_depth & ~drop
    return Landmarks(
        keypoints2d=landmarks.keypoints2d,
        confidence=landmarks.confidence,
        points3d=jnp.where(has_depth[:, None], landmarks.points3d, 0.0),
        detected=landmarks.detected,
        has_depth=has_depth,
    )


def as_bounds(landmarks: Landmarks, mask: Bool[Array, " kpt"]) -> Landmarks:
    """``landmarks`` with F_i cleared where ``mask``, but O_i kept as a bound: those keypoints
    are fitted by their 2D detections, and their lifted depth only keeps the joint from coming
    in front of it (a one-sided residual, :func:`posetrack._residuals.landmark_residuals`).
    Keypoints without depth are unchanged. Jittable.

    For a keypoint whose pixels show a surface in front of the joint (the far side's limbs
    and torso in a side view show the near side), the depth is a lower bound of the joint's,
    not its place: fitting it as a 3D landmark pulls the body toward the camera, dropping it
    (:func:`without_depth`) loses what it does say.
    """
    return eqx.tree_at(lambda lm: lm.has_depth, landmarks, landmarks.has_depth & ~mask)


def depth_bounds(landmarks: Landmarks) -> Bool[Array, " kpt"]:
    """Which keypoints carry a bound (:func:`as_bounds`): detected, F_i false, O_i set."""
    set_ = jnp.any(landmarks.points3d != 0, axis=-1)
    return landmarks.detected & ~landmarks.has_depth & set_


#: Torso keypoints (neck, shoulders, hips) whose lifted depths place the body for
#: :func:`body_depth_limit`.
TORSO_KEYPOINTS = (1, 2, 5, 8, 11)


def body_depth_limit(
    landmarks: Landmarks, band: Float[Array, ""] | float, max_depth: float = 10.0
) -> Float[Array, ""]:
    """The farthest depth a keypoint's window may read as body: the median lifted depth of
    the frame's torso landmarks (neck, shoulders, hips) plus ``band`` metres; ``max_depth``
    where ``band <= 0`` or no torso landmark has depth. Jittable; ``band`` may be traced.

    A keypoint on a thin limb (a wrist or elbow a few pixels wide at 320x240 and 3 m) whose
    detection lies a pixel or more off the limb reads the background behind the person in
    its window, typically 1-2 m behind the joint. Lifting a second time with this limit as
    ``max_depth`` leaves such a keypoint without depth (fitted in 2D) or with the limb pixels
    its window does hold, instead of a landmark metres behind the body. A hand held behind
    the back lies well within half a metre of the torso's depth.
    """
    z = landmarks.points3d[np.asarray(TORSO_KEYPOINTS), 2]
    ok = landmarks.has_depth[np.asarray(TORSO_KEYPOINTS)]
    median = jnp.nanmedian(jnp.where(ok, z, jnp.nan))
    use = (jnp.asarray(band) > 0) & jnp.any(ok)
    return jnp.where(use, jnp.minimum(jnp.where(use, median, 0.0) + band, max_depth), max_depth)


#: The confidence above which :func:`observed_share` counts a keypoint detected.
OBSERVED_CONFIDENCE = 0.3


def observed_share(depths, keypoints2d, confidence, frames: int) -> float:
    """The share of the first ``frames`` frames' keypoints that the camera observed: detected
    (confidence above :data:`OBSERVED_CONFIDENCE`, finite) on a pixel whose depth is > 0 (the
    keypoint rounded to a pixel, clipped into the image); with several people's detections
    (``(people, kpt, 2)`` a frame) the best-observed person's. NumPy, on the host; the gate of the
    offline shape pre-pass (``ShapeFitSettings.offline_first_below``): over 40 frames the
    tuning and report clips read 0.55-0.89 clean, 0.26-0.71 occluded (benchmarks/README.md,
    "A pre-pass for occluded starts").

    Args:
        depths: a sequence of (H, W) depth maps (any unit; 0 or NaN: no depth).
        keypoints2d: a sequence of (kpt, 2) or (people, kpt, 2) pixel coordinates (u, v).
        confidence: a sequence of (kpt,) or (people, kpt) detector confidences.
        frames: how many of the first frames to read (at least 1; at most the recording's).
    """
    n = min(int(frames), len(depths))
    if n < 1:
        raise ValueError(f"observed_share: frames must be >= 1 of a non-empty recording, got {n}")
    seen = total = 0
    for t in range(n):
        dep = np.asarray(depths[t])
        kp = np.asarray(keypoints2d[t], dtype=np.float64)
        conf = np.asarray(confidence[t], dtype=np.float64)
        H, W = dep.shape
        kp, conf = kp.reshape(-1, *kp.shape[-2:]), conf.reshape(-1, conf.shape[-1])
        ok = (conf > OBSERVED_CONFIDENCE) & np.isfinite(kp).all(axis=-1)
        kp = np.where(ok[..., None], kp, 0.0)
        x = np.clip(np.round(kp[..., 0]).astype(np.int64), 0, W - 1)
        y = np.clip(np.round(kp[..., 1]).astype(np.int64), 0, H - 1)
        per_person = (ok & (dep[y, x] > 0)).sum(axis=-1)  # NaN > 0 is False: no depth
        seen += int(per_person.max(initial=0))
        total += conf.shape[-1]
    return seen / total
