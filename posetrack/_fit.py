"""Fitting the body model to landmarks with optimistix Levenberg-Marquardt (Eq. (2)).

``fit_pose`` handles ONE pose (one frame, one hypothesis, one landmark subset) and is pure, so
the tracker vmaps it over hypotheses inside a single jit call (``fit_hypotheses``).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Bool, Float, Int

from ._body import BodyShape, normalize_params
from ._camera import Intrinsics
from ._observe import Landmarks
from ._residuals import ResidualSettings, landmark_residuals, pixel_scale, regulariser_residuals

# optimistix and lineax are imported where a fit is traced, not here: a warm start loads its
# programs from the cache and never traces one, and importing them costs it ~0.4 s.
if TYPE_CHECKING:
    import optimistix as optx


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Levenberg-Marquardt settings. Hashable (a static argument under jit).

    Tracking starts close to the answer, and a vmapped while loop runs every hypothesis until
    the slowest stops, so the step count is capped (``max_steps``); hitting the cap is not a
    failure. See ``benchmarks/README.md`` for the measurements behind the defaults.
    """

    max_steps: int = 8
    """Per-frame cap. Tracking starts within a few centimetres; on our benchmark 8 steps were
    as accurate as 12 (within run-to-run noise) at two thirds of the fit cost (see
    ``benchmarks/README.md``). MHT's default is 4 (``TrackerConfig.fit``); the
    (re-)initialisation fit uses ``TrackerConfig.init_steps``."""
    rtol: float = 1e-4
    atol: float = 1e-6
    linear_solver: str = "cholesky"
    """"cholesky": normal equations, lineax ``Normal(Cholesky())`` (fast; the damping keeps
    them positive definite); "qr": lineax QR (optimistix's default, slower)."""
    residuals: ResidualSettings = ResidualSettings()

    def __post_init__(self):
        if self.max_steps < 1:
            raise ValueError(f"FitSettings.max_steps must be >= 1, got {self.max_steps}")
        if self.linear_solver not in ("cholesky", "qr"):
            raise ValueError(
                f"FitSettings.linear_solver must be 'cholesky' or 'qr', got {self.linear_solver!r}"
            )

    def solver(self) -> optx.LevenbergMarquardt:
        import lineax as lx
        import optimistix as optx

        linear = lx.Normal(lx.Cholesky()) if self.linear_solver == "cholesky" else lx.QR()
        return optx.LevenbergMarquardt(rtol=self.rtol, atol=self.atol, linear_solver=linear)


class FitResult(eqx.Module):
    """Outcome of one fit. Failure is data: ``ok`` is False and ``params`` is the start pose."""

    params: Float[Array, 43]
    """Fitted pose (quaternions unit, w >= 0)."""
    cost: Float[Array, ""]
    """Final value of the landmark term (sum of squared residuals without regularisers)."""
    num_steps: Int[Array, ""]
    """LM steps taken."""
    ok: Bool[Array, ""]
    """The solver returned a finite pose (converged or stopped at ``max_steps``)."""


def fit_problem(
    start_params: Float[Array, 43],
    shape: BodyShape,
    landmarks: Landmarks,
    intrinsics: Intrinsics,
    *,
    use3d: Bool[Array, " kpt"],
    use2d: Bool[Array, " kpt"],
    residuals: ResidualSettings,
) -> tuple[Float[Array, 43], tuple]:
    """``(start, args)`` of Eq. (1) as a least-squares problem for :func:`fit_residuals`.

    The masks are made consistent with the landmarks (a 3D residual needs F_i; a 2D residual
    needs f_i and is used only where the 3D one is not), the start is normalised, and the 2D
    residuals' metres-per-pixel scale is fixed at the start pose.
    """
    use3d = use3d & landmarks.has_depth
    use2d = use2d & landmarks.detected & ~use3d
    start = normalize_params(start_params)
    mpp = pixel_scale(start, shape, intrinsics)
    return start, (shape, landmarks, intrinsics, use3d, use2d, mpp, start, residuals)


def fit_residuals(params: Float[Array, 43], args: tuple) -> Float[Array, " residual"]:
    """The residual vector of Eq. (1) plus the regularisers, for ``args`` from
    :func:`fit_problem` (optimistix' ``fn(y, args)`` form).

    Differentiable; its derivative is the materialised (residual, 43) Jacobian times the
    tangent (see :func:`_residuals_matrix_jvp`)."""
    return _residuals(params, args[:-1], args[-1])


def _raw_residuals(params, dyn_args: tuple, settings: ResidualSettings):
    shape, landmarks, intrinsics, use3d, use2d, mpp, start = dyn_args
    lm = landmark_residuals(
        params, shape, landmarks, intrinsics,
        use3d=use3d, use2d=use2d, metres_per_pixel=mpp, settings=settings,
    )  # fmt: skip
    reg = regulariser_residuals(params, start, settings, shape, landmarks.has_depth)
    return jnp.concatenate([lm.reshape(-1), reg])


