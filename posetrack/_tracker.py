"""The host-side tracker: body shape, (re-)initialisation, track loss, whole sequences.

Inputs are checked by :mod:`posetrack._inputs`; a sequence's result is
:class:`posetrack._result.TrackResult`.

The per-frame math is :func:`posetrack._step.tracker_step`, one jitted call per frame. This
module keeps what is naturally sequential and rare: estimating the body dimensions from the
first frames, initialising from observations alone, deciding that a track is lost and
re-initialising when observations return.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable, Sequence
from functools import cache, partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from . import _body as body
from ._arbitration import Branch, OnlineArbitration, Reading
from ._associate import (
    PERSON_RULES,
    Candidates,
    FollowSettings,
    PersonFollower,
    PersonRule,
    lift_candidates,
    other_people_mask,
)
from ._batcher import Pending, resolve
from ._bothways import Reindexed, fuse_smoothed, fuse_weights
from ._camera import Intrinsics, project_host
from ._chunk import status_limits, step_chunk
from ._config import MODES, TrackerConfig
from ._depthobs import NO_FLOOR, fit_floor_plane, tracker_landmarks, tracker_observation
from ._duplicates import DuplicateFilter, DuplicateSettings
from ._fit import FitSettings, fit_pose
from ._geometry import surface_offsets
from ._init import estimate_shape, initial_pose, pose_moved_onto
from ._inputs import check_depth, check_frame, check_people
from ._observe import Landmarks, observed_share
from ._programs import (
    Program,
    device_f32,
    device_key,
    prepare_in_background,
    prepare_now,
    program,
)
from ._residuals import LEG_TERM_FIELDS
from ._result import TrackResult, keypoint_confidence
from ._shapefit import (
    ShapeFitSettings,
    _Refinement,
    _start_refinement,
    refine_programs,
    refine_shape,
)
from ._sides import (
    SIDE_GROUPS,
    SideLabeller,
    SideSettings,
    arbitration_spans,
    frontal_turns,
    prefer_exchanged,
    two_sided_exchanged,
)
from ._smooth import (
    OnlineWindow,
    SmoothSettings,
    online_flush,
    online_update_program,
    smooth_sequence,
    smooth_window_program,
)
from ._so3 import quat_to_matrix
from ._step import (
    LOST,
    NO_OBSERVATION,
    TRACKED,
    FrameEstimate,
    TrackState,
    score_hypotheses,
    tracker_step,
)
from ._visibility import TORSO_PAIRS

_DTYPE = jnp.float32


def _host_f32(x):
    """``x`` as a float32 argument of a compiled program: a float32 JAX array as it is, anything
    else converted on the host (``jnp.asarray`` would put it on the device and convert it there,
    one more dispatched operation per argument and frame). The same values either way."""
    if isinstance(x, jax.Array) and x.dtype == _DTYPE:
        return x
    return np.asarray(x, np.float32)


#: The pose pushed into the online window for a frame outside any track (never published).
_NO_POSE = body.facing_camera_params_np(2.5)

#: Fewer tracked frames than this and ``refine`` is skipped (the shape stays as estimated).
_MIN_REFINE_FRAMES = 3


@dataclasses.dataclass
class _Refining:
    """An online refinement run a part at a time (``ShapeFitSettings.online_spread``): the
    work, its frames' indices, the earlier refinement's ``(report, seconds)`` to record with
    it, and the :attr:`Tracker._frames_seen` of its last part (one part a frame)."""

    work: _Refinement
    frames_used: np.ndarray
    first: tuple | None
    at: int


#: The online mode's default lag, frames (100 ms at 30 fps): each pose is published once the
#: ``ONLINE_LAG`` frames after it are seen. The smallest lag whose poses beat a Gaussian filter
#: of the per-frame poses (sigma 2 frames, which sees the future) on D, clean and occluded,
#: on the tuning seeds of both the standard and the wide generator (lag 2 missed the wide
#: occluded clips by 0.7 mm; benchmarks/README.md). ``lag=0`` publishes each frame's pose at
#: once (shakier).
ONLINE_LAG = 3

#: Every left/right keypoint pair exchanged (a whole-body swap): ``x[_BODY_FLIP]``.
_BODY_FLIP = body.flip_labels(range(18))

#: Frames per compiled call in :meth:`Tracker.run` (offline and per-frame modes): the steps of
#: up to this many frames run as one ``lax.scan`` with the track-loss logic inside
#: (:mod:`posetrack._chunk`), the same poses as one call per frame, bit for bit.
RUN_CHUNK = 16

#: ``progress(done, total, postfix)``: called after each frame by :meth:`Tracker.run`.
ProgressCallback = Callable[[int, int, str], None]


# Module-level programs, compiled once per (static part of the config, shapes) and shared by
# every Tracker (``_programs.Program``: a jitted function that is also kept on disk when the
# cache is on, so a new process skips tracing). The config is an ordinary argument: its static
# fields are part of the pytree structure (a change recompiles), its float fields are traced
# leaves (a change does not).
@program("step")
def step(
    config: TrackerConfig, shape, intrinsics, floor, state: TrackState, depth, kp2d, conf
) -> tuple[TrackState, FrameEstimate]:
    """:func:`~posetrack.tracker_step`, compiled, exactly as :meth:`Tracker.update` calls it."""
    return tracker_step(config, shape, intrinsics, floor, state, depth, kp2d, conf)


@program("lift", rare=True)
def lift(config: TrackerConfig, shape, intrinsics, depth, kp2d, conf) -> Landmarks:
    """The tracker's lifting (``tracker_landmarks``), compiled."""
    return tracker_landmarks(config, shape, intrinsics, depth, kp2d, conf)


@program("initial_fit", static_argnums=(0,), rare=True)
def initial_fit(settings: FitSettings, shape, intrinsics, params0, lm: Landmarks, key):
    """The (re-)initialisation fit on all landmarks, compiled; returns (FitResult, keypoints,
    (next key, hypotheses' key)): ``jax.random.split(key)`` rides along, so a new track
    runs no JAX operation of its own (each would be one more compilation on a cold start,
    3 s of one while the step compiled beside it)."""
    res = fit_pose(
        params0, shape, lm, intrinsics, use3d=lm.has_depth, use2d=lm.detected, settings=settings
    )
    keys = jax.random.split(key)
    return res, body.keypoints(shape, res.params), (keys[0], keys[1])


@program("score_fits", rare=True)
def score_fits(config: TrackerConfig, shape, intrinsics, floor, depth, params) -> Array:
    """Delta (Eq. 3) of a few whole-body fits ``params`` (fits, 43) against one frame's depth,
    observed around the first fit's root, compiled: how ``reinit_check_delta`` weighs a
    facing check's exchanged fit against the plain one."""
    z_d, z_fg, known, small = tracker_observation(config, depth, intrinsics, floor, params[0, :3])
    return score_hypotheses(config, shape, params, z_d, z_fg, small, known)


def _keep_best_observed(kept: dict, stretch: int, n3d: int, entry) -> None:
    """The body-shape refinement's frame choice: per stretch of frames, the tracked frame with
    the most 3D landmarks. ``kept[stretch] = (n3d, *entry())`` when ``n3d`` beats the kept
    one (``entry`` is only called then)."""
    if n3d > kept.get(stretch, (-1,))[0]:
        kept[stretch] = (n3d, *entry())


@dataclasses.dataclass
class _RunOutputs:
    """What :meth:`Tracker.run` collects per frame (NumPy, frames first)."""

    kp3: np.ndarray
    params: np.ndarray
    delta: np.ndarray
    status: np.ndarray
    conf: np.ndarray
    lm3: np.ndarray
    has_d: np.ndarray
    det: np.ndarray
    person: np.ndarray
    exchanged: np.ndarray
    num_people: np.ndarray
    kp2: np.ndarray
    lm_conf: np.ndarray

    @classmethod
    def empty(cls, T: int, groups: int) -> _RunOutputs:
        return cls(
            kp3=np.full((T, 18, 3), np.nan), params=np.full((T, 43), np.nan),
            delta=np.full(T, np.nan), status=np.full(T, NO_OBSERVATION, np.int8),
            conf=np.zeros((T, 18), np.float32), lm3=np.zeros((T, 18, 3)),
            has_d=np.zeros((T, 18), bool), det=np.zeros((T, 18), bool),
            person=np.full(T, -1, np.int64), exchanged=np.zeros((T, groups), bool),
            num_people=np.zeros(T, np.int64), kp2=np.zeros((T, 18, 2), np.float32),
            lm_conf=np.zeros((T, 18), np.float32),
        )  # fmt: skip

    def copy_span(self, start: int, stop: int) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name)[start:stop].copy() for f in dataclasses.fields(self)}

    def put_span(self, start: int, span: dict[str, np.ndarray]) -> None:
        for name, v in span.items():
            getattr(self, name)[start : start + len(v)] = v


def _along_rays(lm3: np.ndarray, has_d: np.ndarray, moved: np.ndarray | None) -> np.ndarray:
    """The (T, 18, 3) landmarks with depth moved along their camera rays by ``moved`` (18,)
    metres (a refined shape's change of surface offsets); unchanged where ``moved`` is None."""
    if moved is None:
        return lm3
    norm = np.linalg.norm(lm3, axis=-1, keepdims=True)
    ray = np.divide(lm3, norm, out=np.zeros_like(lm3), where=norm > 0)
    return np.where(has_d[..., None], lm3 + moved[None, :, None] * ray, lm3)


@dataclasses.dataclass
class _Prepared:
    """One frame of a chunk as the host prepared it (:meth:`Tracker._prepare_chunk`)."""

    t: int
    person_index: int
    """The followed detection (-1: not found; no step)."""
    cands: Candidates
    depth: np.ndarray
    """Depth as fitted (metres, other people removed)."""
    kp: np.ndarray
    conf: np.ndarray
    lost_only: bool
    """Without a step: only other people in view (the frame counts as lost)."""
    person: int
    """:attr:`Tracker.person` after the frame."""
    exchanged: np.ndarray
    host: tuple
    """The host's state after preparing the frame: (follower reference, frames since it was
    updated, labeller, duplicate filter, frames seen); restored if the track is dropped here."""


#: The face's left/right pairs (eyes, ears) exchanged: an index over 18 keypoints.
_FACE_FLIP = body.flip_labels(np.ravel(SIDE_GROUPS["face"]))


def _turns_around(turns: list[tuple[int, int]], spans: dict) -> list[tuple[int, int]]:
    """The turns (``[(start, stop), ...]``) widened so that no arbitrated stretch of ``spans``
    (start -> stop) straddles their ends (a stretch is judged inside one tracking of the
    turn, whole), merged where they then overlap."""
    out: list[tuple[int, int]] = []
    for start, stop in turns:
        for a, b in spans.items():
            if a < start < b:
                start = a
            if a < stop < b:
                stop = b
        if out and start < out[-1][1]:
            out[-1] = (out[-1][0], max(stop, out[-1][1]))
        else:
            out.append((start, stop))
    return out


def _body_flipped(lm: Landmarks) -> Landmarks:
    """``lm`` (host arrays) with every left/right keypoint pair exchanged."""
    return jax.tree.map(lambda x: np.asarray(x)[_BODY_FLIP], lm)


def _faces_away(params: np.ndarray, reference: np.ndarray) -> bool:
    """Whether pose ``params`` (43,) faces more than 90 degrees away from ``reference``: their
    root left/right axes point apart."""
    left = quat_to_matrix(np.asarray(params[3:7], np.float64))[:, 0]
    return bool(np.dot(left, quat_to_matrix(np.asarray(reference[3:7], np.float64))[:, 0]) < 0)


