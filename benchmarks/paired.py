"""Paired change of one tracker variant against another, over the runs of ``decide.py``.

A run is one clip at one occlusion level (``group, seed, motion, occ``); ``decide.py`` tracks
it with each tracker seed (``--tracker-seeds``: the hypotheses' random landmark subsets) and
every variant. The change of a run is the candidate's D minus the baseline's, averaged over
the tracker seeds the run has (the same seeds for both, so the pair shares every clip and
seed); the table gives, per group and occlusion and over all runs, the mean change, its
standard deviation and standard error over the runs, ``t`` = mean / standard error, the runs
better and worse by more than 5 mm, swapped-limb frames summed, and both variants' mean
acceleration error and coverage. ``spread`` is the baseline's own standard deviation of D
across tracker seeds, averaged over the runs: what a decision on one tracker seed would have
read as change.

Why (benchmarks/README.md, "A side view hides the far arm"): on a clip whose track comes
apart somewhere, the tracker seed alone moves D by 30-80 mm, so a mean change decided on one
seed is largely decided by which clips diverge under that seed.

    python benchmarks/paired.py RUNS.jsonl [MORE.jsonl ...] --candidate far1.0 [--json OUT]
    python benchmarks/paired.py RUNS.jsonl ... --spread default  # mean D per tracker seed
    python benchmarks/paired.py RUNS.jsonl ... --candidate follow0.4 --shared  # both answered
    python benchmarks/paired.py RUNS.jsonl ... --candidate alone30 --changed  # a rare event
    python benchmarks/paired.py RUNS.jsonl ... --candidate alone30 --changed --pooled
    python benchmarks/paired.py RUNS.jsonl ... --candidate follow0.4 --shared --null 2000
    python benchmarks/paired.py RUNS.jsonl ... --candidate X --shared --null 4000 --rule screen

``--shared``: D and swapped-limb frames over the frames both variants answered (what
``decide.py`` records against the first variant it tracks), for a change that answers frames
the baseline did not: over each version's own frames those frames' difficulty is charged to
it (benchmarks/README.md, "The follower's reference").

``--changed``: for a change that acts on a few runs in a hundred (a screen sized for a rare
event, benchmarks/README.md, "The only person in view, refused"), every run and tracker seed
whose D, coverage or swapped-limb frames differ, with its change on the frames both answered,
the frames each answers and the D of the frames only the candidate answers, then the totals.
With ``--pooled`` one line per run, its tracker seeds pooled (a rule that reads each run as the
mean of its seeds; ``--min-shared``: the frames a seed's both variants must share for its D
change to count).

``--null FLIPS``: how often the rule's D clauses would fail (or pass) a candidate with no
effect and this screen's spread (:func:`null_rule`): on occluded side views a run moves by
tens of mm with any change, and a cell clause at t >= 1 over six cells fails such a candidate
more often than not (benchmarks/README.md, "How often the rule fails a candidate with no
effect").

``--rule screen|report``: the verdict of the rule of 2026-12-07 (:func:`rule_verdict`), each
clause's outcome printed and stored with ``--json``; ``--wall RATIO`` adds the wall-time clause
(the median time per run, candidate over baseline)."""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

#: A run is better or worse when its change exceeds this (mm), as in decide's earlier tables.
CLEAR_MM = 5.0


def load(paths: list[str]) -> list[dict]:
    """The records of ``decide.py`` JSON-lines files, joined (:func:`join`); a line that is not
    a record is an error naming the file and line."""
    lines = []
    for path in paths:
        with open(path) as f:
            for n, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                    _key(rec)
                except (ValueError, KeyError) as e:
                    raise SystemExit(f"error: {path}:{n}: not a decide.py record ({e})") from None
                lines.append((rec, f"{path}:{n}"))
    return join(lines)


def _key(rec: dict) -> tuple:
    return rec["group"], rec["seed"], rec["motion"], rec["occ"], rec["tseed"]


