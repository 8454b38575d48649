#!/usr/bin/env python
"""Motion benchmark: does the tracker's output move like the person? (issue 12)

For each clip (a seed of ``posetrack.synth.generate``, motions cycling through the built-in
ones, each clip at occlusion level 0 and 2) the same recording is tracked by:

* naive lifting (each keypoint at its own depth, held where missing);
* LVM and MHT_h with no motion model (``mode="per-frame"``, the paper's trackers, the
  detector's left/right labels taken as they come);
* MHT_h per-frame + a Gaussian filter over time (sigma = 2 frames): the post-hoc floor;
* MHT_h ``mode="offline"`` (the default of ``posetrack track``): the motion model over the
  whole recording, with the body shape refined against the depth of 8 frames and the
  detector's left/right swaps undone where the depth agrees (the two-sided labelling, each
  exchanged stretch tracked both ways and kept by Delta); the same without any left/right
  relabelling (``sides=None``, ``--no-fix-sides``: "no L/R"); with the two-sided labelling
  taken as read, without the depth's arbitration (``SideSettings(arbitrate=False)``: "L/R
  unarbitrated", the opt-in of 2026-11-25); and with the shape measured between lifted
  keypoints only (``refine=None``, ``--no-refine-shape``: "kp shape");
* MHT_h ``mode="online"`` with lag 3 (``ONLINE_LAG``, the default of ``--online`` since
  2026-11-25: each pose waits for the 3 frames after it) and lag 0 (no delay); causal, the
  body shape refined after 20 tracked frames and again after 60 (since 2026-11-27), the
  detector's left/right swaps undone by the forward labelling with the depth judging each
  exchange over its first lag + 1 frames (the online default since 2026-11-26); lag 3 with
  the landmark-based shape (``refine=None``: "kp shape"), without left/right relabelling
  ("no L/R", ``sides=None``, ``--no-fix-sides``), with the forward labelling taken as read
  ("L/R as read", ``SideSettings(arbitrate=False)``, the opt-in before 2026-11-26) and with
  the shape refined once, after 60 frames ("refined once", the default before 2026-11-27);
  with detections that jumped onto another keypoint fitted as given ("duplicates kept",
  ``duplicates=None``, the default before 2026-11-27 evening); and with only the arms' and
  legs' left/right labels undone, the torso's as detected ("torso as detected",
  ``SideSettings()``, the online default before 2026-11-28 and the offline one before that
  evening).

Columns: D (mm), coverage, C_j(100 mm), acceleration error (mm/frame^2), frames with a
swapped limb pair, the worst clip's D as a multiple of LVM's on the same clip, and on the
``idle`` clips the jitter (mm/frame) against the truth's own. Cost: the offline smoother's and
the online model's time per frame as a ratio to the per-frame step, measured in the same run.

Seeds come from ``REPORT_SEEDS`` (never tuned on; the smoother's defaults were chosen on
seeds 100-103 of ``TUNING_SEEDS``).

    python benchmarks/motion.py --clips 12          # ~15 min on 2 cores
    python benchmarks/motion.py --quick             # 3 clips
    python benchmarks/motion.py --motions real --clips 12   # real motion capture, ~30 min
    python benchmarks/motion.py --online-only ...   # LVM and the online default only
    python benchmarks/motion.py --offline-only ...  # LVM and the offline default only
    python benchmarks/motion.py --refit-only ...    # both defaults, refit after / in the batch
    python benchmarks/motion.py --refit-only --online-only ...  # the online pair only
    python benchmarks/motion.py --facing-only ...   # both defaults, re-init keeping facing too
    python benchmarks/motion.py --neck-only 1 ...   # both defaults, head's turn limited too
    python benchmarks/motion.py --band-only 0.7 ... # both defaults, lifting's depth band too
    python benchmarks/motion.py --model-only 0.1 ...  # LVM, online as shipped and with the pose
                                                    # reading the left/right labels at ties
    python benchmarks/motion.py --far-only 1.0 ...  # LVM, both modes with the far side's
                                                    # unconfident limbs fitted in 2D
    python benchmarks/motion.py --defaults-only ... # LVM and both defaults only
    python benchmarks/motion.py --targets ...       # issue 12's target rows, all as shipped

Rows that pair with an in-batch row also get ``D_pair_mm``: D over the joints and frames both
rows estimate (the in-batch refit gives up on more frames of some wide clips).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from accuracy import REAL  # the reported real-capture clips (tune.py tunes on others)
from facing import neck_config  # the fit's neck limit, as facing.py --neck measures it
from seeds import REPORT_SEEDS

import posetrack as pt
from posetrack.app import machine_summary

MOTIONS = ("walk", "box", "reach", "wave", "squat", "turn", "walk_across", "idle")
LAG = pt.ONLINE_LAG  # the online default (3)
ROWS = (
    "naive lifting", "LVM", "MHT_h per-frame", "MHT_h + Gaussian", "MHT_h offline",
    "MHT_h offline, no L/R", "MHT_h offline, L/R unarbitrated", "MHT_h offline, kp shape",
    f"MHT_h online L={LAG}", "MHT_h online L=0", f"MHT_h online L={LAG}, kp shape",
    f"MHT_h online L={LAG}, no L/R", f"MHT_h online L={LAG}, L/R as read",
    f"MHT_h online L={LAG}, refined once", f"MHT_h online L={LAG}, duplicates kept",
    "MHT_h offline, duplicates kept", f"MHT_h online L={LAG}, torso as detected",
    "MHT_h offline, torso as detected", "MHT_h offline, refit in the batch",
    f"MHT_h online L={LAG}, refit in the batch",
)  # fmt: skip


def _tracked_twice(tracker: pt.Tracker) -> int:
    """Frames the tracker's left/right arbitration tracked a second time (its side_spans)."""
    return sum(stop - start for start, stop, *_ in tracker.side_spans)


