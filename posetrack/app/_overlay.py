"""Overlay video: each frame's colour image (or colourised depth) with the estimated skeleton.

An MP4 is H.264 (``yuv420p``, ``+faststart``), so browsers, Jupyter and phones play it: it is
encoded by the FFmpeg binary that the ``imageio-ffmpeg`` wheel ships (a dependency), fed raw
frames through a pipe. OpenCV's wheels carry no H.264 encoder (``avc1`` fails to open), only
MPEG-4 Part 2 (``mp4v``), which most players but no browser play: that is the fallback when
the FFmpeg binary cannot run. Where no MP4 writer opens at all, an animated GIF (imageio's
bundled Pillow plugin) is written instead, scaled to at most :data:`GIF_MAX_WIDTH` pixels wide
because GIF frames are kept in memory until the end. :func:`video_codec` says which codec a
written file holds.

Colours: green skeleton = tracked, red = lost (Delta above ``lost_delta`` or agreement
below ``lost_agreement``), grey = no observation (the held pose, if any); small cyan dots =
the 2D detections the tracker was given.

Beside the image, by default, a second panel of the same height shows the skeleton from the
side (or from above) at one fixed metric scale, with trails of the last 1.5 s and the floor
(:class:`~posetrack.app._panel.SkeletonPanel`); ``panel=None`` leaves the image alone.
"""

from __future__ import annotations

import errno
import os
import shutil
import struct
import warnings
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np

from .._camera import Intrinsics
from .._result import STATUS_NAMES
from ._panel import PANELS, SkeletonPanel
from ._progress import Progress
from ._viz import CYAN, STATUS_COLORS, colorize_depth, draw_skeleton, put_label, write_gif

GIF_MAX_WIDTH = 480
"""GIF fallback frames are downscaled to this width (pixels) at most."""


def project_points(intrinsics: Intrinsics, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection in NumPy (no JAX dispatch per frame).

    Args:
        intrinsics: the camera.
        points: ``(..., 3)`` camera-frame points, metres; NaN = absent.

    Returns:
        ``(uv (..., 2) pixels, valid (...,) bool)``: valid = finite and at least 5 cm in front
        of the camera.
    """
    p = np.asarray(points, dtype=np.float64)
    z = p[..., 2]
    valid = np.isfinite(p).all(axis=-1) & (z > 0.05)
    zs = np.where(valid, z, 1.0)
    u = float(intrinsics.fx) * np.where(valid, p[..., 0], 0.0) / zs + float(intrinsics.cx)
    v = float(intrinsics.fy) * np.where(valid, p[..., 1], 0.0) / zs + float(intrinsics.cy)
    return np.stack([u, v], axis=-1), valid


def depth_range(depth: Sequence[np.ndarray], *, samples: int = 5) -> tuple[float, float]:
    """A fixed (near, far) range in metres for colourising a whole depth sequence.

    One range for all frames: per-frame percentiles would make the grey levels flicker.
    Computed from up to ``samples`` frames spread over the sequence.
    """
    n = len(depth)
    values = []
    for t in np.unique(np.linspace(0, n - 1, min(samples, n)).round().astype(int)):
        d = np.asarray(depth[int(t)], dtype=np.float32)
        d = d[np.isfinite(d) & (d > 0)]
        if d.size:
            values.append(d[:: max(1, d.size // 20000)])
    if not values:
        return 0.5, 5.0
    near, far = np.percentile(np.concatenate(values), [2, 98])
    return float(near), float(max(far, near + 0.1))


def overlay_frame(
    image: np.ndarray,
    keypoints3d: np.ndarray,
    intrinsics: Intrinsics,
    *,
    status: int,
    delta: float,
    frame_id: int,
    detections: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Draw one frame of the overlay.

    Args:
        image: ``uint8 (H, W, 3)`` RGB (colour, or colourised depth).
        keypoints3d: ``(18, 3)`` estimated COCO-18 keypoints, metres, camera frame; NaN rows
            are not drawn.
        intrinsics: the camera the keypoints are projected with.
        status: 0 tracked, 1 lost, 2 no observation (sets the colour).
        delta: Delta of the frame (Eq. (3)); NaN when not computed.
        frame_id: frame number for the label.
        detections: optional ``((18, 2) pixels, (18,) confidence)`` 2D keypoints given to the
            tracker, drawn as small dots where the confidence is positive.

    Returns:
        ``uint8 (H, W, 3)`` RGB.
    """
    img = np.ascontiguousarray(image, dtype=np.uint8)
    scale = max(1, round(img.shape[1] / 400))
    if detections is not None:
        uv2, conf2 = detections
        for (u, v), c in zip(np.asarray(uv2, np.float64), np.asarray(conf2)):
            if c > 0 and np.isfinite(u) and np.isfinite(v):
                cv2.circle(img, (int(round(u)), int(round(v))), scale + 1, CYAN, -1, cv2.LINE_AA)
    uv, valid = project_points(intrinsics, keypoints3d)
    if valid.any():
        img = draw_skeleton(
            img, uv, color=STATUS_COLORS[int(status)], valid=valid, thickness=scale + 1
        )
    label = f"frame {int(frame_id)}  {STATUS_NAMES[int(status)]}"
    if np.isfinite(delta):
        label += f"  Delta {float(delta):.2f}"
    return put_label(img, label, color=STATUS_COLORS[int(status)])


class _Mp4Writer:
    """Streams frames to an MP4 with OpenCV (mp4v, the fallback); frames all of one size."""

    codec = "mpeg4"

    def __init__(self, path: Path, fps: float, size: tuple[int, int]):
        w, h = size
        # Round down to even sizes: MPEG-4 encoders work on 2x2 chroma blocks and some builds
        # refuse odd sizes; one lost pixel row/column is invisible in an overlay.
        self.size = (w - w % 2, h - h % 2)
        self.path = path
        self.writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, self.size)
        self.frames = 0

    @property
    def ok(self) -> bool:
        return self.writer.isOpened()

    def write(self, rgb: np.ndarray) -> None:
        w, h = self.size
        self.writer.write(cv2.cvtColor(np.ascontiguousarray(rgb[:h, :w]), cv2.COLOR_RGB2BGR))
        self.frames += 1

    def close(self) -> None:
        self.writer.release()