def join(records: list[tuple[dict, str]]) -> list[dict]:
    """One record per clip, occlusion and tracker seed from ``(record, where)`` pairs: records
    of the same run and seed holding other variants (a variant run later beside stored ones)
    are merged; a variant seen twice for one run and seed is an error naming both places."""
    out, seen = {}, {}
    for rec, where in records:
        key = _key(rec)
        for name, value in rec.items():
            if not isinstance(value, dict):
                continue
            if (key, name) in seen:
                raise SystemExit(
                    f"error: {where}: clip {key[:4]} tracker seed {key[4]} variant {name!r} "
                    f"again (first at {seen[key, name]}): one per clip and seed"
                )
            seen[key, name] = where
        out.setdefault(key, {}).update(rec)
    return list(out.values())


def run_changes(records: list[dict], base: str, candidate: str, shared: bool = False) -> list[dict]:
    """One entry per run: its group, occlusion, tracker seeds, both variants' D averaged over
    them, the change and the baseline's spread (standard deviation over seeds; 0 with one).
    Every run must have both variants and the same tracker seeds as the others. ``shared``:
    D and swapped-limb frames over the frames both variants answered (the candidate's
    ``"shared"`` entry, recorded by ``decide.py`` against ``base``) instead of each
    variant's own frames."""
    runs = defaultdict(dict)
    for rec in records:
        for name in (base, candidate):
            if name not in rec:
                raise SystemExit(
                    f"error: clip {rec['group']} {rec['seed']} occ {rec['occ']} tracker seed "
                    f"{rec['tseed']} has no variant {name!r} (it has "
                    f"{sorted(k for k, v in rec.items() if isinstance(v, dict))})"
                )
        runs[(rec["group"], rec["seed"], rec["motion"], rec["occ"])][rec["tseed"]] = rec
    if not runs:
        raise SystemExit("error: no records")
    seed_sets = {key: sorted(by_seed) for key, by_seed in runs.items()}
    full = max(seed_sets.values(), key=len)
    short = [f"{k[0]} {k[1]} occ {k[3]}: {s}" for k, s in seed_sets.items() if s != full]
    if short:
        raise SystemExit(
            f"error: runs incomplete (tracker seeds {full} elsewhere): " + "; ".join(short[:5])
        )
    out = []
    for (group, seed, motion, occ), by_seed in runs.items():
        pick = {t: _measures(by_seed[t], base, candidate, shared) for t in full}
        b = np.array([pick[t][0]["D"] for t in full])
        c = np.array([pick[t][1]["D"] for t in full])
        out.append({
            "group": group, "seed": seed, "motion": motion, "occ": occ, "tseeds": full,
            "base_D": float(b.mean()), "candidate_D": float(c.mean()),
            "base_D_by_tseed": b.tolist(),
            "change": float((c - b).mean()), "spread": float(b.std(ddof=1)) if len(b) > 1 else 0.0,
            "base_swaps": sum(pick[t][0]["swaps"] for t in full),
            "candidate_swaps": sum(pick[t][1]["swaps"] for t in full),
            # (nan where a record predates the measure)
            **{f"{role}_{m}": float(np.mean([by_seed[t][name].get(m, math.nan) for t in full]))
               for role, name in (("base", base), ("candidate", candidate))
               for m in ("accel", "cov")},
        })  # fmt: skip
    return out


def _measures(rec: dict, base: str, candidate: str, shared: bool) -> tuple[dict, dict]:
    """The baseline's and the candidate's ``D`` and ``swaps`` in one record: each over its
    own frames, or (``shared``) over the frames both answered."""
    if not shared:
        return rec[base], rec[candidate]
    s = rec[candidate].get("shared")
    if s is None or s.get("vs") != base:
        raise SystemExit(
            f"error: clip {rec['group']} {rec['seed']} occ {rec['occ']} tracker seed "
            f"{rec['tseed']}: {candidate!r} has no shared-frame measures against {base!r} "
            f"(decide.py records them against the first variant tracked, from 2026-12-04)"
        )
    return {"D": s["base_D"], "swaps": s["base_swaps"]}, {"D": s["D"], "swaps": s["swaps"]}


def changed(records: list[dict], base: str, candidate: str, frames: int) -> list[dict]:
    """The records (one per run and tracker seed) whose ``candidate`` differs from ``base`` in
    D, coverage or swapped-limb frames, each with the change on the frames both answered
    (``shared``), the frames each answered (coverage x ``frames``, the clip's length; coverage
    counts joints, so this is approximate where a frame holds some joints only) and the D of
    the frames only the candidate answered (``new_D``, from its own-frame and shared-frame D
    weighted by those counts; nan where it answered none more)."""
    return [_seed_change(r, base, candidate, frames) for r in records if _moved(r, base, candidate)]


