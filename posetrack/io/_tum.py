"""TUM RGB-D benchmark sequences: the lists, time-stamp association and the known cameras.

A sequence folder (``rgbd_dataset_freiburg1_xyz``) holds ``rgb/`` and ``depth/`` PNGs and the
lists ``rgb.txt`` and ``depth.txt``: one ``timestamp filename`` per line (seconds since the
Unix epoch; the file relative to the folder), ``#`` starts a comment line. Depth PNGs hold
16-bit depth x 5000 (5000 = 1 m, 0 = no measurement) and are registered to colour (pixel for
pixel), both 640x480.

Colour and depth are not synchronised. Each colour image is paired with a depth image as the
benchmark's ``associate.py`` describes it: the closest time stamps first, each image used at
most once, and only pairs less than ``max_difference`` (0.02 s) apart.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._camera import Intrinsics
from ._errors import InputError, format_value
from ._frames import KEYPOINTS_SUFFIX, format_ranges
from ._json import read_text

#: Depth units per metre of the benchmark's depth PNGs.
TUM_DEPTH_SCALE = 5000.0
#: Default largest time difference (s) between a colour image and its depth image.
TUM_MAX_DIFFERENCE = 0.02
#: ``fx, fy, cx, cy`` (pixels) of the freiburg1/2/3 colour cameras, as the benchmark publishes
#: them (640x480; with distortion for freiburg1 and 2, not applied here). For reference: the
#: default is :data:`TUM_REGISTERED_DEPTH`.
TUM_CAMERAS = {
    1: (517.3, 516.5, 318.6, 255.3),
    2: (520.9, 521.0, 325.1, 249.7),
    3: (535.4, 539.2, 320.1, 247.6),
}
#: ``fx, fy, cx, cy`` the benchmark recommends for its depth images, which the Kinect's driver
#: registered to colour with these (ROS default) parameters: undistorting registered depth with
#: the colour calibration is "not trivial", so the benchmark's own tools use these for every
#: sequence, and so does :func:`load_tum` by default.
TUM_REGISTERED_DEPTH = (525.0, 525.0, 319.5, 239.5)
TUM_IMAGE_SIZE = (640, 480)
_FREIBURG = re.compile(r"freiburg([123])")


def is_tum_folder(folder: str | os.PathLike[str]) -> bool:
    """Whether ``folder`` holds ``rgb.txt`` and ``depth.txt`` (a TUM RGB-D sequence)."""
    folder = Path(folder)
    return (folder / "rgb.txt").is_file() and (folder / "depth.txt").is_file()


def read_tum_list(path: str | os.PathLike[str]) -> tuple[np.ndarray, list[Path]]:
    """Read a TUM ``rgb.txt`` or ``depth.txt``.

    Args:
        path: the list; every line is ``timestamp filename`` (seconds; the file relative to the
            list's folder), or blank, or a ``#`` comment.

    Returns:
        ``(timestamps float64 (N,) seconds, files)`` in time order; every file exists.

    Raises:
        InputError: unreadable or non-UTF-8 list; a line without exactly two fields, with a
            time stamp that is not a finite number, or naming a file that does not exist (the
            field is ``line <n>``); a time stamp listed twice; no entry.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "file", str(path), "does not exist")
    text = read_text(path, "TUM", "image list")
    stamps: list[float] = []
    files: list[Path] = []
    lines: dict[float, int] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        entry = line.strip()
        if not entry or entry.startswith("#"):
            continue
        fields = entry.split()
        where = f"line {number}"
        if len(fields) != 2:
            raise InputError(
                path, where, entry,
                f"is {format_value(entry)}; expected 'timestamp filename' (2 fields, not "
                f"{len(fields)})",
            )  # fmt: skip
        try:
            stamp = float(fields[0])
        except ValueError:
            stamp = math.nan
        if not math.isfinite(stamp):
            raise InputError(
                path, where, fields[0],
                f"time stamp {format_value(fields[0])} is not a number of seconds",
            )  # fmt: skip
        if stamp in lines:
            raise InputError(
                path, where, fields[0], f"time stamp {fields[0]} is also on line {lines[stamp]}"
            )
        file = Path(fields[1])
        file = file if file.is_absolute() else path.parent / file
        if not file.is_file():
            raise InputError(path, where, fields[1], f"names {file}, which does not exist")
        lines[stamp] = number
        stamps.append(stamp)
        files.append(file)
    if not stamps:
        raise InputError(path, "lines", 0, "lists no images ('timestamp filename' lines)")
    order = np.argsort(np.asarray(stamps), kind="stable")
    return np.asarray(stamps, np.float64)[order], [files[i] for i in order]