class _H264Writer:
    """Streams frames to an H.264 MP4 through imageio-ffmpeg's FFmpeg binary."""

    codec = "h264"

    def __init__(self, path: Path, fps: float, size: tuple[int, int]):
        w, h = size
        self.size = (w - w % 2, h - h % 2)  # yuv420p needs even sizes
        self.path = path
        self.frames = 0
        self._gen = None
        try:
            import imageio_ffmpeg

            self._gen = imageio_ffmpeg.write_frames(
                str(path), self.size, fps=float(fps), codec="libx264", pix_fmt_in="rgb24",
                pix_fmt_out="yuv420p", quality=None, macro_block_size=1,
                output_params=["-crf", "23", "-preset", "veryfast", "-movflags", "+faststart"],
                # FFmpeg writes its messages straight to our stderr (imageio-ffmpeg passes no
                # pipe for it): a full disk would print six FFmpeg lines before our one
                # 'error:' line. write_video checks the file instead (_finished_mp4).
                ffmpeg_log_level="quiet",
            )  # fmt: skip
            with warnings.catch_warnings():
                # JAX warns at any fork; subprocess forks and at once execs FFmpeg in C, so no
                # Python (and no JAX thread state) runs in the child.
                warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
                self._gen.send(None)  # starts FFmpeg
        except (ImportError, OSError, RuntimeError):  # no wheel, or its binary does not run
            self._gen = None

    @property
    def ok(self) -> bool:
        return self._gen is not None

    def write(self, rgb: np.ndarray) -> None:
        w, h = self.size
        self._gen.send(np.ascontiguousarray(rgb[:h, :w], dtype=np.uint8))
        self.frames += 1

    def close(self) -> None:
        if self._gen is not None:
            self._gen.close()


