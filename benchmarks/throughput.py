"""Throughput of many recordings: ``posetrack.track_many`` against one sequence at a time.

Generated sequences (``posetrack.synth``, seeds 300-315, 320x240) are tracked with the shipped
configuration, first one after another (``posetrack.track``, the reference, in the same run:
in chunks of ``RUN_CHUNK`` frames per call as shipped, and frame by frame, ``chunk=1``, what a
loop of ``Tracker.update`` does), then with ``track_many`` at batch sizes B, with each
``--chunks`` value (frames per batched call; 1: one call per frame). Frames per second
exclude compilation: every program is compiled (and reported) by a warm-up run first. Also
reported: the compile seconds of the batched program for that B, the peak memory of the
process, and how far each sequence's D moved against its single (chunked) run.

The command line is measured the same way on a data set of ``--cli`` recordings written to
disk: ``posetrack track`` once per recording (a new process each, the compilation cache warm)
against one ``posetrack track-many --batch 4`` over a manifest of them (cache warm too),
launch to exit, ``--no-video``.

Usage: python benchmarks/throughput.py [--batches 1,4,16] [--modes per-frame,offline]
       [--chunks 16,1] [--sequences 16] [--frames 60] [--cli 8]
       [--out benchmarks/results/throughput.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import posetrack as pt  # noqa: E402
from posetrack import _programs  # noqa: E402
from posetrack.app import machine_info  # noqa: E402


def _d(result, seq) -> float:
    return float(np.nanmean(np.linalg.norm(result.keypoints3d - seq.joints3d, axis=-1)) * 1000)


def _cli_rows(seqs, n: int) -> list[dict]:
    """``posetrack track`` per recording vs one ``posetrack track-many``, warm cache."""
    with tempfile.TemporaryDirectory(prefix="posetrack-throughput-") as tmp:
        root = Path(tmp)
        env = dict(os.environ, PYTHONPATH=str(ROOT), POSETRACK_CACHE_DIR=str(root / "cache"))
        lines = ["name,depth,keypoints,intrinsics"]
        for i, s in enumerate(seqs[:n]):
            pt.synth.save(s, root / f"rec{i}")
            lines.append(f"r{i},rec{i}/depth,rec{i}/keypoints,rec{i}/intrinsics.json")
        (root / "m.csv").write_text("\n".join(lines) + "\n")

        def run(args):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "posetrack", *args, "--no-video", "--quiet"],
                           check=True, env=env, capture_output=True)  # fmt: skip
            return time.perf_counter() - t0

        def track(i, out):
            return run(["track", "--depth", str(root / f"rec{i}" / "depth"), "--keypoints",
                        str(root / f"rec{i}" / "keypoints"), "--intrinsics",
                        str(root / f"rec{i}" / "intrinsics.json"), "--out", str(out)])  # fmt: skip

        def many(out):
            return run(["track-many", "--manifest", str(root / "m.csv"), "--out", str(out),
                        "--batch", "4"])  # fmt: skip

        track(0, root / "warm-track")  # fill the cache for both commands
        many(root / "warm-many")
        t_track = sum(track(i, root / f"t{i}") for i in range(n))
        t_many = many(root / "many")
    frames = sum(len(s.depth) for s in seqs[:n])
    return [
        {"command": "posetrack track, one process per recording", "recordings": n,
         "s": t_track, "fps": frames / t_track},
        {"command": "posetrack track-many --batch 4", "recordings": n, "s": t_many,
         "fps": frames / t_many},
    ]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", default="1,4,16")
    ap.add_argument("--modes", default="per-frame,offline")
    ap.add_argument(
        "--chunks",
        default=f"{pt.RUN_CHUNK},1",
        help="track_many's frames per batched call (1: one call per frame)",
    )
    ap.add_argument("--sequences", type=int, default=16)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--cli", type=int, default=8, help="recordings for the command rows (0: none)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "throughput.json"))
    args = ap.parse_args()
    batches = [int(b) for b in args.batches.split(",")]
    chunks = [int(c) for c in args.chunks.split(",")]
    seqs = [
        pt.synth.generate(300 + i, n_frames=args.frames, width=320, height=240, with_rgb=False)
        for i in range(args.sequences)
    ]
    inputs = [(s.intrinsics, s.depth, s.keypoints2d, s.confidence) for s in seqs]
    n_frames = args.sequences * args.frames
    rows = []
    for mode in [m for m in args.modes.split(",") if m]:
        warm = seqs[0]
        refs = {}  # one at a time: chunked (what pt.track does) and frame by frame (update)
        for chunk in (pt.RUN_CHUNK, 1):
            pt.track(warm.depth, warm.keypoints2d, warm.confidence, warm.intrinsics, mode=mode,
                     chunk=chunk)  # fmt: skip
            t0 = time.perf_counter()
            single = [pt.track(d, k, c, i, mode=mode, chunk=chunk) for i, d, k, c in inputs]
            refs[chunk] = time.perf_counter() - t0
            d = [_d(r, s) for r, s in zip(single, seqs)]
            if chunk == pt.RUN_CHUNK:
                d_single = d
            name = "one at a time" if chunk > 1 else "one at a time, frame by frame"
            rows.append({
                "mode": mode, "B": name, "chunk": chunk, "fps": n_frames / refs[chunk],
                "speedup": refs[pt.RUN_CHUNK] / refs[chunk], "compile_s": None,
                "max_dD_mm": float(np.max(np.abs(np.subtract(d, d_single)))),
                "mean_D_mm": float(np.mean(d)),
            })  # fmt: skip
            print(f"{mode}: {name} {rows[-1]['fps']:.1f} frames/s", flush=True)
        t_single = refs[pt.RUN_CHUNK]
        for chunk in chunks:
            name = "chunk_many" if chunk > 1 and mode != "online" else "step_many"
            for B in batches:
                n_log = len(_programs.log())
                pt.track_many(inputs[:B], batch=B, mode=mode, chunk=chunk)  # compiles for B
                compiled = [e for e in _programs.log()[n_log:] if e.name == name]
                t0 = time.perf_counter()
                many = pt.track_many(inputs, batch=B, mode=mode, chunk=chunk)
                t_many = time.perf_counter() - t0
                d_many = [_d(r, s) for r, s in zip(many, seqs)]
                rows.append({
                    "mode": mode, "B": B, "chunk": chunk, "fps": n_frames / t_many,
                    "speedup": t_single / t_many,
                    "compile_s": round(sum(e.trace_s + e.compile_s for e in compiled), 1),
                    "max_dD_mm": float(np.max(np.abs(np.subtract(d_many, d_single)))),
                    "mean_D_mm": float(np.mean(d_many)),
                })  # fmt: skip
                print(f"{mode}: B={B} chunk {chunk} {rows[-1]['fps']:.1f} frames/s", flush=True)
    cli = _cli_rows(seqs, args.cli) if args.cli else []
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    print(f"\n{args.sequences} sequences x {args.frames} frames, 320x240, shipped MHT_h "
          f"(N = 10); frames/s without compilation; peak memory {peak_mb:.0f} MB")  # fmt: skip
    print(f"{'mode':>10} {'B':>30} {'chunk':>6} {'frames/s':>9} {'x single':>9} {'x by frame':>10} "
          f"{'compile s':>10} {'max |dD| mm':>12} {'mean D mm':>10}")  # fmt: skip
    for r in rows:
        comp = "" if r["compile_s"] is None else f"{r['compile_s']:.1f}"
        by_frame = next(q["fps"] for q in rows if q["mode"] == r["mode"] and q["chunk"] == 1
                        and isinstance(q["B"], str))  # fmt: skip
        r["x_frame_by_frame"] = r["fps"] / by_frame
        print(f"{r['mode']:>10} {str(r['B']):>30} {r['chunk']:>6} {r['fps']:9.1f} "
              f"{r['speedup']:9.2f} {r['x_frame_by_frame']:10.2f} {comp:>10} "
              f"{r['max_dD_mm']:12.2f} {r['mean_D_mm']:10.1f}")  # fmt: skip
    for r in cli:
        print(f"{r['command']}: {r['recordings']} recordings in {r['s']:.1f} s "
              f"({r['fps']:.1f} frames/s), launch to exit, warm cache")  # fmt: skip
    record = {
        "benchmark": "throughput", "sequences": args.sequences, "frames": args.frames,
        "resolution": "320x240", "devices": 1, "peak_rss_MB": round(peak_mb),
        "machine": machine_info(), "rows": rows, "command_line": cli,
    }  # fmt: skip
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