#: ``--online-only``: the online default at both lags (and LVM, the reference of "worst"), and
#: at lag 3 the default before 2026-11-28 (the torso's left/right labels as detected).
ONLINE_ROWS = (
    "LVM", f"MHT_h online L={LAG}", "MHT_h online L=0", f"MHT_h online L={LAG}, torso as detected",
)  # fmt: skip


#: ``--offline-only``: LVM, the offline default and the offline default with the torso's
#: left/right labels as detected (arms and legs relabelled only: the default before the
#: evening of 2026-11-28; results/motion_offline_torso*.json, run before, have the row
#: "MHT_h offline, torso relabelled too" beside that default instead).
OFFLINE_ROWS = ("LVM", "MHT_h offline", "MHT_h offline, torso as detected")

#: ``--refit-only``: LVM and both defaults (offline, online at lag 3), each also with the
#: consensus refit inside the batch instead of after the scores
#: (``TrackerConfig(consensus_in_batch=True)``; a candidate default, 2026-11-28).
REFIT_ROWS = (
    "LVM", "MHT_h offline", "MHT_h offline, refit in the batch", f"MHT_h online L={LAG}",
    f"MHT_h online L={LAG}, refit in the batch",
)  # fmt: skip
#: ``--refit-only --online-only``: the online rows of :data:`REFIT_ROWS` (2026-11-28 evening).
REFIT_ONLINE_ROWS = ("LVM", f"MHT_h online L={LAG}", f"MHT_h online L={LAG}, refit in the batch")
#: ``--facing-only``: LVM and both defaults (offline, online at lag 3), each also with a
#: re-initialisation after a loss that keeps the lost track's facing where the detections
#: turned round (``TrackerConfig(reinit_keep_facing=KEEP)``, ``--keep``, default 5; a candidate
#: default, 2026-11-28).
FACING_ROWS = (
    "LVM", "MHT_h offline", "MHT_h offline, facing kept", f"MHT_h online L={LAG}",
    f"MHT_h online L={LAG}, facing kept",
)  # fmt: skip
#: ``--neck-only W``: LVM and both defaults, each also with the fit's soft limit on the head's
#: turn (``ResidualSettings(neck_limit=W)``; a candidate default, 2026-11-28).
NECK_ROWS = (
    "LVM", "MHT_h offline", "MHT_h offline, neck limited", f"MHT_h online L={LAG}",
    f"MHT_h online L={LAG}, neck limited",
)  # fmt: skip
#: ``--band-only M``: LVM and both defaults, each also with the lifting's depth band
#: (``TrackerConfig(lift_band=M)``; a candidate default, 2026-11-28 night).
BAND_ROWS = (
    "LVM", "MHT_h offline", "MHT_h offline, lift band", f"MHT_h online L={LAG}",
    f"MHT_h online L={LAG}, lift band",
)  # fmt: skip
#: ``--model-only TIE``: LVM and the online default, also with its own pose reading the
#: left/right labels where the forward pass is within TIE of a tie
#: (``SideSettings.for_mode("online", online_model=TIE)``; a candidate default of 2026-11-29,
#: stopped by two report sets: opt-in, results/motion_model*.json).
MODEL = ", pose reads ties"
MODEL_ROWS = ("LVM", f"MHT_h online L={LAG}", f"MHT_h online L={LAG}{MODEL}")
#: ``--defaults-only``: LVM and both defaults (offline, online at lag 3), nothing else: the
#: before/after of a change to the defaults themselves, read beside an earlier run's rows
#: (2026-11-28, the loss tests for a far, jittery person).
DEFAULT_ROWS = ("LVM", "MHT_h offline", f"MHT_h online L={LAG}")
#: ``--targets``: the rows issue 12's targets are read from, all as shipped now: naive
#: lifting, LVM, the per-frame MHT_h (no left/right relabelling: the paper's tracker) and its
#: Gaussian filter (the post-hoc floor), and both defaults (2026-11-29).
TARGET_ROWS = (
    "naive lifting", "LVM", "MHT_h per-frame", "MHT_h + Gaussian", "MHT_h offline",
    f"MHT_h online L={LAG}",
)  # fmt: skip
#: ``--far-only R``: LVM and both modes with the confidence gate on the far side's limbs in a
#: side view (``TrackerConfig(depth_confidence_far=R)``; a candidate of 2026-11-29, stopped
#: by two report sets: opt-in, results/motion_far_*.json). The defaults' rows are not run
#: again: the same clips' rows of ``--targets`` (and the offline ones of the smoother's pose
#: weight) are read beside them.
FAR = ", far side gated"
FAR_ROWS = ("LVM", f"MHT_h offline{FAR}", f"MHT_h online L={LAG}{FAR}")
#: Suffix of a row that pairs with the row named without it (``D_pair_mm``).
IN_BATCH = ", refit in the batch"


