"""Render + Delta per frame for N hypotheses: which formulation to batch the renderer with.

Times, steady state after a warm-up call (compile time reported separately), float32:

* ``vmap``       ``jax.vmap`` over hypotheses of the fused render + Delta;
* ``map``        ``jax.lax.map`` over hypotheses (one hypothesis per loop step);
* ``map_bs4``    ``jax.lax.map(..., batch_size=4)``;
* ``map_cull``   ``lax.map`` + tile culling (``render_and_score(cull=True)``, the default);
* ``map_allcap`` ``lax.map``, but each hypothesis evaluates all capsules at once with
                 (capsule, H, W) intermediates instead of the library's loop over capsules
                 (the formulation of the first prototype; 160x120, N <= 20 only);

soft (default sharpness) and hard (``sharpness=None``), for N in {1, 5, 20, 100} at 160x120
and 320x240. Then a scoring-resolution study: how well Delta at 80x60 / 160x120 / 320x240
ranks perturbed hypotheses compared with Delta at 640x480, and what each costs.

Usage: python benchmarks/render_formulations.py [--json PATH] [--quick | --sweep]
Timings on shared CPUs vary run to run (+-30 % here): the table reports the minimum and the
median of the repetitions. Never run two benchmarks at once.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from posetrack._camera import Intrinsics
from posetrack._depthobs import downsample_depth
from posetrack._render import (
    DEFAULT_SHARPNESS,
    Capsules,
    capsule_fields,
    capsule_params,
    ray_grid,
    render_and_score,
    render_depth,
    soft_terms,
)
from posetrack._score import delta_from_sums, delta_sums
from posetrack.app import machine_info

D_M = 0.15


def machine() -> dict:
    return machine_info()


def kinect(width: int, height: int) -> Intrinsics:
    """Kinect v1 depth intrinsics (f = 525 px at 640x480) scaled to ``width`` x ``height``."""
    return Intrinsics.create(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640,
                             height=480).scaled(width, height)


def stick_body(rng=None, jitter=0.0, center=(0.0, 0.1, 3.0)):
    """16 capsules of a person 3 m from the camera; ``jitter`` (metres) perturbs endpoints
    the way different hypotheses of one frame differ."""
    c = np.asarray(center)
    j = {
        "pelvis": (0, 0, 0), "spine": (0, -0.25, 0.02), "neck": (0, -0.5, 0), "head": (0, -0.68, 0),
        "lsho": (0.18, -0.48, 0), "lelb": (0.25, -0.2, -0.1), "lwri": (0.3, 0.02, -0.3),
        "rsho": (-0.18, -0.48, 0), "relb": (-0.3, -0.3, 0.05), "rwri": (-0.55, -0.35, 0.1),
        "lhip": (0.1, 0.02, 0), "lkne": (0.12, 0.45, -0.05), "lank": (0.12, 0.88, 0),
        "rhip": (-0.1, 0.02, 0), "rkne": (-0.14, 0.45, 0.02), "rank": (-0.15, 0.88, 0.05),
    }
    j = {name: np.asarray(p, float) + c for name, p in j.items()}
    if rng is not None:
        j = {name: p + rng.normal(0, jitter, 3) for name, p in j.items()}
    segs = [("pelvis", "spine", 0.13), ("spine", "neck", 0.14), ("neck", "head", 0.09),
            ("head", "head", 0.11), ("lsho", "lelb", 0.05), ("lelb", "lwri", 0.04),
            ("rsho", "relb", 0.05), ("relb", "rwri", 0.04), ("lhip", "lkne", 0.07),
            ("lkne", "lank", 0.055), ("rhip", "rkne", 0.07), ("rkne", "rank", 0.055),
            ("lsho", "rsho", 0.06), ("lhip", "rhip", 0.09), ("lwri", "lwri", 0.045),
            ("rwri", "rwri", 0.045)]
    return (np.stack([j[s[0]] for s in segs]), np.stack([j[s[1]] for s in segs]),
            np.array([s[2] for s in segs]))


def stack(bodies) -> Capsules:
    return Capsules(*(jnp.asarray(np.stack(v), jnp.float32) for v in zip(*bodies)))


def observation(k: Intrinsics, rng):
    """Observation maps of the unperturbed body: hard render + Kinect-like noise."""
    truth = Capsules(*(jnp.asarray(v, jnp.float32) for v in stick_body()))
    depth, fg = (np.asarray(v) for v in render_depth(truth, k, sharpness=None))
    noisy = depth + rng.normal(0, 1.425e-3 * depth**2).astype(np.float32)
    return jnp.asarray(np.where(fg > 0, noisy, 0.0)), jnp.asarray(fg)


# ---------------------------------------------------------------------------------------------
# Formulations.


def _score_allcap(x, y, caps, z_d, z_fg, sharpness):
    """One hypothesis, all capsules at once: (P, H, W) intermediates reduced over P."""
    p = {k: v[:, None, None] for k, v in capsule_params(caps).items()}
    delta, z = capsule_fields(x[None], y[None], p)
    if sharpness is None:
        key = jnp.where(delta < 0.0, z - 1e3, delta)
        depth = jnp.take_along_axis(z, jnp.argmin(key, axis=0)[None], axis=0)[0]
        fg = jnp.any(delta < 0.0, axis=0).astype(z.dtype)
    else:
        log_nc, score = soft_terms(delta, z, sharpness)
        fg = -jnp.expm1(jnp.sum(log_nc, axis=0))
        depth = jnp.sum(jax.nn.softmax(score, axis=0) * z, axis=0)
    return delta_from_sums(*delta_sums(z_d, z_fg, depth, fg, D_M))


def make_variant(name: str, k: Intrinsics, sharpness):
    sh = None if sharpness is None else jnp.float32(sharpness)
    x, y = ray_grid(k, jnp.float32)

    def one(caps, z_d, z_fg):
        r_d, r_fg = render_depth(caps, k, sharpness=sh)  # the library's renderer, one body
        return delta_from_sums(*delta_sums(z_d, z_fg, r_d, r_fg, D_M))

    if name == "vmap":
        return jax.jit(lambda c, zd, zf: jax.vmap(lambda ci: one(ci, zd, zf))(c))
    if name == "map":
        return jax.jit(lambda c, zd, zf: jax.lax.map(lambda ci: one(ci, zd, zf), c))
    if name == "map_bs4":
        return jax.jit(lambda c, zd, zf: jax.lax.map(lambda ci: one(ci, zd, zf), c,
                                                     batch_size=4))
    if name == "map_cull":
        return jax.jit(lambda c, zd, zf: render_and_score(c, zd, zf, k, sharpness=sharpness,
                                                          d_M=D_M))
    if name == "map_allcap":
        return jax.jit(lambda c, zd, zf: jax.lax.map(
            lambda ci: _score_allcap(x, y, ci, zd, zf, sh), c))
    raise ValueError(name)


def timeit(fn, args, *, min_reps=3, max_reps=15, budget_s=1.0):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    times = []
    start = time.perf_counter()
    while len(times) < (2 if times and times[0] > 0.4 else min_reps) or (
            len(times) < max_reps and time.perf_counter() - start < budget_s):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return out, compile_s, 1e3 * min(times), 1e3 * float(np.median(times))


def run_timings(resolutions, ns, quick: bool):
    rows = []
    rng = np.random.default_rng(0)
    for width, height in resolutions:
        k = kinect(width, height)
        z_d, z_fg = observation(k, rng)
        for n in ns:
            caps = stack([stick_body(rng, 0.03) for _ in range(n)])
            variants = [("vmap", DEFAULT_SHARPNESS), ("map", DEFAULT_SHARPNESS),
                        ("map_bs4", DEFAULT_SHARPNESS), ("map_cull", DEFAULT_SHARPNESS),
                        ("map", None), ("map_cull", None)]
            if width == 160 and n <= 20 and not quick:
                variants.insert(2, ("map_allcap", DEFAULT_SHARPNESS))
            reference = None
            for name, sharpness in variants:
                fn = make_variant(name, k, sharpness)
                out, comp, tmin, tmed = timeit(fn, (caps, z_d, z_fg))
                if sharpness is not None:
                    if reference is None:
                        reference = np.asarray(out)
                    err = float(np.max(np.abs(np.asarray(out) - reference)))
                else:
                    err = float("nan")
                row = dict(resolution=f"{width}x{height}", n=n, variant=name,
                           soft=sharpness is not None, compile_s=round(comp, 2),
                           ms_min=round(tmin, 2), ms_median=round(tmed, 2),
                           max_abs_diff_vs_vmap=err)
                rows.append(row)
                print(f"{row['resolution']:>8} N={n:<3} {name:<10} "
                      f"{'soft' if row['soft'] else 'hard':<4} compile {comp:5.2f} s   "
                      f"min {tmin:8.2f} ms   median {tmed:8.2f} ms", flush=True)
    return rows


def resolution_study(n_per_level: int = 8):
    """Delta at several scoring resolutions vs Delta at 640x480 on perturbed hypotheses."""
    rng = np.random.default_rng(1)
    k_full = kinect(640, 480)
    a, b, r = stick_body()
    truth = Capsules(*(jnp.asarray(v, jnp.float32) for v in (a, b, r)))
    depth, fg = (np.asarray(v) for v in jax.jit(render_depth, static_argnames="sharpness")(
        truth, k_full, sharpness=None))
    depth = np.where(fg > 0, depth + rng.normal(0, 1.425e-3 * depth**2), 0.0).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = 0.0  # sensor holes
    # Hypotheses of one frame differ by a few cm: joint jitter 0.5-8 cm.
    levels = (0.005, 0.01, 0.02, 0.04, 0.08)
    hyps = [stick_body(rng, s) for s in levels for _ in range(n_per_level)]
    caps = stack(hyps)
    # The true error of each hypothesis: mean capsule-endpoint distance to the truth, metres.
    error = np.array([np.mean(np.linalg.norm(np.concatenate([h[0] - a, h[1] - b]), axis=-1))
                      for h in hyps])

    def ranks(v):
        return np.argsort(np.argsort(v))

    def spearman(u, v):
        return float(np.corrcoef(ranks(u), ranks(v))[0, 1])

    rows = []
    for sharpness in (DEFAULT_SHARPNESS, None):
        scores = {}
        for width, height in ((640, 480), (320, 240), (160, 120), (80, 60)):
            k = kinect(width, height)
            z_d = downsample_depth(jnp.asarray(depth), 640 // width)
            z_fg = (z_d > 0).astype(jnp.float32)
            fn = jax.jit(lambda c, zd, zf, k=k, sh=sharpness: render_and_score(
                c, zd, zf, k, sharpness=sh, d_M=D_M))
            out, _, tmin, _ = timeit(fn, (caps, z_d, z_fg))
            scores[width] = np.asarray(out)
            ref = scores[640]
            close = error < np.median(error)  # the harder half: near-truth hypotheses
            row = dict(
                resolution=f"{width}x{height}", soft=sharpness is not None, n=len(hyps),
                ms_min=round(tmin, 2),
                spearman_vs_true_error=round(spearman(scores[width], error), 3),
                spearman_vs_true_error_close_half=round(
                    spearman(scores[width][close], error[close]), 3),
                spearman_vs_640=round(spearman(scores[width], ref), 3),
                picked_error_mm=round(1e3 * float(error[np.argmin(scores[width])]), 1),
                smallest_error_mm=round(1e3 * float(error.min()), 1),
                mean_abs_diff_vs_640=round(float(np.mean(np.abs(scores[width] - ref))), 4),
            )
            rows.append(row)
            print(f"{row['resolution']:>8} {'soft' if row['soft'] else 'hard'}  N={len(hyps)} "
                  f"{tmin:8.2f} ms   Spearman vs true error {row['spearman_vs_true_error']:.3f}"
                  f" (closer half {row['spearman_vs_true_error_close_half']:.3f}), "
                  f"vs 640x480 {row['spearman_vs_640']:.3f}   picked error "
                  f"{row['picked_error_mm']} mm (best {row['smallest_error_mm']})   mean "
                  f"|Delta - Delta_640| "
                  f"{row['mean_abs_diff_vs_640']:.4f}", flush=True)
    return rows


def culling_sweep(n: int = 20):
    """``render_and_score(cull=True)`` over its static granularity parameters."""
    rows = []
    rng = np.random.default_rng(2)
    for width, height in ((160, 120), (320, 240)):
        k = kinect(width, height)
        z_d, z_fg = observation(k, rng)
        caps = stack([stick_body(rng, 0.03) for _ in range(n)])
        for tile in (4, 8, 16):
            for chunk in (8, 16, 32):
                for group in (1, 2, 4):
                    fn = jax.jit(lambda c, zd, zf, k=k, t=tile, ch=chunk, g=group:
                                 render_and_score(c, zd, zf, k, tile=t, chunk=ch, group=g))
                    _, comp, tmin, tmed = timeit(fn, (caps, z_d, z_fg), budget_s=0.5)
                    rows.append(dict(resolution=f"{width}x{height}", n=n, tile=tile,
                                     chunk=chunk, group=group, compile_s=round(comp, 2),
                                     ms_min=round(tmin, 2), ms_median=round(tmed, 2)))
                    print(f"{width}x{height} N={n} tile {tile:2d} chunk {chunk:2d} group {group}:"
                          f" min {tmin:7.2f} ms  median {tmed:7.2f} ms", flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", help="write the results as JSON to this path")
    parser.add_argument("--quick", action="store_true", help="160x120 and N in {1, 20} only")
    parser.add_argument("--sweep", action="store_true",
                        help="only sweep the culling parameters (tile, chunk, group), ~2 min")
    args = parser.parse_args()
    if args.sweep:
        print(" | ".join(f"{k}: {v}" for k, v in machine().items()))
        rows = culling_sweep()
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"machine": machine(), "culling_sweep": rows}, f, indent=1)
        return
    info = machine()
    print(" | ".join(f"{k}: {v}" for k, v in info.items()))
    t0 = time.perf_counter()
    if args.quick:
        timings = run_timings([(160, 120)], [1, 20], quick=True)
    else:
        timings = run_timings([(160, 120), (320, 240)], [1, 5, 20, 100], quick=False)
    print("\nScoring resolution (culled, 40 hypotheses, joint jitter 0.5-8 cm):")
    study = resolution_study()
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")

    print("\nms per frame (min over repetitions), render + Delta, float32:")
    keys = sorted({(r["variant"], r["soft"]) for r in timings},
                  key=lambda v: (not v[1], v[0]))
    ns = sorted({r["n"] for r in timings})
    for res in sorted({r["resolution"] for r in timings}, key=lambda s: int(s.split("x")[0])):
        print(f"\n| {res} | " + " | ".join(f"N={n}" for n in ns) + " |")
        print("|---|" + "---|" * len(ns))
        for variant, soft in keys:
            cells = []
            for n in ns:
                hit = [r for r in timings if (r["resolution"], r["n"], r["variant"], r["soft"])
                       == (res, n, variant, soft)]
                cells.append(f"{hit[0]['ms_min']:.1f}" if hit else "-")
            if any(c != "-" for c in cells):
                print(f"| {variant} ({'soft' if soft else 'hard'}) | " + " | ".join(cells) + " |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": info, "timings": timings, "resolution_study": study}, f,
                      indent=1)
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
