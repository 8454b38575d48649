"""Does Delta tell a track that faces the wrong way, on frames judged tracked? (a diagnosis)

The tracker has no test that a track judged tracked faces the wrong way (benchmarks/README.md,
"A side view's restart from the last tracked facing": the frame's lifted left/right pair and
the nose's 2D direction were looked at and do not tell). This script tracks wide walk_across
clips (clean and occluded, the default tracker) with a spy on the frames judged tracked and,
per such frame, fits the frame's landmarks twice with the re-initialisation's fit (60 LM
steps, ``initial_fit``): as the tracker labelled them, started facing the track's way, and
with every left/right pair exchanged, started turned round. It records Delta (Eq. (3), the
tracker's own scoring against the frame's depth and floor) of the track's pose and of both
fits, and how each faces against the truth (the shoulders' and hips' left axis seen from
above). ``summary`` then reads "the fit facing against the track minus the fit facing with it"
(and minus the track's own Delta) on frames whose track faces right and wrong, per frame and
as k frames in a row. Tuning seeds only; the spy wraps a private tracker method and changes
nothing it reads.

    python benchmarks/turned_delta.py track OUT.json [--mode online] [--seeds 2638-2661]
        [--part 0 --parts 2]
    python benchmarks/turned_delta.py summary OUT*.json [--json results/turned_delta.json]
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np
from decide import generate_clip, settings
from flip_delta import left_axis
from parts import add_part_arguments, check_part, share
from seeds import parse_seeds

import posetrack as pt
import posetrack._tracker as tracker_module
from posetrack._init import initial_pose
from posetrack._so3 import quat_to_matrix

MARGINS = (0.0, -0.005, -0.01, -0.02, -0.03)
ROWS_OF_K = (1, 2, 3, 5)


def _facing(params: np.ndarray, truth_left: np.ndarray) -> float:
    """Cosine between a pose's root left axis (x-z plane) and the truth's (:func:`left_axis`)."""
    v = quat_to_matrix(np.asarray(params[3:7], np.float64))[:, 0] * np.array([1.0, 0, 1])
    return float(v @ truth_left / max(np.linalg.norm(v), 1e-9))


def track_run(seed: int, occ: int, mode: str) -> list[dict]:
    """One clip: the rows of its frames judged tracked (see the module docstring)."""
    seq = generate_clip(seed, "walk_across", "wide", occ)
    tr = pt.Tracker(seq.intrinsics, mode=mode, seed=0, **settings("default", mode))
    seen: dict[int, list] = {}
    inner = tr._tracked

    def spy(frame, cands, person, kp, conf, est):  # online, a frame may be tracked twice
        seen.setdefault(frame - 1, []).append(
            (np.array(kp), np.array(conf), np.array(est.params), tr._depth_fit)
        )
        return inner(frame, cands, person, kp, conf, est)

    tr._tracked = spy
    res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
    floor = tracker_module.NO_FLOOR if tr._floor is None else tuple(np.asarray(tr._floor, float))
    key = jax.random.PRNGKey(0)

    def fit(p0, lm):
        out = tracker_module.initial_fit(
            tr._init_settings, tr.shape, tr.intrinsics, tracker_module._host_f32(p0), lm, key
        )
        return np.asarray(out[0].params, np.float64)

    rows = []
    for t in range(len(res.status)):
        if int(res.status[t]) != 0 or t not in seen:
            continue
        # The kept reading's record: the one whose pose is the result's.
        kp, conf, params, depth = min(seen[t], key=lambda c: np.abs(c[2] - res.params[t]).sum())
        params = params.astype(np.float64)
        R = quat_to_matrix(params[3:7])
        lm = tr._lift(depth, kp, conf)
        lm_x = tracker_module._body_flipped(lm)
        p0 = initial_pose(
            np.asarray(lm.points3d), np.asarray(lm.has_depth), tr.shape,
            allow_partial=True, axes=(R[:, 0], R[:, 1]),
        )  # fmt: skip
        p0_x = initial_pose(
            np.asarray(lm_x.points3d), np.asarray(lm_x.has_depth), tr.shape,
            allow_partial=True, axes=(-R[:, 0], R[:, 1]),
        )  # fmt: skip
        if p0 is None or p0_x is None:
            continue
        plain, exch = fit(p0, lm), fit(p0_x, lm_x)
        fits = tr._deltas(depth, plain, exch, floor)
        own = tr._deltas(depth, params, exch, floor)
        truth = left_axis(seq.joints3d[t])
        has_d = np.asarray(lm.has_depth)
        rows.append(dict(
            t=t, track=_facing(params, truth), plain=_facing(plain, truth),
            exch=_facing(exch, truth), d_track=float(own[0]), d_plain=float(fits[0]),
            d_exch=float(fits[1]), n3d=int(has_d.sum()),
            pairs=int(has_d[[2, 5]].all()) + int(has_d[[8, 11]].all()),
        ))  # fmt: skip
    return rows


def _against(row: dict, reference: str) -> float | None:
    """Delta of the fresh fit facing against the track minus that of the one facing with it
    (``reference="fit"``) or minus the track's own (``"track"``); None where the two fits face
    the same way."""
    side = np.sign(row["track"])
    fits = [(np.sign(row["plain"]), row["d_plain"]), (np.sign(row["exch"]), row["d_exch"])]
    same = [d for s, d in fits if s == side]
    other = [d for s, d in fits if s != side]
    if not same or not other:
        return None
    return other[0] - (same[0] if reference == "fit" else row["d_track"])


def summary(runs: list[dict]) -> dict:
    """The tables of the module docstring, as a dict (printed by ``main``)."""
    rows = [r for run in runs for r in run["rows"]]
    out: dict = dict(
        runs=len(runs),
        tracked_frames=len(rows),
        wrong_frames=sum(r["track"] < 0 for r in rows),
        runs_with_wrong=sorted(
            [run["seed"], run["occ"]] for run in runs if any(r["track"] < 0 for r in run["rows"])
        ),
        labels_against_truth={
            name: dict(
                frames=len(sel),
                fit_faces_wrong=sum(r["plain"] < 0 for r in sel),
                with_a_pair=sum(r["pairs"] > 0 for r in sel),
                with_a_pair_fit_faces_wrong=sum(r["plain"] < 0 and r["pairs"] > 0 for r in sel),
            )
            for name, sel in (
                ("wrong", [r for r in rows if r["track"] < 0]),
                ("right", [r for r in rows if r["track"] >= 0]),
            )
        },
    )
    for ref in ("fit", "track"):
        signal = [(r["track"] < 0, _against(r, ref)) for r in rows]
        wrong = np.array([s for w, s in signal if w and s is not None])
        right = np.array([s for w, s in signal if not w and s is not None])
        out[f"per_frame_vs_{ref}"] = dict(
            wrong_n=len(wrong), right_n=len(right),
            wrong_percentiles_10_50_90=np.percentile(wrong, [10, 50, 90]).round(4).tolist(),
            right_percentiles_10_50_90=np.percentile(right, [10, 50, 90]).round(4).tolist(),
            below={str(m): [int(np.sum(wrong < m)), int(np.sum(right < m))] for m in MARGINS},
        )  # fmt: skip
        in_a_row = {}
        for m in MARGINS[:4]:
            for k in ROWS_OF_K:
                fired = {"wrong": 0, "right": 0, "wrong_runs": set(), "right_runs": set()}
                for run in runs:
                    count, last = 0, None
                    for r in run["rows"]:
                        if last is not None and r["t"] != last + 1:
                            count = 0  # a frame not judged tracked breaks the row
                        last = r["t"]
                        s = _against(r, ref)
                        if s is None:
                            continue
                        count = count + 1 if s < m else 0
                        if count == k:
                            side = "wrong" if r["track"] < 0 else "right"
                            fired[side] += 1
                            fired[f"{side}_runs"].add((run["seed"], run["occ"]))
                in_a_row[f"m={m} k={k}"] = [
                    fired["wrong"], len(fired["wrong_runs"]),
                    fired["right"], len(fired["right_runs"]),
                ]  # fmt: skip
        out[f"in_a_row_vs_{ref}"] = in_a_row
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("track", help="track the clips and write the per-frame rows")
    t.add_argument("out")
    t.add_argument("--mode", default="online", choices=("online", "offline"))
    t.add_argument("--seeds", default="2638-2661", help="tuning seeds of wide walk_across clips")
    add_part_arguments(t)
    s = sub.add_parser("summary", help="read the rows: the tables")
    s.add_argument("files", nargs="+")
    s.add_argument("--json", help="write the summary here")
    args = parser.parse_args()
    if args.cmd == "track":
        check_part(t, args)
        runs = share([(seed, occ) for seed in parse_seeds(args.seeds) for occ in (0, 2)], args)
        out = []
        for seed, occ in runs:
            rows = track_run(seed, occ, args.mode)
            out.append(dict(seed=seed, occ=occ, mode=args.mode, rows=rows))
            wrong = sum(r["track"] < 0 for r in rows)
            print(seed, occ, "tracked", len(rows), "facing wrong", wrong, flush=True)
            with open(args.out, "w") as f:  # after every run: a stopped look keeps its runs
                json.dump(out, f)
        return 0
    runs = []
    for path in args.files:
        with open(path) as f:
            runs += json.load(f)
    table = summary(runs)
    print(
        f"{table['runs']} runs, {table['tracked_frames']} tracked frames, "
        f"{table['wrong_frames']} facing wrong (runs: {table['runs_with_wrong']})"
    )
    for name, c in table["labels_against_truth"].items():
        print(
            f"track {name}: the fit on the frame's labels faces wrong in {c['fit_faces_wrong']} "
            f"of {c['frames']} ({c['with_a_pair_fit_faces_wrong']} of {c['with_a_pair']} with "
            "a left/right pair)"
        )
    for ref in ("fit", "track"):
        p = table[f"per_frame_vs_{ref}"]
        print(f"\nagainst-facing fit minus the {ref}'s Delta, 10/50/90th percentiles: "
              f"wrong {p['wrong_percentiles_10_50_90']}, right {p['right_percentiles_10_50_90']}")
        print("| below m | wrong frames | right frames |\n|---|---|---|")
        for m, (w, r) in p["below"].items():
            print(f"| {m} | {w} / {p['wrong_n']} | {r} / {p['right_n']} |")
        print("| m, k in a row | fires on wrong (runs) | on right (runs) |\n|---|---|---|")
        for mk, (w, wr, r, rr) in table[f"in_a_row_vs_{ref}"].items():
            print(f"| {mk} | {w} ({wr}) | {r} ({rr}) |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(table, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
