"""The one exception raised for bad input files."""

from __future__ import annotations

import os
from typing import Any

_MAX_VALUE_CHARS = 80


def format_value(value: Any) -> str:
    """``repr`` of an offending value, shortened so one bad 600 KB file cannot flood a terminal."""
    text = repr(value)
    if len(text) > _MAX_VALUE_CHARS:
        text = text[: _MAX_VALUE_CHARS - 3] + "..."
    return text


class InputError(ValueError):
    """Bad input file: the message names the file, the field and the offending value.

    It subclasses :class:`ValueError` so callers that already catch ``ValueError`` keep working.
    The message reads ``"<path>: <field>: <what is wrong>"``, e.g.::

        /x/k/000012_keypoints.json: people[0].pose_keypoints_2d: has 53 numbers; expected
        54 (COCO-18) or 75 (BODY_25)

    Attributes:
        path: the offending file or folder (``str``), as given by the caller.
        field: where in the file, e.g. ``"people[0].pose_keypoints_2d[7]"``, ``"IHDR.bit_depth"``,
            ``"intrinsic_matrix"``, ``"frames"``.
        value: the offending value itself (a number, a string, a tuple of sizes...).
    """

    def __init__(self, path: str | os.PathLike[str], field: str, value: Any, problem: str):
        self.path = os.fspath(path)
        self.field = field
        self.value = value
        self.problem = problem
        super().__init__(f"{self.path}: {field}: {problem}")

    def __reduce__(self):
        # Exceptions with a custom __init__ need this to survive pickling (multiprocessing).
        return (type(self), (self.path, self.field, self.value, self.problem))
