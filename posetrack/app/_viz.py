"""Pictures: colourised depth with skeletons drawn on it, contact sheets and animated GIFs.

OpenCV only (already a dependency); everything returns or writes uint8 RGB images.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

#: COCO-18 limbs (keypoint index pairs) drawn for a skeleton.
LIMBS = (
    (1, 2), (2, 3), (3, 4), (1, 5), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11),
    (11, 12), (12, 13), (8, 11), (1, 0), (0, 14), (14, 16), (0, 15), (15, 17),
)  # fmt: skip

GREEN = (40, 220, 60)
RED = (255, 40, 90)
CYAN = (40, 230, 255)
YELLOW = (250, 210, 40)
WHITE = (255, 255, 255)
GREY = (170, 170, 170)
STATUS_COLORS = (GREEN, RED, GREY)
"""Skeleton colour (RGB) per tracker status code: tracked, lost, no observation."""


def colorize_depth(
    depth_m: np.ndarray, *, near: float | None = None, far: float | None = None, gray: bool = False
) -> np.ndarray:
    """(H, W) depth in metres -> (H, W, 3) uint8 RGB (TURBO colour map, or near = bright grey
    with ``gray=True`` so coloured skeletons stand out; invalid = black)."""
    d = np.asarray(depth_m, dtype=np.float32)
    valid = np.isfinite(d) & (d > 0)
    if near is None or far is None:
        vals = d[valid]
        lo, hi = np.percentile(vals, [2, 98]) if vals.size else (0.5, 5.0)
        near = lo if near is None else near
        far = max(hi, lo + 0.1) if far is None else far
    x = np.clip((d - near) / max(far - near, 1e-6), 0, 1)
    if gray:
        g = (60 + (1 - x) * 170).astype(np.uint8)
        img = np.stack([g, g, g], axis=-1)
    else:
        img = cv2.applyColorMap(((1 - x) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    img[~valid] = 0
    return img


def draw_skeleton(
    image: np.ndarray,
    uv: np.ndarray,
    *,
    color: tuple[int, int, int] = GREEN,
    valid: np.ndarray | None = None,
    thickness: int = 2,
) -> np.ndarray:
    """Draw a COCO-18 skeleton (pixel coordinates (18, 2)) on a copy of ``image`` (RGB)."""
    out = np.ascontiguousarray(image.copy())
    uv = np.asarray(uv, dtype=np.float64)
    ok = np.all(np.isfinite(uv), axis=-1)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    limit = 4 * max(out.shape[:2])
    ok &= np.all(np.abs(uv) < limit, axis=-1)
    pts = np.round(np.where(ok[:, None], uv, 0)).astype(int)
    for a, b in LIMBS:
        if ok[a] and ok[b]:
            cv2.line(out, tuple(pts[a]), tuple(pts[b]), color, thickness, cv2.LINE_AA)
    for i in np.flatnonzero(ok):
        cv2.circle(out, tuple(pts[i]), thickness + 1, color, -1, cv2.LINE_AA)
    return out


def put_label(
    image: np.ndarray, text: str, *, color=WHITE, scale: float | None = None
) -> np.ndarray:
    """Write ``text`` in the top-left corner on a dark band."""
    out = image.copy()
    scale = scale or max(0.35, out.shape[1] / 900)
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    cv2.rectangle(out, (0, 0), (w + 8, h + base + 6), (0, 0, 0), -1)
    cv2.putText(out, text, (4, h + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, color, 1, cv2.LINE_AA)
    return out


def contact_sheet(images: Sequence[np.ndarray], *, columns: int = 4, pad: int = 4) -> np.ndarray:
    """Tile equally sized RGB images into one picture, row-major."""
    if not images:
        raise ValueError("contact_sheet: no images")
    h, w = images[0].shape[:2]
    rows = (len(images) + columns - 1) // columns
    sheet = np.full((rows * (h + pad) + pad, columns * (w + pad) + pad, 3), 24, np.uint8)
    for i, img in enumerate(images):
        r, c = divmod(i, columns)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        sheet[y : y + h, x : x + w] = img
    return sheet


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write an RGB uint8 image as PNG (atomically: temp file, then rename)."""
    from ..io import atomic_write_bytes

    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f"could not encode PNG for {path}")
    atomic_write_bytes(Path(path), buf.tobytes())


def write_gif(path: str | Path, images: Sequence[np.ndarray], *, fps: float = 10.0) -> None:
    """Write an animated GIF (looping) with imageio, atomically."""
    import imageio.v3 as iio

    from ..io import atomic_write_bytes

    data = iio.imwrite("<bytes>", np.stack(images), extension=".gif", duration=1000.0 / fps, loop=0)
    atomic_write_bytes(Path(path), data)


