"""Turned round: frames whose estimated body faces more than 90 degrees away from the truth.

A detector that reads a person as facing the other way exchanges every left/right pair at
once (the wide generator's whole-body swaps). A track (re)started on such a frame, or fitted
to such frames for long, turns the model round: every joint off by up to a body width, and a
turned model then fits the exchanged labels best, so it can stay turned for the rest of the
recording. The swapped-limb frames of ``motion.py`` do not see it (the limbs are swapped
relative to a turned torso, i.e. consistent); this counts it directly: the angle, about the
vertical, between the estimated and the true right-to-left shoulder direction.

Tracks wide real-motion tuning clips (``tune.REAL``, ``variety="wide"``, 120 frames at 30 fps,
320x240; motion ``REAL[seed % 8]``) offline and online with the shipped configuration and with
a candidate: ``TrackerConfig(reinit_keep_facing=N)`` (``--keep N``: a re-initialisation within
N frames of a loss keeps the lost track's facing where the detections turned round; 5 is the
default since 2026-11-28, so compare other windows), or the fit's soft limit on the head's
turn (``--neck W``: ``ResidualSettings(neck_limit=W)``), and prints
per configuration and mode the mean D, the turned-round frames, the re-initialisations that
kept the facing, and the clips that differ by more than 1 mm. Tuning seeds only.

    python benchmarks/facing.py --seeds 158-181 --out benchmarks/results/facing.json
    python benchmarks/facing.py --seeds 150-165 --occlusion 2 --part 0 --parts 2 --out A.json
    python benchmarks/facing.py --merge A.json B.json --out benchmarks/results/facing_occluded.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from parts import add_part_arguments, check_part, share
from seeds import TUNING_SEEDS, TUNING_TEXT, parse_seeds
from tune import real_motion

import posetrack as pt
from posetrack.app import machine_info

MODES = ("offline", "online")
#: The configurations compared: the shipped one, and a candidate: ``reinit_keep_facing=keep``
#: (``--keep``), or with ``--neck W`` the soft limit on the head's turn
#: (``ResidualSettings(neck_limit=W)`` in the fit of every hypothesis and the initialisation).
NAMES = ("shipped", "facing kept at re-initialisation")
NECK_NAME = "neck turn limited"


def neck_config(weight: float) -> pt.TrackerConfig:
    """The shipped configuration with the fit's neck limit at ``weight``."""
    fit = pt.TrackerConfig().fit
    return pt.TrackerConfig(
        fit=dataclasses.replace(
            fit, residuals=dataclasses.replace(fit.residuals, neck_limit=weight)
        )
    )


def configs(keep: int, neck: float = 0.0) -> dict[str, pt.TrackerConfig]:
    if neck > 0:
        return {NAMES[0]: pt.TrackerConfig(), NECK_NAME: neck_config(neck)}
    return dict(zip(NAMES, (pt.TrackerConfig(), pt.TrackerConfig(reinit_keep_facing=keep))))


def facing_error_deg(keypoints3d: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T,) degrees between the estimated and the true right-to-left shoulder direction,
    about the camera's vertical axis (the x-z plane); NaN where not estimated."""

    def yaw(k):
        v = k[:, 5] - k[:, 2]
        return np.arctan2(v[:, 2], v[:, 0])

    d = yaw(np.asarray(keypoints3d, float)) - yaw(np.asarray(truth, float))
    return np.degrees(np.abs(np.angle(np.exp(1j * d))))


def track_clip(seed: int, occlusion: int, keep: int = 15, neck: float = 0.0) -> list[dict]:
    """One clip tracked in each mode with each configuration."""
    motion = real_motion(seed)
    seq = pt.synth.generate(
        seed, motion=motion, n_frames=120, fps=30.0, occlusion_level=occlusion, width=320,
        height=240, with_rgb=False, variety="wide",
    )  # fmt: skip
    runs = []
    for mode in MODES:
        for name, config in configs(keep, neck).items():
            tracker = pt.Tracker(seq.intrinsics, config, mode=mode)
            res = tracker.run(seq.depth, seq.keypoints2d, seq.confidence)
            turned = facing_error_deg(res.keypoints3d, seq.joints3d)
            runs.append({
                "seed": seed, "motion": motion, "occlusion": occlusion, "mode": mode,
                "config": name, "D_mm": pt.accuracy(res.keypoints3d, seq.joints3d).mean_mm,
                "turned_frames": int(np.sum(turned > 90)),
                "reinit_flips": tracker.reinit_flips,
            })  # fmt: skip
    return runs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="158-181", help="tuning seeds, e.g. 158-181")
    ap.add_argument("--occlusion", type=int, default=0)
    add_part_arguments(ap)
    ap.add_argument(
        "--keep", type=int, default=15, help="reinit_keep_facing of the second configuration"
    )
    ap.add_argument(
        "--neck",
        type=float,
        default=0.0,
        help="candidate: the fit's neck limit at this weight (instead of --keep)",
    )
    ap.add_argument("--merge", nargs="*", default=None, help="JSON files of parts to merge")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "facing.json"))
    a = ap.parse_args()
    check_part(ap, a)
    if a.merge:
        runs = [r for f in a.merge for r in json.loads(Path(f).read_text())["runs"]]
    else:
        seeds = parse_seeds(a.seeds)
        if not all(s in TUNING_SEEDS for s in seeds):
            ap.error(f"--seeds: tuning seeds only ({TUNING_TEXT})")
        runs, t0 = [], time.perf_counter()
        for seed in share(seeds, a):
            for run in track_clip(seed, a.occlusion, a.keep, a.neck):
                runs.append(run)
                print(f"[{time.perf_counter() - t0:5.0f}s] {json.dumps(run)}", file=sys.stderr)
    table = {}
    ref = {
        (r["seed"], r["occlusion"], r["mode"]): r["D_mm"] for r in runs if r["config"] == "shipped"
    }
    print(f"\n{'mode':8s} {'configuration':38s} {'clips':>5s} {'D mm':>6s} {'turned':>6s} "
          f"{'flips':>5s}  clips > 1 mm off the shipped one")  # fmt: skip
    for mode in MODES:
        for name in (*NAMES, NECK_NAME):
            rs = [r for r in runs if r["mode"] == mode and r["config"] == name]
            if not rs:
                continue
            off = [
                f"{r['seed']} {r['D_mm']:.1f} ({ref[k]:.1f})" for r in rs
                if (k := (r["seed"], r["occlusion"], mode)) in ref and abs(r["D_mm"] - ref[k]) > 1
            ]  # fmt: skip
            row = table.setdefault(mode, {})[name] = {
                "clips": len(rs), "D_mm": float(np.mean([r["D_mm"] for r in rs])),
                "turned_frames": int(sum(r["turned_frames"] for r in rs)),
                "reinit_flips": int(sum(r["reinit_flips"] for r in rs)), "differ": off,
            }  # fmt: skip
            print(f"{mode:8s} {name:38s} {row['clips']:5d} {row['D_mm']:6.1f} "
                  f"{row['turned_frames']:6d} {row['reinit_flips']:5d}  "
                  f"{', '.join(off)}")  # fmt: skip
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps({
        "benchmark": "facing", "keep": a.keep, "neck": a.neck, "table": table, "runs": runs,
        "machine": machine_info(),
    }, indent=1))  # fmt: skip
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
