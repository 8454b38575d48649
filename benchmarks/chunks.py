"""What running frames as a ``lax.scan`` over chunks would buy (issue 13, item 2): a probe.

Today every frame is one jitted call of the tracker step from Python, and ``Tracker`` waits for
its result (the host decides track loss, re-initialisation, the followed person, from each
frame's Delta and landmark counts). A chunk of C frames inside one ``lax.scan`` pays the
dispatch, the argument transfer and the wait once per chunk instead of once per frame, but the
host can then only act between chunks (a lost track would be rewound to the frame it was lost).

This script measures the ceiling of that change on one recording, before building it: the
shipped configuration's step (exactly ``tracker_step``) run over a generated clip
(``posetrack.synth``, throughput seed 300, 320x240)

- **per frame, waiting**: one call per frame, the result waited for (what ``Tracker`` does);
- **per frame, queued**: one call per frame, waited for only at the end (JAX's asynchronous
  dispatch; not possible with a host decision per frame);
- **scan, C frames**: ``lax.scan`` of the same step over chunks of C frames, one call and one
  wait per chunk (C = 1 is the scan's own overhead);

all starting from the same initialised state, and reports ms per frame (the fastest of
``--repeats`` passes over the clip, compilation excluded and reported apart), the ratio to
"per frame, waiting", and how far the poses moved from it (max over frames and keypoints, mm;
the scan is a different program, so float rounding may change a hypothesis' Delta). The whole
``Tracker.run`` (host logic included) is timed in the same run, per-frame and offline, with one
step call per frame (``chunk=1``) and with the shipped chunks (``posetrack.RUN_CHUNK``), as a
user sees it; "moved" is then against ``chunk=1`` (0: the same poses).

Usage: python benchmarks/chunks.py [--frames 120] [--chunks 1,8,30,120] [--repeats 3]
       [--out benchmarks/results/chunks.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import posetrack as pt  # noqa: E402
from posetrack._inputs import check_depth  # noqa: E402
from posetrack._tracker import step  # noqa: E402
from posetrack.app import machine_info  # noqa: E402


def _scan_chunk(config, shape, intrinsics, floor, state, depths, kps, confs):
    """``tracker_step`` over the frames of a chunk: one program, one call."""

    def body(st, frame):
        st, est = pt.tracker_step(config, shape, intrinsics, floor, st, *frame)
        return st, (est.keypoints3d, est.delta, est.agreement, est.num_3d)

    return jax.lax.scan(body, state, (depths, kps, confs))


scan_chunk = jax.jit(_scan_chunk)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--chunks", default="1,8,30,120", help="chunk sizes C (frames per call)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes; the fastest is kept")
    ap.add_argument("--seed", type=int, default=300)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "chunks.json"))
    args = ap.parse_args(argv)
    chunks = [int(c) for c in args.chunks.split(",")]
    T = args.frames
    if any(c < 1 or T % c for c in chunks):
        ap.error(f"--chunks: every C must divide --frames {T}, got {chunks}")

    seq = pt.synth.generate(args.seed, motion="walk", n_frames=T, fps=30.0, width=320,
                            height=240, with_rgb=False)  # fmt: skip
    tr = pt.Tracker(seq.intrinsics, mode="per-frame")
    depth = np.stack([check_depth(tr.intrinsics, d, tr.depth_scale, "chunks") for d in seq.depth])
    kp = np.asarray(seq.keypoints2d, np.float32)
    conf = np.asarray(seq.confidence, np.float32)

    if not tr.initialize(seq.depth[0], seq.keypoints2d[0], seq.confidence[0]):
        raise SystemExit("chunks.py: the first frame did not initialise the track")
    cfg, shape, intr, floor, state0 = tr.config, tr.shape, tr.intrinsics, tr.floor, tr.state

    def per_frame(wait: bool):
        st, out = state0, []
        for t in range(T):
            st, est = step(cfg, shape, intr, floor, st, depth[t], kp[t], conf[t])
            if wait:
                jax.block_until_ready(est)
            out.append(est.keypoints3d)
        return np.asarray(jax.block_until_ready(jax.numpy.stack(out)))

    def scanned(c: int):
        st, out = state0, []
        for s in range(0, T, c):
            st, (k3, delta, agree, n3) = scan_chunk(
                cfg, shape, intr, floor, st, depth[s : s + c], kp[s : s + c], conf[s : s + c]
            )
            # The host would decide here (loss, re-initialisation), once per chunk.
            jax.block_until_ready((k3, delta, agree, n3))
            out.append(np.asarray(k3))
        return np.concatenate(out)

    def timed(fn):
        t0 = time.perf_counter()
        fn()  # compiles (or loads) on the first call
        compile_s = time.perf_counter() - t0
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = fn()
            best = min(best, time.perf_counter() - t0)
        return res, 1000 * best / T, compile_s

    rows = []
    ref, ms_ref, c_ref = timed(lambda: per_frame(True))
    rows.append({"path": "per frame, waiting", "C": 1, "ms_per_frame": ms_ref,
                 "compile_or_first_pass_s": c_ref, "max_pose_change_mm": 0.0})  # fmt: skip
    for name, fn, c in [("per frame, queued", lambda: per_frame(False), 1)] + [
        (f"scan, {c} frames", (lambda c=c: scanned(c)), c) for c in chunks
    ]:
        res, ms, comp = timed(fn)
        moved = float(np.nanmax(np.linalg.norm(res - ref, axis=-1)) * 1000)
        rows.append({"path": name, "C": c, "ms_per_frame": ms, "compile_or_first_pass_s": comp,
                     "max_pose_change_mm": moved})  # fmt: skip
    # The whole public call (its own initialisation and host logic included; the same body
    # shape, so no shape estimation), one step call per frame (chunk=1) against the shipped
    # chunked run (Tracker.chunk: the host prepares the next chunk while one computes),
    # alternating, per-frame and offline modes (offline adds the left/right pre-pass, the
    # body-shape refinement and the motion model, which chunks do not change).
    runs = [(m, c) for m in ("per-frame", "offline") for c in (1, pt.RUN_CHUNK)]
    best = dict.fromkeys(runs, np.inf)
    poses = {}
    for i in range(args.repeats + 1):
        for mode, c in runs:
            user = pt.Tracker(seq.intrinsics, mode=mode, chunk=c)
            user.shape = shape
            t0 = time.perf_counter()
            poses[mode, c] = user.run(seq.depth, seq.keypoints2d, seq.confidence).keypoints3d
            if i:  # the first pass compiles what the probe did not (lifting, initial fit, ...)
                best[mode, c] = min(best[mode, c], time.perf_counter() - t0)
    for mode, c in runs:
        moved = float(np.nanmax(np.linalg.norm(poses[mode, c] - poses[mode, 1], axis=-1)) * 1000)
        rows.append({"path": f"Tracker.run ({mode} mode, chunk {c})", "C": c,
                     "ms_per_frame": 1000 * best[mode, c] / T, "compile_or_first_pass_s": None,
                     "max_pose_change_mm": moved})  # fmt: skip

    print(f"chunks.py: seed {args.seed}, {T} frames 320x240, shipped MHT_h N = {cfg.n}, "
          f"{jax.default_backend()}")  # fmt: skip
    print(f"{'path':30s} {'ms/frame':>9s} {'x waiting':>9s} {'first s':>8s} {'moved mm':>9s}")
    for r in rows:
        r["speedup_vs_waiting"] = ms_ref / r["ms_per_frame"]
        first = (
            "" if r["compile_or_first_pass_s"] is None else f"{r['compile_or_first_pass_s']:.1f}"
        )
        moved = "" if r["max_pose_change_mm"] is None else f"{r['max_pose_change_mm']:.2f}"
        print(f"{r['path']:30s} {r['ms_per_frame']:9.2f} {r['speedup_vs_waiting']:9.2f} "
              f"{first:>8s} {moved:>9s}")  # fmt: skip
    out = {"seed": args.seed, "frames": T, "n": cfg.n, "rows": rows, "machine": machine_info()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