def report_clips(clips: int, start: int, motions: str) -> list[tuple[int, str]]:
    """``(seed, motion)`` of a report set's clips: ``REPORT_SEEDS[start:start + clips]``, the
    motions cycling through :data:`MOTIONS` (``motions="procedural"``) or accuracy.py's real
    clips present on this machine (``"real"``; ``ValueError`` where none is)."""
    cycle = MOTIONS
    if motions == "real":
        available = set(pt.synth.list_real_motions())
        cycle = tuple(m for m in REAL if m in available)
        if not cycle:
            raise ValueError(
                "--motions real: none of accuracy.py's real clips is present (looked in "
                "$POSETRACK_DATA or ../shared/data; see README, Synthetic data)"
            )
    return [(REPORT_SEEDS[start + i], cycle[(start + i) % len(cycle)]) for i in range(clips)]


def run_clip(
    seed: int,
    motion: str,
    occlusion: int,
    frames: int,
    variety: str,
    online_only: bool = False,
    offline_only: bool = False,
    refit_only: bool = False,
    facing_only: bool = False,
    keep: int = 5,
    neck: float = 0.0,
    defaults_only: bool = False,
    band: float = 0.0,
    targets: bool = False,
    model: float = 0.0,
    far: float = 0.0,
) -> dict:
    """Every row's estimate of one clip (``online_only``: :data:`ONLINE_ROWS`;
    ``offline_only``: :data:`OFFLINE_ROWS`) and the costs measured on it."""
    seq = pt.synth.generate(
        seed, motion=motion, n_frames=frames, fps=30.0, occlusion_level=occlusion,
        width=320, height=240, with_rgb=False, variety=variety,
    )  # fmt: skip
    args = (seq.depth, seq.keypoints2d, seq.confidence)
    out: dict[str, np.ndarray] = {}
    lvm = pt.track(*args, seq.intrinsics, pt.TrackerConfig.recommended("lvm"), mode="per-frame")
    out["LVM"] = lvm.keypoints3d
    if defaults_only:
        res = pt.track(*args, seq.intrinsics)
        out["MHT_h offline"], cost = res.keypoints3d, {"step_ms": res.ms_per_frame}
        out[f"MHT_h online L={LAG}"] = pt.track(*args, seq.intrinsics, mode="online").keypoints3d
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    if model > 0:
        cost = {}
        sides = pt.SideSettings.for_mode("online", online_model=model)
        for suffix, kwargs in (("", {}), (MODEL, {"sides": sides})):
            tr = pt.Tracker(seq.intrinsics, mode="online", **kwargs)
            out[f"MHT_h online L={LAG}{suffix}"] = tr.run(*args).keypoints3d
            cost[f"online_retracked_share{suffix}"] = _tracked_twice(tr) / frames
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    if far > 0:
        config = pt.TrackerConfig(depth_confidence_far=far)
        out[f"MHT_h offline{FAR}"] = pt.track(*args, seq.intrinsics, config).keypoints3d
        out[f"MHT_h online L={LAG}{FAR}"] = pt.track(
            *args, seq.intrinsics, config, mode="online"
        ).keypoints3d
        return {"truth": seq.joints3d, "est": out, "cost": {}}
    if targets:
        _baseline_rows(seq, args, out)
        res = pt.track(*args, seq.intrinsics)
        out["MHT_h offline"], cost = res.keypoints3d, {"step_ms": res.ms_per_frame}
        out[f"MHT_h online L={LAG}"] = pt.track(*args, seq.intrinsics, mode="online").keypoints3d
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    # One candidate beside both defaults: the fit's neck limit, the lifting's depth band, or
    # the facing guard's window.
    candidate = (
        (", neck limited", neck_config(neck)) if neck > 0
        else (", lift band", pt.TrackerConfig(lift_band=band)) if band > 0
        else (", facing kept", pt.TrackerConfig(reinit_keep_facing=keep)) if facing_only
        else None
    )  # fmt: skip
    if candidate is not None:
        suffix, config = candidate
        res = pt.track(*args, seq.intrinsics)
        out["MHT_h offline"], cost = res.keypoints3d, {"step_ms": res.ms_per_frame}
        out["MHT_h offline" + suffix] = pt.track(*args, seq.intrinsics, config).keypoints3d
        out[f"MHT_h online L={LAG}"] = pt.track(*args, seq.intrinsics, mode="online").keypoints3d
        out[f"MHT_h online L={LAG}" + suffix] = pt.track(
            *args, seq.intrinsics, config, mode="online"
        ).keypoints3d
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    # The consensus refit inside the batch (TrackerConfig.consensus_in_batch; opt-in).
    in_batch = pt.TrackerConfig(consensus_in_batch=True)
    if refit_only or not (online_only or offline_only):
        if not (refit_only and online_only):
            out["MHT_h offline, refit in the batch"] = pt.track(
                *args, seq.intrinsics, in_batch
            ).keypoints3d
        out[f"MHT_h online L={LAG}, refit in the batch"] = pt.track(
            *args, seq.intrinsics, in_batch, mode="online"
        ).keypoints3d
    if refit_only:
        cost = {}
        if not online_only:
            res = pt.track(*args, seq.intrinsics)
            out["MHT_h offline"], cost["step_ms"] = res.keypoints3d, res.ms_per_frame
        out[f"MHT_h online L={LAG}"] = pt.track(*args, seq.intrinsics, mode="online").keypoints3d
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    if offline_only:
        cost = _offline_default(seq, args, out, full=False)
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    cost = {} if online_only else _offline_rows(seq, args, out, frames)
    for lag in (LAG, 0):
        on_tr = pt.Tracker(seq.intrinsics, mode="online", lag=lag)
        out[f"MHT_h online L={lag}"] = on_tr.run(*args).keypoints3d
        if lag == LAG:
            cost["online_ms"] = float(np.median(on_tr.motion_times[1:]) * 1000)
            cost["online_step_ms"] = float(np.median(on_tr.step_times) * 1000)
            cost["online_refine_s"] = on_tr.refine_s
            # The online arbitration tracks the first frames of each exchange twice
            # (SideSettings.online_frames: lag + 1 by default).
            cost["online_retracked_share"] = _tracked_twice(on_tr) / frames
    # The torso's left/right labels taken as detected (arms and legs relabelled only: the
    # online default until 2026-11-28).
    out[f"MHT_h online L={LAG}, torso as detected"] = pt.track(
        *args, seq.intrinsics, mode="online", sides=pt.SideSettings()
    ).keypoints3d
    if online_only:
        return {"truth": seq.joints3d, "est": out, "cost": cost}
    # Detections that jumped onto another keypoint fitted as given (the online default until
    # 2026-11-27 evening; duplicates=None).
    out[f"MHT_h online L={LAG}, duplicates kept"] = pt.track(
        *args, seq.intrinsics, mode="online", duplicates=None
    ).keypoints3d
    # The body shape refined once, after 60 tracked frames (the online default until
    # 2026-11-27), instead of after 20 and again after 60.
    once = dataclasses.replace(pt.ShapeFitSettings.tracking("online"), online_first=0)
    out[f"MHT_h online L={LAG}, refined once"] = pt.track(
        *args, seq.intrinsics, mode="online", refine=once
    ).keypoints3d
    out[f"MHT_h online L={LAG}, kp shape"] = pt.track(
        *args, seq.intrinsics, mode="online", refine=None
    ).keypoints3d
    out[f"MHT_h online L={LAG}, no L/R"] = pt.track(
        *args, seq.intrinsics, mode="online", sides=None
    ).keypoints3d
    out[f"MHT_h online L={LAG}, L/R as read"] = pt.track(
        *args, seq.intrinsics, mode="online", sides=pt.SideSettings(arbitrate=False)
    ).keypoints3d
    return {"truth": seq.joints3d, "est": out, "cost": cost}


