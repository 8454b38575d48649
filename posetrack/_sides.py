"""Which detected keypoint is the left one: undoing a detector's left/right swaps (host side).

2D detectors exchange left and right: an arm's elbow and wrist for a few frames, a leg's knee
and ankle, the whole body when a person is seen from the side. Fitted as given, a swap pulls
the model's limbs across the body; a few Levenberg-Marquardt steps then cannot swing them
back when the labels return (the model sits in a local minimum with the limbs crossed), and
MHT_h's temporal weights W^h call the true keypoints outliers because they jump away from the
swapped pose. The swap locks in for far longer than the detector made it.

The keypoints themselves show a swap: both sides jump at once, by the distance between them,
and jump back when it ends, while each side alone moves continuously. So, before the tracker
sees a frame, each group of left/right pairs (:data:`SIDE_GROUPS`; by default the arms'
elbow+wrist and the legs' knee+ankle) gets one of two labellings, "as detected" or
"exchanged", by the forward (filtering) pass of a two-state hidden Markov chain:

* going from labelling s' to s between frames costs, summed over the group's keypoint slots,
  the image distance (converted to metres at the person's depth) between the slot's keypoint
  under s and the slot's last seen position on the cheapest path into s'; a keypoint unseen
  for k frames may have moved (k - 1) x ``speed`` for free, and one keypoint adds at most
  ``cap`` (an outlier costs no more than a jump);
* "exchanged" costs ``switch_cost`` per frame, so it wins only while it saves jumps: a swap
  of n frames is undone while n x switch_cost stays below the two jumps it saves;
* the labelling used for a frame is the cheaper state after that frame. It is causal, so the
  live tracker and the offline one share it; a Viterbi back-trace over the whole recording
  was tried and corrected no more frames (300 against 306 wrong labels on wide tuning clips).

A group unseen in a frame keeps its memory; one seen on one side only still decides by that
side's continuity. Arms truly crossing make no jump: both labellings cost the same there and
"as detected" wins by ``switch_cost``.

Distances are 2D on purpose: the lifted depth at a wrist or an elbow often lands on the
background behind a thin limb (metre jumps from one frame to the next), and 3D distances
gave more wrong labels (363 against 306 on wide tuning clips). The face (eyes, ears: a few
centimetres apart, often missed) is not relabelled by default: on the standard tuning clips
relabelling it made more errors than it removed (17 -> 88 wrong frames); the torso
(shoulders, hips) is, judged by the depth (below).

The forward pass alone removed most swapped-limb frames where the person is seen whole, but
under occlusion (one side hidden: its return looks like a jump) it misread often enough to
cost accuracy; read backwards the same stretches show no jump. So :meth:`Tracker.run` offline
reads the whole recording from both directions (:func:`two_sided_exchanged`): on the tuning
clips (seeds 100-111, standard and wide, occlusion 0 and 2) the wrongly exchanged
group-frames fell from 31 / 107 (wide clean / occluded, forward) to 16 / 47, and on the
standard occluded clips from 64 to 0. Taken as read, that reading still exchanged correct
labels on occluded side views (a person walking across the image, arms overlapping in the
image), where 2D continuity is ambiguous.

**The depth arbitrates** (:attr:`SideSettings.arbitrate`, the offline default). Each stretch
read exchanged (:func:`arbitration_spans`: the exchanged run plus
:attr:`SideSettings.arbitrate_after` frames) is tracked twice from the same tracker state,
with the labels exchanged and as detected, and the exchange is kept only where its poses'
Delta (Eq. (3), the tracker's own depth score) summed over the stretch is lower
(:func:`prefer_exchanged`). Where the sides overlap in the image, both readings render alike
and a tie keeps the detections' labels; a true swap drags the model's limbs across the body
and the depth says so. On 20 occluded side-view tuning clips (seeds 116-135, walk_across and
turn) D was 64.0 mm without relabelling, 66.3 with the two-sided reading taken as read and
63.9 arbitrated; on the wide tuning clips (seeds 100-111) 78.7 / 60.0 / 63.5 mm clean. A
margin of 0.1 on the Delta sums was tried and made tuning clips worse (a turn clip 52.7 ->
57.1 mm): small differences are informative. The cost is the second tracking of those
stretches (benchmarks/motion.py records the share of frames).

**Online the depth arbitrates too** (:meth:`Tracker.update`, ``mode="online"``): only the
forward pass exists, so the stretch is not known in advance. Where the forward pass newly
reads a group exchanged, that frame and the next ones (:attr:`SideSettings.online_frames`;
by default the lag + 1, the most for which the decision still comes before the stretch's
first pose is published) are tracked twice from the same state, exchanged and as detected,
and the reading with the lower Delta summed is kept (a group newly read exchanged while
another is judged stays as detected until that judgement ends, then is judged on its own).
An exchange the depth refused stays refused while the forward pass reads it; one it kept is
judged again after :attr:`SideSettings.online_rejudge` frames (the forward pass holds a
misreading until the next real jump). On the tuning clips (seeds 100-107 standard, 100-105
wide; lag 3; D mm clean / occluded) the online tracker without relabelling gave 35.3 / 53.2
standard and 75.2 / 89.0 wide, the forward reading taken as read 31.8 / 55.5 and 49.9 /
74.9, arbitrated 31.0 / 51.8 and 56.5 / 73.2 (judged once per exchange, never again:
standard occluded 53.3; again after 8 frames instead of 16: 31.0 / 50.5 and 57.4 / 73.4, at
more cost; all with lag + 1 = 4 frames judged). Judging 2 frames instead of 4 gave the same
D on those clips within their noise (one clip decided it); on 42 tuning clips (standard
100-123, wide 100-117) the means of the four (generator, occlusion) D's were 64.1 mm judging
2 frames, 63.3 judging 4, 71.3 without relabelling, so lag + 1 stays the default; 62.8 at
lag + 1 once a group newly read inside another's judgement waited for its own
(benchmarks/README.md). An exchange the forward pass drops again within the judged frames
(held in fewer than :attr:`SideSettings.online_min_held` of them, by default 2) is not kept
whatever the depth says: a detector outlier's jump reads as a one-frame exchange, and on
wide tuning clips a Delta sum a hair lower kept such readings (with the rule the mean of
the four wide D's fell by 1.6 mm; benchmarks/README.md).

**Online, the tracker's own pose reads the labels where the 2D continuity cannot**
(:attr:`SideSettings.online_model`). After a stretch where one side was unseen, or sat on the
other (a knee reported on the other knee), the forward pass's two paths cost the same: its
margin falls to centimetres, the paths trade places for free, and its reading follows
``switch_cost``, so it drops an exchange the depth kept a frame later and reads the swap's
end as a new one (a wide tuning clip: the legs fitted swapped for 10 frames, then again for
9). There the group is read as the tracker's last tracked pose says: the labelling under which
the detections lie nearer that pose projected into the image (:meth:`SideLabeller.refer`);
the judge, the veto and the re-judgement work on that reading as on the forward pass's.
Within a tie the forward margin still drifts toward "as detected" by ``switch_cost`` a frame,
so the pose decides for about ``online_model / switch_cost`` frames (10 at 0.1 m) and a
swapped pose cannot hold its swap for longer. **Opt-in** (default 0): on 96 wide real tuning
runs it met a rule written first (benchmarks/README.md: D 73.52 -> 71.21 mm, swapped-limb
frames 715 -> 597, 17 runs better and 4 worse by more than 5 mm), but two report sets got
worse (wide clean 46.9 -> 51.4 mm, a side-view walk 88 -> 144; real motion wide occluded
97.1 -> 100.4, one clip 147 -> 189), which the rule made a stop. Where it loses, the pose
it asks had followed a swap the forward pass never read, and it holds that swap longer.
Offline the two-sided reading has no such blind spot and the chunked pass has no pose on
the host in time, so it is online only.

**The torso is relabelled too, online and offline** (:meth:`SideSettings.for_mode`): a
detector that reads the person as facing the other way exchanges every pair at once,
shoulders and hips included (the wide generator's whole-body swaps). Undone limb by limb,
the torso stays exchanged and turns the model round (on a tuning clip the shoulders 300 mm
and the wrists 600 mm off for 19 frames). With the depth judging each exchange, relabelling
the torso online brought the mean D of 40 tuning clips from 55.84 to 53.02 mm, no group
worse (wide real motion clean 49.2 -> 44.5, occluded 85.2 -> 75.8). Offline it first failed
its rule on those clips (mean 48.06 -> 47.66 mm, but wide real occluded 70.6 -> 73.0, one
clip whose track is lost for a while either way; over tracker seeds 0-2 it met it, 48.29 ->
47.32), and was held back; on 48 fresh wide real motion tuning runs (seeds 100-123, clean and
occluded) it met a rule written first, 64.75 -> 61.98 mm (clean 50.6 -> 46.2, occluded 78.9
-> 77.8, swapped-limb frames 305 -> 252; two clips with a whole-body swap 57 -> 18 and 115
-> 68 mm), and is the offline default since 2026-11-28. The face failed both modes
(benchmarks/README.md, "Relabel the torso and the face too"). The torso and the face were
first left out on label counts alone, before the depth arbitrated (standard tuning clips:
torso 0 -> 10 wrong frames, face 17 -> 88).

The tracker relabels by default offline and online (``sides="auto"``; ``sides=None``,
``posetrack track --no-fix-sides`` turn it off); per-frame (the paper's tracker) it does not.

NumPy, not JAX: a handful of numbers per frame beside the person association, which is host
side too (:mod:`posetrack._associate`), and each frame depends on the last.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._body import flip_labels

#: Groups of COCO-18 (right, left) pairs a detector exchanges together, by name. A
#: whole-body swap exchanges all of them at once.
SIDE_GROUPS: dict[str, tuple[tuple[int, int], ...]] = {
    "arms": ((3, 6), (4, 7)),
    "legs": ((9, 12), (10, 13)),
    "face": ((14, 15), (16, 17)),
    "torso": ((2, 5), (8, 11)),
}


_NEVER = 1e9  # the cost of a labelling that is ruled out

#: :func:`frontal_turns`: the detected shoulders overlap in the image (a side view) while their
#: distance is at most this share of the neck-to-hips distance (a frontal view: ~0.7).
TURN_OVERLAP = 0.2


@dataclasses.dataclass(frozen=True)
class SideSettings:
    """Left/right relabelling of the followed person's detections (:class:`SideLabeller`).

    Defaults chosen on tuning seeds 100-105 (standard and wide synthetic clips), by the frames
    whose labelling disagreed with the truth.
    """

    groups: tuple[str, ...] = ("arms", "legs")
    """Which :data:`SIDE_GROUPS` are relabelled. The tracker's default offline and online
    adds the torso (:meth:`for_mode`)."""
    switch_cost: float = 0.01
    """Cost (m) per frame of the "exchanged" labelling. A swap of n frames is undone while
    n x switch_cost is below the two jumps it saves (sides 0.3 m apart: up to ~60 frames)."""
    cap: float = 0.5
    """Largest cost (m) one keypoint's jump adds."""
    speed: float = 0.05
    """How far (m per frame) a keypoint may move while unseen without cost."""
    min_confidence: float = 0.1
    """Keypoints at or below this confidence are unseen."""
    two_sided_margin: float = 0.1
    """Offline (the whole recording known, :func:`two_sided_exchanged`): a group is read
    exchanged only where the forward and the backward pass together favour it by more than
    this (m)."""
    torso_with_limbs: bool = False
    """Offline (:func:`two_sided_exchanged`), with the "torso" group: the torso is read
    exchanged only in frames where the arms or the legs are too (a whole-body swap); alone,
    the shoulders and hips of a side view overlap in the image and one noisy frame reads as
    a swap. Tried on 40 tuning clips with the torso offline (benchmarks/README.md): mean D
    48.06 -> 47.61 mm, but one occluded clip lost 15 mm: not a default."""
    arbitrate: bool = True
    """The depth decides. Offline (:func:`arbitration_spans`) each stretch the two-sided
    labelling reads exchanged is tracked twice from the same state, with the labels exchanged
    and as detected, and the exchange is kept only where its poses' Delta (Eq. (3)) summed
    over the stretch is lower by more than :attr:`arbitrate_margin`; online the first
    :attr:`online_frames` frames of each exchange are (see the module docstring). False: the
    labelling is taken as read (the 2D evidence alone)."""
    frontal_turns: float = 0.0
    """Offline, with :attr:`arbitrate` and the "torso" group: > 0 also judges each turn through
    a frontal (or back) view: a stretch from a side view, where the detected shoulders overlap
    in the image (their distance at most :data:`TURN_OVERLAP` of the neck-to-hips distance),
    through frames where they stand at least this ratio apart, to the next overlap or the
    recording's end (:func:`frontal_turns`). The turn is tracked as labelled (its stretches
    read exchanged judged as usual), then again from the same state with every labelling
    mirrored (each group and the face exchanged against its reading: the detector's whole-body
    swap undone), and the mirrored tracking is kept where its Delta summed is lower by
    :attr:`turn_margin` a frame (:attr:`Tracker.turn_spans`). A whole-body swap that starts and
    ends while the shoulders overlap shows no jump to either 2D pass, and the track turns round
    with the swapped labels (benchmarks/README.md, "Does Delta tell a turned track?": every
    long wrong-facing stretch there started so). 0: off (the default: 0.45 helped on 48 used
    tuning runs but failed its screen on 76 fresh ones, none better, two worse by 7-44 mm,
    with a quarter of the frames tracked twice: benchmarks/README.md). Not in the paper."""
    turn_margin: float = 0.01
    """With :attr:`frontal_turns`: how much lower, per frame both trackings estimate, the
    mirrored tracking's Delta must be to be kept (a turn's two readings tie where the body
    is seen from the side, and a tie kept mirrored turns the track round for the rest of the
    turn; in a look at 48 wide walk_across tuning runs, the mirrorings that helped led by
    0.012-0.1 a frame, the two that did harm by 0.002 and 0.007: read off those runs; on the
    screen's fresh runs a harmful mirroring led by 0.025 and 0.029 a frame, so no margin
    separates them)."""
    arbitrate_groups: bool = False
    """Offline, with :attr:`arbitrate`: where more than one group was read exchanged in a
    stretch, each of those groups' exchange is also tracked alone (the others as detected),
    and of the readings that beat the detections as they are (:func:`prefer_exchanged`),
    every group's exchange included, the one whose Delta summed is lowest is kept. A
    stretch is otherwise decided for every group together, so one group's false readings
    take down another's true one (on a tuning clip the legs' swap was read right while the
    arms' and torso's scattered false readings made the exchanged reading lose the person;
    benchmarks/README.md, "What the left/right undoing does on 1386") or ride along with it.
    One more tracking of the stretch per group read exchanged. Opt-in: on 56 fresh tuning
    runs (2026-12-04) D -0.45 mm but swapped-limb frames 426 -> 430, moving clips by up to
    25 mm either way; its screen failed (benchmarks/README.md, "Each group's exchange judged
    on its own"). Not in the paper."""
    arbitrate_after: int = 5
    """Frames after each exchanged stretch that its Delta comparison also covers (a wrong
    labelling leaves the limbs misplaced for a few frames after it ends)."""
    arbitrate_margin: float = 0.0
    """How much lower (Delta summed over the stretch) the exchanged reading must score."""
    online_frames: int | None = None
    """Online (:meth:`Tracker.update`, with :attr:`arbitrate`): how many frames, from the
    first one the forward pass newly reads a group exchanged, are tracked both ways before
    the depth decides. At most the tracker's lag + 1 keeps the decision before the stretch's
    first pose is published. ``None``: the lag + 1. Fewer frames cost less (2 at lag 3: half
    the second tracking) and decide on less evidence: on 42 tuning clips 2 frames gave a mean
    D 0.8 mm above 4 (benchmarks/README.md; measured before the fix of judgements that
    overlap)."""
    online_min_held: int = 2
    """Online: an exchange is kept only if the forward pass, on the exchanged reading, still
    reads the group exchanged in at least this many of the judged frames (the first
    included; at most all of them, :attr:`online_frames`); until then the detections' labels
    lead. A reading the forward pass drops again at once is a detector outlier's jump more
    often than a swap (on a wide tuning clip one was kept by a Delta sum 0.7 % lower). 1: the
    depth alone decides (before 2026-11-26 evening). Chosen on tuning clips by a rule written
    before the run (benchmarks/README.md)."""
    online_anchor: float = 0.0
    """Online: when the depth keeps an exchange, the forward pass is anchored to it: the
    exchanged reading of the judged groups leads the "as detected" one by at least this (m)
    from then on, so it holds until the detections jump back. Without it (0) the forward
    pass keeps its own margin, which a stretch where the two sides' detections coincide (a
    knee reported on the other knee for a dozen frames) leaves near zero: the exchange the
    depth kept is dropped a frame later and the swap is fitted as detected. Opt-in: it holds
    the depth's wrong verdicts as long as its right ones, and on 32 wide real tuning runs it
    made D worse by 1.4-1.9 mm and the swapped-limb frames 180 -> 260 at 0.25 / 0.5 m
    (benchmarks/README.md, "Online: a kept exchange held until the detections jump back").
    Not in the paper."""
    online_groups: bool = False
    """Online (with :attr:`arbitrate`): where the forward pass newly reads several groups
    exchanged in one frame, each group's exchange alone is also tracked over the judged
    frames (the others as detected), and of the readings that beat the detections
    (:func:`prefer_exchanged`, after :attr:`online_min_held`), every group's exchange
    together included, the one whose Delta summed is lowest is kept (the online twin of
    :attr:`arbitrate_groups`). Judged together, one group's misreading takes down another's
    true exchange or rides along with it (a test clip: D 52.1 mm together, 26.9 per group);
    on the tuning clip that prompted it (the arms' true swap refused together with a misread
    of the legs, then a whole-body swap fitted and locked in) the arms alone lost to the
    detections too (benchmarks/README.md, "Online: where the left/right undoing loses"). One
    more tracking of the judged frames per group read, only in those frames. Opt-in: its
    screen on 56 fresh tuning runs passed (D -0.93 mm, swapped-limb frames 605 -> 538); the
    online report stage (2026-12-04) gave D -0.60 mm and fewer swapped-limb frames but 14
    fewer answered frames of 23,040, where its rule asked for none. Not in the paper."""
    online_rejudge: int = 16
    """Online: a group read exchanged for more than this many frames since the depth last
    judged it is judged again (exchanged from here on, or as detected), so an exchange the
    forward pass holds after the swap ended (a side hidden for a while) does not last."""
    online_model: float = 0.0
    """Online: where the forward pass's margin of a group is within this (m) of a tie, the
    group is read as the tracker's own pose of the last tracked frame says
    (:meth:`SideLabeller.refer`: the labelling under which the detections lie nearer that
    pose projected into the image, if it leads by more than :attr:`online_model_margin` and
    the pose is at most :attr:`online_model_age` frames old). At a tie the forward pass's
    two paths trade places for free and its reading follows ``switch_cost``: after a
    stretch where one side was unseen or sat on the other (the margin drops to
    centimetres), it drops an exchange the depth kept a frame later. The pose carried the
    depth's verdict and the motion through those frames. 0: off (the forward pass alone;
    the default: 0.1 met its rule on tuning runs and was stopped by two report sets, see
    the module docstring). Not in the paper."""
    online_model_margin: float = 0.05
    """Online, with :attr:`online_model`: how much (m, summed over the group's seen keypoints)
    nearer the tracker's pose one labelling must put the detections."""
    online_model_age: int = 3
    """Online, with :attr:`online_model`: the tracker's pose is used up to this many frames
    after it was tracked."""

    @classmethod
    def for_mode(cls, mode: str, **changes) -> SideSettings:
        """The :class:`Tracker`'s default for a mode (``sides="auto"``): arms, legs and torso
        offline and online, arms and legs per-frame (where nothing is relabelled; decided on
        tuning clips, see the module docstring). ``changes`` override fields, e.g.
        ``arbitrate_margin=0.1``."""
        if mode not in ("offline", "online", "per-frame"):
            raise ValueError(
                f"SideSettings.for_mode: mode must be 'offline', 'online' or 'per-frame', "
                f"got {mode!r}"
            )
        if mode in ("offline", "online"):
            changes = {"groups": ("arms", "legs", "torso"), **changes}
        return cls(**changes)

    def __post_init__(self):
        for name in ("arbitrate", "arbitrate_groups", "online_groups", "torso_with_limbs"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(
                    f"SideSettings: {name} must be True or False, got {getattr(self, name)!r}"
                )
        for name, least in (
            ("arbitrate_after", 0),
            ("online_frames", 1),
            ("online_rejudge", 1),
            ("online_min_held", 1),
            ("online_model_age", 0),
        ):
            n = getattr(self, name)
            if n is None and name == "online_frames":
                continue
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < least:
                raise ValueError(
                    f"SideSettings: {name} must be an int >= {least} (frames), got {n!r}"
                )
        names = ("switch_cost", "cap", "speed", "min_confidence", "two_sided_margin")
        for name in (*names, "arbitrate_margin", "online_anchor", "online_model",
                     "online_model_margin", "frontal_turns", "turn_margin"):  # fmt: skip
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"SideSettings: {name} must be a finite number, got {v!r}")
        if self.frontal_turns != 0 and not TURN_OVERLAP < self.frontal_turns <= 2:
            raise ValueError(
                f"SideSettings: frontal_turns must be 0 (off) or in ({TURN_OVERLAP}, 2], got "
                f"{self.frontal_turns!r}"
            )
        for name in ("online_anchor", "online_model", "online_model_margin", "turn_margin"):
            if getattr(self, name) < 0:
                raise ValueError(
                    f"SideSettings: {name} must be >= 0 (m), got {getattr(self, name)!r}"
                )
        if self.switch_cost <= 0 or self.cap <= 0 or self.speed < 0 or self.two_sided_margin < 0:
            raise ValueError(
                "SideSettings: switch_cost and cap must be positive, speed and "
                f"two_sided_margin >= 0, got {self.switch_cost!r}, {self.cap!r}, "
                f"{self.speed!r}, {self.two_sided_margin!r}"
            )
        if not 0 <= self.min_confidence < 1:
            raise ValueError(
                f"SideSettings: min_confidence must be in [0, 1), got {self.min_confidence!r}"
            )
        groups = tuple(self.groups)
        bad = [g for g in groups if g not in SIDE_GROUPS]
        if bad or len(set(groups)) != len(groups):
            raise ValueError(
                f"SideSettings: groups must be distinct names from {tuple(SIDE_GROUPS)}, "
                f"got {self.groups!r}"
            )
        object.__setattr__(self, "groups", groups)