def associate_timestamps(
    first: np.ndarray, second: np.ndarray, *, max_difference: float = TUM_MAX_DIFFERENCE
) -> np.ndarray:
    """Pair time stamps one-to-one, closest first (TUM ``associate.py``'s rule).

    Args:
        first: ``(N,)`` seconds, e.g. the colour images'.
        second: ``(M,)`` seconds, e.g. the depth images'.
        max_difference: pairs must be less than this many seconds apart.

    Returns:
        ``int64 (N,)``: the index into ``second`` paired with each of ``first``, -1 if none.
        Candidate pairs are taken in order of increasing difference; a pair is kept when
        neither stamp is paired yet.
    """
    max_difference = float(max_difference)
    if not (math.isfinite(max_difference) and max_difference > 0):
        raise ValueError(f"max_difference must be a positive number of seconds: {max_difference}")
    a = np.asarray(first, np.float64).reshape(-1)
    b = np.asarray(second, np.float64).reshape(-1)
    order = np.argsort(b, kind="stable")
    sorted_b = b[order]
    # Only the stamps within the window can pair: a sweep, not all N x M differences
    # (TUM sequences have thousands of images per list).
    lo = np.searchsorted(sorted_b, a - max_difference, side="left")
    hi = np.searchsorted(sorted_b, a + max_difference, side="right")
    candidates = []
    for i in range(len(a)):
        for k in range(lo[i], hi[i]):
            difference = abs(a[i] - sorted_b[k])
            if difference < max_difference:
                candidates.append((difference, i, int(order[k])))
    candidates.sort()
    match = np.full(len(a), -1, np.int64)
    used = np.zeros(len(b), bool)
    for _difference, i, j in candidates:
        if match[i] < 0 and not used[j]:
            match[i], used[j] = j, True
    return match


@dataclass(frozen=True)
class TumSequence:
    """A TUM RGB-D sequence's images: one frame per colour image, in time order."""

    folder: Path
    timestamps: np.ndarray
    """``float64 (T,)`` seconds: the colour images' time stamps."""
    rgb: list[Path]
    """The colour image of each frame."""
    depth: list[Path | None]
    """The associated depth image of each frame, None where none is close enough."""
    depth_timestamps: np.ndarray
    """``float64 (T,)`` seconds of the associated depth images, NaN where none."""
    unused_depth: int
    """Depth images paired with no colour image."""


def read_tum_sequence(
    folder: str | os.PathLike[str], *, max_difference: float = TUM_MAX_DIFFERENCE
) -> TumSequence:
    """Read ``rgb.txt`` and ``depth.txt`` of a TUM sequence and pair depth to colour.

    Raises:
        InputError: the folder or a list is missing; a bad list line (see
            :func:`read_tum_list`).
    """
    folder = Path(folder)
    if not folder.is_dir():
        what = "does not exist" if not folder.exists() else "is not a folder"
        raise InputError(folder, "folder", str(folder), f"TUM RGB-D sequence folder {what}")
    for name in ("rgb.txt", "depth.txt"):
        if not (folder / name).is_file():
            raise InputError(
                folder, name, None,
                f"no {name}: a TUM RGB-D sequence folder holds rgb.txt, depth.txt, rgb/ and "
                "depth/",
            )  # fmt: skip
    rgb_stamps, rgb = read_tum_list(folder / "rgb.txt")
    depth_stamps, depth = read_tum_list(folder / "depth.txt")
    match = associate_timestamps(rgb_stamps, depth_stamps, max_difference=max_difference)
    paired = match >= 0
    return TumSequence(
        folder=folder,
        timestamps=rgb_stamps,
        rgb=rgb,
        depth=[depth[j] if j >= 0 else None for j in match],
        depth_timestamps=np.where(paired, depth_stamps[np.maximum(match, 0)], np.nan),
        unused_depth=len(depth) - int(paired.sum()),
    )