def _finished_mp4(path: Path) -> bool:
    """Whether ``path`` is an MP4 whose writer finished: its top-level boxes are whole and one
    is the index (``moov``), which both writers add last (FFmpeg then moves it to the front).

    Neither writer reports a failure: FFmpeg exits with an error that imageio-ffmpeg does not
    check, OpenCV's ``VideoWriter.write`` returns nothing. A disk that fills up mid-video left
    a file cut short, without an index, that no player opens, in an output folder that
    otherwise looked complete. Reads only the box headers (16 bytes per box).
    """
    size = path.stat().st_size
    found, pos = False, 0
    with open(path, "rb") as f:
        while pos + 8 <= size:
            f.seek(pos)
            length, kind = struct.unpack(">I4s", f.read(8))
            if length == 1:  # 64-bit size after the type
                length = struct.unpack(">Q", f.read(8))[0]
            elif length == 0:  # the box runs to the end of the file
                length = size - pos
            if length < 8 or pos + length > size:
                return False
            found |= kind == b"moov"
            pos += length
    return found and pos == size


def _video_error(path: Path, codec: str) -> OSError:
    """The error for a video its writer did not finish (see :func:`_finished_mp4`)."""
    # The writers do not say why. A disk with (almost) nothing left is the usual reason, and
    # the one a user can act on: say so in the OS's own words.
    if shutil.disk_usage(path.parent).free < 1 << 20:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    return OSError(
        errno.EIO, f"the {codec} video writer stopped before finishing the file", str(path)
    )


def video_codec(path: str | os.PathLike[str]) -> str | None:
    """The codec of an MP4's video track as its four-character code (``"avc1"`` for H.264,
    ``"mp4v"`` for MPEG-4 Part 2), read from the file's sample description; None if none."""
    data = Path(path).read_bytes()
    i = data.find(b"stsd")
    if i < 0 or len(data) < i + 20:
        return None
    # stsd: size(4) 'stsd' version/flags(4) entry count(4), then entry: size(4) format(4).
    return data[i + 16 : i + 20].decode("ascii", "replace")


def write_video(
    stem: str | os.PathLike[str],
    frames: Iterable[np.ndarray],
    *,
    fps: float,
    size: tuple[int, int],
    formats: Sequence[str] = ("mp4", "gif"),
) -> Path:
    """Write RGB frames as ``<stem>.mp4`` (H.264, else mp4v), or ``<stem>.gif`` where no MP4
    writer opens.

    The file is written in place (not atomically): call this inside a folder that is itself
    written atomically (:func:`posetrack.io.atomic_dir`), as :func:`save_results` does.

    Args:
        stem: output path without the suffix.
        frames: ``uint8 (H, W, 3)`` RGB images, all of ``size``; consumed once, streamed for
            MP4.
        fps: frames per second.
        size: ``(width, height)`` of the frames, pixels.
        formats: formats to try, in order (``"mp4"``, ``"gif"``).

    Returns:
        The file written.

    Raises:
        OSError: no format could be written, or the MP4 writer did not finish the file (a
            full disk: ``ENOSPC``); a cut-short file is never returned.
    """
    stem = Path(stem)
    w, h = size
    if "mp4" in formats:
        path = stem.with_suffix(".mp4")
        for kind in (_H264Writer, _Mp4Writer):
            writer = kind(path, fps, size)
            if writer.ok:
                try:
                    for frame in frames:
                        writer.write(frame)
                finally:
                    writer.close()
                if writer.frames and not _finished_mp4(path):
                    error = _video_error(path, writer.codec)
                    path.unlink(missing_ok=True)
                    raise error
                return path
            writer.close()
            path.unlink(missing_ok=True)
    if "gif" in formats:
        factor = min(1.0, GIF_MAX_WIDTH / w)
        small = (max(1, round(w * factor)), max(1, round(h * factor)))
        images = [
            frame if factor == 1.0 else cv2.resize(frame, small, interpolation=cv2.INTER_AREA)
            for frame in frames
        ]
        path = stem.with_suffix(".gif")
        write_gif(path, images, fps=fps)
        return path
    raise OSError(f"{stem}: no video writer available for formats {tuple(formats)}")


