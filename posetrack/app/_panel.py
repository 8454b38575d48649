"""A 3D view of the skeleton over time: the second panel of the overlay video.

The overlay shows the skeleton projected into the camera image, where depth is invisible: a
person walking towards the camera and one standing still look alike. This panel looks at the
same keypoints from the side (horizontal: depth, vertical: height) or from above (horizontal:
the camera's x, vertical: depth, far at the top), orthographically, at one fixed metric scale
for the whole clip, with:

* the current skeleton in the status colour (:data:`~posetrack.app._viz.STATUS_COLORS`);
* fading trails of the last ``trail_s`` seconds of the pelvis (yellow) and of the wrists and
  ankles (fainter), so motion over time is visible;
* in the side view, the floor line when the tracker found a floor plane (``TrackResult.floor``);
* a metric grid with labelled ticks (every 0.5 m where that leaves room for the labels), the
  view's name and its axes.

Axes. With a floor plane the panel works in the floor frame of :func:`posetrack.floor_frame`
placed under the camera (y up = the floor's normal, height 0 = the floor; depth = the camera's
viewing direction laid onto the floor, 0 = under the camera). Without one it assumes a level
camera: up = the camera's -y, height 0 = the camera's height, depth = the camera's z.

Cost: the scale, the projected keypoints of every frame and the static background (grid, ticks,
labels, floor) are computed once; a frame copies the background and draws the trails' short
segments (5 trails of 45 at 30 fps) and the skeleton: about 0.4 ms at 240 px (README). NumPy
and OpenCV only, no JAX.
"""

from __future__ import annotations

import cv2
import numpy as np

from .._world import WorldFrame, floor_frame
from ._viz import STATUS_COLORS, YELLOW, draw_skeleton

PANELS = ("side", "top")
"""The views :class:`SkeletonPanel` draws (``posetrack track --video-panel``)."""

BACKGROUND = (24, 26, 30)
GRID = (58, 62, 70)
TEXT = (200, 200, 200)
FLOOR = (196, 150, 90)
"""Panel colours (RGB): background, grid lines, labels, the floor line."""

PELVIS_TRAIL = YELLOW
LIMB_TRAIL = (150, 160, 190)
TRAIL_JOINTS = (4, 7, 10, 13)
"""COCO-18 keypoints whose trails are drawn besides the pelvis': the wrists and the ankles."""

TICK_STEPS = (0.5, 1.0, 2.0, 5.0, 10.0)
"""Grid spacings tried (metres), the first that leaves room for the tick labels is used."""

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_LEVEL = np.diag([1.0, -1.0, -1.0])  # camera -> a level y-up frame, z towards the camera


def pelvis(keypoints3d: np.ndarray) -> np.ndarray:
    """``(..., 3)`` the middle of the hips (COCO-18 8 and 11) of ``(..., 18, 3)`` keypoints;
    NaN where either hip is."""
    kp = np.asarray(keypoints3d, dtype=np.float64)
    return 0.5 * (kp[..., 8, :] + kp[..., 11, :])