def _moved(rec: dict, base: str, candidate: str) -> bool:
    """Whether ``candidate`` differs from ``base`` in D, coverage or swapped-limb frames."""
    return not all(_same(rec[base][m], rec[candidate][m]) for m in ("D", "cov", "swaps"))


def _seed_change(rec: dict, base: str, candidate: str, frames: int) -> dict:
    """One record's row of :func:`changed`."""
    b, c = rec[base], rec[candidate]
    s = _measures(rec, base, candidate, True)
    n_b, n_c = _answered(b, frames), _answered(c, frames)
    n_s = c["shared"]["frames"]
    new = n_c - n_s
    new_D = (c["D"] * n_c - s[1]["D"] * n_s) / new if new > 0 else math.nan
    return {
        "group": rec["group"], "seed": rec["seed"], "motion": rec["motion"],
        "occ": rec["occ"], "tseed": rec["tseed"], "shared_frames": n_s,
        "base_frames": n_b, "candidate_frames": n_c,
        "base_shared_D": s[0]["D"], "candidate_shared_D": s[1]["D"],
        "change": s[1]["D"] - s[0]["D"], "new_D": new_D,
        "base_swaps": s[0]["swaps"], "candidate_swaps": s[1]["swaps"],
    }  # fmt: skip


def pooled_changed(
    records: list[dict], base: str, candidate: str, frames: int, min_shared: int = 30
) -> tuple[list[dict], dict]:
    """:func:`changed` with each run's tracker seeds pooled (a run changes when any of its
    seeds does), for a rule that reads each run as the mean of its seeds: ``(rows, totals)``.

    A seed's change is the candidate's D minus the baseline's on the frames both answered,
    counted only where they share at least ``min_shared`` frames (fewer are too few to judge a
    D on); a run's change is the mean over its counted seeds (NaN, and the run left out of the
    mean and the counts, where none counts). Frames and swapped-limb frames (on the shared
    frames, ``swaps``; on each variant's own, ``own_swaps``) are summed over the seeds. Totals:
    runs, changed runs, frames answered (and runs answering more than 2 % fewer), the mean
    change over every run that counts (unchanged runs at 0), the worst change and the changed
    runs worse / better by more than ``CLEAR_MM``, swaps of the changed runs, the D of the
    frames only the candidate answered against the changed runs' shared-frame D (both
    frame-weighted, every seed of a changed run), and both variants' mean acceleration error
    over all records."""
    run_changes(records, base, candidate, shared=True)  # both variants, seeds complete
    runs = defaultdict(list)
    for rec in records:
        runs[(rec["group"], rec["seed"], rec["motion"], rec["occ"])].append(rec)
    rows, all_changes = [], []
    new_sum = new_n = shared_sum = shared_n = 0.0
    for (group, seed, motion, occ), recs in runs.items():
        seeds = [_seed_change(r, base, candidate, frames) for r in recs]
        kept = [x["change"] for x in seeds if x["shared_frames"] >= min_shared]
        change = float(np.mean(kept)) if kept else math.nan
        if kept:
            all_changes.append(change)
        moved = sum(_moved(r, base, candidate) for r in recs)
        if not moved:
            continue
        for x in seeds:
            new = x["candidate_frames"] - x["shared_frames"]
            if new > 0:  # the frames only the candidate answered
                new_sum += x["new_D"] * new
                new_n += new
            if x["shared_frames"]:
                shared_sum += x["candidate_shared_D"] * x["shared_frames"]
                shared_n += x["shared_frames"]
        rows.append({
            "group": group, "seed": seed, "motion": motion, "occ": occ,
            "tseeds": sorted(r["tseed"] for r in recs), "seeds_changed": moved,
            "seeds_counted": len(kept),
            "base_frames": sum(x["base_frames"] for x in seeds),
            "candidate_frames": sum(x["candidate_frames"] for x in seeds),
            "change": change,
            "swaps": [sum(x[k] for x in seeds) for k in ("base_swaps", "candidate_swaps")],
            "own_swaps": [sum(r[v]["swaps"] for r in recs) for v in (base, candidate)],
        })  # fmt: skip
    counted = [r for r in rows if not math.isnan(r["change"])]
    totals = {
        "runs": len(runs), "changed": len(rows),
        "base_frames": sum(_answered(r[base], frames) for r in records),
        "candidate_frames": sum(_answered(r[candidate], frames) for r in records),
        "fewer_2pct": sum(r["candidate_frames"] < 0.98 * r["base_frames"] for r in rows),
        "runs_counted": len(all_changes),
        "mean_change": float(np.mean(all_changes)) if all_changes else math.nan,
        "worst_change": max((r["change"] for r in counted), default=math.nan),
        "worse_5mm": sum(r["change"] > CLEAR_MM for r in counted),
        "better_5mm": sum(r["change"] < -CLEAR_MM for r in counted),
        "swaps_changed": [sum(r["swaps"][i] for r in rows) for i in (0, 1)],
        "own_swaps_changed": [sum(r["own_swaps"][i] for r in rows) for i in (0, 1)],
        "new_D": new_sum / new_n if new_n else math.nan, "new_frames": int(new_n),
        "changed_shared_D": shared_sum / shared_n if shared_n else math.nan,
        "accel": [float(np.mean([r[v]["accel"] for r in records])) for v in (base, candidate)],
    }  # fmt: skip
    return rows, totals


