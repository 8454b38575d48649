"""Residuals of Eq. (1) of the paper, as a least-squares residual vector.

Eq. (1):  S(x, O, o) = sum_i F_i ||M_i - O_i|| + (f_i - F_i) ||m_i - o_i||

Two choices the paper leaves open, made here and measured in ``benchmarks/``:

* **Units.** 3D residuals are in metres, 2D residuals in pixels. A pixel error e at depth z is
  a lateral displacement of e * z / f metres, so every 2D residual is multiplied by
  ``z_i / f`` (``z_i`` the depth of keypoint i in the fit's starting pose, held fixed during a
  fit so the scale cannot be "optimised" by moving the body away; ``f = sqrt(fx fy)``). One 3D
  landmark and one 2D landmark then pull equally hard on lateral errors, whatever the
  resolution and distance.
* **Sum of norms.** Eq. (1) sums norms, not squares: an outlier costs in proportion to its
  distance, not its square. A least-squares solver (Levenberg-Marquardt) minimises
  ``0.5 * sum r_k^2``; the ``"l1"`` loss feeds it ``r_i = w_i e_i`` with
  ``w_i = (|e_i|^2 + eps^2)^(-1/4)``, whose square ``|e_i|^2 / sqrt(|e_i|^2 + eps^2)`` equals
  ``|e_i|`` up to ``eps`` (a smooth Charbonnier form of Eq. (1), quadratic within ``eps`` of
  zero). The weight is held constant in the Jacobian (``stop_gradient``), which makes each LM
  step an iteratively-reweighted-least-squares step: differentiating through the weight
  instead gave a Gauss-Newton model so poor that LM needed 3x the steps (measured: 30 steps
  vs 10 for the same sub-millimetre answer). The ``"l2"`` loss (plain squares) is what most
  LM implementations would do.

Two weak regularisers keep every fit well-posed: ``|q|^2 - 1`` per quaternion (the scale of a
quaternion is otherwise free, normalisation happens inside the kinematics) and a pull toward
the starting pose (a joint whose landmarks are all excluded by a subset is otherwise
unconstrained, and so are the limbs' twists).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._body import NUM_JOINTS, BodyShape, keypoints
from ._camera import Intrinsics, project
from ._observe import Landmarks


@dataclasses.dataclass(frozen=True)
class ResidualSettings:
    """How Eq. (1) becomes a residual vector. Hashable (a static argument under jit)."""

    loss: str = "l1"
    """"l1": the paper's sum of norms (smoothed, see module docstring); "l2": sum of squares."""
    eps: float = 0.01
    """Smoothing scale of the "l1" loss, metres."""
    prior_weight: float = 0.02
    """Weight of the pull toward the starting pose (per parameter, metres-equivalent)."""
    unit_weight: float = 0.1
    """Weight of the ``|q|^2 - 1`` residuals."""

    def __post_init__(self):
        if self.loss not in ("l1", "l2"):
            raise ValueError(f"ResidualSettings.loss must be 'l1' or 'l2', got {self.loss!r}")
        if not self.eps > 0:
            raise ValueError(f"ResidualSettings.eps must be positive, got {self.eps}")


def pixel_scale(
    start_params: Float[Array, 43], shape: BodyShape, intrinsics: Intrinsics
) -> Float[Array, " kpt"]:
    """Metres per pixel at each keypoint's depth in the starting pose: ``z_i / f``."""
    z = keypoints(shape, start_params)[:, 2]
    f = jnp.sqrt(intrinsics.fx * intrinsics.fy)
    return jnp.clip(z, 0.2, 20.0) / f


def landmark_residuals(
    params: Float[Array, 43],
    shape: BodyShape,
    landmarks: Landmarks,
    intrinsics: Intrinsics,
    *,
    use3d: Bool[Array, " kpt"],
    use2d: Bool[Array, " kpt"],
    metres_per_pixel: Float[Array, " kpt"],
    settings: ResidualSettings,
) -> Float[Array, "kpt 5"]:
    """Per-keypoint residuals of Eq. (1): 3 metric 3D components, then 2 scaled 2D ones.

    A keypoint contributes its 3D residual where ``use3d`` and its 2D residual where ``use2d``;
    the caller guarantees ``use3d`` implies F_i and ``use2d`` implies f_i and not ``use3d``
    (Eq. (1)'s F_i and f_i - F_i). Masked entries are exactly zero.
    """
    M = keypoints(shape, params)
    m = project(intrinsics, M)
    e3 = (M - landmarks.points3d) * use3d[:, None]
    e2 = (m - landmarks.keypoints2d) * (use2d * metres_per_pixel)[:, None]
    if settings.loss == "l1":
        e3 = _sqrt_reweight(e3, settings.eps)
        e2 = _sqrt_reweight(e2, settings.eps)
    return jnp.concatenate([e3, e2], axis=-1)


def _sqrt_reweight(e: Array, eps: float) -> Array:
    # |r|^2 = |e|^2 / sqrt(|e|^2 + eps^2) ~ |e|: the sum of squares becomes a sum of norms.
    # eps > 0 keeps the factor and its derivative finite at e = 0.
    sq = jnp.sum(e * e, axis=-1, keepdims=True)
    return e * jax.lax.stop_gradient((sq + eps * eps) ** -0.25)


def regulariser_residuals(
    params: Float[Array, 43], start_params: Float[Array, 43], settings: ResidualSettings
) -> Float[Array, 53]:
    """``unit_weight (|q_j|^2 - 1)`` for the 10 quaternions and ``prior_weight (x - x_start)``."""
    q = params[3:].reshape(NUM_JOINTS, 4)
    unit = settings.unit_weight * (jnp.sum(q * q, axis=-1) - 1.0)
    prior = settings.prior_weight * (params - start_params)
    return jnp.concatenate([unit, prior])
