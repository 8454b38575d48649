#!/usr/bin/env python
"""Accuracy benchmark: the paper's Table 1, Table 2, Fig. 3 and Fig. 5 on generated RGB-D.

Sequences come from ``posetrack.synth`` (a body, sensor and detector model that differs from
the tracker's own), with real motion capture (CMU, MSR Action3D, UTKinect) where
``../shared/data`` is present and the built-in procedural motions otherwise, at occlusion levels
0-4. Seeds are fixed and disjoint from the seeds the tracker's defaults were tuned on (100+).

    python benchmarks/accuracy.py              # full run (~45 min on 2 cores)
    python benchmarks/accuracy.py --quick      # a few sequences (~8 min)
    python benchmarks/accuracy.py --markdown   # the README's tables from the saved results

Prints the tables and writes ``results.json``, ``fig3_success.png``, ``fig5_occlusion.png``
into ``--out`` (default ``benchmarks/results/accuracy``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from seeds import REPORT_SEEDS  # benchmarks/seeds.py: reported, tuning, test seeds

import posetrack as pt
from posetrack import lift_sequence
from posetrack.app import line_plot, machine_summary, write_png

PROCEDURAL = ("walk", "box", "wave", "reach", "squat", "turn")
REAL = (
    "cmu:131_01", "cmu:131_02", "cmu:131_03", "msr:a02_s03_e01", "msr:a06_s05_e01",
    "msr:a13_s07_e01", "msr:a14_s04_e02", "msr:a18_s06_e01", "utk:s03_e01:waveHands",
    "utk:s05_e02:pickUp", "utk:s07_e01:throw", "utk:s09_e01:push",
)  # fmt: skip
TABLE1_GRID = (
    (0.0, 0.0),
    (0.0, 0.05),
    (0.0, 0.10),
    (0.0, 0.15),
    (0.05, 0.10),
    (0.05, 0.15),
    (0.05, 0.30),
)


def methods(quick: bool) -> dict[str, pt.TrackerConfig]:
    """Table 2's rows.

    * ``... (paper)``: the paper's method alone at its best setting (its Table 2):
      ``TrackerConfig.paper(method)``, every addition of this project off;
    * ``LVM``, ``MHT_r``, ``MHT_g``: the same (N, r, R) with our additions
      (``TrackerConfig.recommended``: surface offset, unknown invalid depth, floor removal,
      2D temporal weight, reseeding, consensus refit);
    * ``MHT_h N=5`` and ``MHT_h``: what we ship, with the paper's N = 5 and with N = 10;
    * (full run only) the optional dense refinement on top of LVM and MHT_h.
    """
    rows = {
        "LVM (paper)": pt.TrackerConfig.paper("lvm"),
        "MHT_r (paper)": pt.TrackerConfig.paper("mht_r"),
        "MHT_g (paper)": pt.TrackerConfig.paper("mht_g"),
        "MHT_h (paper)": pt.TrackerConfig.paper("mht_h"),
        "LVM": pt.TrackerConfig.recommended("lvm"),
        "MHT_r": pt.TrackerConfig.recommended("mht_r"),
        "MHT_g": pt.TrackerConfig.recommended("mht_g"),
        "MHT_h N=5": pt.TrackerConfig.recommended("mht_h", num_hypotheses=5),
        "MHT_h": pt.TrackerConfig(),
    }
    if not quick:
        rows["LVM +refine"] = pt.TrackerConfig.recommended(
            "lvm", refine_steps=3, refine_weight=1.0
        )
        rows["MHT_h +refine"] = pt.TrackerConfig(refine_steps=3, refine_weight=1.0)
    return rows


#: Which LVM row each row's gain is measured against: the paper's method against the paper's
#: baseline, ours against LVM with the same additions (like for like).
BASELINE = {
    "LVM (paper)": "LVM (paper)", "MHT_r (paper)": "LVM (paper)", "MHT_g (paper)": "LVM (paper)",
    "MHT_h (paper)": "LVM (paper)", "naive": "LVM (paper)",
}  # fmt: skip

#: Table 1 is the paper's experiment: its methods alone over the (r, R) grid.
TABLE1_METHODS = ("MHT_r (paper)", "MHT_g (paper)", "MHT_h (paper)")


def sequences(quick: bool) -> list[tuple[str, int]]:
    """(motion, seed) pairs. Each clip has its own seed (0, 1, 2, ...; the defaults were tuned
    on 100+): with one seed for all, every clip would share the detector's random events (the
    same left/right swap in the same frames), and the clips would not be independent."""
    real = [m for m in REAL if m in set(pt.synth.list_real_motions())]
    motions = ["walk", "box", *real[:1]] if quick else [*PROCEDURAL, *real]
    return [(m, REPORT_SEEDS[i]) for i, m in enumerate(motions)]


def run(args) -> dict:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seqs = sequences(args.quick)
    levels = tuple(range(5)) if not args.quick else (0, 2, 4)
    configs = methods(args.quick)
    records = []  # one per (sequence, level, method)
    table1 = []  # one per (sequence, method, r, R) at level args.table1_level
    curves_d = CURVES_D
    errors: dict[str, list[np.ndarray]] = {name: [] for name in [*configs, "naive"]}
    t_start = time.perf_counter()
    total = len(seqs) * len(levels)
    k = 0
    for motion, seed in seqs:
        for level in levels:
            k += 1
            t0 = time.perf_counter()
            seq = pt.synth.generate(
                seed, motion=motion, n_frames=args.frames, occlusion_level=level, with_rgb=False
            )
            plain = lift_sequence(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics)
            naive = pt.naive_lifting(*plain)
            acc = pt.accuracy(naive, seq.joints3d)
            errors["naive"].append(pt.joint_errors(naive, seq.joints3d))
            records.append(
                {"motion": motion, "seed": seed, "level": level, "method": "naive", **acc.row()}
            )
            line = [f"[{k}/{total}] {motion} s{seed} occl {level}: naive {acc.mean_mm:.0f}"]
            for name, cfg in configs.items():
                res = pt.track(
                    seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, cfg, seed=seed,
                    mode="per-frame",  # the paper's tables; motion.py measures the motion model
                )
                acc = pt.accuracy(res.keypoints3d, seq.joints3d)
                errors[name].append(pt.joint_errors(res.keypoints3d, seq.joints3d))
                records.append({"motion": motion, "seed": seed, "level": level, "method": name,
                                **acc.row(), "ms_per_frame": res.ms_per_frame})  # fmt: skip
                line.append(f"{name} {acc.mean_mm:.0f}")
            if level == args.table1_level:
                for name in TABLE1_METHODS:
                    for r, R in TABLE1_GRID:
                        if name.startswith("MHT_r") and r == 0 and R == 0:
                            continue  # all landmarks, identical hypotheses: LVM (N/A in the paper)
                        cfg = configs[name].replace(r=r, R=R)
                        res = pt.track(
                            seq.depth,
                            seq.keypoints2d,
                            seq.confidence,
                            seq.intrinsics,
                            cfg,
                            seed=seed,
                            mode="per-frame",
                        )
                        acc1 = pt.accuracy(res.keypoints3d, seq.joints3d)
                        table1.append({"motion": motion, "seed": seed, "method": name,
                                       "r": r, "R": R, "D_mean_mm": acc1.mean_mm,
                                       "coverage": acc1.coverage})  # fmt: skip
            print(" | ".join(line) + f"  [{time.perf_counter() - t0:.0f}s]", flush=True)

    names = [*configs, "naive"]

    def mean_of(method, level=None, min_level=None):
        vals = [r["D_mean_mm"] for r in records if r["method"] == method
                and (level is None or r["level"] == level)
                and (min_level is None or r["level"] >= min_level)]  # fmt: skip
        return float(np.mean(vals)) if vals else float("nan")

    def std_of(method):
        return float(np.mean([r["D_std_mm"] for r in records if r["method"] == method]))

    def coverage_of(method, level=None, min_level=None):
        """Share of (frame, joint) pairs estimated: D skips the others, so a method that
        gives up on frames would look better by D alone."""
        vals = [r["coverage"] for r in records if r["method"] == method
                and (level is None or r["level"] == level)
                and (min_level is None or r["level"] >= min_level)]  # fmt: skip
        return float(np.mean(vals)) if vals else float("nan")

    summary = {
        "table2": {
            m: {
                "D_mean_mm": mean_of(m),
                "D_std_mm": std_of(m),
                "D_clean_mm": mean_of(m, level=0),
                "D_occluded_mm": mean_of(m, min_level=1),
                "coverage": coverage_of(m),
                "coverage_clean": coverage_of(m, level=0),
                "coverage_occluded": coverage_of(m, min_level=1),
            }
            for m in names
        },  # fmt: skip
        "fig5": {m: {lv: mean_of(m, level=lv) for lv in levels} for m in names},
        "fig5_coverage": {m: {lv: coverage_of(m, level=lv) for lv in levels} for m in names},
        "fig3": {
            m: [
                float(
                    np.mean(
                        np.where(np.isfinite(e := np.concatenate(errors[m]).ravel()), e, np.inf)
                        * 1000
                        < d
                    )
                )
                for d in curves_d
            ]
            for m in names
        },  # fmt: skip
    }
    t1, t1_cov = {}, {}
    for row in table1:
        key = (row["r"], row["R"])
        t1.setdefault(key, {}).setdefault(row["method"], []).append(row["D_mean_mm"])
        t1_cov.setdefault(key, {}).setdefault(row["method"], []).append(row["coverage"])
    summary["table1"] = [
        {"r": r, "R": R, **{m: float(np.mean(v)) for m, v in d.items()},
         "coverage": {m: float(np.mean(v)) for m, v in t1_cov[(r, R)].items()}}
        for (r, R), d in sorted(t1.items())
    ]  # fmt: skip
    for m in names:
        s = summary["table2"][m]
        base = summary["table2"][BASELINE.get(m, "LVM")]
        s["baseline"] = BASELINE.get(m, "LVM")
        s["gain_vs_LVM_occluded"] = 1 - s["D_occluded_mm"] / base["D_occluded_mm"]
        s["gain_vs_LVM_clean"] = 1 - s["D_clean_mm"] / base["D_clean_mm"]

    # -- print ----------------------------------------------------------------------------
    print(f"\nmachine: {machine_summary()}; {len(seqs)} sequences x {len(levels)} "
          f"occlusion levels, "
          f"{args.frames} frames each; {time.perf_counter() - t_start:.0f} s")  # fmt: skip

    # -- write ----------------------------------------------------------------------------
    write_figures(summary, levels, out)
    result = {"machine": machine_summary(), "frames": args.frames, "levels": list(levels),
              "table1_level": args.table1_level, "seconds": time.perf_counter() - t_start,
              "sequences": [{"motion": m, "seed": s} for m, s in seqs],
              "configs": {m: dataclasses.asdict(c) for m, c in configs.items()},
              "paper_only": {m: c.is_paper() for m, c in configs.items()},
              "summary": summary, "records": records, "table1_records": table1}  # fmt: skip
    from posetrack.io import atomic_write_text

    print("\n" + markdown_tables(result))
    atomic_write_text(out / "results.json", json.dumps(result, indent=1, default=str))
    print(
        f"\nwrote {out / 'results.json'}, {out / 'fig3_success.png'}, {out / 'fig5_occlusion.png'}"
    )
    return result


CURVES_D = np.arange(0, 301, 10)

# What each Table 2 row is, for the Markdown tables (rows not listed print without a setting).
SETTINGS = {
    "LVM (paper)": "the paper's baseline alone: LM on all landmarks, sum of norms",
    "MHT_r (paper)": "the paper's method alone, its best: N=20, r=0.05, R=0.15",
    "MHT_g (paper)": "the paper's method alone, its best: N=5, r=0.05, R=0.15",
    "MHT_h (paper)": "the paper's method alone, its best: N=5, r=R=0",
    "LVM": "LVM with our observation additions (surface offset, unknown depth, floor, depth band)",
    "MHT_r": "N=20, r=0.05, R=0.15 with all our additions",
    "MHT_g": "N=5, r=0.05, R=0.15 with all our additions",
    "MHT_h N=5": "shipped MHT_h with the paper's N=5",
    "MHT_h": "**shipped default**: N=10, all our additions, l2 loss, 4 LM steps",
    "LVM +refine": "LVM + dense refinement (3 steps)",
    "MHT_h +refine": "shipped + dense refinement (3 steps)",
    "naive": "each keypoint at its own depth (no model; the shipped lifting, depth band included)",
}


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def markdown_tables(saved: dict) -> str:
    """Table 2, Fig. 5 and Table 1 of a saved ``results.json`` as Markdown (for the READMEs).

    Every table shows the share of joints estimated beside D: D skips unestimated joints, so a
    method that gives up would look better by D alone."""
    summary, levels = saved["summary"], saved["levels"]
    t2, fig5 = summary["table2"], summary["fig5"]
    cov5 = summary.get("fig5_coverage", {})
    lines = [
        "**Table 2** (D in mm: mean over sequences of the per-sequence mean; std = mean of the "
        "per-sequence std over frames; est. = share of (frame, joint) pairs estimated, which D "
        "is computed on; gain = reduction of D against the baseline named):",
        "",
        "| method | setting | D mean | D std | est. | clean (level 0) | occluded (levels 1-4) "
        "| baseline | gain occluded | gain clean |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m, s in t2.items():
        lines.append(
            f"| {m} | {SETTINGS.get(m, '')} | {s['D_mean_mm']:.1f} | {s['D_std_mm']:.1f} "
            f"| {_pct(s.get('coverage', float('nan')))} "
            f"| {s['D_clean_mm']:.1f} | {s['D_occluded_mm']:.1f} | {s.get('baseline', 'LVM')} "
            f"| {_pct(s['gain_vs_LVM_occluded'])} | {_pct(s['gain_vs_LVM_clean'])} |"
        )
    head = " | ".join(f"level {lv}" for lv in levels)
    lines += ["", "**Fig. 5**: D (mm) per occlusion level (share of joints estimated)", "",
              f"| method | {head} | level {levels[-1]} / level {levels[0]} |",
              "|---|" + "---|" * (len(levels) + 1)]  # fmt: skip
    for m, row in fig5.items():
        vals = [row[str(lv)] if str(lv) in row else row[lv] for lv in levels]
        crow = cov5.get(m, {})
        covs = [crow.get(str(lv), crow.get(lv, float("nan"))) for lv in levels]
        cells = [f"{v:.1f} ({100 * c:.0f} %)" for v, c in zip(vals, covs)]
        lines.append(f"| {m} | " + " | ".join(cells) + f" | {vals[-1] / vals[0]:.2f} |")
    t1_names = [m for m in TABLE1_METHODS if any(m in row for row in summary["table1"])]
    lines += ["", f"**Table 1**: D (mm) over the (r, R) grid at occlusion level "
              f"{saved.get('table1_level', 2)}, the paper's methods alone (MHT_r N=20, MHT_g N=5, "
              "MHT_h N=5), with the share of joints estimated; N/A: r = R = 0 makes MHT_r's "
              "hypotheses identical, i.e. LVM", "",
              "| r | R | " + " | ".join(t1_names) + " |",
              "|---|---|" + "---|" * len(t1_names)]  # fmt: skip
    for row in summary["table1"]:
        cov = row.get("coverage", {})
        cells = [
            f"{row[m]:.1f} ({100 * cov[m]:.0f} %)" if m in row and m in cov
            else (f"{row[m]:.1f}" if m in row else "N/A")
            for m in t1_names
        ]  # fmt: skip
        lines.append(f"| {row['r']:.2f} | {row['R']:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_figures(summary: dict, levels, out: Path) -> None:
    """Fig. 3 and Fig. 5 as PNGs from the summary (also from a saved results.json)."""
    names = list(summary["fig5"])
    fig5_of = {m: {int(k): v for k, v in summary["fig5"][m].items()} for m in names}
    fig3 = line_plot(
        {m: (CURVES_D, np.asarray(summary["fig3"][m])) for m in names},
        title="Fig. 3: joint success rate C_j(d), all sequences and levels",
        xlabel="d (mm)", ylabel="C_j(d)", ylim=(0.0, 1.0),
    )  # fmt: skip
    fig5 = line_plot(
        {m: (list(levels), [fig5_of[m][lv] for lv in levels]) for m in names},
        title="Fig. 5: D vs occlusion level", xlabel="occlusion level", ylabel="D (mm)",
    )  # fmt: skip
    write_png(out / "fig3_success.png", fig3)
    write_png(out / "fig5_occlusion.png", fig5)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--quick", action="store_true", help="3 sequences at levels 0, 2, 4")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--table1-level", type=int, default=2)
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "accuracy"))
    p.add_argument(
        "--replot", action="store_true", help="only redraw the figures from --out/results.json"
    )
    p.add_argument(
        "--markdown", action="store_true",
        help="only print the tables of --out/results.json as Markdown",
    )  # fmt: skip
    args = p.parse_args(argv)
    if args.markdown:
        print(markdown_tables(json.loads((Path(args.out) / "results.json").read_text())))
        return 0
    if args.replot:
        out = Path(args.out)
        saved = json.loads((out / "results.json").read_text())
        write_figures(saved["summary"], saved["levels"], out)
        print(f"wrote {out / 'fig3_success.png'}, {out / 'fig5_occlusion.png'}")
        return 0
    run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