class Tracker:
    """Track one person through an RGB-D sequence.

    Example::

        tracker = posetrack.Tracker(intrinsics, posetrack.TrackerConfig(method="mht_h"))
        result = tracker.run(depth_frames, keypoints2d, confidence)
        result.keypoints3d  # (T, 18, 3) metres

    or frame by frame with :meth:`update`. For a live camera use ``mode="online"``: each
    frame's smoothed pose is published ``lag`` frames later as :attr:`lagged` (default
    :data:`ONLINE_LAG`, 3 frames: 100 ms at 30 fps; ``lag=0`` publishes at once, shakier).
    The body dimensions are estimated from the first
    ``config.shape_frames`` frames of :meth:`run` unless ``shape`` is given.

    **Body shape from depth** (``refine="auto"``, the default offline and online, unless
    ``shape`` is given): :func:`refine_shape` refits the body dimensions and the poses of 8
    tracked frames against their depth (:meth:`ShapeFitSettings.tracking`). Offline it runs
    after the forward pass on frames spread over the recording, the part radii free to grow or
    shrink together (one girth for the body), and the motion model then fits every frame with
    the refined shape (the per-frame poses' keypoints as its anchor); with
    ``ShapeFitSettings.offline_first`` (opt-in) the first frames are tracked alone first and
    the whole recording starts from their refined shape (:meth:`progress_frames`; with
    ``offline_first_below`` only where those frames are poorly observed). Online
    it runs causally, when ``ShapeFitSettings.online_first`` (20) and again when
    ``online_after`` (60) frames have been tracked, each time on frames among those (the
    second from the landmark-based shape again), and the frames after are tracked with the
    refined shape (those two :meth:`update` calls take a few seconds longer on a CPU). Where
    a joint sits inside the body, the shoulders above all, then follows the person rather
    than the default adult.
    ``refine=None`` turns it off; :attr:`refine_report` says what it changed.

    **Several people in view.** Keypoints may list P people per frame (``(P, 18, 2)``, any
    order, P varying from frame to frame). The tracker chooses one person when it first
    initialises (``person``: ``"auto"`` = the most complete detection, the closest of those;
    ``"largest"``, ``"closest"`` or an index into the first frame's list) and then follows it:
    each frame the detection nearest (in 3D) to where the person was last seen is taken if it
    lies within a gate (``follow``, :class:`FollowSettings`; ``"auto"``, the default:
    :meth:`FollowSettings.for_mode`, offline with a depth band), the others are ignored and
    their pixels removed from the depth the tracker fits. When only other people are in view
    the frame is 'lost' (the last pose is held); after ``config.lost_patience`` such frames
    the track restarts, but only on a detection near the last position and consistent with
    the body proportions measured while tracking. ``follow=None`` takes the highest-scoring
    detection every frame (what a per-frame choice does: the track hops between people; kept
    for comparison).

    **Left/right swaps of the detector** are undone before each frame is fitted
    (``sides``, :class:`SideSettings`; ``"auto"``, the default: on offline and online, off
    per-frame): a group of keypoints (arms, legs, the torso:
    :meth:`SideSettings.for_mode`) whose left and right sides both jump and later jump back
    is read exchanged while that is the continuous reading.
    Offline a pre-pass reads the whole recording forwards and backwards
    (:func:`two_sided_exchanged`), and the depth arbitrates: each stretch read exchanged is
    tracked twice from the same state, exchanged and as detected, and the exchange is kept
    only where its poses' Delta is lower (:attr:`side_spans`). 2D continuity alone misreads
    occluded side views (arms overlapping in the image); the depth does not reward those
    misreadings. Online only the forward pass exists; where it newly reads a group
    exchanged, the next ``lag + 1`` frames are tracked both ways and the depth decides before
    any of them is published (:meth:`update`). :attr:`TrackResult.exchanged` says where
    labels were exchanged.

    **A detection that jumped onto another keypoint** (an ankle reported on the neck for a
    dozen frames, a wrist on the other wrist) is dropped before the labelling and the fit
    while it stays away from where it was last seen (``duplicates``,
    :class:`DuplicateSettings`; ``"auto"``, the default: on offline, where the left/right
    pre-pass withholds it too, and online; off per-frame, the paper's tracker;
    :attr:`duplicates_dropped` counts them).

    **Frames in chunks.** Offline and per-frame, :meth:`run` runs the steps of ``chunk``
    frames (default :data:`RUN_CHUNK`, 16) as one compiled call, the track-loss decisions
    inside it, and prepares the next chunk on the host while one computes; the poses are
    those of one call per frame (``chunk=1``, what :meth:`update` does), bit for bit. A
    tracker's first call steps one frame, so the first pose does not wait for a whole chunk;
    the poses of a chunk are reported when its call is done. Online, :meth:`run` goes
    frame by frame (the motion model and the left/right judgement run between frames).
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        config: TrackerConfig | None = None,
        *,
        shape: body.BodyShape | None = None,
        seed: int = 0,
        depth_scale: float = 1000.0,
        person: PersonRule = "auto",
        follow: FollowSettings | str | None = "auto",
        mode: str = "offline",
        lag: int = ONLINE_LAG,
        motion: SmoothSettings = SmoothSettings(),
        fps: float = 30.0,
        sides: SideSettings | str | None = "auto",
        refine: ShapeFitSettings | str | None = "auto",
        chunk: int = RUN_CHUNK,
        duplicates: DuplicateSettings | str | None = "auto",
    ):
        # As given: the offline shape pre-pass (``refine.offline_first``) tracks with them.
        self._options = dict(
            config=config, shape=shape, seed=seed, depth_scale=depth_scale, person=person,
            follow=follow, mode=mode, lag=lag, motion=motion, fps=fps, sides=sides,
            refine=refine, chunk=chunk, duplicates=duplicates,
        )  # fmt: skip
        self._intrinsics_given = intrinsics
        if mode not in MODES:
            raise ValueError(f"Tracker: mode must be one of {MODES}, got {mode!r}")
        if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 0:
            raise ValueError(f"Tracker: lag must be an int >= 0 (frames), got {lag!r}")
        if not isinstance(motion, SmoothSettings):
            raise TypeError(f"Tracker: motion must be posetrack.SmoothSettings, got {type(motion)}")
        if mode == "online" and lag >= motion.online_window:
            raise ValueError(
                f"Tracker: lag {lag} must be smaller than motion.online_window "
                f"({motion.online_window} frames)"
            )
        if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
            raise ValueError(f"Tracker: chunk must be an int >= 1 (frames per call), got {chunk!r}")
        self.chunk = int(chunk)
        """Frames per compiled call in offline and per-frame :meth:`run` (1: one call per
        frame, as :meth:`update`); see :data:`RUN_CHUNK`."""
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"Tracker: fps must be positive, got {fps!r}")
        # The lag is the online mode's alone: offline and per-frame poses wait for nothing.
        lag = int(lag) if mode == "online" else 0
        self.mode, self.lag, self.motion, self.fps = mode, lag, motion, float(fps)
        # The configuration as this mode runs it (TrackerConfig.for_mode: the fields left to
        # the mode, far_side_bound and bound_trusted, decided).
        config = config or TrackerConfig()
        if not isinstance(config, TrackerConfig):
            raise TypeError(f"Tracker: config must be posetrack.TrackerConfig, got {type(config)}")
        config = config.for_mode(mode)
        # What the motion model's compiled programs see: ``both_ways`` is the run's business,
        # not theirs (one program either way, and one cache entry for ``posetrack warmup``).
        self._smoother = dataclasses.replace(motion, both_ways=False)
        # The smoother fits the step's landmarks, so what the step's fits add holds in it too:
        # the depth bounds (TrackerConfig.far_side_bound), the limit on crossed legs
        # (ResidualSettings.leg_cross: its landmarks would cross them again where the detector
        # exchanged them) and label-free legs (ResidualSettings.leg_labels_free) with the
        # fits' gates on them (side-on, margin, fewest landmarks on depth): LEG_TERM_FIELDS.
        own, add, fits = motion.residuals, {}, config.fit.residuals
        if config.far_side_bound and not own.depth_bounds:
            add["depth_bounds"] = True
        if fits.leg_cross > 0 or fits.leg_labels_free:  # the fits' leg terms, as a group
            add.update({name: getattr(fits, name) for name in LEG_TERM_FIELDS})
        if add:
            residuals = dataclasses.replace(own, **add)
            self._smoother = dataclasses.replace(self._smoother, residuals=residuals)
        if isinstance(sides, str) and sides == "auto":
            sides = None if mode == "per-frame" else SideSettings.for_mode(mode)
        if sides is not None and not isinstance(sides, SideSettings):
            raise TypeError(
                f"Tracker: sides must be 'auto', posetrack.SideSettings or None, got {sides!r}"
            )
        self.sides: SideSettings | None = sides
        if isinstance(duplicates, str) and duplicates == "auto":
            duplicates = None if mode == "per-frame" else DuplicateSettings()
        if duplicates is not None and not isinstance(duplicates, DuplicateSettings):
            raise TypeError(
                "Tracker: duplicates must be 'auto', posetrack.DuplicateSettings or None, got "
                f"{duplicates!r}"
            )
        self.duplicates: DuplicateSettings | None = duplicates
        if isinstance(refine, str) and refine == "auto":
            auto = mode != "per-frame" and shape is None
            refine = ShapeFitSettings.tracking(mode) if auto else None
        if refine is not None and not isinstance(refine, ShapeFitSettings):
            raise TypeError(
                f"Tracker: refine must be 'auto', posetrack.ShapeFitSettings or None, got "
                f"{refine!r}"
            )
        if refine is not None and mode == "per-frame":
            raise ValueError(
                "Tracker: refine (body shape from depth) needs mode='offline' or 'online', got "
                "mode='per-frame'"
            )
        self.refine: ShapeFitSettings | None = refine
        self.refine_report: dict | None = None
        """After :meth:`run` with ``refine``: :func:`refine_shape`'s report of that run
        (``None`` when it did not run in the last :meth:`run`)."""
        if not isinstance(intrinsics, Intrinsics):
            raise TypeError(
                f"Tracker: intrinsics must be posetrack.Intrinsics, got {type(intrinsics)}"
            )
        vals = [float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)]
        if not all(np.isfinite(vals)) or vals[0] <= 0 or vals[1] <= 0:
            raise ValueError(f"Tracker: intrinsics are not physical: fx, fy, cx, cy = {vals}")
        if not (np.isfinite(depth_scale) and depth_scale > 0):
            raise ValueError(f"Tracker: depth_scale must be positive, got {depth_scale!r}")
        if isinstance(follow, str) and follow == "auto":
            follow = FollowSettings.for_mode(mode)
        if follow is not None and not isinstance(follow, FollowSettings):
            raise TypeError(
                f"Tracker: follow must be 'auto', posetrack.FollowSettings or None, got {follow!r}"
            )
        is_index = isinstance(person, (int, np.integer)) and not isinstance(person, bool)
        if (is_index and person < 0) or (not is_index and person not in PERSON_RULES):
            raise ValueError(
                f"Tracker: person must be one of {PERSON_RULES} or an index >= 0, got {person!r}"
            )
        self.person_rule = person
        self.follow = follow
        self.config = config
        self.intrinsics = jax.tree.map(device_f32, intrinsics)
        self.depth_scale = float(depth_scale)
        self.shape = (
            None if shape is None else jax.tree.map(device_f32, shape)
        )
        self._key = device_key(seed)
        self._state: TrackState | None = None
        self._floor = device_f32(NO_FLOOR)
        self._lost_run = 0
        self._ever_initialized = False
        # (frame, state, last tracked keypoints) of the last track loss: a quick
        # re-initialisation keeps its facing; the followed person's keypoints (18, 2) and
        # confidences (18,) as fitted in the last tracked frame.
        self._dropped: tuple | None = None
        self._last_tracked_kp: tuple | None = None
        # (frame, pose (43,), keypoints (18, 3)) of the last frame judged tracked: where a
        # re-initialisation without a left/right pair starts (reinit_partial_frames).
        self._last_tracked_pose: tuple | None = None
        self.reinit_flip_frames: tuple[int, ...] = ()
        """Frames (0-based, as counted by :meth:`update` and :meth:`run`; since the last
        :meth:`run`) whose re-initialisation exchanged every left/right pair to keep the lost
        track's facing (``TrackerConfig.reinit_keep_facing``): places where the tracker
        overrode the detector's labels."""
        self.reinit_check_deltas: tuple[tuple[int, float, float], ...] = ()
        """With ``TrackerConfig.reinit_check_delta``: (frame, Delta of the plain fit, Delta of
        the exchanged fit) of every re-initialisation whose facing check weighed the two (since
        the last :meth:`run`; a frame the offline tracker tracks again appears again)."""
        # The initial fit reads the facing from the whole body, the detector's leg labels
        # included: with the limit on crossed legs (ResidualSettings.leg_cross) legs the
        # detector labelled exchanged would turn the body round instead (the legs uncross from
        # a right facing in the frames after), and with label-free legs
        # (ResidualSettings.leg_labels_free) the legs would say nothing of the facing (a side
        # view under occlusion then started turned round).
        init_residuals = dataclasses.replace(
            self.config.fit.residuals, leg_cross=0.0, leg_labels_free=False
        )
        self._init_settings = dataclasses.replace(
            self.config.fit, max_steps=self.config.init_steps, residuals=init_residuals
        )
        self.compile_s = 0.0
        self._init_timed = False
        self._step_calls = 0
        self._step_times: list[float] = []
        self._motion_times: list[float] = []
        self.smooth_s = 0.0
        self.sides_s = 0.0
        """Seconds of the last :meth:`run`'s left/right pre-pass (offline, ``sides`` set)."""
        self.both_ways_frames = 0
        """Offline with :attr:`SmoothSettings.both_ways`: frames the last :meth:`run` averaged
        over its two passes (both tracked the same person there)."""
        self.refine_s = 0.0
        self.prepass_s = self._prepass_refine_s = 0.0
        """Seconds of the last offline :meth:`run`'s shape pre-pass (``refine.offline_first``;
        0 without one): its tracking and refinement, part of :attr:`refine_s` too."""
        self.prepass_share: float | None = None
        """The last offline :meth:`run`'s gate of the shape pre-pass
        (``refine.offline_first_below``): the share of its frames' keypoints observed on depth
        (:func:`~posetrack.observed_share`); the pre-pass ran where it was below the gate.
        None without a gate."""
        self._prepare_started = False
        # Inside track_many: whether run() gives the batch slot up after its steps (a shape
        # pre-pass's tracker does not: its recording is tracked again in the same slot).
        self._leaves_slot = True
        # (StepBatcher, slot) when track_many runs this tracker's steps batched with others'.
        self._batched = None
        self._found_floor: np.ndarray | None = None  # the first in this run (TrackResult.floor)
        self._depth_fit: np.ndarray | None = None
        self.side_spans: list[tuple[int, int, float, float, bool]] = []
        """With :attr:`sides` arbitrated, per stretch tracked both ways ``(start, stop, Delta
        summed as detected, Delta summed exchanged, exchange kept)``: after an offline
        :meth:`run`, the stretches the two-sided labelling read exchanged; online, the first
        frames of each exchange the forward pass read (since the last :meth:`run`)."""
        self.turn_spans: list[tuple[int, int, float, float, bool]] = []
        """With :attr:`SideSettings.frontal_turns`, after an offline :meth:`run`: per turn
        through a frontal view tracked both ways ``(start, stop, Delta summed as labelled,
        Delta summed mirrored, mirrored kept)``."""
        self.side_span_groups: list[np.ndarray] = []
        """Per entry of :attr:`side_spans`, ``bool (groups,)``: which :attr:`sides` groups the
        stretch judged (online, the groups newly read exchanged; offline, those the two-sided
        labelling read exchanged in any of its frames)."""
        self._forget_person()
        self._reset_motion()

    def _reset_motion(self) -> None:
        """Empty the online motion model's window (a new recording starts)."""
        self._window = OnlineWindow.empty(self.motion.online_window)
        self._window_frames = np.full(self.motion.online_window, -1, np.int64)
        self._window_valid = np.zeros(self.motion.online_window, bool)
        self._frames_seen = 0
        # Online body-shape refinement (causal): tracked frames counted so far, and per
        # stretch of them the best-observed one (3D landmarks, params, depth, kp2, confidence).
        self._online_refine_pending = self.mode == "online" and self.refine is not None
        self._online_tracked = 0
        self._online_kept: dict[int, tuple] = {}
        # The optional earlier refinement (``refine.online_first``): its frames, and the shape
        # the tracker began with (the later refinement starts from it again).
        self._online_first_pending = self._online_refine_pending and self.refine.online_first > 0
        self._online_kept_first: dict[int, tuple] = {}
        self._online_shape0 = None
        # A refinement run a part at a time (``refine.online_spread``) and not yet taken up;
        # one of an earlier recording is dropped.
        self._refining: _Refining | None = None
        self._arbitration = None
        self.lagged: tuple[int, np.ndarray, np.ndarray] | None = None
        """Online mode: ``(frame, params (43,), keypoints (18, 3))`` of the frame ``lag``
        frames before the newest, smoothed (``None`` until there is one)."""

    def _online(self, est: FrameEstimate | None, conf: np.ndarray):
        """The online motion model after a frame: push it into the window, smooth, publish
        the lagged output (:attr:`lagged`). Returns the smoothed ``(params, keypoints)`` of
        frame ``t - lag`` (``None`` if that frame has no pose)."""
        if self._state is None:  # no track: the frame takes part in no smoothing
            kps, params, valid = np.zeros((18, 3)), _NO_POSE, False
        elif est is None:  # held: the pose continues, nothing observed
            kps = np.asarray(body.keypoints(self.shape, self._state.best))
            params, valid, conf = self._state.best, True, np.zeros(18)
        else:
            kps, params, valid = est.keypoints3d, est.params, True
        t0 = time.perf_counter()
        self._window, pose, pose_kps = online_update_program(
            self._smoother, self.shape, _host_f32(self.fps), self._window,
            _host_f32(kps), _host_f32(conf), _host_f32(params), np.asarray(valid, bool),
            self.lag,
        )  # fmt: skip
        self._window_frames = np.roll(self._window_frames, -1)
        self._window_frames[-1] = self._frames_seen - 1
        i = self.motion.online_window - 1 - self.lag
        frame = int(self._window_frames[i])
        # The host mirrors the window's frame numbers and validity (no device round trip).
        self._window_valid = np.roll(self._window_valid, -1)
        self._window_valid[-1] = valid
        has_pose = frame >= 0 and self._window_valid[i]
        if has_pose:
            pose, pose_kps = jax.device_get((pose, pose_kps))  # one transfer
        self._motion_times.append(time.perf_counter() - t0)
        self.lagged = (frame, pose, pose_kps) if has_pose else None
        return self.lagged[1:] if has_pose else None

    def _forget_person(self) -> None:
        # Identity of the followed person: survives a track loss, not a reset().
        self._follower = PersonFollower(self.follow, self.person_rule, self.intrinsics)
        self._person = -1
        self._labeller = (
            None if self.sides is None else SideLabeller(float(self.intrinsics.fx), self.sides)
        )
        self._duplicate_filter = self._new_duplicate_filter()
        self.exchanged = np.zeros(0 if self.sides is None else len(self.sides.groups), bool)
        """Which :attr:`sides` groups the last frame's detections had exchanged."""
        # Offline (run): the pre-pass's followed person and labelling per frame, and the frame
        # being tracked. None outside run() and online.
        self._two_sided: tuple[np.ndarray, np.ndarray] | None = None
        self._run_frame: int | None = None
        # Offline with arbitration (SideSettings.arbitrate): while a stretch is tracked again,
        # the groups whose two-sided reading applies (all False: the labels as detected; one
        # group: SideSettings.arbitrate_groups); None: every group.
        self._exchange_mask: np.ndarray | None = None
        # Offline with SideSettings.frontal_turns: while a turn is tracked the other way, every
        # labelling is mirrored (each group and the face exchanged against its reading).
        self._mirrored = False
        # Online with arbitration: the groups the depth kept as detected (until the labeller
        # reads them as detected again), the groups this frame newly exchanged (or held
        # exchanged past online_rejudge frames since they were judged), and the stretch being
        # tracked both ways (or None).
        G = len(self.exchanged)
        self._veto = np.zeros(G, bool)
        self._new_exchanged = np.zeros(G, bool)
        self._since_judged = np.zeros(G, np.int64)
        self._arbitration: OnlineArbitration | None = None
        # The frames of the judgement that ended at the last update, as the kept reading saw
        # them (``run`` rewrites their rows: each was recorded as the reading leading then).
        self._judged_rows: list | None = None

    # -- set-up ------------------------------------------------------------------------------

    def _start_preparing(self, *, update: bool = True) -> None:
        """Once per tracker: start building its programs in the background."""
        if not self._prepare_started:
            self._prepare_started = True
            self.prepare(background=True, update=update)

    def prepare(self, *, background: bool = False, update: bool | None = None) -> None:
        """Build the compiled programs this tracker needs for its configuration, image size and
        mode now, instead of at the first frame that needs each.

        With ``background=True`` it returns once the step is traced and the rest goes on in
        threads (a frame that needs a program waits for it): :meth:`run` and the first
        :meth:`update` do this, so the step compiles while the body shape is estimated and
        the track initialised. With the cache on
        (:func:`posetrack.enable_cache`, as the command line does), a later process reads the
        programs from disk instead of tracing and compiling them (``posetrack warmup``).

        ``update``: build the per-frame step of :meth:`update` (a live camera) rather than the
        chunked one of :meth:`run` (:attr:`chunk`); by default only in online mode, whose
        :meth:`run` steps frame by frame too.
        """
        if update is None:
            update = self.mode == "online"
        if not isinstance(step, Program):  # replaced (tests count its traces): compile on use
            return
        f32 = partial(jax.ShapeDtypeStruct, dtype=_DTYPE)
        N = self.config.n
        shape = self.shape if self.shape is not None else body.BodyShape.default(_DTYPE)
        intr = self.intrinsics
        depth, kp, conf = f32(intr.shape), f32((18, 2)), f32((18,))
        key = jax.ShapeDtypeStruct(self._key.shape, self._key.dtype)  # a split key's too
        state = TrackState(
            hypotheses=f32((N, 43)), previous=f32((N, 18, 3)), best=f32((43,)), key=key,
            trusted=jax.ShapeDtypeStruct((), bool),
        )
        step_args = (self.config, shape, intr, f32((4,)), state, depth, kp, conf)
        main = step
        if (not update or self._batched is not None) and self._chunked:
            C = self.chunk
            main = step_chunk
            step_args = (
                self.config, shape, intr, f32((4,)), state, jax.ShapeDtypeStruct((), jnp.int32),
                f32((2,)), jax.ShapeDtypeStruct((C,), bool), jax.ShapeDtypeStruct((C,), bool),
                f32((C, *intr.shape)), f32((C, 18, 2)), f32((C, 18)),
            )  # fmt: skip

        @cache  # for the first frame's programs and the smoother's: traced once
        def landmarks():  # their structure: tracing the lifting (~0.1 s), off the step's path
            return jax.eval_shape(
                partial(tracker_landmarks, self.config), shape, intr, depth, kp, conf
            )  # fmt: skip

        def first_jobs() -> list:  # what the first frame needs beside the step
            lm = landmarks()
            jobs = [
                (lift, (self.config, shape, intr, depth, kp, conf)),
                (initial_fit, (self._init_settings, shape, intr, f32((43,)), lm, key)),
            ]
            if self.mode == "online":
                # Every online frame runs it, the first one included: it builds beside the
                # step.
                jobs.append((online_update_program, (
                    self._smoother, shape, f32(()), jax.eval_shape(lambda: self._window),
                    f32((18, 3)), f32((18,)), f32((43,)), jax.ShapeDtypeStruct((), bool),
                    self.lag,
                )))  # fmt: skip
            return jobs

        def smooth_jobs() -> list:  # the offline motion model (needed after the frames)
            if self.mode != "offline":
                return []
            W = self.motion.window
            window_lm = jax.tree.map(
                lambda a: jax.ShapeDtypeStruct((W, *a.shape), a.dtype), landmarks()
            )  # fmt: skip
            return [(smooth_window_program, (
                self._smoother, shape, intr, f32((W, 43)), window_lm,
                jax.ShapeDtypeStruct((W,), bool), f32(()), f32((W, 18)), f32((W, 18, 3)),
                f32((W, 43)), f32((W,)),
            ))]  # fmt: skip

        def refine_jobs() -> list:  # the body-shape refinement (after the first frames)
            if self.refine is None or self.refine.crop:
                return []
            # Working out their argument shapes traces the observation (about 1 s): done in
            # the builder thread, not before the first frame.
            part = self.refine.online_part if self.mode == "online" else 0
            return refine_programs(
                self._refine_settings(), self.config, shape, intr, self.refine.frames, part
            )  # fmt: skip

        later = [smooth_jobs, refine_jobs]
        if self._batched is not None:  # track_many: the batcher compiles the batched program
            self._batched[0].prepare(step_args)
            prepare_in_background([first_jobs, *later])
            return
        if not background:
            prepare_now([first_jobs, (main, step_args), *later])
            return
        # The step (the big program), then the offline motion model and the body-shape
        # refinement (the first frames do not need them) in one thread. Tracing holds the
        # interpreter, so the small programs the first frame needs (set-up; online, the
        # online model) start once the step is traced; their compilation then runs beside
        # the step's.
        prepare_in_background([(main, step_args), *later])
        main.wait_traced(*step_args)
        prepare_in_background([first_jobs])

    def _lift(self, depth_m, kp, conf) -> Landmarks:
        shape = self.shape if self.shape is not None else body.BodyShape.default(_DTYPE)
        return lift(self.config, shape, self.intrinsics, depth_m, kp, conf)

    def estimate_shape(self, depths, keypoints2d, confidence) -> dict[str, float]:
        """Estimate the body dimensions from several frames and use them from now on.

        Returns the per-field ratios to the default adult (see ``estimate_shape``).
        """
        pts, flags = [], []
        saved, self.shape = self.shape, None
        for i, (d, k, c) in enumerate(zip(depths, keypoints2d, confidence)):
            d, k, c = check_frame(self.intrinsics, d, k, c, self.depth_scale, f"frame {i}")
            lm = self._lift(d, k, c)
            pts.append(np.asarray(lm.points3d))
            flags.append(np.asarray(lm.has_depth))
        self.shape = saved
        if not pts:
            raise ValueError("estimate_shape: no frames given")
        # With fewer than 3 frames a length has fewer than 3 measurements; accept what there is.
        shape, ratios = estimate_shape(np.stack(pts), np.stack(flags), min_samples=min(3, len(pts)))
        self.shape = jax.tree.map(device_f32, shape)
        self._state = None
        return ratios

    def reset(self) -> None:
        """Forget the track and the person followed (the next frame starts afresh and chooses
        a person by the ``person`` rule)."""
        self._drop_track()
        self._forget_person()
        self._ever_initialized = False
        self._dropped = None
        self._last_tracked_pose = None

    def _drop_track(self) -> None:
        """Forget the hypotheses after a loss; keep who is followed."""
        if self._state is not None:  # the facing a quick re-initialisation keeps
            # The state itself: inside track_many it is the batch's pending result.
            self._dropped = (self._frames_seen, self._state, self._last_tracked_kp)
        self._state = None
        self._lost_run = 0
        if self._labeller is not None:
            self._labeller.reset()
        if self._duplicate_filter is not None:
            self._duplicate_filter.reset()
        # The next segment starts afresh: no smoothing across the re-initialisation.
        self._window = eqx.tree_at(
            lambda w: w.valid, self._window, jnp.zeros_like(self._window.valid)
        )
        self._window_valid[:] = False

    @property
    def person(self) -> int:
        """Index, in the last frame's list of people, of the detection followed (-1: none)."""
        return self._person

    def _frame_for_person(
        self, depth_m: np.ndarray, kp_all: np.ndarray, conf_all: np.ndarray
    ) -> tuple[int, Candidates, np.ndarray, np.ndarray, np.ndarray]:
        """Choose the followed person; return (index, candidates, depth for the fit, its
        keypoints (18, 2), its confidence (18,)). Without the person: zero keypoints."""
        cands = lift_candidates(depth_m, kp_all, conf_all, self.intrinsics)
        p = self._follower.select(cands, reacquiring=self._state is None)
        self._person = p
        self._follower.observe(cands, p)
        if p < 0:
            return p, cands, depth_m, np.zeros((18, 2), np.float32), np.zeros(18, np.float32)
        kp, conf = cands.person(p)
        if self._duplicate_filter is not None:  # before the labelling: a jump misleads it too
            conf, _ = self._duplicate_filter.update(
                kp, conf, cands.points3d[p], cands.has_depth[p]
            )
        if self._labeller is not None:
            raw, last = (kp, conf), self.exchanged  # last: the labelling of the last frame
            kp, conf, self.exchanged = self._labeller.update(
                kp, conf, cands.points3d[p], cands.has_depth[p]
            )
            if self._two_sided is not None and self._run_frame is not None:
                self.exchanged = self._offline_exchanged(p, self.exchanged)
                kp, conf = self._labeller.relabel(*raw, self.exchanged)
                if self._mirrored:  # the whole body: the face too (not a relabelled group)
                    kp, conf = kp[_FACE_FLIP], conf[_FACE_FLIP]
            elif self._arbitrates_online:
                self._veto &= self.exchanged  # a veto ends with the exchange it vetoed
                self.exchanged = self.exchanged & ~self._veto
                fresh = self.exchanged & ~last
                if self._arbitration is not None:
                    # A judgement is in flight: a group newly read exchanged inside it stays
                    # as detected and is judged on its own once this judgement ends.
                    self.exchanged, fresh = self.exchanged & ~fresh, np.zeros_like(fresh)
                self._since_judged = np.where(self.exchanged, self._since_judged + 1, 0)
                self._new_exchanged = fresh | (self._since_judged > self.sides.online_rejudge)
                kp, conf = self._labeller.relabel(*raw, self.exchanged)
        if self.follow is not None and self.follow.mask_others and len(cands) > 1:
            own = cands.has_depth[p]
            z_ref = float(np.median(cands.points3d[p, own, 2])) if own.any() else None
            mask = other_people_mask(depth_m, cands, p, self.intrinsics, reference_depth=z_ref)
            if mask.any():
                depth_m = np.where(mask, np.float32(0), depth_m)
        return p, cands, depth_m, kp, conf

    def _new_duplicate_filter(self) -> DuplicateFilter | None:
        """A fresh filter of :attr:`duplicates` (None without it)."""
        if self.duplicates is None:
            return None
        return DuplicateFilter(float(self.intrinsics.fx), self.duplicates)

    def _others_only(self, p: int, cands: Candidates) -> bool:
        """The followed person (chosen before) was not found but others are usable in view:
        the frame is lost without a step (else, with ``p < 0``, nothing was observed)."""
        return p < 0 and self._follower.reference is not None and self._follower.usable(cands)

    def _offline_exchanged(self, p: int, forward: np.ndarray) -> np.ndarray:
        """In offline :meth:`run`, the labelling of detection ``p`` in the frame being tracked:
        the pre-pass's where it labelled that detection (while a stretch is tracked again, for
        the groups of ``_exchange_mask`` only); elsewhere as detected when arbitrating, else
        the forward pass's."""
        persons, exchanged = self._two_sided
        if persons[self._run_frame] == p:
            row = exchanged[self._run_frame]
            row = row if self._exchange_mask is None else row & self._exchange_mask
        else:
            row = np.zeros_like(forward) if self.sides.arbitrate else forward
        return ~row if self._mirrored else row

    @property
    def duplicates_dropped(self) -> int:
        """Keypoint detections dropped because they jumped onto another keypoint, since the
        tracker was made or :meth:`reset` (:attr:`duplicates`; 0 without it)."""
        f = self._duplicate_filter
        return 0 if f is None else f.dropped_count

    @property
    def initialized(self) -> bool:
        return self._state is not None

    @property
    def state(self) -> TrackState | None:
        """The hypotheses carried to the next frame (``None`` before initialisation)."""
        return self._state

    @property
    def floor(self) -> Array:
        """The floor plane (nx, ny, nz, d) in use, metres; ``NO_FLOOR`` when none was found."""
        return self._floor

    @property
    def motion_times(self) -> list[float]:
        """Wall seconds of every online motion-model call (``mode="online"``; the first one
        compiles)."""
        return list(self._motion_times)

    @property
    def step_times(self) -> list[float]:
        """Wall seconds of every steady-state step (the first, compiling call excluded)."""
        return list(self._step_times)

    def initialize(self, depth, keypoints2d, confidence) -> bool:
        """(Re-)initialise the track from one frame's observations alone, without a tracker
        step (``update`` does this by itself when needed). Returns whether it succeeded."""
        depth_m, kp, conf = check_frame(
            self.intrinsics, depth, keypoints2d, confidence, self.depth_scale, "initialize"
        )
        return self._initialize(depth_m, kp, conf)

    def _initialize(self, depth_m, kp, conf) -> bool:
        if self.shape is None:
            self.shape = body.BodyShape.default(_DTYPE)
        lm = self._lift(depth_m, kp, conf)
        if int(np.sum(np.asarray(lm.has_depth))) < self.config.min_landmarks:
            return False
        # The very first start may be partial (heavily occluded sequences must start somehow);
        # a re-initialisation after a loss waits for a torso, since a partial restart that
        # throws away the track's history was measured to do more harm than good (opt-in,
        # reinit_partial_frames: a partial restart from the last tracked pose, or with
        # reinit_partial_axes from its facing only).
        hinted = []  # non-empty where the start took the last tracked pose's facing

        def start(lm):
            hinted.clear()
            points, has_depth = np.asarray(lm.points3d), np.asarray(lm.has_depth)
            p0 = initial_pose(
                points, has_depth, self.shape, allow_partial=not self._ever_initialized
            )
            if p0 is None and self._recently_tracked(self.config.reinit_partial_frames):
                if self.config.reinit_partial_axes:
                    # The lost track's facing only: its limbs may have drifted before the
                    # loss; the frame places them as at any start.
                    R = quat_to_matrix(np.asarray(self._last_tracked_pose[1][3:7], np.float64))
                    p0 = initial_pose(points, has_depth, self.shape, axes=(R[:, 0], R[:, 1]))
                    hinted.append(True)
                else:
                    p0 = pose_moved_onto(*self._last_tracked_pose[1:], points, has_depth)
            return p0

        def flip_start() -> None:
            # Read as facing away right after a loss: a detector's whole-body swap, not a
            # person turned round unseen. Start on the landmarks with left and right exchanged
            # (and, online, go on relabelling them until the labelling sees the swap end).
            self.reinit_flip_frames += (max(self._frames_seen - 1, 0),)
            if self._labeller is not None and self.mode == "online":
                self._labeller.reset(first=np.ones(len(self.exchanged), bool))

        def fit(p0, lm):
            return initial_fit(
                self._init_settings, self.shape, self.intrinsics, _host_f32(p0), lm, self._key
            )

        p0 = start(lm)
        flipped = p0 is not None and self._turned_since_drop(p0, kp, conf)
        if flipped:
            lm = _body_flipped(lm)
            p0 = start(lm)
            if p0 is not None:
                flip_start()
        if p0 is None:
            return False
        t0 = time.perf_counter()
        res, kps, keys = fit(p0, lm)
        params = np.asarray(res.params)
        if not self._init_timed:  # the first call compiles: count it as compile time
            self.compile_s += time.perf_counter() - t0
            self._init_timed = True
        turned = None if flipped else self._turned_fit(params, np.asarray(lm.has_depth))
        if turned is not None:
            # The fit turned round against the lost track (TrackerConfig.reinit_check_fit,
            # reinit_check_tracked): the exchanged landmarks are fitted too and kept if their
            # fit keeps the facing.
            lm_x = _body_flipped(lm)
            p0_x = start(lm_x)
            if p0_x is not None:
                fit_x = fit(p0_x, lm_x)
                params_x = np.asarray(fit_x[0].params)
                if (
                    np.all(np.isfinite(params_x))
                    and not turned(params_x)
                    and self._exchange_not_worse(depth_m, params, params_x)
                ):
                    (res, kps, keys), params = fit_x, params_x
                    flip_start()
        if not np.all(np.isfinite(params)):
            return False
        floor = self._fit_floor(depth_m, params)
        if hinted and (
            _faces_away(params, self._last_tracked_pose[1])
            or self._deltas(depth_m, params, params, floor)[0] > self.config.lost_delta
        ):
            # A start oriented by the last tracked pose whose fit turned round on a side
            # view's few landmarks, or that the depth does not bear out (the loss test's
            # Delta): not one to trust; wait for a frame that orients the body. (Scored as
            # a pair: the shape score_fits is compiled for.)
            return False
        self._floor = device_f32(floor)
        if self._found_floor is None and floor != NO_FLOOR:
            self._found_floor = np.asarray(floor, np.float64)
        N = self.config.n
        self._key, sub = keys
        # Tiled on the host (the first frame's path: no small programs to compile or load).
        self._state = TrackState(
            hypotheses=jax.device_put(np.tile(params[None], (N, 1))),
            previous=jax.device_put(np.tile(np.asarray(kps)[None], (N, 1, 1))),
            best=res.params,
            key=sub,
            trusted=jax.device_put(np.True_),
        )
        self._lost_run = 0
        self._ever_initialized = True
        return True

    def _tracked(self, frame: int, cands, person: int, kp, conf, est) -> None:
        """What a frame judged tracked leaves for later ones (per frame and chunked alike):
        the follower's reference, the keypoints the facing test compares with, and the pose a
        partial re-initialisation starts from (``frame`` as counted by ``_frames_seen``)."""
        self._follower.tracked(cands, person)
        self._last_tracked_kp = (kp, conf)
        self._last_tracked_pose = (frame, est.params, est.keypoints3d)

    def _recently_tracked(self, window: int) -> bool:
        """Whether the track, now lost, was last judged tracked at most ``window`` frames ago
        (a pose that failed the loss tests is no place to restart from)."""
        return (
            window > 0
            and self._state is None
            and self._last_tracked_pose is not None
            and self._frames_seen - self._last_tracked_pose[0] <= window
        )

    def _turned_fit(self, params: np.ndarray, has_depth: np.ndarray):
        """The facing test a re-initialisation's initial fit ``params`` failed, as a function
        of a fit, or None where it passed or no test applies. ``reinit_check_fit``: the fit
        faces away from the pose at the loss (within ``reinit_check_frames``; the start
        faced its way). ``reinit_check_tracked``: the fit faces away from the last tracked
        pose, within that many frames of it, on a frame without both left/right pairs."""
        check = self.config.reinit_check_frames  # None: reinit_keep_facing's window
        if self.config.reinit_check_fit and self._faces_away_from_drop(params, check):
            return lambda p: self._faces_away_from_drop(p, check)
        both_pairs = np.asarray(has_depth, bool)[np.ravel(TORSO_PAIRS)].all()
        if self._recently_tracked(self.config.reinit_check_tracked) and not both_pairs:
            tracked = np.asarray(self._last_tracked_pose[1], np.float64)
            if _faces_away(params, tracked):
                return lambda p: _faces_away(p, tracked)
        return None

    def _deltas(self, depth_m, first: np.ndarray, second: np.ndarray, floor=None) -> np.ndarray:
        """Delta (Eq. 3) of two initial fits (43,) against this frame's depth, with ``floor``
        (default: as the ``first`` would find it; one compiled program, ``score_fits``)."""
        floor = self._fit_floor(depth_m, first) if floor is None else floor
        fits = _host_f32(np.stack([first, second]))
        return np.asarray(
            score_fits(self.config, self.shape, self.intrinsics, device_f32(floor), depth_m, fits)
        )

    def _exchange_not_worse(self, depth_m, plain: np.ndarray, exchanged: np.ndarray) -> bool:
        """Whether a facing check's exchanged fit may replace the plain one: always, unless
        ``config.reinit_check_delta`` is set; then only if its Delta (Eq. 3, against this
        frame's depth, the floor as the plain fit would find it) is at most the plain fit's
        plus that margin."""
        margin = self.config.reinit_check_delta
        if margin is None:
            return True
        delta = self._deltas(depth_m, plain, exchanged)
        frame = max(self._frames_seen - 1, 0)
        self.reinit_check_deltas += ((frame, float(delta[0]), float(delta[1])),)
        return bool(delta[1] <= delta[0] + margin)

    def _faces_away_from_drop(self, params: np.ndarray, window: int | None = None) -> bool:
        """Whether ``params``, a re-initialisation at most ``window`` frames (default
        ``config.reinit_keep_facing``) after a track loss, faces more than 90 degrees away
        from the pose at the loss."""
        window = self.config.reinit_keep_facing if window is None else window
        if self._dropped is None or self._state is not None or window < 1:
            return False
        frame, before, _ = self._dropped
        if self._frames_seen - frame > window:
            return False
        return _faces_away(params, np.asarray(resolve(before).best, np.float64))

    def _turned_since_drop(self, p0: np.ndarray, kp: np.ndarray, conf: np.ndarray) -> bool:
        """Whether a re-initialisation at most ``config.reinit_keep_facing`` frames after a
        track loss reads the person turned round: its start ``p0`` faces more than 90 degrees
        away from the pose at the loss, and this frame's keypoints ``kp`` are the last tracked
        frame's with left and right exchanged (:func:`exchanged_since`). Both: a track lost
        because it had turned round itself (a wrong first pose) is not kept turned."""
        if not self._faces_away_from_drop(p0):
            return False
        last = self._dropped[2]
        return last is not None and bool(exchanged_since(*last, kp, conf))

    def _fit_floor(self, depth_m: np.ndarray, params: np.ndarray) -> tuple[float, ...]:
        """The floor plane, or ``NO_FLOOR`` when there is none we can trust.

        RANSAC finds the dominant near-horizontal plane; outdoors, with depth only on people,
        that "plane" can cut through the people themselves. A floor is accepted only if the
        fitted root (pelvis) lies 0.3-1.6 m above it, as for a standing or sitting person.
        """
        if not self.config.use_floor:
            return NO_FLOOR
        try:
            normal, offset = fit_floor_plane(np.asarray(depth_m), self.intrinsics)
        except ValueError:  # no floor-like plane in view
            return NO_FLOOR
        root_height = float(np.dot(normal, params[:3]) + offset)
        if not 0.3 <= root_height <= 1.6:
            return NO_FLOOR
        return (*[float(v) for v in normal], float(offset))

    # -- per frame ---------------------------------------------------------------------------

    def update(self, depth, keypoints2d, confidence) -> tuple[FrameEstimate | None, int]:
        """Process one frame. Returns (estimate or None, status code); the estimate's fields
        are NumPy arrays, fetched from the device in one transfer.

        In ``mode="online"`` the motion model runs after the step. With ``lag=L`` (default
        :data:`ONLINE_LAG`, 3) the estimate's ``params`` and ``keypoints3d`` are this frame's
        per-frame pose and the published pose is :attr:`lagged`, the smoothed pose of the frame
        L frames back; with ``lag=0`` the estimate's ``params`` and ``keypoints3d`` are the
        smoothed pose of this frame itself (no delay, shakier). With ``refine`` (online's
        default), the call that completes ``refine.online_after`` tracked frames also refines
        the body shape (a few seconds on a CPU; :attr:`refine_s`, summed over the
        refinements; while a left/right stretch is judged, the call after the judgement), and
        so does the one that completes ``refine.online_first``, where set. With ``sides``
        (online's default), a frame in which the left/right labelling newly reads a group
        exchanged starts a stretch of :attr:`SideSettings.online_frames` frames (by default
        lag + 1) tracked both ways (two steps per frame); each call then returns the leading
        reading's estimate, and the last one keeps the reading whose Delta summed is lower
        (:attr:`side_spans`).

        ``depth``: (H, W) uint16 in sensor units (``depth_scale`` per metre) or float metres;
        ``keypoints2d``: (18, 2) pixels for one person or (P, 18, 2) for the P people detected
        (any order); ``confidence``: (18,) or (P, 18), 0 = missing. :attr:`person` says which
        detection was followed.
        """
        if not self._arbitrates_online:
            out = self._update_once(depth, keypoints2d, confidence)
            if self._refining is not None:  # its next part (online_spread)
                self._online_refine_due()
            return out
        return self._update_arbitrated(depth, keypoints2d, confidence)

    @property
    def reinit_flips(self) -> int:
        """How many re-initialisations kept the lost track's facing
        (:attr:`reinit_flip_frames`)."""
        return len(self.reinit_flip_frames)

    @property
    def _arbitrates_online(self) -> bool:
        return self.mode == "online" and self.sides is not None and self.sides.arbitrate

    def _update_once(self, depth, keypoints2d, confidence) -> tuple[FrameEstimate | None, int]:
        """:meth:`update` along one labelling."""
        self._frames_seen += 1
        est, st = self._update_frame(depth, keypoints2d, confidence)
        if self.mode != "online":
            return est, st
        if self._labeller is not None and self.sides.online_model > 0:
            # The next frame's left/right reading may ask this frame's pose (near a tie).
            self._labeller.refer(
                None if st != TRACKED else project_host(self.intrinsics, est.keypoints3d)
            )
        observed = est is not None and st != NO_OBSERVATION
        conf = keypoint_confidence(est) * (0.5 if st == LOST else 1.0) if observed else np.zeros(18)
        newest = self._online(est if observed else None, conf)
        if self._online_refine_pending and st == TRACKED:
            self._online_refine_frame(est)
        if newest is not None and observed and self.lag == 0:
            p, k = newest
            est = eqx.tree_at(
                lambda e: (e.params, e.keypoints3d), est, (np.asarray(p), np.asarray(k))
            )
        return est, st

    def _update_arbitrated(self, depth, kp2d, conf) -> tuple[FrameEstimate | None, int]:
        """:meth:`update` online with :attr:`SideSettings.arbitrate`: where the forward
        labelling newly reads a group exchanged, the frame and the next ones (``online_frames``
        in all; by default the lag + 1, so no pose of the stretch is published before the
        decision) are tracked twice from the same state, exchanged and as detected, and the
        reading whose poses score the lower Delta summed is kept (:func:`prefer_exchanged`);
        an exchange the depth rejected stays vetoed until the labelling reads the group as
        detected again. Until the decision the leading reading's state is the tracker's."""
        arb = self._arbitration
        if arb is None:
            self._online_refine_due()
            before = self._online_snapshot()
            out = self._update_once(depth, kp2d, conf)
            new = self._new_exchanged.copy()
            if not new.any() or self._person < 0:
                return out
            self._since_judged[new] = 0  # judged from here (as detected: vetoed, so 0 anyway)
            first = Branch(self._online_snapshot(), [self._judged_row(out)])
            arb = OnlineArbitration(left=self._online_frames(), readings=[Reading(new, first)])
            if self.sides.online_groups and new.sum() > 1:
                # Each group's exchange alone too: the others vetoed as in the detections'.
                for g in np.flatnonzero(new):
                    only = np.zeros_like(new)
                    only[g] = True
                    branch = self._judged_branch(before, new, new & ~only, depth, kp2d, conf)
                    arb.readings.append(Reading(only, branch))
            arb.detected = self._judged_branch(before, new, new, depth, kp2d, conf)
            self._arbitration = arb
        else:
            for reading in [*arb.readings, None]:
                branch = arb.detected if reading is None else reading.branch
                self._restore_online(branch.snapshot)
                branch.rows.append(self._judged_row(self._update_once(depth, kp2d, conf)))
                branch.snapshot = self._online_snapshot()
                if reading is not None and self.exchanged[reading.groups].any():
                    reading.held += 1
        arb.left -= 1
        kept_groups, keep = arb.leading(self.sides)
        if arb.left <= 0:
            self._arbitration = None
            self.side_spans.append(arb.report(self._frames_seen, keep))
            judged = arb.groups if kept_groups is None else kept_groups
            self.side_span_groups.append(judged.copy())
            self._judged_rows = keep.rows
        self._restore_online(keep.snapshot)
        if arb.left <= 0 and kept_groups is not None and self.sides.online_anchor > 0:
            # The depth kept the exchange: the next frames continue it until the detections
            # jump back (SideSettings.online_anchor), not only while the 2D margin favours it.
            self._labeller.anchor(kept_groups, self.sides.online_anchor)
            self.exchanged = self.exchanged | kept_groups
        return keep.out

    def _judged_branch(
        self, before: tuple, new: np.ndarray, vetoed: np.ndarray, depth, kp2d, conf
    ) -> Branch:
        """A judged stretch's reading that starts from ``before`` (an online snapshot) with
        the ``vetoed`` groups of the newly exchanged ``new`` kept as detected: its first
        frame tracked, the groups of ``new`` judged from here."""
        self._restore_online(before)
        self._veto = self._veto | vetoed
        row = self._judged_row(self._update_once(depth, kp2d, conf))
        self._since_judged[new] = 0
        return Branch(self._online_snapshot(), [row])

    def _judged_row(self, out: tuple) -> tuple:
        """A judged frame's row of a :class:`Branch`: what the update returned, with the
        labelling and the person it used."""
        return out, self.exchanged.copy(), self._person

    def _online_frames(self) -> int:
        n = self.sides.online_frames
        return self.lag + 1 if n is None else int(n)

    def _online_snapshot(self) -> tuple:
        """:meth:`_snapshot` plus what the online mode carries from frame to frame."""
        return (
            self._snapshot(), self._window, self._window_frames.copy(),
            self._window_valid.copy(), self.lagged, self._online_refine_pending,
            self._online_tracked, dict(self._online_kept), self._person, self.exchanged.copy(),
            self._veto.copy(), self._since_judged.copy(), self._depth_fit,
            dict(self._online_kept_first),
        )  # fmt: skip

    def _restore_online(self, snap: tuple) -> None:
        self._restore(snap[0])
        (
            self._window, frames, valid, self.lagged, self._online_refine_pending,
            self._online_tracked, kept, self._person, exchanged, veto, since, self._depth_fit,
            kept_first,
        ) = snap[1:]  # fmt: skip
        self._window_frames, self._window_valid = frames.copy(), valid.copy()
        self._online_kept, self.exchanged = dict(kept), exchanged.copy()
        self._online_kept_first = dict(kept_first)
        self._veto, self._since_judged = veto.copy(), since.copy()

    def _online_refine_frame(self, est: FrameEstimate) -> None:
        """Online body shape from depth, causally: keep the best-observed tracked frame of
        each of ``refine.frames`` stretches of the first ``refine.online_after`` tracked
        frames (and of the first ``refine.online_first``, where set); when they are all seen,
        refine :attr:`shape` on them (the next frames are tracked with it)."""
        R = self.refine
        if self._online_tracked >= R.online_after:  # all in; the refinement waits its turn
            return
        lm = est.landmarks
        n3d = int(np.asarray(lm.has_depth).sum())
        entry = cache(
            lambda: (
                np.asarray(est.params), self._depth_fit, np.asarray(lm.keypoints2d),
                np.asarray(lm.confidence), self._frames_seen - 1,
            )
        )  # fmt: skip
        _keep_best_observed(
            self._online_kept, self._online_tracked * R.frames // R.online_after, n3d, entry
        )
        if self._online_tracked < R.online_first:
            _keep_best_observed(
                self._online_kept_first, self._online_tracked * R.frames // R.online_first, n3d,
                entry,
            )  # fmt: skip
        self._online_tracked += 1
        if not self._arbitrates_online:  # else the next update refines, before any branching
            self._online_refine_due()

    def _online_refine_due(self) -> None:
        """Refine the body shape online once ``refine.online_after`` tracked frames are in
        (and once at ``refine.online_first``, where set). With ``refine.online_spread`` a
        refinement runs a part of its steps at each call (one per frame seen) and is taken
        up at the call after its last part; the next refinement starts only then."""
        if self._refining is not None:
            if self._refining.at == self._frames_seen:
                return
            self._advance_refinement()
            if self._refining is not None:
                return
        if self._online_first_pending and self._online_tracked >= self.refine.online_first:
            self._online_first_pending = False
            kept, self._online_kept_first = self._online_kept_first, {}
            if len(kept) >= _MIN_REFINE_FRAMES:
                self._online_shape0 = self.shape
                self._refine_kept(kept)
                if self._refining is not None:
                    return
        if not self._online_refine_pending or self._online_tracked < self.refine.online_after:
            return
        self._online_refine_pending = False
        kept, self._online_kept = self._online_kept, {}
        if len(kept) < _MIN_REFINE_FRAMES:
            return
        if self._online_shape0 is None:
            self._refine_kept(kept)
            return
        first = (self.refine_report, self.refine_s)
        if self.refine.online_spread:  # the earlier shape tracks until this one is taken up
            self._refine_kept(kept, self._online_shape0, first)
            return
        self.shape = self._online_shape0  # the same prior as without the earlier one
        self._refine_kept(kept)
        self.refine_s += first[1]
        self.refine_report["online_first"] = first[0]

    def _refine_kept(self, kept: dict, start=None, first: tuple | None = None) -> None:
        """:meth:`_refine_on` the frames of ``kept`` (stretch -> ``(n3d, *entry)``, see
        :func:`_keep_best_observed`), in stretch order; with ``refine.online_spread``, start
        refining ``start`` (default :attr:`shape`) on them a part at a time (``first``: the
        earlier refinement's ``(report, seconds)``, recorded with this one)."""
        rows = [kept[k][1:] for k in sorted(kept)]
        params, depths, kp2, lm_conf, frames_used = (np.stack(c) for c in zip(*rows))
        if not self.refine.online_spread:
            self._refine_on(params, depths, kp2, lm_conf, frames_used)
            return
        work = _start_refinement(
            self.shape if start is None else start, params, depths, kp2, lm_conf,
            self.intrinsics, settings=self._refine_settings(), config=self.config,
            floor=np.asarray(self._floor), depth_scale=1000.0, pad_to=self.refine.frames,
        )  # fmt: skip
        self._refining = _Refining(work, frames_used, first, at=-1)
        self._advance_refinement()

    def _advance_refinement(self) -> None:
        """The pending online refinement's next part, or, all run, its shape taken up
        (:attr:`shape`, :attr:`refine_report`, :attr:`refine_s`)."""
        r = self._refining
        r.at = self._frames_seen
        if r.work.done < self.refine.steps:
            r.work.part(self.refine.online_part)  # the size refine_jobs prepares
            return
        self._refining = None
        self.shape, report = r.work.finish()
        report["frames_used"] = np.asarray(r.frames_used)
        self.refine_report, self.refine_s = report, report["seconds"]
        if r.first is not None:
            self.refine_s += r.first[1]
            self.refine_report["online_first"] = r.first[0]

    def _update_frame(self, depth, keypoints2d, confidence) -> tuple[FrameEstimate | None, int]:
        """:meth:`update` without the online motion model."""
        self._start_preparing()
        depth_m = check_depth(self.intrinsics, depth, self.depth_scale, "update")
        kp_all, conf_all = check_people(keypoints2d, confidence, "update")
        p, cands, depth_fit, kp, conf = self._frame_for_person(depth_m, kp_all, conf_all)
        if p < 0:
            if not self._others_only(p, cands):
                return None, NO_OBSERVATION  # nobody (usable) in view, or nobody chosen yet
            # Only other people in view: the followed person is lost this frame.
            if self._state is not None:
                self._lost_run += 1
                if self._lost_run >= self.config.lost_patience:
                    self._drop_track()
            return None, LOST
        if self._state is None and not self._initialize(depth_fit, kp, conf):
            return None, NO_OBSERVATION
        self._depth_fit = depth_fit  # run() keeps a few for the body-shape refinement
        t0 = time.perf_counter()
        run_step = step if self._batched is None else partial(
            self._batched[0].step, self._batched[1]
        )
        state, est = run_step(
            self.config, self.shape, self.intrinsics, self._floor, self._state, depth_fit, kp, conf
        )
        jax.block_until_ready(est)
        dt = time.perf_counter() - t0
        # Every field the host reads below and in ``run`` comes back in one transfer: read one
        # by one from the device they were ~20 round trips a frame (4 ms of a 14 ms frame on
        # a GPU whose step takes 4; benchmarks/chunks.py). The batched step's are NumPy already.
        est = jax.device_get(est)
        if self._step_calls == 0:  # the first call compiles
            self.compile_s += dt
        else:
            self._step_times.append(dt)
        self._step_calls += 1
        if int(est.num_3d) < self.config.min_landmarks:
            # Too little to fit: hold the previous pose, keep the hypotheses.
            return est, NO_OBSERVATION
        cfg = self.config
        lost = float(est.delta) > cfg.lost_delta or float(est.agreement) < cfg.lost_agreement
        # The state carries the verdict (TrackState.trusted), as the chunked scan's does.
        self._state = eqx.tree_at(lambda t: t.trusted, state, np.bool_(not lost))
        if lost:
            self._lost_run += 1
            if self._lost_run >= self.config.lost_patience:
                self._drop_track()
            return est, LOST
        self._lost_run = 0
        self._tracked(self._frames_seen, cands, p, kp, conf, est)
        return est, TRACKED

    def run(
        self,
        depths: Sequence,
        keypoints2d: Sequence | np.ndarray,
        confidence: Sequence | np.ndarray,
        *,
        progress: ProgressCallback | None = None,
    ) -> TrackResult:
        """Track a whole sequence. ``depths`` may be any sequence (e.g. a lazy file reader).

        ``progress(done, total, postfix)`` is called after every frame (``None``: silent); the
        application layer's ``posetrack.app.ProgressBar("tracking")`` draws a bar from it.
        """
        if progress is False:
            progress = None
        if progress is not None and not callable(progress):
            raise TypeError(
                "run: progress must be a callable progress(done, total, postfix) or None, got "
                f"{progress!r} (for a text bar: progress=posetrack.app.ProgressBar('tracking'))"
            )
        T = len(depths)
        if len(keypoints2d) != T or len(confidence) != T:
            raise ValueError(
                f"run: {T} depth frames but {len(keypoints2d)} keypoint frames and "
                f"{len(confidence)} confidence frames"
            )
        if T == 0:
            raise ValueError("run: the sequence has no frames")
        self._start_preparing(update=self.mode == "online")
        # This run's refinement only: a run that cannot refine reports none, not an earlier one's.
        self.refine_report, self.refine_s = None, 0.0
        pre = self.prepass_frames(T)
        progress_pre = None
        if progress is not None:  # one bar: the pre-pass's frames, then each pass's
            total = pre + T * self.passes(T)
            progress_pre, progress = _share(progress, 0, total), _share(progress, pre, total)
        pre_report = None  # the pre-pass's refinement (refine_report["offline_first"])
        self.prepass_s, self.prepass_share = 0.0, None
        if pre and self.refine.offline_first_below is not None:
            self.prepass_share = observed_share(depths, keypoints2d, confidence, pre)
            if self.prepass_share >= self.refine.offline_first_below:  # a clean start: none
                if progress_pre is not None:
                    progress_pre(pre, pre, "no shape pre-pass")
                pre = 0
        if pre:
            pre_report = self._shape_prepass(depths, keypoints2d, confidence, pre, progress_pre)
        if self.shape is None:
            n = min(self.config.shape_frames, T)
            t0 = time.perf_counter()
            self.estimate_shape(*self._shape_frames(depths, keypoints2d, confidence, n))
            self.compile_s += time.perf_counter() - t0
        G = 0 if self.sides is None else len(self.sides.groups)
        out = _RunOutputs.empty(T, G)
        both_ways = self.passes(T) == 2
        self.both_ways_frames = 0
        progress_back = None
        if both_ways and progress is not None:  # the two passes share one bar
            progress, progress_back = _share(progress, 0, 2 * T), _share(progress, T, 2 * T)
        self._reset_motion()
        self._found_floor = None
        # Body shape from depth: the best-observed tracked frame of each of F equal stretches
        # of the recording (its depth as fitted: other people removed) is kept for refine_shape.
        n_keep = 0 if self.refine is None or self.mode != "offline" else min(self.refine.frames, T)
        kept: dict[int, tuple[int, int, np.ndarray]] = {}  # stretch -> (3D landmarks, t, depth)
        spans: dict[int, int] = {}
        turns: list[tuple[int, int]] = []  # SideSettings.frontal_turns
        self.side_spans, self.side_span_groups, self._judged_rows = [], [], None
        self.turn_spans = []
        self.reinit_flip_frames, self.reinit_check_deltas = (), ()
        if self.sides is not None and self.mode == "offline":
            t0 = time.perf_counter()
            persons, exchanged, spans, turns = self._offline_plan(depths, keypoints2d, confidence)
            self._two_sided = (persons, exchanged)
            self.sides_s = time.perf_counter() - t0
        frames = partial(self._run_frames_into, out, kept, n_keep, depths, keypoints2d, confidence)
        try:
            t = 0
            for start, stop in turns:
                t = self._run_spans(t, start, spans, out, kept, frames, progress)
                t = self._arbitrate_turn(start, stop, spans, out, kept, frames, progress)
            self._run_spans(t, T, spans, out, kept, frames, progress)
        finally:
            self._two_sided, self._run_frame, self._exchange_mask = None, None, None
            self._mirrored = False
        back = None
        if both_ways:
            back = self._track_backwards(out, depths, keypoints2d, confidence, G, progress_back)
        kp3, params, delta, status, conf_out = out.kp3, out.params, out.delta, out.status, out.conf
        lm3, has_d, det, kp2, lm_conf = out.lm3, out.has_d, out.det, out.kp2, out.lm_conf
        person, num_people = out.person, out.num_people
        exchanged = None if self.sides is None else out.exchanged
        if self._batched is not None and self._leaves_slot:  # no more steps: others need not wait
            self._batched[0].leave(self._batched[1])
        per_frame = interpolated = None
        if self.mode == "online" and self.lag > 0:
            # The newest frames' smoothed poses were never lagged out: smooth the last window.
            sm, sk = online_flush(
                self._smoother, self.shape, jnp.asarray(self.fps, _DTYPE), self._window
            )
            sm, sk = np.asarray(sm), np.asarray(sk)
            newest = (self._window_frames > T - 1 - self.lag) & self._window_valid
            for j in np.flatnonzero(newest):
                params[self._window_frames[j]], kp3[self._window_frames[j]] = sm[j], sk[j]
        if self.mode == "offline":
            valid = np.isfinite(kp3).all(axis=(1, 2))
            if n_keep and len(kept) >= _MIN_REFINE_FRAMES:
                moved = self._refine_shape(list(kept.values()), params, kp2, lm_conf)
                for rows in (out,) if back is None else (out, back):
                    rows.lm3 = _along_rays(rows.lm3, rows.has_d, moved)
                lm3 = out.lm3
                if pre:  # the pre-pass's refinement, as online's earlier one is reported
                    self.refine_s += self._prepass_refine_s
                    self.refine_report["offline_first"] = pre_report
            if valid.any():
                per_frame = kp3.copy()
                t0 = time.perf_counter()
                smoothed, smoothed_kps, interpolated = self._smooth_rows(out, valid)
                if back is not None:
                    smoothed, smoothed_kps = self._fuse_backwards(
                        out, back, valid, smoothed, smoothed_kps
                    )
                params = np.where(valid[:, None], smoothed, params)
                kp3 = np.where(valid[:, None, None], smoothed_kps, kp3)
                self.smooth_s = time.perf_counter() - t0
        # Never NaN parameters: frames without an estimate take the nearest estimated pose.
        have = np.flatnonzero(np.isfinite(params).all(axis=1))
        if len(have):
            params = params[nearest_index(have, T)]
        else:
            params = np.tile(body.facing_camera_params_np(2.5), (T, 1))
        times = self._step_times
        return TrackResult(
            keypoints3d=kp3,
            params=params,
            delta=delta,
            status=status,
            confidence=conf_out,
            landmarks3d=lm3,
            has_depth=has_d,
            detected=det,
            shape=self.shape,
            config=self.config,
            compile_s=float(self.compile_s),
            ms_per_frame=float(np.median(times) * 1000) if times else float("nan"),
            person_index=person,
            num_people=num_people,
            per_frame_keypoints3d=per_frame,
            exchanged=exchanged,
            interpolated=interpolated,
            floor=self._found_floor,
            mode=self.mode,
            lag=self.lag,
        )

    @property
    def _chunked(self) -> bool:
        """Whether :meth:`run` runs its steps in chunks (offline and per-frame modes; inside
        :func:`track_many` too, as one batched call of many trackers' chunks)."""
        return self.chunk > 1 and self.mode != "online"

    def _run_frames_into(
        self, out: _RunOutputs, kept: dict, n_keep: int, depths, keypoints2d, confidence,
        progress, start: int, stop: int,
    ) -> None:
        """:meth:`run`'s work for frames ``[start, stop)``: in chunks of :attr:`chunk` steps
        (:meth:`_run_chunks_into`) or one :meth:`update` per frame."""
        if self._chunked:
            self._run_chunks_into(
                out, kept, n_keep, depths, keypoints2d, confidence, progress, start, stop
            )  # fmt: skip
            return
        for t in range(start, stop):
            self._run_frame_into(out, kept, n_keep, depths, keypoints2d, confidence, progress, t)

    def _run_chunks_into(
        self, out: _RunOutputs, kept: dict, n_keep: int, depths, keypoints2d, confidence,
        progress, t: int, stop: int,
    ) -> None:
        """:meth:`run`'s frames ``[t, stop)`` with up to :attr:`chunk` steps per call
        (:mod:`posetrack._chunk`). The host prepares each frame as :meth:`update` does (the
        followed person, its labelling: none of it depends on a step while the track lives),
        the scan runs the steps and the track-loss logic, the host records the rows.

        Pipelined: while one chunk computes, the host prepares the next and queues it behind
        (its state and lost count are the first's outputs, still on the device), then reads
        the first's results. If the first chunk drops the track, the next one's preparation
        is undone (the host's state restored to the frame of the drop) and its results are
        never read: the frames after the drop are prepared again, from a new track."""
        pending = None  # (prepared frames, the call's outputs, seconds at dispatch)
        self._chunk_read = 0.0  # when the last chunk's results were read
        # A tracker's first call steps one frame (padding after it): the first pose then
        # comes as soon as the program is ready, not a whole chunk's steps later. Its result
        # is read before the next chunk is prepared: on a cold start the builder thread is
        # tracing the later programs then, and the host's work for 16 frames, slowed by it
        # for the interpreter, delayed the first pose by 0.5-1 s. (Not inside track_many: reading
        # there would wait for the batch.)
        limit = 1 if self._step_calls == 0 else self.chunk
        first = self._step_calls == 0 and self._batched is None
        while True:
            frames: list[_Prepared] = []
            if t < stop:
                frames, t = self._prepare_chunk(
                    out, kept, n_keep, depths, keypoints2d, confidence, progress, t, stop,
                    limit,
                )  # fmt: skip
                limit = self.chunk
            call = self._dispatch_chunk(frames) if frames else None
            if pending is not None:
                resume = self._finish_chunk(
                    out, kept, n_keep, len(depths), confidence, progress, *pending
                )  # fmt: skip
                if resume is not None:  # dropped: the frames after the drop start afresh
                    pending, t = None, resume
                    continue
            if call is None and t >= stop:
                # One read, at the end (inside track_many, the batch's share of them).
                self._state, lost_run = resolve((self._state, self._lost_run))
                self._lost_run = int(lost_run)
                return
            pending = None if call is None else (frames, *call)
            if first and pending is not None:
                first, pending = False, None
                resume = self._finish_chunk(
                    out, kept, n_keep, len(depths), confidence, progress, frames, *call
                )  # fmt: skip
                if resume is not None:
                    t = resume

    def _prepare_chunk(
        self, out: _RunOutputs, kept: dict, n_keep: int, depths, keypoints2d, confidence,
        progress, t: int, stop: int, limit: int,
    ) -> tuple[list[_Prepared], int]:
        """The host's part of :meth:`update` before the step, for the frames from ``t`` until
        ``limit`` (at most :attr:`chunk`) of them have a live track (or ``stop``). Without a
        track (never while a chunk is queued: it leaves its state) a frame either
        (re-)initialises it or is recorded at once, without a step. Returns the prepared
        frames and the next frame."""
        frames: list[_Prepared] = []
        while t < stop and len(frames) < limit:
            self._run_frame = t
            self._frames_seen += 1
            depth_m = check_depth(self.intrinsics, depths[t], self.depth_scale, f"frame {t}")
            kp_all, conf_all = check_people(keypoints2d[t], confidence[t], f"frame {t}")
            p, cands, depth_fit, kp, conf = self._frame_for_person(depth_m, kp_all, conf_all)
            lost_only = self._others_only(p, cands)
            if self._state is None and not (p >= 0 and self._initialize(depth_fit, kp, conf)):
                # No track, and this frame starts none: it ends here, without a step.
                self._record_frame(
                    out, kept, n_keep, len(depths), confidence, progress, t, None,
                    LOST if lost_only else NO_OBSERVATION, self.exchanged, self._person, None,
                    held=None,
                )  # fmt: skip
                t += 1
                continue
            frames.append(_Prepared(
                t, p, cands, depth_fit, kp, conf, lost_only, self._person, self.exchanged.copy(),
                (self._follower.reference, self._follower.since, copy.deepcopy(self._labeller),
                 copy.deepcopy(self._duplicate_filter), self._frames_seen),
            ))  # fmt: skip
            t += 1
        return frames, t

    def _dispatch_chunk(self, frames: list[_Prepared]) -> tuple:
        """Queue the prepared frames' steps as one call; the track's state and lost count
        become the call's (device) outputs. Returns ``(outputs, seconds at dispatch)``."""
        C, (H, W) = self.chunk, frames[0].depth.shape
        depth = np.zeros((C, H, W), np.float32)
        kp2 = np.zeros((C, 18, 2), np.float32)
        conf2 = np.zeros((C, 18), np.float32)
        run, lost_only = np.zeros(C, bool), np.zeros(C, bool)
        for i, f in enumerate(frames):
            run[i], lost_only[i] = f.person_index >= 0, f.lost_only
            if run[i]:
                depth[i], kp2[i], conf2[i] = f.depth, f.kp, f.conf
        t0 = time.perf_counter()
        lost_run = self._lost_run
        args = (
            self.config, self.shape, self.intrinsics, self._floor, self._state,
            np.int32(lost_run) if isinstance(lost_run, int) else lost_run,
            status_limits(self.config), run, lost_only, depth, kp2, conf2,
        )  # fmt: skip
        if self._batched is None:
            (self._state, self._lost_run), res = step_chunk(*args)
            return res, t0
        # track_many: the state and lost count stay the batch's (Pending) until the next
        # chunk's batch or the end of the frames reads them.
        share = self._batched[0].submit(self._batched[1], *args)
        self._state, self._lost_run = share.part(lambda r: r[0][0]), share.part(lambda r: r[0][1])
        return share.part(lambda r: r[1]), t0

    def _finish_chunk(
        self, out: _RunOutputs, kept: dict, n_keep: int, T: int, confidence, progress,
        frames: list[_Prepared], res, t0: float,
    ) -> int | None:
        """Read a dispatched chunk's results (one transfer) and record its frames. Returns
        the frame after a drop (the host's state restored to that frame's), else None."""
        res = res.get() if isinstance(res, Pending) else jax.device_get(res)
        # Its compute began at its dispatch or when the chunk before it was done (queued).
        now = time.perf_counter()
        dt, self._chunk_read = now - max(t0, self._chunk_read), now
        steps = sum(f.person_index >= 0 for f in frames)
        if self._step_calls == 0:  # the first call compiles
            self.compile_s += dt
        elif steps:
            self._step_times.extend([dt / steps] * steps)
        self._step_calls += 1
        for i, f in enumerate(frames):
            st, dropped = int(res.status[i]), bool(res.dropped[i])
            est = None
            if f.person_index >= 0:
                est = jax.tree.map(lambda a: a[i, ...], res.estimate)
                self._depth_fit = f.depth
                if st == TRACKED:
                    self._tracked(f.host[-1], f.cands, f.person_index, f.kp, f.conf, est)
            self._record_frame(
                out, kept, n_keep, T, confidence, progress, f.t, est, st, f.exchanged,
                f.person, f.depth, held=None if dropped else res.held[i],
            )  # fmt: skip
            if dropped:
                # As after this frame's update: the later frames' preparation undone.
                (self._follower.reference, self._follower.since, self._labeller,
                 self._duplicate_filter, self._frames_seen) = f.host  # fmt: skip
                self._person, self.exchanged, self._run_frame = f.person, f.exchanged.copy(), f.t
                self._drop_track()
                return f.t + 1
        return None

    def _record_frame(
        self, out: _RunOutputs, kept: dict, n_keep: int, T: int, confidence, progress, t: int,
        est, st: int, exchanged, person: int, depth_fit, *, held,
    ) -> None:
        """Frame ``t``'s row of ``out`` (:meth:`_put_row`), its progress report, and the
        body-shape refinement's candidate frames; chunked or after one :meth:`update`."""
        out.num_people[t] = int(np.any(np.reshape(confidence[t], (-1, 18)) > 0, axis=1).sum())
        self._put_row(out, t, est, st, exchanged, person, pose=True, held=held)
        if progress is not None:
            progress(t + 1, T, "" if est is None else f"delta {float(est.delta):.2f}")
        if n_keep and st == TRACKED:
            _keep_best_observed(
                kept, t * n_keep // T, int(out.has_d[t].sum()), lambda: (t, depth_fit)
            )

    def _run_frame_into(
        self, out: _RunOutputs, kept: dict, n_keep: int, depths, keypoints2d, confidence,
        progress, t: int,
    ) -> None:
        """:meth:`run`'s work for frame ``t``: the update, and its results into ``out`` (and
        ``kept``, the candidate frames of the body-shape refinement)."""
        self._run_frame = t
        T = len(depths)
        est, st = self.update(depths[t], keypoints2d[t], confidence[t])
        if self.mode == "online" and self.lagged is not None and self.lag > 0:
            i, p_lag, k_lag = self.lagged
            out.params[i], out.kp3[i] = p_lag, k_lag
        held = None if self._state is None else self._state.best
        rows, self._judged_rows = self._judged_rows, None
        if rows:
            # An online judgement ended here: its earlier frames were recorded as the reading
            # that led then; record them as the kept one saw them (the per-frame pose only
            # where it is not yet published: published poses are never changed).
            for j, ((e, s), ex, person) in enumerate(rows[:-1]):
                tt = t - len(rows) + 1 + j
                if tt >= 0:
                    self._put_row(out, tt, e, s, ex, person, pose=tt > t - self.lag, held=held)
        # The labelling this frame was fitted with (a judgement's end may have anchored the
        # next frames' labelling already: SideSettings.online_anchor).
        exchanged = rows[-1][1] if rows else self.exchanged
        self._record_frame(
            out, kept, n_keep, T, confidence, progress, t, est, st, exchanged, self._person,
            self._depth_fit, held=held,
        )  # fmt: skip

    def _put_row(
        self, out: _RunOutputs, t: int, est, st: int, exchanged, person: int, *, pose: bool,
        held,
    ) -> None:
        """Frame ``t``'s row of ``out`` from its update's ``(est, st)``; its pose too where
        ``pose`` (else the row's pose is left as it is). ``held``: the live track's pose after
        the frame (the held one where nothing was observed; None: no live track)."""
        out.status[t] = st
        out.person[t] = person
        out.exchanged[t] = exchanged if self.sides is not None and person >= 0 else False
        out.delta[t], out.conf[t] = np.nan, 0.0
        if est is None:
            out.lm3[t], out.has_d[t], out.det[t], out.kp2[t], out.lm_conf[t] = 0, False, False, 0, 0
            if pose and held is not None:
                # The track lives but its person was not seen (nobody, or only other
                # people): hold the last pose, as for a frame without observation.
                out.params[t] = np.asarray(held)
                out.kp3[t] = np.asarray(body.keypoints(self.shape, held))
            return
        lm = est.landmarks
        out.lm3[t], out.has_d[t], out.det[t], out.kp2[t], out.lm_conf[t] = (
            np.asarray(lm.points3d),
            np.asarray(lm.has_depth),
            np.asarray(lm.detected),
            np.asarray(lm.keypoints2d),
            np.asarray(lm.confidence),
        )
        if st == NO_OBSERVATION:
            if pose and held is not None:
                out.params[t] = np.asarray(held)
                out.kp3[t] = np.asarray(body.keypoints(self.shape, held))
            return
        if pose:
            out.params[t] = np.asarray(est.params)
            out.kp3[t] = np.asarray(est.keypoints3d)
        out.delta[t] = float(est.delta)
        out.conf[t] = keypoint_confidence(est) * (0.5 if st == LOST else 1.0)

    def _run_spans(
        self, t: int, stop: int, spans: dict, out: _RunOutputs, kept: dict, frames, progress
    ) -> int:
        """Track frames ``[t, stop)``, each arbitrated stretch of ``spans`` (start -> stop)
        that starts there by :meth:`_arbitrate_span`. Returns ``stop``."""
        for start in sorted(spans):
            if start < t or start >= stop:  # inside a stretch already tracked, or beyond
                continue
            frames(progress, t, start)
            t = self._arbitrate_span(start, spans[start], out, kept, frames, progress)
        frames(progress, t, stop)
        return stop

    def _arbitrate_turn(
        self, start: int, stop: int, spans: dict, out: _RunOutputs, kept: dict, frames, progress
    ) -> int:
        """:attr:`SideSettings.frontal_turns`: track the turn ``[start, stop)`` as labelled
        (its arbitrated stretches judged as usual), then again from the same state with every
        labelling mirrored (the detector's whole-body swap undone), and keep the mirrored
        tracking where its poses' Delta summed is lower by :attr:`SideSettings.turn_margin` a
        frame (:func:`prefer_exchanged`). Returns ``stop``."""
        before = self._point(start, stop, out, kept)
        # The records of the stretches and re-initialisations inside: the kept reading's.
        n, checks = len(self.side_spans), self.reinit_check_deltas
        self._run_spans(start, stop, spans, out, kept, frames, None)
        delta_as = out.delta[start:stop].copy()
        labelled = self._point(start, stop, out, kept)
        records = self.side_spans[n:], self.side_span_groups[n:], self.reinit_check_deltas
        del self.side_spans[n:], self.side_span_groups[n:]
        self.reinit_check_deltas = checks
        self._back_to(before, start, out, kept)
        self._mirrored = True
        try:
            self._run_spans(start, stop, spans, out, kept, frames, progress)
        finally:
            self._mirrored = False
        delta_mirrored = out.delta[start:stop].copy()
        shared = int(np.sum(np.isfinite(delta_as) & np.isfinite(delta_mirrored)))
        chosen = prefer_exchanged(delta_as, delta_mirrored, self.sides.turn_margin * shared)
        self.turn_spans.append(
            (start, stop, float(np.nansum(delta_as)), float(np.nansum(delta_mirrored)), chosen)
        )
        if not chosen:
            self._back_to(labelled, start, out, kept)
            self.side_spans[n:], self.side_span_groups[n:], self.reinit_check_deltas = records
        return stop

    def _arbitrate_span(
        self, start: int, stop: int, out: _RunOutputs, kept: dict, frames, progress
    ) -> int:
        """Track frames ``[start, stop)`` twice from the same state, with the two-sided
        labelling and with the labels as detected, and keep the reading whose poses score the
        lower Delta (:func:`prefer_exchanged`). Returns ``stop``."""
        before = self._point(start, stop, out, kept)
        delta_ex = self._reading(start, stop, out, frames, None, None)
        groups = out.exchanged[start:stop].any(axis=0)
        exchanged = self._point(start, stop, out, kept)
        self._back_to(before, start, out, kept)
        delta_as = self._reading(start, stop, out, frames, progress, np.zeros_like(groups))
        chosen = prefer_exchanged(delta_as, delta_ex, self.sides.arbitrate_margin)
        if self.sides.arbitrate_groups and groups.sum() > 1:
            # Every group's exchange alone too; the lowest Delta summed of those that beat the
            # detections, the exchange of all of them included, is kept.
            bar = np.nansum(delta_ex) if chosen else np.inf
            best = self._arbitrate_groups(start, stop, out, kept, frames, before, groups,
                                          delta_as, bar)  # fmt: skip
            if best is not None:  # one group's exchange alone did best
                chosen, groups, delta_ex, exchanged = True, *best
        self.side_spans.append(
            (start, stop, float(np.nansum(delta_as)), float(np.nansum(delta_ex)), chosen)
        )
        self.side_span_groups.append(groups)
        if chosen:
            self._back_to(exchanged, start, out, kept)
        return stop

    def _point(self, start: int, stop: int, out: _RunOutputs, kept: dict) -> tuple:
        """Where an arbitrated stretch ``[start, stop)`` can be tracked again from or come
        back to: the tracker's state, the stretch's outputs and the kept frames."""
        return self._snapshot(), out.copy_span(start, stop), dict(kept)

    def _back_to(self, point: tuple, start: int, out: _RunOutputs, kept: dict) -> None:
        """The tracker, the outputs and ``kept`` as they were at ``point`` (:meth:`_point`)."""
        snap, span, kept_then = point
        self._restore(snap)
        out.put_span(start, span)
        kept.clear()
        kept.update(kept_then)

    def _reading(
        self, start: int, stop: int, out: _RunOutputs, frames, progress, mask: np.ndarray | None
    ) -> np.ndarray:
        """Track ``[start, stop)`` with the two-sided labelling applied to the groups of
        ``mask`` only (None: every group; all False: the labels as detected); the Delta of
        its frames."""
        self._exchange_mask = mask
        try:
            frames(progress, start, stop)
        finally:
            self._exchange_mask = None
        return out.delta[start:stop].copy()

    def _arbitrate_groups(
        self, start, stop, out: _RunOutputs, kept: dict, frames, before: tuple, groups,
        delta_as, bar: float,
    ):  # fmt: skip
        """:attr:`SideSettings.arbitrate_groups`: the stretch ``[start, stop)`` tracked once
        per group read exchanged, with only that group's exchange (from ``before``, a
        :meth:`_point`). Returns ``(groups, Delta per frame, point)`` of the group whose Delta
        summed is lowest among those that beat the detections (:func:`prefer_exchanged`) and
        ``bar`` (the exchange of every group's sum where that beat them, else inf), or
        ``None``; the tracker is left as detected (as it was when called)."""
        detected = self._point(start, stop, out, kept)
        best, best_sum = None, bar
        for g in np.flatnonzero(groups):
            only = np.zeros_like(groups)
            only[g] = True
            self._back_to(before, start, out, kept)
            delta_g = self._reading(start, stop, out, frames, None, only)
            total = float(np.nansum(delta_g))
            wins = prefer_exchanged(delta_as, delta_g, self.sides.arbitrate_margin)
            if wins and total < best_sum:
                best, best_sum = (only, delta_g, self._point(start, stop, out, kept)), total
        self._back_to(detected, start, out, kept)
        return best

    def prepass_frames(self, frames: int) -> int:
        """Frames of the offline shape pre-pass :meth:`run` makes over a recording of
        ``frames`` frames (``refine.offline_first``; 0 when it makes none)."""
        return prepass_frames(self.mode, self.refine, frames)

    def progress_frames(self, frames: int) -> int:
        """Frames :meth:`run`'s progress counts over a recording of ``frames`` frames: the
        shape pre-pass's, then each pass's (:meth:`passes`)."""
        return self.prepass_frames(frames) + frames * self.passes(frames)

    def _shape_prepass(self, depths, keypoints2d, confidence, n: int, progress) -> dict | None:
        """The offline shape pre-pass (``refine.offline_first``): a tracker as this one was
        made (its seed and settings, no pre-pass) tracks the first ``n`` frames and refines
        the shape on them; that shape becomes :attr:`shape`, the start of the whole
        recording's tracking. Inside :func:`~posetrack.track_many` it steps in this tracker's
        batch slot. Returns its :attr:`refine_report` (``None`` if it could not refine)."""
        t0 = time.perf_counter()
        options = dict(self._options, shape=self.shape)
        options["refine"] = dataclasses.replace(self.refine, offline_first=0)
        pre = Tracker(self._intrinsics_given, **options)
        pre._batched, pre._leaves_slot = self._batched, False
        pre.run(
            *(Reindexed(x, np.arange(n)) for x in (depths, keypoints2d, confidence)),
            progress=progress,
        )
        self.shape = pre.shape
        self.compile_s += pre.compile_s
        self.prepass_s = time.perf_counter() - t0
        self._prepass_refine_s = pre.refine_s
        return pre.refine_report

    def passes(self, frames: int) -> int:
        """How many times :meth:`run` goes through a recording of ``frames`` frames (its
        progress counts each pass; :func:`run_passes`)."""
        return run_passes(self.mode, self.motion, frames)

    def _track_backwards(
        self, out: _RunOutputs, depths, keypoints2d, confidence, groups: int, progress
    ) -> _RunOutputs:
        """Offline with :attr:`SmoothSettings.both_ways`: track the recording again from its
        last frame to its first (a fresh track, the person each frame's forward row followed,
        their labels as the forward pass fitted them). Returns the backward pass's rows in the
        recording's order. The tracker is left as the forward pass left it (its state after
        the last frame)."""
        T = len(depths)
        order = np.arange(T - 1, -1, -1)
        after_forward = (self._snapshot(), self._person, self.exchanged.copy())
        self.reset()
        self._reset_motion()
        back = _RunOutputs.empty(T, groups)
        if self.sides is not None:
            self._two_sided = (out.person[order], out.exchanged[order])
        views = [Reindexed(x, order) for x in (depths, keypoints2d, confidence)]
        try:
            self._run_frames_into(back, {}, 0, *views, progress, 0, T)
        finally:
            self._two_sided, self._run_frame = None, None
        snap, self._person, self.exchanged = after_forward
        self._restore(snap)  # the follower, floor and flips too
        fields = dataclasses.fields(back)
        return _RunOutputs(**{f.name: getattr(back, f.name)[order] for f in fields})

    def _smooth_rows(
        self, rows: _RunOutputs, valid: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One pass's per-frame rows smoothed where ``valid`` (:func:`smooth_sequence`):
        ``(params, keypoints, interpolated)``."""
        lms = Landmarks(
            keypoints2d=rows.kp2, confidence=rows.lm_conf,
            points3d=rows.lm3.astype(np.float32), detected=rows.det, has_depth=rows.has_d,
        )  # fmt: skip
        return smooth_sequence(
            self._smoother, self.shape, self.intrinsics, np.nan_to_num(rows.params), lms,
            valid, fps=self.fps, keypoints=rows.kp3, pose_confidence=rows.conf,
        )  # fmt: skip

    def _fuse_backwards(
        self, out: _RunOutputs, back: _RunOutputs, valid: np.ndarray, params, keypoints
    ) -> tuple[np.ndarray, np.ndarray]:
        """Offline both ways: smooth the backward pass as the forward one was and, in the
        frames both passes have an estimate of the same person (either may have had no
        observation there: both smoothed tracks bridge it), replace the forward pass's smoothed
        poses by the fusion of the two smoothed tracks (:func:`fuse_smoothed`, the backward
        pass's weight ramped in and out by :func:`fuse_weights`)."""
        valid_b = np.isfinite(back.kp3).all(axis=(1, 2))
        same = (out.person == back.person) | (out.person < 0) | (back.person < 0)
        weight = fuse_weights(valid & valid_b & same, valid)
        fused = weight > 0
        if not fused.any():
            return params, keypoints
        smoothed_b, kps_b, _ = self._smooth_rows(back, valid_b)
        p, k = fuse_smoothed(
            self.shape, params[fused], smoothed_b[fused], keypoints[fused], kps_b[fused],
            weight[fused],
        )  # fmt: skip
        params, keypoints = params.copy(), keypoints.copy()
        params[fused], keypoints[fused] = p, k
        self.both_ways_frames = int(fused.sum())
        return params, keypoints

    def _snapshot(self) -> tuple:
        """The host-side state :meth:`update` carries from frame to frame in offline
        :meth:`run` (device arrays are immutable and shared; the follower and the labeller are
        copied). What each frame sets afresh (the person index, its labelling, the depth
        fitted) is not kept."""
        keep = {id(self.intrinsics): self.intrinsics}
        return (
            self._state, self._floor, self._found_floor, self._lost_run, self._ever_initialized,
            self._key, self._frames_seen,
            copy.deepcopy(self._follower, keep), copy.deepcopy(self._labeller),
            copy.deepcopy(self._duplicate_filter), self._dropped, self.reinit_flip_frames,
            self._last_tracked_kp, self._last_tracked_pose,
        )  # fmt: skip

    def _restore(self, snap: tuple) -> None:
        (
            self._state, self._floor, self._found_floor, self._lost_run, self._ever_initialized,
            self._key, self._frames_seen, follower, labeller, duplicate_filter, self._dropped,
            self.reinit_flip_frames, self._last_tracked_kp, self._last_tracked_pose,
        ) = snap  # fmt: skip
        keep = {id(self.intrinsics): self.intrinsics}
        self._follower = copy.deepcopy(follower, keep)
        self._labeller = copy.deepcopy(labeller)
        self._duplicate_filter = copy.deepcopy(duplicate_filter)

    def _refine_settings(self) -> ShapeFitSettings:
        """:attr:`refine`, its image no larger than the sensor's. When and on how many frames
        the refinement runs (``frames``, the online and offline schedules, the pre-pass gate)
        is the tracker's business, not the program's: those fields take their defaults here,
        so every schedule runs one program (``frames`` reaches it as ``pad_to``)."""
        H, W = self.intrinsics.shape
        plain = ShapeFitSettings()
        return dataclasses.replace(
            self.refine, width=min(self.refine.width, W), height=min(self.refine.height, H),
            frames=plain.frames, online_after=plain.online_after,
            online_first=plain.online_first, offline_first=plain.offline_first,
            offline_first_below=plain.offline_first_below, online_spread=plain.online_spread,
        )  # fmt: skip

    def _refine_on(self, params, depths, kp2, lm_conf, frames_used) -> None:
        """Refine :attr:`shape` with :func:`refine_shape` on F frames (their poses as the
        start; depth in metres as fitted) and record :attr:`refine_report` /
        :attr:`refine_s`. Offline after the forward pass, online once (causally)."""
        t0 = time.perf_counter()
        refined, report = refine_shape(
            self.shape, params, depths, kp2, lm_conf, self.intrinsics,
            settings=self._refine_settings(), config=self.config,
            floor=np.asarray(self._floor), pad_to=self.refine.frames,
        )  # fmt: skip
        report["frames_used"] = np.asarray(frames_used)
        self.refine_report = report
        self.refine_s = time.perf_counter() - t0
        self.shape = refined

    def _refine_shape(self, kept, params, kp2, lm_conf) -> np.ndarray | None:
        """Offline: refine :attr:`shape` on the ``kept`` frames ``(n3d, t, depth metres)``
        (:meth:`_refine_on`). Returns the change of the 18 surface offsets the new shape
        implies (metres; ``None`` without ``surface_offset``), for :func:`_along_rays`."""
        t = np.asarray([k[1] for k in kept])
        before = self.shape
        self._refine_on(params[t], np.stack([k[2] for k in kept]), kp2[t], lm_conf[t], t)
        if not self.config.surface_offset:
            return None
        return np.asarray(surface_offsets(self.shape) - surface_offsets(before))

    def _shape_frames(self, depths, keypoints2d, confidence, n: int) -> tuple[list, list, list]:
        """The followed person's observations in the first ``n`` frames, for
        :meth:`estimate_shape` (before any pose exists, people are followed by their lifted
        keypoints alone, with the same rules as :meth:`update`)."""
        ds, kps, confs = [], [], []
        for d, cands, p in self._followed(depths, keypoints2d, confidence, n):
            kp, conf = cands.person(p) if p >= 0 else (np.zeros((18, 2)), np.zeros(18))
            ds.append(d)
            kps.append(kp)
            confs.append(conf)
        return ds, kps, confs

    def _offline_plan(self, depths, keypoints2d, confidence) -> tuple:
        """What an offline :meth:`run` with :attr:`sides` decides before its first fit, from the
        detections alone: ``(person (T,), exchanged (T, groups), spans, turns)``, the two-sided
        labelling (:meth:`_two_sided_labels`), the stretches the depth arbitrates (start ->
        stop; none without :attr:`SideSettings.arbitrate`) and the turns tracked both ways
        (``[(start, stop), ...]``, widened around the stretches; :attr:`turn_spans` records
        their judgements)."""
        persons, exchanged, turns = self._two_sided_labels(depths, keypoints2d, confidence)
        if not self.sides.arbitrate:
            return persons, exchanged, {}, []
        spans = dict(arbitration_spans(exchanged, self.sides.arbitrate_after))
        return persons, exchanged, spans, _turns_around(turns, spans)

    def _two_sided_labels(self, depths, keypoints2d, confidence) -> tuple:
        """Offline left/right labelling (:func:`two_sided_exchanged`) over the whole recording:
        ``(person (T,), exchanged (T, groups), turns)``, the person as a pre-pass follows them
        (a frame where the tracker follows another detection falls back to the forward pass),
        ``turns`` the followed person's turns through a frontal view (:func:`frontal_turns`,
        with :attr:`SideSettings.frontal_turns`; else none)."""
        persons, frames = [], []
        # The pass reads what the tracking pass will fit: with ``duplicates``, a detection
        # that jumped onto another keypoint is withheld here too (its own causal filter).
        dups = self._new_duplicate_filter()
        for _, cands, p in self._followed(depths, keypoints2d, confidence, len(depths)):
            persons.append(p)
            if p < 0:
                frames.append(None)
                continue
            kp, conf = cands.person(p)
            if dups is not None:
                conf, _ = dups.update(kp, conf, cands.points3d[p], cands.has_depth[p])
            frames.append((kp, conf, cands.points3d[p], cands.has_depth[p]))
        exchanged = two_sided_exchanged(frames, float(self.intrinsics.fx), self.sides)
        turns = []
        if self.sides.frontal_turns > 0 and "torso" in self.sides.groups:
            turns = frontal_turns(frames, self.sides.frontal_turns, self.sides.min_confidence)
        return np.asarray(persons, np.int64), exchanged, turns

    def _followed(self, depths, keypoints2d, confidence, n: int):
        """Yield ``(depth metres, candidates, followed index or -1)`` for the first ``n``
        frames, followed by a fresh :class:`PersonFollower` by the rules of :meth:`update` (by
        lifted keypoints alone: no pose exists yet)."""
        follower = PersonFollower(self.follow, self.person_rule, self.intrinsics)
        for i in range(n):
            d = check_depth(self.intrinsics, depths[i], self.depth_scale, f"frame {i}")
            kp_all, conf_all = check_people(keypoints2d[i], confidence[i], f"frame {i}")
            cands = lift_candidates(d, kp_all, conf_all, self.intrinsics)
            p = follower.select(cands)
            follower.observe(cands, p)
            yield d, cands, p


def run_passes(mode: str, motion: SmoothSettings, frames: int) -> int:
    """Passes :meth:`Tracker.run` makes over ``frames`` frames in ``mode``: 2 offline with
    :attr:`SmoothSettings.both_ways` (forwards, then backwards), else 1."""
    return 2 if mode == "offline" and motion.both_ways and frames > 1 else 1


def prepass_frames(mode: str, refine: ShapeFitSettings | str | None, frames: int) -> int:
    """Frames of the offline shape pre-pass :meth:`Tracker.run` makes over ``frames`` frames
    (``refine.offline_first``; 0 when it makes none). ``refine`` as :class:`Tracker` takes it
    (``"auto"``: with no ``shape`` given)."""
    if isinstance(refine, str) and refine == "auto":
        refine = ShapeFitSettings.tracking(mode) if mode != "per-frame" else None
    first = 0 if refine is None or mode != "offline" else refine.offline_first
    return first if 0 < first < frames else 0


def _share(progress: ProgressCallback, offset: int, total: int) -> ProgressCallback:
    """``progress`` for one of several passes over the frames: its frames counted from
    ``offset`` of ``total``."""
    return lambda done, _total, postfix="": progress(offset + done, total, postfix)


def nearest_index(have: np.ndarray, n: int) -> np.ndarray:
    """For each of ``n`` frames, the nearest frame of ``have`` (the earlier one on a tie).

    Args:
        have: ``(K,)`` increasing frame indices, K >= 1.
        n: number of frames.

    Returns:
        ``(n,)`` int64, entries of ``have``.
    """
    # A binary search per frame, O(n log K) time and O(n) memory. The (n, K) table of
    # distances this replaced took 1.6 GB at n = K = 10,000 frames (5 s at the end of a
    # 10,000-frame run: benchmarks/reliability.py), and would not fit at 100,000.
    t = np.arange(n)
    after = np.searchsorted(have, t)  # the first of have at or after t
    hi = have[np.minimum(after, len(have) - 1)]
    lo = have[np.maximum(after - 1, 0)]
    return np.where(np.abs(t - lo) <= np.abs(hi - t), lo, hi)


def exchanged_since(
    kp_then: np.ndarray, conf_then: np.ndarray, kp_now: np.ndarray, conf_now: np.ndarray
) -> bool:
    """Whether the shoulders and hips of ``kp_now`` (18, 2) sit nearer the other side's
    positions in ``kp_then`` than their own: summed over those pairs seen in both frames
    (confidence above 0.1), the image distances with the labels exchanged are the smaller.
    False where neither pair is seen in both."""
    a = b = 0.0
    # The shoulders and the hips: a whole-body swap exchanges them, a limb's swap does not.
    for r, s in TORSO_PAIRS:  # right, left
        if min(conf_then[r], conf_then[s], conf_now[r], conf_now[s]) <= 0.1:
            continue
        a += np.linalg.norm(kp_now[r] - kp_then[r]) + np.linalg.norm(kp_now[s] - kp_then[s])
        b += np.linalg.norm(kp_now[r] - kp_then[s]) + np.linalg.norm(kp_now[s] - kp_then[r])
    return bool(b < a)


def track(
    depths,
    keypoints2d,
    confidence,
    intrinsics: Intrinsics,
    config: TrackerConfig | None = None,
    *,
    shape: body.BodyShape | None = None,
    seed: int = 0,
    progress: ProgressCallback | None = None,
    person: PersonRule = "auto",
    follow: FollowSettings | str | None = "auto",
    mode: str = "offline",
    lag: int = ONLINE_LAG,
    motion: SmoothSettings = SmoothSettings(),
    fps: float = 30.0,
    sides: SideSettings | str | None = "auto",
    refine: ShapeFitSettings | str | None = "auto",
    chunk: int = RUN_CHUNK,
    duplicates: DuplicateSettings | str | None = "auto",
) -> TrackResult:
    """Track a sequence in one call (see :class:`Tracker`). ``keypoints2d[t]`` is one person
    ``(18, 2)`` or every detected person ``(P, 18, 2)``. ``mode``: "offline" (default: the
    motion model over the whole recording), "online" (causal, ``lag`` frames of delay) or
    "per-frame" (the paper's tracker alone); ``lag``: online, each pose waits for the ``lag``
    frames after it (default :data:`ONLINE_LAG`, 3); ``fps`` scales the motion prior; ``sides``
    undoes the detector's left/right swaps (:class:`SideSettings`; ``"auto"``: offline, read
    from both directions and arbitrated by the depth; online, read forwards and each exchange
    judged by the depth before it is published; ``None``: off); ``chunk``: frames per compiled
    call (:data:`RUN_CHUNK`; 1: one call per frame, the same poses); ``duplicates`` drops
    detections that jumped onto another keypoint (:class:`DuplicateSettings`; ``"auto"``:
    offline and online, not per-frame)."""
    return Tracker(
        intrinsics, config, shape=shape, seed=seed, person=person, follow=follow, mode=mode,
        lag=lag, motion=motion, fps=fps, sides=sides, refine=refine, chunk=chunk,
        duplicates=duplicates,
    ).run(depths, keypoints2d, confidence, progress=progress)  # fmt: skip


def lift_sequence(
    depths,
    keypoints2d,
    confidence,
    intrinsics: Intrinsics,
    *,
    config: TrackerConfig | None = None,
    depth_scale: float = 1000.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Plain lifting of every frame (no model, no surface offset): the naive baseline's input.
    With ``config``'s lifting otherwise, the depth band (``lift_band``, default 0.7 m since
    2026-11-28) included; pass ``TrackerConfig(lift_band=0)`` for the paper's lifting.

    Returns:
        (points3d (T, 18, 3) metres, has_depth (T, 18)); pass them to ``naive_lifting``.
    """
    config = (config or TrackerConfig()).replace(surface_offset=False)
    intr = jax.tree.map(lambda x: jnp.asarray(x, _DTYPE), intrinsics)
    shape = body.BodyShape.default(_DTYPE)
    pts, flags = [], []
    for i in range(len(depths)):
        d, k, c = check_frame(
            intr, depths[i], keypoints2d[i], confidence[i], depth_scale, f"frame {i}"
        )
        lm = lift(config, shape, intr, d, k, c)
        pts.append(np.asarray(lm.points3d))
        flags.append(np.asarray(lm.has_depth))
    return np.stack(pts), np.stack(flags)
