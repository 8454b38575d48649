"""OpenPose-like 2D keypoint detector errors, driven by what the camera actually sees.

Input: ground-truth projections of the 18 COCO keypoints and, per keypoint and frame, how
much of its neighbourhood shows the joint's own body parts (self-occlusion score) and how much
is covered by an occluding rectangle. Output: OpenPose-style (x, y, confidence), with
(0, 0, 0) for a missed keypoint.

Error model (pixel sizes for a 640-px-wide image, scaled with the width):

* localisation noise: Gaussian, ``sigma_px`` per axis for a clearly visible keypoint, growing
  to ``occluded_sigma_factor`` x that when hidden; temporally correlated (AR(1), ``rho``) like
  a real detector's jitter;
* confidence in [0, 1]: ~N(0.82, 0.08) when visible, pulled toward 0.45 when self-occluded
  and 0.3 when under an occluder, lower for small people;
* misses (0, 0, 0): ``p_miss_visible`` when visible, up to ``p_miss_self`` when
  self-occluded (``p_miss_face`` for the face keypoints, scaled by 1 - self-visibility),
  ``p_miss_occluder`` under a rectangle,
  always outside the image;
* hallucinated joints: a hidden elbow/wrist/knee/ankle that is still reported sits on a
  plausible but wrong limb: its 2D bone from the parent is rotated by a slowly varying angle
  (sd ``hallucination_deg``) and rescaled by up to +-20 %;
* gross outliers: episodes (start rate ``outlier_rate`` per keypoint-frame, mean
  ``outlier_frames`` frames) where a keypoint sits on another keypoint or elsewhere on a bone,
  with a plausible confidence U(0.2, 0.7);
* left/right swaps: episodes (mean ``swap_frames`` frames) exchanging the elbow+wrist,
  knee+ankle or eye+ear pairs, at ``swap_rate`` per group-frame, x9 when the two sides
  overlap in the image (side views).

Off by default (the "wide" variety of ``generate`` turns them on):

* heavy-tailed localisation noise (``noise_family`` "student_t" or "laplace", same variance);
* swap lengths drawn uniformly from ``swap_lengths`` instead of geometric;
* whole-body left/right swaps (all eight pairs, shoulders and hips included: the person
  seen facing the other way) at ``body_swap_rate`` per frame, x9 when the shoulders and hips
  overlap;
* snaps: an arm's (leg's) elbow+wrist (knee+ankle) reported on the other arm (leg), so both
  sides sit on one limb, at ``snap_rate`` per group-frame, x9 when the sides overlap.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._skeleton import KPT_PARENT, LR_PAIRS, N_KPT

_FACE = (0, 14, 15, 16, 17)
_LIMB_END = (3, 4, 6, 7, 9, 10, 12, 13)
_SWAP_GROUPS = (((3, 6), (4, 7)), ((9, 12), (10, 13)), ((14, 15), (16, 17)))
_SNAP_GROUPS = _SWAP_GROUPS[:2]  # arms and legs
NOISE_FAMILIES = ("gaussian", "student_t", "laplace")
_BONES = ((1, 2), (2, 3), (3, 4), (1, 5), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11),
          (11, 12), (12, 13), (8, 11), (2, 5), (1, 0))
_CONFUSABLE = {3: (6, 4, 2), 4: (7, 3), 6: (3, 7, 5), 7: (4, 6), 9: (12, 10, 8), 10: (13, 9),
               12: (9, 13, 11), 13: (10, 12), 2: (5, 3), 5: (2, 6), 8: (11, 9), 11: (8, 12),
               0: (14, 15), 14: (15, 16), 15: (14, 17), 16: (17, 14), 17: (16, 15), 1: (2, 5)}


@dataclasses.dataclass(frozen=True)
class DetectorConfig:
    """Parameters of :func:`simulate_detector` (pixels for a 640-px-wide image)."""

    sigma_px: float = 3.0
    """Localisation noise per axis for a visible keypoint, px."""
    rho: float = 0.6
    """Frame-to-frame correlation of the localisation noise."""
    occluded_sigma_factor: float = 3.0
    """Noise multiplier for fully hidden keypoints."""
    p_miss_visible: float = 0.01
    p_miss_self: float = 0.3
    p_miss_face: float = 0.8
    p_miss_occluder: float = 0.75
    conf_visible: float = 0.82
    conf_self: float = 0.45
    conf_occluder: float = 0.3
    conf_sd: float = 0.08
    hallucination_deg: float = 25.0
    outlier_rate: float = 0.004
    outlier_frames: float = 3.0
    swap_rate: float = 0.002
    swap_frames: float = 4.0
    noise_family: str = "gaussian"
    """Localisation noise distribution, one of :data:`NOISE_FAMILIES`; the heavy-tailed ones
    are scaled to the same variance (``sigma_px``)."""
    noise_dof: float = 3.0
    """Degrees of freedom of the "student_t" family (> 2)."""
    swap_lengths: tuple[int, int] | None = None
    """(min, max) frames of a swap or snap episode, uniform; None: geometric with mean
    ``swap_frames``."""
    body_swap_rate: float = 0.0
    """Start rate of whole-body left/right swaps, per frame."""
    snap_rate: float = 0.0
    """Start rate of one limb snapping onto the other side's limb, per group-frame."""

    def __post_init__(self) -> None:
        if self.noise_family not in NOISE_FAMILIES:
            raise ValueError(f"DetectorConfig: noise_family must be one of {NOISE_FAMILIES}, "
                             f"got {self.noise_family!r}")
        if not self.noise_dof > 2:
            raise ValueError(f"DetectorConfig: noise_dof must be > 2, got {self.noise_dof!r}")
        if self.swap_lengths is not None:
            lo, hi = self.swap_lengths
            if int(lo) != lo or int(hi) != hi or not 1 <= lo <= hi:
                raise ValueError("DetectorConfig: swap_lengths must be integers 1 <= min <= "
                                 f"max, got {self.swap_lengths!r}")

    @staticmethod
    def perfect() -> DetectorConfig:
        """No errors at all: GT projections, confidence 1 when visible, misses only outside
        the image."""
        return DetectorConfig(
            sigma_px=0.0, occluded_sigma_factor=1.0, p_miss_visible=0.0, p_miss_self=0.0,
            p_miss_face=0.0, p_miss_occluder=0.0, conf_visible=1.0, conf_self=1.0,
            conf_occluder=1.0, conf_sd=0.0, hallucination_deg=0.0, outlier_rate=0.0,
            swap_rate=0.0,
        )


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], rho: float,
         family: str = "gaussian", dof: float = 3.0) -> np.ndarray:
    """Unit-variance AR(1) noise along axis 0, innovations of the given family."""
    if family == "gaussian":
        n = rng.standard_normal(shape)
    elif family == "student_t":
        n = rng.standard_t(dof, size=shape) * np.sqrt((dof - 2.0) / dof)
    else:  # laplace: variance 2 b^2
        n = rng.laplace(0.0, np.sqrt(0.5), size=shape)
    out = np.empty(shape)
    out[0] = n[0]
    c = np.sqrt(max(1 - rho * rho, 0.0))
    for t in range(1, shape[0]):
        out[t] = rho * out[t - 1] + c * n[t]
    return out


