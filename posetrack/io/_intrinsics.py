"""Camera intrinsics files: JSON or OpenCV YAML/XML, the layout detected from the keys.

JSON layouts:

* **Open3D** ``PinholeCameraIntrinsic``: ``{"width", "height", "intrinsic_matrix"}`` with the
  9 numbers stored COLUMN-major: ``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``.
* **plain**: ``{"fx", "fy", "cx", "cy", "width", "height"}`` (what
  :meth:`posetrack.Intrinsics.to_dict` writes).
* **ROS** ``sensor_msgs/CameraInfo`` as JSON: ``{"width", "height", "K"}`` with ``K`` ROW-major
  ``[fx, 0, cx, 0, fy, cy, 0, 0, 1]`` (ROS 2 spells it ``k``). The ROS calibration file layout
  (``image_width``, ``image_height``, ``camera_matrix.data`` row-major) is read too.

OpenCV ``cv::FileStorage`` files (``.yml``, ``.yaml``, ``.xml``, or text starting with
``%YAML`` / ``<?xml``), read with ``cv2.FileStorage``:

* **OpenCV/ROS calibration**: ``camera_matrix`` or ``cameraMatrix`` (an ``opencv-matrix``, or a
  map with ``data`` row-major as ROS writes it), the size from ``image_width`` /
  ``image_height`` (or ``width`` / ``height``, or ``cameraResolution: [w, h]``).
* **EasyMocap** ``intri.yml``: ``K_<name>`` per camera, ``dist_<name>``, and a ``names``
  list. A file with several cameras needs one chosen as ``intri.yml#<name>`` (the text after
  the last ``#`` of a path that does not exist as given). EasyMocap writes no image size
  (EasyVolcap's ``W_<name>`` / ``H_<name>`` are read if present).

A file without an image size takes ``image_size`` (``load_recording`` passes the depth images'
size); without one it is an error that says how to give it. Distortion coefficients
(``D``/``d``, ``distortion_coefficients``, ``dist_<name>``, ...) are ignored with a note: the
pinhole model needs undistorted (registered) depth images.

A matrix may also be given as 3 rows of 3 numbers (``K.tolist()``), read as rows.
Values are pixels; (0, 0) is the centre of the top-left pixel. Skew must be 0. A file with
the keys of several layouts is accepted only if they agree.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from .._camera import Intrinsics
from ._atomic import atomic_write_text
from ._errors import InputError, format_value
from ._filestorage import load_filestorage, looks_like_filestorage
from ._json import load_json, number

_PLAIN_KEYS = ("fx", "fy", "cx", "cy")


def _size(path: Path, doc: dict, key: str, other: str) -> int:
    if key not in doc:
        raise InputError(
            path, key, None, f"is missing; the image size needs both {key} and {other}"
        )
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


#: Separates a camera name from the file in ``intri.yml#01``.
CAMERA_SEPARATOR = "#"
_K_CAMERA = re.compile(r"K_(.+)")
_DISTORTION_KEYS = (
    "D", "d", "distortion_coefficients", "dist_coeffs", "distCoeffs", "dist", "distortion",
)  # fmt: skip


def split_camera(path: str | os.PathLike[str]) -> tuple[Path, str | None]:
    """``"intri.yml#01"`` -> ``(Path("intri.yml"), "01")``; ``(path, None)`` without a ``#``.

    The camera name is the text after the last ``#`` of the file name. A path that exists
    as given is never split (a file may have ``#`` in its name).
    """
    text = os.fspath(path)
    if CAMERA_SEPARATOR not in Path(text).name or Path(text).exists():
        return Path(text), None
    file, _, camera = text.rpartition(CAMERA_SEPARATOR)
    return Path(file), camera


def _camera_matrix(path: Path, key: str, value: Any) -> dict[str, tuple[float, str]]:
    """fx, fy, cx, cy of a row-major K: an OpenCV matrix map (``{rows, cols, dt, data}``; ROS
    calibration writes it without ``dt``), 9 numbers or 3 rows of 3."""
    if isinstance(value, dict):
        for dim in ("rows", "cols"):
            if dim in value and value[dim] != 3:
                raise InputError(
                    path, f"{key}.{dim}", value[dim],
                    f"is {format_value(value[dim])}; the camera matrix is 3x3",
                )  # fmt: skip
        if "data" not in value:
            raise InputError(
                path, f"{key}.data", None,
                "is missing; expected the 9 numbers of the 3x3 camera matrix, row-major",
            )  # fmt: skip
        key, value = f"{key}.data", value["data"]
    K = _matrix(path, key, value, column_major=False)
    flat = not (isinstance(value, list) and isinstance(value[0], list))
    return _from_matrix(path, key, K, column_major=False, flat=flat)


def _camera_names(path: Path, doc: dict) -> list[str] | None:
    """The cameras of a multi-camera file (EasyMocap ``K_<name>``), None for a one-camera
    layout. EasyMocap's ``names`` list gives them in order; without it, the ``K_`` keys."""
    keyed = [m.group(1) for k in doc if (m := _K_CAMERA.fullmatch(k))]
    if not keyed:
        return None
    names = doc.get("names")
    if names is None:
        return keyed
    if isinstance(names, (str, int)) and not isinstance(names, bool):
        names = [names]  # cv2.FileStorage writes a list of one name as that name
    if not isinstance(names, list) or not names:
        raise InputError(
            path, "names", names,
            f"is {format_value(names)}; expected the list of camera names (one K_<name> each)",
        )  # fmt: skip
    out = []
    for i, name in enumerate(names):
        if isinstance(name, bool) or not isinstance(name, (str, int)):
            raise InputError(
                path, f"names[{i}]", name, f"is {format_value(name)}; expected a camera name"
            )
        out.append(str(name))
    return out


@dataclass(frozen=True)
class _Layout:
    """What one file holds: the candidate K of each layout found, where its size and its
    distortion coefficients would be."""

    found: dict[str, dict[str, tuple[float, str]]]
    size_keys: tuple[tuple[str, str], ...]
    distortion_keys: tuple[str, ...]


def _layout(path: Path, doc: dict, camera: str | None) -> _Layout:
    """Parse every layout whose keys are present (``found``: ``{layout: {name: (value,
    field)}}``), after choosing the camera of a multi-camera file."""
    names = _camera_names(path, doc)
    if names is not None:
        how = f"choose one as {path}{CAMERA_SEPARATOR}NAME"
        if camera is None:
            if len(names) > 1:
                raise InputError(
                    path, "names", names,
                    f"holds {len(names)} cameras ({', '.join(names)}); {how}, e.g. "
                    f"{path}{CAMERA_SEPARATOR}{names[0]}",
                )  # fmt: skip
            camera = names[0]
        elif camera not in names:
            what = "an empty camera name" if not camera else f"no camera {camera!r}"
            raise InputError(
                path, "names", camera,
                f"{what}; the file holds {', '.join(names)} ({how})",
            )  # fmt: skip
        key = f"K_{camera}"
        if key not in doc:
            raise InputError(path, key, None, f"is missing; names lists camera {camera!r}")
        return _Layout(
            found={f"EasyMocap intri.yml, camera {camera}": _camera_matrix(path, key, doc[key])},
            size_keys=((f"W_{camera}", f"H_{camera}"), ("width", "height"),
                       ("image_width", "image_height")),
            distortion_keys=(f"dist_{camera}", f"D_{camera}"),
        )  # fmt: skip
    if camera is not None:
        raise InputError(
            path, f"{CAMERA_SEPARATOR}{camera}", camera,
            f"selects camera {camera!r}, but the file holds one camera (no K_<name> "
            f"entries); drop '{CAMERA_SEPARATOR}{camera}'",
        )  # fmt: skip
    found: dict[str, dict[str, tuple[float, str]]] = {}
    if "intrinsic_matrix" in doc:
        value = doc["intrinsic_matrix"]
        K = _matrix(path, "intrinsic_matrix", value, column_major=True)
        flat = not (isinstance(value, list) and isinstance(value[0], list))
        found["Open3D"] = _from_matrix(path, "intrinsic_matrix", K, column_major=True, flat=flat)
    for key in ("K", "k"):
        if key in doc:
            found["ROS CameraInfo"] = _camera_matrix(path, key, doc[key])
            break
    for key in ("camera_matrix", "cameraMatrix"):
        if key in doc:
            found[f"OpenCV/ROS calibration ({key})"] = _camera_matrix(path, key, doc[key])
    if any(k in doc for k in _PLAIN_KEYS):
        for k in _PLAIN_KEYS:
            if k not in doc:
                needs = ", ".join(_PLAIN_KEYS)
                raise InputError(path, k, None, f"is missing (the plain layout needs {needs})")
        found["plain"] = {k: (number(path, k, doc[k]), k) for k in _PLAIN_KEYS}
    return _Layout(
        found=found,
        size_keys=(("width", "height"), ("image_width", "image_height")),
        distortion_keys=_DISTORTION_KEYS,
    )


def _image_size(
    path: Path, doc: dict, size_keys: tuple[tuple[str, str], ...]
) -> tuple[int, int, tuple[str, str]] | None:
    """``(width, height, (width field, height field))`` from the file, None if it has none."""
    for w_key, h_key in size_keys:
        if w_key in doc or h_key in doc:
            return _size(path, doc, w_key, h_key), _size(path, doc, h_key, w_key), (w_key, h_key)
    if "cameraResolution" in doc:  # OpenCV's interactive-calibration: [width, height]
        value = doc["cameraResolution"]
        if not isinstance(value, list) or len(value) != 2:
            raise InputError(
                path, "cameraResolution", value,
                f"is {format_value(value)}; expected [width, height]",
            )  # fmt: skip
        fields = ("cameraResolution[0]", "cameraResolution[1]")
        sizes = dict(zip(fields, value))
        width = _size(path, sizes, fields[0], fields[1])
        return width, _size(path, sizes, fields[1], fields[0]), fields
    return None


def _notes(
    path: Path, doc: dict, fx: float, fy: float, distortion_keys: tuple[str, ...]
) -> list[str]:
    notes = []
    for key in distortion_keys:
        value = doc.get(key)
        if isinstance(value, dict):
            value = value.get("data")
        if isinstance(value, list) and value and isinstance(value[0], list):
            value = [v for row in value if isinstance(row, list) for v in row]
        if isinstance(value, list) and any(
            isinstance(v, (int, float)) and not isinstance(v, bool) and v != 0 for v in value
        ):
            notes.append(
                f"{path.name}: distortion coefficients {key} are ignored (pinhole model): "
                "the depth images must be undistorted (registered)"
            )
    if not 0.8 <= fx / fy <= 1.25:
        notes.append(
            f"{path.name}: fx/fy = {fx / fy:.2f}; depth cameras have square pixels (fx ~= fy), "
            "check the calibration"
        )
    return notes


@dataclass(frozen=True)
class IntrinsicsFile:
    """An intrinsics file as read: the intrinsics and what was found."""

    intrinsics: Intrinsics
    """Validated intrinsics (pixels)."""
    layout: str
    """The layout(s) detected, e.g. ``"plain"``, ``"EasyMocap intri.yml, camera 01 (OpenCV
    YAML)"``."""
    notes: list[str]
    """One-line remarks: ignored distortion, fx/fy far from 1."""
    size_in_file: bool
    """False where the file gives no image size and ``image_size`` was used."""


def _check_image_size(image_size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        w = h = 0
    if w <= 0 or h <= 0 or (w, h) != tuple(image_size):
        raise ValueError(f"image_size must be (width, height), positive ints: {image_size!r}")
    return w, h


def read_intrinsics_file(
    path: str | os.PathLike[str], *, image_size: tuple[int, int] | None = None
) -> IntrinsicsFile:
    """Read an intrinsics file in any layout (see the module docstring).

    Args:
        path: a JSON or OpenCV YAML/XML file; ``FILE#NAME`` chooses camera NAME of a file with
            several (EasyMocap ``intri.yml``).
        image_size: ``(width, height)`` in pixels for a file that gives no image size; a size
            in the file wins.

    Raises:
        InputError: see :func:`read_intrinsics`.
    """
    path, camera = split_camera(path)
    fallback = None if image_size is None else _check_image_size(image_size)
    try:
        with open(path, "rb") as f:
            head = f.read(64)
    except OSError:
        head = b""  # the loader below reports it, naming the file
    if looks_like_filestorage(path, head):
        doc = load_filestorage(path, "intrinsics")
        start = head.lstrip(b"\xef\xbb\xbf").lstrip()[:1]
        form = {b"<": " (OpenCV XML)", b"{": " (OpenCV JSON)"}.get(start, " (OpenCV YAML)")
        expected = "JSON, or OpenCV YAML/XML"
    else:
        doc = load_json(path, "intrinsics")
        form = ""
        if not isinstance(doc, dict):
            raise InputError(
                path, "(top level)", type(doc).__name__,
                f"is a JSON {type(doc).__name__}; expected an object with intrinsics fields",
            )  # fmt: skip
        expected = "JSON"
    layout = _layout(path, doc, camera)
    found = layout.found
    if not found:
        keys = sorted(map(str, doc))
        raise InputError(
            path, "(top level)", keys,
            f"no known intrinsics layout in keys {format_value(keys)} ({expected}); expected "
            "Open3D (width, height, intrinsic_matrix), plain (fx, fy, cx, cy, width, height), "
            "ROS CameraInfo (width, height, K), an OpenCV calibration (camera_matrix, "
            "image_width, image_height) or EasyMocap intri.yml (K_<name>)",
        )  # fmt: skip
    size = _image_size(path, doc, layout.size_keys)
    if size is not None:
        width, height, size_fields = size
    elif fallback is not None:
        (width, height), size_fields = fallback, ("image width", "image height")
    else:
        w_key, h_key = layout.size_keys[0]
        raise InputError(
            path, f"{w_key} / {h_key}", None,
            f"the file gives no image size (no {w_key} / {h_key}"
            + ("; EasyMocap's intri.yml never does" if w_key.startswith("W_") else "")
            + "). posetrack track and load_recording take it from the depth images; "
            f"elsewhere add {w_key} and {h_key} to the file or give the size "
            "(read_intrinsics(path, image_size=(width, height)); posetrack warmup --size WxH)",
        )  # fmt: skip
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
    return IntrinsicsFile(
        intrinsics=intrinsics,
        layout=" + ".join(layouts) + form,
        notes=_notes(path, doc, fx, fy, layout.distortion_keys),
        size_in_file=size is not None,
    )


def read_intrinsics(
    path: str | os.PathLike[str], *, image_size: tuple[int, int] | None = None
) -> Intrinsics:
    """Read camera intrinsics from JSON (Open3D, plain or ROS) or OpenCV YAML/XML (OpenCV or
    ROS calibration, EasyMocap ``intri.yml``); the layout is detected from the keys.

    Args:
        path: the file (``.yml``, ``.yaml`` and ``.xml``, or text starting with ``%YAML`` or
            ``<?xml``, are read with ``cv2.FileStorage``; anything else as JSON).
            ``FILE#NAME`` chooses camera NAME of a file with several (EasyMocap's
            ``K_<name>``); a file with one camera needs no name.
        image_size: ``(width, height)`` in pixels, used only when the file gives no image size
            (EasyMocap's ``intri.yml`` gives none); a size in the file wins.

    Returns:
        Validated :class:`posetrack.Intrinsics` (pixels).

    Raises:
        InputError: unreadable or empty file, invalid JSON or YAML/XML (naming the line); no
            known layout; a missing, non-numeric or non-finite field; a matrix that is not 3x3
            or has the other storage order, a non-zero skew or a bottom row other than
            [0, 0, 1]; no image size and no ``image_size``; a non-positive focal length or
            size; a principal point outside the image; layouts in one file that disagree; a
            multi-camera file without a camera chosen (the message lists the names), or a
            camera it does not hold.
    """
    return read_intrinsics_file(path, image_size=image_size).intrinsics


def read_intrinsics_json(path: str | os.PathLike[str]) -> Intrinsics:
    """Read camera intrinsics; the older name of :func:`read_intrinsics`, which also reads
    OpenCV YAML/XML (Open3D, plain and ROS JSON as before).

    Raises:
        InputError: see :func:`read_intrinsics`.
    """
    return read_intrinsics(path)

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