def tum_intrinsics(folder: str | os.PathLike[str]) -> tuple[Intrinsics, str] | None:
    """The benchmark's intrinsics for the registered depth (:data:`TUM_REGISTERED_DEPTH`,
    640x480) when the folder's name names a freiburg1/2/3 camera, with a note; None if it
    names none (``rgbd_dataset_freiburg1_xyz`` -> freiburg1)."""
    name = Path(folder).resolve().name
    found = _FREIBURG.search(name)
    if found is None:
        return None
    camera = int(found.group(1))
    fx, fy, cx, cy = TUM_REGISTERED_DEPTH
    w, h = TUM_IMAGE_SIZE
    note = (
        f"intrinsics: TUM freiburg{camera} (from the folder name {name}): the benchmark's "
        f"parameters for its registered depth (fx {fx}, fy {fy}, cx {cx}, cy {cy}, {w}x{h}); "
        f"give intrinsics to use others, e.g. the colour calibration {TUM_CAMERAS[camera]}"
    )
    return Intrinsics.create(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h), note


def pair_tum_keypoints(
    keypoints_dir: str | os.PathLike[str],
    rgb: list[Path],
    *,
    rgb_list: Path,
    allow_missing: bool,
    notes: list[str],
) -> list[Path | None]:
    """The OpenPose file of each colour image: ``<rgb stem>_keypoints.json`` (or
    ``<rgb stem>.json``), None where absent (only with ``allow_missing``).

    Args:
        keypoints_dir: the folder of OpenPose JSON.
        rgb: the colour images (``read_tum_list(rgb_list)``).
        rgb_list: ``rgb.txt``, for messages.
        allow_missing: absent or stray keypoint files are noted, not refused.
        notes: where the notes go.

    Raises:
        InputError: the folder is missing or holds no JSON; without ``allow_missing``: a
            colour image without keypoints, or keypoints for no listed colour image.
    """
    folder = Path(keypoints_dir)
    if not folder.is_dir():
        what = "does not exist" if not folder.exists() else "is not a folder"
        raise InputError(folder, "folder", str(folder), f"keypoints folder {what}")
    files = sorted(
        p for p in folder.iterdir()
        if p.suffix.lower() == ".json" and not p.name.startswith(".") and p.is_file()
    )  # fmt: skip
    if not files:
        raise InputError(folder, "frames", 0, "no keypoints frames: no file ending in .json")
    suffix = KEYPOINTS_SUFFIX + ".json"
    preferred = [p for p in files if p.name.lower().endswith(suffix)]
    if preferred:
        files = preferred
    by_stem = {
        p.name[: -len(suffix)] if p.name.lower().endswith(suffix) else p.stem: p for p in files
    }
    stems = [p.stem for p in rgb]
    paired = [by_stem.get(s) for s in stems]
    listed = set(stems)
    strays = sorted(p.name for s, p in by_stem.items() if s not in listed)
    missing = [t for t, p in enumerate(paired) if p is None]
    hint = (
        "Pass allow_missing=True (CLI: --allow-missing) to treat them as frames without "
        "observation"
    )
    if strays:
        shown = ", ".join(strays[:3]) + (", ..." if len(strays) > 3 else "")
        if not allow_missing:
            raise InputError(
                folder, "frames", strays,
                f"{len(strays)} keypoint file(s) match no image of {rgb_list} ({shown}); "
                f"keypoint files are named after the colour images (<rgb stem>{suffix}). "
                "Pass allow_missing=True (CLI: --allow-missing) to ignore them.",
            )  # fmt: skip
        notes.append(
            f"keypoints: ignored {len(strays)} file(s) matching no image of {rgb_list} ({shown})"
        )
    if missing:
        what = (
            f"no keypoint file for {len(missing)} of the {len(rgb)} colour images of {rgb_list} "
            f"(frames {format_ranges(missing)}, e.g. {stems[missing[0]]}{suffix})"
        )
        if not allow_missing:
            raise InputError(folder, "frames", missing, f"{what}. {hint}.")
        notes.append(f"allow_missing: frames without observation because of {what}")
    return paired
