#!/usr/bin/env python
"""Frames judged lost: why, and what the output is worth on the frames two versions share.

Tracks wide clips with the shipped configuration and records, per frame, the status (tracked,
lost, no observation), the followed person's index (-1: the association found nobody), the
best Delta, the agreement the loss test reads, and the per-frame and final errors against the
truth. ``--compare A.jsonl B.jsonl`` pairs two such files (two versions of the code, run one
after the other, e.g. one from a ``git worktree`` of the commit before via ``PYTHONPATH``) and
prints per clip D, coverage and D_pair: the mean per-frame joint error over the frames both
estimate. Written for the loss tests of 2026-11-28 (benchmarks/README.md, "Loss tests that
hold for a far, jittery person"; ``results/loss_tests_*.json``).

Clip kinds: ``real`` (``tune.REAL[seed % 8]``, tuning clips), ``procedural`` (walk, box, reach,
wave, squat, turn, walk_across, idle by ``seed % 8``) and ``report-real`` (accuracy.py's real
clips, ``REAL[seed % len]``, as ``motion.py --motions real``); 120 frames at 30 fps, 320x240,
``variety="wide"``. Tuning kinds take tuning seeds only; ``report-real`` report seeds only (to
report, never to choose).

    python benchmarks/losses.py --kind real --seeds 100-111 --occlusion 2 --out A.jsonl
    PYTHONPATH=/tmp/before python benchmarks/losses.py ... --out B.jsonl   # the version before
    python benchmarks/losses.py --compare B.jsonl A.jsonl --json results/x.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from accuracy import REAL as REPORT_REAL
from seeds import REPORT_SEEDS, TUNING_SEEDS, TUNING_TEXT, parse_seeds
from tune import REAL

import posetrack as pt
from posetrack.app import machine_info

PROCEDURAL = ("walk", "box", "reach", "wave", "squat", "turn", "walk_across", "idle")
KINDS = ("real", "procedural", "report-real")


def clip_motion(seed: int, kind: str) -> str:
    """The motion of clip ``seed`` of ``kind``."""
    table = {"real": REAL, "procedural": PROCEDURAL, "report-real": REPORT_REAL}[kind]
    return table[seed % len(table)]


def frame_agreement(res: pt.TrackResult, distance: float) -> np.ndarray:
    """(T,) the agreement the loss test reads (``posetrack._step.landmark_agreement``, the
    same function), here from the run's per-frame poses and landmarks."""
    import jax

    from posetrack._step import landmark_agreement

    pf = res.keypoints3d if res.per_frame_keypoints3d is None else res.per_frame_keypoints3d
    T = len(pf)
    lms = pt.Landmarks(  # the agreement reads the 3D landmarks and their flags only
        keypoints2d=np.zeros((T, 18, 2), np.float32), confidence=res.detected.astype(np.float32),
        points3d=res.landmarks3d.astype(np.float32), detected=res.detected,
        has_depth=res.has_depth,
    )  # fmt: skip
    agree = jax.vmap(landmark_agreement, in_axes=(0, 0, None))(np.nan_to_num(pf), lms, distance)
    return np.asarray(agree, np.float64)


def track_clip(seed: int, occlusion: int, kind: str, mode: str) -> dict:
    """One clip tracked with the shipped configuration: its per-frame record."""
    motion = clip_motion(seed, kind)
    seq = pt.synth.generate(
        seed, motion=motion, n_frames=120, fps=30.0, occlusion_level=occlusion, width=320,
        height=240, with_rgb=False, variety="wide",
    )  # fmt: skip
    config = pt.TrackerConfig()
    res = pt.Tracker(seq.intrinsics, config, mode=mode).run(
        seq.depth, seq.keypoints2d, seq.confidence
    )
    truth = np.asarray(seq.joints3d)
    pf = res.keypoints3d if res.per_frame_keypoints3d is None else res.per_frame_keypoints3d

    def err(k):  # mm per frame, -1 where not estimated
        return np.nan_to_num(np.linalg.norm(k - truth, axis=-1).mean(-1) * 1000, nan=-1.0)

    acc = pt.accuracy(res.keypoints3d, truth)
    return {
        "seed": seed, "occ": occlusion, "kind": kind, "motion": motion, "mode": mode,
        "D": acc.mean_mm, "coverage": acc.coverage, "status": res.status.tolist(),
        "person": res.person_index.tolist(),
        "delta": np.nan_to_num(res.delta, nan=-1.0).tolist(),
        "agreement": frame_agreement(res, float(config.consensus_distance)).tolist(),
        "err_pf": err(pf).tolist(), "err": err(res.keypoints3d).tolist(),
    }  # fmt: skip


