"""Does the offline mode track with the wrong body shape? (issue 12, a diagnosis)

The online mode refines the body shape against the depth while it tracks (after 20 and 60
frames); the offline mode tracks the whole recording with the shape measured between the
first frames' lifted keypoints and refines it only after the per-frame pass, for the smoother.
Under occlusion the lifted keypoints are worst, and ``online_gap.py`` found the online per-frame
pass 10 mm better than the offline one there. This tracks each clip online, then offline as
shipped and offline given the shape the online tracker ended with (a causal estimate from the
clip's first 60 frames, not the truth), and reports D of the offline per-frame pass and of its
output for both. D is ``pt.accuracy``'s mean 3D error, mm, over all 18 keypoints.

Tuning seeds only (wide real motion, ``tune.REAL``, as ``decide.py --real-seeds``); clean and
occluded (level 2); 120 frames at 30 fps, 320x240; tracker seed 0.

    python benchmarks/offline_shape.py --seeds 112-127
    python benchmarks/offline_shape.py --part 0 --parts 2 --out A.json  # two processes
    python benchmarks/offline_shape.py --merge A.json B.json  # -> results/offline_shape.json
"""

from __future__ import annotations

import numpy as np
from tune import diagnosis_runs, mean_error_all_mm, write_diagnosis

import posetrack as pt

COLUMNS = ("online", "offline_pass", "offline", "online_shape_pass", "online_shape")


def run_clip(seq) -> dict:
    def mm(keypoints3d):
        return mean_error_all_mm(keypoints3d, seq.joints3d)

    online = pt.Tracker(seq.intrinsics, mode="online", seed=0)
    row = {"online": mm(online.run(seq.depth, seq.keypoints2d, seq.confidence).keypoints3d)}
    for name, kw in (("offline", {}), ("online_shape", {"shape": online.shape})):
        res = pt.Tracker(seq.intrinsics, mode="offline", seed=0, **kw).run(
            seq.depth, seq.keypoints2d, seq.confidence
        )
        row[f"{name}_pass"] = mm(res.per_frame_keypoints3d)
        row[name] = mm(res.keypoints3d)
    return row


def main() -> int:
    a, runs = diagnosis_runs(__doc__, "112-127", "offline_shape", run_clip)
    table = {}
    for label, occ in (("clean", 0), ("occluded", 2)):
        rows = [r for r in runs if r["occlusion"] == occ]
        if rows:
            table[label] = {"runs": len(rows)}
            table[label].update({c: float(np.mean([r[c] for r in rows])) for c in COLUMNS})
    print("\nOffline with the shape it starts with and with the online tracker's final shape "
          "(D mm over 18 keypoints; wide real motion tuning clips)")  # fmt: skip
    print(f"{'clips':9s} {'runs':>4s} " + " ".join(f"{c:>17s}" for c in COLUMNS))
    for label, row in table.items():
        print(f"{label:9s} {row['runs']:4d} " + " ".join(f"{row[c]:17.2f}" for c in COLUMNS))
    write_diagnosis(a.out, "offline_shape", table, runs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
