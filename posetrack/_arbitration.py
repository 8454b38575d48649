"""A stretch judged online by the depth (:attr:`SideSettings.arbitrate` under
``mode="online"``): its readings (the detections' labels, and each exchange of left/right
groups) tracked from the same state, and which of them leads.

The tracker (:meth:`~posetrack.Tracker.update`) owns the tracking and its snapshots; this
module holds what one judgement keeps between frames and the rule that reads it
(:func:`~posetrack._sides.prefer_exchanged` on the Delta summed over the judged frames)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._sides import SideSettings, prefer_exchanged
from ._step import NO_OBSERVATION, FrameEstimate


def frame_delta(est: FrameEstimate | None, status: int) -> float:
    """The Delta of a frame's pose (NaN where the frame has none), as the arbitration sums."""
    return float(est.delta) if est is not None and status != NO_OBSERVATION else float("nan")


@dataclasses.dataclass
class Branch:
    """One reading of a stretch under online arbitration: the tracker's state after its
    newest frame and, per judged frame, what :meth:`Tracker.update` returned for it."""

    snapshot: tuple
    rows: list
    """Per judged frame, ``(out, exchanged, person)`` as this reading saw it (:meth:`Tracker.run`
    records the kept reading's)."""

    @property
    def out(self) -> tuple:
        """What :meth:`Tracker.update` returned for the newest frame."""
        return self.rows[-1][0]

    @property
    def deltas(self) -> list[float]:
        """Each judged frame's Delta (NaN where it has none)."""
        return [frame_delta(*row[0]) for row in self.rows]


@dataclasses.dataclass
class Reading:
    """One exchanged reading of a stretch judged online: which groups it exchanges, its
    branch, and in how many judged frames its forward pass still read one of them exchanged
    (the first one did)."""

    groups: np.ndarray
    branch: Branch
    held: int = 1


@dataclasses.dataclass
class OnlineArbitration:
    """A stretch tracked both ways online (:meth:`Tracker._update_arbitrated`)."""

    left: int
    readings: list[Reading]
    """Every newly read group's exchange together first; with
    :attr:`SideSettings.online_groups`, where several were read together, then each one's
    alone."""
    detected: Branch | None = None

    @property
    def groups(self) -> np.ndarray:
        """``bool (groups,)``: the groups being judged."""
        return self.readings[0].groups

    @property
    def exchanged(self) -> Branch:
        """The branch with every judged group exchanged."""
        return self.readings[0].branch

    def leading(self, sides: SideSettings) -> tuple[np.ndarray | None, Branch]:
        """``(groups exchanged, branch)`` of the reading that leads: of the exchanged
        readings that held long enough and beat the detections (:func:`prefer_exchanged`),
        the one whose Delta summed is lowest; else ``(None, the detections' branch)``."""
        # Until an exchanged reading has held long enough the detections' labels lead (the
        # leading reading's frames enter the poses published meanwhile); a stretch shorter
        # than online_min_held frames needs all of them.
        frames = len(self.exchanged.rows) + self.left
        best, best_sum = (None, self.detected), np.inf
        for r in self.readings:
            if r.held < min(sides.online_min_held, frames):
                continue
            deltas = np.array(r.branch.deltas)
            wins = prefer_exchanged(np.array(self.detected.deltas), deltas, sides.arbitrate_margin)
            if wins and np.nansum(deltas) < best_sum:
                best, best_sum = (r.groups, r.branch), float(np.nansum(deltas))
        return best

    def report(self, frames_seen: int, kept: Branch) -> tuple[int, int, float, float, bool]:
        """A :attr:`Tracker.side_spans` entry; its exchanged Delta is the kept reading's, or
        where the detections' was kept, every group's exchange together."""
        n = len(self.exchanged.deltas)
        ex = self.exchanged if kept is self.detected else kept
        return (
            frames_seen - n, frames_seen, float(np.nansum(self.detected.deltas)),
            float(np.nansum(ex.deltas)), kept is not self.detected,
        )  # fmt: skip
