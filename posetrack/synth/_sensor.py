"""Kinect-v1-like depth sensor model applied to a noise-free depth rendering.

Effects, in the order applied (all metres inside, uint16 millimetres out, 0 = invalid):

1. Projector shadow: the IR projector sits ``projector_baseline`` to the side of the IR camera
   (+x, Kinect v1 layout), so background next to a foreground object that the projector
   cannot light gets no depth: an invalid band on the left of people, ~f*b*(1/z_fg - 1/z_bg)
   pixels wide (about 8 px for a person at 2.5 m in front of a wall at 5 m, at 640x480).
   Computed exactly per image row (rectified geometry): a pixel is shadowed when some pixel
   to its right has a smaller projector coordinate ``u - f*b/z``.
2. Grazing-angle dropouts: where the surface is seen at more than ~78 deg incidence
   (silhouettes of limbs, far floor) depth drops out with probability rising to
   ``grazing_dropout``, in small clusters.
3. Axial noise: Gaussian with sigma_z = a + b (z - z0)^2 (Nguyen, Izadi & Lovell 2012:
   a = 1.2 mm, b = 1.9 mm/m^2, z0 = 0.4 m), part white and part spatially correlated
   (``noise_correlated`` of the variance, blob size ``noise_corr_px``).
4. Depth edges: at depth discontinuities (jump > 4 cm + 3 % of z) boundary pixels take a
   neighbour's depth (lateral noise, jagged silhouettes) or drop out in clusters.
5. Random holes: ~``holes_per_frame`` elliptic blobs (radius 2-7 px at 640x480) per frame,
   plus dropouts on dark hair (top/back of the head).
6. Quantisation in disparity: Kinect v1 measures disparity in 1/8 pixel with f = 580 px and
   b = 7.5 cm, so depth steps grow as z^2 / (8 * 580 * 0.075) (2.9 mm at 1 m, 2.6 cm at 3 m).
7. Range: 0 outside [min_range, max_range]. max_range defaults to 5.5 m so the back wall
   (4.5-5 m) is measured, as a Kinect v1 in "default" mode does beyond its nominal 4 m.

Noise fields and dropouts are independent from frame to frame (the sensor flickers).
"""

from __future__ import annotations

import dataclasses
import statistics

import cv2
import numpy as np


@dataclasses.dataclass(frozen=True)
class SensorConfig:
    """Parameters of :func:`simulate_sensor`; pixel sizes are for a 640-px-wide image and
    scale with the width."""

    min_range: float = 0.5
    """Closest valid depth, m."""
    max_range: float = 5.5
    """Farthest valid depth, m."""
    noise_a: float = 0.0012
    """Axial noise sigma at z0, m."""
    noise_b: float = 0.0019
    """Axial noise growth, m / m^2."""
    noise_z0: float = 0.4
    """Distance of minimal noise, m."""
    noise_correlated: float = 0.4
    """Fraction of the noise variance that is spatially correlated."""
    noise_corr_px: float = 3.0
    """Size (Gaussian sigma) of the correlated noise blobs, px."""
    quantize: bool = True
    """Quantise in Kinect v1 disparity steps."""
    disparity_focal_px: float = 580.0
    """Native IR focal length for the disparity model, px (independent of output size)."""
    disparity_baseline: float = 0.075
    """Projector-camera baseline for the disparity model, m."""
    disparity_subpixel: int = 8
    """Disparity resolution: 1 / this many pixels."""
    projector_baseline: float = 0.075
    """Projector offset along camera +x for shadows, m (0 disables; negative: other side)."""
    edge_jump: float = 0.04
    """Minimal depth jump of a discontinuity, m (plus ``edge_jump_rel`` * z)."""
    edge_jump_rel: float = 0.03
    """Relative part of the discontinuity threshold."""
    edge_dropout: float = 0.35
    """Probability that a pixel next to a discontinuity is invalid."""
    edge_jitter: float = 0.3
    """Probability that a pixel next to a discontinuity takes a neighbour's depth."""
    grazing_cos: float = 0.2
    """Dropouts start below this |cos(incidence)|."""
    grazing_dropout: float = 0.8
    """Dropout probability at 90 deg incidence."""
    holes_per_frame: float = 3.0
    """Mean number of random elliptic holes per frame."""
    hole_radius_px: tuple[float, float] = (2.0, 7.0)
    """Range of hole radii, px."""
    hair_dropout: float = 0.3
    """Dropout probability on hair pixels (dark, scattering)."""

    def sigma(self, z: np.ndarray) -> np.ndarray:
        """Axial noise standard deviation (m) at depth z (m)."""
        return self.noise_a + self.noise_b * np.maximum(z - self.noise_z0, 0.0) ** 2

    def quantization_step(self, z: np.ndarray) -> np.ndarray:
        """Depth step (m) between adjacent disparity levels at depth z (m)."""
        fb = self.disparity_focal_px * self.disparity_baseline
        return z**2 / (self.disparity_subpixel * fb)


