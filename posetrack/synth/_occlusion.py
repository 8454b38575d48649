"""Rectangular occluders removed from the RGB-D stream (the paper's Fig. 4 experiment).

Level ``k`` in 0..4 places ``k`` rectangles over the person, each covering nominally
``area_fraction`` (default 12 %) of the person's bounding box: nominal coverage 0 / 12 / 24 /
36 / 48 % of the box (their union is smaller where rectangles overlap or stick out of the
box). A rectangle appears centred near a random body keypoint and then lives in the box's
normalised coordinates, so it follows the person;
it drifts slowly (<= 0.25 box sizes per second, bouncing inside the box), persists for
1-3 s and then reappears elsewhere with a new size and aspect ratio (1:2.5 .. 2.5:1).
Lifetimes are staggered, so at most one rectangle jumps at a time, and never flickers.
"""

from __future__ import annotations

import numpy as np

MAX_LEVEL = 4


def person_boxes(uv: np.ndarray, pad: float = 0.08) -> np.ndarray:
    """Smoothed person boxes (T, 4) = (u0, v0, u1, v1) from projected body points (T, P, 2).

    Padded by ``pad`` of the box height and smoothed over +-5 frames so that rectangles
    attached to the box move smoothly.
    """
    lo = uv.min(axis=1)
    hi = uv.max(axis=1)
    h = (hi[:, 1] - lo[:, 1])[:, None]
    box = np.concatenate([lo - pad * h, hi + pad * h], axis=1)
    T = box.shape[0]
    k = 5
    out = np.empty_like(box)
    for t in range(T):
        out[t] = box[max(0, t - k) : t + k + 1].mean(axis=0)
    return out


def occluder_rects(rng: np.random.Generator, boxes: np.ndarray, level: int, fps: float, *,
                   area_fraction: float = 0.12, anchors: np.ndarray | None = None
                   ) -> np.ndarray:
    """Occluding rectangles per frame.

    Args:
        rng: randomness.
        boxes: (T, 4) person boxes (u0, v0, u1, v1), px.
        level: 0 (none) .. 4.
        fps: frame rate, Hz (lifetimes and drift are in seconds).
        area_fraction: nominal area of each rectangle as a fraction of the box.
        anchors: optional (T, P, 2) body points (px); a new rectangle is centred near one of
            them (so it covers the body, not the empty corners of the box).

    Returns:
        (T, level, 4) rectangles (u0, v0, u1, v1) in pixels (may extend past the image).
    """
    if not 0 <= level <= MAX_LEVEL:
        raise ValueError(f"occlusion_level must be in 0..{MAX_LEVEL}, got {level}")
    T = boxes.shape[0]
    out = np.zeros((T, level, 4))
    dt = 1.0 / fps
    for r in range(level):
        age = 0.0
        life = -1.0
        # Stagger the first lifetime so rectangles do not all reappear together.
        first = True
        for t in range(T):
            if age >= life:
                c = rng.uniform(0.15, 0.85, size=2)
                if anchors is not None:
                    u0, v0, u1, v1 = boxes[t]
                    a_px = anchors[t, int(rng.integers(anchors.shape[1]))]
                    c = (a_px - [u0, v0]) / np.maximum([u1 - u0, v1 - v0], 1e-6)
                    c = np.clip(c + rng.normal(0.0, 0.08, size=2), 0.1, 0.9)
                ar = np.exp(rng.uniform(np.log(1 / 2.5), np.log(2.5)))
                a = area_fraction * rng.uniform(0.8, 1.2)
                wh = np.array([np.sqrt(a * ar), np.sqrt(a / ar)])
                ang = rng.uniform(0, 2 * np.pi)
                vel = rng.uniform(0.0, 0.25) * np.array([np.cos(ang), np.sin(ang)])
                life = rng.uniform(1.0, 3.0)
                age = rng.uniform(0, life) if first else 0.0
                first = False
            c = c + vel * dt
            for k in range(2):  # bounce inside [0.1, 0.9] of the box
                if c[k] < 0.1 or c[k] > 0.9:
                    vel[k] = -vel[k]
                    c[k] = np.clip(c[k], 0.1, 0.9)
            age += dt
            u0, v0, u1, v1 = boxes[t]
            size = np.array([u1 - u0, v1 - v0])
            centre = np.array([u0, v0]) + c * size
            half = 0.5 * wh * size
            out[t, r] = [*(centre - half), *(centre + half)]
    return out


def rect_mask(rects: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Boolean (H, W) union of rectangles (n, 4) (u0, v0, u1, v1); pixel centres inside."""
    H, W = shape
    m = np.zeros((H, W), dtype=bool)
    for u0, v0, u1, v1 in rects:
        a, b = max(int(np.ceil(u0)), 0), min(int(np.floor(u1)) + 1, W)
        c, d = max(int(np.ceil(v0)), 0), min(int(np.floor(v1)) + 1, H)
        if a < b and c < d:
            m[c:d, a:b] = True
    return m
