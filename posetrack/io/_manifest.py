"""The manifest of ``posetrack track-many``: one recording per CSV row, checked before tracking.

Format: CSV with a header row. Columns ``name,depth,keypoints,intrinsics`` are required;
``rgb`` and ``depth_scale`` are optional (empty cell: none / 1000). Relative paths are relative
to the manifest's folder. ``name`` becomes the output folder ``DIR/<name>/``: letters, digits,
``.``, ``_`` and ``-``, not starting with ``.``, unique in the manifest.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import re
from pathlib import Path

from .._camera import Intrinsics
from ._depth import probe_depth_png
from ._errors import InputError
from ._frames import list_frames
from ._intrinsics import CAMERA_SEPARATOR, read_intrinsics

REQUIRED = ("name", "depth", "keypoints", "intrinsics")
OPTIONAL = ("rgb", "depth_scale")
_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]*")


@dataclasses.dataclass(frozen=True)
class ManifestRow:
    """One recording of a manifest, paths resolved and checked."""

    line: int
    """Line number in the manifest file (the header is line 1)."""
    name: str
    depth: Path
    keypoints: Path
    intrinsics_path: Path
    """The intrinsics file; ``FILE#NAME`` where the row chooses a camera (``intri.yml#01``)."""
    intrinsics: Intrinsics
    rgb: Path | None
    depth_scale: float
    frames: int
    """Depth images in the folder (the recording's length before pairing)."""


def read_manifest(path: str | os.PathLike[str]) -> list[ManifestRow]:
    """Read and check a manifest: every row's folders and files exist, its intrinsics parse
    (``FILE#NAME`` chooses a camera; a file without an image size takes the first depth
    image's), its depth folder holds depth images. The frames themselves are checked when the
    row is loaded (:func:`posetrack.io.load_recording`).

    Raises:
        InputError: ``"<manifest>: row <line> (<name>): <column>: <problem>"`` for the first
            bad row, or naming the header for a missing or unknown column.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(path, "file", None, "no such manifest file") from None
    except UnicodeDecodeError as e:
        raise InputError(path, "file", None, f"not UTF-8 text ({e.reason})") from None
    reader = csv.reader(text.splitlines())
    header = [h.strip() for h in next(reader, [])]
    if not header or header == [""]:
        raise InputError(path, "header", None, f"empty; expected columns {','.join(REQUIRED)}")
    for col in REQUIRED:
        if col not in header:
            raise InputError(
                path, "header", header, f"no column {col!r}; expected {','.join(REQUIRED)} "
                f"(optional: {','.join(OPTIONAL)})",
            )  # fmt: skip
    unknown = [h for h in header if h not in REQUIRED + OPTIONAL]
    if unknown or len(set(header)) != len(header):
        bad = unknown[0] if unknown else next(h for h in header if header.count(h) > 1)
        raise InputError(
            path, "header", bad, f"unknown or repeated column {bad!r}; allowed: "
            f"{','.join(REQUIRED + OPTIONAL)}",
        )  # fmt: skip
    base = path.parent
    rows: list[ManifestRow] = []
    seen: dict[str, int] = {}
    for line, cells in enumerate(reader, start=2):
        if not cells or all(not c.strip() for c in cells):
            continue  # blank line
        if len(cells) != len(header):
            raise InputError(
                path, f"row {line}", len(cells), f"has {len(cells)} cells; the header has "
                f"{len(header)}",
            )  # fmt: skip
        rows.append(_row(path, base, line, dict(zip(header, (c.strip() for c in cells))), seen))
    if not rows:
        raise InputError(path, "rows", 0, "the manifest lists no recording")
    return rows


def _row(manifest: Path, base: Path, line: int, cell: dict[str, str], seen: dict) -> ManifestRow:
    name = cell["name"]
    where = f"row {line}" + (f" ({name})" if name else "")

    def bad(column: str, value, problem: str) -> InputError:
        return InputError(manifest, f"{where}: {column}", value, problem)

    if not _NAME.fullmatch(name):
        raise bad("name", name, f"{name!r} is not a folder name (letters, digits, '.', '_', '-'; "
                  "not starting with '.')")  # fmt: skip
    if name in seen:
        raise bad("name", name, f"{name!r} is also the name of row {seen[name]}")
    seen[name] = line

    def resolve(column: str, *, folder: bool | None) -> Path | None:
        value = cell.get(column, "")
        if not value:
            if column in REQUIRED:
                raise bad(column, value, "empty")
            return None
        p = Path(value).expanduser()
        p = p if p.is_absolute() else base / p
        if not p.exists():
            raise bad(column, value, f"{p}: no such {'folder' if folder else 'file'}")
        if folder is True and not p.is_dir():
            raise bad(column, value, f"{p}: not a folder")
        if folder is False and not p.is_file():
            raise bad(column, value, f"{p}: not a file")
        return p

    depth = resolve("depth", folder=True)
    keypoints = resolve("keypoints", folder=True)
    camera = None  # intri.yml#01: camera 01 of a multi-camera file (read_intrinsics)
    text = cell["intrinsics"]
    if CAMERA_SEPARATOR in Path(text).name:
        whole = Path(text).expanduser()
        if not (whole if whole.is_absolute() else base / whole).exists():
            cell["intrinsics"], _, camera = text.rpartition(CAMERA_SEPARATOR)
    intr_path = resolve("intrinsics", folder=False)
    if camera is not None:
        intr_path = Path(f"{intr_path}{CAMERA_SEPARATOR}{camera}")
    rgb = resolve("rgb", folder=None)  # a folder of images or a video file
    scale_text = cell.get("depth_scale", "")
    try:
        scale = float(scale_text) if scale_text else 1000.0
    except ValueError:
        raise bad("depth_scale", scale_text, "not a number") from None
    if not (math.isfinite(scale) and scale > 0):
        raise bad("depth_scale", scale_text, "must be a positive number (units per metre)")
    try:
        files = list_frames(depth, extensions=(".png",), what="depth")
        h, w = probe_depth_png(next(iter(files.values())))
    except InputError as e:
        raise bad("depth", e.value, str(e)) from None
    frames = len(files)
    try:  # a file without an image size (EasyMocap's intri.yml) takes the depth images'
        intrinsics = read_intrinsics(intr_path, image_size=(w, h))
    except InputError as e:
        raise bad("intrinsics", e.value, str(e)) from None
    return ManifestRow(
        line=line, name=name, depth=depth, keypoints=keypoints, intrinsics_path=intr_path,
        intrinsics=intrinsics, rgb=rgb, depth_scale=scale, frames=frames,
    )  # fmt: skip