def write_overlay(
    stem: str | os.PathLike[str],
    *,
    keypoints3d: np.ndarray,
    status: np.ndarray,
    delta: np.ndarray,
    frame_ids: np.ndarray,
    intrinsics: Intrinsics,
    fps: float,
    rgb: Sequence[np.ndarray] | None = None,
    depth: Sequence[np.ndarray] | None = None,
    depth_scale: float = 1000.0,
    detections: tuple[np.ndarray, np.ndarray] | None = None,
    panel: str | None = "side",
    floor: np.ndarray | None = None,
    progress: bool = False,
    formats: Sequence[str] = ("mp4", "gif"),
) -> Path:
    """Render the overlay of a tracked sequence to ``<stem>.mp4`` (or ``.gif``).

    Each video frame is the image with the skeleton drawn on it and, with ``panel``, a
    :class:`~posetrack.app._panel.SkeletonPanel` view on its right: as high as the image,
    as wide as high (plus one column where that keeps the frame width even, as ``yuv420p``
    needs).

    Args:
        stem: output path without the suffix.
        keypoints3d: ``(T, 18, 3)`` metres, camera frame, NaN = not estimated.
        status: ``(T,)`` status codes (0 tracked, 1 lost, 2 no observation).
        delta: ``(T,)`` Delta per frame (NaN = not computed).
        frame_ids: ``(T,)`` frame numbers for the labels.
        intrinsics: camera of the images (colour registered to depth).
        fps: frames per second of the video.
        rgb: ``T`` colour images ``uint8 (H, W, 3)``; preferred background.
        depth: ``T`` depth images, float metres or ``uint16`` in units of ``1/depth_scale`` m;
            used (colourised, near = bright) when ``rgb`` is None.
        depth_scale: units per metre of ``uint16`` depth.
        detections: optional ``((T, 18, 2) pixels, (T, 18) confidence)`` 2D keypoints.
        panel: ``"side"`` (default) or ``"top"``: the 3D view drawn beside the image; None:
            the image alone.
        floor: ``(4,)`` floor plane ``(nx, ny, nz, d)`` (``TrackResult.floor``), drawn in the
            side view and giving it its up direction; None = unknown.
        progress: show a progress bar on stderr.
        formats: see :func:`write_video`.

    Returns:
        The video file written.

    Raises:
        ValueError: no frames to draw on, an unknown ``panel``.
    """
    if rgb is None and depth is None:
        raise ValueError("write_overlay: give rgb or depth frames to draw on")
    if panel is not None and panel not in PANELS:
        raise ValueError(f"write_overlay: panel must be one of {PANELS} or None, got {panel!r}")
    T = len(keypoints3d)
    w, h = intrinsics.width, intrinsics.height
    side = None
    if panel is not None:
        side = SkeletonPanel(
            keypoints3d, status, kind=panel, height=h, width=h + (w + h) % 2, floor=floor,
            fps=fps,
        )  # fmt: skip

    def to_metres(d):
        d = np.asarray(d)
        return d.astype(np.float32) / np.float32(depth_scale) if d.dtype == np.uint16 else d

    near = far = None
    if rgb is None:
        near, far = depth_range(_Lazy(depth, to_metres))

    def frames():
        for t in Progress(range(T), "overlay", enabled=progress):
            if rgb is not None:
                image = np.asarray(rgb[t], dtype=np.uint8)
            else:
                image = colorize_depth(to_metres(depth[t]), near=near, far=far, gray=True)
            drawn = overlay_frame(
                image, keypoints3d[t], intrinsics, status=int(status[t]),
                delta=float(delta[t]), frame_id=int(frame_ids[t]),
                detections=None if detections is None else (detections[0][t], detections[1][t]),
            )  # fmt: skip
            yield drawn if side is None else np.concatenate([drawn[:h, :w], side.render(t)], axis=1)

    width = w if side is None else w + side.width
    return write_video(stem, frames(), fps=fps, size=(width, h), formats=formats)


class _Lazy(Sequence[np.ndarray]):
    """A sequence view that applies ``fn`` on indexing (keeps depth on disk)."""

    def __init__(self, items: Sequence, fn):
        self.items, self.fn = items, fn

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, t):  # type: ignore[override]
        return self.fn(self.items[t])
