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
from ._intrinsics import read_intrinsics_file
from ._openpose import AMBIGUOUS_RATIO, read_openpose_json
from ._rgb import VIDEO_EXTENSIONS, RgbFrames, RgbVideo
from ._tum import (
    TUM_DEPTH_SCALE,
    TUM_MAX_DIFFERENCE,
    is_tum_folder,
    pair_tum_keypoints,
    read_tum_sequence,
    tum_intrinsics,
)

logger = logging.getLogger("posetrack.io")


@dataclass(frozen=True, eq=False)
class Recording:
    """A validated recording: T frames paired by frame number (or, from a TUM RGB-D
    sequence, by time stamp: :func:`load_tum`).

    A plain frozen dataclass rather than an ``eqx.Module``: it lives on the host, holds lazy
    file readers, and never enters a jitted function (its arrays do, one frame at a time).
    Arrays are read-only.
    """

    frame_ids: np.ndarray
    """``int64 (T,)`` frame numbers (from the file names), increasing. From a TUM sequence:
    0, 1, 2, ... the colour images in time order (their time stamps: :attr:`timestamps`)."""
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
    """Frames per second if known (from a colour video, or a TUM sequence's time stamps),
    else None."""
    notes: tuple[str, ...]
    """One-line remarks for the user (layouts detected, person choices, frames without
    observation, dropped keypoints, ignored distortion); the CLI prints each as
    ``note: ...`` on stderr before tracking."""
    timestamps: np.ndarray | None = None
    """``float64 (T,)`` seconds of each frame where the input has time stamps (a TUM
    sequence: the colour image's, seconds since the Unix epoch), else None."""

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
        intrinsics_path: intrinsics file of the depth camera (:func:`read_intrinsics`: JSON
            or OpenCV YAML/XML; ``intri.yml#NAME`` chooses a camera). A file without an image
            size (EasyMocap's ``intri.yml``) takes the first depth image's.
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
            the intrinsics (or from the first depth image's, where the intrinsics file gives
            no size), a TUM RGB-D folder (use :func:`load_tum`), keypoint files mixing
            layouts, a ``person_id`` found in no file, colour of another size than depth, a
            video with another frame count, keypoints that look detected on a smaller image
            (``keypoints_scale=None``).
    """
    scale = check_depth_scale(depth_scale)
    kp_scale = _keypoints_scale(keypoints_scale)
    _refuse_tum_folder(Path(depth_dir))
    depth_files = list_frames(depth_dir, extensions=(".png",), what="depth")
    notes: list[str] = []
    intrinsics, size = _depth_intrinsics(intrinsics_path, next(iter(depth_files.values())), notes)
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
    return _assemble(
        frame_ids, paired, video=video, intrinsics=intrinsics, size=size, scale=scale,
        keypoints_dir=None if keypoints_dir is None else Path(keypoints_dir),
        person_id=person_id, keypoint_margin=keypoint_margin, out_of_image=out_of_image,
        keypoints_scale=keypoints_scale, kp_scale=kp_scale, notes=notes,
    )  # fmt: skip


def load_tum(
    folder: str | os.PathLike[str],
    *,
    keypoints_dir: str | os.PathLike[str] | None = None,
    intrinsics_path: str | os.PathLike[str] | None = None,
    depth_scale: float = TUM_DEPTH_SCALE,
    max_difference: float = TUM_MAX_DIFFERENCE,
    person_id: int | None = None,
    allow_missing: bool = False,
    keypoint_margin: float = 16.0,
    out_of_image: Literal["error", "drop"] = "error",
    keypoints_scale: float | None = None,
) -> Recording:
    """Load a TUM RGB-D benchmark sequence: one frame per colour image of ``rgb.txt``.

    Each colour image is paired with the depth image of ``depth.txt`` closest in time, one to
    one, less than ``max_difference`` seconds apart (the rule of the benchmark's
    ``associate.py``). A colour image without such a depth image is a frame without
    observation (noted, not an error: the two streams are not synchronised). The recording's
    colour (:attr:`Recording.rgb`) is the sequence's ``rgb/``, registered to depth.

    Frame ids are 0, 1, 2, ... the colour images in time order; :attr:`Recording.timestamps`
    holds their time stamps and :attr:`Recording.fps` comes from their median spacing.

    Args:
        folder: the sequence folder (``rgb.txt``, ``depth.txt``, ``rgb/``, ``depth/``).
        keypoints_dir: folder of OpenPose JSON detected on the colour images, named after them
            (``<rgb stem>_keypoints.json``, e.g. ``1305031102.175304_keypoints.json``), or None.
        intrinsics_path: intrinsics file as for :func:`load_recording`; None: the freiburg1/2/3
            camera named in the folder's name (``rgbd_dataset_freiburg1_xyz``), with a note.
        depth_scale: depth units per metre (the benchmark's 5000).
        max_difference: seconds a colour image and its depth image may be apart (less than).
        person_id, allow_missing, keypoint_margin, out_of_image, keypoints_scale: as for
            :func:`load_recording`; ``allow_missing`` covers colour images without a keypoint
            file and keypoint files matching no colour image.

    Returns:
        A :class:`Recording`.

    Raises:
        InputError: a missing folder or list, a bad list line (naming the list and the line),
            no intrinsics and a folder name that names no freiburg camera, unpaired keypoint
            files (without ``allow_missing``), and the errors of :func:`load_recording`.
    """
    scale = check_depth_scale(depth_scale)
    kp_scale = _keypoints_scale(keypoints_scale)
    folder = Path(folder)
    seq = read_tum_sequence(folder, max_difference=max_difference)
    notes: list[str] = []
    first_depth = next((p for p in seq.depth if p is not None), None)
    if first_depth is None:
        raise InputError(
            folder, "depth.txt", None,
            f"no depth image lies within {max_difference:g} s of any colour image of rgb.txt "
            f"({len(seq.rgb)} images from t = {seq.timestamps[0]:.6f} s); check the lists",
        )  # fmt: skip
    if intrinsics_path is not None:
        intrinsics, size = _depth_intrinsics(intrinsics_path, first_depth, notes)
    else:
        known = tum_intrinsics(folder)
        if known is None:
            raise InputError(
                folder, "intrinsics", folder.resolve().name,
                f"no intrinsics given and the folder name {folder.resolve().name!r} names no "
                "TUM camera (freiburg1, freiburg2 or freiburg3); give the intrinsics file "
                "(CLI: --intrinsics FILE)",
            )  # fmt: skip
        intrinsics, note = known
        notes.append(note)
        size = (
            f"the TUM camera of {folder.resolve().name}", "is",
            "the benchmark's images are 640x480; give the intrinsics of these images",
        )  # fmt: skip
    n = len(seq.rgb)
    frame_ids = np.arange(n, dtype=np.int64)
    paired: dict[str, list[Path | None]] = {"depth": list(seq.depth), "rgb": list(seq.rgb)}
    if keypoints_dir is not None:
        paired["keypoints"] = pair_tum_keypoints(
            keypoints_dir, seq.rgb, rgb_list=folder / "rgb.txt", allow_missing=allow_missing,
            notes=notes,
        )  # fmt: skip
    no_depth = [t for t, p in enumerate(seq.depth) if p is None]
    spacing = float(np.median(np.diff(seq.timestamps))) if n > 1 else 0.0
    fps = 1.0 / spacing if spacing > 0 else None
    notes.append(
        f"TUM: {n} colour images of {folder / 'rgb.txt'}"
        + (f" at {fps:.2f} fps (median spacing of their time stamps)" if fps else "")
        + f", each paired with the closest depth image less than {max_difference:g} s away"
        + (
            f"; none close enough for {len(no_depth)} ({format_ranges(no_depth)}): frames "
            "without observation"
            if no_depth
            else ""
        )
        + (f"; {seq.unused_depth} depth image(s) unused" if seq.unused_depth else "")
    )
    return _assemble(
        frame_ids, paired, video=None, intrinsics=intrinsics, size=size, scale=scale,
        keypoints_dir=None if keypoints_dir is None else Path(keypoints_dir),
        person_id=person_id, keypoint_margin=keypoint_margin, out_of_image=out_of_image,
        keypoints_scale=keypoints_scale, kp_scale=kp_scale, notes=notes,
        timestamps=seq.timestamps, fps=fps,
    )  # fmt: skip


def _keypoints_scale(keypoints_scale: float | None) -> float:
    kp_scale = 1.0 if keypoints_scale is None else float(keypoints_scale)
    if not (np.isfinite(kp_scale) and kp_scale > 0):
        raise ValueError(f"keypoints_scale must be positive, got {keypoints_scale!r}")
    return kp_scale


def _refuse_tum_folder(depth_dir: Path) -> None:
    """A TUM sequence (or its ``depth/``) given as a depth folder: its files are named by time
    stamp (``1305031102.160407.png``), whose last run of digits is no frame number."""
    for folder in (depth_dir, depth_dir.parent) if depth_dir.name == "depth" else (depth_dir,):
        if is_tum_folder(folder):
            what = "is" if folder == depth_dir else "is the depth/ folder of"
            raise InputError(
                depth_dir, "folder", str(depth_dir),
                f"{what} a TUM RGB-D sequence ({folder} holds rgb.txt and depth.txt; its "
                f"images are named by time stamp): load it with load_tum({str(folder)!r}) "
                f"(CLI: --tum {folder} instead of --depth)",
            )  # fmt: skip


def _depth_intrinsics(
    intrinsics_path: str | os.PathLike[str], first_depth: Path, notes: list[str]
) -> tuple[Intrinsics, tuple[str, str, str]]:
    """Read the intrinsics file; one without an image size takes the first depth image's.

    Returns:
        ``(intrinsics, (what gives the size, a verb, why depth must match))`` for size errors;
        the layout note goes first in ``notes``, the file's own notes after it.
    """
    h, w = probe_depth_png(first_depth)
    read = read_intrinsics_file(intrinsics_path, image_size=(w, h))
    k = read.intrinsics
    if read.size_in_file:
        notes.insert(0, f"intrinsics: {read.layout} layout, {k.width}x{k.height}")
        size = (str(intrinsics_path), "says", "intrinsics must belong to the depth images")
    else:
        notes.insert(
            0,
            f"intrinsics: {read.layout} layout, {k.width}x{k.height} from the depth images "
            f"({first_depth.name}; {intrinsics_path} gives no image size)",
        )
        size = (
            f"the first depth image {first_depth}", "is",
            f"every depth image must have the same size ({intrinsics_path} gives none)",
        )  # fmt: skip
    notes[1:1] = read.notes
    return k, size


def _assemble(
    frame_ids: np.ndarray,
    paired: dict[str, list[Path | None]],
    *,
    video: Path | None,
    intrinsics: Intrinsics,
    size: tuple[str, str, str],
    scale: float,
    keypoints_dir: Path | None,
    person_id: int | None,
    keypoint_margin: float,
    out_of_image: Literal["error", "drop"],
    keypoints_scale: float | None,
    kp_scale: float,
    notes: list[str],
    timestamps: np.ndarray | None = None,
    fps: float | None = None,
) -> Recording:
    """Check every depth image, read every keypoint file, open the colour: the recording of
    paired files (``paired``: ``{"depth"|"keypoints"|"rgb": [path or None] * T}``).
    ``size``: what gave the image size, a verb and why depth must match it (for errors)."""
    n = len(frame_ids)
    width, height = intrinsics.width, intrinsics.height
    size_source, size_verb, size_why = size

    for path in paired["depth"]:
        if path is None:
            continue
        h, w = probe_depth_png(path)
        if (h, w) != (height, width):
            raise InputError(
                path,
                "size",
                (w, h),
                f"depth image is {w}x{h} but {size_source} {size_verb} {width}x{height} "
                f"(width x height); {size_why}",
            )
    has_depth = np.array([p is not None for p in paired["depth"]])
    depth = DepthSequence(
        paired["depth"],
        frame_ids=frame_ids,
        shape=(height, width),
        scale=scale,
        size_source=size_source,
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
            _check_keypoint_resolution(keypoints_dir, everyone, width, height)
        elif kp_scale != 1.0:
            notes.append(
                f"keypoints: pixel coordinates multiplied by {kp_scale:g} (pixel centre to "
                "pixel centre)"
            )
        if person_id is not None and not (person_index >= 0).any():
            raise InputError(
                keypoints_dir,
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
    elif "rgb" in paired:
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
        timestamps=None if timestamps is None else _readonly(np.asarray(timestamps, np.float64)),
    )