def metres_per_pixel(
    points3d: np.ndarray, has_depth: np.ndarray, seen: np.ndarray, fx: float
) -> float:
    """Metres per image pixel at a person's depth: the median depth of their seen keypoints'
    ``(18, 3)`` plainly lifted points (3 m where none has depth) over the focal length."""
    h3 = np.asarray(has_depth, bool).reshape(18) & np.isfinite(points3d).all(axis=-1) & seen
    return (float(np.median(points3d[h3, 2])) if h3.any() else 3.0) / fx


class SideLabeller:
    """The forward pass over one followed person's frames (see the module docstring).

    Example::

        lab = SideLabeller(fx=intrinsics.fx)
        for kp2d, conf, points3d, has_depth in frames:
            kp2d, conf, exchanged = lab.update(kp2d, conf, points3d, has_depth)
    """

    def __init__(self, fx: float, settings: SideSettings = SideSettings()):
        if not isinstance(settings, SideSettings):
            raise TypeError(f"SideLabeller: settings must be SideSettings, got {type(settings)}")
        if not (np.isfinite(fx) and fx > 0):
            raise ValueError(f"SideLabeller: fx must be a positive focal length, got {fx!r}")
        self.settings = settings
        self.fx = float(fx)
        pairs = [SIDE_GROUPS[g] for g in settings.groups]
        # Per group: its keypoint slots (right keypoints, then left) and the other side's
        # keypoint for each slot (what fills it under the "exchanged" labelling).
        self._slots = [np.array([a for a, _ in p] + [b for _, b in p]) for p in pairs]
        self._flipped = [flip_labels(slots)[slots] for slots in self._slots]
        self.reset()

    def reset(self, first: np.ndarray | None = None) -> None:
        """Forget the person's past (a new track starts).

        ``first``: ``bool (groups,)``, how each group's first sighting is read (exchanged where
        True); ``None``: as detected. The backward pass of :func:`two_sided_exchanged` starts
        from the forward pass's last labelling this way.
        """
        self._first = np.zeros(len(self._slots), bool) if first is None else np.asarray(first, bool)
        self._cost = np.zeros((len(self._slots), 2))
        # Per group and labelling: each slot's last seen pixel, whether it was ever seen,
        # and frames since.
        self._px = [np.zeros((2, len(k), 2)) for k in self._slots]
        self._seen = [np.zeros((2, len(k)), bool) for k in self._slots]
        self._age = [np.zeros((2, len(k))) for k in self._slots]
        # The tracker's own pose (online_model): (18, 2) pixels and frames since it was tracked.
        self._model: np.ndarray | None = None
        self._model_age = 0

    @property
    def exchanged(self) -> np.ndarray:
        """``bool (groups,)`` the forward pass's labelling of the last frame, per
        ``settings.groups`` (before any :attr:`SideSettings.online_model` reading)."""
        return self._cost[:, 1] < self._cost[:, 0]

    @property
    def margin(self) -> np.ndarray:
        """``(groups,)`` metres: the cost of "exchanged" minus that of "as detected" after the
        last frame (negative: exchanged is the cheaper reading)."""
        return self._cost[:, 1] - self._cost[:, 0]

    def anchor(self, groups: np.ndarray, margin: float) -> None:
        """Make each of ``groups`` (``bool (groups,)``) read exchanged, ahead of "as detected"
        by at least ``margin`` (m): evidence from outside the 2D continuity (the depth kept
        the exchange) replaces a near-tie."""
        for g in np.flatnonzero(np.asarray(groups, bool)):
            cost = self._cost[g] - self._cost[g].min()
            self._cost[g] = (max(cost[0], float(margin)), 0.0)

    def refer(self, keypoints2d: np.ndarray | None) -> None:
        """Tell the labeller the tracker's pose of the frame just tracked, projected into the
        image (``(18, 2)`` pixels), or None where that frame was not tracked (the last pose
        ages by a frame). Read by :meth:`update` with :attr:`SideSettings.online_model`."""
        if keypoints2d is None:
            self._model_age += 1
        else:
            self._model = np.asarray(keypoints2d, np.float64).reshape(18, 2)
            self._model_age = 0

    def relabel(
        self, keypoints2d: np.ndarray, confidence: np.ndarray, exchanged: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Copies of one frame's ``(18, 2)`` keypoints and ``(18,)`` confidences with the left
        and right keypoints of each group where ``exchanged`` (``bool (groups,)``) swapped."""
        swap = [k for k, e in zip(self._slots, np.asarray(exchanged, bool), strict=True) if e]
        labels = flip_labels(np.concatenate(swap or [[]]))
        return np.asarray(keypoints2d)[labels], np.asarray(confidence)[labels]

    def update(
        self,
        keypoints2d: np.ndarray,
        confidence: np.ndarray,
        points3d: np.ndarray,
        has_depth: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Take one frame of the followed person; return it relabelled.

        Args:
            keypoints2d: ``(18, 2)`` pixels. confidence: ``(18,)``, 0 = missing.
            points3d: ``(18, 3)`` plainly lifted keypoints, metres (only their median depth
                is used, to turn pixels into metres).
            has_depth: ``(18,)`` where ``points3d`` is valid.

        Returns:
            ``(keypoints2d, confidence, exchanged)``: copies with each exchanged group's left
            and right keypoints and confidences swapped; ``exchanged`` ``bool (groups,)``:
            :attr:`exchanged`, or with :attr:`SideSettings.online_model` and a pose from
            :meth:`refer`, that pose's reading where the forward pass is near a tie.
        """
        s = self.settings
        kp = np.asarray(keypoints2d, np.float64).reshape(18, 2)
        conf = np.asarray(confidence, np.float64).reshape(18)
        p3 = np.asarray(points3d, np.float64).reshape(18, 3)
        seen = (conf > s.min_confidence) & np.isfinite(kp).all(axis=-1)
        m_per_px = metres_per_pixel(p3, has_depth, seen, self.fx)
        ask_pose = (
            s.online_model > 0 and self._model is not None and self._model_age <= s.online_model_age
        )
        # online_model: per group, how far (m) the detections lie from the tracker's pose
        # under each labelling [as detected, exchanged].
        pose_cost = np.zeros((len(self._slots), 2))
        for g, orders in enumerate(zip(self._slots, self._flipped, strict=True)):
            # What fills the slots under each labelling: (labelling, slot, ...).
            okp, oseen = kp[np.stack(orders)], seen[np.stack(orders)]
            if ask_pose:
                d = np.linalg.norm(okp - self._model[orders[0]], axis=-1) * m_per_px
                pose_cost[g] = np.minimum(np.where(oseen, d, 0.0), s.cap).sum(axis=-1)
            # Jump costs [previous labelling, this labelling, slot].
            d = np.linalg.norm(okp[None] - self._px[g][:, None], axis=-1) * m_per_px
            d = np.maximum(d - s.speed * (self._age[g][:, None] - 1.0), 0.0)
            both = oseen[None] & self._seen[g][:, None]
            step = np.minimum(np.where(both, d, 0.0), s.cap).sum(axis=-1)
            total = self._cost[g][:, None] + step + np.array([0.0, s.switch_cost])[None, :]
            best_prev = total.argmin(axis=0)
            cost = total.min(axis=0)
            if not self._seen[g][0].any():
                # The group's first sighting is read as detected (or as ``first`` says).
                # Without this anchor, "exchanged since the start" is as continuous as
                # "exchanged during the swap", and wins once a swap lasts longer than the
                # track before it.
                cost[0 if self._first[g] else 1] = _NEVER
            # Each labelling's memory continues the cheapest path into it.
            px = self._px[g][best_prev]
            was_seen = self._seen[g][best_prev]
            age = self._age[g][best_prev] + 1.0
            px = np.where(oseen[..., None], okp, px)
            was_seen |= oseen
            age = np.where(oseen, 1.0, age)
            self._px[g], self._seen[g], self._age[g] = px, was_seen, age
            self._cost[g] = cost - cost.min()
        ex = self.exchanged
        if ask_pose:
            # Near a tie of the forward pass, the labelling the pose prefers by enough.
            lead = pose_cost[:, 1] - pose_cost[:, 0]
            ask = (np.abs(self.margin) < s.online_model) & (np.abs(lead) > s.online_model_margin)
            ex = np.where(ask, lead < 0, ex)
        return (*self.relabel(keypoints2d, confidence, ex), ex)


def two_sided_exchanged(
    frames: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None],
    fx: float,
    settings: SideSettings = SideSettings(),
) -> np.ndarray:
    """The labelling of a whole recording, read from both directions (offline).

    The forward pass alone misreads where a side was unseen for a while: the keypoint's last
    seen position is stale, its return looks like a jump, and "exchanged" holds until the next
    real jump. Read backwards, the same stretch shows no jump. So the forward pass runs, then
    the backward pass (from the last frame to the first, its first sighting read as the
    forward pass's last labelling), and a group is read exchanged where the two passes' margins
    (:attr:`SideLabeller.margin`, each including the frame itself) sum below
    ``-settings.two_sided_margin``. A true swap shows its jumps to both passes.

    Args:
        frames: per frame, the followed person's ``(keypoints2d (18, 2), confidence (18,),
            points3d (18, 3), has_depth (18,))`` as :meth:`SideLabeller.update` takes them,
            or ``None`` where nobody was followed.
        fx: focal length, pixels.

    Returns:
        ``bool (frames, groups)``; False where ``frames`` has ``None``.
    """
    groups = len(settings.groups)
    margins = np.zeros((2, len(frames), groups))
    lab = SideLabeller(fx, settings)
    for t, f in enumerate(frames):
        if f is not None:
            lab.update(*f)
            margins[0, t] = lab.margin
    last = lab.exchanged
    lab.reset(first=last)
    for t in range(len(frames) - 1, -1, -1):
        if frames[t] is not None:
            lab.update(*frames[t])
            margins[1, t] = lab.margin
    seen = np.array([f is not None for f in frames], bool)
    exchanged = (margins.sum(axis=0) < -settings.two_sided_margin) & seen[:, None]
    if settings.torso_with_limbs and "torso" in settings.groups:
        g = settings.groups.index("torso")
        limbs = [i for i, name in enumerate(settings.groups) if name in ("arms", "legs")]
        exchanged[:, g] &= exchanged[:, limbs].any(axis=1)
    return exchanged


