"""Exact ray casting of the body and room, and a simple shaded colour rendering.

Analytic ray-surface intersection (no sphere tracing, no meshes):

* ellipsoid: the ray is mapped into the ellipsoid's unit-sphere frame, a quadratic is solved;
* round cone (tapered capsule): the nearest valid root among the two end spheres and the
  truncated cone tangent to both (valid between the tangent circles);
* planes (floor, walls): closed form.

Each primitive is tested only on the pixels of its projected bounding box. One ray per pixel
centre: depth is the z coordinate of the nearest hit (rays have z = 1), like a range sensor.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ._scene import BODY_LABEL0, LABEL_FLOOR, LABEL_SIDE_WALL, LABEL_WALL, Scene
from ._skeleton import Ellipsoid, RoundCone, Subject


@dataclasses.dataclass
class Render:
    """Noise-free rendering of one frame."""

    depth: np.ndarray
    """(H, W) float32 z (m) of the nearest surface, inf where nothing is hit."""
    label: np.ndarray
    """(H, W) int16: 0 none, 1 floor, 2 back wall, 3 side wall, BODY_LABEL0 + k primitive k."""
    normal: np.ndarray
    """(H, W, 3) float32 unit surface normal (camera frame), facing the camera."""


class Background:
    """Static room rendering, computed once per sequence."""

    def __init__(self, scene: Scene, rays: np.ndarray):
        H, W = rays.shape[:2]
        depth = np.full((H, W), np.inf)
        label = np.zeros((H, W), dtype=np.int16)
        normal = np.zeros((H, W, 3))
        C_world = -scene.R_cam_world.T @ scene.t_cam_world
        for pl in scene.planes:
            n = scene.R_cam_world @ np.asarray(pl.normal)
            c = pl.offset - float(np.asarray(pl.normal) @ C_world)
            den = rays @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(np.abs(den) > 1e-9, c / den, np.inf)
            t = np.where(t > 0, t, np.inf)
            hit = t < depth
            depth[hit] = t[hit]
            label[hit] = pl.label
            normal[hit] = n
        self.depth = depth.astype(np.float32)
        self.label = label
        self.normal = normal.astype(np.float32)
        # World coordinates of the hit points, for floor tiles / wall shading.
        p_cam = rays * np.where(np.isfinite(depth), depth, 0.0)[..., None]
        self.p_world = (p_cam - scene.t_cam_world) @ scene.R_cam_world


def _bbox(centres: np.ndarray, radii: np.ndarray, K: tuple[float, float, float, float],
          W: int, H: int) -> tuple[int, int, int, int] | None:
    """Conservative pixel box of spheres (n, 3), (n,) in the camera frame, or None if empty."""
    fx, fy, cx, cy = K
    z0 = centres[:, 2] - radii
    if np.any(z0 < 0.05):
        return (0, W, 0, H)  # too close to bound: test every pixel
    z1 = centres[:, 2] + radii
    # x/z over the box [x-r, x+r] x [z-r, z+r] is extreme at its corners.
    xs = np.concatenate([(centres[:, 0] - radii) / z0, (centres[:, 0] - radii) / z1,
                         (centres[:, 0] + radii) / z0, (centres[:, 0] + radii) / z1])
    ys = np.concatenate([(centres[:, 1] - radii) / z0, (centres[:, 1] - radii) / z1,
                         (centres[:, 1] + radii) / z0, (centres[:, 1] + radii) / z1])
    u0 = max(int(np.floor(fx * xs.min() + cx)), 0)
    u1 = min(int(np.ceil(fx * xs.max() + cx)) + 1, W)
    v0 = max(int(np.floor(fy * ys.min() + cy)), 0)
    v1 = min(int(np.ceil(fy * ys.max() + cy)) + 1, H)
    if u0 >= u1 or v0 >= v1:
        return None
    return (u0, u1, v0, v1)


def _hit_ellipsoid(r: np.ndarray, c: np.ndarray, R: np.ndarray, radii: np.ndarray
                   ) -> np.ndarray:
    """Nearest hit depth t (inf if none) of rays r (h, w, 3) from the camera centre."""
    o = (R.T @ (-c)) / radii
    d = (r @ R) / radii
    A = np.einsum("hwi,hwi->hw", d, d)
    B = d @ o
    C = o @ o - 1.0
    disc = B * B - A * C
    with np.errstate(invalid="ignore"):
        t = (-B - np.sqrt(disc)) / A
    t = np.where((disc >= 0) & (t > 0), t, np.inf)
    return t


def _normal_ellipsoid(p: np.ndarray, c: np.ndarray, R: np.ndarray, radii: np.ndarray
                      ) -> np.ndarray:
    q = (p - c) @ R
    n = (q / radii**2) @ R.T
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _hit_round_cone(r: np.ndarray, rr: np.ndarray, a: np.ndarray, b: np.ndarray, ra: float,
                    rb: float) -> np.ndarray:
    """Nearest hit of rays r (h, w, 3) (|r|^2 = rr) with the convex hull of two spheres."""
    ab = b - a
    L = float(np.linalg.norm(ab))
    ra_ = r @ a
    rb_ = r @ b

    def sphere(rc: np.ndarray, cc: np.ndarray, rad: float) -> np.ndarray:
        disc = rc * rc - rr * (cc @ cc - rad * rad)
        with np.errstate(invalid="ignore"):
            t = (rc - np.sqrt(disc)) / rr
        return np.where((disc >= 0) & (t > 0), t, np.inf)

    t = np.minimum(sphere(ra_, a, ra), sphere(rb_, b, rb))
    if L <= abs(ra - rb) + 1e-9:
        return t  # one sphere contains the other
    w = ab / L
    sin_a = (ra - rb) / L
    cos_a = np.sqrt(1.0 - sin_a * sin_a)
    tau = sin_a / cos_a
    k0 = ra / cos_a
    sd = r @ w
    so = -float(a @ w)
    g = 1.0 + tau * tau
    A = rr - g * sd * sd
    Bh = -ra_ - g * so * sd + k0 * tau * sd
    C = float(a @ a) - g * so * so + 2 * k0 * tau * so - k0 * k0
    disc = Bh * Bh - A * C
    s_lo, s_hi = ra * sin_a, L + rb * sin_a
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(disc)
        for sign in (-1.0, 1.0):
            tc = (-Bh + sign * sq) / A
            s = so + tc * sd
            ok = (disc >= 0) & (tc > 0) & (s >= s_lo) & (s <= s_hi) & np.isfinite(tc)
            t = np.where(ok & (tc < t), tc, t)
    return t


def _normal_round_cone(p: np.ndarray, a: np.ndarray, b: np.ndarray, ra: float, rb: float
                       ) -> np.ndarray:
    ab = b - a
    L = float(np.linalg.norm(ab))
    w = ab / max(L, 1e-12)
    sin_a = np.clip((ra - rb) / max(L, 1e-12), -0.999, 0.999)
    cos_a = np.sqrt(1 - sin_a**2)
    q = p - a
    s = q @ w
    radial = q - s[:, None] * w
    radial /= np.maximum(np.linalg.norm(radial, axis=-1, keepdims=True), 1e-12)
    n = radial * cos_a + w * sin_a
    na = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-12)
    qb = p - b
    nb = qb / np.maximum(np.linalg.norm(qb, axis=-1, keepdims=True), 1e-12)
    n = np.where((s < ra * sin_a)[:, None], na, n)
    n = np.where((s > L + rb * sin_a)[:, None], nb, n)
    return n


def primitives_camera(subject: Subject, origins: np.ndarray, rotations: np.ndarray,
                      scene: Scene) -> list[tuple]:
    """Camera-frame parameters of every primitive for one frame.

    ``origins`` (S, 3) and ``rotations`` (S, 3, 3) are world-frame segment poses.
    """
    Rcw = scene.R_cam_world
    o_c = origins @ Rcw.T + scene.t_cam_world
    R_c = np.einsum("ij,sjk->sik", Rcw, rotations)
    out = []
    for prim in subject.primitives:
        o, R = o_c[prim.seg], R_c[prim.seg]
        if isinstance(prim, Ellipsoid):
            c = o + R @ np.asarray(prim.centre)
            out.append(("e", c, R, np.asarray(prim.radii, dtype=np.float64)))
        else:
            assert isinstance(prim, RoundCone)
            out.append(("c", o + R @ np.asarray(prim.a), o + R @ np.asarray(prim.b),
                        float(prim.ra), float(prim.rb)))
    return out


def render_frame(prims: list[tuple], background: Background, rays: np.ndarray,
                 rr: np.ndarray, K: tuple[float, float, float, float]) -> Render:
    """Ray-cast the body primitives over the static background."""
    H, W = rays.shape[:2]
    depth = background.depth.copy()
    label = background.label.copy()
    normal = background.normal.copy()
    for k, pr in enumerate(prims):
        if pr[0] == "e":
            _, c, R, radii = pr
            box = _bbox(c[None], np.array([radii.max()]), K, W, H)
        else:
            _, a, b, ra, rb = pr
            box = _bbox(np.stack([a, b]), np.array([ra, rb]), K, W, H)
        if box is None:
            continue
        u0, u1, v0, v1 = box
        r = rays[v0:v1, u0:u1]
        if pr[0] == "e":
            t = _hit_ellipsoid(r, c, R, radii)
        else:
            t = _hit_round_cone(r, rr[v0:v1, u0:u1], a, b, ra, rb)
        dsub = depth[v0:v1, u0:u1]
        m = t < dsub
        if not m.any():
            continue
        dsub[m] = t[m]
        label[v0:v1, u0:u1][m] = BODY_LABEL0 + k
        p = r[m] * t[m][:, None]
        if pr[0] == "e":
            n = _normal_ellipsoid(p, c, R, radii)
        else:
            n = _normal_round_cone(p, a, b, ra, rb)
        normal[v0:v1, u0:u1][m] = n
    return Render(depth=depth, label=label, normal=normal)


def hair_mask(render: Render, head_label: int, R_cam_head: np.ndarray) -> np.ndarray:
    """Pixels of the head whose surface normal points up or backward in the head frame."""
    hm = render.label == head_label
    out = np.zeros(hm.shape, dtype=bool)
    if hm.any():
        nh = render.normal[hm] @ R_cam_head  # normal in the head frame
        hair = (nh[:, 1] > 0.35) | ((nh[:, 2] < -0.1) & (nh[:, 1] > -0.55))
        hair |= (np.abs(nh[:, 0]) > 0.8) & (nh[:, 1] > 0.0)
        out[hm] = hair
    return out


def shade(render: Render, background: Background, subject: Subject, hair: np.ndarray,
          rng: np.random.Generator, floor_rgb: tuple[int, int, int],
          wall_rgb: tuple[int, int, int], *,
          others: Sequence[tuple[Subject, np.ndarray]] = ()) -> np.ndarray:
    """Simple Lambert-shaded colour image (H, W, 3) uint8, registered to the depth.

    Per-part albedo (skin, shirt, trousers, shoes, hair on the top/back of the head), floor
    tiles, one light above and behind the camera plus ambient, mild sensor noise.

    Args:
        render: the frame; body labels ``BODY_LABEL0 + k`` number the primitives of
            ``subject`` first, then those of each of ``others`` in turn.
        background: the static room.
        subject: the (main) person; ``hair``: (H, W) bool, its hair pixels.
        rng: sensor noise.
        floor_rgb, wall_rgb: room albedo.
        others: further people rendered in the same frame, (subject, hair mask) each.
    """
    people = [(subject, hair), *others]
    n = sum(len(s.primitives) for s, _ in people)
    lut = np.zeros((BODY_LABEL0 + n, 3), dtype=np.float32)
    lut[LABEL_FLOOR] = floor_rgb
    lut[LABEL_WALL] = wall_rgb
    lut[LABEL_SIDE_WALL] = np.asarray(wall_rgb) * 0.92
    k = BODY_LABEL0
    for s, _ in people:
        for prim in s.primitives:
            lut[k] = s.colors[prim.group]
            k += 1
    alb = lut[render.label]
    floor = render.label == LABEL_FLOOR
    if floor.any():
        pw = background.p_world[floor]
        tiles = (np.floor(pw[:, 0] / 0.5) + np.floor(pw[:, 2] / 0.5)) % 2
        alb[floor] *= (0.9 + 0.1 * tiles)[:, None]
    for s, h in people:
        if h.any():
            alb[h] = s.colors["hair"]
    light = np.array([0.25, -0.85, -0.6], dtype=np.float32)
    light /= np.linalg.norm(light)
    lam = np.clip(render.normal @ light, 0.0, 1.0)
    img = alb * (0.38 + 0.62 * lam)[..., None]
    img += 2.0 * rng.standard_normal(img.shape, dtype=np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)