def _baseline_rows(seq, args, out: dict) -> tuple[pt.Tracker, pt.TrackResult]:
    """The naive lifting, MHT_h per-frame and Gaussian rows into ``out``. The per-frame pass is
    that of an offline run without relabelling (the paper's tracker on the detections as
    they come); that tracker and its result are returned."""
    pts, flags = pt.lift_sequence(*args, seq.intrinsics)
    out["naive lifting"] = pt.naive_lifting(pts, flags)
    tr = pt.Tracker(seq.intrinsics, mode="offline", sides=None)
    off = tr.run(*args)
    out["MHT_h per-frame"] = off.per_frame_keypoints3d
    out["MHT_h + Gaussian"] = pt.gaussian_smoothed(off.per_frame_keypoints3d, 2.0)
    return tr, off


def _offline_rows(seq, args, out: dict, frames: int) -> dict:
    """Naive lifting, the per-frame, Gaussian and offline rows into ``out``; their costs."""
    tr, off = _baseline_rows(seq, args, out)
    out["MHT_h offline, L/R unarbitrated"] = pt.track(
        *args, seq.intrinsics, sides=pt.SideSettings(arbitrate=False)
    ).keypoints3d
    out["MHT_h offline, kp shape"] = pt.track(*args, seq.intrinsics, refine=None).keypoints3d
    out["MHT_h offline, no L/R"] = off.keypoints3d
    cost = _offline_default(seq, args, out)
    cost.update({"step_ms": off.ms_per_frame, "offline_ms": tr.smooth_s * 1000 / frames})
    return cost


