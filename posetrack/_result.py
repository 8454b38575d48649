"""What a tracked sequence returns: :class:`TrackResult`, its status codes' and joint states'
names, and the per-keypoint confidence written into it."""

from __future__ import annotations

import dataclasses

import numpy as np

from . import _body as body
from ._config import TrackerConfig
from ._step import NO_OBSERVATION, FrameEstimate

#: The frame status codes' names (also the strings written to files).
STATUS_NAMES = ("tracked", "lost", "no_observation")
#: Names of :attr:`TrackResult.joint_state`'s values (also written to ``poses.npz``, whose
#: writer, in io, holds the same tuple: the core never imports io; tests/test_layout.py checks).
JOINT_STATES = ("not_estimated", "predicted", "observed")


@dataclasses.dataclass(frozen=True)
class TrackResult:
    """A tracked sequence (NumPy arrays over frames T)."""

    keypoints3d: np.ndarray
    """(T, 18, 3) metres, camera frame, COCO-18; NaN where not estimated (before the first
    initialisation, and after a track loss until re-initialisation succeeds)."""
    params: np.ndarray
    """(T, 43) pose parameters (never NaN: frames without an estimate repeat the nearest one)."""
    delta: np.ndarray
    """(T,) Delta (Eq. (3)) of the tracker's per-frame pose (offline: before the motion
    model, of the forward pass); NaN where not estimated."""
    status: np.ndarray
    """(T,) int8: 0 tracked, 1 lost, 2 no observation (``STATUS_NAMES``)."""
    confidence: np.ndarray
    """(T, 18) per-keypoint confidence in [0, 1] (see :func:`keypoint_confidence`)."""
    landmarks3d: np.ndarray
    """(T, 18, 3) lifted landmarks O_i (zeros where F_i is false, except the depth bounds of
    ``TrackerConfig(far_side_bound=True)``, :func:`posetrack._observe.as_bounds`)."""
    has_depth: np.ndarray
    """(T, 18) F_i flags."""
    detected: np.ndarray
    """(T, 18) f_i flags."""
    shape: body.BodyShape
    """Body dimensions used."""
    config: TrackerConfig
    """The tracker's configuration."""
    compile_s: float
    """Seconds spent compiling (first calls of the jitted functions)."""
    ms_per_frame: float
    """Median wall time of a steady-state tracker step, milliseconds."""
    person_index: np.ndarray
    """(T,) int: index into each frame's list of people of the detection the tracker followed;
    -1 where none was (nobody detected, or only other people: the frame is then 'lost')."""
    num_people: np.ndarray
    """(T,) int: people detected in each frame (with at least one keypoint)."""
    per_frame_keypoints3d: np.ndarray | None = None
    """(T, 18, 3) the per-frame estimates before the motion model (``None`` when no motion
    model ran: then they are ``keypoints3d``); offline both ways
    (:attr:`SmoothSettings.both_ways`), the forward pass's (the backward pass is fused in
    after smoothing)."""
    exchanged: np.ndarray | None = None
    """(T, groups) bool: where the detector's left and right keypoints of each
    ``sides.groups`` group (default arms, legs) were exchanged back before fitting
    (:class:`SideSettings`); ``None`` when no relabelling ran (``sides=None``; online and
    per-frame by default)."""
    interpolated: np.ndarray | None = None
    """(T, 4) bool, offline only: where the motion model started a limb (right arm, left arm,
    right leg, left leg: :data:`posetrack.LIMB_NAMES`) from its neighbours' pose because
    the per-frame pose had followed a doubtful keypoint jump (:class:`SmoothSettings`
    ``outlier_distance``); a place to look at the detections. ``None`` when no offline
    smoothing ran."""
    floor: np.ndarray | None = None
    """(4,) the first floor plane the tracker found in this recording, ``(nx, ny, nz, d)``
    in the camera frame with ``n @ p + d`` a point's height (metres); ``None`` when none was
    found (or ``use_floor`` is off). :func:`posetrack.floor_frame` builds the world frame on it."""
    mode: str = "per-frame"
    """How ``keypoints3d`` was made: "offline" (smoothed over the whole recording), "online"
    (causal, with a fixed lag) or "per-frame" (each frame on its own, the paper's way)."""
    lag: int = 0
    """Online: the lag, frames (each pose used the frames up to ``lag`` after it); 0
    otherwise."""

    @property
    def others_ignored(self) -> int:
        """Frames in which at least one detected person other than the followed one was
        ignored."""
        return int(np.sum(self.num_people - (self.person_index >= 0) > 0))

    @property
    def status_names(self) -> list[str]:
        return [STATUS_NAMES[s] for s in self.status]

    @property
    def joint_state(self) -> np.ndarray:
        """(T, 18) int8 state of each joint (:data:`JOINT_STATES`), in the spirit of Azure
        Kinect's confidence levels: 0 not estimated (NaN keypoint), 1 predicted (estimated but
        not detected in 2D this frame: placed by the rest of the body, the previous frames and,
        offline, the motion model), 2 observed (detected in 2D this frame, with or without
        depth)."""
        estimated = np.isfinite(self.keypoints3d).all(axis=-1)
        seen = np.asarray(self.detected, bool) & (self.status != NO_OBSERVATION)[:, None]
        return np.where(estimated, np.where(seen, 2, 1), 0).astype(np.int8)


def keypoint_confidence(est: FrameEstimate) -> np.ndarray:
    """Per-keypoint confidence in [0, 1] of one frame's estimate.

    ``support * agreement``: support is 1 for a keypoint whose 3D landmark the selected
    hypothesis used, 0.7 if it was only detected in 2D, 0.3 if it was not observed (the pose
    there is inferred from the rest of the body and the previous frame); agreement is
    ``exp(-(spread / 5 cm)^2)`` with spread the median over all N hypotheses (the selected one
    included) of their keypoint's distance from the selected one (1 for LVM). In frames flagged
    lost, ``Tracker.run`` halves it. It is a relative indicator for weighting and display, not
    a calibrated probability.
    """
    used = np.asarray(est.used3d)[int(est.best)]
    lm = est.landmarks
    support = np.where(used, 1.0, np.where(np.asarray(lm.detected), 0.7, 0.3))
    agreement = np.exp(-((np.asarray(est.spread) / 0.05) ** 2))
    return (support * agreement).astype(np.float32)
