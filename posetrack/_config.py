"""The tracker's configuration: which variant (LVM, MHT_r, MHT_g, MHT_h) and its settings.

:class:`TrackerConfig` is an ``eqx.Module``. Whether a field is static or traced is decided
where the field is declared:

* ``eqx.field(static=True)``: anything that changes shapes, loop structure or code paths (the
  method, N, image sizes, switches, LM settings). Changing one compiles a new tracker step.
* plain fields (floats): thresholds, sigmas and ratios. They are pytree leaves, so the jitted
  step receives them as traced scalars; a parameter sweep (the paper's Table 1) or a tuning
  grid over them reuses one compiled step. Host-side thresholds (track loss) are leaves too,
  for the same reason: changing them must not recompile anything.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx

from ._fit import FitSettings
from ._observe import LIFT_RULES
from ._render import DEFAULT_SHARPNESS
from ._residuals import ResidualSettings
from ._score import DEFAULT_D_M

METHODS: tuple[str, ...] = ("lvm", "mht_r", "mht_g", "mht_h")

#: How :meth:`Tracker.run` makes its poses: the motion model over the whole recording, the
#: causal motion model with a fixed lag, or each frame on its own (the paper).
MODES: tuple[str, ...] = ("offline", "online", "per-frame")

#: LM steps per frame of each MHT hypothesis' fit (``TrackerConfig.fit``'s default for MHT).
MHT_FIT_STEPS = 4

#: The paper's best (N, r, R) of each method, its Table 2.
PAPER_BEST: dict[str, dict] = {
    "lvm": dict(num_hypotheses=1),
    "mht_r": dict(num_hypotheses=20, r=0.05, R=0.15),
    "mht_g": dict(num_hypotheses=5, r=0.05, R=0.15),
    "mht_h": dict(num_hypotheses=5, r=0.0, R=0.0),
}

#: The switches that add this project's changes to the paper's method, and their values in the
#: paper's method alone (see README "Beyond the paper").
BEYOND_THE_PAPER: dict[str, bool | int | float] = {
    "surface_offset": False,
    "invalid_is_unknown": False,
    "use_floor": False,
    "temporal_2d": False,
    "reseed": False,
    "consensus_refit": False,
    "limb_hypotheses": 0,
    "all_landmarks_hypothesis": False,
    "occlusion_gate": False,
    "depth_confidence": 0.0,
    "depth_confidence_far": 0.0,
    "far_side_2d": False,
    "far_side_bound": False,
    "reinit_keep_facing": 0,
    "reinit_check_tracked": 0,
    "lift_band": 0.0,
}

_POSITIVE = (
    "sigma_g", "sigma_h", "d_hmax", "d_M", "sharpness", "body_range", "limb_distance",
    "occlusion_margin", "occlusion_tolerance",
)  # fmt: skip


class TrackerConfig(eqx.Module):
    """Everything that selects a tracker variant and its settings.

    The defaults are our recommended tracker: MHT_h with the paper's r = R = 0, N = 10, sigmas
    tuned on generated sequences disjoint from the benchmark's (``benchmarks/tune.py``), and
    the switchable additions that measured to help (see README "Beyond the paper").
    :meth:`paper` gives the paper's method alone; :meth:`recommended` the paper's best (N, r,
    R) of a method with our additions.

    Static fields (``eqx.field(static=True)``) select code paths and shapes; the float fields
    are traced leaves of the jitted step (changing them never recompiles).
    """

    method: str = eqx.field(default="mht_h", static=True)
    """"lvm" (all landmarks, one hypothesis), "mht_r", "mht_g" or "mht_h"."""
    num_hypotheses: int = eqx.field(default=10, static=True)
    """N; forced to 1 for LVM. The paper's MHT_h uses 5 (``TrackerConfig.paper``); 10 was
    about 5 % more accurate on our tuning sequences at about 1.6x the cost."""
    r: float = 0.0
    """Random exclusion ratio of 2D landmarks (w^r = 1 - r). Traced."""
    R: float = 0.0
    """Random exclusion ratio of 3D landmarks (W^r = 1 - R). Traced."""
    sigma_g: float = 1.5
    """sigma_g of W^g = exp(-d_g / (2 sigma_g^2)); d_g in [0, 1]. Traced."""
    sigma_h: float = 0.5
    """sigma_h of W^h = exp(-d_h / (2 sigma_h^2)); d_h in [0, 1]. Traced."""
    d_hmax: float = 0.45
    """Truncation distance of d_h, metres. Traced."""
    d_M: float = DEFAULT_D_M
    """Depth clamp of Eq. (3), metres. Traced."""
    score_width: int = eqx.field(default=160, static=True)
    """Width of the depth maps Delta is computed on (the sensor's depth is downsampled)."""
    score_height: int = eqx.field(default=120, static=True)
    """Height of the depth maps Delta is computed on."""
    sharpness: float = DEFAULT_SHARPNESS
    """Soft rasteriser sharpness, 1/metre (the dense refinement; and the scoring when
    ``hard_scoring`` is False). Traced."""
    hard_scoring: bool = eqx.field(default=True, static=True)
    """Score hypotheses (Eq. (3)) with the hard renderer, i.e. exact ray casting of the
    capsules, as the paper does. Scoring needs no gradient; the hard renderer is 2-3x faster
    than the soft one. False: the soft renderer at ``sharpness``."""
    body_range: float = 1.2
    """Observation preprocessing: keep depth within this distance (metres) of the previous
    estimate's root laterally and in depth (the paper's 'predefined range'). Traced."""
    lift_window: int = eqx.field(default=5, static=True)
    """Side of the depth window (pixels, at the sensor's resolution) of the lifting median."""
    lift_rule: str = eqx.field(default="median", static=True)
    """How a keypoint's depth is read from its window (:func:`~posetrack.lift_keypoints`):
    "median" (default) or "nearest" (the median of the nearest cluster of depths: a thin
    limb's own depth rather than the background around it; opt-in, see benchmarks/README.md).
    Every lifting of the tracker uses it (step, initialisation, body-shape estimates)."""
    lift_band: float = 0.7
    """Metres: the lifting ignores window depths more than this behind the median lifted depth
    of the frame's torso keypoints (:func:`~posetrack.body_depth_limit`): a thin
    limb's keypoint a pixel off the limb then reads the limb pixels its window holds, or no
    depth (2D only), instead of the background 1-2 m behind. 0 = off (the paper's lifting).
    0.7, the observation's own bound behind the root, since 2026-11-28 (wide real motion
    tuning clips, 48 runs a mode: offline D 65.4 -> 60.9 mm, online 80.8 -> 76.9;
    benchmarks/README.md). Every lifting of the tracker uses it. Traced."""
    confidence_threshold: float = 0.4
    """A keypoint is detected (f_i) when its confidence exceeds this. Traced."""
    depth_confidence: float = 0.0
    """Off by default (0, the paper: every detected keypoint with valid depth is a 3D
    landmark). Above 0, a detected keypoint's depth is a 3D landmark of the per-frame step
    (F_i: its fits and Delta's choice, and what the step reports, which track loss and the
    smoother read) only where its confidence is at least this fraction of the median
    confidence of the frame's detected body keypoints (neck to ankles,
    :func:`~posetrack.confident_depth`); below it the hypotheses fit its 2D detection
    instead. A detector reports the keypoints it infers behind
    an occluder (the far arm behind the torso in a side view, a leg behind a box) at a lower
    confidence, and the depth on such a keypoint's pixel is the occluder's surface, 20-50 cm
    too close. Relative, so it follows a detector's own confidence scale. The
    (re-)initialisation and the body-shape estimates still lift every detected keypoint.
    At 0.8 it measured 1.1 mm worse on average over 40 tuning runs, with 15 % fewer
    swapped-limb frames (benchmarks/README.md, "What was tried"); not in the paper. Traced."""
    depth_confidence_far: float = 0.0
    """Off by default (0). Above 0, ``depth_confidence``'s rule with this ratio for the
    elbow, wrist, knee and ankle of the side the previous output turns away from the camera
    (more than 30 degrees from facing it; :func:`posetrack._visibility.far_side`); the
    larger of the two ratios applies there. In a side view the far arm hangs behind the torso
    and its depth is the near side's surface, 20-45 cm too close (wide walk_across tuning
    clips), while a pose facing the camera keeps every landmark as the paper has it. At 1.0
    (2026-11-29) it met its tuning rule (side-view tuning clips -4 to -5 mm; 40 decision
    clips offline 46.9 -> 44.9, online 52.7 -> 49.9) and was stopped by two report sets (wide
    online +3.5 mm, real wide offline +2.9; benchmarks/README.md, "A side view hides the far
    arm"): opt-in. On 24 fresh tuning runs, each with tracker seeds 0-2 (2026-12-01), it
    changed D by -0.09 mm offline and +0.10 online ("Decisions on several tracker seeds").
    Not in the paper. Traced."""
    far_side_2d: bool = eqx.field(default=False, static=True)
    """Off by default. In a side view (the previous output turned more than 30 degrees from
    the camera, :func:`posetrack._visibility.far_side`) the far side's shoulder and hip as well
    as its elbow, wrist, knee and ankle are fitted by their 2D detections only, whatever the
    detector's confidence: their pixels show the near side's surface (the far hip is lifted
    20-30 cm too close), and the 3D residuals pull the whole body toward the camera. Unlike
    ``depth_confidence_far`` it includes the torso and needs no confidence gap (a synthetic or
    real detector may report a hidden joint as confidently as a seen one). Its screen failed
    (2026-12-03, 48 fresh tuning runs: D +1.36 mm, occluded side views +12 mm, swapped-limb
    frames -15 %; benchmarks/README.md, "The far2d screen"): with an occluder on the near
    side too few 3D landmarks remain. Not in the paper."""
    far_side_bound: bool | None = eqx.field(default=None, static=True)
    """``None`` (the default): decided by the tracker's mode (:meth:`for_mode`, which
    :class:`Tracker` applies): **on online** (with :attr:`bound_trusted`), off offline and
    per-frame; ``True`` / ``False``: in every mode. In a side view (turned more than
    ``bound_turn_sin``) the far side's shoulder, elbow, wrist, hip, eye and ear and the neck
    (:func:`posetrack._visibility.side_view_bounds`; not the far knee and ankle, which the
    camera sees between the legs) are fitted by their 2D detections, and
    their lifted depth becomes a one-sided bound (:func:`posetrack._observe.as_bounds`): the
    fit keeps the joint behind the surface its pixels show (the near side's) instead of on
    it, and they leave the track-loss test's agreement share (they disagree with any right
    pose). Unlike ``far_side_2d`` their depth still constrains the fit. Turns on
    ``fit.residuals.depth_bounds`` (and the offline smoother's, in ``Tracker``). Not with
    ``far_side_2d``. The online default since 2026-12-07 (with ``bound_trusted``): its online
    screen on fresh tuning seeds (76 runs x 3 tracker seeds, a rule written before its runs)
    gained D -3.6 mm (t -3.1; side views -13 mm), and its online report stage (the four report
    sets, 96 runs x 2 seeds) passed with -0.3 mm (wide clean -2.9, real motion +0.2 to +1.6)
    (benchmarks/README.md, "`bound_trusted` online, under the rule of 2026-12-07"); offline it
    stays off (its offline report stage failed, see ``bound_trusted``). Not in the paper."""
    bound_turn_sin: float = 0.75
    """``far_side_bound`` applies while the previous output is turned by more than this sine
    of its angle from facing the camera (0.75: 49 degrees). At ``far_side``'s 0.5 (30
    degrees) the far side is still mostly seen, and treating its depth as a bound let the
    body drift back (tuning clips 1277, 1287: +20 and +15 mm; both unchanged at 0.75, which
    keeps the gains of 1211, 1276 and 1286; 0.87 lost 1286's). Traced."""
    bound_trusted: bool | None = eqx.field(default=None, static=True)
    """``None`` (the default): decided by the mode (:meth:`for_mode`): on online wherever the
    bound is on, off offline and per-frame (an explicit ``far_side_bound=True`` offline is
    ungated, as before 2026-12-07); ``True`` needs ``far_side_bound=True``.
    ``far_side_bound`` applies only while the last frame with an observation
    passed the track-loss test (its Delta at most ``lost_delta`` and its agreement at least
    ``lost_agreement``: the frame's status, :attr:`posetrack.TrackState.trusted`). The bound trusts
    the previous pose's facing to say which side is far; a pose that failed the test (a track coming
    apart, often turned round) bounds the near side instead and pulls the body further off (tuning
    clip 1700, CMU 131_03: +109 mm). Its screen (2026-12-06, 72 fresh tuning runs x 3 tracker seeds,
    offline) gained 2.9 mm (t -2.9; side views -12 mm) but answered 0.48 % fewer frames; online (72
    more, lag 3) -3.7 mm (t -3.2; side views -21 mm) with 0.12 % fewer: both failed their rules'
    coverage clause (benchmarks/README.md, "`far_side_bound` behind a trusted pose only"). Under a
    coverage clause judged like D a third screen passed (-2.3 mm, t -2.2) and the offline report
    stage failed by that clause's cell condition at its edge (real motion, wide, occluded: coverage
    -0.0254 with t -1.50; D -0.6 mm overall, wide clean 45.6 -> 42.0), so it stays off offline
    ("`bound_trusted` under a coverage clause judged like D"); online it is the default since
    2026-12-07 (``far_side_bound``). With ``reinit_partial_axes``
    closing those drops (2026-12-07, 60 fresh runs x 3 seeds, offline) coverage rose (+0.97 %)
    but D did not move enough (-0.75 mm, t -0.66; CMU occluded +3.9): "The trusted bound with
    the side view's restart, offline". Not in the paper."""
    bound_min_landmarks: float = 5.0
    """``far_side_bound`` applies only while at least this many landmarks keep their depth
    besides the bounded ones; with fewer (an occluder over the near side) the landmarks are
    used as lifted: on occluded walk_across tuning clips the bounds alone let the per-frame
    pose drift (1249: 57.6 -> 68.9 mm with no minimum, 56.7 with 5, 59.4 with 7). Traced."""
    surface_offset: bool = eqx.field(default=True, static=True)
    """Push lifted landmarks back by the local body radius (surface -> joint centre). Not in
    the paper; see README "Beyond the paper"."""
    temporal_2d: bool = eqx.field(default=True, static=True)
    """A temporal weight for 2D-only landmarks (detected, no valid depth) from their distance
    in pixels to the hypothesis' reprojected previous keypoint, converted to metres at its
    depth and weighted like the paper's w^h = l W^h + (1 - l). The paper defines W^h only for
    3D landmarks (2D-only landmarks get weight 1). Not in the paper."""
    fit: FitSettings | None = eqx.field(default=None, static=True)
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
    init_steps: int = eqx.field(default=60, static=True)
    """LM steps of the (re-)initialisation fit on all landmarks."""
    shape_frames: int = eqx.field(default=15, static=True)
    """Frames used to estimate the body dimensions when none are given."""
    reseed: bool = eqx.field(default=True, static=True)
    """Replace the worst hypothesis by the best after each frame (drift remedy; not in the
    paper)."""
    reseed_margin: float = 0.15
    """With ``reseed``, also replace every hypothesis whose Delta exceeds the best's by more
    than this (1.0: only the worst is replaced). 0.05 reseeded too eagerly: a hypothesis that
    had drawn a limb's true keypoints after a run of left/right swaps was overwritten before it
    could win, and the limb stayed wrong (see README, Limitations; this change was made after
    looking at reported benchmark clips, see benchmarks/README.md). Traced."""
    consensus_refit: bool = eqx.field(default=True, static=True)
    """Refit the winner on all landmarks within ``consensus_distance`` of it (not in the paper)."""
    consensus_distance: float = 0.12
    """Metres (2D: at the keypoint's depth) within which a landmark agrees with the winner.
    Traced."""
    consensus_in_batch: bool = eqx.field(default=False, static=True)
    """With ``consensus_refit``: instead of refitting this frame's winner after the scores (a
    second fit and render program inside the step, about a third of its compilation), fit one
    more hypothesis in the same batch: the previous output on the landmarks within
    ``consensus_distance`` of its keypoints, scored with the others; if it wins it takes the
    best hypothesis' place, as the refit does. Not in the paper."""
    all_landmarks_hypothesis: bool = eqx.field(default=False, static=True)
    """Opt-in (not in the paper): hypothesis 0 of the N fits every landmark, as LVM does,
    instead of a weighted subset; Delta decides between it and the others, and it is reseeded
    like them. Per-frame on wide real-motion tuning clips (seeds 112-159, 96 runs) D fell
    89.1 -> 88.5 mm clean and 122.9 -> 120.8 occluded, and MHT_h was worse than LVM on 4
    clips instead of 7; but offline and online (seeds 160-173) it failed the rule written
    before the runs (offline clean +1.6 mm, one clip with a 22-frame swap; online more runs
    worse than better by 5 mm), so it is not the default (benchmarks/README.md, "One
    hypothesis on every landmark"). Without the consensus refit it does not replace it."""
    limb_hypotheses: int = eqx.field(default=0, static=True)
    """S of the N hypotheses restart every frame from the previous output with each limb
    turned onto this frame's 3D landmarks: as labelled, then with both arms and legs, the
    arms, the legs exchanged left/right (``posetrack._limbs``; 0 = off, at most 4; LVM has
    none: :attr:`num_limb_hypotheses`). Delta decides between them and the other hypotheses,
    so a locked left/right swap or a limb too fast for the fit's few steps can recover. Not in
    the paper."""
    limb_distance: float = 0.2
    """A landmark enters a limb hypothesis' fit if it lies within this of the re-initialised
    pose (metres). Traced."""
    occlusion_gate: bool = eqx.field(default=False, static=True)
    """Every other hypothesis leaves out the 3D landmarks that the previous output says were
    lifted onto a body part hiding the joint (``posetrack._visibility``: in a side view the
    far arm's keypoints are lifted onto the torso's surface, 20-30 cm too close), fitting
    their 2D detections instead; the other hypotheses keep them and Delta decides. (Dropping
    them for every hypothesis locked wrong poses in.) Not in the paper."""
    occlusion_margin: float = 0.1
    """Metres: a landmark counts as hidden when both the model's nearest surface on its ray
    and the landmark lie more than this in front of the model's joint. Traced."""
    occlusion_tolerance: float = 0.06
    """Metres: a hidden landmark must also be explained by the hiding part: the surface the
    sensor saw lies within this of that part's surface on the detection's ray (farther in
    front, the limb itself was seen: the model is wrong and the landmark stays). Traced."""
    invalid_is_unknown: bool = eqx.field(default=True, static=True)
    """Delta ignores rendered body over pixels without valid depth (holes, removed areas): the
    sensor cannot say the body is not there. False: Eq. (3) as written, where such pixels count
    as background. Not in the paper; see README "Beyond the paper"."""
    refine_steps: int = eqx.field(default=0, static=True)
    """LM steps of the final refinement of the output pose against the dense depth through
    the soft rasteriser (0 = off; not in the paper)."""
    refine_width: int = eqx.field(default=80, static=True)
    """Width of the depth maps the refinement renders (its Jacobian costs 43 renders)."""
    refine_height: int = eqx.field(default=60, static=True)
    """Height of the depth maps the refinement renders."""
    refine_weight: float = 2.0
    """Weight of Delta against the landmark term in the refinement. Traced."""
    lost_delta: float = 0.85
    """A frame whose best Delta exceeds this is 'lost' (host side)."""
    lost_agreement: float = 0.6
    """A frame whose output pose lies within ``consensus_distance`` of fewer than this share of
    its plausible 3D landmarks is 'lost' (an implausible pose: it explains too little of what
    is seen; host side). Landmarks lifted more than 0.4 m from the landmarks' median depth (a
    keypoint that missed a far, thin limb, lifted onto the wall behind) do not count
    (``posetrack._step.landmark_agreement``; since 2026-11-28, benchmarks/README "Loss tests
    that hold for a far, jittery person")."""
    lost_patience: int = eqx.field(default=5, static=True)
    """Consecutive lost frames before the tracker re-initialises from observations."""
    reinit_keep_facing: int = eqx.field(default=5, static=True)
    """A re-initialisation within this many frames of a track loss keeps the lost track's
    facing: if this frame's landmarks turn the person round against the pose at the loss
    (their left-right axes more than 90 degrees apart) and its shoulders and hips sit on the
    other side's positions of the last tracked frame, its keypoints are read with every
    left/right pair exchanged (host side; 0 = off; 5, the default, met its rule on tuning
    clips and changed no report clip, ``benchmarks/facing.py``, ``benchmarks/motion.py
    --facing-only``; 15 failed on an occluded clip). A person does not turn round in half a
    second unseen; a detector reading them as facing away does, and a track restarted on its
    reading stays turned round (not in the paper)."""
    reinit_check_fit: bool = eqx.field(default=False, static=True)
    """With :attr:`reinit_keep_facing`: where a re-initialisation's start kept the lost
    track's facing but its initial fit turned round (a whole-body left/right swap of the
    detector that the start's closed form did not follow, while the shoulders and hips
    already sat exchanged in the last tracked frame), the landmarks with every left/right
    pair exchanged are fitted too and kept if that fit keeps the facing (host side; one more
    initial fit there). On a wide real-motion tuning clip the fit turned the body round and
    the online tracker kept it turned for 65 frames (263 mm; with this, 74 mm). Opt-in: its
    screens (2026-12-05, 56 fresh tuning runs per mode) changed no run, the event being rare
    (benchmarks/README.md, "Where 1467 turns round, located"). Not in the paper."""
    reinit_check_frames: int | None = eqx.field(default=None, static=True)
    """With :attr:`reinit_check_fit`: how many frames after a track loss its check applies
    (``None``: :attr:`reinit_keep_facing`'s). The start's flip needs this frame's shoulders
    and hips to sit on the last tracked frame's other side, which fades as the person moves
    while lost; the check asks more of the frame (the start kept the facing, the fit turned
    round, the exchanged fit keeps it) and so can look further back. On a wide real-motion
    tuning clip lost for 10 frames (1531) the fit turned round after the restart and stayed
    so for 35 frames (127 mm; with 15 frames, 106). 15 failed its screen (2026-12-05, 110
    fresh tuning runs online: 5 changed, D -0.63 mm, but one lost clip 24 mm worse where the
    rule allowed 20; benchmarks/README.md, "A longer look back for the re-initialisation's
    fit check"), so it is not the default."""
    reinit_partial_frames: int = eqx.field(default=0, static=True)
    """> 0: a re-initialisation after a track loss that sees no left/right pair with depth
    (neither both shoulders nor both hips: a side view, the far side hidden by the body, or an
    occluder) starts from the pose of the last frame judged tracked, if that was at most this
    many frames ago, moved onto the landmarks it does see, instead of waiting for a frame that
    shows a pair (host side; the usual initial fit and loss tests follow; never from a pose
    that failed the loss tests). 0 (the default): it waits, as a partial restart facing the
    camera was measured to do more harm than good. A person walking across a side view under
    occlusion shows no pair for seconds: on a wide tuning clip a loss waited 51 frames for one
    (benchmarks/README.md, "A restart from the lost pose"). Not in the paper."""
    reinit_partial_axes: bool = eqx.field(default=False, static=True)
    """With :attr:`reinit_partial_frames`: the restart without a left/right pair takes only
    the last tracked pose's facing (its root's left and up axes) and places the limbs from
    the frame's landmarks as any start does, instead of the whole last tracked pose (a loss
    usually follows a drift, which that pose carries into the restart); a restart whose fit
    turns round against that facing, or whose Delta (Eq. 3) against the frame's depth is above
    :attr:`lost_delta`, is refused (the next frame tries again). False (the default): the
    whole pose. With ``reinit_partial_frames=25`` it passed an offline screen (60 fresh
    tuning runs x 3 tracker seeds: answered frames +1.4 %, D -0.61 mm on the frames both
    answer, none worse by 5 mm) and failed the online one (an occluded side view +63 mm: a
    right restart kept, on few landmarks, through a turn the loss test cannot see, where the
    default started afresh after it), so it is not the default (benchmarks/README.md, "A
    side view's restart from the last tracked facing"); with ``bound_trusted`` its offline
    screen failed too (2026-12-07: coverage +0.97 %, D -0.75 mm with t -0.66). Not in the
    paper."""
    reinit_check_tracked: int = eqx.field(default=25, static=True)
    """> 0: a re-initialisation at most this many frames after the last frame judged tracked,
    on a frame that does not show both left/right pairs with depth (shoulders and hips), whose
    initial fit faces more than 90 degrees away from that tracked pose, fits the landmarks
    with every left/right pair exchanged too and keeps that fit if it faces the tracked pose's
    way (host side; one more initial fit there). Unlike :attr:`reinit_check_fit` it compares
    with the last *tracked* pose, not the pose at the loss (which drifted for
    ``lost_patience`` frames), and needs no exchanged keypoints in the last tracked frame: in
    side views a third of re-initialisations started turned round, all from frames with one
    left/right pair, lifted wrongly (benchmarks/README.md, "A facing check against the last
    tracked pose"). 25 (the default since 2026-12-06) passed its offline and online screens
    (D -0.60 / -2.47 mm on the frames both answer, swapped-limb frames -4 / -14 % over 60
    fresh tuning runs x 4 tracker seeds per mode) and both report stages (96 runs x 2 tracker
    seeds per mode: D -0.15 / -0.17 mm, no cell worse; it changed 2 of 192 trackings offline,
    -28.7 and +0.2 mm, and 1 online, -38.7). It is right as often as the last tracked pose
    faces right: a track that turned round while judged tracked is kept turned. 0: off. Not in
    the paper."""
    reinit_check_delta: float | None = eqx.field(default=None, static=True)
    """A margin on Delta (Eq. 3) for the facing checks' exchange (:attr:`reinit_check_tracked`,
    :attr:`reinit_check_fit`): where set, the exchanged landmarks' fit replaces the plain one
    only if its Delta is at most the plain fit's plus this margin (both fits rendered against
    the frame's depth; host side, one small scoring call where a check fires; its first use
    compiles a small program). ``None`` (the default): facing alone decides. Delta sees the
    depth that 2D-only landmarks do not: on the screen's side views, 15 of 49 firings of the
    tracked check turned a right facing wrong, and a margin of 0.02 refused 10 of those while
    keeping 31 of 32 right flips, read off the same runs. On fresh tuning runs it did not
    hold: 0.02 refused 8 of 10 right flips there (their exchanged fits scored worse by up to
    0.040), and its offline screen failed (2026-12-06: 4 of 60 runs changed, D +0.18 mm, one
    run +10.2; benchmarks/README.md, "Delta's margin on the facing check, screened"), so it
    stays off. Not in the paper."""
    min_landmarks: int = eqx.field(default=4, static=True)
    """Fewer 3D landmarks than this: the frame is 'no_observation' (pose held)."""
    use_floor: bool = eqx.field(default=True, static=True)
    """Fit a floor plane at (re-)initialisation and drop depth near it from the observation
    (not in the paper). A plane is used only if the body's root lies 0.3-1.6 m above it (else:
    no floor)."""

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"TrackerConfig.method must be one of {METHODS}, got {self.method!r}")
        if self.fit is None:
            self.fit = (
                FitSettings(residuals=ResidualSettings(loss="l1"))
                if self.method == "lvm"
                else FitSettings(max_steps=MHT_FIT_STEPS, residuals=ResidualSettings(loss="l2"))
            )
        elif not isinstance(self.fit, FitSettings):
            raise ValueError(f"TrackerConfig.fit must be a FitSettings or None, got {self.fit!r}")
        if self.far_side_bound and not self.fit.residuals.depth_bounds:
            bounds = dataclasses.replace(self.fit.residuals, depth_bounds=True)
            self.fit = dataclasses.replace(self.fit, residuals=bounds)
        # Python numbers become floats, so an int (r=0) never changes the traced dtype; arrays
        # (a vmapped sweep over configurations) pass through.
        # The traced fields are the non-static ones: the declarations below are the only list.
        traced = (f.name for f in dataclasses.fields(self) if not f.metadata.get("static"))
        for name in traced:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                if isinstance(v, (bool, str)) or v is None:
                    raise ValueError(f"TrackerConfig.{name} must be a number, got {v!r}")
                continue
            setattr(self, name, float(v))
        if self.lift_rule not in LIFT_RULES:
            raise ValueError(
                f"TrackerConfig.lift_rule must be one of {LIFT_RULES}, got {self.lift_rule!r}"
            )
        if self.num_hypotheses < 1:
            raise ValueError(
                f"TrackerConfig.num_hypotheses must be >= 1, got {self.num_hypotheses}"
            )
        for name in ("r", "R"):
            v = getattr(self, name)
            if isinstance(v, float) and not 0.0 <= v < 1.0:
                raise ValueError(f"TrackerConfig.{name} must be in [0, 1), got {v}")
        v = self.lift_band
        if isinstance(v, float) and not (math.isfinite(v) and v >= 0):
            raise ValueError(f"TrackerConfig.lift_band must be >= 0 metres, got {v!r}")
        v = self.depth_confidence
        if isinstance(v, float) and not 0.0 <= v <= 1.0:
            raise ValueError(f"TrackerConfig.depth_confidence must be in [0, 1], got {v}")
        v = self.bound_turn_sin
        if isinstance(v, float) and not 0.0 <= v <= 1.0:
            raise ValueError(f"TrackerConfig.bound_turn_sin must be in [0, 1], got {v}")
        v = self.bound_min_landmarks
        if isinstance(v, float) and not (math.isfinite(v) and v >= 0):
            raise ValueError(f"TrackerConfig.bound_min_landmarks must be >= 0, got {v!r}")
        v = self.depth_confidence_far
        if isinstance(v, float) and not 0.0 <= v <= 1.0:
            raise ValueError(f"TrackerConfig.depth_confidence_far must be in [0, 1], got {v}")
        for name in _POSITIVE:
            v = getattr(self, name)
            if isinstance(v, float) and not (math.isfinite(v) and v > 0):
                raise ValueError(f"TrackerConfig.{name} must be a positive number, got {v!r}")
        if not 0 <= self.limb_hypotheses <= 4 or (self.n > 1 and self.limb_hypotheses >= self.n):
            raise ValueError(
                f"TrackerConfig.limb_hypotheses must be in 0..4 and smaller than the number of "
                f"hypotheses ({self.n}), got {self.limb_hypotheses}"
            )
        for name in ("far_side_bound", "bound_trusted"):
            if getattr(self, name) not in (None, True, False):
                raise ValueError(
                    f"TrackerConfig.{name} must be True, False or None (by the tracker's mode), "
                    f"got {getattr(self, name)!r}"
                )
        if self.bound_trusted and self.far_side_bound is not True:
            raise ValueError(
                "TrackerConfig.bound_trusted gates far_side_bound; set far_side_bound=True too "
                f"(got bound_trusted=True, far_side_bound={self.far_side_bound!r})"
            )
        if self.far_side_2d and self.far_side_bound:
            raise ValueError(
                "TrackerConfig: far_side_2d and far_side_bound are two treatments of the same "
                "landmarks; set one of them, got both True"
            )
        if not isinstance(self.reinit_check_fit, bool):
            raise ValueError(
                f"TrackerConfig.reinit_check_fit must be True or False, got "
                f"{self.reinit_check_fit!r}"
            )
        for name in (
            "reinit_keep_facing",
            "reinit_check_frames",
            "reinit_partial_frames",
            "reinit_check_tracked",
        ):
            n = getattr(self, name)
            if n is None and name == "reinit_check_frames":
                continue
            if isinstance(n, bool) or not isinstance(n, int) or n < 0:
                raise ValueError(f"TrackerConfig.{name} must be an int >= 0 (frames), got {n!r}")
        axes = self.reinit_partial_axes
        if not isinstance(axes, bool):
            raise ValueError(f"TrackerConfig.reinit_partial_axes must be a bool, got {axes!r}")
        margin = self.reinit_check_delta
        if margin is not None and (
            isinstance(margin, bool)
            or not isinstance(margin, (int, float))
            or not math.isfinite(margin)
        ):
            raise ValueError(
                f"TrackerConfig.reinit_check_delta must be None or a finite number (a margin on "
                f"Delta), got {margin!r}"
            )
        if self.score_width < 8 or self.score_height < 8:
            raise ValueError(
                f"TrackerConfig: score size must be at least 8x8, got "
                f"{self.score_width}x{self.score_height}"
            )

    @property
    def n(self) -> int:
        """Number of hypotheses actually used (1 for LVM)."""
        return 1 if self.method == "lvm" else self.num_hypotheses

    @property
    def num_limb_hypotheses(self) -> int:
        """Limb hypotheses actually used (0 for LVM)."""
        return 0 if self.n == 1 else self.limb_hypotheses

    def for_mode(self, mode: str) -> TrackerConfig:
        """This configuration with the fields left to the tracker's mode (``None``) decided for
        ``mode`` (``"offline"``, ``"online"`` or ``"per-frame"``): ``far_side_bound`` on online
        (off with ``far_side_2d``, its alternative), off otherwise; ``bound_trusted`` on where
        the bound is on and the mode is online. Fields given stay as given. :class:`Tracker`
        and :func:`track_many` call it; the result is what their results' ``config`` shows."""
        if mode not in MODES:
            raise ValueError(
                f"TrackerConfig.for_mode: mode must be 'offline', 'online' or 'per-frame', "
                f"got {mode!r}"
            )
        bound = self.far_side_bound
        if bound is None:
            bound = mode == "online" and not self.far_side_2d
        trusted = self.bound_trusted
        if trusted is None:
            trusted = bound and mode == "online"
        if (bound, trusted) == (self.far_side_bound, self.bound_trusted):
            return self
        return self.replace(far_side_bound=bound, bound_trusted=trusted)

    def replace(self, **changes) -> TrackerConfig:
        """A copy with ``changes`` applied (validated like the constructor)."""
        return dataclasses.replace(self, **changes)

    @staticmethod
    def recommended(method: str = "mht_h", **overrides) -> TrackerConfig:
        """What we ship for ``method``: the defaults for MHT_h (N = 10); for the other methods
        the paper's best (N, r, R) and Eq. (1)'s sum of norms (``"l1"``), with our additions
        (surface offset, unknown invalid depth, floor removal, 2D temporal weight, reseeding,
        consensus refit) on. ``posetrack track --method`` uses this."""
        if method == "mht_h":
            return TrackerConfig(**{"method": "mht_h", **overrides})
        return _paper_best(method, overrides)

    @staticmethod
    def paper(method: str, **overrides) -> TrackerConfig:
        """The paper's method alone, at its best setting (its Table 2): LVM; MHT_r N=20 r=0.05
        R=0.15; MHT_g N=5 r=0.05 R=0.15; MHT_h N=5 r=R=0; Eq. (1)'s sum of norms (``"l1"``),
        8 LM steps per frame; every addition of this project off (``BEYOND_THE_PAPER``: no
        surface offset, Eq. (3) with invalid depth as background, no floor removal, no 2D
        temporal weight, no reseeding, no consensus refit).

        What the paper does not specify keeps our defaults: the sigmas and d_hmax (the paper
        gives no values), the 'predefined range' of the observation (``body_range``), the
        scoring resolution, the lifting window, the confidence threshold, and the host-side
        initialisation, body-shape estimation and track-loss handling (by agreement only:
        ``lost_delta = 1``, since with the floor in the observation a right pose scores
        Delta ~0.9).
        """
        # Without floor removal the floor under the feet is part of the observation, so even
        # a right pose has Delta ~0.9 (measured: 0.88-0.91 on the demo's sequence, 0.6 with the
        # floor removed): track loss by Delta (ours, host side) is off; by agreement it stays.
        return _paper_best(method, {**BEYOND_THE_PAPER, "lost_delta": 1.0, **overrides})

    def is_paper(self) -> bool:
        """Whether every addition beyond the paper is off."""
        return all(getattr(self, k) == v for k, v in BEYOND_THE_PAPER.items())


def _paper_best(method: str, overrides: dict) -> TrackerConfig:
    """The paper's best (N, r, R) of ``method`` with Eq. (1)'s sum of norms, then
    ``overrides``."""
    if method not in PAPER_BEST:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    l1 = FitSettings(residuals=ResidualSettings(loss="l1"))
    return TrackerConfig(**{"method": method, **PAPER_BEST[method], "fit": l1, **overrides})