def _same(x: float, y: float) -> bool:
    """Equal, or both NaN (a D over no frames)."""
    return x == y or (math.isnan(x) and math.isnan(y))


def _answered(measures: dict, frames: int) -> int:
    """Frames a variant answered in a clip of ``frames``: its coverage x ``frames``."""
    return round(measures["cov"] * frames)


def summary(runs: list[dict]) -> dict:
    """Mean change over ``runs``, its standard deviation, standard error and t, the runs better
    and worse by more than ``CLEAR_MM``, swapped-limb frames summed, the mean spread, and both
    variants' mean acceleration error (mm/frame^2) and coverage."""
    change = np.array([r["change"] for r in runs])
    n = len(change)
    sd = float(change.std(ddof=1)) if n > 1 else math.nan
    se = sd / math.sqrt(n) if n > 1 else math.nan
    mean, t = _t(change)
    return {
        "runs": n, "base_D": float(np.mean([r["base_D"] for r in runs])),
        "candidate_D": float(np.mean([r["candidate_D"] for r in runs])),
        "change": mean, "sd": sd, "se": se,
        "t": t,
        "better": int((change < -CLEAR_MM).sum()), "worse": int((change > CLEAR_MM).sum()),
        "base_swaps": sum(r["base_swaps"] for r in runs),
        "candidate_swaps": sum(r["candidate_swaps"] for r in runs),
        "spread": float(np.mean([r["spread"] for r in runs])),
        **{f"{role}_{m}": float(np.mean([r[f"{role}_{m}"] for r in runs]))
           for role in ("base", "candidate") for m in ("accel", "cov")},
    }  # fmt: skip


def _t(values: np.ndarray) -> tuple[float, float]:
    """Mean and t (mean / standard error) of ``values``; t 0 for no change, +-inf for a
    change without spread."""
    mean = float(values.mean())
    se = float(values.std(ddof=1)) / math.sqrt(len(values)) if len(values) > 1 else math.nan
    if se and se > 0:
        return mean, mean / se
    return mean, 0.0 if mean == 0 else math.copysign(math.inf, mean)


def coverage_clause(runs: list[dict]) -> dict:
    """The coverage clause of benchmarks/README.md ("`bound_trusted` under a coverage clause
    judged like D"): each run's change is the candidate's coverage minus the baseline's, each
    the mean over its tracker seeds. It fails iff (a) the mean over all runs is below -0.0025
    with t <= -2, or below -0.015 whatever its t; or (b) a group x occlusion cell's mean is
    below -0.025 with t <= -1.5, or below -0.06 whatever its t."""
    cells = []
    for label, rs in _groups(runs):
        mean, t = _t(np.array([r["candidate_cov"] - r["base_cov"] for r in rs]))
        cells.append({"label": label, "runs": len(rs), "mean": mean, "t": t})
    every = cells[-1]
    fails_all = (every["mean"] < -0.0025 and every["t"] <= -2) or every["mean"] < -0.015
    failing = [c["label"] for c in cells[:-1]
               if (c["mean"] < -0.025 and c["t"] <= -1.5) or c["mean"] < -0.06]  # fmt: skip
    worst = min(cells[:-1], key=lambda c: c["mean"])
    return {"holds": not fails_all and not failing, "all": every, "worst_cell": worst,
            "failing_cells": failing, "cells": cells}  # fmt: skip


