"""One tracker step: LVM (the paper's baseline) and the Multiple Hypothesis Tracker (MHT_r/g/h).

One frame is ONE jitted call (:func:`tracker_step`): lifting, landmark weights and subset
sampling, N Levenberg-Marquardt fits (vmapped), N renders and Delta scores (Eq. (3)), selection
of the best hypothesis. Shapes are static: a configuration compiles once and then runs every
frame without recompiling. The host-side ``Tracker`` (``_tracker.py``) adds what is not
per-frame math: body-shape estimation, initialisation from observations, track-loss
handling, progress.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from . import _body as body
from ._camera import Intrinsics, project
from ._depthobs import downsample_depth, observation_maps
from ._fit import FitSettings, fit_hypotheses, fit_pose
from ._observe import Landmarks, lift_keypoints
from ._refine import refine_pose
from ._render import DEFAULT_SHARPNESS, Capsules
from ._residuals import ResidualSettings
from ._score import DEFAULT_D_M, render_and_score
from ._select import (
    GEOMETRY_PARTNER,
    L_2D,
    gaussian_weight,
    geometry_distance,
    sample_subset,
    temporal_distance,
)

Method = Literal["lvm", "mht_r", "mht_g", "mht_h"]
METHODS: tuple[str, ...] = ("lvm", "mht_r", "mht_g", "mht_h")

#: LM steps per frame of each MHT hypothesis' fit (``TrackerConfig.fit``'s default for MHT).
MHT_FIT_STEPS = 4

#: Frame status codes (also the strings written to files).
TRACKED, LOST, NO_OBSERVATION = 0, 1, 2
STATUS_NAMES = ("tracked", "lost", "no_observation")


@dataclasses.dataclass(frozen=True)
class TrackerConfig:
    """Everything that selects a tracker variant. Hashable: it is the jit-static part.

    The defaults are our recommended tracker: MHT_h with the paper's r = R = 0, N = 10, sigmas
    tuned on generated sequences disjoint from the benchmark's, and the switchable additions
    that the benchmark showed to help (reseed, consensus refit, surface offset, unknown
    invalid depth). :meth:`paper` gives the paper's best (N, r, R) of each method (its Table 2)
    with the other settings at these defaults.
    """

    method: str = "mht_h"
    """"lvm" (all landmarks, one hypothesis), "mht_r", "mht_g" or "mht_h"."""
    num_hypotheses: int = 10
    """N; forced to 1 for LVM. The paper's MHT_h uses 5 (``TrackerConfig.paper``); 10 was
    about 5 % more accurate on our benchmark at about 1.6x the cost."""
    r: float = 0.0
    """Random exclusion ratio of 2D landmarks (w^r = 1 - r)."""
    R: float = 0.0
    """Random exclusion ratio of 3D landmarks (W^r = 1 - R)."""
    sigma_g: float = 1.5
    """sigma_g of W^g = exp(-d_g / (2 sigma_g^2)); d_g in [0, 1]."""
    sigma_h: float = 0.5
    """sigma_h of W^h = exp(-d_h / (2 sigma_h^2)); d_h in [0, 1]."""
    d_hmax: float = 0.45
    """Truncation distance of d_h, metres."""
    d_M: float = DEFAULT_D_M
    """Depth clamp of Eq. (3), metres."""
    score_width: int = 160
    """Width of the depth maps Delta is computed on (the sensor's depth is downsampled)."""
    score_height: int = 120
    """Height of the depth maps Delta is computed on."""
    sharpness: float = DEFAULT_SHARPNESS
    """Soft rasteriser sharpness, 1/metre (the dense refinement; and the scoring when
    ``hard_scoring`` is False)."""
    hard_scoring: bool = True
    """Score hypotheses (Eq. (3)) with the hard renderer, i.e. exact ray casting of the
    capsules, as the paper does. Scoring needs no gradient; the hard renderer is 2-3x faster
    than the soft one. False: the soft renderer at ``sharpness``."""
    body_range: float = 1.2
    """Observation preprocessing: keep depth within this distance (metres) of the previous
    estimate's root laterally and in depth (the paper's 'predefined range')."""
    lift_window: int = 5
    """Side of the depth window (pixels, at the sensor's resolution) of the lifting median."""
    confidence_threshold: float = 0.4
    """A keypoint is detected (f_i) when its confidence exceeds this."""
    surface_offset: bool = True
    """Push lifted landmarks back by the local body radius (surface -> joint centre). Not in
    the paper; see README "Beyond the paper"."""
    fit: FitSettings | None = None
    """Levenberg-Marquardt settings of the per-frame fits (and the initialisation's, with
    ``init_steps``). ``None``: the method's default, resolved at construction:

    * MHT: 4 LM steps with the plain least-squares loss ``"l2"``. Its subsets and consensus
      refit already keep outliers out, and squares are the efficient estimator for the
      inliers (5-7 % lower D than ``"l1"`` on our tuning sequences). Each hypothesis starts
      from its own previous pose every frame; stopping after 4 steps keeps it near that pose
      (a temporal smoothing) and was both faster and more accurate than 6, 8 or 12 steps
      (D 69.2 / 71.7 / 72.9 mm on seed 100, 58.0 / 60.7 / 64.6 mm on seeds 101-102).
    * LVM: ``FitSettings()`` (8 steps) with the paper's sum of norms ``"l1"`` (robust: all
      landmarks, outliers included, enter its fit; ``"l2"`` was 1.8x worse)."""
    init_steps: int = 60
    """LM steps of the (re-)initialisation fit on all landmarks."""
    shape_frames: int = 15
    """Frames used to estimate the body dimensions when none are given."""
    reseed: bool = True
    """Replace the worst hypothesis by the best after each frame (drift remedy)."""
    reseed_margin: float = 0.15
    """With ``reseed``, also replace every hypothesis whose Delta exceeds the best's by more
    than this (1.0: only the worst is replaced). 0.05 reseeded too eagerly: a hypothesis that
    had drawn a limb's true keypoints after a run of left/right swaps was overwritten before it
    could win, and the limb stayed wrong (see README, Limitations)."""
    consensus_refit: bool = True
    """Refit the winner on all landmarks within ``consensus_distance`` of it (not in the paper)."""
    consensus_distance: float = 0.12
    """Metres (2D: at the keypoint's depth) within which a landmark agrees with the winner."""
    invalid_is_unknown: bool = True
    """Delta ignores rendered body over pixels without valid depth (holes, removed areas): the
    sensor cannot say the body is not there. False: Eq. (3) as written, where such pixels count
    as background. Not in the paper; see README "Beyond the paper"."""
    refine_steps: int = 0
    """LM steps of the final refinement of the output pose against the dense depth through
    the soft rasteriser (0 = off; not in the paper)."""
    refine_width: int = 80
    """Width of the depth maps the refinement renders (its Jacobian costs 43 renders)."""
    refine_height: int = 60
    """Height of the depth maps the refinement renders."""
    refine_weight: float = 2.0
    """Weight of Delta against the landmark term in the refinement."""
    lost_delta: float = 0.85
    """A frame whose best Delta exceeds this is 'lost'."""
    lost_agreement: float = 0.6
    """A frame whose output pose lies within ``consensus_distance`` of fewer than this share of
    its 3D landmarks is 'lost' (an implausible pose: it explains too little of what is seen)."""
    lost_patience: int = 5
    """Consecutive lost frames before the tracker re-initialises from observations."""
    min_landmarks: int = 4
    """Fewer 3D landmarks than this: the frame is 'no_observation' (pose held)."""
    use_floor: bool = True
    """Fit a floor plane at (re-)initialisation and drop depth near it from the observation. A
    plane is used only if the body's root lies 0.3-1.6 m above it (else: no floor)."""

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"TrackerConfig.method must be one of {METHODS}, got {self.method!r}")
        if self.fit is None:
            fit = (
                FitSettings(residuals=ResidualSettings(loss="l1"))
                if self.method == "lvm"
                else FitSettings(max_steps=MHT_FIT_STEPS, residuals=ResidualSettings(loss="l2"))
            )
            object.__setattr__(self, "fit", fit)
        elif not isinstance(self.fit, FitSettings):
            raise ValueError(f"TrackerConfig.fit must be a FitSettings or None, got {self.fit!r}")
        if self.num_hypotheses < 1:
            raise ValueError(
                f"TrackerConfig.num_hypotheses must be >= 1, got {self.num_hypotheses}"
            )
        for name in ("r", "R"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ValueError(f"TrackerConfig.{name} must be in [0, 1), got {v}")
        for name in ("sigma_g", "sigma_h", "d_hmax", "d_M", "sharpness", "body_range"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"TrackerConfig.{name} must be a positive number, got {v!r}")
        if self.score_width < 8 or self.score_height < 8:
            raise ValueError(
                f"TrackerConfig: score size must be at least 8x8, got "
                f"{self.score_width}x{self.score_height}"
            )

    @property
    def n(self) -> int:
        """Number of hypotheses actually used (1 for LVM)."""
        return 1 if self.method == "lvm" else self.num_hypotheses

    @staticmethod
    def recommended(method: str = "mht_h", **overrides) -> TrackerConfig:
        """What we ship for ``method``: the defaults for MHT_h (N = 10), the paper's best
        (N, r, R) for the other methods (:meth:`paper`)."""
        if method == "mht_h":
            return TrackerConfig(**{"method": "mht_h", **overrides})
        return TrackerConfig.paper(method, **overrides)

    @staticmethod
    def paper(method: str, **overrides) -> TrackerConfig:
        """The paper's best setting of ``method`` (its Table 2): LVM; MHT_r N=20 r=0.05 R=0.15;
        MHT_g N=5 r=0.05 R=0.15; MHT_h N=5 r=R=0; all with Eq. (1)'s sum of norms (``"l1"``).
        Other fields take the defaults unless overridden (``reseed=False,
        consensus_refit=False`` gives the paper's method alone)."""
        l1 = FitSettings(residuals=ResidualSettings(loss="l1"))
        base = {
            "lvm": dict(method="lvm", num_hypotheses=1, fit=l1),
            "mht_r": dict(method="mht_r", num_hypotheses=20, r=0.05, R=0.15, fit=l1),
            "mht_g": dict(method="mht_g", num_hypotheses=5, r=0.05, R=0.15, fit=l1),
            "mht_h": dict(method="mht_h", num_hypotheses=5, r=0.0, R=0.0, fit=l1),
        }
        if method not in base:
            raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
        return TrackerConfig(**{**base[method], **overrides})


#: Fields of TrackerConfig that change no shape and no code path: they are passed to the jitted
#: step as traced arrays, so changing them (a parameter sweep, Table 1 of the paper) never
#: recompiles. Everything else in TrackerConfig is static.
TUNABLE_FIELDS = (
    "r", "R", "sigma_g", "sigma_h", "d_hmax", "d_M", "sharpness", "body_range",
    "confidence_threshold", "consensus_distance", "refine_weight", "reseed_margin",
)  # fmt: skip


def split_config(
    config: TrackerConfig, dtype=jnp.float32
) -> tuple[TrackerConfig, dict[str, Array]]:
    """(static part, tunables): the static part has every tunable reset to its default, so two
    configurations that differ only in tunables share one compiled step."""
    defaults = TrackerConfig(method=config.method)
    static = dataclasses.replace(config, **{f: getattr(defaults, f) for f in TUNABLE_FIELDS})
    tunables = {f: jnp.asarray(getattr(config, f), dtype) for f in TUNABLE_FIELDS}
    return static, tunables


class ConfigView:
    """A TrackerConfig whose tunable fields are (traced) arrays; used inside the jitted step."""

    def __init__(self, static: TrackerConfig, tunables: dict[str, Array]):
        self._static = static
        self._tunables = tunables

    def __getattr__(self, name):
        if name in TUNABLE_FIELDS:
            return self._tunables[name]
        return getattr(self._static, name)


class TrackState(eqx.Module):
    """What the tracker carries from one frame to the next."""

    hypotheses: Float[Array, "hyp 43"]
    """Each hypothesis' pose (unit quaternions)."""
    previous: Float[Array, "hyp kpt 3"]
    """Each hypothesis' model keypoints M^h at the previous frame, metres (for W^h)."""
    best: Float[Array, 43]
    """The previous frame's output pose."""
    key: PRNGKeyArray
    """Random key, split once per frame."""


class FrameEstimate(eqx.Module):
    """The tracker's output for one frame (arrays; batched over frames by :class:`Tracker`)."""

    params: Float[Array, 43]
    """The selected pose."""
    keypoints3d: Float[Array, "kpt 3"]
    """Its 18 keypoints, metres, camera frame."""
    delta: Float[Array, ""]
    """Delta of the selected hypothesis (Eq. (3)); in [0, 1]."""
    deltas: Float[Array, " hyp"]
    """Delta of every hypothesis."""
    best: Int[Array, ""]
    """Index of the selected hypothesis."""
    hypotheses: Float[Array, "hyp 43"]
    """Every hypothesis' fitted pose this frame (before any re-seeding)."""
    num_3d: Int[Array, ""]
    """Landmarks with depth (sum of F_i)."""
    agreement: Float[Array, ""]
    """Share of the 3D landmarks within ``consensus_distance`` of the output pose's keypoints
    (1 when there are none): a pose that explains few of its landmarks is implausible."""
    num_2d: Int[Array, ""]
    """Detected keypoints (sum of f_i)."""
    spread: Float[Array, " kpt"]
    """Per keypoint, the median distance (metres) of the hypotheses' keypoints from the selected
    one: how much the hypotheses disagree about it (0 for LVM)."""
    used3d: Bool[Array, "hyp kpt"]
    """Which 3D landmarks each hypothesis drew."""
    used2d: Bool[Array, "hyp kpt"]
    """Which 2D landmarks each hypothesis drew (a 2D residual enters the fit only where the
    keypoint's 3D landmark was not used)."""
    fit_ok: Bool[Array, " hyp"]
    """Whether each hypothesis' LM solve returned a finite pose."""
    landmarks: Landmarks
    """The lifted observations of this frame."""


def surface_offsets(shape: body.BodyShape) -> Float[Array, " kpt"]:
    """Depth of each keypoint's joint centre behind the body surface the sensor sees, metres.

    Face keypoints (nose, eyes, ears) are on the surface (0); the others lie about one local
    part radius behind it.
    """
    z = jnp.zeros_like(shape.torso)
    sh, el, wr = (
        1.1 * shape.upper_arm_radius,
        1.1 * shape.forearm_radius,
        0.9 * shape.forearm_radius,
    )
    hip, kn, an = 1.35 * shape.thigh_radius, shape.shin_radius, 0.8 * shape.shin_radius
    neck = 0.6 * shape.torso_radius
    return jnp.stack([z, neck, sh, el, wr, sh, el, wr, hip, kn, an, hip, kn, an, z, z, z, z])


def _rest_lengths(shape: body.BodyShape) -> Array:
    rest = body.keypoints(shape, body.facing_camera_params(3.0, dtype=shape.torso.dtype))
    partner = np.asarray(GEOMETRY_PARTNER, np.int32)
    return jnp.maximum(jnp.linalg.norm(rest - rest[partner], axis=-1), 0.03)


def _part_radii(shape: body.BodyShape) -> Array:
    """Radius of the part between each keypoint and its geometry partner, metres."""
    z = 0.05 * jnp.ones_like(shape.torso)
    ua, fa = shape.upper_arm_radius, shape.forearm_radius
    th, sn, to = shape.thigh_radius, shape.shin_radius, shape.torso_radius
    return jnp.stack([z, to, to, ua, fa, to, ua, fa, to, th, sn, to, th, sn, z, z, z, z])


def scoring_size(
    config: TrackerConfig, height: int, width: int, *, refine: bool = False
) -> tuple[int, int]:
    """(h, w) of the scoring maps: ``score_width`` wide, and ``score_height`` high when it has the
    sensor's aspect ratio (within 2 %); otherwise the height follows the sensor's aspect ratio
    (e.g. 160x90 for a 16:9 sensor), so the maps never drop part of the image. With ``refine``,
    the same for ``refine_width`` x ``refine_height``."""
    if refine:
        w, h = config.refine_width, config.refine_height
    else:
        w, h = config.score_width, config.score_height
    if abs(h / w - height / width) > 0.02 * height / width:
        h = max(8, round(w * height / width))
    return h, w


def score_depth(
    depth: Float[Array, "H W"],
    intrinsics: Intrinsics,
    config: TrackerConfig,
    *,
    refine: bool = False,
) -> tuple[Float[Array, "h w"], Intrinsics]:
    """The sensor depth at the scoring resolution, and the matching intrinsics.

    Blocks of ``(H // h) x (W // w)`` pixels are reduced by ``downsample_depth``; a remainder
    of rows/columns that does not fill a block (e.g. 1080 = 9 x 120 fits, 1000 would not) is
    cropped from the bottom/right first, which leaves fx, fy, cx, cy unchanged.
    """
    H, W = depth.shape
    h, w = scoring_size(config, H, W, refine=refine)
    if H < h or W < w:
        raise ValueError(f"depth {W}x{H} is smaller than the scoring size {w}x{h}")
    fy, fx = H // h, W // w
    cropped = depth[: h * fy, : w * fx]
    crop_intr = Intrinsics(
        fx=intrinsics.fx, fy=intrinsics.fy, cx=intrinsics.cx, cy=intrinsics.cy,
        width=w * fx, height=h * fy,
    )  # fmt: skip
    return downsample_depth(cropped, (fy, fx)), crop_intr.scaled(w, h)


def observation(config, depth, intrinsics, floor, center, *, refine: bool = False):
    """(z_d, z_fg, known, intrinsics) at the scoring (or refinement) resolution: the paper's
    observation preprocessing around ``center`` (the previous root position)."""
    small, small_intr = score_depth(depth, intrinsics, config, refine=refine)
    known = (small > 0).astype(small.dtype) if config.invalid_is_unknown else None
    z_d, z_fg = observation_maps(
        small, small_intr, center=center, radius=config.body_range, floor=(floor[:3], floor[3])
    )
    return z_d, z_fg, known, small_intr


#: Floor plane (nx, ny, nz, d) used when none was found: 100 m below, so nothing is dropped.
NO_FLOOR = (0.0, -1.0, 0.0, 100.0)


def _landmarks(config, shape, intrinsics, depth, kp2d, conf) -> Landmarks:
    offset = surface_offsets(shape) if config.surface_offset else 0.0
    return lift_keypoints(
        depth, kp2d, conf, intrinsics,
        window=config.lift_window, confidence_threshold=config.confidence_threshold,
        depth_offset=offset,
    )  # fmt: skip


def _selection(config: TrackerConfig, key, shape, intrinsics, depth, lm: Landmarks, previous):
    """(use3d, use2d) per hypothesis: the landmark subsets of the MHT, all landmarks for LVM."""
    N = config.n
    F, f = lm.has_depth, lm.detected
    if config.method == "lvm":
        return jnp.broadcast_to(F, (N, 18)), jnp.broadcast_to(f, (N, 18))
    dtype = lm.points3d.dtype
    W = jnp.full((N, 18), 1.0 - config.R, dtype)
    w = jnp.full((N, 18), 1.0 - config.r, dtype)
    if config.method in ("mht_g", "mht_h"):
        partner = np.asarray(GEOMETRY_PARTNER, np.int32)
        rest = _rest_lengths(shape)
        radii = _part_radii(shape)

        def geom(prev):
            # The partner is the observed landmark where it has depth, else this hypothesis'
            # previous model keypoint.
            pts = jnp.where(F[partner][:, None], lm.points3d[partner], prev[partner])
            return geometry_distance(lm, pts, jnp.ones((18,), bool), rest, radii, depth, intrinsics)

        Wg = gaussian_weight(jax.vmap(geom)(previous), config.sigma_g)
        W = jnp.minimum(W, Wg)
        w = jnp.minimum(w, jnp.where(F, L_2D * Wg + (1 - L_2D), 1.0))
    if config.method == "mht_h":
        d3, d2 = jax.vmap(
            lambda prev: temporal_distance(lm, prev, intrinsics, d_hmax=config.d_hmax)
        )(previous)
        Wh = gaussian_weight(d3, config.sigma_h)
        wh2 = gaussian_weight(d2, config.sigma_h)
        W = jnp.minimum(W, Wh)
        w = jnp.minimum(w, jnp.where(F, L_2D * Wh + (1 - L_2D), L_2D * wh2 + (1 - L_2D)))
    keys = jax.random.split(key, (N, 2))
    use3d = jax.vmap(sample_subset, in_axes=(0, 0, None))(keys[:, 0], W, F)
    use2d = jax.vmap(sample_subset, in_axes=(0, 0, None))(keys[:, 1], w, f)
    return use3d, use2d


def _score(config, shape, params, z_d, z_fg, small_intr, known):
    """Delta of Eq. (3) of each hypothesis in ``params`` (hyp, 43): the scoring renderer."""
    return render_and_score(
        _capsules_batch(shape, params), z_d, z_fg, small_intr,
        sharpness=None if config.hard_scoring else config.sharpness, d_M=config.d_M,
        known=known,
    )  # fmt: skip


def _capsules_batch(shape, params) -> Capsules:
    a, b, radius = jax.vmap(lambda p: body.capsules(shape, p))(params)
    return Capsules(a=a, b=b, radius=radius)


def _reseed(config, params, deltas, best, chosen):
    """The hypotheses carried to the next frame: with ``reseed``, the worst hypothesis and any
    whose Delta trails the best by more than ``reseed_margin`` restart from the winner (they
    then diverge again through their own subsets)."""
    if not (config.reseed and config.n > 1):
        return params
    worse = (deltas > deltas[best] + config.reseed_margin) | (
        jnp.arange(config.n) == jnp.argmax(deltas)
    )
    return jnp.where(worse[:, None], chosen[None, :], params)


def _consensus_refit(
    config, shape, intrinsics, lm: Landmarks, chosen, chosen_delta, z_d, z_fg, small_intr, known
):
    """Refit the winner on every landmark it agrees with (its inliers), keep it if Delta agrees.

    The winning hypothesis was fitted on a random subset; landmarks it did not draw but that lie
    within ``consensus_distance`` of its keypoints are evidence too (the RANSAC consensus set).
    Refitting on all of them from the winner's pose recovers the accuracy the subset gave up,
    while the landmarks the winner disagrees with stay out. The refit replaces the winner only
    if its Delta is not worse.
    """
    M = body.keypoints(shape, chosen)
    tau = config.consensus_distance
    d3 = jnp.linalg.norm(M - lm.points3d, axis=-1)
    m = project(intrinsics, M)
    f = jnp.sqrt(intrinsics.fx * intrinsics.fy)
    d2 = jnp.linalg.norm(m - lm.keypoints2d, axis=-1) * jnp.maximum(M[:, 2], 0.2) / f
    use3d = lm.has_depth & (d3 < tau)
    use2d = lm.detected & (d2 < tau)
    refit = fit_pose(chosen, shape, lm, intrinsics, use3d=use3d, use2d=use2d, settings=config.fit)
    delta_refit = _score(config, shape, refit.params[None], z_d, z_fg, small_intr, known)[0]
    better = delta_refit <= chosen_delta
    return jnp.where(better, refit.params, chosen), jnp.where(better, delta_refit, chosen_delta)


def tracker_step(
    config: TrackerConfig,
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    floor: Float[Array, 4],
    state: TrackState,
    depth: Float[Array, "H W"],
    keypoints2d: Float[Array, "kpt 2"],
    confidence: Float[Array, " kpt"],
) -> tuple[TrackState, FrameEstimate]:
    """One frame of the tracker (pure; jit it with ``config`` static, as ``Tracker`` does).

    Args:
        config: the variant and its settings (static).
        shape: body dimensions.
        intrinsics: the depth camera (depth registered to the keypoints' image).
        floor: supporting plane (nx, ny, nz, d), n.p + d = height above the floor (``NO_FLOOR``
            when unknown).
        state: hypotheses carried from the previous frame.
        depth: (H, W) depth, metres, float32; 0 or NaN invalid.
        keypoints2d: (18, 2) pixels; confidence: (18,), 0 = missing.

    Returns:
        The new state and this frame's :class:`FrameEstimate`.
    """
    key, key_next = jax.random.split(state.key)
    lm = _landmarks(config, shape, intrinsics, depth, keypoints2d, confidence)
    use3d, use2d = _selection(config, key, shape, intrinsics, depth, lm, state.previous)
    fits = fit_hypotheses(
        state.hypotheses, shape, lm, intrinsics, use3d=use3d, use2d=use2d, settings=config.fit
    )
    params = fits.params
    # Hypothesis evaluation (Eq. (3)) on the downsampled, range-cropped observation.
    z_d, z_fg, known, small_intr = observation(config, depth, intrinsics, floor, state.best[:3])
    deltas = _score(config, shape, params, z_d, z_fg, small_intr, known)
    best = jnp.argmin(deltas)
    chosen = params[best]
    chosen_delta = deltas[best]
    if config.consensus_refit and config.method != "lvm":
        chosen, chosen_delta = _consensus_refit(
            config, shape, intrinsics, lm, chosen, chosen_delta, z_d, z_fg, small_intr, known
        )
        params = params.at[best].set(chosen)
    if config.refine_steps > 0:
        # Polish the winner against the dense depth (at the refinement resolution), on the
        # winner's own landmark subset; keep it if its Delta (scoring resolution) is not worse.
        rz_d, rz_fg, rknown, r_intr = observation(
            config, depth, intrinsics, floor, state.best[:3], refine=True
        )
        refined = refine_pose(
            chosen, shape, lm, intrinsics, use3d=use3d[best], use2d=use2d[best],
            z_d=rz_d, z_fg=rz_fg, score_intrinsics=r_intr, steps=config.refine_steps,
            weight=config.refine_weight, sharpness=config.sharpness, d_M=config.d_M,
            settings=config.fit, known=rknown,
        )  # fmt: skip
        d_ref = _score(config, shape, refined[None], z_d, z_fg, small_intr, known)[0]
        better = d_ref <= chosen_delta
        chosen = jnp.where(better, refined, chosen)
        chosen_delta = jnp.where(better, d_ref, chosen_delta)
        params = params.at[best].set(chosen)
    hyps = _reseed(config, params, deltas, best, chosen)
    kps = jax.vmap(lambda p: body.keypoints(shape, p))(params)
    spread = jnp.median(jnp.linalg.norm(kps - kps[best][None], axis=-1), axis=0)
    new_state = TrackState(
        hypotheses=hyps,
        previous=jax.vmap(lambda p: body.keypoints(shape, p))(hyps),
        best=chosen,
        key=key_next,
    )
    out_kps = kps[best]
    near = jnp.linalg.norm(out_kps - lm.points3d, axis=-1) < config.consensus_distance
    n3 = jnp.sum(lm.has_depth)
    agreement = jnp.where(n3 > 0, jnp.sum(near & lm.has_depth) / jnp.maximum(n3, 1), 1.0)
    est = FrameEstimate(
        params=chosen,
        keypoints3d=kps[best],
        delta=chosen_delta,
        deltas=deltas.at[best].set(chosen_delta),
        best=best,
        hypotheses=params,
        num_3d=n3,
        agreement=agreement,
        num_2d=jnp.sum(lm.detected),
        spread=spread,
        used3d=use3d,
        used2d=use2d,
        fit_ok=fits.ok,
        landmarks=lm,
    )
    return new_state, est