def frontal_turns(
    frames: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None],
    apart: float,
    min_confidence: float = 0.1,
) -> list[tuple[int, int]]:
    """The turns through a frontal (or back) view of a recording, from its 2D detections.

    Per frame, the detected shoulders' image distance over the distance from the neck to the
    hips' midpoint (either hip where one is missed); frames without both shoulders, the neck
    and a hip keep the last ratio. A turn runs from the last frame whose ratio is at most
    :data:`TURN_OVERLAP` (the shoulders overlap: a side view) before the ratio reaches
    ``apart``, to the next frame at most :data:`TURN_OVERLAP` (exclusive) or the end. A
    recording that starts apart has no turn there (no side view before it).

    Args:
        frames: as :func:`two_sided_exchanged` takes them (``None``: nobody followed).
        apart: the ratio a frontal view reaches.
        min_confidence: keypoints at or below it are missed.

    Returns:
        ``[(start, stop), ...]``, increasing, ``stop`` exclusive.
    """
    ratio = np.full(len(frames), np.nan)
    for t, f in enumerate(frames):
        if f is None:
            continue
        kp, conf = np.asarray(f[0], np.float64), np.asarray(f[1], np.float64)
        seen = conf > min_confidence
        hips = [h for h in (8, 11) if seen[h]]
        if not (seen[1] and seen[2] and seen[5] and hips):
            continue
        torso = np.linalg.norm(kp[1] - kp[hips].mean(axis=0))
        if torso > 1e-6:
            ratio[t] = np.linalg.norm(kp[5] - kp[2]) / torso
    turns: list[tuple[int, int]] = []
    side = None  # the last frame read as a side view
    start = None
    last = np.nan
    for t, r in enumerate(ratio):
        r = last if np.isnan(r) else r
        last = r
        if np.isnan(r):
            continue
        if r <= TURN_OVERLAP:
            if start is not None:
                turns.append((start, t))
                start = None
            side = t
        elif r >= apart and start is None and side is not None:
            start, side = side, None
    if start is not None:
        turns.append((start, len(frames)))
    return turns


