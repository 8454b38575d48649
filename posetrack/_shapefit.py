"""Body shape from depth: fit the body dimensions through the soft rasteriser's gradients.

:func:`~posetrack.estimate_shape` measures bone lengths between lifted landmarks; it cannot
see the part radii, and it cannot see where a joint sits inside the body. Here the shape is
refined against the dense depth of a few frames: the log-scale factors ``u`` of the
:class:`~posetrack.BodyShape` fields (``shape_k = base_k * exp(u_k)``; ``shoulder_drop``, which
may be zero or negative, is additive: ``base + SHOULDER_DROP_UNIT * u``) and, jointly, the F
poses (a pose fitted with the wrong shape compensates for it; holding the poses fixed would
ask the shape to explain the poses' errors) minimise

    mean_f [ delta_weight * Delta_f + landmark_weight * |r_f|^2 ] + prior_weight * |u / sigma|^2

with ``Delta_f`` the soft Delta of Eq. (3) of the paper (the capsules rendered with a finite
sharpness, ``cull=False`` so reverse mode works), ``r_f`` the landmark residuals of Eq. (1)
(each 3D landmark pushed behind the surface by the *current* shape's local radius, so a
radius change moves the joints it implies), and a Gaussian prior pulling ``u`` to 0, i.e.
toward the landmark-based estimate, so fields the data does not see stay put.

The optimiser is Adam written by hand (no new dependency), a fixed number of steps in one
``lax.scan``: one jitted program, every frame rendered at once (``vmap``) at each step.
Why first order: the depth term is one scalar per frame, so a Gauss-Newton model of it (as in
``_refine``) has rank one per frame; its curvature across 15 shape fields would come from the
damping alone. Adam's per-coordinate step also makes the mixed units (metres, quaternion
components, log-scales) a non-issue. Quaternions (wxyz) are renormalised after each step.
"""

from __future__ import annotations

import dataclasses
import math
import time
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import BodyShape, capsules, normalize_params
from ._camera import Intrinsics
from ._config import TrackerConfig
from ._depthobs import NO_FLOOR, fit_floor_plane, tracker_observation
from ._geometry import surface_offsets
from ._observe import Landmarks, lift_keypoints
from ._programs import device_f32, program
from ._render import DEFAULT_SHARPNESS, Capsules, capsule_fields, capsule_params, soft_terms
from ._residuals import ResidualSettings, landmark_residuals, pixel_scale
from ._score import DEFAULT_D_M, delta_from_sums, delta_sums

#: Every BodyShape field, in declaration order.
SHAPE_FIELDS = tuple(f.name for f in dataclasses.fields(BodyShape))

SHOULDER_DROP_UNIT = 0.1
"""Metres of ``shoulder_drop`` per unit of its (additive) factor: with ``prior_sigma`` 0.1 the
prior's standard deviation is 1 cm."""

_DTYPE = jnp.float32


