"""The "wide" variety of ``generate``: a per-clip draw that widens body, camera, sensor and
detector randomisation beyond the standard generator's.

The tracker's defaults were tuned on the standard generator; a benchmark that tunes on one
seed range and reports on another under these wider conditions measures how well they
generalise. Everything is drawn once per clip from its own random stream, so the standard
streams (subject, motion, scene, sensor, detector) draw exactly what they draw without it:
the wide clip of a seed is the standard clip of that seed with these changes applied.

Ranges (U = uniform, logU = log-uniform; "x" = multiplier on the standard value):

* body: girth x U(0.8, 1.35); upper arm, forearm, thigh and shank each x N(1, 0.06) clipped
  to [0.85, 1.15]; shoulder width x U(0.85, 1.2); hip width x U(0.85, 1.25); shoulders
  U(0, 0.07) m below the neck keypoint; torso surface shifted U(-0.03, 0.03) m forward.
* camera: height U(0.6, 2.2) m; pitch = aim at the body + U(-4, 8) deg, clipped to [0, 35]
  deg; roll U(-5, 5) deg.
* sensor: axial noise sigma x U(0.7, 2.5); edge, grazing, hair dropout probabilities and
  holes per frame x U(0.7, 2.0) (probabilities at most 0.95).
* detector: jitter sigma x logU(0.5, 3); AR(1) rho U(0.3, 0.85); noise family Gaussian
  (p 0.4), Student-t with U(2.5, 5) degrees of freedom (0.3) or Laplace (0.3); miss
  probabilities x logU(0.7, 3) (at most 0.95); outlier rate x logU(0.5, 3) with mean
  length U(2, 8) frames; swap rate x U(1, 4) with lengths uniform in 5..U{12..30} frames;
  whole-body swaps U(0.0005, 0.004) per frame; limb snaps U(0.0005, 0.004) per group-frame.

The frame rate is never drawn: it stays the caller's ``fps`` (benchmarks should vary it).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ._detector import NOISE_FAMILIES, DetectorConfig
from ._scene import CameraVariation
from ._sensor import SensorConfig
from ._skeleton import BodyVariation

VARIETIES = ("standard", "wide")
"""Values of ``generate(variety=...)``."""

_P_MAX = 0.95  # widened probabilities stay below certainty


@dataclasses.dataclass(frozen=True)
class WideDraw:
    """One clip's draw of the "wide" variety (see the module docstring for the ranges)."""

    body: BodyVariation
    """Changes to the subject's dimensions."""
    camera: CameraVariation
    """Camera height, extra tilt and roll."""
    depth_noise_scale: float
    """Multiplier on the axial depth noise sigma (``noise_a``, ``noise_b``)."""
    dropout_scale: float
    """Multiplier on the sensor's dropout probabilities and holes per frame."""
    jitter_scale: float
    """Multiplier on the detector's localisation noise ``sigma_px``."""
    jitter_rho: float
    """The detector noise's frame-to-frame correlation."""
    noise_family: str
    """Detector noise family, one of ``NOISE_FAMILIES``."""
    noise_dof: float
    """Degrees of freedom when ``noise_family`` is "student_t"."""
    miss_scale: float
    """Multiplier on the detector's miss probabilities."""
    outlier_scale: float
    """Multiplier on the outlier start rate."""
    outlier_frames: float
    """Mean outlier episode length, frames."""
    swap_scale: float
    """Multiplier on the left/right swap rate."""
    swap_lengths: tuple[int, int]
    """(min, max) frames of a swap or snap episode."""
    body_swap_rate: float
    """Whole-body left/right swap start rate, per frame."""
    snap_rate: float
    """Limb snap start rate, per group-frame."""

    def sensor_config(self, base: SensorConfig | None = None) -> SensorConfig:
        """``base`` (default :class:`SensorConfig`) with this draw's noise and dropouts."""
        b = base or SensorConfig()
        m, q = self.depth_noise_scale, self.dropout_scale
        return dataclasses.replace(
            b, noise_a=b.noise_a * m, noise_b=b.noise_b * m,
            edge_dropout=min(b.edge_dropout * q, _P_MAX),
            grazing_dropout=min(b.grazing_dropout * q, _P_MAX),
            hair_dropout=min(b.hair_dropout * q, _P_MAX),
            holes_per_frame=b.holes_per_frame * q,
        )  # fmt: skip

    def detector_config(self, base: DetectorConfig | None = None) -> DetectorConfig:
        """``base`` (default :class:`DetectorConfig`) with this draw's detector errors."""
        b = base or DetectorConfig()
        m = self.miss_scale
        return dataclasses.replace(
            b, sigma_px=b.sigma_px * self.jitter_scale, rho=self.jitter_rho,
            noise_family=self.noise_family, noise_dof=self.noise_dof,
            p_miss_visible=min(b.p_miss_visible * m, _P_MAX),
            p_miss_self=min(b.p_miss_self * m, _P_MAX),
            p_miss_face=min(b.p_miss_face * m, _P_MAX),
            p_miss_occluder=min(b.p_miss_occluder * m, _P_MAX),
            outlier_rate=b.outlier_rate * self.outlier_scale, outlier_frames=self.outlier_frames,
            swap_rate=b.swap_rate * self.swap_scale, swap_lengths=self.swap_lengths,
            body_swap_rate=self.body_swap_rate, snap_rate=self.snap_rate,
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict of every drawn value (for ``meta["wide"]``)."""
        return dataclasses.asdict(self)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    # Multipliers: as likely to halve as to double, so most clips stay near the standard.
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_wide(rng: np.random.Generator) -> WideDraw:
    """Draw one clip's "wide" parameters (ranges in the module docstring).

    Args:
        rng: the clip's own stream for this draw (nothing else may use it, so that adding a
            parameter at the end leaves the earlier ones unchanged).
    """

    def limb() -> float:
        return float(np.clip(rng.normal(1.0, 0.06), 0.85, 1.15))

    body = BodyVariation(
        girth=float(rng.uniform(0.8, 1.35)),
        upper_arm=limb(), forearm=limb(), thigh=limb(), shank=limb(),
        shoulder_width=float(rng.uniform(0.85, 1.2)),
        hip_width=float(rng.uniform(0.85, 1.25)),
        shoulder_drop=float(rng.uniform(0.0, 0.07)),
        torso_shift=float(rng.uniform(-0.03, 0.03)),
    )  # fmt: skip
    camera = CameraVariation(
        height=float(rng.uniform(0.6, 2.2)),
        extra_tilt_deg=float(rng.uniform(-4.0, 8.0)),
        roll_deg=float(rng.uniform(-5.0, 5.0)),
        max_tilt_deg=35.0,
    )
    depth_noise_scale = float(rng.uniform(0.7, 2.5))
    dropout_scale = float(rng.uniform(0.7, 2.0))
    jitter_scale = _log_uniform(rng, 0.5, 3.0)
    jitter_rho = float(rng.uniform(0.3, 0.85))
    family = NOISE_FAMILIES[int(rng.choice(3, p=[0.4, 0.3, 0.3]))]
    dof = float(rng.uniform(2.5, 5.0))
    return WideDraw(
        body=body, camera=camera, depth_noise_scale=depth_noise_scale,
        dropout_scale=dropout_scale, jitter_scale=jitter_scale, jitter_rho=jitter_rho,
        noise_family=family, noise_dof=dof,
        miss_scale=_log_uniform(rng, 0.7, 3.0),
        outlier_scale=_log_uniform(rng, 0.5, 3.0),
        outlier_frames=float(rng.uniform(2.0, 8.0)),
        swap_scale=float(rng.uniform(1.0, 4.0)),
        swap_lengths=(5, int(rng.integers(12, 31))),
        body_swap_rate=float(rng.uniform(0.0005, 0.004)),
        snap_rate=float(rng.uniform(0.0005, 0.004)),
    )  # fmt: skip
