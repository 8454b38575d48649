"""How fast does a track turn round while judged tracked, against how fast people turn?
(a diagnosis)

A track can turn the body round while every frame still passes the loss tests (walk_across
2239: the output's facing went from 18 to 172 degrees off the truth over 20 frames, judged
tracked throughout; benchmarks/README.md, "A facing check against the last tracked pose").
A loss test on the facing's rate ("the body turned by more than X degrees within w frames")
could catch that, if people do not turn as fast. This script tracks tuning clips with the
default tracker (one mode, one tracker seed) and, on the per-frame pass's keypoints
(``TrackResult.per_frame_keypoints3d``: what the loss tests see), measures the facing about
the camera's vertical (the shoulders' and hips' left direction in the x-z plane, as
``flip_delta.py``), per frame, of the estimate and of the truth. For windows of w frames
inside a stretch judged tracked it sorts each window by what happened in it:

- *wrong turn*: the estimate's facing error grew by more than 90 degrees over the window;
- *fast genuine turn*: the truth itself turned by more than X degrees (a test at X fires on it
  too where the estimate follows);
- *other*: the rest (a firing there is a false alarm);

and prints, per window w and threshold X, how many windows of each kind the test
"|the estimate's facing change over w frames| > X" fires on, and the episodes of a track
turned from under 45 to over 135 degrees off the truth while judged tracked. Tuning seeds
only; nothing in the tracker is changed.

    python benchmarks/turn_rate.py OUT.json --side-seeds 2282-2305 --cmu-late-seeds 2306-2311 \\
        --real-seeds 2312-2323 [--mode offline] [--tracker-seed 0] [--part 0 --parts 2]
    python benchmarks/turn_rate.py OUT.json --merge A.json B.json   # one table of both parts
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from decide import clips, generate_clip
from flip_delta import left_axis
from parts import add_part_arguments, check_part, share
from seeds import parse_seeds

import posetrack as pt

WINDOWS = (5, 10, 20)
THRESHOLDS = (45, 60, 90, 120)


def facing_deg(k: np.ndarray) -> np.ndarray:
    """(T,) the body's facing about the camera's vertical, degrees: the angle in the x-z plane
    of :func:`flip_delta.left_axis` ((T, 18, 3) keypoints; NaN where any is NaN)."""
    v = left_axis(k)
    return np.degrees(np.arctan2(v[:, 2], v[:, 0]))


def wrapped(d: np.ndarray) -> np.ndarray:
    """Angle differences (degrees) wrapped into [-180, 180)."""
    return (np.asarray(d) + 180.0) % 360.0 - 180.0


def track_run(group, seed, motion, variety, occ, mode, tseed) -> dict:
    """One clip tracked with the default tracker: its per-frame facing, the truth's, and the
    per-frame status."""
    seq = generate_clip(seed, motion, variety, occ)
    res = pt.Tracker(seq.intrinsics, mode=mode, seed=tseed).run(
        seq.depth, seq.keypoints2d, seq.confidence
    )
    per_frame = res.per_frame_keypoints3d if res.per_frame_keypoints3d is not None else (
        res.keypoints3d
    )  # fmt: skip
    return {
        "group": group, "seed": seed, "motion": motion, "occ": occ, "mode": mode,
        "tseed": tseed, "status": [int(s) for s in res.status],
        "facing": [round(float(f), 2) for f in facing_deg(per_frame)],
        "truth": [round(float(f), 2) for f in facing_deg(seq.joints3d)],
    }  # fmt: skip


def windows(run: dict, w: int) -> list[tuple[float, float, float]]:
    """``(estimate's turn, truth's turn, growth of the error)`` in degrees of every window of
    ``w`` frames inside a stretch judged tracked (every frame of it ``TRACKED``)."""
    status = np.asarray(run["status"])
    est, truth = np.asarray(run["facing"], float), np.asarray(run["truth"], float)
    err = np.abs(wrapped(est - truth))
    out = []
    for t in range(w, len(status)):
        if np.all(status[t - w : t + 1] == pt.TRACKED) and np.all(np.isfinite(est[t - w : t + 1])):
            out.append((
                float(wrapped(est[t] - est[t - w])), float(wrapped(truth[t] - truth[t - w])),
                float(err[t] - err[t - w]),
            ))  # fmt: skip
    return out


def episodes(run: dict) -> list[dict]:
    """Stretches judged tracked throughout in which the estimate went from under 45 to over
    135 degrees off the truth's facing: first and last frame, frames, both turns."""
    status = np.asarray(run["status"])
    est, truth = np.asarray(run["facing"], float), np.asarray(run["truth"], float)
    err = np.abs(wrapped(est - truth))
    out, good = [], None  # good: the last tracked frame under 45 degrees off
    for t in range(len(status)):
        if status[t] != pt.TRACKED or not np.isfinite(err[t]):
            good = None
            continue
        if err[t] < 45:
            good = t
        elif err[t] > 135 and good is not None:
            turn = float(np.sum(wrapped(np.diff(est[good : t + 1]))))
            true_turn = float(np.sum(wrapped(np.diff(truth[good : t + 1]))))
            out.append({
                "seed": run["seed"], "group": run["group"], "occ": run["occ"],
                "from": good, "to": t, "frames": t - good,
                "turn_deg": round(turn, 1), "truth_turn_deg": round(true_turn, 1),
            })  # fmt: skip
            good = None
    return out


