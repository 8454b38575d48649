"""The offline pass with the body shape refined inside it, a prototype (issue 12, a screen).

``offline_shape.py`` found the offline mode tracking occluded clips with a worse body shape
than the online mode, which refines it against the depth after 20 and 60 tracked frames
while it tracks. This prototype does that inside the offline pass: a ``Tracker`` subclass
(offline, ``chunk=1``: one step per call, so the refinement lands between two frames) whose
reset turns on the online refinement's frame keeping, so the shape is refined after 20 and 60
tracked frames from the frames kept so far and the pass goes on with it; the refinement after
the pass (for the smoother) is unchanged. A prototype's shortcut: inside the offline left/right
arbitration's second tracking of a stretch, its frames count (and may be kept) twice.

Each clip is tracked offline as shipped (``default``) and with the prototype (``inpass``);
per run: D (``pt.accuracy``, the 13 body joints), D of the per-frame pass, coverage,
swapped-limb frames, acceleration error and seconds, as ``decide.py`` measures them.

Tuning seeds only (wide real motion, ``tune.REAL``, as ``decide.py --real-seeds``); clean and
occluded (level 2); 120 frames at 30 fps, 320x240; tracker seed 0.

    python benchmarks/inpass_shape.py --seeds 128-143
    python benchmarks/inpass_shape.py --seeds 128-143 --part 0 --parts 2 --out A.json
    python benchmarks/inpass_shape.py --merge A.json B.json  # -> results/inpass_shape.json
"""

from __future__ import annotations

import time

import numpy as np
from tune import decision_measures, diagnosis_runs, write_diagnosis

import posetrack as pt

VARIANTS = ("default", "inpass")


class InPassTracker(pt.Tracker):
    """Offline, one step per call, the body shape refined after 20 and 60 tracked frames as
    online (private hooks of ``Tracker``: a prototype, not an API)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, chunk=1, **kwargs)

    def _reset_motion(self) -> None:
        super()._reset_motion()
        self._online_refine_pending = self.refine is not None
        self._online_first_pending = self._online_refine_pending and self.refine.online_first > 0

    def _update_once(self, depth, keypoints2d, confidence):
        est, st = super()._update_once(depth, keypoints2d, confidence)
        if self._online_refine_pending and st == pt.TRACKED:
            self._online_refine_frame(est)
        return est, st


def run_clip(seq) -> dict:
    row = {}
    for name, cls in (("default", pt.Tracker), ("inpass", InPassTracker)):
        t0 = time.perf_counter()
        res = cls(seq.intrinsics, mode="offline", seed=0).run(
            seq.depth, seq.keypoints2d, seq.confidence
        )
        row[name] = {
            **decision_measures(res.keypoints3d, seq.joints3d), "s": time.perf_counter() - t0,
            "pass_D": pt.accuracy(res.per_frame_keypoints3d, seq.joints3d).mean_mm,
        }  # fmt: skip
    return row


def summary(rows: list[dict]) -> dict:
    out = {"runs": len(rows)}
    for v in VARIANTS:
        out[v] = {
            "D": float(np.mean([r[v]["D"] for r in rows])),
            "pass_D": float(np.mean([r[v]["pass_D"] for r in rows])),
            "swaps": int(sum(r[v]["swaps"] for r in rows)),
            "accel": float(np.mean([r[v]["accel"] for r in rows])),
            "s": float(sum(r[v]["s"] for r in rows)),
        }
    d = np.array([r["inpass"]["D"] - r["default"]["D"] for r in rows])
    out["better_by_5mm"], out["worse_by_5mm"] = int((d < -5).sum()), int((d > 5).sum())
    return out


def main() -> int:
    a, runs = diagnosis_runs(__doc__, "128-143", "inpass_shape", run_clip)
    table = {}
    for label, occ in (("clean", 0), ("occluded", 2), ("all", None)):
        rows = [r for r in runs if occ is None or r["occlusion"] == occ]
        if rows:
            table[label] = summary(rows)
    print("\nOffline as shipped -> with the shape refined inside the pass (prototype; D mm over "
          "13 joints, wide real motion tuning clips)")  # fmt: skip
    print(f"{'clips':9s} {'runs':>4s} {'D':>17s} {'pass D':>17s} {'swaps':>11s} {'>5mm +/-':>9s}")
    for label, t in table.items():
        d, i = t["default"], t["inpass"]
        print(
            f"{label:9s} {t['runs']:4d} {d['D']:7.2f} -> {i['D']:6.2f} "
            f"{d['pass_D']:7.2f} -> {i['pass_D']:6.2f} {d['swaps']:4d} -> {i['swaps']:4d} "
            f"{t['better_by_5mm']:4d}/{t['worse_by_5mm']:<4d}"
        )
    write_diagnosis(a.out, "inpass_shape", table, runs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
