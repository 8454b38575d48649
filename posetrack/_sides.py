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
centimetres apart, often missed) and the torso (shoulders, hips) are not relabelled by
default: on the standard tuning clips relabelling them made more errors than it removed
(face 17 -> 88 wrong frames, torso 0 -> 10), and a wrongly exchanged torso turns the body
round.

The tracker runs it only when asked (``Tracker(..., sides=SideSettings())``, ``posetrack track
--fix-sides``): on the report clips it removed most swapped-limb frames where the person is
seen whole, but under occlusion (one side hidden) and with legs crossing in side views it
misreads often enough to cost accuracy (README, Motion).

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


@dataclasses.dataclass(frozen=True)
class SideSettings:
    """Left/right relabelling of the followed person's detections (:class:`SideLabeller`).

    Defaults chosen on tuning seeds 100-105 (standard and wide synthetic clips), by the frames
    whose labelling disagreed with the truth.
    """

    groups: tuple[str, ...] = ("arms", "legs")
    """Which :data:`SIDE_GROUPS` are relabelled."""
    switch_cost: float = 0.01
    """Cost (m) per frame of the "exchanged" labelling. A swap of n frames is undone while
    n x switch_cost is below the two jumps it saves (sides 0.3 m apart: up to ~60 frames)."""
    cap: float = 0.5
    """Largest cost (m) one keypoint's jump adds."""
    speed: float = 0.05
    """How far (m per frame) a keypoint may move while unseen without cost."""
    min_confidence: float = 0.1
    """Keypoints at or below this confidence are unseen."""

    def __post_init__(self):
        for name in ("switch_cost", "cap", "speed", "min_confidence"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"SideSettings: {name} must be a finite number, got {v!r}")
        if self.switch_cost <= 0 or self.cap <= 0 or self.speed < 0:
            raise ValueError(
                "SideSettings: switch_cost and cap must be positive and speed >= 0, got "
                f"{self.switch_cost!r}, {self.cap!r}, {self.speed!r}"
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

    def reset(self) -> None:
        """Forget the person's past (a new track starts)."""
        self._cost = np.zeros((len(self._slots), 2))
        # Per group and labelling: each slot's last seen pixel, whether it was ever seen,
        # and frames since.
        self._px = [np.zeros((2, len(k), 2)) for k in self._slots]
        self._seen = [np.zeros((2, len(k)), bool) for k in self._slots]
        self._age = [np.zeros((2, len(k))) for k in self._slots]

    @property
    def exchanged(self) -> np.ndarray:
        """``bool (groups,)`` the labelling chosen for the last frame, per
        ``settings.groups``."""
        return self._cost[:, 1] < self._cost[:, 0]

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
            and right keypoints and confidences swapped; ``exchanged`` ``bool (groups,)``.
        """
        s = self.settings
        kp = np.asarray(keypoints2d, np.float64).reshape(18, 2)
        conf = np.asarray(confidence, np.float64).reshape(18)
        p3 = np.asarray(points3d, np.float64).reshape(18, 3)
        seen = (conf > s.min_confidence) & np.isfinite(kp).all(axis=-1)
        h3 = np.asarray(has_depth, bool).reshape(18) & np.isfinite(p3).all(axis=-1) & seen
        z_ref = float(np.median(p3[h3, 2])) if h3.any() else 3.0
        m_per_px = z_ref / self.fx
        for g, orders in enumerate(zip(self._slots, self._flipped, strict=True)):
            # What fills the slots under each labelling: (labelling, slot, ...).
            okp, oseen = kp[np.stack(orders)], seen[np.stack(orders)]
            # Jump costs [previous labelling, this labelling, slot].
            d = np.linalg.norm(okp[None] - self._px[g][:, None], axis=-1) * m_per_px
            d = np.maximum(d - s.speed * (self._age[g][:, None] - 1.0), 0.0)
            both = oseen[None] & self._seen[g][:, None]
            step = np.minimum(np.where(both, d, 0.0), s.cap).sum(axis=-1)
            total = self._cost[g][:, None] + step + np.array([0.0, s.switch_cost])[None, :]
            best_prev = total.argmin(axis=0)
            cost = total.min(axis=0)
            if not self._seen[g][0].any():
                # The group's first sighting is read as detected. Without this anchor,
                # "exchanged since the start" is as continuous as "exchanged during the
                # swap", and wins once a swap lasts longer than the track before it.
                cost[1] = _NEVER
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
        labels = flip_labels(np.concatenate([k for k, e in zip(self._slots, ex) if e] or [[]]))
        return np.asarray(keypoints2d)[labels], np.asarray(confidence)[labels], ex
