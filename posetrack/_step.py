"""One tracker step: LVM (the paper's baseline) and the Multiple Hypothesis Tracker (MHT_r/g/h).

One frame is ONE jitted call (:func:`tracker_step`): lifting, landmark weights and subset
sampling (``_select.py``), N Levenberg-Marquardt fits (vmapped, ``_fit.py``), the observation
(``_depthobs.py``), N renders and Delta scores (Eq. (3), ``_render.py``), selection of the best
hypothesis, and what this project adds around it: the consensus refit, reseeding, and the
optional limb hypotheses (``_limbs.py``), self-occlusion gate (``_visibility.py``) and dense
refinement. Shapes are static: a configuration compiles once and then runs every frame
without recompiling. The host-side ``Tracker`` (``_tracker.py``) adds what is not per-frame
math: body-shape estimation, initialisation from observations, track-loss handling.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from . import _body as body
from ._associate import PLAUSIBLE_DEPTH_BAND
from ._camera import Intrinsics
from ._config import TrackerConfig
from ._depthobs import landmark_offsets, tracker_landmarks, tracker_observation
from ._fit import fit_hypotheses, fit_pose
from ._limbs import limb_hypotheses
from ._observe import Landmarks, as_bounds, confident_depth, without_depth
from ._refine import refine_pose
from ._render import Capsules, render_and_score
from ._residuals import LEGS_EXCHANGED, exchanged_leg_pairs, label_free_legs
from ._select import consensus_set, landmark_subsets
from ._visibility import far_side, self_occluded, side_view_bounds

#: Frame status codes: what a frame's step (and the host's track-loss logic around it) made of
#: the frame. :mod:`posetrack._tracker` (host) and :mod:`posetrack._chunk` (inside a scan) share
#: them; the file outputs write them as :data:`posetrack.STATUS_NAMES`.
TRACKED, LOST, NO_OBSERVATION = 0, 1, 2


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
    trusted: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(True))
    """Whether the last frame with an observation passed the track-loss test (Delta at most
    ``TrackerConfig.lost_delta``, landmark agreement at least ``lost_agreement``); True for a
    fresh start. The step passes it on unchanged: the test that judges the frame's status
    sets it (:class:`~posetrack.Tracker` on the host, the chunked scan on the device, one
    meaning: ``posetrack._chunk.status_limits``), so it is that status, never a second
    spelling of it. ``TrackerConfig.bound_trusted`` reads it."""


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
    """Share of the plausible 3D landmarks within ``consensus_distance`` of the output pose's
    keypoints (1 when there are none; :func:`landmark_agreement`): a pose that explains few of
    its landmarks is implausible."""
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


def hypothesis_capsules(shape: body.BodyShape, params: Float[Array, "hyp 43"]) -> Capsules:
    """The capsule surface of every hypothesis (a leading ``hyp`` axis), camera frame."""
    a, b, radius = jax.vmap(lambda p: body.capsules(shape, p))(params)
    return Capsules(a=a, b=b, radius=radius)


def score_hypotheses(
    config: TrackerConfig,
    shape: body.BodyShape,
    params: Float[Array, "hyp 43"],
    z_d: Float[Array, "h w"],
    z_fg: Float[Array, "h w"],
    intrinsics: Intrinsics,
    known: Float[Array, "h w"] | None,
) -> Float[Array, " hyp"]:
    """Delta of Eq. (3) of each hypothesis against the observation (hard or soft renderer as
    ``config.hard_scoring`` says)."""
    return render_and_score(
        hypothesis_capsules(shape, params), z_d, z_fg, intrinsics,
        sharpness=None if config.hard_scoring else config.sharpness, d_M=config.d_M,
        known=known,
    )  # fmt: skip


def reseed_hypotheses(
    config: TrackerConfig,
    params: Float[Array, "hyp 43"],
    deltas: Float[Array, " hyp"],
    best: Int[Array, ""],
    chosen: Float[Array, 43],
) -> Float[Array, "hyp 43"]:
    """The hypotheses carried to the next frame (not in the paper).

    With ``config.reseed``, the worst hypothesis and every one whose Delta exceeds the best's
    (``deltas[best]``) by more than ``config.reseed_margin`` restart from ``chosen`` (the
    output pose); they diverge again through their own subsets. Otherwise (and for N = 1)
    ``params`` unchanged.
    """
    n = params.shape[0]
    if not (config.reseed and n > 1):
        return params
    worse = (deltas > deltas[best] + config.reseed_margin) | (jnp.arange(n) == jnp.argmax(deltas))
    return jnp.where(worse[:, None], chosen[None, :], params)


def keep_if_not_worse(
    candidate: Float[Array, 43],
    candidate_delta: Float[Array, ""],
    chosen: Float[Array, 43],
    chosen_delta: Float[Array, ""],
) -> tuple[Float[Array, 43], Float[Array, ""]]:
    """``(candidate, candidate_delta)`` where its Delta is not worse than the chosen pose's,
    else ``(chosen, chosen_delta)``: how the step's second opinions (the consensus refit, the
    dense refinement) replace the winner."""
    better = candidate_delta <= chosen_delta
    return jnp.where(better, candidate, chosen), jnp.where(better, candidate_delta, chosen_delta)


def consensus_refit(
    config: TrackerConfig,
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    landmarks: Landmarks,
    chosen: Float[Array, 43],
    chosen_delta: Float[Array, ""],
    score: Callable[[Float[Array, "hyp 43"]], Float[Array, " hyp"]],
) -> tuple[Float[Array, 43], Float[Array, ""]]:
    """Refit the winner on every landmark it agrees with (its inliers), keep it if Delta agrees.

    The winning hypothesis was fitted on a random subset; landmarks it did not draw but that lie
    within ``consensus_distance`` of its keypoints (2D: in metres at the keypoint's depth) are
    evidence too (the RANSAC consensus set). Refitting on all of them from the winner's pose
    recovers the accuracy the subset gave up, while the landmarks the winner disagrees with
    stay out. Not in the paper.

    Args:
        config: ``consensus_distance`` and the LM settings ``fit``.
        shape, intrinsics, landmarks: as for :func:`~posetrack.fit_pose`.
        chosen, chosen_delta: the winner and its Delta.
        score: ``(hyp, 43) -> (hyp,)`` Delta of poses against this frame's observation.

    Returns:
        ``(pose, delta)``: the refit and its Delta if that is not worse, else the winner's.
    """
    use3d, use2d = consensus_set(
        landmarks, body.keypoints(shape, chosen), intrinsics, config.consensus_distance
    )
    refit = fit_pose(
        chosen, shape, landmarks, intrinsics, use3d=use3d, use2d=use2d, settings=config.fit
    )
    return keep_if_not_worse(refit.params, score(refit.params[None])[0], chosen, chosen_delta)


def landmark_agreement(
    keypoints3d: Float[Array, "kpt 3"],
    lm: Landmarks,
    distance: Float[Array, ""] | float,
    legs_free: bool | Bool[Array, ""] = False,
) -> Float[Array, ""]:
    """The share of plausible 3D landmarks within ``distance`` of ``keypoints3d`` (1 if none).

    Plausible: lifted within :data:`PLAUSIBLE_DEPTH_BAND` of the landmarks' median depth. A
    keypoint a few pixels off a far, thin limb is lifted onto whatever lies behind it (a wall
    0.5-1 m back); no pose can agree with it, so it does not count against the pose. The
    track-loss test (``TrackerConfig.lost_agreement``) reads this.

    ``legs_free`` (the fits' ``ResidualSettings.leg_labels_free``; False skips it, an array
    gates it): each knee pair and each ankle pair counted whichever way round agrees with
    more of its landmarks, as the fits took them; otherwise a pose fitted to exchanged leg
    labels would disagree with them. The fits' ``leg_labels_margin`` is not applied: a count
    of agreeing landmarks has no margin to speak of.
    """
    near = jnp.linalg.norm(keypoints3d - lm.points3d, axis=-1) < distance
    z = jnp.where(lm.has_depth, lm.points3d[:, 2], jnp.nan)
    plausible = lm.has_depth & (jnp.abs(z - jnp.nanmedian(z)) <= PLAUSIBLE_DEPTH_BAND)
    if legs_free is not False:
        flipped = keypoints3d[LEGS_EXCHANGED]
        near_x = jnp.linalg.norm(flipped - lm.points3d, axis=-1) < distance
        # Fewer disagreeing landmarks is the lower cost.
        miss = (~near & plausible).astype(jnp.int32)
        miss_x = (~near_x & plausible).astype(jnp.int32)
        near = jnp.where(exchanged_leg_pairs(miss, miss_x, legs_free), near_x, near)
    n = jnp.sum(plausible)
    return jnp.where(n > 0, jnp.sum(near & plausible) / jnp.maximum(n, 1), 1.0)


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
    """One frame of the tracker (pure; ``jax.jit`` it whole, as ``Tracker`` does).

    Args:
        config: the variant and its settings (a pytree: static fields select the code, the
            float fields are traced).
        shape: body dimensions.
        intrinsics: the depth camera (depth registered to the keypoints' image).
        floor: supporting plane (nx, ny, nz, d), n.p + d = height above the floor
            (``posetrack._depthobs.NO_FLOOR`` when unknown).
        state: hypotheses carried from the previous frame.
        depth: (H, W) depth, metres, float32; 0 or NaN invalid.
        keypoints2d: (18, 2) pixels; confidence: (18,), 0 = missing.

    Returns:
        The new state and this frame's :class:`FrameEstimate`.
    """
    key, key_next = jax.random.split(state.key)
    lm = tracker_landmarks(config, shape, intrinsics, depth, keypoints2d, confidence)
    # With TrackerConfig.depth_confidence > 0 (off by default), keypoints detected far less
    # confidently than the rest of the body (inferred behind an occluder: their depth is the
    # occluder's) are fitted in 2D only; depth_confidence_far (off by default) does the same
    # for the limbs of the side the previous output turns away from the camera. At 0 the
    # landmarks are unchanged.
    far = far_side(state.best)
    ratio = jnp.maximum(config.depth_confidence, config.depth_confidence_far * far)
    lm = confident_depth(lm, ratio)
    if config.far_side_2d:  # (off by default) the far side's limbs and torso, whatever the
        # detector's confidence: their pixels show the near side's surface in a side view
        lm = without_depth(lm, far_side(state.best, torso=True))
    elif config.far_side_bound:  # (off by default) those, the far eye and ear and the neck
        # in 2D, their depth a bound the joint stays behind (a surface in front of it)
        bounds = side_view_bounds(state.best, config.bound_turn_sin) & lm.has_depth
        enough = jnp.sum(lm.has_depth & ~bounds) >= config.bound_min_landmarks
        if config.bound_trusted:  # (off by default) only behind a pose that passed the test
            enough = enough & state.trusted
        lm = as_bounds(lm, bounds & enough)
    use3d, use2d = landmark_subsets(config, key, shape, intrinsics, depth, lm, state.previous)
    if config.occlusion_gate:
        # Every other hypothesis leaves out the 3D landmarks that the previous output says
        # were lifted onto a body part hiding the joint (``_visibility.py``), fitting their 2D
        # detections instead; the others keep them, and Delta decides between the two.
        hidden = self_occluded(
            shape, state.best, lm, intrinsics, landmark_offsets(config, shape),
            config.occlusion_margin, config.occlusion_tolerance,
        )  # fmt: skip
        gated = (jnp.arange(use3d.shape[0]) % 2 == 1)[:, None] & hidden[None, :]
        use3d = use3d & ~gated
        use2d = use2d | gated  # flagged landmarks have depth, so they were detected
    starts, lm_fit = state.hypotheses, lm
    N, S = starts.shape[0], config.num_limb_hypotheses
    if S:
        # The last S hypotheses restart from the previous output with the limbs turned onto
        # this frame's landmarks, as labelled and swapped (``_limbs.py``; not in the paper);
        # each fits its own relabelled landmarks.
        s_start, s_lm, s_u3, s_u2 = limb_hypotheses(
            shape, intrinsics, state.best, lm, count=S, distance=config.limb_distance
        )
        starts = starts.at[N - S :].set(s_start)
        lm_fit = jax.tree.map(
            lambda x, y: jnp.broadcast_to(x, (N, *x.shape)).at[N - S :].set(y), lm, s_lm
        )
        use3d = use3d.at[N - S :].set(s_u3)
        use2d = use2d.at[N - S :].set(s_u2)
    in_batch = config.consensus_refit and config.consensus_in_batch and config.method != "lvm"
    if in_batch:
        # One more hypothesis: the previous output refitted on its consensus set (see
        # ``TrackerConfig.consensus_in_batch``).
        c3, c2 = consensus_set(
            lm, body.keypoints(shape, state.best), intrinsics, config.consensus_distance
        )
        starts = jnp.concatenate([starts, state.best[None]])
        use3d, use2d = jnp.concatenate([use3d, c3[None]]), jnp.concatenate([use2d, c2[None]])
        if S:
            lm_fit = jax.tree.map(lambda x, y: jnp.concatenate([x, y[None]]), lm_fit, lm)
    fits = fit_hypotheses(
        starts, shape, lm_fit, intrinsics, use3d=use3d, use2d=use2d, settings=config.fit,
        per_hypothesis_landmarks=bool(S),
    )  # fmt: skip
    params = fits.params
    # Hypothesis evaluation (Eq. (3)) on the downsampled, range-cropped observation.
    z_d, z_fg, known, small_intr = tracker_observation(
        config, depth, intrinsics, floor, state.best[:3]
    )

    def score(p):
        return score_hypotheses(config, shape, p, z_d, z_fg, small_intr, known)

    deltas = score(params)
    if in_batch:
        extra, extra_delta = params[N], deltas[N]
        params, deltas, use3d, use2d = params[:N], deltas[:N], use3d[:N], use2d[:N]
        fits = jax.tree.map(lambda x: x[:N], fits)
    best = jnp.argmin(deltas)
    chosen = params[best]
    chosen_delta = deltas[best]
    if in_batch:
        chosen, chosen_delta = keep_if_not_worse(extra, extra_delta, chosen, chosen_delta)
        params = params.at[best].set(chosen)
    elif config.consensus_refit and config.method != "lvm":
        chosen, chosen_delta = consensus_refit(
            config, shape, intrinsics, lm, chosen, chosen_delta, score
        )
        params = params.at[best].set(chosen)
    if config.refine_steps > 0:
        # Polish the winner against the dense depth (at the refinement resolution), on the
        # winner's own landmark subset; keep it if its Delta (scoring resolution) is not worse.
        rz_d, rz_fg, rknown, r_intr = tracker_observation(
            config, depth, intrinsics, floor, state.best[:3], refine=True
        )
        refined = refine_pose(
            chosen, shape, jax.tree.map(lambda x: x[best], lm_fit) if S else lm, intrinsics,
            use3d=use3d[best], use2d=use2d[best],
            z_d=rz_d, z_fg=rz_fg, score_intrinsics=r_intr, steps=config.refine_steps,
            weight=config.refine_weight, sharpness=config.sharpness, d_M=config.d_M,
            settings=config.fit, known=rknown,
        )  # fmt: skip
        chosen, chosen_delta = keep_if_not_worse(
            refined, score(refined[None])[0], chosen, chosen_delta
        )
        params = params.at[best].set(chosen)
    hyps = reseed_hypotheses(config, params, deltas, best, chosen)
    kps = jax.vmap(lambda p: body.keypoints(shape, p))(params)
    # The limb hypotheses try deliberate alternatives (swaps): their disagreement with the
    # winner is by design, not doubt about it, so only the other hypotheses count.
    regular = kps[: max(N - S, 1)]
    spread = jnp.median(jnp.linalg.norm(regular - kps[best][None], axis=-1), axis=0)
    n3 = jnp.sum(lm.has_depth)
    legs_free = label_free_legs(chosen, config.fit.residuals, lm.has_depth)  # as the fits did
    agreement = landmark_agreement(kps[best], lm, config.consensus_distance, legs_free)
    new_state = TrackState(
        hypotheses=hyps,
        previous=jax.vmap(lambda p: body.keypoints(shape, p))(hyps),
        best=chosen,
        key=key_next,
        trusted=state.trusted,  # the loss test's, set by whoever judges the frame
    )
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