#: The stages of the rule of 2026-12-07 (benchmarks/README.md, "How often the rule fails a
#: candidate with no effect"; its report stage as in "`bound_trusted` online, under the rule of
#: 2026-12-07"): a screen on fresh tuning seeds, then the report sets.
RULE_STAGES = ("screen", "report")


def rule_verdict(
    runs: list[dict], records: list[dict] | None = None, stage: str = "screen",
    wall_max: float | None = None, base: str = "default", candidate: str | None = None,
) -> dict:
    """The verdict of the rule of 2026-12-07 on ``runs`` (:func:`run_changes`). A screen
    passes iff the mean change over all runs is below 0 with t <= -2; no group x occlusion
    cell is worse by more than 1 mm with t >= 2; the swapped-limb frames do not rise; the mean
    acceleration error rises by at most 10 %; and :func:`coverage_clause` holds. The report
    stage asks the mean below 0 (any t), the same cell clause, swapped-limb frames up by at
    most 10 %, and the rest as the screen. ``wall_max``: also the median over ``records``
    (:func:`load`) of the candidate's wall time per run (``"s"``) at most that many times the
    baseline's (issue 12's online budget: 1.3)."""
    if stage not in RULE_STAGES:
        raise ValueError(f"stage must be one of {RULE_STAGES}, got {stage!r}")
    rows = table(runs)
    every = rows[-1][1]
    mean_ok = every["change"] < 0 and (stage == "report" or every["t"] <= -2)
    failing = [label for label, s in rows[:-1] if s["change"] > 1.0 and s["t"] >= 2]
    swap_limit = every["base_swaps"] * (1.10 if stage == "report" else 1.0)
    clauses = {
        "mean": mean_ok,
        "cells": not failing,
        "swaps": every["candidate_swaps"] <= swap_limit,
        "accel": every["candidate_accel"] <= 1.10 * every["base_accel"],
        "coverage": coverage_clause(runs)["holds"],
    }
    out = {"stage": stage, "failing_cells": failing}
    if wall_max is not None:
        if records is None or candidate is None:
            raise ValueError("wall_max needs the records and the candidate's name")
        ratio = float(np.median([r[candidate]["s"] for r in records])
                      / np.median([r[base]["s"] for r in records]))  # fmt: skip
        out["wall_ratio"] = ratio
        clauses["wall"] = ratio <= wall_max
    return {**out, "clauses": clauses, "passed": all(clauses.values())}


def null_rule(
    runs: list[dict],
    flips: int = 2000,
    seed: int = 0,
    cell_mm: float = 1.0,
    cell_t: tuple[float, ...] = (1.0, 1.5, 2.0, 2.5),
    mean_t: tuple[float, ...] = (1.0, 2.0),
) -> dict:
    """How often the D rule's clauses decide a candidate with **no effect** and this screen's
    spread. Each run's change is multiplied by a random sign (its two variants exchanged: with
    no effect either order is as likely), ``flips`` times; per threshold T in ``cell_t``,
    ``cell_fails`` is the share of flips in which some group x occlusion cell is worse by more
    than ``cell_mm`` with t >= T (the cell clause, T = 1 in the rules so far), and per T in
    ``mean_t`` ``mean_passes`` the share in which the mean over all runs is below 0 with
    t <= -T (the mean clause, T = 1 so far). Runs are read as :func:`run_changes` gives them
    (each the mean of its tracker seeds)."""
    cells = [np.array([r["change"] for r in rs]) for _, rs in _groups(runs)[:-1]]
    bounds = np.cumsum([len(c) for c in cells])[:-1]
    rng = np.random.default_rng(seed)
    fails = {t: 0 for t in cell_t}
    passes = {t: 0 for t in mean_t}
    for _ in range(flips):
        signs = np.split(rng.choice((-1.0, 1.0), size=len(runs)), bounds)
        flipped = [c * s for c, s in zip(cells, signs)]
        stats = [_t(c) for c in flipped]
        for t_min in cell_t:
            fails[t_min] += any(m > cell_mm and t >= t_min for m, t in stats)
        mean, t = _t(np.concatenate(flipped))
        for t_min in mean_t:
            passes[t_min] += mean < 0 and t <= -t_min
    return {
        "flips": flips, "seed": seed, "cell_mm": cell_mm,
        "cell_fails": {str(t): fails[t] / flips for t in cell_t},
        "mean_passes": {str(t): passes[t] / flips for t in mean_t},
    }  # fmt: skip


