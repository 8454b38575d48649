"""Camera intrinsics JSON files, three layouts detected from their keys.

* **Open3D** ``PinholeCameraIntrinsic``: ``{"width", "height", "intrinsic_matrix"}`` with the
  9 numbers stored COLUMN-major: ``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``.
* **plain**: ``{"fx", "fy", "cx", "cy", "width", "height"}`` (what
  :meth:`posetrack.Intrinsics.to_dict` writes).
* **ROS** ``sensor_msgs/CameraInfo`` as JSON: ``{"width", "height", "K"}`` with ``K`` ROW-major
  ``[fx, 0, cx, 0, fy, cy, 0, 0, 1]`` (ROS 2 spells it ``k``; ``D``/``d`` distortion is
  ignored with a note: feed rectified images). The ROS calibration file layout
  (``image_width``, ``image_height``, ``camera_matrix.data`` row-major) is read too.

A matrix may also be given as 3 rows of 3 numbers (``K.tolist()``), read as rows.
Values are pixels; (0, 0) is the centre of the top-left pixel. Skew must be 0. A file with
the keys of several layouts is accepted only if they agree.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Literal

from .._camera import Intrinsics
from ._atomic import atomic_write_text
from ._errors import InputError, format_value
from ._json import load_json, number

_PLAIN_KEYS = ("fx", "fy", "cx", "cy")


def _size(path: Path, doc: dict, key: str) -> int:
    if key not in doc:
        raise InputError(path, key, None, "is missing; the image size is needed")
    value = number(path, key, doc[key])
    if value != int(value) or value <= 0:
        raise InputError(path, key, doc[key], f"is {doc[key]!r}; expected a positive integer")
    return int(value)


def _matrix(path: Path, key: str, value: Any, *, column_major: bool) -> list[list[float]]:
    """3x3 K from a flat list of 9 (in the layout's order) or 3 rows of 3."""
    if isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) for r in value):
        if any(len(r) != 3 for r in value):
            raise InputError(path, key, value, "expected 9 numbers or 3 rows of 3")
        return [[number(path, f"{key}[{r}][{c}]", value[r][c]) for c in range(3)] for r in range(3)]
    if not isinstance(value, list) or len(value) != 9:
        n = len(value) if isinstance(value, list) else format_value(value)
        raise InputError(path, key, value, f"has {n} entries; expected 9 numbers")
    flat = [number(path, f"{key}[{k}]", v) for k, v in enumerate(value)]
    if column_major:
        return [[flat[c * 3 + r] for c in range(3)] for r in range(3)]
    return [flat[r * 3 : r * 3 + 3] for r in range(3)]


def _from_matrix(
    path: Path, key: str, K: list[list[float]], *, column_major: bool, flat: bool
) -> dict[str, tuple[float, str]]:
    def where(r: int, c: int) -> str:
        if not flat:
            return f"{key}[{r}][{c}]"
        return f"{key}[{c * 3 + r if column_major else r * 3 + c}]"

    if K[2][0] != 0 or K[2][1] != 0:
        if flat and K[0][2] == 0 and K[1][2] == 0:
            order = (
                "looks row-major, but Open3D stores intrinsic_matrix column-major "
                "[fx, 0, 0, 0, fy, 0, cx, cy, 1]"
                if column_major
                else "looks column-major, but ROS K is row-major [fx, 0, cx, 0, fy, cy, 0, 0, 1]"
            )
            as_written = [K[r][c] for c in range(3) for r in range(3)] if column_major else [
                v for row in K for v in row
            ]
            raise InputError(path, key, as_written, order)
        raise InputError(path, where(2, 0), K[2][0:2], "bottom row of K must be [0, 0, 1]")
    if K[2][2] != 1:
        raise InputError(path, where(2, 2), K[2][2], "bottom-right entry of K must be 1")
    if K[1][0] != 0:
        raise InputError(path, where(1, 0), K[1][0], "K[1][0] must be 0")
    if K[0][1] != 0:
        raise InputError(path, where(0, 1), K[0][1], "skew K[0][1] must be 0 (not supported)")
    return {
        "fx": (K[0][0], where(0, 0)),
        "fy": (K[1][1], where(1, 1)),
        "cx": (K[0][2], where(0, 2)),
        "cy": (K[1][2], where(1, 2)),
    }


def _candidates(path: Path, doc: dict) -> dict[str, dict[str, tuple[float, str]]]:
    """Parse every layout whose keys are present: ``{layout: {name: (value, field)}}``."""
    found: dict[str, dict[str, tuple[float, str]]] = {}
    if "intrinsic_matrix" in doc:
        value = doc["intrinsic_matrix"]
        K = _matrix(path, "intrinsic_matrix", value, column_major=True)
        flat = not (isinstance(value, list) and isinstance(value[0], list))
        found["Open3D"] = _from_matrix(path, "intrinsic_matrix", K, column_major=True, flat=flat)
    for key in ("K", "k"):
        if key in doc:
            value = doc[key]
            K = _matrix(path, key, value, column_major=False)
            flat = not (isinstance(value, list) and isinstance(value[0], list))
            found["ROS CameraInfo"] = _from_matrix(path, key, K, column_major=False, flat=flat)
            break
    if isinstance(doc.get("camera_matrix"), dict):
        value = doc["camera_matrix"].get("data")
        K = _matrix(path, "camera_matrix.data", value, column_major=False)
        found["ROS calibration"] = _from_matrix(
            path, "camera_matrix.data", K, column_major=False, flat=True
        )
    if any(k in doc for k in _PLAIN_KEYS):
        for k in _PLAIN_KEYS:
            if k not in doc:
                needs = ", ".join(_PLAIN_KEYS)
                raise InputError(path, k, None, f"is missing (the plain layout needs {needs})")
        found["plain"] = {k: (number(path, k, doc[k]), k) for k in _PLAIN_KEYS}
    return found


