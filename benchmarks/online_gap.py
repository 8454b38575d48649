"""Where the online mode loses to the offline one (issue 12, a diagnosis).

Both modes run the same per-frame tracker (the MHT step) and then a motion model over its
poses, so their gap splits into two parts: the per-frame pass (its left/right labelling
above all: offline reads the recording from both directions, online forwards with the depth
judging each exchange over lag + 1 frames; and the body shape, which online is refined after
20 and 60 frames and offline only after the pass) and the motion model (offline: every
frame's pose fitted jointly with its landmarks; online: the tracker's keypoints smoothed over
the last 12 frames, published 3 frames late). This tracks each clip four times (offline and
online, with the shipped left/right relabelling and with none) and reports D of the
per-frame pass and of the published output for each.

The online per-frame pass is what each ``Tracker.update`` returned (inside an online
judgement, the reading that led at that frame); the offline one is
``TrackResult.per_frame_keypoints3d``. D is ``pt.accuracy``'s mean 3D error, mm, over all 18
keypoints (not its default 13 body joints) and the frames that have an estimate.

Tuning seeds only (wide real motion, ``tune.REAL``, as ``decide.py --real-seeds``); clean
and occluded (level 2); 120 frames at 30 fps, 320x240; tracker seed 0.

    python benchmarks/online_gap.py --seeds 112-127
    python benchmarks/online_gap.py --seeds 112-127 --part 0 --parts 2 --out A.json  # two processes
    python benchmarks/online_gap.py --merge A.json B.json --out benchmarks/results/online_gap.json
"""

from __future__ import annotations

import numpy as np
from tune import diagnosis_runs, mean_error_all_mm, write_diagnosis

import posetrack as pt

#: (column, mode, left/right relabelling on) of each tracking of a clip.
RUNS = (("offline", "offline", True), ("online", "online", True),
        ("offline_no_sides", "offline", False), ("online_no_sides", "online", False))  # fmt: skip


def track(seq, mode: str, sides: bool) -> dict:
    """D of the per-frame pass and of the published output, and swapped-limb frames."""
    kw = {} if sides else {"sides": None}
    tr = pt.Tracker(seq.intrinsics, mode=mode, seed=0, **kw)
    passed = np.full(seq.joints3d.shape, np.nan)
    update = tr.update

    def recording_update(depth, keypoints2d, confidence):
        est, st = update(depth, keypoints2d, confidence)
        if est is not None and st != pt.NO_OBSERVATION:
            passed[recording_update.frame] = np.asarray(est.keypoints3d)
        recording_update.frame += 1
        return est, st

    recording_update.frame = 0
    if mode == "online":
        tr.update = recording_update  # the online pass: what each update returned
    res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
    if mode == "offline":
        passed = res.per_frame_keypoints3d
    return {
        "pass_mm": mean_error_all_mm(passed, seq.joints3d),
        "output_mm": mean_error_all_mm(res.keypoints3d, seq.joints3d),
        "swapped_limb_frames": pt.swapped_limb_frames(res.keypoints3d, seq.joints3d),
    }


def run_clip(seq) -> dict:
    return {name: track(seq, mode, sides) for name, mode, sides in RUNS}


def summary(runs: list[dict]) -> dict:
    """Means over the runs, per occlusion level and together."""
    out = {}
    groups = (
        ("clean", [r for r in runs if r["occlusion"] == 0]),
        ("occluded", [r for r in runs if r["occlusion"] > 0]),
        ("all", runs),
    )
    for label, rows in groups:
        if not rows:
            continue
        out[label] = {"runs": len(rows)}
        for name, _, _ in RUNS:
            out[label][name] = {
                k: float(np.mean([r[name][k] for r in rows]))
                for k in ("pass_mm", "output_mm", "swapped_limb_frames")
            }
    return out


def main() -> int:
    a, runs = diagnosis_runs(__doc__, "112-127", "online_gap", run_clip)
    table = summary(runs)
    print("\nOnline against offline, wide real motion tuning clips (D mm: per-frame pass -> "
          "published; swapped-limb frames per run)")  # fmt: skip
    print(f"{'clips':9s} {'runs':>4s}  " + "  ".join(f"{n:>24s}" for n, _, _ in RUNS))
    for label, row in table.items():
        cells = "  ".join(
            f"{row[n]['pass_mm']:7.2f} -> {row[n]['output_mm']:6.2f} "
            f"{row[n]['swapped_limb_frames']:5.1f}"
            for n, _, _ in RUNS
        )
        print(f"{label:9s} {row['runs']:4d}  {cells}")
    write_diagnosis(a.out, "online_gap", table, runs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