def table(runs: list[dict]) -> list[tuple[str, dict]]:
    """``(label, summary)`` per group and occlusion (in the runs' order), then over all."""
    return [(label, summary(rs)) for label, rs in _groups(runs)]


def _groups(runs: list[dict]) -> list[tuple[str, list[dict]]]:
    """The runs per group and occlusion (in the runs' order), then all of them."""
    rows = {}
    for r in runs:
        occ = "clean" if r["occ"] == 0 else f"occlusion {r['occ']}"
        rows.setdefault(f"{r['group']}, {occ}", []).append(r)
    return [*rows.items(), ("all", runs)]


def seed_means(records: list[dict], variant: str) -> list[tuple[str, dict]]:
    """How much a variant's reported means move with the tracker seed alone: per group and
    occlusion (then over all runs) each tracker seed's mean D over the runs, and the mean of
    the runs' own standard deviations over seeds (``spread``). Every run must have the same
    seeds (as :func:`run_changes` checks)."""
    out = []
    for label, runs in _groups(run_changes(records, variant, variant)):
        by_seed = np.mean([r["base_D_by_tseed"] for r in runs], axis=0)
        out.append((label, {
            "D_by_tseed": {t: float(d) for t, d in zip(runs[0]["tseeds"], by_seed)},
            "runs": len(runs), "spread": float(np.mean([r["spread"] for r in runs])),
        }))  # fmt: skip
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", help="decide.py JSON-lines files")
    ap.add_argument("--base", default="default", help="the baseline variant (default: default)")
    ap.add_argument("--candidate", help="the variant whose change is read")
    ap.add_argument(
        "--spread", metavar="VARIANT",
        help="instead: that variant's mean D per tracker seed (how much a reported mean moves "
        "with the seed alone)",
    )  # fmt: skip
    ap.add_argument(
        "--shared", action="store_true",
        help="D and swapped-limb frames over the frames both variants answered (decide.py's "
        "'shared' measures) instead of each variant's own frames; coverage as always",
    )  # fmt: skip
    ap.add_argument(
        "--changed", action="store_true",
        help="instead: the runs whose D, coverage or swaps differ, one line each, then totals",
    )  # fmt: skip
    ap.add_argument(
        "--pooled", action="store_true",
        help="with --changed: one line per run, its tracker seeds pooled (the mean change over "
        "the seeds sharing at least --min-shared frames)",
    )  # fmt: skip
    ap.add_argument(
        "--min-shared", type=int, default=30,
        help="with --pooled: a seed's D change counts where both answer this many frames (30)",
    )  # fmt: skip
    ap.add_argument("--frames", type=int, default=120, help="frames per clip (decide.py: 120)")
    ap.add_argument(
        "--null", type=int, metavar="FLIPS",
        help="with --candidate: also how often the D rule's cell and mean clauses decide a "
        "candidate with no effect and this spread (FLIPS random sign flips of the runs' changes)",
    )  # fmt: skip
    ap.add_argument(
        "--rule", choices=RULE_STAGES,
        help="with --candidate: print the verdict of the rule of 2026-12-07 at this stage "
        "(benchmarks/README.md; rule_verdict) and store it with --json",
    )  # fmt: skip
    ap.add_argument(
        "--wall", type=float, metavar="RATIO",
        help="with --rule: also the median wall time per run at most RATIO x the baseline's",
    )  # fmt: skip
    ap.add_argument("--json", help="write the runs and the table here")
    a = ap.parse_args()
    for path in a.runs:
        if not Path(path).is_file():
            ap.error(f"{path}: no such file")
    if (a.candidate is None) == (a.spread is None):
        ap.error("give one of --candidate and --spread")
    if a.spread:
        rows = seed_means(load(a.runs), a.spread)
        seeds = list(rows[-1][1]["D_by_tseed"])
        print(f"{a.spread}: mean D mm (13 joints) per tracker seed; spread = the runs' own sd")
        print(f"{'runs':<34} {'n':>3} " + " ".join(f"{'seed ' + str(t):>8}" for t in seeds)
              + f" {'range':>6} {'spread':>6}")  # fmt: skip
        for label, r in rows:
            ds = list(r["D_by_tseed"].values())
            print(f"{label:<34} {r['runs']:>3} " + " ".join(f"{d:>8.2f}" for d in ds)
                  + f" {max(ds) - min(ds):>6.2f} {r['spread']:>6.1f}")  # fmt: skip
        if a.json:
            doc = {"variant": a.spread, "files": a.runs}
            doc["table"] = [{"label": label, **r} for label, r in rows]
            Path(a.json).write_text(json.dumps(doc, indent=1) + "\n")
        return 0
    if a.pooled and not a.changed:
        ap.error("--pooled goes with --changed")
    if a.changed and a.pooled:
        return _print_pooled(load(a.runs), a.base, a.candidate, a.frames, a.min_shared, a.json)
    if a.changed:
        return _print_changed(load(a.runs), a.base, a.candidate, a.frames, a.json)
    if a.wall is not None and a.rule is None:
        ap.error("--wall goes with --rule")
    records = load(a.runs)
    runs = run_changes(records, a.base, a.candidate, shared=a.shared)
    rows = table(runs)
    print(
        f"{a.candidate} - {a.base}, D mm (13 joints"
        + (", frames both answered" if a.shared else "")
        + f"), each run averaged over tracker seeds {runs[0]['tseeds']}"
    )
    head = f"{'runs':<28} {'n':>3} {'base':>7} {'cand':>7} {'change':>7} {'se':>5} {'t':>6}"
    print(
        head + f" {'better/worse':>12} {'swaps':>10} {'spread':>6} {'accel':>11} {'coverage':>11}"
    )
    for label, s in rows:
        print(
            f"{label:<28} {s['runs']:>3} {s['base_D']:>7.2f} {s['candidate_D']:>7.2f} "
            f"{s['change']:>+7.2f} {s['se']:>5.2f} {s['t']:>+6.2f} "
            f"{s['better']:>5} / {s['worse']:<4} {s['base_swaps']:>4}->{s['candidate_swaps']:<4} "
            f"{s['spread']:>6.1f} {s['base_accel']:>5.2f}->{s['candidate_accel']:<5.2f} "
            f"{s['base_cov']:.3f}->{s['candidate_cov']:.3f}"
        )
    clause = coverage_clause(runs)
    worst, failing = clause["worst_cell"], clause["failing_cells"]
    print(
        f"coverage clause {'holds' if clause['holds'] else 'FAILS'}: mean change over all runs "
        f"{clause['all']['mean']:+.4f} (t {clause['all']['t']:+.2f}); worst cell "
        f"{worst['label']} {worst['mean']:+.4f} (t {worst['t']:+.2f})"
        + ("; failing cells: " + ", ".join(failing) if failing else "")
    )
    null = None
    if a.null:
        null = null_rule(runs, flips=a.null)
        print(
            f"with no effect and this spread ({a.null} sign flips): some cell worse by more "
            f"than {null['cell_mm']:g} mm with t >= "
            + ", ".join(f"{t}: {p:.2f}" for t, p in null["cell_fails"].items())
            + "; mean below 0 with t <= -"
            + ", -".join(f"{t}: {p:.2f}" for t, p in null["mean_passes"].items())
        )
    verdict = None
    if a.rule:
        verdict = rule_verdict(runs, records, a.rule, a.wall, a.base, a.candidate)
        print(
            f"rule of 2026-12-07, {a.rule}: {'PASSES' if verdict['passed'] else 'FAILS'} ("
            + ", ".join(f"{k} {'ok' if ok else 'FAILS'}" for k, ok in verdict["clauses"].items())
            + (f"; wall time ratio {verdict['wall_ratio']:.3f}" if "wall_ratio" in verdict else "")
            + (f"; failing cells: {', '.join(verdict['failing_cells'])}"
               if verdict["failing_cells"] else "")  # fmt: skip
            + ")"
        )
    if a.json:
        doc = {"base": a.base, "candidate": a.candidate, "files": a.runs, "runs": runs,
               "shared": a.shared, "coverage_clause": clause}  # fmt: skip
        if null is not None:
            doc["null"] = null
        if verdict is not None:
            doc["rule"] = verdict
        doc["table"] = [{"label": label, **s} for label, s in rows]
        Path(a.json).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


