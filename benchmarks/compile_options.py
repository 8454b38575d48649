"""What XLA's CPU options trade between the tracker step's compilation and its speed.

A cold start waits for the step's compilation (README, Start-up time), so options that
compile faster are tempting; this measures what they cost a frame. One process: a short
generated clip (seed 7, 64 frames, 320x240, occlusion level 1) is tracked per frame to catch
a real input of the chunked step (``posetrack._chunk.track_chunk``, 16 frames, the shipped
configuration: its third call, a tracked state), the step is lowered once and compiled with
each option set, and then every compiled version runs that call ``--reps`` times, the
versions alternating (a shared machine's speed drifts). Reported per option set: compile
seconds, median and minimum ms a call of 16 frames, the median's ratio to the shipped
options', and whether the outputs equal the shipped ones bit for bit.

Option sets: ``shipped`` (``posetrack._programs.CPU_OPTIONS``: LLVM -O1), ``older_emitters``
(``CPU_OPTIONS_RARE``: XLA's older loop emitters, what the set-up programs and the online
model use) and ``O0`` (LLVM -O0).

Usage: python benchmarks/compile_options.py [--reps 60]
       [--out benchmarks/results/compile_options.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402

import posetrack as pt  # noqa: E402
from posetrack import _programs, _tracker  # noqa: E402
from posetrack._chunk import track_chunk  # noqa: E402
from posetrack.app import machine_info  # noqa: E402

OPTIONS = {
    "shipped": dict(_programs.CPU_OPTIONS),
    "older_emitters": dict(_programs.CPU_OPTIONS_RARE),
    "O0": {**_programs.CPU_OPTIONS, "xla_backend_optimization_level": 0},
}


def captured_call() -> tuple:
    """The arguments of the third chunked step of a per-frame run (host copies)."""
    calls: list = []
    real = _tracker.step_chunk

    def spy(*args):
        out = real(*args)
        calls.append(jax.tree.map(lambda x: np.asarray(x) if isinstance(x, jax.Array) else x, args))
        return out

    spy.wait_traced, spy.prepare = real.wait_traced, real.prepare  # what prepare() calls
    _tracker.step_chunk = spy
    try:
        seq = pt.synth.generate(7, n_frames=64, width=320, height=240, occlusion_level=1)
        pt.track(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, mode="per-frame")
    finally:
        _tracker.step_chunk = real
    if len(calls) < 3:
        raise RuntimeError(f"expected at least 3 chunked calls, got {len(calls)}")
    return calls[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=60)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/compile_options.json"))
    a = ap.parse_args()
    if jax.default_backend() != "cpu":
        sys.exit("compile_options.py measures XLA's CPU options: run it on a CPU backend")
    args = captured_call()
    lowered = jax.jit(track_chunk).lower(*args)
    compiled, compile_s = {}, {}
    for name, options in OPTIONS.items():
        t0 = time.perf_counter()
        compiled[name] = lowered.compile(options)
        compile_s[name] = time.perf_counter() - t0
        print(f"compiled {name} in {compile_s[name]:.2f} s", file=sys.stderr)
    times: dict[str, list[float]] = {n: [] for n in compiled}
    outputs = {}
    for _ in range(a.reps):
        for name, fn in compiled.items():
            t0 = time.perf_counter()
            outputs[name] = jax.block_until_ready(fn(*args))
            times[name].append(time.perf_counter() - t0)
    ref = jax.tree.leaves(outputs["shipped"])
    rows = []
    for name in compiled:
        same = all(
            np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
            for x, y in zip(ref, jax.tree.leaves(outputs[name]), strict=True)
        )
        rows.append({
            "options": name, "xla_options": OPTIONS[name], "compile_s": round(compile_s[name], 2),
            "ms_per_chunk_median": round(1e3 * float(np.median(times[name])), 1),
            "ms_per_chunk_min": round(1e3 * float(np.min(times[name])), 1),
            "same_outputs": same,
        })  # fmt: skip
    base = rows[0]["ms_per_chunk_median"]
    print(f"\nThe chunked step (16 frames, 320x240, shipped configuration), {a.reps} calls each")
    print(f"{'options':>15} {'compile s':>10} {'ms/chunk':>9} {'min':>7} {'ratio':>6}  same")
    for r in rows:
        r["ratio_to_shipped"] = round(r["ms_per_chunk_median"] / base, 3)
        print(
            f"{r['options']:>15} {r['compile_s']:>10.2f} {r['ms_per_chunk_median']:>9.1f} "
            f"{r['ms_per_chunk_min']:>7.1f} {r['ratio_to_shipped']:>6.2f}  {r['same_outputs']}"
        )
    Path(a.out).write_text(json.dumps({
        "benchmark": "compile_options.py", "reps": a.reps, "chunk": 16, "machine": machine_info(),
        "rows": rows,
    }, indent=1))  # fmt: skip
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