def _notes(path: Path, doc: dict, fx: float, fy: float) -> list[str]:
    notes = []
    for key in ("D", "d", "distortion_coefficients"):
        value = doc.get(key)
        if isinstance(value, dict):
            value = value.get("data")
        if isinstance(value, list) and any(
            isinstance(v, (int, float)) and not isinstance(v, bool) and v != 0 for v in value
        ):
            notes.append(
                f"{path.name}: distortion coefficients {key} are ignored (pinhole model); "
                "use rectified images"
            )
    if not 0.8 <= fx / fy <= 1.25:
        notes.append(
            f"{path.name}: fx/fy = {fx / fy:.2f}; depth cameras have square pixels (fx ~= fy), "
            "check the calibration"
        )
    return notes


def read_intrinsics_with_layout(path: str | os.PathLike[str]) -> tuple[Intrinsics, str, list[str]]:
    """Parse an intrinsics file: ``(intrinsics, layout name, notes)``."""
    path = Path(path)
    doc = load_json(path, "intrinsics")
    if not isinstance(doc, dict):
        raise InputError(
            path, "(top level)", type(doc).__name__,
            f"is a JSON {type(doc).__name__}; expected an object with intrinsics fields",
        )  # fmt: skip
    found = _candidates(path, doc)
    if not found:
        raise InputError(
            path,
            "(top level)",
            sorted(map(str, doc)),
            f"no known intrinsics layout in keys {format_value(sorted(map(str, doc)))}; "
            "expected Open3D (width, height, intrinsic_matrix), plain (fx, fy, cx, cy, width, "
            "height) or ROS CameraInfo (width, height, K)",
        )
    if "ROS calibration" in found and "width" not in doc:
        width, height = _size(path, doc, "image_width"), _size(path, doc, "image_height")
        size_fields = ("image_width", "image_height")
    else:
        width, height = _size(path, doc, "width"), _size(path, doc, "height")
        size_fields = ("width", "height")
    layouts = list(found)
    values = found[layouts[0]]
    for other in layouts[1:]:
        for name in _PLAIN_KEYS:
            a, field_a = values[name]
            b, field_b = found[other][name]
            if not math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9):
                raise InputError(
                    path, f"{field_a} / {field_b}", (a, b),
                    f"layouts {layouts[0]} and {other} disagree on {name}: {a} vs {b}",
                )  # fmt: skip
    (fx, fx_field), (fy, fy_field) = values["fx"], values["fy"]
    (cx, cx_field), (cy, cy_field) = values["cx"], values["cy"]
    for value, where in ((fx, fx_field), (fy, fy_field)):
        if value <= 0:
            raise InputError(path, where, value, f"focal length is {value}; must be positive")
    if not 0 <= cx <= width:
        raise InputError(
            path, cx_field, cx,
            f"principal point cx = {cx} lies outside the image "
            f"(0 <= cx <= {size_fields[0]} = {width})",
        )  # fmt: skip
    if not 0 <= cy <= height:
        raise InputError(
            path, cy_field, cy,
            f"principal point cy = {cy} lies outside the image "
            f"(0 <= cy <= {size_fields[1]} = {height})",
        )  # fmt: skip
    try:
        intrinsics = Intrinsics.create(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
    except ValueError as e:  # kept in case Intrinsics.create grows stricter checks
        raise InputError(path, "intrinsics", values, str(e)) from e
    return intrinsics, " + ".join(layouts), _notes(path, doc, fx, fy)


def read_intrinsics_json(path: str | os.PathLike[str]) -> Intrinsics:
    """Read camera intrinsics from JSON in the Open3D, plain or ROS layout (auto-detected).

    Returns:
        Validated :class:`posetrack.Intrinsics` (pixels).

    Raises:
        InputError: unreadable, empty or non-JSON file; no known layout; a missing, non-numeric
            or non-finite field; a matrix that is not 3x3 or has the other storage order, a
            non-zero skew or a bottom row other than [0, 0, 1]; a non-positive focal length or
            size; a principal point outside the image; layouts in one file that disagree.
    """
    return read_intrinsics_with_layout(path)[0]


def write_intrinsics_json(
    path: str | os.PathLike[str],
    intrinsics: Intrinsics,
    *,
    layout: Literal["plain", "open3d", "ros"] = "plain",
) -> None:
    """Write intrinsics as JSON, atomically, in one of the layouts :func:`read_intrinsics_json`
    reads (``"ros"`` writes ROS 1 CameraInfo fields with zero distortion)."""
    d = intrinsics.to_dict()
    fx, fy, cx, cy = d["fx"], d["fy"], d["cx"], d["cy"]
    size = {"width": d["width"], "height": d["height"]}
    if layout == "plain":
        doc: dict[str, Any] = d
    elif layout == "open3d":
        doc = {**size, "intrinsic_matrix": [fx, 0.0, 0.0, 0.0, fy, 0.0, cx, cy, 1.0]}
    elif layout == "ros":
        doc = {
            "height": d["height"],
            "width": d["width"],
            "distortion_model": "plumb_bob",
            "D": [0.0] * 5,
            "K": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "P": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        }
    else:
        raise ValueError(
            f"write_intrinsics_json: layout must be plain, open3d or ros, got {layout!r}"
        )
    atomic_write_text(path, json.dumps(doc, indent=2) + "\n")
