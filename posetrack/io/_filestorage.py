"""OpenCV ``cv::FileStorage`` files (YAML or XML) read into plain Python values.

``cv2.FileStorage`` parses the file (no YAML or XML package is needed); the tree of nodes is
then copied into dicts, lists, ints, floats and strings, so a reader can treat it like parsed
JSON. An ``!!opencv-matrix`` (XML ``type_id="opencv-matrix"``) comes out as the map it is
written as: ``{"rows": 3, "cols": 3, "dt": "d", "data": [row-major numbers]}``. Matrices are
not decoded with ``FileNode.mat()``: it fails on the same map without the type tag (ROS
calibration YAML writes ``camera_matrix`` that way), and the map keeps every number for the
error messages.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2

from ._errors import InputError
from ._json import read_text

#: Extensions read as OpenCV YAML/XML; anything else is JSON unless its text starts like one.
FILESTORAGE_SUFFIXES = (".yml", ".yaml", ".xml")
_HEADERS = ("%YAML", "<?xml", "<opencv_storage")
# OpenCV's parse errors end in "...in function '<where>(<line>): <problem>'".
_PARSE_ERROR = re.compile(r"\((\d+)\): (.*?)'?\s*$")


def looks_like_filestorage(path: Path, head: bytes) -> bool:
    """Whether a file is OpenCV YAML/XML: by extension, or by its first bytes (``%YAML``...)."""
    if path.suffix.lower() in FILESTORAGE_SUFFIXES:
        return True
    text = head.lstrip(b"\xef\xbb\xbf").lstrip().decode("ascii", "replace")
    return text.startswith(_HEADERS)


def _value(node: Any) -> Any:
    if node.isMap():
        return {key: _value(node.getNode(key)) for key in node.keys()}
    if node.isSeq():
        return [_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None  # an empty value ("key:" with nothing after it)


def load_filestorage(path: Path, what: str) -> dict[str, Any]:
    """Parse an OpenCV YAML/XML file into a dict; every failure is an :class:`InputError`.

    Args:
        path: the file.
        what: what the file should hold ("intrinsics"), for messages.

    Raises:
        InputError: unreadable, empty or non-UTF-8 file; a parse error (naming the line
            OpenCV reports); a top level that is not a map.
    """
    text = read_text(path, what, "OpenCV YAML/XML")
    # From memory rather than by file name: the bytes are already read (with the errors above),
    # and the format then follows the content (YAML, XML or JSON), not the extension.
    flags = cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY
    try:
        storage = cv2.FileStorage(text, flags)
    except (cv2.error, SystemError) as e:
        # The binding raises SystemError with the cv2.error as its cause.
        cause = e.__cause__ if isinstance(e, SystemError) and e.__cause__ is not None else e
        message = str(cause).strip()
        found = _PARSE_ERROR.search(message)
        if found:
            line, problem = int(found.group(1)), found.group(2).strip()
            raise InputError(
                path, f"line {line}", problem,
                f"is not valid OpenCV YAML/XML ({problem}); expected {what}",
            ) from None  # fmt: skip
        last = message.splitlines()[-1] if message else type(e).__name__
        raise InputError(
            path, "file", last, f"is not valid OpenCV YAML/XML ({last}); expected {what}"
        ) from None
    try:
        if not storage.isOpened():
            raise InputError(path, "file", None, f"OpenCV could not open it as {what} YAML/XML")
        root = storage.root()
        doc = _value(root)
    finally:
        storage.release()
    if not isinstance(doc, dict):
        kind = "a list" if isinstance(doc, list) else type(doc).__name__
        raise InputError(
            path, "(top level)", kind, f"is {kind}; expected a map of {what} fields"
        )
    return doc
