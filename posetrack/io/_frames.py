"""Frame numbering, folder listing and pairing of per-frame files across folders.

Frame-number rule: the frame number of a file is the LAST run of decimal digits in its name
after removing the extension and an OpenPose ``_keypoints`` suffix::

    depth/000012.png          -> 12
    rgb/frame_12.jpg          -> 12
    000012_keypoints.json     -> 12
    000012_rendered.png       -> 12
    cam2_000012.png           -> 12   (the last run wins, so a camera number before it is fine)
    000012_v2.png             -> 2    (!) a trailing version number is taken as the frame number

Hidden files (names starting with ``.``) are ignored: they are editor/OS droppings or the
temporary files of an interrupted atomic write.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ._errors import InputError

_DIGITS = re.compile(r"\d+")
KEYPOINTS_SUFFIX = "_keypoints"
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def frame_number(name: str | os.PathLike[str]) -> int | None:
    """Frame number of a file name (see the module docstring for the rule), or None."""
    stem = Path(name).name
    if "." in stem:
        stem = stem[: stem.rindex(".")]
    if stem.endswith(KEYPOINTS_SUFFIX):
        stem = stem[: -len(KEYPOINTS_SUFFIX)]
    runs = _DIGITS.findall(stem)
    return int(runs[-1]) if runs else None


def format_ranges(ids: Iterable[int], *, max_ranges: int = 12) -> str:
    """Compact list of frame numbers: ``[3, 4, 5, 9, 12]`` -> ``"3-5, 9, 12"``.

    More than ``max_ranges`` ranges are cut with a count, so a message stays one line.
    """
    ids = sorted(set(int(i) for i in ids))
    ranges: list[tuple[int, int]] = []
    for i in ids:
        if ranges and i == ranges[-1][1] + 1:
            ranges[-1] = (ranges[-1][0], i)
        else:
            ranges.append((i, i))
    parts = [f"{a}" if a == b else f"{a}-{b}" for a, b in ranges]
    if len(parts) > max_ranges:
        shown = ", ".join(parts[:max_ranges])
        return f"{shown}, ... ({len(ids)} frames in {len(parts)} ranges)"
    return ", ".join(parts)


def list_frames(
    folder: str | os.PathLike[str],
    *,
    extensions: Sequence[str],
    what: str,
    prefer_suffix: str | None = None,
    notes: list[str] | None = None,
) -> dict[int, Path]:
    """Map frame number -> file for the files of ``folder`` with one of ``extensions``.

    Args:
        folder: the folder to list (not recursive).
        extensions: lower-case extensions with the dot, e.g. ``(".png",)``; matched
            case-insensitively.
        what: what the files are ("depth", "keypoints", "RGB"), for messages.
        prefer_suffix: if some matching files end with this (e.g. ``"_keypoints.json"``,
            case-insensitively), the others are ignored: OpenPose's own files win over a
            ``params.json`` or ``camera.json`` left beside them.
        notes: a list to append a one-line remark to when files are ignored.

    Returns:
        ``{frame_number: path}`` sorted by frame number.

    Raises:
        InputError: the folder is missing or not a folder; holds no matching file; a matching
            file has no digits in its name; two files map to the same frame number.
    """
    folder = Path(folder)
    if not folder.exists():
        raise InputError(folder, "folder", str(folder), f"{what} folder does not exist")
    if not folder.is_dir():
        raise InputError(folder, "folder", str(folder), f"expected a folder of {what} files")
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    except OSError as e:
        raise InputError(folder, "folder", str(folder), f"cannot be listed ({e.strerror})") from e
    files = [p for p in entries if p.suffix.lower() in extensions and p.is_file()]
    if not files:
        others = [p.name for p in entries]
        shown = ", ".join(others[:5]) + (", ..." if len(others) > 5 else "")
        held = f"it holds {len(others)} other entries ({shown})" if others else "it is empty"
        raise InputError(
            folder,
            "frames",
            0,
            f"no {what} frames: no file ending in {' / '.join(extensions)}; {held}",
        )
    if prefer_suffix is not None:
        suffix = prefer_suffix.lower()
        preferred = [p for p in files if p.name.lower().endswith(suffix)]
        if preferred and len(preferred) < len(files):
            ignored = sorted(p.name for p in files if not p.name.lower().endswith(suffix))
            shown = ", ".join(ignored[:3]) + (", ..." if len(ignored) > 3 else "")
            if notes is not None:
                notes.append(f"{what}: ignored {len(ignored)} file(s) in {folder} not ending in "
                             f"{prefer_suffix} ({shown})")  # fmt: skip
            files = preferred
    frames: dict[int, Path] = {}
    for p in files:
        number = frame_number(p.name)
        if number is None:
            raise InputError(
                p,
                "name",
                p.name,
                f"{what} file name has no frame number (the last run of digits in a file "
                "name is its frame number); rename or remove it",
            )
        if number in frames:
            raise InputError(
                folder,
                "frames",
                number,
                f"frame {number} appears twice: {frames[number].name} and {p.name}",
            )
        frames[number] = p
    return dict(sorted(frames.items()))


def pair_frames(
    sources: Mapping[str, tuple[Path, Mapping[int, Path]]], *, allow_missing: bool
) -> tuple[np.ndarray, dict[str, list[Path | None]], list[str]]:
    """Pair per-frame files of several folders by frame number.

    Args:
        sources: ``{what: (folder, {frame_number: path})}``, e.g. depth and keypoints.
        allow_missing: if False, a frame present in one folder and absent in another is an
            error; if True the recording covers the union of frame numbers and absent files are
            ``None`` (the caller treats such frames as frames without observation).

    Returns:
        ``(frame_ids (T,) int64 sorted, {what: [path or None] * T}, notes)``.

    Raises:
        InputError: frames are missing and ``allow_missing`` is False; the message lists the
            missing frame numbers of each folder as compact ranges.
    """
    union = sorted(set().union(*(set(m) for _f, m in sources.values())))
    missing = {what: sorted(set(union) - set(m)) for what, (_f, m) in sources.items()}
    lacking = {what: ids for what, ids in missing.items() if ids}
    notes: list[str] = []
    if lacking:
        parts = [
            f"{what} ({sources[what][0]}) lacks {len(ids)} frame(s): {format_ranges(ids)}"
            for what, ids in lacking.items()
        ]
        if not allow_missing:
            first = next(iter(lacking))
            raise InputError(
                sources[first][0],
                "frames",
                lacking[first],
                "frames do not pair up: "
                + "; ".join(parts)
                + ". Pass allow_missing=True (CLI: --allow-missing) to treat them as frames "
                "without observation.",
            )
        notes.append("allow_missing: frames without observation because " + "; ".join(parts))
    paired = {what: [m.get(i) for i in union] for what, (_f, m) in sources.items()}
    return np.asarray(union, dtype=np.int64), paired, notes