def _clustered(rng: np.random.Generator, shape: tuple[int, int], p: np.ndarray | float,
               blob_px: float) -> np.ndarray:
    """Random boolean mask with per-pixel probability ``p`` that comes in blobs of ~blob_px.

    A low-resolution Gaussian field, upsampled and thresholded at the normal quantile of p.
    """
    H, W = shape
    f = max(int(round(blob_px)), 1)
    small = rng.standard_normal(((H + f - 1) // f + 1, (W + f - 1) // f + 1)).astype(np.float32)
    g = cv2.resize(small, (small.shape[1] * f, small.shape[0] * f),
                   interpolation=cv2.INTER_LINEAR)[:H, :W]
    g /= max(float(g.std()), 1e-6)
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-6, 1 - 1e-6)
    if p.ndim == 0:
        return g < statistics.NormalDist().inv_cdf(float(p))
    # Vectorised normal quantile through a lookup table (p is a per-pixel map).
    return g < np.interp(p, _P_GRID, _Q_GRID)


_P_GRID = np.linspace(1e-6, 1 - 1e-6, 2049)
_Q_GRID = np.array([statistics.NormalDist().inv_cdf(float(x)) for x in _P_GRID])


def projector_shadow(z: np.ndarray, fx: float, baseline: float) -> np.ndarray:
    """Pixels the projector cannot light (bool (H, W)); z (H, W) in m, 0/inf = no surface.

    Rows are epipolar lines (projector displaced along x). A point at column u is in shadow
    iff a surface point farther toward the projector side has a smaller projector coordinate
    g = u - f b / z, i.e. crosses the projector's ray to it.
    """
    if baseline == 0:
        return np.zeros(z.shape, dtype=bool)
    if baseline < 0:  # projector on the left: mirror the rows
        return projector_shadow(z[:, ::-1], fx, -baseline)[:, ::-1]
    H, W = z.shape
    valid = np.isfinite(z) & (z > 0)
    zz = np.where(valid, z, 1.0)
    u = np.arange(W, dtype=np.float64)[None, :]
    g = np.where(valid, u - fx * baseline / zz, np.inf)
    # Minimum over the columns strictly to the right.
    suffix = np.minimum.accumulate(g[:, ::-1], axis=1)[:, ::-1]
    right = np.concatenate([suffix[:, 1:], np.full((H, 1), np.inf)], axis=1)
    return valid & (right < g - 0.25)


def depth_edges(z: np.ndarray, jump: float, rel: float) -> np.ndarray:
    """Pixels adjacent to a depth discontinuity (bool (H, W)); invalid (0/inf) count as far."""
    zz = np.where(np.isfinite(z) & (z > 0), z, 1e3).astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    zmax = cv2.dilate(zz, k)
    zmin = cv2.erode(zz, k)
    return (zmax - zmin) > (jump + rel * zmin)


def simulate_sensor(rng: np.random.Generator, depth: np.ndarray, *, fx: float, fy: float,
                    cx: float, cy: float, config: SensorConfig | None = None,
                    normal: np.ndarray | None = None, hair: np.ndarray | None = None
                    ) -> np.ndarray:
    """Turn a noise-free depth map into a Kinect-v1-like measurement.

    Args:
        rng: randomness for this frame.
        depth: (H, W) noise-free z, m; inf or 0 where nothing is seen.
        fx, fy, cx, cy: intrinsics of ``depth``, px.
        config: sensor parameters (defaults: :class:`SensorConfig`).
        normal: optional (H, W, 3) unit normals (camera frame) for grazing-angle dropouts.
        hair: optional (H, W) bool mask of hair pixels.

    Returns:
        (H, W) uint16 depth in millimetres, 0 = invalid.
    """
    cfg = config or SensorConfig()
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"simulate_sensor: depth must be (H, W), got shape {z.shape}")
    H, W = z.shape
    s = W / 640.0
    valid = np.isfinite(z) & (z > 0)
    z0 = np.where(valid, z, 0.0)
    drop = ~valid
    drop |= projector_shadow(np.where(valid, z, np.inf), fx, cfg.projector_baseline)
    if normal is not None and cfg.grazing_dropout > 0:
        uu = (np.arange(W) - cx) / fx
        vv = (np.arange(H) - cy) / fy
        ray = np.stack(np.broadcast_arrays(uu[None, :], vv[:, None], np.ones((1, 1))), -1)
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        cos = np.abs(np.sum(ray * normal, axis=-1))
        p = cfg.grazing_dropout * np.clip((cfg.grazing_cos - cos) / cfg.grazing_cos, 0, 1)
        sel = p > 0
        if sel.any():
            drop |= sel & _clustered(rng, (H, W), p, 2.0 * s)
    # Axial noise: white + correlated part, same marginal sigma_z(z).
    white = rng.standard_normal((H, W), dtype=np.float32)
    corr = _clustered_field(rng, (H, W), cfg.noise_corr_px * s)
    rho = cfg.noise_correlated
    n = np.sqrt(1 - rho) * white + np.sqrt(rho) * corr
    zn = z0 + cfg.sigma(z0) * n
    # Depth edges: lateral jitter, then clustered dropouts.
    edge = depth_edges(np.where(valid, z, 0.0), cfg.edge_jump, cfg.edge_jump_rel)
    if edge.any():
        vs, us = np.nonzero(edge)
        jit = rng.uniform(size=vs.size) < cfg.edge_jitter
        k = rng.integers(0, 4, size=vs.size)
        dv = np.array([-1, 1, 0, 0])[k]
        du = np.array([0, 0, -1, 1])[k]
        v2 = np.clip(vs + dv, 0, H - 1)
        u2 = np.clip(us + du, 0, W - 1)
        src_z, src_drop = zn[v2, u2], drop[v2, u2]
        zn[vs[jit], us[jit]] = src_z[jit]
        drop[vs[jit], us[jit]] = src_drop[jit]
        drop |= edge & _clustered(rng, (H, W), cfg.edge_dropout, 1.5 * s)
    # Random holes (elliptic blobs) and hair dropouts.
    n_holes = rng.poisson(cfg.holes_per_frame)
    if n_holes:
        mask = np.zeros((H, W), np.uint8)
        for _ in range(n_holes):
            c = (int(rng.integers(0, W)), int(rng.integers(0, H)))
            ax = (max(int(round(rng.uniform(*cfg.hole_radius_px) * s)), 1),
                  max(int(round(rng.uniform(*cfg.hole_radius_px) * s)), 1))
            cv2.ellipse(mask, c, ax, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        drop |= mask.astype(bool)
    if hair is not None and cfg.hair_dropout > 0 and hair.any():
        drop |= hair & _clustered(rng, (H, W), cfg.hair_dropout, 2.0 * s)
    if cfg.quantize:
        fb = cfg.disparity_focal_px * cfg.disparity_baseline
        q = cfg.disparity_subpixel
        d = np.round(fb / np.maximum(zn, 1e-3) * q) / q
        zn = fb / np.maximum(d, 1.0 / q)
    drop |= (zn < cfg.min_range) | (zn > cfg.max_range)
    out = np.round(zn * 1000.0)
    out[drop] = 0
    return np.clip(out, 0, 65535).astype(np.uint16)


def _clustered_field(rng: np.random.Generator, shape: tuple[int, int], sigma_px: float
                     ) -> np.ndarray:
    """Unit-variance Gaussian noise field correlated over ~sigma_px pixels."""
    H, W = shape
    f = max(int(round(sigma_px)), 1)
    small = rng.standard_normal(((H + f - 1) // f + 1, (W + f - 1) // f + 1)).astype(np.float32)
    g = cv2.resize(small, (small.shape[1] * f, small.shape[0] * f),
                   interpolation=cv2.INTER_CUBIC)[:H, :W]
    return g / max(float(g.std()), 1e-6)


def ideal_sensor(depth: np.ndarray, config: SensorConfig | None = None) -> np.ndarray:
    """Noise-free conversion: range limits and millimetre rounding only (uint16, 0 invalid)."""
    cfg = config or SensorConfig()
    z = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(z) & (z >= cfg.min_range) & (z <= cfg.max_range)
    out = np.where(ok, np.round(np.where(ok, z, 0) * 1000.0), 0)
    return np.clip(out, 0, 65535).astype(np.uint16)
