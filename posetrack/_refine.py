"""Refinement of a pose against the dense depth through the soft rasteriser.

What differentiability buys beyond the paper: after the hypotheses are scored, the winner is
polished by Levenberg-Marquardt on its landmark residuals (Eq. (1), its own landmark subset)
plus ``sqrt(weight * Delta)``, with Delta (Eq. (3)) computed on the soft rendering. Delta's
derivative reaches every body part the depth sensor sees, including parts whose keypoints the
detector missed. The rendering uses the culled renderer, whose forward-mode derivative is what
optimistix' ``jac="fwd"`` linearisation needs.
"""

from __future__ import annotations

import jax.numpy as jnp

from ._body import BodyShape, capsules, normalize_params
from ._camera import Intrinsics
from ._fit import FitSettings, fit_problem, fit_residuals
from ._observe import Landmarks
from ._render import Capsules, render_and_score


def _refine_residuals(params, args):
    (fit_args, shape, z_d, z_fg, small_intr, sharpness, d_M, weight, known) = args
    lm = fit_residuals(params, fit_args)
    a, b, r = capsules(shape, params)
    delta = render_and_score(
        Capsules(a=a[None], b=b[None], radius=r[None]), z_d, z_fg, small_intr,
        sharpness=sharpness, d_M=d_M, known=known,
    )[0]  # fmt: skip
    # sqrt(weight * Delta): its square adds weight * Delta to the LM cost. Delta >= 0; the
    # floor keeps sqrt's derivative finite.
    return jnp.concatenate([lm, jnp.sqrt(weight * jnp.maximum(delta, 1e-6))[None]])


def refine_pose(
    params,
    shape: BodyShape,
    landmarks: Landmarks,
    intrinsics: Intrinsics,
    *,
    use3d,
    use2d,
    z_d,
    z_fg,
    score_intrinsics: Intrinsics,
    steps: int,
    weight: float,
    sharpness: float,
    d_M: float,
    settings: FitSettings,
    known=None,
):
    """Polish ``params`` on its landmarks plus ``weight * Delta`` (soft). Returns the pose
    (the input pose if the solve fails)."""
    start, fit_args = fit_problem(
        params, shape, landmarks, intrinsics, use3d=use3d, use2d=use2d,
        residuals=settings.residuals,
    )  # fmt: skip
    args = (fit_args, shape, z_d, z_fg, score_intrinsics, sharpness, d_M, weight, known)
    import optimistix as optx  # on first use, as in ``_fit``

    sol = optx.least_squares(
        _refine_residuals,
        settings.solver(),
        start,
        args=args,
        max_steps=steps,
        throw=False,
    )
    out = normalize_params(sol.value)
    ok = jnp.all(jnp.isfinite(out))
    return jnp.where(ok, out, start)
