#!/usr/bin/env python
"""Tuning the tracker's defaults: one factor at a time around the shipped MHT_h, tuning seeds only.

The protocol (benchmarks/README.md, "Tuning protocol"): a default may be chosen from what this
script prints, never from ``accuracy.py``'s reported sequences. It evaluates the shipped
``TrackerConfig()`` and, for each tuned default, the same configuration with that one field
changed, on generated sequences whose seeds come from ``seeds.TUNING_SEEDS`` only (any other
seed is refused): the six procedural motions and eight real clips (MSR Action3D, UTKinect)
that ``accuracy.py`` does not report (CMU subject 131 has only the three clips it reports,
so none here). Each clip has its own seed (clip i: ``TUNING_SEEDS[i + seed_offset]``), at
occlusion levels 0, 2 and 4. LVM (``TrackerConfig.recommended("lvm")``) is printed for scale.

Float fields of ``TrackerConfig`` (``reseed_margin``, the sigmas, ``d_hmax``,
``consensus_distance``) are traced tunables: they share the shipped configuration's compiled
step. ``num_hypotheses`` and the LM steps change shapes or loops and compile once each.

    python benchmarks/tune.py                   # full grid (estimated 30-60 min on 2 cores)
    python benchmarks/tune.py --quick           # 2 clips, level 2, one value per factor (~3 min)
    python benchmarks/tune.py --factors sigma_h d_hmax --json tune.json
    python benchmarks/tune.py --seed-offset 20  # other tuning seeds (120, 121, ...)

Prints the table (D in mm: mean over sequences of each sequence's mean joint error; share of
body joints estimated; milliseconds per steady-state frame) and writes ``--json PATH``.
Never run two benchmarks at once on a 2-core machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from parts import add_part_arguments, check_part, share
from seeds import REPORT_SEEDS, TUNING_SEEDS, TUNING_TEXT, parse_seeds  # benchmarks/seeds.py

import posetrack as pt
from posetrack.app import machine_info

PROCEDURAL = ("walk", "box", "wave", "reach", "squat", "turn")
#: Real clips that accuracy.py's REAL list does not contain (tests check it): other actions
#: and other subjects of the same two data sets.
REAL = (
    "msr:a05_s02_e01",
    "msr:a11_s03_e01",
    "msr:a16_s08_e01",
    "msr:a20_s01_e01",
    "utk:s02_e01:carry",
    "utk:s04_e01:sitDown",
    "utk:s06_e02:pull",
    "utk:s08_e01:clapHands",
)
LEVELS = (0, 2, 4)

#: Values tried for each tuned default, one factor at a time (the shipped value is the
#: reference row; a value equal to it is skipped). "lm_steps" is ``TrackerConfig.fit``'s
#: ``max_steps`` with the shipped MHT loss (``"l2"``).
GRID = {
    "num_hypotheses": (5, 20),
    "reseed_margin": (0.05, 0.3, 1.0),
    "sigma_g": (1.0, 2.5),
    "sigma_h": (0.3, 0.8),
    "d_hmax": (0.3, 0.6),
    "consensus_distance": (0.08, 0.16),
    "lm_steps": (2, 6, 8),
}


def real_motion(seed: int) -> str:
    """The real clip a tuning seed's wide real-motion run tracks (``REAL[seed % len(REAL)]``;
    decide.py --real-seeds, facing.py, losses.py --kind real)."""
    return REAL[seed % len(REAL)]


#: D in the diagnoses is over all 18 keypoints (``pt.accuracy``'s default is the 13 body joints).
ALL_KEYPOINTS = tuple(range(len(pt.KEYPOINT_NAMES)))


def mean_error_all_mm(keypoints3d: np.ndarray, truth: np.ndarray) -> float:
    """D (``pt.accuracy``) over all 18 keypoints and the frames with an estimate, mm."""
    return pt.accuracy(keypoints3d, truth, joints=ALL_KEYPOINTS).mean_mm


def decision_measures(keypoints3d: np.ndarray, truth: np.ndarray) -> dict:
    """What a decision run records of an output (``decide.py``, ``inpass_shape.py``): D over
    the 13 body joints, coverage, swapped-limb frames and acceleration error."""
    acc = pt.accuracy(keypoints3d, truth)
    return {
        "D": acc.mean_mm, "cov": acc.coverage,
        "swaps": pt.swapped_limb_frames(keypoints3d, truth),
        "accel": float(pt.acceleration_error(keypoints3d, truth)),
    }  # fmt: skip


def shared_measures(keypoints3d: np.ndarray, base: np.ndarray, truth: np.ndarray) -> dict:
    """D over the 13 body joints and swapped-limb frames of an output and of a baseline's
    output of the same clip, over the frames both answered (``decide.py``'s ``"shared"``).
    A change that answers frames the baseline did not is charged for how hard those frames
    are when D runs over each version's own frames; here it is not (its coverage says the
    rest)."""
    both = np.isfinite(keypoints3d).any(axis=(1, 2)) & np.isfinite(base).any(axis=(1, 2))
    if not both.any():
        return {"frames": 0, "D": math.nan, "base_D": math.nan, "swaps": 0, "base_swaps": 0}
    k, b, g = keypoints3d[both], base[both], truth[both]
    return {
        "frames": int(both.sum()),
        "D": pt.accuracy(k, g).mean_mm, "base_D": pt.accuracy(b, g).mean_mm,
        "swaps": pt.swapped_limb_frames(k, g), "base_swaps": pt.swapped_limb_frames(b, g),
    }  # fmt: skip


def diagnosis_runs(doc: str, seeds: str, benchmark: str, run_clip) -> tuple:
    """The command line and runs of a diagnosis over wide real-motion tuning clips (judge.py,
    online_gap.py, offline_shape.py): ``--seeds`` (tuning seeds only: anything else is a
    command-line error), ``--part``/``--parts`` (this process's share), ``--merge`` (JSON files
    of parts: their ``"runs"`` instead of running) and ``--out`` (default
    ``results/<benchmark>.json``). Each seed's clip (:func:`real_motion`, the wide generator,
    120 frames at 30 fps, 320x240) at occlusion 0 and 2 is given to ``run_clip(seq)``, whose
    row is prefixed with the seed, motion and occlusion and printed to stderr.

    Returns ``(args, runs)``."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--seeds", default=seeds, help="wide real motion tuning seeds")
    add_part_arguments(ap)
    ap.add_argument("--merge", nargs="*", default=None, help="JSON files of parts to merge")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / f"{benchmark}.json"))
    a = ap.parse_args()
    check_part(ap, a)
    if a.merge:
        return a, [r for f in a.merge for r in json.loads(Path(f).read_text())["runs"]]
    chosen = parse_seeds(a.seeds)
    try:
        check_seeds(chosen)
    except ValueError as e:
        ap.error(str(e))
    todo = share([(s, occ) for s in chosen for occ in (0, 2)], a)
    runs, t0 = [], time.perf_counter()
    for i, (seed, occ) in enumerate(todo):
        seq = pt.synth.generate(
            seed, motion=real_motion(seed), n_frames=120, fps=30.0, occlusion_level=occ,
            width=320, height=240, with_rgb=False, variety="wide",
        )  # fmt: skip
        runs.append({"seed": seed, "motion": real_motion(seed), "occlusion": occ, **run_clip(seq)})
        print(f"[{time.perf_counter() - t0:5.0f}s {i + 1}/{len(todo)}] {json.dumps(runs[-1])}",
              file=sys.stderr)  # fmt: skip
    return a, runs


