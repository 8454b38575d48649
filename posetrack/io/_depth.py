"""Depth images: 16-bit single-channel PNGs, one per frame.

Pixel values are integer depth units along the optical axis (z, not ray length); ``scale`` is
units per metre: 1000 for millimetres (Kinect v1/v2, Azure Kinect, RealSense at the default
depth unit), 5000 for the TUM RGB-D benchmark. 0 means "no measurement".

Invalid-depth representation: :func:`read_depth` returns float32 metres with **0.0** where the
sensor gave no measurement (not NaN). Zero is what every sensor writes, it survives any
arithmetic a mask is applied to afterwards (0 * w = 0, whereas NaN * 0 = NaN would poison a
jitted sum), and ``depth > 0`` is the validity mask.

Every file is checked before decoding: the PNG signature, the header (size, bit depth, colour
type) and the chunk structure, so a truncated file (copy interrupted, recorder killed) is
reported as truncated, not as a random decoder failure.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ._atomic import atomic_write_bytes
from ._errors import InputError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_IEND_CHUNK = b"\x00\x00\x00\x00IEND\xaeB`\x82"
_COLOR_TYPES = {0: "grayscale", 2: "RGB", 3: "palette", 4: "grayscale+alpha", 6: "RGBA"}
_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_OTHER_FORMATS = (
    (b"\xff\xd8\xff", "a JPEG"),
    (b"II*\x00", "a TIFF"),
    (b"MM\x00*", "a TIFF"),
    (b"BM", "a BMP"),
    (b"RIFF", "a RIFF (WebP?)"),
    (b"GIF8", "a GIF"),
)


@dataclass(frozen=True)
class PngHeader:
    """The IHDR fields of a PNG that matter here."""

    width: int
    height: int
    bit_depth: int
    color_type: int


def check_depth_scale(scale: float) -> float:
    """``scale`` (sensor units per metre) as a float; ValueError unless positive and finite."""
    scale = float(scale)
    if not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"depth scale must be a positive number of units per metre, got {scale!r}")
    return scale


def _describe_non_png(head: bytes) -> str:
    for magic, name in _OTHER_FORMATS:
        if head.startswith(magic):
            return f"is {name} file, not a PNG"
    if head[:1] in (b"{", b"[", b"<") or head.isascii():
        return "is a text file, not a PNG"
    return "is not a PNG file"


def _parse_header(path: Path, head: bytes, size: int) -> PngHeader:
    """Check signature and IHDR of the first 33 bytes of a PNG file; return the header."""
    if size == 0:
        raise InputError(path, "file", 0, "is empty (0 bytes); expected a 16-bit PNG depth image")
    if not head.startswith(PNG_SIGNATURE):
        if PNG_SIGNATURE.startswith(head):
            raise InputError(path, "file", size, f"is truncated: only {size} bytes")
        raise InputError(path, "signature", head[:8], _describe_non_png(head[:8]))
    if len(head) < 33:
        raise InputError(path, "IHDR", size, f"is truncated: {size} bytes, no complete header")
    length, ctype = struct.unpack(">I4s", head[8:16])
    if ctype != b"IHDR" or length != 13:
        raise InputError(path, "IHDR", ctype, "is a corrupt PNG: the first chunk is not IHDR")
    width, height, bit_depth, color_type = struct.unpack(">IIBB", head[16:26])
    return PngHeader(width=width, height=height, bit_depth=bit_depth, color_type=color_type)


def _check_depth_header(path: Path, header: PngHeader) -> None:
    if header.width == 0 or header.height == 0:
        raise InputError(
            path,
            "IHDR.width x IHDR.height",
            (header.width, header.height),
            f"image has zero size ({header.width}x{header.height})",
        )
    if header.bit_depth != 16 or header.color_type != 0:
        kind = _COLOR_TYPES.get(header.color_type, f"colour type {header.color_type}")
        channels = _CHANNELS.get(header.color_type, "?")
        if header.color_type != 0:
            field, value = "IHDR.color_type", kind
        else:
            field, value = "IHDR.bit_depth", header.bit_depth
        hint = (
            " (an 8-bit image is usually a visualisation of depth, not the data)"
            if header.bit_depth == 8 and header.color_type == 0
            else " (is this a colour image in the depth folder?)"
            if header.color_type in (2, 3, 6)
            else ""
        )
        raise InputError(
            path,
            field,
            value,
            f"is {'an' if header.bit_depth == 8 else 'a'} {header.bit_depth}-bit {kind} PNG "
            f"({channels} channel(s)); depth must be a "
            f"16-bit single-channel (grayscale) PNG{hint}",
        )


def _check_chunks(path: Path, data: bytes) -> None:
    """Walk the chunk list: detect truncation exactly and name where the data stops."""
    pos, size = 8, len(data)
    while True:
        if pos + 8 > size:
            raise InputError(
                path,
                "PNG chunks",
                size,
                f"is truncated: the file ends at byte {size} before the IEND chunk "
                "(interrupted copy or recording?)",
            )
        length, ctype = struct.unpack(">I4s", data[pos : pos + 8])
        end = pos + 12 + length
        if end > size:
            name = ctype.decode("latin-1")
            raise InputError(
                path,
                "PNG chunks",
                size,
                f"is truncated: chunk {name!r} at byte {pos} needs {length + 12} bytes but the "
                f"file ends at byte {size} (interrupted copy or recording?)",
            )
        if ctype == b"IEND":
            return
        pos = end


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except IsADirectoryError as e:
        raise InputError(path, "file", str(path), "is a folder, not a PNG file") from e
    except OSError as e:
        raise InputError(path, "file", str(path), f"cannot be read ({e.strerror})") from e


def probe_depth_png(path: str | os.PathLike[str]) -> tuple[int, int]:
    """Validate a depth PNG without decoding it and return its ``(height, width)``.

    Reads the 33-byte header and the last 12 bytes (which must be the IEND chunk; if they are
    not, the whole chunk list is walked, which tolerates trailing bytes after IEND and names
    the point of truncation otherwise). Cheap enough to run over every frame of a recording
    before tracking starts.

    Raises:
        InputError: as :func:`read_depth`, except for errors in the compressed pixel data.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(33)
            header = _parse_header(path, head, size)
            _check_depth_header(path, header)
            f.seek(max(size - 12, 0))
            tail = f.read(12)
    except IsADirectoryError as e:
        raise InputError(path, "file", str(path), "is a folder, not a PNG file") from e
    except OSError as e:
        raise InputError(path, "file", str(path), f"cannot be read ({e.strerror})") from e
    if tail != _IEND_CHUNK:
        _check_chunks(path, _read_bytes(path))
    return header.height, header.width


