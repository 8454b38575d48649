"""Which judge tells the better of two tracker seeds' tracks (issue 12, a look, no decision).

The tracker seed alone (the hypotheses' random landmark subsets) moves a clip's D by sd 7 mm,
12-14 mm on wide side views and occluded real motion (``results/seed_noise_look.json``), and
the per-frame pass's mean Delta does not tell which seed's track is the better one. A judge
that did would let a multi-start tracker keep the better track. This tracks tuning clips with
the shipped offline tracker under two tracker seeds and records, beside D (against the
truth), judges the tracker could compute itself from a finished track (lower = better):

* ``delta_pf``: mean Delta (Eq. (3)) of the per-frame poses (what ``decide.py`` records);
* ``delta_final``: mean Delta of the final (smoothed, shape-refined) poses, rendered with the
  track's own shape and scored like a hypothesis, centred on the pose's own root;
* ``delta_p90``: the 90th percentile of those per-frame Deltas (where a track came apart);
* ``kp2d``: mean image distance (px, capped at ``CAP_PX``) between the final keypoints
  projected and the confident detections (confidence > 0.3);
* ``lm3d``: mean distance (mm, capped at ``CAP_MM``) between the final keypoints and the
  lifted landmarks where depth was valid;
* ``pf_gap``: mean distance (mm) between the per-frame and the final body joints (how much
  the motion model had to move the per-frame track);
* ``accel_self``: the final track's own mean acceleration (mm/frame^2, body joints).

Per clip and occlusion the two seeds form a pair; for each judge the summary gives the
correlation of its change with D's change, how often the lower judge is the lower D (all
pairs, and pairs whose D differs by more than 5 mm), and D of picking the lower judge against
a random seed (mean and SE over pairs) and against the oracle. Tuning seeds only.

    python benchmarks/seed_judges.py run OUT.jsonl --real-seeds 1202-1209 \\
        --procedural-seeds 1210-1215 --standard-seeds 1216-1221 --side-seeds 1222-1225 \\
        [--part 0 --parts 2]
    python benchmarks/seed_judges.py summary OUT.jsonl [MORE.jsonl] --json RESULT.json
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
import warnings
from collections import defaultdict

import jax
import jax.numpy as jnp
import numpy as np
from decide import clips, settings
from parts import add_part_arguments, check_part, share
from seeds import parse_seeds
from tune import decision_measures

import posetrack as pt
from posetrack._body import BODY_JOINTS
from posetrack._camera import project_host
from posetrack._depthobs import NO_FLOOR, tracker_observation
from posetrack._step import score_hypotheses

#: Caps of the per-keypoint distances (a detector outlier should not decide alone).
CAP_PX = 25.0
CAP_MM = 150.0
#: Confidence above which a detection counts (the tracker's own threshold).
CONF = 0.3
#: A pair whose two seeds' D differ by more than this (mm) is a "big" pair.
BIG_MM = 5.0
JUDGES = ("delta_pf", "delta_final", "delta_p90", "kp2d", "lm3d", "pf_gap", "accel_self")


def final_deltas(config, shape, intrinsics, depth_m, params, floor) -> np.ndarray:
    """(T,) Delta of each frame's pose ``params[t]`` against its own depth frame, scored as
    the tracker scores a hypothesis (observation centred on the pose's root)."""

    @jax.jit
    def score(d, p, fl):
        z_d, z_fg, known, small = tracker_observation(config, d, intrinsics, fl, p[:3])
        return score_hypotheses(config, shape, p[None], z_d, z_fg, small, known)[0]

    fl = jnp.asarray(NO_FLOOR if floor is None else floor, jnp.float32)
    return np.array([float(score(d, p, fl)) for d, p in zip(depth_m, params)])


def _body_accel(kp: np.ndarray) -> np.ndarray:
    """(T - 2, 13) a track's own body-joint accelerations, mm/frame^2 (frames 1..T-2)."""
    body = list(BODY_JOINTS)
    return np.linalg.norm(kp[2:, body] - 2 * kp[1:-1, body] + kp[:-2, body], axis=-1) * 1000.0


def judges(seq, res, config) -> dict:
    """The judges of the module docstring for one finished track ``res`` of ``seq``."""
    ok = res.status == 0
    depth_m = seq.depth.astype(np.float32) / np.float32(1000.0)
    deltas = final_deltas(config, res.shape, seq.intrinsics, depth_m, res.params, res.floor)
    kp = res.keypoints3d
    uv = project_host(seq.intrinsics, kp)
    det = seq.keypoints2d if seq.keypoints2d.ndim == 3 else seq.keypoints2d[:, 0]
    conf = seq.confidence if seq.confidence.ndim == 2 else seq.confidence[:, 0]
    seen = (conf > CONF) & ok[:, None] & np.isfinite(uv).all(-1)
    px = np.minimum(np.linalg.norm(uv - det, axis=-1), CAP_PX)
    lm = res.has_depth & ok[:, None] & np.isfinite(kp).all(-1)
    mm = np.minimum(np.linalg.norm(kp - res.landmarks3d, axis=-1) * 1000.0, CAP_MM)
    body = list(BODY_JOINTS)
    pf = res.per_frame_keypoints3d if res.per_frame_keypoints3d is not None else kp
    gap = np.linalg.norm(pf[:, body] - kp[:, body], axis=-1) * 1000.0
    acc = _body_accel(kp)
    return {
        "delta_pf": float(np.nanmean(np.where(ok, res.delta, np.nan))),
        "delta_final": float(np.nanmean(np.where(ok, deltas, np.nan))),
        "delta_p90": float(np.nanpercentile(np.where(ok, deltas, np.nan), 90)),
        "kp2d": float(px[seen].mean()),
        "lm3d": float(mm[lm].mean()),
        "pf_gap": float(np.nanmean(gap[ok])),
        "accel_self": float(np.nanmean(acc)),
    }


def profiles(kp: np.ndarray, truth: np.ndarray) -> dict:
    """Per-frame ``err_t`` (mean body-joint error, mm; NaN where not estimated) and ``acc_t``
    (the track's own mean body-joint acceleration, mm/frame^2, frames 1..T-2), rounded to
    0.1: what the windowed splice of :func:`splice_summary` reads."""
    err = np.nanmean(pt.joint_errors(kp, truth), axis=1) * 1000.0
    acc = np.nanmean(_body_accel(kp), axis=1)
    return {
        "err_t": [round(float(v), 1) for v in err],
        "acc_t": [round(float(v), 1) for v in acc],
    }


def splice_summary(pairs: list[tuple[dict, dict]], window: int) -> dict:
    """Per window of ``window`` frames, keep the seed whose track accelerates less there
    (``acc_t``); the spliced track's frame-mean error against a random seed's and the
    window-wise oracle's (seams ignored: an upper bound of what a local restart could buy)."""
    with warnings.catch_warnings():  # a window of lost frames is all NaN: the first seed kept
        warnings.simplefilter("ignore", RuntimeWarning)
        return _splice(pairs, window)


def _splice(pairs: list[tuple[dict, dict]], window: int) -> dict:
    pick, rand, oracle = [], [], []
    for a, b in pairs:
        ea, eb = np.array(a["err_t"]), np.array(b["err_t"])
        # acc_t[k] is frame k + 1's; pad to T with the edge values
        aa, ab = (np.pad(np.array(r["acc_t"]), 1, mode="edge") for r in (a, b))
        out_p, out_o = [], []
        for s in range(0, len(ea), window):
            w = slice(s, s + window)
            take_b = np.nanmean(ab[w]) < np.nanmean(aa[w])
            out_p.append(eb[w] if take_b else ea[w])
            out_o.append(eb[w] if np.nanmean(eb[w]) < np.nanmean(ea[w]) else ea[w])
        pick.append(np.nanmean(np.concatenate(out_p)))
        oracle.append(np.nanmean(np.concatenate(out_o)))
        rand.append((np.nanmean(ea) + np.nanmean(eb)) / 2)
    gain = np.array(pick) - np.array(rand)
    return {
        "window": window,
        "pick_vs_random": float(gain.mean()),
        "pick_vs_random_se": _se(gain),
        "oracle_vs_random": float((np.array(oracle) - np.array(rand)).mean()),
    }


def run(a) -> None:
    side, real, procedural, standard = (
        None if text is None else parse_seeds(text)
        for text in (a.side_seeds, a.real_seeds, a.procedural_seeds, a.standard_seeds)
    )
    chosen = clips(real, side, False, procedural, standard)
    seeds = [int(s) for s in a.tracker_seeds.split(",")]
    todo = share([(c, occ, ts) for c in chosen for occ in (0, 2) for ts in seeds], a)
    kwargs = settings("default", "offline")
    with open(a.out, "a") as f:
        for (group, seed, motion, variety), occ, ts in todo:
            seq = pt.synth.generate(
                seed, motion=motion, n_frames=120, fps=30.0, occlusion_level=occ, width=320,
                height=240, with_rgb=False, variety=variety,
            )  # fmt: skip
            t0 = time.perf_counter()
            tr = pt.Tracker(seq.intrinsics, mode="offline", seed=ts, **kwargs)
            res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
            s = time.perf_counter() - t0
            rec = {"group": group, "seed": seed, "motion": motion, "occ": occ, "tseed": ts}
            rec.update(decision_measures(res.keypoints3d, seq.joints3d), s=s)
            rec.update(judges(seq, res, tr.config))
            rec.update(profiles(res.keypoints3d, seq.joints3d))
            f.write(json.dumps(rec) + "\n")
            f.flush()
            print(json.dumps(rec), flush=True)


def _pairs(rows: list[dict]) -> list[tuple[dict, dict]]:
    by = defaultdict(dict)
    for r in rows:
        by[r["group"], r["seed"], r["occ"]][r["tseed"]] = r
    out = []
    for key, seeds in sorted(by.items()):
        if len(seeds) != 2:
            raise SystemExit(f"error: {key}: tracker seeds {sorted(seeds)}, need exactly two")
        a, b = (seeds[s] for s in sorted(seeds))
        out.append((a, b))
    return out


def _se(x: np.ndarray) -> float:
    """Standard error of the mean (NaN for fewer than two values)."""
    return float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")


def judge_summary(pairs: list[tuple[dict, dict]], judge: str) -> dict:
    """How well ``judge`` (lower = better) picks the lower-D track of each pair."""
    dD = np.array([b["D"] - a["D"] for a, b in pairs])
    dJ = np.array([b[judge] - a[judge] for a, b in pairs])
    pick = np.array([b["D"] if b[judge] < a[judge] else a["D"] for a, b in pairs])
    rand = np.array([(a["D"] + b["D"]) / 2 for a, b in pairs])
    oracle = np.array([min(a["D"], b["D"]) for a, b in pairs])
    right = np.sign(dJ) == np.sign(dD)
    big = np.abs(dD) > BIG_MM
    gain = pick - rand
    return {
        "corr": float(np.corrcoef(dJ, dD)[0, 1]),
        "right": int(right.sum()),
        "right_big": int(right[big].sum()),
        "big": int(big.sum()),
        "pairs": len(pairs),
        "pick_vs_random": float(gain.mean()),
        "pick_vs_random_se": _se(gain),
        "oracle_vs_random": float((oracle - rand).mean()),
    }


def summary(a) -> int:
    rows = []
    for path in a.files:
        with open(path) as f:
            rows += [json.loads(line) for line in f if line.strip()]
    pairs = _pairs(rows)
    out = {j: judge_summary(pairs, j) for j in JUDGES}
    groups = defaultdict(list)
    for p in pairs:
        groups[f"{p[0]['group']}, occlusion {p[0]['occ']}"].append(p)
    by_group = {g: {j: judge_summary(ps, j) for j in JUDGES} for g, ps in groups.items()}
    print(f"{len(pairs)} pairs, {int(out['delta_pf']['big'])} with |dD| > {BIG_MM:g} mm")
    print(f"{'judge':12s} {'corr':>6s} {'right':>6s} {'big':>6s} {'pick-rnd':>9s} {'SE':>5s}")
    for j, s in out.items():
        print(
            f"{j:12s} {s['corr']:6.2f} {s['right']:3d}/{s['pairs']:<2d} "
            f"{s['right_big']:2d}/{s['big']:<3d} {s['pick_vs_random']:9.2f} "
            f"{s['pick_vs_random_se']:5.2f}"
        )
    print(f"oracle vs random: {out['delta_pf']['oracle_vs_random']:.2f} mm")
    splices = []
    if all("err_t" in r for r in rows):
        for w in (15, 30, 60):
            sp = splice_summary(pairs, w)
            splices.append(sp)
            print(
                f"splice by acceleration, {w}-frame windows: {sp['pick_vs_random']:.2f} "
                f"(SE {sp['pick_vs_random_se']:.2f}), window oracle {sp['oracle_vs_random']:.2f}"
            )
    if a.json:
        doc = {
            "what": __doc__.split("\n\n")[0],
            "machine": {"cpu": platform.processor() or platform.machine(), "jax": jax.__version__},
            "date": time.strftime("%Y-%m-%d"),
            "files": a.files,
            "summary": out,
            "groups": by_group,
            "splices": splices,
            "runs": rows,
        }
        with open(a.json, "w") as f:
            f.write(_dumps(doc))
    return 0


def _dumps(doc: dict) -> str:
    """``doc`` as indented JSON with each run on one line (the per-frame profiles would
    otherwise take a line per number)."""
    runs = doc["runs"]
    head = json.dumps({k: v for k, v in doc.items() if k != "runs"}, indent=1)
    lines = ",\n".join("  " + json.dumps(r) for r in runs)
    return head[:-2] + ',\n "runs": [\n' + lines + "\n ]\n}\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", help="JSON lines, appended to")
    r.add_argument("--tracker-seeds", default="0,1")
    r.add_argument("--real-seeds")
    r.add_argument("--procedural-seeds")
    r.add_argument("--standard-seeds")
    r.add_argument("--side-seeds")
    add_part_arguments(r)
    s = sub.add_parser("summary")
    s.add_argument("files", nargs="+")
    s.add_argument("--json")
    a = ap.parse_args()
    if a.cmd == "run":
        check_part(r, a)
        run(a)
        return 0
    return summary(a)


if __name__ == "__main__":
    raise SystemExit(main())
