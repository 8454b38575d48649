"""Detections that jumped onto another keypoint: dropped before the fit (host side).

A 2D detector sometimes reports a keypoint on top of another one: an ankle on the neck, a
wrist on the other wrist, for several frames, with an ordinary confidence (part-affinity
detectors assign a heat-map peak to the wrong part). Fitted as given, the model folds the
limb to reach it: on a wide tuning clip (seed 154, UTKinect "carry", clean) a left ankle
reported on the neck for 15 frames bent the shank up and put the model's ankle 1.2-1.5 m from
the true one, online and per-frame, while MHT_h's temporal weights, which only lower a
landmark's chance of being drawn, let it into enough hypotheses for one to win.

Two detections of different keypoints at one spot are not an error by themselves (a hand at
the face, the shoulders of a person seen from the side). What gives the error away is how
it got there: the wrong keypoint *jumped* onto the other one, from where it was last seen,
while the other stayed put. So, per frame, for the followed person's keypoints:

* two detections closer than :attr:`DuplicateSettings.radius` (metres at the person's
  depth, converted with the focal length as the left/right labelling does) are coincident;
* a keypoint has *jumped* if it lies more than :attr:`DuplicateSettings.jump` from where it
  was last kept, less what it may have moved meanwhile (:attr:`DuplicateSettings.speed` per
  frame since);
* of a coincident pair, the one that jumped is dropped (confidence 0) when the other did not;
  once dropped, it stays dropped while it is still that far from where it was last kept (a
  keypoint stuck on another one moves with it, sometimes a few pixels apart), so an episode
  of many frames is dropped whole. Where both or neither jumped, both stay.

A dropped keypoint is only withheld: the MHT fits without it (a missing detection is
routine) and the body's other keypoints carry the frame. Keypoints moving together (a hand
brought to the face) do not jump and are never dropped.

Measured on tuning clips (seeds 136-157, standard and wide, clean and occluded, against the
generator's truth): 548 keypoint-frames dropped of 86,400, 408 of them more than 15 px from
the true keypoint; the decision on the tracker's D is in benchmarks/README.md.

NumPy, not JAX: eighteen points per frame, each frame depending on the last, beside the
left/right labelling (:mod:`posetrack._sides`), which it runs before.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._sides import metres_per_pixel


@dataclasses.dataclass(frozen=True)
class DuplicateSettings:
    """Dropping detections that jumped onto another keypoint (:class:`DuplicateFilter`)."""

    radius: float = 0.08
    """Two detections closer than this (m, at the person's depth) are coincident. A keypoint
    stuck on another one keeps its own detection noise: at 3.5 m and 320 px wide, 2-10 px
    apart (0.03-0.12 m); at 0.05 the filter lost such an episode after 6 of its 15 frames."""
    jump: float = 0.25
    """A keypoint more than this (m) from where it was last kept, beyond ``speed`` per frame
    since, has jumped (7.5 m/s at 30 fps: faster than a limb moves)."""
    speed: float = 0.05
    """How far (m per frame) a keypoint may have moved since it was last kept."""
    min_confidence: float = 0.1
    """Keypoints at or below this confidence are not detections."""
    settle: int = 1
    """Frames in a row a keypoint must be kept near a spot it jumped to before that spot
    becomes where it was last kept (the reference of the next jumps). With 1 (the default),
    a one-frame outlier that landed on no other keypoint becomes the reference at once, and
    the keypoint's return to its true place is a jump: beside another keypoint (a nose back
    beside the ears, a wrist back at the hip) it is dropped until ``speed`` allows the
    distance (10-15 frames after a 1 m outlier). 5 withholds fewer good detections and more
    bad ones (tuning clips: dropped within 15 px of the truth 145 -> 104, further off 391 ->
    455) but did not track better offline (benchmarks/README.md): not the default."""

    def __post_init__(self):
        if isinstance(self.settle, bool) or not isinstance(self.settle, int) or self.settle < 1:
            raise ValueError(
                f"DuplicateSettings: settle must be an int >= 1 (frames), got {self.settle!r}"
            )
        for name in ("radius", "jump", "speed", "min_confidence"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"DuplicateSettings: {name} must be a finite number, got {v!r}")
        if self.radius <= 0 or self.jump <= 0 or self.speed < 0:
            raise ValueError(
                "DuplicateSettings: radius and jump must be positive and speed >= 0, got "
                f"radius={self.radius!r}, jump={self.jump!r}, speed={self.speed!r}"
            )
        if not 0 <= self.min_confidence < 1:
            raise ValueError(
                f"DuplicateSettings: min_confidence must be in [0, 1), got {self.min_confidence!r}"
            )


class DuplicateFilter:
    """The causal pass over one followed person's frames (see the module docstring).

    Example::

        dup = DuplicateFilter(fx=intrinsics.fx)
        for kp2d, conf, points3d, has_depth in frames:
            conf, dropped = dup.update(kp2d, conf, points3d, has_depth)
    """

    def __init__(self, fx: float, settings: DuplicateSettings = DuplicateSettings()):
        if not isinstance(settings, DuplicateSettings):
            raise TypeError(
                f"DuplicateFilter: settings must be DuplicateSettings, got {type(settings)}"
            )
        if not (np.isfinite(fx) and fx > 0):
            raise ValueError(f"DuplicateFilter: fx must be a positive focal length, got {fx!r}")
        self.settings = settings
        self.fx = float(fx)
        self.dropped_count = 0
        """Keypoint-frames dropped since the filter was made (resets do not clear it)."""
        self.reset()

    def reset(self) -> None:
        """Forget where the keypoints were (a new track or person starts)."""
        self._px = np.zeros((18, 2))  # where each keypoint was last kept (settled), pixels
        self._seen = np.zeros(18, bool)  # ever kept
        self._age = np.zeros(18)  # frames since _px was set
        self._dropped = np.zeros(18, bool)  # dropped in the last frame
        self._spot = np.zeros((18, 2))  # a kept jump's spot, not yet settled
        self._held = np.zeros(18, np.int64)  # frames in a row kept near _spot (0: none)

    def update(
        self,
        keypoints2d: np.ndarray,
        confidence: np.ndarray,
        points3d: np.ndarray,
        has_depth: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Take one frame of the followed person (the arguments of
        :meth:`~posetrack.SideLabeller.update`: ``(18, 2)`` pixels, ``(18,)`` confidences,
        and the plainly lifted ``(18, 3)`` points with their ``(18,)`` flags, whose median
        depth turns pixels into metres).

        Returns:
            ``(confidence, dropped)``: a copy of ``confidence`` with the dropped keypoints' set
            to 0, and ``bool (18,)`` which were dropped.
        """
        s = self.settings
        kp = np.asarray(keypoints2d, np.float64).reshape(18, 2)
        conf = np.asarray(confidence).reshape(18)
        p3 = np.asarray(points3d, np.float64).reshape(18, 3)
        seen = (conf > s.min_confidence) & np.isfinite(kp).all(axis=-1)
        m_per_px = metres_per_pixel(p3, has_depth, seen, self.fx)
        apart = np.linalg.norm(kp[:, None] - kp[None], axis=-1) * m_per_px
        coincident = (apart < s.radius) & seen[:, None] & seen[None, :] & ~np.eye(18, dtype=bool)
        moved = np.linalg.norm(kp - self._px, axis=-1) * m_per_px - s.speed * (self._age - 1.0)
        jumped = seen & self._seen & (moved > s.jump)
        drop = (coincident & jumped[:, None] & ~jumped[None, :]).any(axis=1)
        drop |= self._dropped & jumped  # an episode goes on while it stays away
        keep = seen & ~drop
        # A kept jump is where the keypoint is only once it has held there ``settle`` frames
        # in a row; until then the jumps of the next frames are measured from before it.
        trial = keep & jumped
        near = np.linalg.norm(kp - self._spot, axis=-1) * m_per_px < s.jump
        self._held = np.where(trial, np.where(near & (self._held > 0), self._held + 1, 1), 0)
        self._spot = np.where(trial[:, None], kp, self._spot)
        settled = keep & (~jumped | (self._held >= s.settle))
        self._px = np.where(settled[:, None], kp, self._px)
        self._seen |= keep
        self._age = np.where(settled, 1.0, self._age + 1.0)
        self._dropped = drop
        self.dropped_count += int(drop.sum())
        return np.where(drop, np.zeros_like(conf), conf), drop