def _episodes(rng: np.random.Generator, start_p: np.ndarray, mean_len: float,
              lengths: tuple[int, int] | None = None) -> np.ndarray:
    """Boolean (T, ...) on/off episodes: start with prob start_p (T, ...), geometric length
    with mean ``mean_len``, or uniform in ``lengths`` = (min, max) when given."""
    T = start_p.shape[0]
    on = np.zeros(start_p.shape, dtype=bool)
    left = np.zeros(start_p.shape[1:], dtype=int)
    u = rng.uniform(size=start_p.shape)
    if lengths is None:
        lens = rng.geometric(1.0 / max(mean_len, 1.0), size=start_p.shape)
    else:
        lens = rng.integers(int(lengths[0]), int(lengths[1]) + 1, size=start_p.shape)
    for t in range(T):
        start = (left == 0) & (u[t] < start_p[t])
        left = np.where(start, lens[t], left)
        on[t] = left > 0
        left = np.maximum(left - 1, 0)
    return on


def simulate_detector(rng: np.random.Generator, joints2d: np.ndarray, self_vis: np.ndarray,
                      occ: np.ndarray, in_image: np.ndarray, *, width: int, height: int,
                      config: DetectorConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulated OpenPose output for one person over a sequence.

    Args:
        rng: randomness.
        joints2d: (T, 18, 2) ground-truth projections, px.
        self_vis: (T, 18) fraction (0..1) of each keypoint's neighbourhood showing its own
            body parts (1 = fully visible, 0 = hidden behind other parts or facing away).
        occ: (T, 18) fraction (0..1) of the neighbourhood under an occluding rectangle.
        in_image: (T, 18) projection inside the image.
        width, height: image size, px.
        config: error parameters.

    Returns:
        keypoints (T, 18, 2) float32 px ((0, 0) when missed) and confidence (T, 18) float32
        in [0, 1] (0 when missed).
    """
    cfg = config or DetectorConfig()
    T = joints2d.shape[0]
    s = width / 640.0
    vis = self_vis * (1 - occ)
    kp = joints2d.astype(np.float64).copy()
    # Person size in the image (for size-relative errors and confidence).
    ext = np.ptp(np.where(in_image[..., None], joints2d, np.nan), axis=1)
    ext = np.nan_to_num(ext, nan=100.0 * s)
    size = np.maximum(np.max(ext, axis=-1), 20.0 * s)  # (T,)
    # Hallucinated limb ends for hidden joints (rotated/rescaled 2D bone from the parent).
    if cfg.hallucination_deg > 0:
        ang = np.deg2rad(cfg.hallucination_deg) * _ar1(rng, (T, N_KPT), 0.95)
        scl = 1 + 0.2 * np.tanh(_ar1(rng, (T, N_KPT), 0.95))
        for k in _LIMB_END:
            p = KPT_PARENT[k]
            hidden = vis[:, k] < 0.5
            if not hidden.any():
                continue
            b = joints2d[:, k] - joints2d[:, p]
            c, sn = np.cos(ang[:, k]), np.sin(ang[:, k])
            rb = np.stack([c * b[:, 0] - sn * b[:, 1], sn * b[:, 0] + c * b[:, 1]], -1)
            alt = joints2d[:, p] + rb * scl[:, k, None]
            kp[hidden, k] = alt[hidden]
    # Localisation noise, larger when hidden.
    sig = cfg.sigma_px * s * (1 + (cfg.occluded_sigma_factor - 1) * (1 - vis))
    kp += sig[..., None] * _ar1(rng, (T, N_KPT, 2), cfg.rho, cfg.noise_family, cfg.noise_dof)
    # Confidence.
    m = cfg.conf_visible - (cfg.conf_visible - cfg.conf_self) * (1 - self_vis)
    m = m - (m - cfg.conf_occluder) * occ
    m = m * np.clip(size / (150.0 * s), 0.6, 1.0)[:, None]
    conf = np.clip(m + cfg.conf_sd * rng.standard_normal((T, N_KPT)), 0.05, 1.0)
    # Gross outliers: on another keypoint or elsewhere on a bone, for a few frames.
    if cfg.outlier_rate > 0:
        on = _episodes(rng, np.full((T, N_KPT), cfg.outlier_rate), cfg.outlier_frames)
        for k in range(N_KPT):
            ts = np.nonzero(on[:, k])[0]
            if ts.size == 0:
                continue
            # One target per episode (frames of an episode are consecutive).
            starts = ts[np.concatenate([[True], np.diff(ts) > 1])]
            for t0 in starts:
                t1 = t0
                while t1 + 1 < T and on[t1 + 1, k]:
                    t1 += 1
                sl = slice(t0, t1 + 1)
                if rng.uniform() < 0.5:
                    j = int(rng.choice(_CONFUSABLE[k]))
                    tgt = joints2d[sl, j]
                else:
                    a, b = _BONES[int(rng.integers(len(_BONES)))]
                    f = rng.uniform(0.1, 0.9)
                    d = joints2d[sl, b] - joints2d[sl, a]
                    nrm = np.stack([-d[:, 1], d[:, 0]], -1)
                    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-6)
                    tgt = joints2d[sl, a] + f * d + rng.uniform(-0.04, 0.04) * size[sl, None] * nrm
                kp[sl, k] = tgt + cfg.sigma_px * s * rng.standard_normal((t1 - t0 + 1, 2))
                conf[sl, k] = rng.uniform(0.2, 0.7)
    # Left/right swaps of limb pairs, likelier when the two sides overlap (side views).
    if cfg.swap_rate > 0:
        for group in _SWAP_GROUPS:
            r_idx = [a for a, _ in group]
            l_idx = [b for _, b in group]
            on = _side_episodes(rng, cfg, cfg.swap_rate, joints2d, r_idx, l_idx, size)
            _swap(kp, conf, on, r_idx, l_idx)
    # Whole-body swaps (facing direction misread), likelier when the torso is seen sideways.
    if cfg.body_swap_rate > 0:
        r_idx = [a for a, _ in LR_PAIRS]
        l_idx = [b for _, b in LR_PAIRS]
        on = _side_episodes(rng, cfg, cfg.body_swap_rate, joints2d, [2, 8], [5, 11], size)
        _swap(kp, conf, on, r_idx, l_idx)
    # Snaps: one side's limb reported on the other side's limb (both on one arm or leg).
    if cfg.snap_rate > 0:
        for group in _SNAP_GROUPS:
            r_idx = [a for a, _ in group]
            l_idx = [b for _, b in group]
            on = _side_episodes(rng, cfg, cfg.snap_rate, joints2d, r_idx, l_idx, size)
            for t0, t1 in _runs(on):
                src, dst = (r_idx, l_idx) if rng.uniform() < 0.5 else (l_idx, r_idx)
                n = t1 - t0
                kp[t0:t1, dst] = kp[t0:t1, src] + cfg.sigma_px * s * rng.standard_normal(
                    (n, len(dst), 2))
                conf[t0:t1, dst] = conf[t0:t1, src] * rng.uniform(0.7, 1.0, size=(n, len(dst)))
    # Misses.
    p_self = np.full(N_KPT, cfg.p_miss_self)
    p_self[list(_FACE)] = cfg.p_miss_face
    p_miss = 1 - (1 - cfg.p_miss_visible) * (1 - p_self * (1 - self_vis)) * (
        1 - cfg.p_miss_occluder * occ)
    miss = rng.uniform(size=(T, N_KPT)) < p_miss
    miss |= ~in_image
    inside = (kp[..., 0] >= 0) & (kp[..., 0] <= width - 1) & (kp[..., 1] >= 0) & (
        kp[..., 1] <= height - 1)
    miss |= ~inside
    kp[miss] = 0.0
    conf[miss] = 0.0
    return kp.astype(np.float32), conf.astype(np.float32)


def _overlap(joints2d: np.ndarray, r_idx: list[int], l_idx: list[int], size: np.ndarray
             ) -> np.ndarray:
    """(T,) how much the right and left keypoints coincide in the image: 1 on top of each
    other, ~0 when apart by more than ~15 % of the person's size."""
    d = np.linalg.norm(joints2d[:, r_idx] - joints2d[:, l_idx], axis=-1).mean(axis=1)
    return np.exp(-((d / (0.08 * size)) ** 2))


def _side_episodes(rng: np.random.Generator, cfg: DetectorConfig, rate: float,
                   joints2d: np.ndarray, r_idx: list[int], l_idx: list[int],
                   size: np.ndarray) -> np.ndarray:
    """(T,) bool episodes of a left/right confusion starting at ``rate`` per frame, 9x as
    likely where the two sides' keypoints ``r_idx`` and ``l_idx`` coincide in the image;
    lengths from ``cfg.swap_frames`` / ``cfg.swap_lengths``."""
    overlap = _overlap(joints2d, r_idx, l_idx, size)
    return _episodes(rng, (rate * (1 + 8 * overlap))[:, None], cfg.swap_frames,
                     cfg.swap_lengths)[:, 0]


def _swap(kp: np.ndarray, conf: np.ndarray, sw: np.ndarray, r_idx: list[int],
          l_idx: list[int]) -> None:
    """Exchange the right and left keypoints and confidences in the frames ``sw`` (T,) bool,
    in place."""
    if not sw.any():
        return
    kr, kl = kp[sw][:, r_idx].copy(), kp[sw][:, l_idx].copy()
    cr, cl = conf[sw][:, r_idx].copy(), conf[sw][:, l_idx].copy()
    kp[np.ix_(sw, r_idx)] = kl
    kp[np.ix_(sw, l_idx)] = kr
    conf[np.ix_(sw, r_idx)] = cl
    conf[np.ix_(sw, l_idx)] = cr


def _runs(on: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(),
                    strict=True))


def perfect_detector(joints2d: np.ndarray, in_image: np.ndarray) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    """Ground-truth projections with confidence 1 (0 and (0, 0) outside the image)."""
    kp = joints2d.astype(np.float32).copy()
    conf = in_image.astype(np.float32)
    kp[~in_image] = 0.0
    return kp, conf