def read_depth(path: str | os.PathLike[str], *, scale: float = 1000.0) -> np.ndarray:
    """Read one 16-bit depth PNG as metres.

    Args:
        path: the PNG file.
        scale: depth units per metre (1000 = millimetres, the default; 5000 for TUM RGB-D).

    Returns:
        ``float32 (H, W)`` depth along the optical axis in metres; **0.0 where invalid**
        (the sensor's 0), never NaN.

    Raises:
        InputError: unreadable or empty file, not a PNG, truncated PNG, zero-size image,
            not 16-bit, not single-channel, corrupt pixel data.
        ValueError: ``scale`` is not a positive finite number.
    """
    scale = check_depth_scale(scale)
    path = Path(path)
    data = _read_bytes(path)
    header = _parse_header(path, data[:33], len(data))
    _check_depth_header(path, header)
    _check_chunks(path, data)
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(
            path, "image data", f"{len(data)} bytes", "could not be decoded (corrupt PNG data)"
        )
    if image.dtype != np.uint16 or image.ndim != 2:  # the header said otherwise: corrupt file
        raise InputError(
            path,
            "image data",
            f"{image.dtype} {image.shape}",
            "decoded to something other than a 16-bit single-channel image",
        )
    return image.astype(np.float32) * np.float32(1.0 / scale)


def write_depth_png(
    path: str | os.PathLike[str], depth: np.ndarray, *, scale: float = 1000.0
) -> None:
    """Write metres as a 16-bit depth PNG, atomically (the inverse of :func:`read_depth`).

    Args:
        path: destination ``.png``.
        depth: ``(H, W)`` metres; 0, negative or NaN pixels are written as 0 (invalid).
        scale: depth units per metre (1000 = millimetres).

    Raises:
        ValueError: wrong shape, +inf, or a depth beyond the 16-bit range (65535 / scale m).
    """
    scale = check_depth_scale(scale)
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2 or depth.size == 0:
        raise ValueError(f"write_depth_png: depth must be a non-empty (H, W) array: {depth.shape}")
    valid = np.isfinite(depth) & (depth > 0)
    if np.any(np.isposinf(depth)):
        raise ValueError("write_depth_png: depth contains +inf")
    units = np.where(valid, np.rint(np.where(valid, depth, 0.0) * scale), 0.0)
    if units.max() > 65535:
        raise ValueError(
            f"write_depth_png: depth {depth[valid].max():.3f} m exceeds the 16-bit range "
            f"({65535 / scale:.3f} m at scale {scale:g})"
        )
    ok, encoded = cv2.imencode(".png", units.astype(np.uint16))
    if not ok:
        raise ValueError(f"write_depth_png: OpenCV could not encode {path}")
    atomic_write_bytes(path, encoded.tobytes())


class DepthSequence(Sequence[np.ndarray]):
    """Lazy sequence of depth frames: a PNG is read only when its frame is indexed.

    A 10-minute 640x480 recording is ~9 GB as float32, so nothing is cached. Indexing with an
    int returns ``float32 (H, W)`` metres (0 = invalid, see :func:`read_depth`); a frame whose
    depth file is absent (``allow_missing``) reads as all zeros, i.e. no measurement. Slicing
    returns another lazy :class:`DepthSequence`.
    """

    def __init__(
        self,
        paths: Sequence[Path | None],
        *,
        frame_ids: np.ndarray,
        shape: tuple[int, int],
        scale: float = 1000.0,
        size_source: str = "",
    ):
        if len(paths) != len(frame_ids):
            raise ValueError("DepthSequence: paths and frame_ids differ in length")
        self.paths: tuple[Path | None, ...] = tuple(paths)
        """Depth file per frame, ``None`` where absent."""
        self.frame_ids = np.asarray(frame_ids, dtype=np.int64)
        """Frame number per frame, ``(T,)``."""
        self.shape = (int(shape[0]), int(shape[1]))
        """``(H, W)`` every frame must have."""
        self.scale = check_depth_scale(scale)
        """Depth units per metre."""
        self._size_source = size_source

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return DepthSequence(
                self.paths[index],
                frame_ids=self.frame_ids[index],
                shape=self.shape,
                scale=self.scale,
                size_source=self._size_source,
            )
        index = range(len(self))[index]  # bounds check + negative indices
        path = self.paths[index]
        if path is None:
            return np.zeros(self.shape, dtype=np.float32)
        depth = read_depth(path, scale=self.scale)
        if depth.shape != self.shape:
            h, w = depth.shape
            raise InputError(
                path,
                "size",
                (w, h),
                f"depth image is {w}x{h} but {self._size_source or 'the recording'} is "
                f"{self.shape[1]}x{self.shape[0]} (width x height)",
            )
        return depth

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        h, w = self.shape
        return f"DepthSequence({len(self)} frames, {w}x{h}, scale={self.scale:g})"
