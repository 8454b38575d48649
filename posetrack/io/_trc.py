"""Marker trajectories as a ``.trc`` file (Track Row Column), OpenSim's marker format.

The layout OpenSim's ``TRCFileAdapter`` reads (tab-separated)::

    PathFileType  4  (X/Y/Z)  motion.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame
        OrigNumFrames  (one line)
    30.000000  30.000000  120  18  m  30.000000  1  120
    Frame#  Time  Nose  <tab><tab>  Neck  ...
            X1  Y1  Z1  X2  Y2  Z2  ...
    <blank line>
    1  0.000000  x  y  z  x  y  z ...

A marker not seen in a frame is left empty (no value between its tabs), which OpenSim and
Mokka read as a gap; a zero would be read as a marker at the origin. Frame numbers count from
1 (OpenSim's convention) and times from 0; ``frame_ids`` are the recording's own frame numbers,
used for the times.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._atomic import atomic_write_text
from ._errors import InputError

UNITS = {"m": 1.0, "mm": 1000.0}
"""Units a TRC may be written in, and their factor from metres."""


def write_trc(
    path: str | os.PathLike[str],
    markers: np.ndarray,
    names: Sequence[str],
    *,
    fps: float,
    units: str = "m",
    frame_ids: np.ndarray | None = None,
) -> None:
    """Write marker trajectories to a ``.trc`` file, atomically.

    Args:
        path: the file.
        markers: ``(T, M, 3)`` positions in metres (converted to ``units``); NaN = not seen.
        names: the ``M`` marker names (no tabs or newlines).
        fps: frames per second (``DataRate``).
        units: ``"m"`` or ``"mm"``.
        frame_ids: ``(T,)`` frame numbers of the rows in the recording (times are
            ``(frame_ids - frame_ids[0]) / fps``); default ``0..T-1``.

    Raises:
        ValueError: bad shapes, names, units, fps or frame ids; inf in ``markers``.
    """
    markers = np.asarray(markers, np.float64)
    if markers.ndim != 3 or markers.shape[2] != 3:
        raise ValueError(f"write_trc: markers must be (T, M, 3), got {markers.shape}")
    T, M, _ = markers.shape
    names = [str(n) for n in names]
    if len(names) != M:
        raise ValueError(f"write_trc: {M} markers but {len(names)} names")
    bad = [n for n in names if not n or any(c in n for c in "\t\r\n")]
    if bad:
        raise ValueError(f"write_trc: marker names must be non-empty, without tabs: {bad!r}")
    if units not in UNITS:
        raise ValueError(f"write_trc: units must be one of {tuple(UNITS)}, got {units!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"write_trc: fps must be positive, got {fps!r}")
    if np.isinf(markers).any():
        raise ValueError("write_trc: markers contain inf")
    ids = np.arange(T) if frame_ids is None else np.asarray(frame_ids, np.int64)
    if ids.shape != (T,) or (T > 1 and not np.all(np.diff(ids) > 0)):
        raise ValueError(f"write_trc: frame_ids must be ({T},) and increasing")
    values = markers * UNITS[units]
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{Path(path).name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"{fps:.6f}\t{fps:.6f}\t{T}\t{M}\t{units}\t{fps:.6f}\t1\t{T}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"{a}{i + 1}" for i in range(M) for a in "XYZ"),
        "",
    ]
    times = (ids - (ids[0] if T else 0)) / float(fps)
    for t in range(T):
        cells = ["" if np.isnan(v) else f"{v:.6f}" for v in values[t].reshape(-1)]
        lines.append(f"{t + 1}\t{times[t]:.6f}\t" + "\t".join(cells))
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_trc(path: str | os.PathLike[str]) -> dict:
    """Read a ``.trc`` file (as :func:`write_trc` writes it, or a tool's with the same layout).

    Returns:
        ``{"names": [...], "fps": float, "units": str, "frames": int (T,), "times": (T,),
        "markers": (T, M, 3) in the file's units, NaN where empty}``.

    Raises:
        InputError: not a TRC file, or a header or row that does not parse.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, "file", str(path), f"cannot be read ({e})") from e
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise InputError(path, "line 1", lines[0] if lines else "", "is not a TRC header")
    keys, vals = lines[1].split("\t"), lines[2].split("\t")
    head = dict(zip([k.strip() for k in keys], [v.strip() for v in vals]))
    try:
        fps, n_frames, n_markers = (
            float(head["DataRate"]), int(head["NumFrames"]), int(head["NumMarkers"])
        )  # fmt: skip
    except (KeyError, ValueError) as e:
        raise InputError(
            path, "line 3", lines[2], f"has no valid rate/frames/markers ({e})"
        ) from e
    names = [n.strip() for n in lines[3].split("\t")[2:] if n.strip()]
    if len(names) != n_markers:
        raise InputError(path, "line 4", lines[3], f"names {len(names)} markers, not {n_markers}")
    rows = [ln for ln in lines[5:] if ln.strip()]
    markers = np.full((len(rows), n_markers, 3), np.nan)
    frames, times = np.zeros(len(rows), np.int64), np.zeros(len(rows))
    for i, row in enumerate(rows):
        cells = row.split("\t")
        try:
            frames[i], times[i] = int(cells[0]), float(cells[1])
            vals = [float(c) if c.strip() else np.nan for c in cells[2 : 2 + 3 * n_markers]]
        except (ValueError, IndexError) as e:
            raise InputError(path, f"line {i + 7}", row[:60], f"does not parse ({e})") from e
        markers[i].reshape(-1)[: len(vals)] = vals
    if len(rows) != n_frames:
        raise InputError(path, "NumFrames", n_frames, f"but the file has {len(rows)} rows")
    return {
        "names": names, "fps": fps, "units": head.get("Units", ""), "frames": frames,
        "times": times, "markers": markers,
    }  # fmt: skip