def _print_changed(records: list[dict], base: str, candidate: str, frames: int, out) -> int:
    rows = changed(records, base, candidate, frames)
    print(f"{candidate} - {base}: {len(rows)} of {len(records)} runs x tracker seeds changed; "
          "D mm (13 joints) on the frames both answered; new = frames only the candidate "
          "answered")  # fmt: skip
    print(f"{'run':<48} {'frames':>11} {'base':>7} {'cand':>7} {'change':>7} {'new D':>7} "
          f"{'swaps':>9}")  # fmt: skip
    for r in rows:
        name = f"{r['group']} {r['seed']} {r['motion']} occ {r['occ']} t{r['tseed']}"
        print(f"{name[:48]:<48} {r['base_frames']:>4}->{r['candidate_frames']:<5} "
              f"{r['base_shared_D']:>7.1f} {r['candidate_shared_D']:>7.1f} {r['change']:>+7.1f} "
              f"{r['new_D']:>7.1f} {r['base_swaps']:>3}->{r['candidate_swaps']:<4}")  # fmt: skip
    all_runs = run_changes(records, base, candidate, shared=True)
    new = [(r["new_D"], r["candidate_frames"] - r["shared_frames"]) for r in rows]
    new = [(d, n) for d, n in new if n > 0]
    n_s = sum(r["shared_frames"] for r in rows)
    totals = {
        "runs": len(records), "changed": len(rows),
        "base_frames": sum(_answered(r[base], frames) for r in records),
        "candidate_frames": sum(_answered(r[candidate], frames) for r in records),
        "mean_change_all": float(np.mean([r["change"] for r in all_runs])),
        "worst_change": max((r["change"] for r in rows), default=0.0),
        "worse_5mm": sum(r["change"] > CLEAR_MM for r in rows),
        "better_5mm": sum(r["change"] < -CLEAR_MM for r in rows),
        "more_frames": sum(r["candidate_frames"] > r["base_frames"] for r in rows),
        "fewer_frames": sum(r["candidate_frames"] < r["base_frames"] for r in rows),
        "swaps_changed": [sum(r["base_swaps"] for r in rows),
                          sum(r["candidate_swaps"] for r in rows)],
        "new_D": sum(d * n for d, n in new) / sum(n for _, n in new) if new else math.nan,
        "changed_shared_D": sum(r["candidate_shared_D"] * r["shared_frames"] for r in rows) / n_s
        if n_s else math.nan,
        "accel": [float(np.mean([r[v]["accel"] for r in records])) for v in (base, candidate)],
    }  # fmt: skip
    for k, v in totals.items():
        print(f"  {k}: {v}")
    if out:
        doc = {"base": base, "candidate": candidate, "changed": rows, "totals": totals}
        Path(out).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


def _print_pooled(records, base, candidate, frames, min_shared, out) -> int:
    rows, totals = pooled_changed(records, base, candidate, frames, min_shared)
    print(f"{candidate} - {base}: {len(rows)} of {totals['runs']} runs changed (tracker seeds "
          f"pooled); D mm (13 joints) on the frames both answered, mean over the seeds sharing "
          f">= {min_shared} frames")  # fmt: skip
    print(f"{'run':<44} {'seeds':>9} {'frames':>11} {'change':>7} {'swaps':>9}")
    for r in rows:
        name = f"{r['group']} {r['seed']} {r['motion']} occ {r['occ']}"
        print(f"{name[:44]:<44} {r['seeds_changed']:>3} ch {r['seeds_counted']:>1} n "
              f"{r['base_frames']:>4}->{r['candidate_frames']:<5} {r['change']:>+7.1f} "
              f"{r['swaps'][0]:>3}->{r['swaps'][1]:<4}")  # fmt: skip
    for k, v in totals.items():
        print(f"  {k}: {v}")
    if out:
        doc = {"base": base, "candidate": candidate, "min_shared": min_shared, "changed": rows,
               "totals": totals}  # fmt: skip
        Path(out).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
