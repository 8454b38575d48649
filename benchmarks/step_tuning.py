#!/usr/bin/env python
"""What each speed setting of the tracker step buys, measured in one run (issue 4's tuning).

On one generated frame (synth "walk", seed 0, 640x480, the tracker initialised on frame 0 and
its N hypotheses jittered around the pose), this times the two N-dependent parts of the step
separately, each as one jitted call, interleaved round robin so a neighbour's load hits all
variants alike:

* fits: the N vmapped Levenberg-Marquardt fits (``fit_hypotheses``) with lineax
  ``Normal(Cholesky)`` or ``QR`` (optimistix' default) and 8 / 12 / 20 steps;
* scoring: the N renders + Delta (``render_and_score``, culled) at 160x120 with the soft or the
  hard renderer, hypotheses one after another (``lax.map``) or together (``vmap``).

The shipped settings are Cholesky, 4 steps (MHT; LVM 8), hard, vmap. Accuracy of the choices
is measured by ``benchmarks/accuracy.py`` (rows "MHT_h" and "MHT_h untuned"), not here.

    python benchmarks/step_tuning.py [--ns 1 5 20 100] [--reps 30] [--json PATH]

Never run two benchmarks at once on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import posetrack as pt
from posetrack import TrackerConfig
from posetrack._depthobs import tracker_landmarks, tracker_observation
from posetrack._fit import FitSettings, fit_hypotheses
from posetrack._inputs import check_frame
from posetrack._render import render_and_score
from posetrack._step import hypothesis_capsules
from posetrack.app import machine_info
from posetrack.io import atomic_write_text

FITS = {
    "cholesky, 4 steps (shipped MHT)": FitSettings(max_steps=4),
    "cholesky, 6 steps": FitSettings(max_steps=6),
    "cholesky, 8 steps (shipped LVM)": FitSettings(max_steps=8),
    "cholesky, 12 steps": FitSettings(max_steps=12),
    "cholesky, 20 steps": FitSettings(max_steps=20),
    "qr, 4 steps": FitSettings(max_steps=4, linear_solver="qr"),
    "qr, 8 steps": FitSettings(max_steps=8, linear_solver="qr"),
    "qr, 12 steps": FitSettings(max_steps=12, linear_solver="qr"),
}
SCORERS = {
    "hard, vmap (shipped)": dict(sharpness=None, vectorize=True),
    "hard, lax.map": dict(sharpness=None, vectorize=False),
    "soft, vmap": dict(vectorize=True),
    "soft, lax.map": dict(vectorize=False),
}


def setup():
    seq = pt.synth.generate(0, motion="walk", n_frames=16, with_rgb=False)
    tracker = pt.Tracker(seq.intrinsics, TrackerConfig())
    tracker.estimate_shape(seq.depth[:15], seq.keypoints2d[:15], seq.confidence[:15])
    tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])
    intr = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), seq.intrinsics)
    depth, kp, conf = check_frame(
        intr, seq.depth[1], seq.keypoints2d[1], seq.confidence[1], 1000.0, "benchmark"
    )
    config = TrackerConfig()
    lm = jax.jit(tracker_landmarks)(config, tracker.shape, intr, depth, kp, conf)
    # The tracker's floor and pose after frame 0 (Tracker internals: no public accessor).
    best = tracker.state.best
    z_d, z_fg, known, small_intr = jax.jit(tracker_observation)(
        config, depth, intr, tracker.floor, best[:3]
    )
    return tracker, intr, lm, best, (z_d, z_fg, known, small_intr)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ns", type=int, nargs="+", default=[1, 5, 20, 100])
    p.add_argument("--reps", type=int, default=30)
    p.add_argument("--json", help="write the records (a JSON list) here")
    args = p.parse_args(argv)
    machine = machine_info()
    print("machine: " + " | ".join(f"{k}: {v}" for k, v in machine.items()), flush=True)
    tracker, intr, lm, best, (z_d, z_fg, known, small_intr) = setup()
    shape = tracker.shape
    rng = np.random.default_rng(0)
    records = []
    for n in args.ns:
        starts = jnp.asarray(
            np.asarray(best)[None] + rng.normal(0.0, 0.02, (n, 43)), jnp.float32
        )  # hypotheses a few centimetres / degrees apart, as in tracking
        masks = jnp.asarray(rng.random((n, 18)) < 0.8)
        caps = hypothesis_capsules(shape, starts)
        calls = {}
        for name, settings in FITS.items():
            f = jax.jit(fit_hypotheses, static_argnames="settings")
            calls[("fits", name)] = (
                lambda f=f, s=settings: f(starts, shape, lm, intr, use3d=masks, use2d=masks,
                                          settings=s)  # fmt: skip
            )
        for name, kw in SCORERS.items():
            g = jax.jit(lambda c, kw=kw: render_and_score(c, z_d, z_fg, small_intr, known=known,
                                                          **kw))  # fmt: skip
            calls[("scoring", name)] = lambda g=g: g(caps)
        compile_s, times = {}, {k: [] for k in calls}
        for k, call in calls.items():
            t0 = time.perf_counter()
            jax.block_until_ready(call())
            compile_s[k] = time.perf_counter() - t0
        for _ in range(args.reps):
            for k, call in calls.items():
                t0 = time.perf_counter()
                jax.block_until_ready(call())
                times[k].append(time.perf_counter() - t0)
        for (part, name), ts in times.items():
            records.append({
                "part": part, "setting": name, "N": n, "resolution": "160x120",
                "ms_median": round(1e3 * float(np.median(ts)), 3),
                "ms_min": round(1e3 * float(np.min(ts)), 3),
                "compile_s": round(compile_s[(part, name)] - float(np.median(ts)), 2),
                "machine": machine,
            })  # fmt: skip
        print(f"N={n} done", flush=True)
    print("\n| part | setting | " + " | ".join(f"N={n} ms" for n in args.ns) + " | vs shipped |")
    print("|---|---|" + "---|" * (len(args.ns) + 1))
    for part, names in (("fits", FITS), ("scoring", SCORERS)):
        first = next(iter(names))  # the shipped setting (MHT's, for the fits)
        ref = [r for r in records if r["part"] == part and r["setting"] == first]
        for name in names:
            rows = [r for r in records if r["part"] == part and r["setting"] == name]
            ratio = np.mean([r["ms_median"] / q["ms_median"] for r, q in zip(rows, ref)])
            cells = " | ".join(f"{r['ms_median']:.2f}" for r in rows)
            print(f"| {part} | {name} | {cells} | {ratio:.2f}x |")
    if args.json:
        atomic_write_text(args.json, json.dumps(records, indent=1))
        print(f"wrote {args.json}")
    return records


if __name__ == "__main__":
    sys.exit(0 if main() is not None else 1)
