"""One call to load and cross-check a whole RGB-D recording."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .._camera import Intrinsics
from ._depth import DepthSequence, check_depth_scale, probe_depth_png
from ._errors import InputError
from ._frames import (
    IMAGE_EXTENSIONS,
    KEYPOINTS_SUFFIX,
    format_ranges,
    list_frames,
    pair_frames,
)
from ._intrinsics import read_intrinsics_with_layout
from ._openpose import AMBIGUOUS_RATIO, read_openpose_json
from ._rgb import VIDEO_EXTENSIONS, RgbFrames, RgbVideo

logger = logging.getLogger("posetrack.io")


@dataclass(frozen=True, eq=False)
class Recording:
    """A validated recording: T frames paired by frame number.

    A plain frozen dataclass rather than an ``eqx.Module``: it lives on the host, holds lazy
    file readers, and never enters a jitted function (its arrays do, one frame at a time).
    Arrays are read-only.
    """

    frame_ids: np.ndarray
    """``int64 (T,)`` frame numbers (from the file names), increasing."""
    depth: DepthSequence
    """Lazy ``float32 (H, W)`` metres per frame, 0 = no measurement (all 0 for an absent
    file); read on indexing, never cached."""
    keypoints2d: np.ndarray
    """``float32 (T, 18, 2)`` COCO-18 pixels (u, v) of one person per frame, 0 where missing:
    the ``person_id`` given, else each frame's most prominent person (highest score). With
    several people in view this per-frame choice hops between them: to follow one person
    give :attr:`people2d` to the tracker."""
    confidence: np.ndarray
    """``float32 (T, 18)``; 0 = missing (all 0 in frames without observation)."""
    people2d: np.ndarray
    """``float32 (T, P, 18, 2)`` every person listed in each frame (file order, padded with
    zeros to the most people in any frame; P >= 1); with ``person_id`` only that person."""
    people_confidence: np.ndarray
    """``float32 (T, P, 18)``; 0 = missing or padding."""
    intrinsics: Intrinsics
    """Depth-camera intrinsics; their width x height is the depth image size."""
    rgb: RgbFrames | RgbVideo | None
    """Lazy ``uint8 (H, W, 3)`` RGB per frame, or None without colour input."""
    observed: np.ndarray
    """``bool (T,)``: the frame has a depth image and (with keypoints) a chosen person with
    at least one keypoint. Other frames are frames without observation."""
    num_people: np.ndarray
    """``int64 (T,)`` people listed in each keypoint file (0 without keypoints)."""
    person_index: np.ndarray
    """``int64 (T,)`` index into ``people`` of the chosen person, -1 if none."""
    keypoint_layout: str | None
    """``"COCO-18"`` or ``"BODY_25"`` as found in the files (None without keypoints)."""
    fps: float | None
    """Frames per second if known (from a colour video), else None."""
    notes: tuple[str, ...]
    """One-line remarks for the user (layouts detected, person choices, frames without
    observation, dropped keypoints, ignored distortion); the CLI prints each as
    ``note: ...`` on stderr before tracking."""

    def __len__(self) -> int:
        return len(self.frame_ids)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


#: A recording needs at least this many confident keypoints before their spread is judged.
_MIN_KEYPOINTS_FOR_SCALE_CHECK = 30


def _check_keypoint_resolution(folder: Path, everyone, width: int, height: int) -> None:
    """Refuse keypoints that all lie in the top-left quadrant of the depth image.

    OpenPose run on colour images half the size of depth (a common set-up with Kinect v2's
    1920x1080 colour and a downscaled copy) gives coordinates half as large: every keypoint
    lands in the top-left quadrant, the lifted depth belongs to whatever is there, and the
    tracker would report "0 tracked" with no hint why.
    """
    xyc = np.concatenate([e.reshape(-1, 3) for e in everyone if len(e)] or [np.zeros((0, 3))])
    seen = xyc[xyc[:, 2] > 0]
    if len(seen) < _MIN_KEYPOINTS_FOR_SCALE_CHECK:
        return
    u, v = float(seen[:, 0].max()), float(seen[:, 1].max())
    if u < width / 2 and v < height / 2:
        raise InputError(
            folder, "keypoints", f"largest x = {u:.0f}, largest y = {v:.0f}",
            f"all {len(seen)} keypoints lie in the top-left quadrant of the {width}x{height} "
            f"depth image (largest x {u:.0f}, largest y {v:.0f}), as if detected on an image "
            "half the size (OpenPose on downscaled colour?); rescale them with "
            "--keypoints-scale 2 (keypoints_scale=2), or pass --keypoints-scale 1 to use them "
            "as they are",
        )  # fmt: skip


def load_recording(
    *,
    depth_dir: str | os.PathLike[str],
    keypoints_dir: str | os.PathLike[str] | None = None,
    intrinsics_path: str | os.PathLike[str],
    rgb: str | os.PathLike[str] | None = None,
    depth_scale: float = 1000.0,
    person_id: int | None = None,
    allow_missing: bool = False,
    keypoint_margin: float = 16.0,
    out_of_image: Literal["error", "drop"] = "error",
    keypoints_scale: float | None = None,
) -> Recording:
    """Load, validate and pair a recording; depth and colour stay on disk until indexed.

    Every depth PNG is checked up front without decoding it (header, size, truncation), and
    every keypoint file is parsed and validated, so bad input fails here, before tracking.

    Args:
        depth_dir: folder of 16-bit depth PNGs (``000012.png``, ``frame_12.png``, ...).
        keypoints_dir: folder of OpenPose ``<stem>_keypoints.json`` files, or None.
        intrinsics_path: intrinsics JSON of the depth camera (Open3D, plain or ROS layout).
        rgb: folder of colour images, a video file, or None. Registered to depth.
        depth_scale: depth units per metre (1000 = millimetres; 5000 for TUM RGB-D).
        person_id: OpenPose ``person_id`` to follow; None = the best-scoring person per frame.
        allow_missing: frames present in one folder but not another become frames without
            observation instead of an error.
        keypoint_margin: pixels outside the image a keypoint may lie and be kept.
        out_of_image: ``"error"`` or ``"drop"`` for keypoints farther outside.
        keypoints_scale: scale keypoint pixels by this, pixel centre to pixel centre
            (:func:`read_openpose_json`'s ``scale``), for keypoints detected on an image of
            another size than depth, e.g. 2 for OpenPose run on half-size colour. ``None``
            (default): 1, but a recording whose keypoints all lie in the top-left quadrant of
            the depth image is refused (that is what half-size keypoints look like; pass 1 to
            use them as they are).

    Returns:
        A :class:`Recording`.

    Raises:
        InputError: any bad file (see the readers), no frames, unpaired frames (without
            ``allow_missing``), duplicate frame numbers, a depth image whose size differs from
            the intrinsics, keypoint files mixing layouts, a ``person_id`` found in no file,
            colour of another size than depth, a video with another frame count, keypoints
            that look detected on a smaller image (``keypoints_scale=None``).
    """
    scale = check_depth_scale(depth_scale)
    kp_scale = 1.0 if keypoints_scale is None else float(keypoints_scale)
    if not (np.isfinite(kp_scale) and kp_scale > 0):
        raise ValueError(f"keypoints_scale must be positive, got {keypoints_scale!r}")
    intrinsics_path = Path(intrinsics_path)
    intrinsics, intrinsics_layout, notes = read_intrinsics_with_layout(intrinsics_path)
    width, height = intrinsics.width, intrinsics.height
    notes.insert(0, f"intrinsics: {intrinsics_layout} layout, {width}x{height}")

    depth_files = list_frames(depth_dir, extensions=(".png",), what="depth")
    sources = {"depth": (Path(depth_dir), depth_files)}
    if keypoints_dir is not None:
        sources["keypoints"] = (
            Path(keypoints_dir),
            list_frames(
                keypoints_dir,
                extensions=(".json",),
                what="keypoints",
                prefer_suffix=KEYPOINTS_SUFFIX + ".json",
                notes=notes,
            ),  # fmt: skip
        )
    video = None
    if rgb is not None:
        rgb = Path(rgb)
        if rgb.suffix.lower() in VIDEO_EXTENSIONS and not rgb.is_dir():
            video = rgb
        else:
            sources["rgb"] = (rgb, list_frames(rgb, extensions=IMAGE_EXTENSIONS, what="RGB"))
    frame_ids, paired, pair_notes = pair_frames(sources, allow_missing=allow_missing)
    notes += pair_notes
    n = len(frame_ids)

    for path in paired["depth"]:
        if path is None:
            continue
        h, w = probe_depth_png(path)
        if (h, w) != (height, width):
            raise InputError(
                path,
                "size",
                (w, h),
                f"depth image is {w}x{h} but {intrinsics_path} says {width}x{height} "
                "(width x height); intrinsics must belong to the depth images",
            )
    has_depth = np.array([p is not None for p in paired["depth"]])
    depth = DepthSequence(
        paired["depth"],
        frame_ids=frame_ids,
        shape=(height, width),
        scale=scale,
        size_source=f"{intrinsics_path}",
    )

    keypoints2d = np.zeros((n, 18, 2), np.float32)
    confidence = np.zeros((n, 18), np.float32)
    everyone: list[np.ndarray] = [np.zeros((0, 18, 3), np.float32)] * n
    num_people = np.zeros(n, np.int64)
    person_index = np.full(n, -1, np.int64)
    layout: str | None = None
    if keypoints_dir is not None:
        layout_source: Path | None = None
        multi, ambiguous, dropped, id_missing = [], [], [], []
        kp_observed = np.zeros(n, bool)
        for t, path in enumerate(paired["keypoints"]):
            if path is None:
                continue
            frame = read_openpose_json(
                path,
                person_id=person_id,
                image_size=(width, height),
                margin=keypoint_margin,
                out_of_image=out_of_image,
                scale=kp_scale,
            )
            if frame.layout is not None:
                if layout is None:
                    layout, layout_source = frame.layout, path
                elif frame.layout != layout:
                    raise InputError(
                        path, "people[*].pose_keypoints_2d", frame.layout,
                        f"layout {frame.layout} differs from {layout} in {layout_source}; "
                        "one recording, one keypoint layout",
                    )  # fmt: skip
            keypoints2d[t], confidence[t] = frame.keypoints2d, frame.confidence
            if person_id is None:
                everyone[t] = frame.people
            elif frame.person_index >= 0:
                chosen = np.concatenate([frame.keypoints2d, frame.confidence[:, None]], axis=1)
                everyone[t] = chosen[None]
            num_people[t], person_index[t] = frame.num_people, frame.person_index
            kp_observed[t] = frame.observed
            fid = int(frame_ids[t])
            if frame.num_people > 1 and person_id is None:
                multi.append(fid)
                if frame.ambiguous:
                    ambiguous.append(fid)
            if frame.dropped:
                dropped.append(fid)
            if person_id is not None and frame.person_index < 0 and frame.num_people > 0:
                id_missing.append(fid)
            for note in frame.notes:
                logger.debug(note)
        if keypoints_scale is None:
            _check_keypoint_resolution(sources["keypoints"][0], everyone, width, height)
        elif kp_scale != 1.0:
            notes.append(
                f"keypoints: pixel coordinates multiplied by {kp_scale:g} (pixel centre to "
                "pixel centre)"
            )
        if person_id is not None and not (person_index >= 0).any():
            raise InputError(
                sources["keypoints"][0],
                "person_id",
                person_id,
                "no keypoint file lists a person with this person_id",
            )
        notes.append(
            f"keypoints: {layout or 'no people in any file'}"
            + (" mapped to COCO-18" if layout == "BODY_25" else "")
        )
        if multi:
            notes.append(
                f"keypoints: several people in {len(multi)} frame(s) ({format_ranges(multi)}); "
                "the tracker follows one person from the start (see --person)"
                + (
                    f"; close calls (runner-up >= {AMBIGUOUS_RATIO:.0%} of the most prominent) "
                    f"in {format_ranges(ambiguous)}"
                    if ambiguous
                    else ""
                )
            )
        if id_missing:
            notes.append(
                f"keypoints: person_id {person_id} absent in {len(id_missing)} frame(s) "
                f"({format_ranges(id_missing)}): frames without observation"
            )
        if dropped:
            notes.append(
                f"keypoints: keypoints more than {keypoint_margin:g} px outside the image "
                f"marked missing in {len(dropped)} frame(s) ({format_ranges(dropped)})"
            )
        listed = np.array([p is not None for p in paired["keypoints"]])
        nobody = frame_ids[listed & ~kp_observed & (person_index < 0) & (num_people == 0)]
        if nobody.size:
            notes.append(
                f"keypoints: nobody detected in {nobody.size} frame(s) "
                f"({format_ranges(nobody.tolist())}): frames without observation"
            )
        observed = has_depth & kp_observed
    else:
        observed = has_depth

    P = max(1, max(len(e) for e in everyone))
    people = np.zeros((n, P, 18, 3), np.float32)
    for t, e in enumerate(everyone):
        people[t, : len(e)] = e

    rgb_seq: RgbFrames | RgbVideo | None = None
    fps = None
    if video is not None:
        rgb_seq = RgbVideo(video, frame_ids=frame_ids, shape=(height, width))
        if rgb_seq.frame_count > 0 and rgb_seq.frame_count != n:
            raise InputError(
                video,
                "frame count",
                rgb_seq.frame_count,
                f"video has {rgb_seq.frame_count} frames but the recording has {n} "
                f"(frames {format_ranges(frame_ids.tolist())}); video frame k pairs with the "
                "k-th recording frame, so the counts must match (or extract the video to a "
                "folder of numbered images)",
            )
        rgb_seq[0]  # decode one frame: checks the codec and the size now, not mid-run
        fps = rgb_seq.fps
    elif rgb is not None:
        rgb_seq = RgbFrames(paired["rgb"], frame_ids=frame_ids, shape=(height, width))
        first = next(t for t, p in enumerate(paired["rgb"]) if p is not None)
        rgb_seq[first]  # decode one image: checks it and its size now, not mid-run

    for note in notes:
        logger.info(note)
    return Recording(
        frame_ids=_readonly(frame_ids),
        depth=depth,
        keypoints2d=_readonly(keypoints2d),
        confidence=_readonly(confidence),
        people2d=_readonly(np.ascontiguousarray(people[..., :2])),
        people_confidence=_readonly(np.ascontiguousarray(people[..., 2])),
        intrinsics=intrinsics,
        rgb=rgb_seq,
        observed=_readonly(observed),
        num_people=_readonly(num_people),
        person_index=_readonly(person_index),
        keypoint_layout=layout,
        fps=fps,
        notes=tuple(notes),
    )