def arbitration_spans(exchanged: np.ndarray, after: int) -> list[tuple[int, int]]:
    """The stretches of a recording whose left/right labelling the depth arbitrates.

    Each maximal run of frames in which any group is read exchanged, extended by ``after``
    frames (not past the end); runs that then overlap or touch are merged.

    Args:
        exchanged: ``bool (frames, groups)``, e.g. from :func:`two_sided_exchanged`.
        after: frames added after each run.

    Returns:
        ``[(start, stop), ...]``, increasing, ``stop`` exclusive.
    """
    any_ex = np.asarray(exchanged, bool).any(axis=1)
    T = len(any_ex)
    spans: list[tuple[int, int]] = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], any_ex.astype(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        stop = min(int(stop) + after, T)
        if spans and start <= spans[-1][1]:
            spans[-1] = (spans[-1][0], stop)
        else:
            spans.append((int(start), stop))
    return spans


def prefer_exchanged(
    delta_detected: np.ndarray, delta_exchanged: np.ndarray, margin: float
) -> bool:
    """Whether a stretch tracked with the labels exchanged scored better than as detected.

    Args:
        delta_detected, delta_exchanged: ``(frames,)`` Delta of each frame's pose (Eq. (3));
            NaN where the frame has none.
        margin: how much lower the exchanged reading's sum must be.

    The sums run over the frames both readings estimated; a reading that estimated fewer
    frames (it lost the track) does not win.
    """
    a, b = np.asarray(delta_detected, float), np.asarray(delta_exchanged, float)
    fa, fb = np.isfinite(a), np.isfinite(b)
    both = fa & fb
    if fb.sum() < fa.sum() or not both.any():
        return False
    return bool(b[both].sum() < a[both].sum() - margin)
