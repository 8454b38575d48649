"""How long one ``Tracker.update`` takes online, frame by frame, with the body-shape
refinements run whole (``ShapeFitSettings.online_spread=0``, the default) or a part at each
update (``online_spread=S``).

A live camera delivers a frame every 33 ms at 30 fps. Online, the tracker refines the body
shape after 20 and after 60 tracked frames; run whole, each refinement makes one ``update``
last seconds on a CPU, and the camera's frames meanwhile queue or are dropped. This tracks one
synthetic clip (a tuning seed) frame by frame for each S, after a warm-up run of the same S (so
compilation is not counted: the tracker prepares its programs ahead, see README "Start-up"),
and prints per S: the median and 95th-percentile update, the longest update and its frame,
how many updates took longer than 100 ms, the total, and the refinement's own seconds.
Measured in one process, the settings one after another: compare rows of one run.

    python benchmarks/online_pause.py OUT.json [--spreads 0,10,25,50] [--seed 2419]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np

import posetrack as pt
from posetrack.app import machine_info
from posetrack.io import atomic_write_text


def track(seq, spread: int) -> dict:
    refine = dataclasses.replace(pt.ShapeFitSettings.tracking("online"), online_spread=spread)
    tracker = pt.Tracker(seq.intrinsics, mode="online", refine=refine)
    times, shapes = [], []
    for t in range(len(seq.depth)):
        t0 = time.perf_counter()
        tracker.update(seq.depth[t], seq.keypoints2d[t], seq.confidence[t])
        times.append(time.perf_counter() - t0)
        shapes.append(tracker.shape.to_dict())
    ms = np.asarray(times) * 1000.0
    taken_up = [t for t in range(1, len(shapes)) if shapes[t] != shapes[t - 1]]
    return {
        "spread": spread,
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "max_frame": int(ms.argmax()),
        "over_100ms": int((ms > 100.0).sum()),
        "total_s": float(ms.sum() / 1000.0),
        "refine_s": float(tracker.refine_s),
        "shape_changed_at": taken_up,
        "update_ms": [round(float(v), 2) for v in ms],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="JSON written (atomically)")
    ap.add_argument("--spreads", default="0,10,25,50")
    ap.add_argument("--seed", type=int, default=2419, help="tuning seed of the clip")
    ap.add_argument("--frames", type=int, default=120)
    args = ap.parse_args()
    try:
        spreads = [int(s) for s in args.spreads.split(",")]
        if any(s < 0 for s in spreads):
            raise ValueError("must be >= 0")
    except ValueError as e:
        print(f"error: --spreads {args.spreads!r}: {e}", file=sys.stderr)
        return 2
    pt.enable_cache()
    seq = pt.synth.generate(args.seed, motion="walk", n_frames=args.frames, width=320, height=240)
    info = machine_info()
    print(f"machine: {info['cpu']}, {info['cores']} cores, jax {info['jax']} ({info['backend']})")
    print(f"clip: synth walk, tuning seed {args.seed}, {args.frames} frames, 320x240, online lag 3")
    rows = []
    head = (
        f"{'spread':>6} {'median ms':>9} {'p95 ms':>7} {'max ms':>7} {'at':>4} {'>100ms':>6} "
        f"{'total s':>7} {'refine s':>8}  shape taken up at"
    )
    print(head + "\n" + "-" * len(head))
    for spread in spreads:
        track(seq, spread)  # warm-up: the programs compiled or loaded
        r = track(seq, spread)
        rows.append(r)
        print(
            f"{spread:>6} {r['median_ms']:>9.1f} {r['p95_ms']:>7.1f} {r['max_ms']:>7.0f} "
            f"{r['max_frame']:>4} {r['over_100ms']:>6} {r['total_s']:>7.2f} {r['refine_s']:>8.2f}"
            f"  {r['shape_changed_at']}",
            flush=True,
        )
    record = {
        "what": "Tracker.update wall time online, per frame, by ShapeFitSettings.online_spread",
        "machine": info,
        "seed": args.seed,
        "frames": args.frames,
        "rows": rows,
    }
    atomic_write_text(args.out, json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