def compare(before: list[dict], after: list[dict]) -> dict:
    """Per clip and on average: D, coverage, lost frames and D_pair, before and after."""
    key = lambda r: (r["seed"], r["occ"], r["kind"], r["mode"])  # noqa: E731
    b = {key(r): r for r in before}
    clips = []
    for r in after:
        if key(r) not in b:
            continue
        a = b[key(r)]
        ea, eb = np.array(a["err"]), np.array(r["err"])
        both = (ea >= 0) & (eb >= 0)
        clips.append({
            "seed": r["seed"], "occlusion": r["occ"], "mode": r["mode"], "motion": r["motion"],
            "D_before": a["D"], "D_after": r["D"], "coverage_before": a["coverage"],
            "coverage_after": r["coverage"],
            "D_pair_before": float(ea[both].mean()), "D_pair_after": float(eb[both].mean()),
            "lost_before": int(np.sum(np.array(a["status"]) == pt.LOST)),
            "lost_after": int(np.sum(np.array(r["status"]) == pt.LOST)),
        })  # fmt: skip
    if not clips:
        raise SystemExit("losses.py --compare: no clip is in both files")
    fields = [k for k in clips[0] if k not in ("seed", "occlusion", "mode", "motion")]
    mean = {f: float(np.mean([c[f] for c in clips])) for f in fields}
    return {"mean": mean, "clips": clips}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kind", choices=KINDS, default="real")
    ap.add_argument("--seeds", default="100-111", help="e.g. 100-111 or 100,104,107")
    ap.add_argument("--occlusion", type=int, default=0)
    ap.add_argument("--mode", choices=("offline", "online"), default="offline")
    ap.add_argument("--out", help="JSON lines, one clip each (appended)")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--json", help="--compare: also write the comparison here")
    a = ap.parse_args()
    if a.compare:
        rows = [[json.loads(line) for line in open(f)] for f in a.compare]
        result = compare(*rows)
        print(f"{'seed':>4s} {'occ':>3s} {'mode':8s} {'motion':22s} {'D':>14s} {'coverage':>12s} "
              f"{'lost':>9s} {'D_pair':>14s}")  # fmt: skip
        for c in result["clips"]:
            print(f"{c['seed']:4d} {c['occlusion']:3d} {c['mode']:8s} {c['motion'][:22]:22s} "
                  f"{c['D_before']:6.1f} -> {c['D_after']:5.1f} {c['coverage_before']:.2f} -> "
                  f"{c['coverage_after']:.2f} {c['lost_before']:3d} -> {c['lost_after']:3d} "
                  f"{c['D_pair_before']:6.1f} -> {c['D_pair_after']:5.1f}")  # fmt: skip
        m = result["mean"]
        print(f"mean over {len(result['clips'])}: D {m['D_before']:.2f} -> {m['D_after']:.2f}, "
              f"coverage {m['coverage_before']:.3f} -> {m['coverage_after']:.3f}, D_pair "
              f"{m['D_pair_before']:.2f} -> {m['D_pair_after']:.2f}")  # fmt: skip
        if a.json:
            result.update(files=a.compare, machine=machine_info())
            Path(a.json).write_text(json.dumps(result, indent=1))
            print(f"wrote {a.json}")
        return 0
    if not a.out:
        ap.error("--out is required (or --compare)")
    seeds = parse_seeds(a.seeds)
    report = a.kind == "report-real"
    allowed = REPORT_SEEDS if report else TUNING_SEEDS
    if not all(s in allowed for s in seeds):
        words = f"{REPORT_SEEDS.start}-{REPORT_SEEDS.stop - 1}" if report else TUNING_TEXT
        ap.error(f"--seeds: --kind {a.kind} takes seeds {words} only")
    t0 = time.perf_counter()
    with open(a.out, "a") as f:
        for seed in seeds:
            r = track_clip(seed, a.occlusion, a.kind, a.mode)
            f.write(json.dumps(r) + "\n")
            f.flush()
            lost = int(np.sum(np.array(r["status"]) == pt.LOST))
            unfound = int(np.sum(np.array(r["person"]) < 0))
            print(f"[{time.perf_counter() - t0:5.0f}s] {seed} {r['motion']} occlusion "
                  f"{a.occlusion} {a.mode}: D {r['D']:.1f} coverage {r['coverage']:.2f} lost "
                  f"{lost} (nobody followed: {unfound})", file=sys.stderr)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
