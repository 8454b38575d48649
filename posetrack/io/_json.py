"""Strict JSON reading shared by the keypoint and intrinsics readers."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ._errors import InputError, format_value


def read_text(path: Path, what: str, kind: str) -> str:
    """A text file's contents (UTF-8, a BOM allowed); a missing, unreadable, empty or
    non-UTF-8 file is an :class:`InputError` saying it should hold ``what`` as ``kind``
    ("intrinsics", "JSON")."""
    try:
        data = path.read_bytes()
    except IsADirectoryError as e:
        raise InputError(path, "file", str(path), f"is a folder, not a {what} {kind} file") from e
    except OSError as e:
        raise InputError(path, "file", str(path), f"cannot be read ({e.strerror})") from e
    if not data.strip():
        problem = f"is empty ({len(data)} bytes); expected {what} {kind}"
        raise InputError(path, "file", len(data), problem)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        problem = f"is not UTF-8 text, so not {what} {kind}"
        raise InputError(path, "file", data[:16], problem) from e


def load_json(path: Path, what: str) -> Any:
    """Parse a JSON file; every failure is an :class:`InputError` naming the file.

    Python's ``json`` accepts the non-standard literals ``NaN`` and ``Infinity``; callers
    reject them per field with :func:`number`, so the message can say where they are.
    """
    text = read_text(path, what, "JSON")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        snippet = text[max(e.pos - 20, 0) : e.pos + 20]
        raise InputError(
            path,
            f"line {e.lineno} column {e.colno}",
            snippet,
            f"is not valid JSON ({e.msg}) near {format_value(snippet)}; expected {what} JSON",
        ) from e


def number(path: Path, where: str, value: Any) -> float:
    """A finite JSON number as float, else an :class:`InputError` naming ``where``."""
    # bool is an int subclass in Python, but `true` where a coordinate belongs is a bug.
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(path, where, value, f"is {format_value(value)}; expected a number")
    value = float(value)
    if not math.isfinite(value):
        raise InputError(path, where, value, f"is {value}; expected a finite number")
    return value