@functools.partial(jax.custom_jvp, nondiff_argnums=(2,))
def _residuals(params, dyn_args: tuple, settings: ResidualSettings):
    return _raw_residuals(params, dyn_args, settings)


@functools.partial(_residuals.defjvp, symbolic_zeros=True)
def _residuals_matrix_jvp(settings, primals, tangents):
    """Forward derivative as ``J @ t`` with ``J`` materialised by ``jax.jacfwd``.

    optimistix' Levenberg-Marquardt linearises the residuals, transposes the linearisation
    (for J^T r) and materialises J^T J through it. Given the JVP as a plain matrix product, the
    transpose is one more product instead of a transposed copy of the forward kinematics'
    derivative: every LM program is smaller and compiles about a quarter faster
    (``benchmarks/startup.py``), for the same steps (float32 rounding aside). Tangents of
    the data (landmarks, shape) take the ordinary path, and only when they are not zero.
    """
    params, dyn_args = primals
    t_params, t_dyn = tangents
    f = _raw_residuals(params, dyn_args, settings)
    df = jnp.zeros_like(f)
    if not isinstance(t_params, SymbolicZero):
        df = df + jax.jacfwd(_raw_residuals)(params, dyn_args, settings) @ t_params
    zero = [isinstance(t, SymbolicZero) for t in jax.tree.leaves(t_dyn, is_leaf=_is_zero)]
    if not all(zero):  # somebody differentiates through the data: the plain JVP
        t_dyn = jax.tree.map(_instantiate, t_dyn, is_leaf=_is_zero)
        df = df + jax.jvp(lambda d: _raw_residuals(params, d, settings), (dyn_args,), (t_dyn,))[1]
    return f, df


def _is_zero(x) -> bool:
    return isinstance(x, SymbolicZero)


def _instantiate(t):
    if not isinstance(t, SymbolicZero):
        return t
    if t.dtype == jax.dtypes.float0:  # the tangent of an integer or boolean input
        return np.zeros(t.shape, jax.dtypes.float0)
    return jnp.zeros(t.shape, t.dtype)


def fit_pose(
    start_params: Float[Array, 43],
    shape: BodyShape,
    landmarks: Landmarks,
    intrinsics: Intrinsics,
    *,
    use3d: Bool[Array, " kpt"],
    use2d: Bool[Array, " kpt"],
    settings: FitSettings = FitSettings(),
) -> FitResult:
    """Minimise Eq. (1) over the 43 pose parameters, starting from ``start_params``.

    Args:
        start_params: the starting pose (previous frame's estimate, or an initialisation).
        shape: body dimensions (held fixed).
        landmarks: this frame's lifted observations.
        intrinsics: the camera.
        use3d: (kpt,) which 3D landmarks enter the fit (must imply ``landmarks.has_depth``).
        use2d: (kpt,) which 2D landmarks enter the fit (used where ``use3d`` is false and the
            keypoint is detected).
        settings: solver settings (static).

    Returns:
        :class:`FitResult`; never raises inside jit, never returns NaN parameters.
    """
    start, args = fit_problem(
        start_params, shape, landmarks, intrinsics,
        use3d=use3d, use2d=use2d, residuals=settings.residuals,
    )  # fmt: skip
    _, _, _, use3d, use2d, mpp, _, _ = args
    import optimistix as optx

    sol = optx.least_squares(
        fit_residuals,
        settings.solver(),
        start,
        args=args,
        max_steps=settings.max_steps,
        throw=False,
    )
    params = normalize_params(sol.value)
    finished = (sol.result == optx.RESULTS.successful) | (
        sol.result == optx.RESULTS.nonlinear_max_steps_reached
    )
    ok = finished & jnp.all(jnp.isfinite(params))
    params = jnp.where(ok, params, start)
    lm = landmark_residuals(
        params, shape, landmarks, intrinsics,
        use3d=use3d, use2d=use2d, metres_per_pixel=mpp, settings=settings.residuals,
    )  # fmt: skip
    return FitResult(
        params=params,
        cost=jnp.sum(lm * lm),
        num_steps=jnp.asarray(sol.stats["num_steps"]),
        ok=ok,
    )


def fit_hypotheses(
    start_params: Float[Array, "hyp 43"],
    shape: BodyShape,
    landmarks: Landmarks,
    intrinsics: Intrinsics,
    *,
    use3d: Bool[Array, "hyp kpt"],
    use2d: Bool[Array, "hyp kpt"],
    settings: FitSettings = FitSettings(),
    per_hypothesis_landmarks: bool = False,
) -> FitResult:
    """:func:`fit_pose` vmapped over the leading ``hyp`` axis of the start poses and masks
    (shape and camera shared; the landmarks too, unless ``per_hypothesis_landmarks``: then
    they carry a leading ``hyp`` axis, e.g. relabelled left/right for some hypotheses)."""
    return jax.vmap(
        lambda p, lm, u3, u2: fit_pose(
            p, shape, lm, intrinsics, use3d=u3, use2d=u2, settings=settings
        ),
        in_axes=(0, 0 if per_hypothesis_landmarks else None, 0, 0),
    )(start_params, landmarks, use3d, use2d)
