"""How often the online left/right judge is right (issue 12, a diagnosis).

Online (``Tracker(mode="online")``) a group's labels are exchanged only after the depth judged
the exchange: where the forward left/right pass newly reads a group exchanged, the next lag + 1
frames are tracked both ways and the lower Delta summed wins (``posetrack._sides``). This
tracks wide real-motion tuning clips with the shipped online tracker and compares every
judgement with the truth: were the detections of that group really exchanged (against the
generator's joints projected into the image) in most of the judged frames, and was the
tracker's own pose of that group already swapped when the judgement began? It also counts
the frames whose detections were exchanged while the tracker fitted them as detected, split by
whether a judgement refused them or the forward pass never read them.

Tuning seeds only (wide real motion, ``tune.REAL``, as ``decide.py --real-seeds``); clean and
occluded (level 2); 120 frames at 30 fps, 320x240.

    python benchmarks/judge.py --seeds 112-123 --out benchmarks/results/judge.json
    python benchmarks/judge.py --seeds 112-123 --part 0 --parts 2 --out A.json  # two processes
    python benchmarks/judge.py --merge A.json B.json --out benchmarks/results/judge.json
"""

from __future__ import annotations

import numpy as np
from tune import diagnosis_runs, write_diagnosis

import posetrack as pt

#: Wrist/elbow, knee/ankle and shoulder/hip pairs, as ``SideSettings.for_mode("online")``
#: groups them (arms, legs, torso).
GROUPS = ("arms", "legs", "torso")
#: Image distance (px) by which the exchanged pairing must beat the detected one before the
#: detections count as exchanged against the truth (detector noise is a few px).
SWAP_PX = 4.0


def detections_exchanged(seq) -> np.ndarray:
    """``bool (T, 3)``: per frame and group, the detections of at least one of the group's
    pairs lie nearer the other side's true joints (projected) than their own by SWAP_PX."""
    K, J = seq.intrinsics, seq.joints3d
    uv = np.stack([K.fx * J[..., 0] / J[..., 2] + K.cx, K.fy * J[..., 1] / J[..., 2] + K.cy], -1)
    kp, conf = seq.keypoints2d, seq.confidence
    out = np.zeros((len(kp), len(GROUPS)), bool)
    for g, name in enumerate(GROUPS):
        for right, left in pt.SIDE_GROUPS[name]:
            seen = (conf[:, right] > 0.1) & (conf[:, left] > 0.1)
            own = np.linalg.norm(kp[:, right] - uv[:, right], axis=-1) + np.linalg.norm(
                kp[:, left] - uv[:, left], axis=-1
            )
            other = np.linalg.norm(kp[:, right] - uv[:, left], axis=-1) + np.linalg.norm(
                kp[:, left] - uv[:, right], axis=-1
            )
            out[:, g] |= seen & (other < own - SWAP_PX)
    return out


def pose_exchanged(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``bool (T, 3)``: per frame and group, the tracker's 3D keypoints of at least one pair
    are swapped against the truth (``pt.swapped_limbs``, its 100 mm margin)."""
    return np.stack(
        [pt.swapped_limbs(est, truth, pairs=pt.SIDE_GROUPS[g]).any(axis=1) for g in GROUPS],
        axis=1,
    )


def run_clip(seq) -> dict:
    tr = pt.Tracker(seq.intrinsics, mode="online", seed=0)
    res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
    # (start, stop, groups, kept, Delta summed as detected, Delta summed exchanged)
    judged = [
        (start, stop, groups, kept, delta_detected, delta_exchanged)
        for (start, stop, delta_detected, delta_exchanged, kept), groups in zip(
            tr.side_spans, tr.side_span_groups, strict=True
        )
    ]
    det = detections_exchanged(seq)
    pose = pose_exchanged(res.keypoints3d, seq.joints3d)
    counts = {k: 0 for k in ("swap kept", "swap refused", "correct kept", "correct refused")}
    pose_wrong_before = {k: 0 for k in counts}
    spans = []
    for start, stop, groups, kept, delta_detected, delta_exchanged in judged:
        for g in np.flatnonzero(groups):
            frames = slice(max(start, 0), stop)
            truly = bool(det[frames, g].mean() > 0.5)
            key = f"{'swap' if truly else 'correct'} {'kept' if kept else 'refused'}"
            counts[key] += 1
            if start > 0 and pose[start - 1, g]:
                pose_wrong_before[key] += 1
            spans.append({
                "start": int(start), "stop": int(stop), "group": GROUPS[g], "kept": kept,
                "truly_exchanged": truly, "delta_detected": delta_detected,
                "delta_exchanged": delta_exchanged,
            })  # fmt: skip
    fitted_ex = np.asarray(res.exchanged, bool)[:, : len(GROUPS)]
    missed = det & ~fitted_ex  # exchanged detections fitted as detected
    refused = np.zeros_like(missed)
    for start, stop, groups, kept, *_ in judged:
        if not kept:
            refused[max(start, 0) : stop] |= groups[None, :]
    return {
        "D_mm": pt.accuracy(res.keypoints3d, seq.joints3d).mean_mm,
        "swapped_limb_frames": pt.swapped_limb_frames(res.keypoints3d, seq.joints3d),
        "judgements": counts, "pose_swapped_before": pose_wrong_before,
        "detections_exchanged": int(det.sum()),
        "exchanged_fitted_as_detected": int(missed.sum()),
        "of_which_in_refused_judgements": int((missed & refused).sum()),
        "correct_fitted_exchanged": int((~det & fitted_ex).sum()),
        "by_group": {
            name: {
                "detections_exchanged": int(det[:, g].sum()),
                "exchanged_fitted_as_detected": int(missed[:, g].sum()),
                "of_which_in_refused_judgements": int((missed & refused)[:, g].sum()),
                "pose_swapped": int(pose[:, g].sum()),
            }
            for g, name in enumerate(GROUPS)
        },
        "spans": spans,
    }  # fmt: skip


def main() -> int:
    a, runs = diagnosis_runs(__doc__, "112-123", "judge", run_clip)
    print(f"\nOnline judgements against the truth, wide real motion tuning clips, {len(runs)} runs")
    print(f"{'':18s} {'judged':>7s} {'pose already swapped':>21s}")
    table = {}
    for key in ("swap kept", "swap refused", "correct kept", "correct refused"):
        n = sum(r["judgements"][key] for r in runs)
        before = sum(r["pose_swapped_before"][key] for r in runs)
        table[key] = {"judged": n, "pose_swapped_before": before}
        print(f"{key:18s} {n:7d} {before:21d}")
    frames = {
        k: sum(r[k] for r in runs)
        for k in ("detections_exchanged", "exchanged_fitted_as_detected",
                  "of_which_in_refused_judgements", "correct_fitted_exchanged")
    }  # fmt: skip
    for k, v in frames.items():
        print(f"{k.replace('_', ' ')}: {v} group-frames")
    keys = ("detections_exchanged", "exchanged_fitted_as_detected",
            "of_which_in_refused_judgements", "pose_swapped")  # fmt: skip
    by_group = {
        name: {k: sum(r["by_group"][name][k] for r in runs) for k in keys} for name in GROUPS
    }
    print(f"\n{'group':8s} " + " ".join(f"{k.replace('_', ' '):>30s}" for k in keys))
    for name, row in by_group.items():
        print(f"{name:8s} " + " ".join(f"{row[k]:30d}" for k in keys))
    write_diagnosis(a.out, "judge", table, runs, frames=frames, by_group=by_group)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