@dataclasses.dataclass(frozen=True)
class ShapeFitSettings:
    """Settings of :func:`refine_shape`. Hashable (a static argument under jit: changing one
    compiles a new program)."""

    fields: tuple[str, ...] = SHAPE_FIELDS
    """The shape fields refined; the others keep their input values."""
    fit_poses: bool = True
    """Refine the F poses jointly with the shape (else they stay as given)."""
    steps: int = 150
    """Adam steps."""
    shape_lr: float = 0.01
    """Adam step of the log-scale factors (0.01: 1 % per step at most)."""
    pose_lr: float = 0.002
    """Adam step of the pose parameters (metres and quaternion components)."""
    delta_weight: float = 3.0
    """Weight of Delta (per frame, in [0, 1]). 3 against 1 and against a 10x weaker prior on
    6 tuning clips (``benchmarks/shape.py --tune``): D 37.6 / 39.3 / 39.3 mm, better than the
    landmark-based shape on 6 / 4 / 5 clips."""
    landmark_weight: float = 1.0
    """Weight of the landmark term (sum of squared residuals of one frame, metres^2 for the
    ``"l2"`` loss, ~metres for ``"l1"``)."""
    prior_weight: float = 0.01
    """Weight of ``|u / prior_sigma|^2`` (summed over the refined fields)."""
    prior_sigma: float = 0.1
    """Standard deviation of each log-scale factor around the input shape (0.1: 10 %)."""
    radius_prior_sigma: float | None = None
    """``prior_sigma`` of the part radii (the ``*_radius`` fields); None: ``prior_sigma``. The
    landmark-based shape's radii follow the person's height, not their girth, which only the
    depth shows."""
    girth_prior_sigma: float | None = None
    """``prior_sigma`` of the refined radii's *common* log-scale factor (their mean, one girth
    for the whole body); the radii's deviations from it keep ``radius_prior_sigma`` (or
    ``prior_sigma``), so the ratios between parts stay near the input's. None: no separate
    prior (each radius alone, as before; the same as ``girth_prior_sigma`` equal to the
    radii's sigma)."""
    max_change: float = 0.4
    """Log-scale factors are clipped to [-max_change, max_change] (0.4: x0.67 to x1.5)."""
    width: int = 160
    """Width of the depth maps rendered (the sensor's depth is downsampled to it)."""
    height: int = 120
    """Height of the depth maps rendered."""
    sharpness: float = DEFAULT_SHARPNESS
    """Soft rasteriser sharpness, 1/metre."""
    d_M: float = DEFAULT_D_M
    """Depth clamp of Eq. (3), metres."""
    loss: str = "l1"
    """Landmark loss: "l1" (the paper's sum of norms, robust to detector outliers) or "l2"."""
    crop: bool = True
    """Render a window around the body (one size for all F frames, rounded up to 16 pixels:
    each new size compiles a new program) instead of the whole ``width`` x ``height`` image
    (one program for every recording: what :class:`~posetrack.Tracker` uses)."""
    frames: int = 10
    """Frames :meth:`~posetrack.Tracker.run` refines on (``refine=``): the best-observed
    tracked frame of each of ``frames`` equal stretches of the recording."""
    online_after: int = 60
    """``mode="online"`` (causal): the refinement runs once, when this many frames have been
    tracked, on the best-observed frame of each of ``frames`` equal stretches of them; the
    frames after it are tracked with the refined shape."""
    online_first: int = 0
    """``mode="online"``: also refine once earlier, when this many frames have been tracked
    (0: not), on the best-observed frame of each of ``frames`` stretches of them; the frames
    after it are tracked with that shape until the refinement at ``online_after``, which
    starts again from the shape the tracker began with (the same prior), on its own frames."""
    online_spread: int = 0
    """``mode="online"``: how many :meth:`~posetrack.Tracker.update` calls share each
    refinement. 0: all of it runs inside the update that completes ``online_first`` (or
    ``online_after``) tracked frames, which returns only when it is done (a pause: ~2.5 s on
    2 CPU cores, for a live camera ~75 frames at 30 fps). S >= 1: its Adam steps are split
    into S parts of ``ceil(steps / S)`` steps, one part at each update from there (~25 ms a
    step on 2 CPU cores at the tracker's 80 x 60), and the update after the last part takes the
    refined shape up; the frames in between are tracked with the shape before it, and the
    ``online_after`` refinement starts only once the earlier one is taken up (S above
    ``online_after - online_first`` delays it). The same steps either way, in the same order;
    deterministic (no threads). On 32 tuning runs S = 10 moved D by +0.2 mm (SE 1.3) and S = 25
    by +1.8 (README, "Body shape from depth"): for a live loop that must not wait; not the
    default."""
    offline_first: int = 0
    """``mode="offline"``: before the recording is tracked, track its first this many frames
    alone and refine the shape on them (the best-observed frame of each of ``frames`` stretches
    of them); the whole recording is then tracked from that shape, and refined again after
    (0: not). A recording of no more frames than this has no pre-pass (the refinement after
    the forward pass sees the same frames)."""
    offline_first_below: float | None = None
    """With ``offline_first``: make the pre-pass only where the share of its frames' keypoints
    observed on depth (:func:`~posetrack.observed_share`) is below this (None: always). The
    pre-pass gained under occlusion and cost some clean recordings up to 3.5 mm; 0.6 separated
    the tuning clips' clean starts from their occluded ones (benchmarks/README.md, "A
    pre-pass for occluded starts")."""

    @property
    def online_part(self) -> int:
        """Adam steps per part with ``online_spread`` (``ceil(steps / online_spread)``; 0:
        not spread)."""
        return -(-self.steps // self.online_spread) if self.online_spread else 0

    @classmethod
    def tracking(cls, mode: str = "offline") -> ShapeFitSettings:
        """What :class:`~posetrack.Tracker` runs in ``mode`` (``refine="auto"``): 8 frames,
        100 steps, the whole image at 80 x 60. On tuning seeds 100-105 (6 motions x occlusion
        0/2, both generator varieties) it gave the same D as the defaults within 0.3 mm for a
        tenth of the time (about 1-3 s on 2 CPU cores); one program serves every recording.
        Online it also refines once after 20 tracked frames (``online_first``; then again after
        60, from the landmark-based shape): 59.6 -> 56.8 mm online on 40 tuning clips (seeds
        136-157, benchmarks/README.md).

        Offline (after the forward pass, for the smoother) the radii's common factor is free
        (``girth_prior_sigma`` 1.0: one girth for the body, the ratios between parts held):
        D -0.70 and -0.65 mm on two sets of 44 fresh tuning runs (t -3.8, -3.3), every report
        set's clean and occluded D lower by 0.2-1.1 mm (benchmarks/README.md, "One girth").
        Online it is not: its first screen failed on swapped-limb frames (a third more), an
        excess the same runs on another CPU did not show, and a fresh screen found no gain
        (-0.13 mm, t -0.36; benchmarks/README.md)."""
        if mode not in ("offline", "online"):
            raise ValueError(
                f"ShapeFitSettings.tracking: mode must be 'offline' or 'online', got {mode!r}"
            )
        girth = 1.0 if mode == "offline" else None
        return cls(
            width=80, height=60, steps=100, frames=8, crop=False, online_first=20,
            girth_prior_sigma=girth,
        )  # fmt: skip

    def __post_init__(self):
        unknown = [f for f in self.fields if f not in SHAPE_FIELDS]
        if unknown or not self.fields or len(set(self.fields)) != len(self.fields):
            raise ValueError(
                f"ShapeFitSettings.fields must be distinct BodyShape fields, got {self.fields!r}"
            )
        if self.frames < 1:
            raise ValueError(f"ShapeFitSettings.frames must be >= 1, got {self.frames}")
        if self.online_after < self.frames:
            raise ValueError(
                f"ShapeFitSettings.online_after must be >= frames ({self.frames}), got "
                f"{self.online_after}"
            )
        if self.online_first and not self.frames <= self.online_first < self.online_after:
            raise ValueError(
                f"ShapeFitSettings.online_first must be 0 or in [frames ({self.frames}), "
                f"online_after ({self.online_after})), got {self.online_first}"
            )
        spread = self.online_spread
        if isinstance(spread, bool) or not isinstance(spread, int) or spread < 0:
            raise ValueError(f"ShapeFitSettings.online_spread must be an int >= 0, got {spread!r}")
        if spread > self.steps:
            raise ValueError(
                f"ShapeFitSettings.online_spread must be at most steps ({self.steps}), got {spread}"
            )
        if self.offline_first and self.offline_first < self.frames:
            raise ValueError(
                f"ShapeFitSettings.offline_first must be 0 or >= frames ({self.frames}), got "
                f"{self.offline_first}"
            )
        gate = self.offline_first_below
        if gate is not None and not (math.isfinite(gate) and 0 < gate <= 1):
            raise ValueError(
                f"ShapeFitSettings.offline_first_below must be None or in (0, 1], got {gate!r}"
            )
        if self.steps < 1:
            raise ValueError(f"ShapeFitSettings.steps must be >= 1, got {self.steps}")
        for name in (
            "shape_lr", "pose_lr", "prior_sigma", "max_change", "sharpness", "d_M",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"ShapeFitSettings.{name} must be positive, got {v!r}")
        for name in ("delta_weight", "landmark_weight", "prior_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"ShapeFitSettings.{name} must be >= 0, got {v!r}")
        for name in ("radius_prior_sigma", "girth_prior_sigma"):
            r = getattr(self, name)
            if r is not None and not (math.isfinite(r) and r > 0):
                raise ValueError(f"ShapeFitSettings.{name} must be None or positive, got {r!r}")
        if self.width < 8 or self.height < 8:
            raise ValueError(
                f"ShapeFitSettings: width x height must be at least 8x8, got "
                f"{self.width}x{self.height}"
            )
        if self.loss not in ("l1", "l2"):
            raise ValueError(f"ShapeFitSettings.loss must be 'l1' or 'l2', got {self.loss!r}")


def apply_factors(
    base: BodyShape, u: Float[Array, " field"], fields: tuple[str, ...]
) -> BodyShape:
    """``base`` with each of ``fields`` scaled by ``exp(u)`` (``shoulder_drop``: plus
    ``SHOULDER_DROP_UNIT * u`` metres). Differentiable in ``u``."""
    values = {f: getattr(base, f) for f in SHAPE_FIELDS}
    for k, f in enumerate(fields):
        if f == "shoulder_drop":
            values[f] = values[f] + SHOULDER_DROP_UNIT * u[k]
        else:
            values[f] = values[f] * jnp.exp(u[k])
    return BodyShape(**values)


class _Frames(eqx.Module):
    """What the objective sees of the F frames (leading axis ``frame``). The maps are cropped
    to a window around the body (the same static size for every frame)."""

    z_d: Float[Array, "frame h w"]
    """Observed depth in the window, metres (0 off the foreground)."""
    z_fg: Float[Array, "frame h w"]
    """Observed foreground in the window (0./1.)."""
    known: Float[Array, "frame h w"]
    """1 where the sensor measured depth (``invalid_is_unknown``), else all ones."""
    fg_outside: Float[Array, " frame"]
    """Observed foreground outside the window (it enters |P_u| in full)."""
    ray_x: Float[Array, "frame 1 w"]
    """x component (z = 1) of the window's pixel rays."""
    ray_y: Float[Array, "frame h 1"]
    """y component (z = 1) of the window's pixel rays."""
    landmarks: Landmarks
    """Lifted landmarks with NO surface offset (points on the surface), per frame."""
    rays: Float[Array, "frame kpt 3"]
    """Unit viewing ray of each landmark (the surface offset is added along it)."""
    mpp: Float[Array, "frame kpt"]
    """Metres per pixel of the 2D residuals (at the start pose)."""
    weight: Float[Array, " frame"]
    """1 for a frame of the data, 0 for padding (a copy that only fills the program's frame
    count: :func:`refine_shape`'s ``pad_to``)."""


def soft_delta(
    caps: Capsules,
    ray_x: Float[Array, "1 w"],
    ray_y: Float[Array, "h 1"],
    z_d: Float[Array, "h w"],
    z_fg: Float[Array, "h w"],
    known: Float[Array, "h w"],
    fg_outside: Float[Array, ""],
    *,
    sharpness: float,
    d_M: float,
) -> Float[Array, ""]:
    """Soft Delta (Eq. (3) of the paper) of one body on a window of pixel rays.

    The same soft union and push-back soft-min as :func:`~posetrack.render_depth` (built from
    its public pieces ``capsule_fields`` and ``soft_terms``), but with every capsule evaluated at
    once instead of a scan over capsules: reverse mode then stores one (capsule, h, w) tape
    instead of one per scan step, and the window keeps it small. ``render_and_score`` with
    ``cull=False`` on the full image gives the same value (``tests/test_shapefit.py``) when the
    rendering has no coverage outside the window.
    """
    p = {k: v[:, None, None] for k, v in capsule_params(caps).items()}
    delta, z = capsule_fields(ray_x[None], ray_y[None], p)  # (P, h, w)
    lnc, score = soft_terms(delta, z, jnp.asarray(sharpness, delta.dtype))
    r_fg = -jnp.expm1(jnp.sum(lnc, axis=0)) * known
    r_d = jnp.sum(jax.nn.softmax(score, axis=0) * z, axis=0)
    matched, union = delta_sums(z_d, z_fg, r_d, r_fg, d_M)
    return delta_from_sums(matched, union + fg_outside)


def _frame_loss(shape, params, frames_f: _Frames, intrinsics, settings, res_settings):
    """(Delta, landmark term) of one frame for ``shape`` and ``params``."""
    a, b, r = capsules(shape, params)
    delta = soft_delta(
        Capsules(a=a, b=b, radius=r), frames_f.ray_x, frames_f.ray_y, frames_f.z_d,
        frames_f.z_fg, frames_f.known, frames_f.fg_outside,
        sharpness=settings.sharpness, d_M=settings.d_M,
    )  # fmt: skip
    lm = frames_f.landmarks
    # The sensor sees the surface; the joint lies one local radius behind it, and that radius
    # is being fitted: the 3D landmark moves with it (``TrackerConfig.surface_offset``).
    offset = surface_offsets(shape)
    points = jnp.where(
        lm.has_depth[:, None], lm.points3d + offset[:, None] * frames_f.rays, 0.0
    )
    use3d = lm.has_depth
    use2d = lm.detected & ~use3d
    e = landmark_residuals(
        params, shape, eqx.tree_at(lambda x: x.points3d, lm, points), intrinsics,
        use3d=use3d, use2d=use2d, metres_per_pixel=frames_f.mpp, settings=res_settings,
    )  # fmt: skip
    return delta, jnp.sum(e * e)


def prior_sigmas(settings: ShapeFitSettings) -> np.ndarray:
    """``(field,)`` the prior's standard deviation of each refined field's log-scale factor."""
    radius = settings.radius_prior_sigma or settings.prior_sigma  # None: the fields' own
    return np.asarray(
        [radius if f.endswith("_radius") else settings.prior_sigma for f in settings.fields],
        np.float32,
    )


def shape_prior(u: Float[Array, " field"], settings: ShapeFitSettings) -> Float[Array, ""]:
    """``sum |u / sigma|^2`` over the refined fields; with ``girth_prior_sigma`` the radii's
    factors are split into their mean ``g`` (weighted ``n_radii |g / girth_prior_sigma|^2``)
    and their deviations from it (each with its own sigma). With every radius at one sigma and
    ``girth_prior_sigma`` equal to it, the split sums to the unsplit prior."""
    sigma = prior_sigmas(settings)
    radii = np.asarray([f.endswith("_radius") for f in settings.fields], np.float32)
    n = float(radii.sum())
    if settings.girth_prior_sigma is None or n == 0:  # no radii refined: nothing to split
        return jnp.sum((u / sigma) ** 2)
    g = jnp.sum(u * radii) / n
    return jnp.sum(((u - g * radii) / sigma) ** 2) + n * (g / settings.girth_prior_sigma) ** 2


def _objective(u, poses, base, frames: _Frames, intrinsics, settings):
    res_settings = ResidualSettings(loss=settings.loss)
    shape = apply_factors(base, u, settings.fields)
    deltas, lms = jax.vmap(
        lambda p, fr: _frame_loss(shape, p, fr, intrinsics, settings, res_settings)
    )(poses, frames)
    w = frames.weight
    n = jnp.sum(w)
    data = jnp.sum(w * (settings.delta_weight * deltas + settings.landmark_weight * lms)) / n
    prior = settings.prior_weight * shape_prior(u, settings)
    return data + prior, (jnp.sum(w * deltas) / n, jnp.sum(w * lms) / n)


@program("refine_shape", static_argnums=(0,))
def refine_shape_core(
    settings: ShapeFitSettings,
    base: BodyShape,
    poses: Float[Array, "frame 43"],
    frames: _Frames,
    intrinsics: Intrinsics,
):
    """The jitted refinement: Adam on ``(u, poses)`` for ``settings.steps`` steps.

    Returns:
        ``(u, poses, history)``: the log-scale factors (``field``, in ``settings.fields``
        order), the refined poses (quaternions wxyz, unit) and the per-step
        ``(loss, mean Delta, mean landmark term)`` (``step 3``).
    """
    step = _adam_step(settings, base, frames, intrinsics)
    (x, _, _), history = jax.lax.scan(
        step, _start_carry(settings, poses), jnp.arange(settings.steps)
    )
    final, (d, lm) = _objective(x[0], x[1], base, frames, intrinsics, settings)
    history = jnp.concatenate([history, jnp.stack([final, d, lm])[None]])
    return x[0], x[1], history


def _start_carry(settings: ShapeFitSettings, poses):
    """The refinement's carry before its first step: ``((u, poses), m, v)`` with the factors
    ``u`` and Adam's moments zero and the given poses' quaternions normalised."""
    u0 = jnp.zeros((len(settings.fields),), _DTYPE)
    poses0 = normalize_params(poses.astype(_DTYPE))
    zeros = (u0, jnp.zeros_like(poses0))
    return (u0, poses0), zeros, zeros


def _adam_step(settings: ShapeFitSettings, base: BodyShape, frames: _Frames, intrinsics):
    """One Adam step of the refinement, ``(carry, i) -> (carry, (loss, Delta, landmark))``
    with ``carry = ((u, poses), m, v)`` and ``i`` the step's index (from 0)."""
    grad_fn = jax.value_and_grad(_objective, argnums=(0, 1), has_aux=True)
    b1, b2, eps = 0.9, 0.999, 1e-8
    lr_scale = jnp.asarray(
        [settings.shape_lr, settings.pose_lr if settings.fit_poses else 0.0], _DTYPE
    )

    def step(carry, i):
        x, m, v = carry
        (loss, (d, lm)), g = grad_fn(x[0], x[1], base, frames, intrinsics, settings)
        # A non-finite gradient (never seen; a guard, not a feature) skips the update.
        g = jax.tree.map(lambda t: jnp.where(jnp.isfinite(t), t, 0.0), g)
        m = jax.tree.map(lambda a, b: b1 * a + (1 - b1) * b, m, g)
        v = jax.tree.map(lambda a, b: b2 * a + (1 - b2) * b * b, v, g)
        t = (i + 1).astype(_DTYPE)
        # Cosine decay to 5 % of the step: Adam's steps do not shrink near the optimum by
        # themselves; the decay lets the last steps settle instead of oscillating.
        decay = 0.05 + 0.95 * 0.5 * (1 + jnp.cos(jnp.pi * t / settings.steps))
        upd = jax.tree.map(
            lambda mm, vv: (mm / (1 - b1**t)) / (jnp.sqrt(vv / (1 - b2**t)) + eps), m, v
        )
        u = jnp.clip(x[0] - decay * lr_scale[0] * upd[0], -settings.max_change, settings.max_change)
        p = normalize_params(x[1] - decay * lr_scale[1] * upd[1])
        return ((u, p), m, v), jnp.stack([loss, d, lm])

    return step


@program("refine_shape_part", static_argnums=(0, 1))
def refine_shape_part(
    settings: ShapeFitSettings,
    count: int,
    base: BodyShape,
    frames: _Frames,
    intrinsics: Intrinsics,
    carry,
    first,
):
    """``count`` of :func:`refine_shape_core`'s Adam steps, from step ``first`` (an int32
    scalar) and ``carry = ((u, poses), m, v)``; steps past ``settings.steps`` leave the carry
    as it is. Returns ``(carry, history (count, 3), final (3,))``: ``final`` is the objective
    at the carry returned (the last part's is the refinement's last history row)."""
    step = _adam_step(settings, base, frames, intrinsics)

    def masked(c, i):
        new, row = step(c, i)
        keep = i < settings.steps
        return jax.tree.map(lambda a, b: jnp.where(keep, a, b), new, c), row

    carry, history = jax.lax.scan(masked, carry, first + jnp.arange(count, dtype=jnp.int32))
    (u, poses), _, _ = carry
    final, (d, lm) = _objective(u, poses, base, frames, intrinsics, settings)
    return carry, history, jnp.stack([final, d, lm])


@program("refine_observe", rare=True)
def _observe_frames(config: TrackerConfig, intrinsics, floor, shape, poses, depths, kp2d, conf):
    """Full-size observation maps, surface landmarks, their rays and the 2D residuals' scale,
    and each frame's posed capsules, of every frame (``vmap`` over ``frame``); and the
    intrinsics of the observation maps."""

    def one(p, d, k, c):
        z_d, z_fg, known, small_intr = tracker_observation(config, d, intrinsics, floor, p[:3])
        lm = lift_keypoints(
            d, k, c, intrinsics, window=config.lift_window,
            confidence_threshold=config.confidence_threshold, rule=config.lift_rule,
        )  # fmt: skip
        norm = jnp.linalg.norm(lm.points3d, axis=-1, keepdims=True)
        rays = lm.points3d / jnp.where(norm > 0, norm, 1.0)
        known = jnp.ones_like(z_d) if known is None else known
        caps = capsules(shape, p)
        return z_d, z_fg, known, lm, rays, pixel_scale(p, shape, intrinsics), caps, small_intr

    *maps, small_intr = jax.vmap(one)(poses, depths, kp2d, conf)
    return (*maps, jax.tree.map(lambda x: x[0], small_intr))


def _frames_from_maps(
    z_d, z_fg, known, lm, rays, mpp, small_intr, origin, size, weight
) -> _Frames:
    """The objective's :class:`_Frames`: the maps cropped to windows of ``size`` (h, w) at
    ``origin`` (frame, 2: row, col), with their pixel rays and ``weight`` (frame,). Traceable
    (used to build the program signature ahead of time, :func:`refine_programs`)."""
    F = z_d.shape[0]
    h, w = size
    rows = origin[:, :1] + np.arange(h)[None]  # (frame, h)
    cols = origin[:, 1:] + np.arange(w)[None]  # (frame, w)
    f = np.arange(F)[:, None, None]

    def crop(img):
        return img[f, rows[:, :, None], cols[:, None, :]]

    z_fg_win = crop(z_fg)
    return _Frames(
        z_d=crop(z_d),
        z_fg=z_fg_win,
        known=crop(known),
        fg_outside=jnp.sum(z_fg, axis=(1, 2)) - jnp.sum(z_fg_win, axis=(1, 2)),
        ray_x=((cols - small_intr.cx) / small_intr.fx)[:, None, :].astype(_DTYPE),
        ray_y=((rows - small_intr.cy) / small_intr.fy)[:, :, None].astype(_DTYPE),
        landmarks=lm,
        rays=rays,
        mpp=mpp,
        weight=jnp.asarray(weight, _DTYPE),
    )


def refine_programs(
    settings: ShapeFitSettings, config: TrackerConfig, shape, intrinsics: Intrinsics, frames: int,
    part: int = 0,
) -> list[tuple]:
    """``(program, argument signature)`` of the two programs :func:`refine_shape` runs on
    ``frames`` frames of ``intrinsics``' size, for :meth:`~posetrack._programs.Program.prepare`
    (``settings.crop`` must be off: a cropped window's size is known only from the data);
    ``part`` > 0: the refinement a part of that many steps at a time instead of whole."""
    if settings.crop:
        raise ValueError("refine_programs: the window size of crop=True depends on the data")
    f32 = partial(jax.ShapeDtypeStruct, dtype=_DTYPE)
    H, W = intrinsics.shape
    cfg = config.replace(score_width=settings.width, score_height=settings.height)
    observe_args = (
        cfg, intrinsics, f32((4,)), shape, f32((frames, 43)), f32((frames, H, W)),
        f32((frames, 18, 2)), f32((frames, 18)),
    )  # fmt: skip
    maps = jax.eval_shape(_observe_frames.fn, *observe_args)
    size = maps[0].shape[1:]
    frames_sig = jax.eval_shape(
        lambda *m: _frames_from_maps(
            *m[:6], m[-1], np.zeros((frames, 2), int), size, np.zeros(frames, np.float32)
        ),
        *maps[:6], maps[-1],
    )
    if part:
        u, poses = f32((len(settings.fields),)), f32((frames, 43))
        carry = ((u, poses), (u, poses), (u, poses))
        run = (refine_shape_part, (
            settings, part, shape, frames_sig, intrinsics, carry, jax.ShapeDtypeStruct((), np.int32)
        ))  # fmt: skip
    else:
        run = (refine_shape_core, (settings, shape, f32((frames, 43)), frames_sig, intrinsics))
    return [(_observe_frames, observe_args), run]


def _windows(z_fg, caps, small_intr: Intrinsics, margin: int, step: int):
    """Origins (frame, 2: row, col) and the common size (h, w) of windows holding each
    frame's observed foreground and its rendered capsules (grown by their radius and 25 %, a
    shape may grow) plus ``margin`` pixels; the size is rounded up to ``step`` so clips of
    similar size share one compiled program."""
    a, b, r = (np.asarray(x, np.float64) for x in caps)
    K = np.asarray(small_intr.as_matrix(), np.float64)
    H, W = small_intr.height, small_intr.width
    boxes = []
    for f in range(len(a)):
        pts = np.concatenate([a[f], b[f]])
        rad = np.concatenate([r[f], r[f]]) * 1.25
        z = np.maximum(pts[:, 2], 0.2)
        u = K[0, 0] * pts[:, 0] / z + K[0, 2]
        v = K[1, 1] * pts[:, 1] / z + K[1, 2]
        ru, rv = K[0, 0] * rad / z, K[1, 1] * rad / z
        lo = [np.min(v - rv), np.min(u - ru)]
        hi = [np.max(v + rv), np.max(u + ru)]
        rows, cols = np.nonzero(np.asarray(z_fg[f]) > 0)
        if len(rows):
            lo = [min(lo[0], rows.min()), min(lo[1], cols.min())]
            hi = [max(hi[0], rows.max()), max(hi[1], cols.max())]
        boxes.append((*lo, *hi))
    boxes = np.asarray(boxes)
    span = np.ceil(np.max(boxes[:, 2:] - boxes[:, :2], axis=0)).astype(int) + 1 + 2 * margin
    size_h = min(H, -(-int(span[0]) // step) * step)
    size_w = min(W, -(-int(span[1]) // step) * step)
    centre = 0.5 * (boxes[:, :2] + boxes[:, 2:])
    r0 = np.clip(np.round(centre[:, 0] - size_h / 2), 0, H - size_h).astype(int)
    c0 = np.clip(np.round(centre[:, 1] - size_w / 2), 0, W - size_w).astype(int)
    return np.stack([r0, c0], axis=1), (size_h, size_w)


def _floor_for(depth_m: np.ndarray, intrinsics: Intrinsics, params: np.ndarray):
    """The tracker's floor rule (``Tracker._fit_floor``): a RANSAC plane the root stands
    0.3-1.6 m above, else none."""
    try:
        normal, offset = fit_floor_plane(depth_m, intrinsics)
    except ValueError:
        return NO_FLOOR
    if not 0.3 <= float(np.dot(normal, params[:3]) + offset) <= 1.6:
        return NO_FLOOR
    return (*[float(v) for v in normal], float(offset))


def refine_shape(
    shape: BodyShape,
    params,
    depths,
    keypoints2d,
    confidence,
    intrinsics: Intrinsics,
    *,
    settings: ShapeFitSettings = ShapeFitSettings(),
    config: TrackerConfig | None = None,
    floor="auto",
    depth_scale: float = 1000.0,
    pad_to: int | None = None,
) -> tuple[BodyShape, dict]:
    """Refine body dimensions (and the given poses) against the depth of F frames.

    See the module docstring for the objective. Typical use: track the first frames with the
    landmark-based shape, take 8-15 tracked frames with varied poses, refine, and track again
    with ``shape=refined``.

    Args:
        shape: the starting shape (the prior's centre), e.g. ``TrackResult.shape``.
        params: (F, 43) poses of the F frames fitted with ``shape`` (quaternions wxyz).
        depths: (F, H, W) depth, uint16 sensor units (``depth_scale`` per metre) or float
            metres; 0 / NaN invalid.
        keypoints2d: (F, 18, 2) detected COCO-18 keypoints of the person, pixels.
        confidence: (F, 18) detector confidence (0 = not detected).
        intrinsics: the depth camera (size H x W).
        settings: the optimiser and objective (:class:`ShapeFitSettings`).
        config: the tracker configuration whose observation preprocessing and lifting are used
            (``TrackerConfig()`` by default).
        floor: ``"auto"`` (fit on the first frame with the tracker's rule), ``None`` (no floor
            removal) or ``(nx, ny, nz, d)``.
        depth_scale: sensor units per metre of uint16 depth.
        pad_to: compile for this many frames (at least F): the extra frames are copies of
            the first with weight 0, so they change nothing, and clips that keep different
            numbers of frames share one compiled program (``Tracker`` pads to
            ``settings.frames``). ``None``: F.

    Returns:
        ``(refined, report)``: the refined :class:`BodyShape` (float32), and a dict with
        ``factors`` (field -> refined / input; ``shoulder_drop``: metres added), ``before``
        and ``after`` (mean Delta, mean landmark term, loss), ``params`` ((F, 43) refined poses,
        NumPy), ``history`` ((steps + 1, 3): loss, Delta, landmark term) and ``seconds``.

    Raises:
        ValueError: naming the argument, for inconsistent shapes or non-finite values.
    """
    return _start_refinement(
        shape, params, depths, keypoints2d, confidence, intrinsics, settings=settings,
        config=config, floor=floor, depth_scale=depth_scale, pad_to=pad_to,
    ).run()  # fmt: skip


def _start_refinement(
    shape, params, depths, keypoints2d, confidence, intrinsics, *, settings, config, floor,
    depth_scale, pad_to,
) -> _Refinement:
    """:func:`refine_shape`'s checks and observation maps (its arguments), ready to run."""
    if not isinstance(shape, BodyShape):
        raise ValueError(f"refine_shape: shape must be a posetrack.BodyShape, got {type(shape)}")
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(
            f"refine_shape: intrinsics must be posetrack.Intrinsics, got {type(intrinsics)}"
        )
    if not isinstance(settings, ShapeFitSettings):
        raise ValueError(
            f"refine_shape: settings must be a ShapeFitSettings, got {type(settings)}"
        )
    config = config or TrackerConfig()
    if not isinstance(config, TrackerConfig):
        raise ValueError(f"refine_shape: config must be a TrackerConfig, got {type(config)}")
    vals = shape.to_dict()
    if not all(np.isfinite(list(vals.values()))):
        raise ValueError(f"refine_shape: shape has non-finite fields: {vals}")
    P = np.asarray(params, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 43 or P.shape[0] < 1:
        raise ValueError(f"refine_shape: params must have shape (F, 43), got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("refine_shape: params contain non-finite values")
    F = P.shape[0]
    D = np.asarray(depths)
    H, W = intrinsics.shape
    if D.shape != (F, H, W):
        raise ValueError(
            f"refine_shape: depths must have shape (F, H, W) = {(F, H, W)} (F from params, "
            f"H x W from intrinsics), got {D.shape}"
        )
    if D.dtype == np.uint16:
        D = D.astype(np.float32) / np.float32(depth_scale)
    elif np.issubdtype(D.dtype, np.floating):
        D = D.astype(np.float32)
    else:
        raise ValueError(f"refine_shape: depths must be uint16 or float, got {D.dtype}")
    K = np.asarray(keypoints2d, dtype=np.float32)
    C = np.asarray(confidence, dtype=np.float32)
    if K.shape != (F, 18, 2):
        raise ValueError(f"refine_shape: keypoints2d must have shape {(F, 18, 2)}, got {K.shape}")
    if C.shape != (F, 18):
        raise ValueError(f"refine_shape: confidence must have shape {(F, 18)}, got {C.shape}")
    bad = ~np.isfinite(K).all(axis=-1) | ~np.isfinite(C)
    C = np.where(bad, 0.0, C).astype(np.float32)
    K = np.where(bad[..., None], 0.0, K).astype(np.float32)
    if H < settings.height or W < settings.width:
        raise ValueError(
            f"refine_shape: depth {W}x{H} is smaller than settings' {settings.width}x"
            f"{settings.height}"
        )
    if isinstance(floor, str):
        if floor != "auto":
            raise ValueError(
                f"refine_shape: floor must be 'auto', None or 4 numbers, got {floor!r}"
            )
        floor = _floor_for(D[0], intrinsics, P[0]) if config.use_floor else NO_FLOOR
    elif floor is None:
        floor = NO_FLOOR
    floor = np.asarray(floor, dtype=np.float32)
    if floor.shape != (4,) or not np.all(np.isfinite(floor)):
        raise ValueError(f"refine_shape: floor must be (nx, ny, nz, d), got {floor!r}")

    if pad_to is not None and pad_to < F:
        raise ValueError(f"refine_shape: pad_to must be at least the {F} frames, got {pad_to}")
    weight = np.ones(F, np.float32)
    if pad_to is not None and pad_to > F:
        idx = np.concatenate([np.arange(F), np.zeros(pad_to - F, int)])
        P, D, K, C = P[idx], D[idx], K[idx], C[idx]
        weight = (np.arange(pad_to) < F).astype(np.float32)

    t0 = time.perf_counter()
    cfg = config.replace(score_width=settings.width, score_height=settings.height)
    # Inputs converted on the host (device_f32, device_put): eager jnp conversions were small
    # programs compiled one by one while the refinement's own programs compiled beside them.
    intr = jax.tree.map(device_f32, intrinsics)
    base = jax.tree.map(device_f32, shape)
    poses = device_f32(P)
    z_d, z_fg, known, lm, rays, mpp, caps, small_intr = _observe_frames(
        cfg, intr, jax.device_put(floor), base, poses, jax.device_put(D), jax.device_put(K),
        jax.device_put(C),
    )  # fmt: skip
    if settings.crop:
        small = jax.tree.map(float, small_intr)
        origin, size = _windows(z_fg, caps, small, margin=4, step=16)
    else:
        origin, size = np.zeros((len(P), 2), int), z_d.shape[1:]
    host = partial(jax.tree.map, np.asarray)
    frames = jax.tree.map(jax.device_put, _frames_from_maps(
        *host((z_d, z_fg, known, lm, rays, mpp)), host(small_intr), origin, size, weight
    ))  # fmt: skip
    return _Refinement(settings, base, poses, frames, intr, F, size, t0)


class _Refinement:
    """A :func:`refine_shape` whose observation maps are made: :meth:`run` runs it whole
    (one program); :meth:`part` runs its Adam steps a part at a time (``Tracker``'s
    ``online_spread``) and :meth:`finish` then returns the same ``(refined, report)``."""

    def __init__(self, settings, base, poses, frames, intr, F: int, size, t0: float):
        self.settings, self.base, self.poses, self.frames, self.intr = (
            settings, base, poses, frames, intr
        )
        self.F, self.size, self.t0 = F, size, t0
        self.done = 0
        """Adam steps run by :meth:`part`."""
        self._carry = None
        self._history: list = []
        self._final = None
        self.busy_s = 0.0
        """Seconds spent in :meth:`part` calls (and in making the maps)."""
        self._started = time.perf_counter()

    def run(self) -> tuple[BodyShape, dict]:
        u, poses_out, history = refine_shape_core(
            self.settings, self.base, self.poses, self.frames, self.intr
        )
        return self._result(u, poses_out, history)

    def part(self, count: int) -> None:
        """Run the next ``count`` Adam steps (fewer at the end), waiting for them."""
        t0 = time.perf_counter()
        if self._carry is None:
            self._carry = _start_carry(self.settings, self.poses)
        self._carry, history, self._final = refine_shape_part(
            self.settings, count, self.base, self.frames, self.intr, self._carry,
            np.int32(self.done),
        )  # fmt: skip
        keep = min(count, self.settings.steps - self.done)
        self._history.append(np.asarray(history)[:keep])
        self.done += keep
        self.busy_s += time.perf_counter() - t0

    def finish(self) -> tuple[BodyShape, dict]:
        """``(refined, report)`` once :meth:`part` has run every step; the report's
        ``seconds`` are the parts' (and the maps'), not the wall time they spanned."""
        if self.done < self.settings.steps:
            raise RuntimeError(f"refinement: {self.done} of {self.settings.steps} steps run")
        (u, poses_out), _, _ = self._carry
        history = np.concatenate([*self._history, np.asarray(self._final)[None]])
        return self._result(u, poses_out, history, self.busy_s + self._started - self.t0)

    def _result(self, u, poses_out, history, seconds=None) -> tuple[BodyShape, dict]:
        settings, base, F, size = self.settings, self.base, self.F, self.size
        u = np.asarray(u, dtype=np.float64)
        history = np.asarray(history, dtype=np.float64)
        refined = apply_factors(base, device_f32(u), settings.fields)
        refined = jax.tree.map(lambda x: jnp.asarray(x, _DTYPE), refined)
        factors = {
            f: (float(SHOULDER_DROP_UNIT * u[k]) if f == "shoulder_drop" else float(np.exp(u[k])))
            for k, f in enumerate(settings.fields)
        }
        if seconds is None:
            seconds = time.perf_counter() - self.t0

        def summary(row):
            return {"loss": float(row[0]), "delta": float(row[1]), "landmark": float(row[2])}

        report = {
            "factors": factors,
            "before": summary(history[0]),
            "after": summary(history[-1]),
            "params": np.asarray(poses_out, dtype=np.float64)[:F],
            "history": history,
            "seconds": seconds,
            "frames": F,
            "window": tuple(int(v) for v in size),
        }
        return refined, report
