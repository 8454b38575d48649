"""Optional colour input: a folder of images or a video file, read lazily.

Colour must be registered to depth (same size, same pixel grid: the Azure Kinect
"transformation", RealSense ``align``, iai_kinect2 "registered" topics); the keypoints are
detected on it. Both readers return ``uint8 (H, W, 3)`` RGB (not OpenCV's BGR).

Videos are read with OpenCV (``cv2.VideoCapture``, FFmpeg is built into the
opencv-python wheels) rather than imageio, which needs an extra backend package (``av`` or
``imageio-ffmpeg``) to read any video. Video frame k (0-based) pairs with the k-th frame of
the recording in frame-number order.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from ._atomic import atomic_write_bytes
from ._errors import InputError

VIDEO_EXTENSIONS = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg")


def _check_shape(path: Path, field: str, image: np.ndarray, shape: tuple[int, int]) -> None:
    if image.shape[:2] != shape:
        h, w = image.shape[:2]
        raise InputError(
            path,
            field,
            (w, h),
            f"colour image is {w}x{h} but depth is {shape[1]}x{shape[0]} (width x height); "
            "colour must be registered to depth (same size and pixel grid)",
        )


def read_rgb(path: str | os.PathLike[str]) -> np.ndarray:
    """Read one colour image as ``uint8 (H, W, 3)`` RGB.

    Raises:
        InputError: unreadable, empty or undecodable file.
    """
    path = Path(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)  # not cv2.imread: it fails on non-ASCII paths
    except OSError as e:
        raise InputError(path, "file", str(path), f"cannot be read ({e.strerror})") from e
    if data.size == 0:
        raise InputError(path, "file", 0, "is empty (0 bytes); expected an image")
    image = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise InputError(path, "image data", f"{data.size} bytes", "is not a readable image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def write_rgb(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write one colour image, atomically (the inverse of :func:`read_rgb`).

    Args:
        path: destination; the format follows its extension (``.png`` lossless, ``.jpg``, ...).
        image: ``uint8 (H, W, 3)`` RGB (not OpenCV's BGR).

    Raises:
        ValueError: not a non-empty ``uint8 (H, W, 3)`` array, or an extension OpenCV cannot
            encode.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or image.size == 0:
        raise ValueError(
            f"write_rgb: image must be a non-empty uint8 (H, W, 3) array, got {image.dtype} "
            f"{image.shape}"
        )
    suffix = Path(path).suffix
    try:
        ok, encoded = cv2.imencode(suffix, cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    except cv2.error:
        ok = False
    if not ok:
        raise ValueError(f"write_rgb: OpenCV cannot encode {suffix!r} images ({path})")
    atomic_write_bytes(path, encoded.tobytes())


class RgbFrames(Sequence[np.ndarray]):
    """Lazy colour frames from a folder; a frame without a file reads as black."""

    def __init__(
        self, paths: Sequence[Path | None], *, frame_ids: np.ndarray, shape: tuple[int, int]
    ):
        self.paths: tuple[Path | None, ...] = tuple(paths)
        """Image file per frame, ``None`` where absent."""
        self.frame_ids = np.asarray(frame_ids, dtype=np.int64)
        """Frame number per frame, ``(T,)``."""
        self.shape = (int(shape[0]), int(shape[1]))
        """``(H, W)`` every frame must have (the depth size)."""

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return RgbFrames(self.paths[index], frame_ids=self.frame_ids[index], shape=self.shape)
        index = range(len(self))[index]
        path = self.paths[index]
        if path is None:
            return np.zeros((*self.shape, 3), dtype=np.uint8)
        image = read_rgb(path)
        _check_shape(path, "size", image, self.shape)
        return image

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self[i]


class RgbVideo(Sequence[np.ndarray]):
    """Lazy colour frames from a video file (frame k of the video = k-th recording frame).

    Sequential access (iteration, increasing indices) decodes each frame once; random access
    seeks. Not thread-safe: one decoder is shared.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, frame_ids: np.ndarray, shape: tuple[int, int]
    ):
        self.path = Path(path)
        """The video file."""
        self.frame_ids = np.asarray(frame_ids, dtype=np.int64)
        """Frame number per frame, ``(T,)``."""
        self.shape = (int(shape[0]), int(shape[1]))
        """``(H, W)`` every frame must have (the depth size)."""
        self._capture: cv2.VideoCapture | None = None
        self._next = 0
        capture = self._open()
        self.frame_count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        """Frames in the file as the container reports it (<= 0 if unknown)."""
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        self.fps: float | None = fps if np.isfinite(fps) and fps > 0 else None
        """Frames per second from the container, or None."""

    def _open(self) -> cv2.VideoCapture:
        if self._capture is None:
            if not self.path.is_file():
                raise InputError(self.path, "file", str(self.path), "video file does not exist")
            capture = cv2.VideoCapture(str(self.path))
            if not capture.isOpened():
                raise InputError(
                    self.path, "file", str(self.path), "cannot be opened as a video (OpenCV/FFmpeg)"
                )
            self._capture, self._next = capture, 0
        return self._capture

    def __len__(self) -> int:
        return len(self.frame_ids)

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            raise TypeError("RgbVideo does not support slicing; index frames one by one")
        index = range(len(self))[index]
        capture = self._open()
        if index != self._next:
            capture.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, image = capture.read()
        if not ok or image is None:
            self._next = -1
            raise InputError(
                self.path,
                f"frame {index}",
                index,
                f"could not be decoded (the video has {self.frame_count} frames by its header)",
            )
        self._next = index + 1
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        _check_shape(self.path, f"frame {index} size", image, self.shape)
        return image

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self[i]

    def close(self) -> None:
        """Release the decoder (it is reopened on the next access)."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def __del__(self):
        self.close()