def write_diagnosis(out: str, benchmark: str, table: dict, runs: list[dict], **extra) -> None:
    """A diagnosis' JSON (judge.py, online_gap.py, offline_shape.py): ``benchmark``, ``table``,
    the ``extra`` entries, ``runs`` and the machine, written to ``out``."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps({
        "benchmark": benchmark, "table": table, **extra, "runs": runs, "machine": machine_info(),
    }, indent=1))  # fmt: skip
    print(f"wrote {out}")


def check_seeds(seeds) -> None:
    """Refuse any seed outside ``TUNING_SEEDS`` (reported and test seeds are never tuned on)."""
    bad = [s for s in seeds if s not in TUNING_SEEDS]
    if bad:
        where = " (a reported seed)" if any(s in REPORT_SEEDS for s in bad) else ""
        raise ValueError(
            f"tune.py: seeds {bad} are not tuning seeds{where}; tuning uses only "
            f"TUNING_SEEDS ({TUNING_TEXT}, benchmarks/seeds.py)"
        )


def sequences(quick: bool, seed_offset: int = 0) -> list[tuple[str, int]]:
    """(motion, seed) pairs: one seed per clip, all from ``TUNING_SEEDS``; real clips where
    the data are present (``POSETRACK_DATA``)."""
    available = set(pt.synth.list_real_motions())
    real = [m for m in REAL if m in available]
    motions = ["walk", *real[:1]] if quick else [*PROCEDURAL, *real]
    if not 0 <= seed_offset <= len(TUNING_SEEDS) - len(motions):
        raise ValueError(
            f"tune.py: --seed-offset must keep {len(motions)} seeds inside "
            f"TUNING_SEEDS, got {seed_offset}"
        )
    pairs = [(m, TUNING_SEEDS[seed_offset + i]) for i, m in enumerate(motions)]
    check_seeds([s for _, s in pairs])
    return pairs


def settings(quick: bool, factors=None) -> list[tuple[str, str, pt.TrackerConfig]]:
    """(factor, value label, config) rows: the shipped MHT_h, each factor's alternatives (the
    first only with ``quick``), and LVM."""
    shipped = pt.TrackerConfig()
    rows = [("shipped", "-", shipped)]
    for factor, values in GRID.items():
        if factors and factor not in factors:
            continue
        for v in values[:1] if quick else values:
            if factor == "lm_steps":
                if v == shipped.fit.max_steps:
                    continue
                fit = dataclasses.replace(shipped.fit, max_steps=v)
                cfg = dataclasses.replace(shipped, fit=fit)
            else:
                if v == getattr(shipped, factor):
                    continue
                cfg = dataclasses.replace(shipped, **{factor: v})
            rows.append((factor, f"{v:g}", cfg))
    rows.append(("LVM", "-", pt.TrackerConfig.recommended("lvm")))
    return rows


def shipped_values() -> dict[str, float]:
    """The shipped value of each factor of the grid (the reference row)."""
    shipped = pt.TrackerConfig()
    return {f: shipped.fit.max_steps if f == "lm_steps" else getattr(shipped, f) for f in GRID}


def machine() -> dict[str, object]:
    """What the numbers were measured on: ``posetrack.app.machine_info`` and the load average
    (a tuning run is long, and a busy machine reads slower)."""
    return {**machine_info(), "load_average": [round(x, 2) for x in os.getloadavg()]}


def run(args) -> dict:
    t_start = time.perf_counter()
    seqs = sequences(args.quick, args.seed_offset)
    levels = (2,) if args.quick else tuple(args.levels)
    rows = settings(args.quick, args.factors)
    info = machine()
    print(
        f"machine: {info['cpu']}, {info['cores']} cores, jax {info['jax']} ({info['backend']}), "
        f"XLA_FLAGS={info['XLA_FLAGS']!r}, load average {info['load_average']}"
    )
    print(
        f"{len(seqs)} clips x levels {list(levels)}, {args.frames} frames; {len(rows)} settings; "
        f"seeds {[s for _, s in seqs]}",
        flush=True,
    )
    records = []
    total, k = len(seqs) * len(levels), 0
    for motion, seed in seqs:
        for level in levels:
            k += 1
            t0 = time.perf_counter()
            seq = pt.synth.generate(
                seed, motion=motion, n_frames=args.frames, occlusion_level=level, with_rgb=False
            )
            line = [f"[{k}/{total}] {motion} s{seed} occl {level}:"]
            for factor, value, cfg in rows:
                t1 = time.perf_counter()
                res = pt.track(
                    seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, cfg, seed=seed,
                    mode="per-frame",  # the per-frame defaults are tuned on the per-frame output
                )
                acc = pt.accuracy(res.keypoints3d, seq.joints3d)
                records.append(
                    {
                        "motion": motion,
                        "seed": seed,
                        "level": level,
                        "factor": factor,
                        "value": value,
                        "D_mean_mm": acc.mean_mm,
                        "coverage": acc.coverage,
                        "ms_per_frame": res.ms_per_frame,
                        "seconds": time.perf_counter() - t1,
                    }
                )
                if factor in ("shipped", "LVM"):
                    line.append(f"{factor} {acc.mean_mm:.0f}")
            print(" ".join(line) + f"  [{time.perf_counter() - t0:.0f}s]", flush=True)

    def mean_d(rs) -> float:
        return float(np.mean([r["D_mean_mm"] for r in rs])) if rs else float("nan")

    summary = []
    for factor, value, _ in rows:
        mine = [r for r in records if r["factor"] == factor and r["value"] == value]
        summary.append(
            {
                "factor": factor,
                "value": value,
                "D_mean_mm": mean_d(mine),
                "D_clean_mm": mean_d([r for r in mine if r["level"] == 0]),
                "D_occluded_mm": mean_d([r for r in mine if r["level"] > 0]),
                "coverage": float(np.mean([r["coverage"] for r in mine])),
                "ms_per_frame": float(np.median([r["ms_per_frame"] for r in mine])),
                "seconds": float(np.sum([r["seconds"] for r in mine])),
            }
        )
    ref = summary[0]  # the shipped row
    for row in summary:
        row["vs_shipped"] = row["D_mean_mm"] / ref["D_mean_mm"] - 1
    result = {
        "machine": info,
        "frames": args.frames,
        "levels": list(levels),
        "sequences": [{"motion": m, "seed": s} for m, s in seqs],
        "shipped": shipped_values(),
        "grid": {f: list(v) for f, v in GRID.items()},
        "quick": args.quick,
        "seconds": time.perf_counter() - t_start,
        "summary": summary,
        "records": records,
    }
    print()
    print(table(result))
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(_null_nan(result), indent=1))
        print(f"\nwrote {path}")
    return result


def _null_nan(x):
    """NaN (a column without sequences, e.g. "clean" with --quick) as JSON null."""
    if isinstance(x, dict):
        return {k: _null_nan(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_null_nan(v) for v in x]
    return None if isinstance(x, float) and x != x else x


def table(result: dict) -> str:
    """The summary as a Markdown table."""
    shipped = result["shipped"]
    lines = [
        f"D in mm over {len(result['sequences'])} clips x levels {result['levels']} "
        f"({result['frames']} frames, tuning seeds {result['sequences'][0]['seed']}-"
        f"{result['sequences'][-1]['seed']}); shipped: "
        + ", ".join(f"{f} {v:g}" for f, v in shipped.items())
        + f"; {result['seconds']:.0f} s",
        "",
        "| factor | value | D mean | clean | occluded | vs shipped | joints estimated "
        "| ms/frame | s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["summary"]:
        lines.append(
            f"| {r['factor']} | {r['value']} | {r['D_mean_mm']:.1f} | {r['D_clean_mm']:.1f} "
            f"| {r['D_occluded_mm']:.1f} | {100 * r['vs_shipped']:+.1f} % | {r['coverage']:.3f} "
            f"| {r['ms_per_frame']:.1f} | {r['seconds']:.0f} |"
        )
    return "\n".join(lines).replace("| nan ", "| - ")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="2 clips at level 2, the first alternative of each factor",
    )
    p.add_argument("--frames", type=int, default=60, help="frames per sequence (default 60)")
    p.add_argument(
        "--levels",
        type=int,
        nargs="+",
        default=list(LEVELS),
        help="occlusion levels (default 0 2 4; --quick: 2)",
    )
    p.add_argument(
        "--factors",
        nargs="+",
        choices=list(GRID),
        default=None,
        help="only these factors (default: all)",
    )
    p.add_argument(
        "--seed-offset",
        type=int,
        default=0,
        help="clip i gets TUNING_SEEDS[i + offset] (default 0: 100, 101, ...)",
    )
    p.add_argument("--json", default=None, help="write the results here")
    args = p.parse_args(argv)
    try:
        run(args)
    except ValueError as e:
        if str(e).startswith("tune.py:"):
            print(f"error: {e}", file=sys.stderr)
            return 2
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