def crop_box(
    uv: np.ndarray, shape: tuple[int, int], *, margin: float = 0.15, aspect: float = 0.75
) -> tuple[int, int, int, int]:
    """A (top, bottom, left, right) crop around the finite pixel points ``uv`` (N, 2) with a
    relative margin and a fixed width/height ``aspect``, clipped to the image ``shape`` (H, W)."""
    H, W = shape
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        return 0, H, 0, W
    (u0, v0), (u1, v1) = pts.min(0), pts.max(0)
    h = (v1 - v0) * (1 + 2 * margin) + 20
    w = max((u1 - u0) * (1 + 2 * margin) + 20, h * aspect)
    h = max(h, w / aspect)
    cu, cv = (u0 + u1) / 2, (v0 + v1) / 2
    top, left = int(max(0, cv - h / 2)), int(max(0, cu - w / 2))
    return top, int(min(H, top + h)), left, int(min(W, left + w))


PALETTE = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
)
"""Ten distinguishable line colours (RGB), in series order; :func:`line_plot` draws the
series past the tenth dashed, with hollow markers."""


def _line(
    img: np.ndarray, a, b, color, thickness: int, dash: int = 0, line_type: int = cv2.LINE_AA
) -> None:
    """A segment from pixel ``a`` to ``b``: solid, or with ``dash`` > 0 dashed (dashes and gaps
    of ``dash`` pixels, always antialiased)."""
    if dash <= 0:
        cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), color, thickness, line_type)
        return
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(int(np.linalg.norm(b - a) // dash), 1)
    for i in range(0, n, 2):
        p = a + (b - a) * i / n
        q = a + (b - a) * min(i + 1, n) / n
        cv2.line(img, tuple(map(int, p)), tuple(map(int, q)), color, thickness, cv2.LINE_AA)


def line_plot(
    series: dict[str, tuple[Sequence[float], Sequence[float]]],
    *,
    title: str = "",
    xlabel: str = "",
    ylabel: str = "",
    size: tuple[int, int] = (720, 480),
    ylim: tuple[float, float] | None = None,
) -> np.ndarray:
    """A simple line chart (RGB uint8) with axes, ticks, markers and a legend, drawn with OpenCV
    so figures need no plotting library. ``series`` maps a label to (x values, y values). The
    legend sits right of the plot area (``size`` is the plot's; the image grows to fit it)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    legend_w = 45 + max(
        (cv2.getTextSize(label, font, 0.45, 1)[0][0] for label in series), default=0
    )
    W, H = size[0] + legend_w, size[1]
    img = np.full((H, W, 3), 255, np.uint8)
    left, right, top, bottom = 70, 20 + legend_w, 40, 55
    xs = np.concatenate([np.asarray(x, float) for x, _ in series.values()])
    ys = np.concatenate([np.asarray(y, float) for _, y in series.values()])
    ys = ys[np.isfinite(ys)]
    x0, x1 = float(xs.min()), float(xs.max())
    if x1 == x0:
        x1 = x0 + 1
    y0, y1 = (
        ylim
        if ylim
        else (
            min(0.0, float(ys.min())) if len(ys) else 0.0,
            float(ys.max()) * 1.08 if len(ys) else 1.0,
        )
    )
    if y1 == y0:
        y1 = y0 + 1

    def px(x, y):
        return (
            int(left + (x - x0) / (x1 - x0) * (W - left - right)),
            int(H - bottom - (y - y0) / (y1 - y0) * (H - top - bottom)),
        )

    cv2.rectangle(img, px(x0, y0), px(x1, y1), (0, 0, 0), 1)
    for v in np.linspace(y0, y1, 6):
        p = px(x0, v)
        cv2.line(img, p, (W - right, p[1]), (225, 225, 225), 1)
        cv2.putText(img, f"{v:.3g}", (5, p[1] + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    xt = np.unique(xs) if len(np.unique(xs)) <= 12 else np.linspace(x0, x1, 7)
    for v in xt:
        p = px(v, y0)
        cv2.line(img, p, (p[0], p[1] + 4), (0, 0, 0), 1)
        cv2.putText(img, f"{v:.3g}", (p[0] - 10, p[1] + 18), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 25), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(
        img, xlabel, (W // 2 - 4 * len(xlabel), H - 12), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA
    )
    cv2.putText(img, ylabel, (5, top - 8), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (label, (x, y)) in enumerate(series.items()):
        color = PALETTE[k % len(PALETTE)]
        # Past the palette's ten colours, a series repeats a colour: dashed, hollow markers.
        dashed = k >= len(PALETTE)
        pts = [px(a, b) for a, b in zip(x, y) if np.isfinite(b)]
        for a, b in zip(pts[:-1], pts[1:]):
            _line(img, a, b, color, 2, dash=8 if dashed else 0)
        if len(pts) <= 20:
            for p in pts:
                cv2.circle(img, p, 4, color, 2 if dashed else -1, cv2.LINE_AA)
        ly = top + 12 + 20 * k
        lx = W - legend_w + 5
        _line(img, (lx, ly), (lx + 25, ly), color, 3, dash=5 if dashed else 0, line_type=cv2.LINE_8)
        cv2.putText(img, label, (lx + 32, ly + 5), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return img