def _offline_default(seq, args, out: dict, full: bool = True) -> dict:
    """The offline default's row into ``out``, the row with the torso's left/right labels
    as detected, and (``full``; the default before 2026-11-27's late evening) the row with
    detections on another keypoint fitted as given; the default's costs."""
    frames = len(seq.depth)
    if full:
        out["MHT_h offline, duplicates kept"] = pt.track(
            *args, seq.intrinsics, duplicates=None
        ).keypoints3d
    # The torso's left/right labels as detected (the offline default before 2026-11-28
    # evening; the default now relabels the torso too, as online).
    out["MHT_h offline, torso as detected"] = pt.track(
        *args, seq.intrinsics, sides=pt.SideSettings(groups=("arms", "legs"))
    ).keypoints3d
    lr_tr = pt.Tracker(seq.intrinsics, mode="offline")  # the default
    res = lr_tr.run(*args)
    out["MHT_h offline"] = res.keypoints3d
    return {
        "step_ms": res.ms_per_frame, "offline_ms": lr_tr.smooth_s * 1000 / frames,
        "refine_s": lr_tr.refine_s, "sides_ms": lr_tr.sides_s * 1000 / frames,
        # The default's arbitration tracks each exchanged stretch twice: extra steps per frame.
        "retracked_share": _tracked_twice(lr_tr) / frames,
        "spans": len(lr_tr.side_spans),
        "spans_exchanged": int(sum(s[-1] for s in lr_tr.side_spans)),
        "dropped": lr_tr.duplicates_dropped,
    }  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clips", type=int, default=12)
    ap.add_argument("--start", type=int, default=0, help="index into REPORT_SEEDS")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--quick", action="store_true", help="3 clips")
    ap.add_argument(
        "--variety", choices=("standard", "wide"), default="standard",
        help="posetrack.synth.generate's randomisation (wide: bodies, cameras, sensor and "
        "detector errors the defaults were not tuned on)",
    )  # fmt: skip
    ap.add_argument(
        "--motions", choices=("procedural", "real"), default="procedural",
        help="the built-in motions, or real motion capture retargeted to each generated body "
        "(accuracy.py's reported CMU / MSR Action3D / UTKinect clips, read from ../shared/data "
        "or $POSETRACK_DATA)",
    )  # fmt: skip
    ap.add_argument(
        "--online-only", action="store_true",
        help="LVM and the online default at lags 3 and 0 only (a fifth of the time)",
    )  # fmt: skip
    ap.add_argument(
        "--offline-only", action="store_true",
        help="LVM, the offline default and the offline default with the torso's left/right "
        "labels as detected (arms and legs relabelled only)",
    )  # fmt: skip
    ap.add_argument(
        "--refit-only", action="store_true",
        help="LVM and the offline and online defaults, each also with the consensus refit "
        "inside the batch (TrackerConfig(consensus_in_batch=True)); with --online-only the "
        "online pair only",
    )  # fmt: skip
    ap.add_argument(
        "--facing-only", action="store_true",
        help="LVM and the offline and online defaults, each also with a re-initialisation "
        "that keeps the lost track's facing (TrackerConfig(reinit_keep_facing=KEEP))",
    )  # fmt: skip
    ap.add_argument(
        "--keep", type=int, default=5, metavar="KEEP",
        help="--facing-only: the candidate's reinit_keep_facing (frames after a loss; default 5, "
        "the variant that met its tuning rule on seeds 182-199 / 166-181)",
    )  # fmt: skip
    ap.add_argument(
        "--neck-only", type=float, default=0.0, metavar="W",
        help="LVM and the offline and online defaults, each also with the fit's neck limit at "
        "weight W (ResidualSettings(neck_limit=W))",
    )  # fmt: skip
    ap.add_argument(
        "--band-only", type=float, default=0.0, metavar="M",
        help="LVM and the offline and online defaults, each also with the lifting's depth band "
        "at M metres (TrackerConfig(lift_band=M))",
    )  # fmt: skip
    ap.add_argument(
        "--model-only", type=float, default=0.0, metavar="TIE",
        help="LVM and the online default, also with its own pose reading the left/right labels "
        "where the forward pass is within TIE metres of a tie "
        "(SideSettings.for_mode('online', online_model=TIE))",
    )  # fmt: skip
    ap.add_argument(
        "--far-only", type=float, default=0.0, metavar="R",
        help="LVM and both modes with the confidence gate on the far side's limbs in a side "
        "view (TrackerConfig(depth_confidence_far=R)); the defaults' "
        "rows are those of --targets on the same clips",
    )  # fmt: skip
    ap.add_argument(
        "--defaults-only", action="store_true",
        help="LVM and the offline and online defaults only (a change to the defaults, read "
        "beside an earlier run)",
    )  # fmt: skip
    ap.add_argument(
        "--targets", action="store_true",
        help="the rows issue 12's targets are read from, as shipped: naive lifting, LVM, "
        "MHT_h per-frame and its Gaussian filter, the offline and online defaults",
    )  # fmt: skip
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "motion.json"))
    a = ap.parse_args()
    if a.targets and (
        a.online_only or a.offline_only or a.refit_only or a.facing_only or a.neck_only
        or a.band_only or a.defaults_only
    ):  # fmt: skip
        ap.error("--targets excludes the --*-only options")
    if a.defaults_only and (
        a.online_only or a.offline_only or a.refit_only or a.facing_only or a.neck_only
    ):
        ap.error("--defaults-only excludes the other --*-only options")
    if a.offline_only + a.refit_only > 1 or a.online_only + a.offline_only > 1:
        ap.error("--offline-only excludes --online-only and --refit-only")
    if a.facing_only and (a.online_only or a.offline_only or a.refit_only):
        ap.error("--facing-only excludes --online-only, --offline-only and --refit-only")
    if a.neck_only and (a.online_only or a.offline_only or a.refit_only or a.facing_only):
        ap.error("--neck-only excludes the other --*-only options")
    if a.band_only and (
        a.online_only or a.offline_only or a.refit_only or a.facing_only or a.neck_only
        or a.defaults_only
    ):  # fmt: skip
        ap.error("--band-only excludes the other --*-only options")
    if a.model_only and (
        a.online_only or a.offline_only or a.refit_only or a.facing_only or a.neck_only
        or a.defaults_only or a.band_only or a.targets
    ):  # fmt: skip
        ap.error("--model-only excludes the other --*-only options and --targets")
    if a.far_only and (
        a.online_only or a.offline_only or a.refit_only or a.facing_only or a.neck_only
        or a.defaults_only or a.band_only or a.targets or a.model_only
    ):  # fmt: skip
        ap.error("--far-only excludes the other --*-only options and --targets")
    names = (
        TARGET_ROWS if a.targets else DEFAULT_ROWS if a.defaults_only
        else MODEL_ROWS if a.model_only else FAR_ROWS if a.far_only
        else NECK_ROWS if a.neck_only else BAND_ROWS if a.band_only
        else FACING_ROWS if a.facing_only
        else REFIT_ONLINE_ROWS if a.refit_only and a.online_only else ONLINE_ROWS if a.online_only
        else OFFLINE_ROWS if a.offline_only else REFIT_ROWS if a.refit_only else ROWS
    )  # fmt: skip
    try:
        chosen = report_clips(3 if a.quick else a.clips, a.start, a.motions)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    per_clip = []
    t0 = time.perf_counter()
    for seed, motion in chosen:
        for occ in (0, 2):
            r = run_clip(
                seed, motion, occ, a.frames, a.variety, a.online_only, a.offline_only,
                a.refit_only, a.facing_only, a.keep, a.neck_only, a.defaults_only, a.band_only,
                a.targets, a.model_only, a.far_only,
            )  # fmt: skip
            gt = r["truth"]
            rows = {}
            for name in names:
                est = r["est"][name]
                acc = pt.accuracy(est, gt)
                rows[name] = {
                    "D_mm": acc.mean_mm, "coverage": acc.coverage, "C_100mm": acc.success[100],
                    **pt.motion_metrics(est, gt),
                    "jitter_mm": pt.jitter(est) if motion == "idle" else None,
                }  # fmt: skip
            for name in names:
                if name.endswith(IN_BATCH):
                    # D over the joints and frames both rows of the pair estimate: a row that
                    # gives up on more frames is not credited for leaving out hard ones.
                    base = name[: -len(IN_BATCH)]
                    ea = pt.joint_errors(r["est"][base], gt)
                    eb = pt.joint_errors(r["est"][name], gt)
                    both = np.isfinite(ea) & np.isfinite(eb)
                    for n, e in ((base, ea), (name, eb)):
                        rows[n]["D_pair_mm"] = float(e[both].mean() * 1000) if both.any() else None
            per_clip.append({
                "seed": seed, "motion": motion, "occlusion": occ, "rows": rows,
                "truth_jitter_mm": pt.jitter(gt) if motion == "idle" else None,
                "cost": r["cost"],
            })  # fmt: skip
            print(
                f"[{time.perf_counter() - t0:6.0f}s] seed {seed} {motion:11s} occl {occ}: "
                + "  ".join(
                    f"{n.replace('MHT_h ', '')} {rows[n]['D_mm']:.0f}/{rows[n]['accel_mm']:.0f}"
                    for n in names
                ),
                file=sys.stderr,
                flush=True,
            )
    summary = {}
    for cond, occs in (("clean", (0,)), ("occluded", (2,))):
        clips_c = [c for c in per_clip if c["occlusion"] in occs]
        summary[cond] = {}
        for name in names:
            vals = [c["rows"][name] for c in clips_c]
            ratio = [c["rows"][name]["D_mm"] / c["rows"]["LVM"]["D_mm"] for c in clips_c]
            worst = int(np.argmax([v["D_mm"] for v in vals]))
            jit = [v["jitter_mm"] for v in vals if v["jitter_mm"] is not None]
            summary[cond][name] = {
                "D_mm": float(np.mean([v["D_mm"] for v in vals])),
                "coverage": float(np.mean([v["coverage"] for v in vals])),
                "C_100mm": float(np.mean([v["C_100mm"] for v in vals])),
                "accel_mm": float(np.mean([v["accel_mm"] for v in vals])),
                "swap_frames": int(np.sum([v["swap_frames"] for v in vals])),
                "worst_vs_LVM": float(np.max(ratio)),
                "clips_worse_than_LVM": int(np.sum(np.asarray(ratio) > 1.0)),
                "worst_clip_D_mm": float(vals[worst]["D_mm"]),
                "worst_clip": f"{clips_c[worst]['seed']} {clips_c[worst]['motion']}",
                "jitter_mm": float(np.mean(jit)) if jit else None,
            }
            pair = [v.get("D_pair_mm") for v in vals]
            if pair and all(x is not None for x in pair):
                summary[cond][name]["D_pair_mm"] = float(np.mean(pair))
    costs = [c["cost"] for c in per_clip]
    few_costs = (
        a.refit_only or a.facing_only or a.neck_only or a.defaults_only or a.band_only or a.targets
        or a.model_only or a.far_only
    )  # fmt: skip
    if a.model_only:  # the share of frames the online judge tracked twice, with and without
        cost = {
            f"online_retracked_share_mean{suffix}": float(
                np.mean([c[f"online_retracked_share{suffix}"] for c in costs])
            )
            for suffix in ("", MODEL)
        }
    elif a.offline_only or few_costs:
        cost = {}
    else:
        cost = {
            "online_ms_per_frame": float(np.median([c["online_ms"] for c in costs])),
            "online_step_ms": float(np.median([c["online_step_ms"] for c in costs])),
            "online_retracked_share_mean": float(
                np.mean([c["online_retracked_share"] for c in costs])
            ),
            "online_retracked_share_max": float(
                np.max([c["online_retracked_share"] for c in costs])
            ),
            # Online: the body shape refinement, after 20 and 60 tracked frames (a pause of
            # update()).
            "online_refine_s_median": float(np.median([c["online_refine_s"] for c in costs])),
        }
    if not (a.online_only or few_costs):
        step = float(np.median([c["step_ms"] for c in costs]))
        cost.update({
            "step_ms": step,
            "offline_ms_per_frame": float(np.median([c["offline_ms"] for c in costs])),
            # A clip's smoother time can include a compilation; the smallest is the steady
            # state. benchmarks/speed.py measures both motion models' cost under control.
            "offline_ms_per_frame_min": float(np.min([c["offline_ms"] for c in costs])),
            # The offline left/right pre-pass (both directions), host side.
            "sides_ms_per_frame": float(np.median([c["sides_ms"] for c in costs])),
            # Frames the default's arbitration tracked a second time, as a share of all frames.
            "retracked_share_mean": float(np.mean([c["retracked_share"] for c in costs])),
            "retracked_share_max": float(np.max([c["retracked_share"] for c in costs])),
            "spans": int(np.sum([c["spans"] for c in costs])),
            "spans_exchanged": int(np.sum([c["spans_exchanged"] for c in costs])),
            # Body shape refinement: once per recording (the first clip's includes compilation).
            "refine_s_median": float(np.median([c["refine_s"] for c in costs])),
        })  # fmt: skip
        cost["offline_total_over_step"] = (
            step * (1 + cost["retracked_share_mean"])
            + cost["offline_ms_per_frame"]
            + cost["sides_ms_per_frame"]
        ) / step
    if a.offline_only:
        cost["detections_dropped"] = int(np.sum([c["dropped"] for c in costs]))
    elif not (a.online_only or few_costs):
        cost["online_total_over_step"] = (
            (cost["online_step_ms"] + cost["online_ms_per_frame"])
            * (1 + cost["online_retracked_share_mean"])
            / step
        )
    truth_jit = [c["truth_jitter_mm"] for c in per_clip if c["truth_jitter_mm"] is not None]
    for cond in summary:
        n_c = sum(c["occlusion"] == (0 if cond == "clean" else 2) for c in per_clip)
        print(f"\n{cond} ({n_c} clips)")
        print(f"{'':24s} {'D mm':>6s} {'cover':>6s} {'C100':>6s} {'accel':>6s} {'swaps':>6s} "
              f"{'worst/LVM':>9s} {'worst D':>7s} {'jitter':>6s} {'D pair':>6s}")  # fmt: skip
        for name, v in summary[cond].items():
            jit = "" if v["jitter_mm"] is None else f"{v['jitter_mm']:6.1f}"
            pair = f"{v['D_pair_mm']:6.1f}" if "D_pair_mm" in v else ""
            print(
                f"{name:24s} {v['D_mm']:6.1f} {v['coverage']:6.3f} {v['C_100mm']:6.3f} "
                f"{v['accel_mm']:6.1f} {v['swap_frames']:6d} {v['worst_vs_LVM']:9.2f} "
                f"{v['worst_clip_D_mm']:7.1f} {jit:>6s} {pair:>6s}"
            )
    if truth_jit:
        print(f"\ntruth's own jitter on the idle clips: {np.mean(truth_jit):.1f} mm/frame")
    if a.offline_only:
        print(
            f"\ncost per frame: step {step:.1f} ms; offline smoother "
            f"+{cost['offline_ms_per_frame']:.1f} ms median; left/right pre-pass "
            f"+{cost['sides_ms_per_frame']:.1f} ms, {100 * cost['retracked_share_mean']:.0f} % "
            f"of the frames tracked twice; {cost['detections_dropped']} detections dropped"
        )
    elif a.online_only and not few_costs:
        print(
            f"\ncost per frame: online step {cost['online_step_ms']:.1f} ms, online model "
            f"+{cost['online_ms_per_frame']:.1f} ms, "
            f"{100 * cost['online_retracked_share_mean']:.0f} % of the frames tracked twice; "
            f"body shape refinement {cost['online_refine_s_median']:.1f} s once (median)"
        )
    elif not few_costs:
        print(
            f"\ncost per frame: step {step:.1f} ms; offline smoother "
            f"+{cost['offline_ms_per_frame']:.1f} ms median, {cost['offline_ms_per_frame_min']:.1f}"
            f" ms the least over clips; left/right pre-pass +{cost['sides_ms_per_frame']:.1f} ms, "
            f"{100 * cost['retracked_share_mean']:.0f} % of the frames tracked twice (at most "
            f"{100 * cost['retracked_share_max']:.0f} %; {cost['spans_exchanged']} of "
            f"{cost['spans']} stretches kept exchanged); offline in all "
            f"{cost['offline_total_over_step']:.2f}x the step; online model "
            f"+{cost['online_ms_per_frame']:.1f} ms, "
            f"{100 * cost['online_retracked_share_mean']:.0f} % of the frames tracked twice (at "
            f"most {100 * cost['online_retracked_share_max']:.0f} %; "
            f"{cost['online_total_over_step']:.2f}x the step in all); body shape refinement "
            f"{cost['refine_s_median']:.1f} s per recording (median; online "
            f"{cost['online_refine_s_median']:.1f} s, once)"
        )
    result = {
        "summary": summary, "cost": cost, "clips": per_clip, "frames": a.frames,
        "seeds": [c["seed"] for c in per_clip[::2]], "truth_jitter_mm": truth_jit,
        "variety": a.variety, "motions": a.motions, "online_only": a.online_only,
        "offline_only": a.offline_only, "refit_only": a.refit_only, "facing_only": a.facing_only,
        "keep": a.keep if a.facing_only else None, "neck_only": a.neck_only,
        "band_only": a.band_only, "model_only": a.model_only, "far_only": a.far_only,
        "defaults_only": a.defaults_only, "targets": a.targets,
        "machine": machine_summary(), "wall_s": time.perf_counter() - t0,
    }  # fmt: skip
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=1, default=float))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