class SkeletonPanel:
    """The side or top view of a tracked clip, one image per frame (module docstring).

    Built once per clip: the metric scale is fixed from the 1st-99th percentiles of all
    frames' finite keypoints (plus the floor in the side view), so the view does not jump from
    frame to frame, and a stray keypoint does not shrink everything.

    Example::

        panel = SkeletonPanel(result.keypoints3d, result.status, floor=result.floor)
        image = panel.render(12)  # uint8 (panel.height, panel.width, 3) RGB

    Attributes:
        kind: ``"side"`` or ``"top"``.
        width, height: panel size, pixels.
        scale: pixels per metre, on both axes, for every frame.
        frame: camera -> the panel's metric frame (y up, z towards the camera).
        has_floor: a floor plane was given (the side view draws its line at height 0).
    """

    def __init__(
        self,
        keypoints3d: np.ndarray,
        status: np.ndarray | None = None,
        *,
        kind: str = "side",
        height: int = 240,
        width: int | None = None,
        floor: np.ndarray | None = None,
        fps: float = 30.0,
        trail_s: float = 1.5,
    ):
        """Fix the view of a clip.

        Args:
            keypoints3d: ``(T, 18, 3)`` COCO-18 keypoints, metres, camera frame (x right,
                y down, z forward); NaN = not estimated.
            status: ``(T,)`` status codes (0 tracked, 1 lost, 2 no observation) giving the
                skeleton's colour; default all tracked.
            kind: ``"side"`` (depth across, height up) or ``"top"`` (camera x across, depth up).
            height: panel height, pixels (the overlay uses the image's).
            width: panel width, pixels; default ``height``.
            floor: ``(4,)`` floor plane ``(nx, ny, nz, d)``, camera frame, ``n @ p + d`` =
                height above the floor (``TrackResult.floor``); None (or the tracker's
                ``NO_FLOOR``) = unknown: a level camera is assumed and no floor is drawn.
            fps: frames per second (sets how many past frames the trails hold).
            trail_s: length of the trails, seconds (0: none).

        Raises:
            ValueError: an unknown ``kind``, a bad shape, a panel under 64 pixels, a
                non-positive ``fps``.
        """
        kp = np.asarray(keypoints3d, dtype=np.float64)
        if kp.ndim != 3 or kp.shape[1:] != (18, 3):
            raise ValueError(f"SkeletonPanel: keypoints3d must be (T, 18, 3), got {kp.shape}")
        if kind not in PANELS:
            raise ValueError(f"SkeletonPanel: kind must be one of {PANELS}, got {kind!r}")
        width = height if width is None else width
        if min(int(height), int(width)) < 64:
            raise ValueError(f"SkeletonPanel: panel too small ({width}x{height} px, min 64)")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"SkeletonPanel: fps must be positive, got {fps!r}")
        T = len(kp)
        self.status = np.zeros(T, int) if status is None else np.asarray(status, int)
        if self.status.shape != (T,):
            raise ValueError(f"SkeletonPanel: status must be ({T},), got {self.status.shape}")
        self.kind, self.width, self.height = kind, int(width), int(height)
        self.frame, self.has_floor = _view_frame(floor)
        self.trail = max(0, round(float(trail_s) * float(fps)))

        # Layout: a rotated y-axis name and the tick labels on the left, tick labels and the
        # x-axis name below, the title above.
        self.font = max(0.33, self.height / 700)
        th = cv2.getTextSize("0", _FONT, self.font, 1)[0][1]
        tw = cv2.getTextSize("-0.5", _FONT, self.font, 1)[0][0]
        self.thickness = max(1, round(self.height / 240))
        self.box = (  # plot area (left, top, right, bottom), pixels
            2 * th + 8 + tw, 2 * th + 6, self.width - 6, self.height - (3 * th + 14)
        )  # fmt: skip

        # One scale for the clip, from the robust extent of every frame's keypoints.
        ab = self.to_view(kp.reshape(-1, 3))
        ab = ab[np.isfinite(ab).all(axis=-1)]
        if len(ab):
            lo, hi = np.percentile(ab, [1, 99], axis=0)
        elif kind == "side":  # nothing estimated: a person-sized box 1-4 m away
            lo, hi = np.array([1.0, 0.0 if self.has_floor else -1.0]), np.array([4.0, 1.0])
        else:
            lo, hi = np.array([-1.5, 1.0]), np.array([1.5, 4.0])
        if kind == "side" and self.has_floor:
            lo[1], hi[1] = min(lo[1], 0.0), max(hi[1], 0.0)
        lo, hi = lo - 0.2, hi + 0.2
        grow = np.maximum(1.0 - (hi - lo), 0.0) / 2  # at least 1 m on each axis
        lo, hi = lo - grow, hi + grow
        left, top, right, bottom = self.box
        self.scale = float(min((right - left) / (hi[0] - lo[0]), (bottom - top) / (hi[1] - lo[1])))
        # Centre horizontally; the side view stands on the bottom edge, the top view is centred.
        a0 = 0.5 * (left + right) - self.scale * 0.5 * (lo[0] + hi[0])
        if kind == "side":
            b0 = bottom + self.scale * lo[1]
        else:
            b0 = 0.5 * (top + bottom) + self.scale * 0.5 * (lo[1] + hi[1])
        self._origin = np.array([a0, b0])  # pixel of view coordinates (0, 0)

        self.uv, self.valid = self.project(kp)  # (T, 18, 2), (T, 18)
        self.pelvis_uv, self.pelvis_valid = self.project(pelvis(kp))  # (T, 2), (T,)
        # Drawing needs int pixels, and the trails' colours by age: both once, not per frame.
        self._pts = _int_pixels(self.uv, self.valid)
        self._pelvis_pts = _int_pixels(self.pelvis_uv, self.pelvis_valid)
        self._limb_fade = _fade(LIMB_TRAIL, 0.5, self.trail)
        self._pelvis_fade = _fade(PELVIS_TRAIL, 0.9, self.trail)
        self.background = self._draw_background()

    def to_view(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3)`` camera-frame points -> ``(..., 2)`` metric view coordinates ``(across,
        up)``: side ``(depth, height)``, top ``(x, depth)``, metres (NaN stays NaN)."""
        w = self.frame.points(points)
        if self.kind == "side":
            return np.stack([-w[..., 2], w[..., 1]], axis=-1)
        return np.stack([w[..., 0], -w[..., 2]], axis=-1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where camera-frame points are drawn in the panel.

        Args:
            points: ``(..., 3)`` camera frame, metres; NaN = absent.

        Returns:
            ``(uv (..., 2) pixels, valid (...,) bool)``: valid = finite.
        """
        ab = self.to_view(points)
        uv = self._origin + self.scale * ab * np.array([1.0, -1.0])
        return uv, np.isfinite(uv).all(axis=-1)

    def pixel_of(self, across: float, up: float) -> tuple[float, float]:
        """The pixel ``(u, v)`` of view coordinates in metres (:meth:`to_view`)."""
        u, v = self._origin + self.scale * np.array([across, -up])
        return float(u), float(v)

    @property
    def axis_names(self) -> tuple[str, str]:
        """Names of the horizontal and vertical axes, with units."""
        if self.kind == "side":
            return "depth (m)", "height (m)" if self.has_floor else "up from camera (m)"
        return "x (m)", "depth (m)"

    def _draw_background(self) -> np.ndarray:
        img = np.empty((self.height, self.width, 3), np.uint8)
        img[:] = BACKGROUND
        left, top, right, bottom = self.box
        fs, lt = self.font, cv2.LINE_AA
        th = cv2.getTextSize("0", _FONT, fs, 1)[0][1]
        label_w = cv2.getTextSize("-10.5", _FONT, fs, 1)[0][0]
        step = next(
            (s for s in TICK_STEPS if s * self.scale >= max(2 * th + 6, label_w + 4)),
            TICK_STEPS[-1],
        )
        (a_lo, b_hi), (a_hi, b_lo) = (
            (np.array([left, top]) - self._origin) / self.scale * [1, -1],
            (np.array([right, bottom]) - self._origin) / self.scale * [1, -1],
        )
        for a in np.arange(np.ceil(a_lo / step), np.floor(a_hi / step) + 1) * step:
            u = round(self.pixel_of(a, 0.0)[0])
            cv2.line(img, (u, top), (u, bottom), GRID, 1)
            text = f"{round(a, 6) + 0.0:g}"  # + 0.0: no "-0"
            w = cv2.getTextSize(text, _FONT, fs, 1)[0][0]
            cv2.putText(img, text, (u - w // 2, bottom + th + 5), _FONT, fs, TEXT, 1, lt)
        for b in np.arange(np.ceil(b_lo / step), np.floor(b_hi / step) + 1) * step:
            v = round(self.pixel_of(0.0, b)[1])
            cv2.line(img, (left, v), (right, v), GRID, 1)
            text = f"{round(b, 6) + 0.0:g}"
            w = cv2.getTextSize(text, _FONT, fs, 1)[0][0]
            cv2.putText(img, text, (left - w - 4, v + th // 2), _FONT, fs, TEXT, 1, lt)
        cv2.rectangle(img, (left, top), (right, bottom), GRID, 1)
        if self.kind == "side" and self.has_floor:
            v = round(self.pixel_of(0.0, 0.0)[1])
            if top <= v <= bottom:
                cv2.line(img, (left, v), (right, v), FLOOR, self.thickness + 1, lt)
                cv2.putText(img, "floor", (right - 4 * th - 8, v - 4), _FONT, fs, FLOOR, 1, lt)
        across, up = self.axis_names
        w = cv2.getTextSize(across, _FONT, fs, 1)[0][0]
        cv2.putText(img, across, ((left + right - w) // 2, self.height - 5), _FONT, fs, TEXT, 1, lt)
        cv2.putText(img, f"{self.kind} view", (left, top - 6), _FONT, fs * 1.15, TEXT, 1, lt)
        # The vertical axis name, written horizontally on a strip and turned a quarter; a
        # smaller font where it would not fit beside the plot.
        w = cv2.getTextSize(up, _FONT, fs, 1)[0][0]
        fs_up = fs * min(1.0, (self.height - 4) / (w + 4))
        w = cv2.getTextSize(up, _FONT, fs_up, 1)[0][0]
        strip = np.empty((th + 6, min(w + 4, self.height), 3), np.uint8)
        strip[:] = BACKGROUND
        cv2.putText(strip, up, (2, th + 2), _FONT, fs_up, TEXT, 1, lt)
        strip = np.ascontiguousarray(np.rot90(strip))
        y0 = max(0, min((top + bottom - strip.shape[0]) // 2, self.height - strip.shape[0]))
        img[y0 : y0 + strip.shape[0], 2 : 2 + strip.shape[1]] = strip
        return img

    def render(self, t: int) -> np.ndarray:
        """The panel of frame ``t`` (``0 <= t < T``): ``uint8 (height, width, 3)`` RGB."""
        t = int(t)
        if not 0 <= t < len(self.uv):
            raise ValueError(f"SkeletonPanel.render: frame {t} is outside 0..{len(self.uv) - 1}")
        img = self.background.copy()
        lo = max(0, t - self.trail)
        if t > lo:
            for j in TRAIL_JOINTS:
                _trail(img, self._pts[lo : t + 1, j], self.valid[lo : t + 1, j], self._limb_fade)
            _trail(img, self._pelvis_pts[lo : t + 1], self.pelvis_valid[lo : t + 1],
                   self._pelvis_fade, thickness=self.thickness)  # fmt: skip
        if self.valid[t].any():
            color = STATUS_COLORS[int(self.status[t])]
            img = draw_skeleton(img, self.uv[t], color=color, valid=self.valid[t],
                                thickness=self.thickness)  # fmt: skip
        return img


def _view_frame(floor: np.ndarray | None) -> tuple[WorldFrame, bool]:
    """The panel's metric frame: the floor frame under the camera, else a level camera's."""
    if floor is not None:
        try:
            return floor_frame(np.asarray(floor, np.float64), np.zeros(3)), True
        except ValueError:  # NO_FLOOR, NaN, a degenerate normal: draw without a floor
            pass
    return WorldFrame("camera", _LEVEL, np.zeros(3)), False


def _int_pixels(uv: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Rounded pixels, 0 where not valid, clipped far outside any panel (OpenCV's int range)."""
    return np.round(np.clip(np.where(valid[..., None], uv, 0.0), -1e5, 1e5)).astype(np.int64)


def _fade(color, strength: float, n: int) -> list[tuple[int, int, int]]:
    """Colours of trail segments by age (0 = newest .. n - 1 = oldest): from ``strength`` of
    the way from the background to ``color`` down to the background."""
    bg, c = np.asarray(BACKGROUND, float), np.asarray(color, float)
    alpha = strength * (1.0 - np.arange(n) / max(n, 1))
    return [tuple(int(x) for x in bg + a * (c - bg)) for a in alpha]


def _trail(img, pts, valid, fade, *, thickness=1):
    """Draw a fading polyline (``pts (n, 2)`` int pixels) on ``img``; gaps where a point is
    missing. Plain Python lists: NumPy per segment costs more than the drawing."""
    pts, valid = pts.tolist(), valid.tolist()
    n = len(pts)
    for i in range(1, n):
        if valid[i - 1] and valid[i]:
            cv2.line(img, pts[i - 1], pts[i], fade[n - 1 - i], thickness, cv2.LINE_AA)


def render_panel(
    keypoints3d: np.ndarray,
    t: int,
    *,
    status: np.ndarray | None = None,
    kind: str = "side",
    height: int = 240,
    floor: np.ndarray | None = None,
    fps: float = 30.0,
) -> np.ndarray:
    """The overlay's side (or top) view of frame ``t`` of a clip, as one RGB image.

    The scale is fixed by the whole clip, as in the video. For several frames, build one
    :class:`SkeletonPanel` and call its ``render``.

    Args:
        keypoints3d: ``(T, 18, 3)`` metres, camera frame (``TrackResult.keypoints3d``).
        t: the frame, ``0 <= t < T``.
        status: ``(T,)`` status codes (``TrackResult.status``); default all tracked.
        kind: ``"side"`` or ``"top"``.
        height: pixels (the panel is square).
        floor: floor plane (``TrackResult.floor``) or None.
        fps: frames per second (trail length).

    Returns:
        ``uint8 (height, height, 3)`` RGB.
    """
    panel = SkeletonPanel(keypoints3d, status, kind=kind, height=height, floor=floor, fps=fps)
    return panel.render(t)