def table(runs: list[dict]) -> str:
    """The windows sorted by kind, and how often the rate test fires on each."""
    lines = []
    for w in WINDOWS:
        rows = [x for run in runs for x in windows(run, w)]
        est, truth, grow = (np.array([r[i] for r in rows]) for i in range(3))
        wrong = grow > 90
        lines.append(f"w = {w} frames: {len(rows)} tracked windows, {int(wrong.sum())} wrong "
                     f"turns; the truth's fastest turn {np.max(np.abs(truth)):.0f} deg, "
                     f"99th percentile {np.percentile(np.abs(truth), 99):.0f}")  # fmt: skip
        lines.append("   X   fires on wrong turns   on fast genuine turns   false alarms / 1000")
        for x in THRESHOLDS:
            fires = np.abs(est) > x
            fast = (np.abs(truth) > x) & ~wrong
            other = ~wrong & ~fast
            lines.append(
                f"{x:4d}   {int((fires & wrong).sum()):5d} / {int(wrong.sum()):<5d}          "
                f"{int((fires & fast).sum()):5d} / {int(fast.sum()):<5d}        "
                f"{1000 * (fires & other).sum() / max(other.sum(), 1):8.2f}"
            )
    eps = [e for run in runs for e in episodes(run)]
    lines.append(f"turned round while judged tracked: {len(eps)} episodes")
    lines += [f"  {e['group']} {e['seed']} occ {e['occ']}: frames {e['from']}-{e['to']} "
              f"({e['frames']}), the estimate turned {e['turn_deg']:+.0f} deg, the truth "
              f"{e['truth_turn_deg']:+.0f}" for e in eps]  # fmt: skip
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", help="JSON: one record per run (facing per frame, status)")
    ap.add_argument("--side-seeds", help="wide walk_across clips of these tuning seeds")
    ap.add_argument("--cmu-late-seeds", help="cmu late clips of these tuning seeds")
    ap.add_argument("--real-seeds", help="wide real-motion clips of these tuning seeds")
    ap.add_argument("--mode", default="offline", choices=("offline", "online"))
    ap.add_argument("--tracker-seed", type=int, default=0)
    ap.add_argument("--merge", nargs="+", type=Path, help="instead: the table of these outputs")
    add_part_arguments(ap)
    a = ap.parse_args()
    if a.merge:
        runs = [r for p in a.merge for r in json.loads(p.read_text())]
        Path(a.out).write_text(json.dumps(runs) + "\n")
        print(table(runs))
        return 0
    check_part(ap, a)
    seeds = {k: None if v is None else parse_seeds(v)
             for k, v in (("side", a.side_seeds), ("cmu", a.cmu_late_seeds),
                          ("real", a.real_seeds))}  # fmt: skip
    if all(v is None for v in seeds.values()):
        ap.error("give --side-seeds, --cmu-late-seeds or --real-seeds")
    chosen = clips(seeds["real"], seeds["side"], False, None, None, seeds["cmu"])
    todo = share([(c, occ) for c in chosen for occ in (0, 2)], a)
    runs = []
    for clip, occ in todo:
        runs.append(track_run(*clip, occ, a.mode, a.tracker_seed))
        print(json.dumps({k: v for k, v in runs[-1].items() if not isinstance(v, list)}),
              flush=True)  # fmt: skip
        Path(a.out).write_text(json.dumps(runs) + "\n")
    print(table(runs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
