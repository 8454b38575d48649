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
unconstrained, and so are the limbs' twists). Optionally (``ResidualSettings.leg_limits``, not in
the paper) soft anatomical limits keep knees from bending forward or sideways and thighs from
twisting past 45 degrees (:func:`leg_limit_residuals`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._body import JOINT_NAMES, NUM_JOINTS, BodyShape, flip_labels, keypoints
from ._camera import Intrinsics, project
from ._metrics import LEG_PAIRS
from ._observe import Landmarks, depth_bounds
from ._rotation import quat_normalize, quat_to_matrix
from ._visibility import turn_sine


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
    leg_limits: float = 0.0
    """Weight of the soft anatomical limits on the legs (:func:`leg_limit_residuals`; 0: none,
    the paper's model)."""
    neck_limit: float = 0.0
    """Weight of the soft limit on the head's turn about the torso's vertical
    (:func:`neck_limit_residuals`; 0: none, the paper's model)."""
    leg_cross: float = 0.0
    """Weight of the soft limit that keeps the knees and the ankles from crossing to the other
    side of the body (:func:`leg_cross_residuals`; 0: none, the paper's model). Not in the
    paper."""
    leg_labels_free: bool = False
    """Fit each knee pair and each ankle pair whichever way round is closer (the smaller of
    the pair's residuals as labelled and with the model's left and right exchanged), so a
    detector's exchanged leg labels cost a right-facing pose nothing (:func:`landmark_residuals`).
    In the tracker the track-loss test's agreement takes the pairs the same way
    (:func:`posetrack._step.landmark_agreement`), and the initial fit takes the labels as
    detected (they tell it the facing), as it does without the limit on crossed legs.
    Off: the paper's model. Not in the paper."""
    leg_labels_free_sin: float = 0.0
    """With :attr:`leg_labels_free`: only while the pose is turned side-on to the camera, the
    sine of its turn (the camera-z part of the pelvis' right-to-left axis, as
    :func:`posetrack._visibility.far_side` reads it) above this in size; 0: in every pose.
    Facing the camera (or away) the detector tells the legs apart, and their labels carry
    the facing. Not in the paper."""
    leg_labels_margin: float = 1.0
    """With :attr:`leg_labels_free`: a pair is taken the other way round only where that
    costs less than its labels as detected divided by this (1: whichever is cheaper). Above 1
    the fits keep a preference for the detected labels: a pose turned the wrong way round
    explains exchanged legs as cheaply as the right one explains the labels, and the labels
    are what pulls a turned track back. Not in the paper."""
    leg_terms_min: int = 0
    """The leg terms (:attr:`leg_cross`, :attr:`leg_labels_free`) only on frames with at
    least this many landmarks on depth (0: on every frame). On a handful of landmarks, mostly
    legs (a start under heavy occlusion), the leg labels as detected are what orients the
    body, and the limit on crossed legs can hold it turned round. Not in the paper."""
    depth_bounds: bool = False
    """Fit the landmarks' depth bounds (:func:`posetrack._observe.as_bounds`) one-sidedly
    (:func:`landmark_residuals`); off: a bound is ignored (the keypoint is fitted in 2D).
    ``TrackerConfig(far_side_bound=True)`` turns it on. Not in the paper."""

    def __post_init__(self):
        if self.loss not in ("l1", "l2"):
            raise ValueError(f"ResidualSettings.loss must be 'l1' or 'l2', got {self.loss!r}")
        if not self.eps > 0:
            raise ValueError(f"ResidualSettings.eps must be positive, got {self.eps}")
        if not self.leg_limits >= 0:
            raise ValueError(f"ResidualSettings.leg_limits must be >= 0, got {self.leg_limits}")
        if not self.neck_limit >= 0:
            raise ValueError(f"ResidualSettings.neck_limit must be >= 0, got {self.neck_limit}")
        if not self.leg_cross >= 0:
            raise ValueError(f"ResidualSettings.leg_cross must be >= 0, got {self.leg_cross}")
        if not 0 <= self.leg_labels_free_sin < 1:
            raise ValueError(
                "ResidualSettings.leg_labels_free_sin must be in [0, 1), got "
                f"{self.leg_labels_free_sin}"
            )
        if not 0 <= self.leg_terms_min <= 18:
            raise ValueError(
                f"ResidualSettings.leg_terms_min must be in [0, 18], got {self.leg_terms_min}"
            )
        if not self.leg_labels_margin >= 1:
            raise ValueError(
                f"ResidualSettings.leg_labels_margin must be >= 1, got {self.leg_labels_margin}"
            )


#: The fields of :class:`ResidualSettings` that make up the leg terms (the limit on crossed
#: legs, label-free legs and their gates): what the offline smoother takes from the step's
#: fits as one group (``posetrack.Tracker``), so a gate added here cannot be left behind.
LEG_TERM_FIELDS = (
    "leg_cross", "leg_labels_free", "leg_labels_free_sin", "leg_labels_margin", "leg_terms_min",
)  # fmt: skip


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

    With ``settings.depth_bounds`` a 2D landmark that carries a depth bound
    (:func:`posetrack._observe.as_bounds`) adds ``max(0, z(O_i) - z(M_i))`` in its 3D slot's
    depth component: one-sided, zero while the joint lies behind the surface its pixels show.
    Not in the paper.
    """
    M = keypoints(shape, params)
    args = (landmarks, intrinsics, use3d, use2d, metres_per_pixel, settings)
    e3, e2 = _data_terms(M, *args)
    legs_free = label_free_legs(params, settings, landmarks.has_depth)
    if legs_free is not False:
        # The same landmarks against the model with its knees and ankles exchanged; per pair,
        # the smaller of the two (the exchanged one by the margin).
        x3, x2 = _data_terms(M[LEGS_EXCHANGED], *args)
        cost = jnp.sum(e3 * e3, -1) + jnp.sum(e2 * e2, -1)
        cost_x = jnp.sum(x3 * x3, -1) + jnp.sum(x2 * x2, -1)
        take = exchanged_leg_pairs(cost, cost_x * settings.leg_labels_margin, legs_free)
        e3 = jnp.where(take[:, None], x3, e3)
        e2 = jnp.where(take[:, None], x2, e2)
    if settings.loss == "l1":
        e3 = _sqrt_reweight(e3, settings.eps)
        e2 = _sqrt_reweight(e2, settings.eps)
    return jnp.concatenate([e3, e2], axis=-1)


def _data_terms(M, landmarks, intrinsics, use3d, use2d, metres_per_pixel, settings):
    """Eq. (1)'s 3D and 2D residuals of model keypoints ``M`` (before any loss)."""
    m = project(intrinsics, M)
    e3 = (M - landmarks.points3d) * use3d[:, None]
    if settings.depth_bounds:
        bound = use2d & depth_bounds(landmarks)
        in_front = jnp.maximum(landmarks.points3d[:, 2] - M[:, 2], 0.0)
        e3 = e3.at[:, 2].add(jnp.where(bound, in_front, 0.0))
    e2 = (m - landmarks.keypoints2d) * (use2d * metres_per_pixel)[:, None]
    return e3, e2


def _sqrt_reweight(e: Array, eps: float) -> Array:
    # |r|^2 = |e|^2 / sqrt(|e|^2 + eps^2) ~ |e|: the sum of squares becomes a sum of norms.
    # eps > 0 keeps the factor and its derivative finite at e = 0.
    sq = jnp.sum(e * e, axis=-1, keepdims=True)
    return e * jax.lax.stop_gradient((sq + eps * eps) ** -0.25)


def regulariser_residuals(
    params: Float[Array, 43],
    start_params: Float[Array, 43],
    settings: ResidualSettings,
    shape: BodyShape | None = None,
    has_depth: Bool[Array, " kpt"] | None = None,
) -> Float[Array, " reg"]:
    """``unit_weight (|q_j|^2 - 1)`` for the 10 quaternions, ``prior_weight (x - x_start)``
    and, where ``settings.leg_limits`` > 0, the legs' limits (:func:`leg_limit_residuals`),
    where ``settings.neck_limit`` > 0, the neck's (:func:`neck_limit_residuals`), where
    ``settings.leg_cross`` > 0 the legs' crossing (:func:`leg_cross_residuals`; needs
    ``shape``, and with ``settings.leg_terms_min`` the frame's landmarks on depth
    ``has_depth``: zero on frames with fewer)."""
    q = params[3:].reshape(NUM_JOINTS, 4)
    unit = settings.unit_weight * (jnp.sum(q * q, axis=-1) - 1.0)
    prior = settings.prior_weight * (params - start_params)
    parts = [unit, prior]
    if settings.leg_limits > 0:
        parts.append(settings.leg_limits * leg_limit_residuals(params))
    if settings.neck_limit > 0:
        parts.append(settings.neck_limit * neck_limit_residuals(params))
    if settings.leg_cross > 0:
        if shape is None:
            raise ValueError("ResidualSettings.leg_cross > 0 needs the body shape")
        cross = settings.leg_cross * leg_cross_residuals(params, shape)
        if settings.leg_terms_min > 0:
            if has_depth is None:
                raise ValueError("ResidualSettings.leg_terms_min > 0 needs the landmarks")
            cross = jnp.where(leg_terms_on(settings, has_depth), cross, 0.0)
        parts.append(cross)
    return jnp.concatenate(parts)


#: Quaternion slots (index into the 10 frames of ``params[3:]``) of the hips and knees.
_HIPS = tuple(JOINT_NAMES.index(f"{side}_hip") for side in ("right", "left"))
_KNEES = tuple(JOINT_NAMES.index(f"{side}_knee") for side in ("right", "left"))
#: Half-range of a hip's rotation about the thigh's own axis (internal / external rotation).
HIP_TWIST_MAX_DEG = 45.0
#: How far the shank may bend forward of the thigh's line (hyperextension) and sideways. No
#: slack forward: with 10 degrees a fit started a little forward stopped at the edge with the
#: ankle's 2D keypoint unmet (the straight knee between is a barrier for the keypoint); from
#: 0 the limit pushes it through into the flexion the keypoint allows (tests/test_fit.py).
KNEE_HYPER_MAX_DEG = 0.0
KNEE_SIDE_MAX_DEG = 15.0


def _twist_beyond(q: Float[Array, "*batch 4"], max_deg: float) -> Float[Array, "*batch"]:
    """How far a unit quaternion's twist about the body's y axis (swing-twist decomposition)
    exceeds ``max_deg`` either way: ``max(0, |sin(twist/2)| - sin(max_deg/2))``."""
    w, y = q[..., 0], q[..., 2]
    half_twist = jnp.abs(y) / jnp.sqrt(w * w + y * y + 1e-12)
    return jax.nn.relu(half_twist - jnp.sin(jnp.radians(max_deg) / 2))


def leg_limit_residuals(params: Float[Array, 43]) -> Float[Array, 6]:
    """Soft anatomical limits of the legs, zero inside the range (not in the paper).

    The model's knees are full quaternions, so a shank may bend forward of the thigh as
    easily as backward: where an ankle's keypoint is missing or only 2D, the fit can fold the
    shank toward the camera along the keypoint's ray (measured on wide tuning clips: knees bent
    15-77 degrees the wrong way in up to 30 % of the frames, the truth in at most 4 %).
    A knee bends backward about the thigh's left axis only; the hip's rotation about the
    thigh's own axis is what points that hinge, and it is limited too (else a half turn of the
    thigh would make any forward fold a backward one). Per leg:

    * the hip's twist (swing-twist decomposition about the thigh's axis, body y):
      ``max(0, |sin(twist/2)| - sin(HIP_TWIST_MAX_DEG/2))``;
    * the shank's direction ``d`` in the thigh's frame (rest: straight down, -y; the body's z
      is forward): ``max(0, d_z - sin(KNEE_HYPER_MAX_DEG))`` (bent forward) and
      ``max(0, |d_x| - sin(KNEE_SIDE_MAX_DEG))`` (bent sideways).

    The knee's own twist moves no keypoint or surface and stays free.
    """
    q = quat_normalize(params[3:].reshape(NUM_JOINTS, 4))
    twist = _twist_beyond(q[jnp.array(_HIPS)], HIP_TWIST_MAX_DEG)
    d = -quat_to_matrix(q[jnp.array(_KNEES)])[:, :, 1]  # R @ (0, -1, 0): the shank's direction
    d_x, d_z = d[:, 0], d[:, 2]
    forward = jax.nn.relu(d_z - jnp.sin(jnp.radians(KNEE_HYPER_MAX_DEG)))
    side = jax.nn.relu(jnp.abs(d_x) - jnp.sin(jnp.radians(KNEE_SIDE_MAX_DEG)))
    return jnp.concatenate([twist, forward, side])


#: ``x[LEGS_EXCHANGED]`` reads each knee and ankle as its other side's.
LEGS_EXCHANGED = flip_labels(sum(LEG_PAIRS, ()))


def exchanged_leg_pairs(
    cost: Float[Array, " kpt"], cost_x: Float[Array, " kpt"], gate: Bool[Array, ""] | bool = True
) -> Bool[Array, " kpt"]:
    """Where a knee or ankle is taken the other way round: on both keypoints of each leg
    pair whose summed ``cost_x`` (the model's knees and ankles exchanged) is below its summed
    ``cost`` (as labelled), while ``gate``; per keypoint, lower is better."""
    right, left = (jnp.asarray(side) for side in zip(*LEG_PAIRS, strict=True))
    pair = (cost_x[right] + cost_x[left] < cost[right] + cost[left]) & gate
    return jnp.zeros(cost.shape[0], bool).at[right].set(pair).at[left].set(pair)


def label_free_legs(
    params: Float[Array, 43], settings: ResidualSettings, has_depth: Bool[Array, " kpt"]
) -> bool | Bool[Array, ""]:
    """Whether the knee and ankle pairs are taken whichever way round at ``params`` on a frame
    whose landmarks on depth are ``has_depth``: False (static) without
    :attr:`ResidualSettings.leg_labels_free`; else the traced gates that are set (the side-on
    test of :attr:`~ResidualSettings.leg_labels_free_sin`, the sine of the turn,
    :func:`posetrack._visibility.turn_sine`, above it in size; at least
    :attr:`~ResidualSettings.leg_terms_min` landmarks on depth), True where none is."""
    if not settings.leg_labels_free:
        return False
    free = True
    if settings.leg_labels_free_sin > 0:
        free = jnp.abs(turn_sine(params)) > settings.leg_labels_free_sin
    return free & leg_terms_on(settings, has_depth)


def leg_terms_on(
    settings: ResidualSettings, has_depth: Bool[Array, " kpt"]
) -> bool | Bool[Array, ""]:
    """Whether the leg terms hold on a frame whose landmarks on depth are ``has_depth``: True
    (static) without :attr:`ResidualSettings.leg_terms_min`, else the traced count test."""
    if settings.leg_terms_min > 0:
        return jnp.sum(has_depth) >= settings.leg_terms_min
    return True


def leg_cross_residuals(params: Float[Array, 43], shape: BodyShape) -> Float[Array, 2]:
    """How far, in metres, the knees and the ankles have crossed to the other side of the
    body, zero while each left joint lies left of its right twin (not in the paper):
    ``max(0, -(p_left - p_right) . x)`` for the knees and for the ankles, ``x`` the pelvis'
    right-to-left axis (the root frame's x).

    Each hip is a full ball joint, so nothing in the model keeps a thigh from swinging across
    the body: where the detector exchanges the legs' labels in a side view (the legs pass
    each other in the image while walking), the fit follows them by crossing the legs in
    depth, the far knee 20-25 cm in front of the near one while the hips stay right
    (measured on wide walk_across tuning clips, offline: legs crossed by more than 5 cm on
    14 % of the frames where the truth never crossed them, 187 mm of error there against 77).
    Standing cross-legged is a real pose, so this is a soft limit on the knee and ankle
    centres, which meet only once the legs already overlap by their thickness.
    """
    pts = keypoints(shape, params)
    x = quat_to_matrix(quat_normalize(params[3:7]))[:, 0]
    crossed = [jnp.dot(pts[r] - pts[left], x) for r, left in LEG_PAIRS]
    return jax.nn.relu(jnp.stack(crossed))


_NECK = JOINT_NAMES.index("neck")
#: Half-range of the head's turn about the torso's vertical (cervical rotation: about 70-80
#: degrees each way in adults; anatomy, not fitted to any data set).
NECK_TWIST_MAX_DEG = 80.0


def neck_limit_residuals(params: Float[Array, 43]) -> Float[Array, 1]:
    """Soft limit of the head's turn about the torso's vertical, zero inside the range (not in
    the paper): ``max(0, |sin(twist/2)| - sin(NECK_TWIST_MAX_DEG/2))``, the twist from the
    swing-twist decomposition of the neck's quaternion about the body's y axis.

    The model's neck is a full quaternion, so the head can face backwards over a torso that
    has turned round: when the detector exchanges every left/right pair (a person read as
    facing away), the torso can follow the exchanged shoulders and hips while the head, on
    the unpaired nose, keeps facing the truth's way (measured on wide tuning clips: in the
    turned-round frames the estimated head was turned 120-170 degrees from the estimated
    torso, the truth's never more than 11). With the limit, a turned torso costs the nose.
    """
    q = quat_normalize(params[3 + 4 * _NECK : 7 + 4 * _NECK])
    return _twist_beyond(q, NECK_TWIST_MAX_DEG)[None]
