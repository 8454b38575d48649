"""Where a tracker's 3D error comes from on side views: an error budget (a diagnosis)

Tracks decision clips (``decide.py``'s groups; tuning seeds) with one variant and splits each
answered frame's error (mean over the 13 body joints) into four kinds of frame by the truth:
the track faces the wrong way (its left axis, from the shoulders and hips seen from above,
more than 90 degrees from the truth's), a left/right limb pair is swapped
(:func:`posetrack.swapped_limbs`), a right side view (the truth turned 55-125 degrees from
facing the camera), a right frontal or back view. On the side views it compares the far
arm (the side turned away from the camera) with the near arm: each joint's error, its signed
offset towards the camera, and D with every far-arm joint's error replaced by its near
twin's (what an estimate as good on the far arm as on the near one would give). It also reads
the clip's 2D detections of the arms on side views (no tracking): their image error at the
joint's depth (mm) and how often they are missed, which bounds what any fit of the far arm
can recover from its own keypoints.

    python benchmarks/error_budget.py track OUT.jsonl [--variant farbound] [--side-seeds
        2692-2707] [--real-seeds 2708-2721] [--cmu-late-seeds 2722-2729] [--part 0 --parts 2]
    python benchmarks/error_budget.py summary OUT*.jsonl [--json results/error_budget.json]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict

import numpy as np
from decide import clips, generate_clip, settings
from flip_delta import left_axis
from parts import add_part_arguments, check_part, share
from seeds import parse_seeds

import posetrack as pt

#: Frame kinds, in the order a frame is assigned to the first that holds.
KINDS = ("wrong-facing", "swapped limb", "side view", "front or back view")
#: The arms' (right, left) COCO-18 keypoints.
ARM = {"shoulder": (2, 5), "elbow": (3, 6), "wrist": (4, 7)}
#: A side view: the truth turned this many degrees from facing the camera (exclusive).
SIDE = (55.0, 125.0)
BODY = list(pt.BODY_JOINTS)


def _far_near(values: np.ndarray, left_far: np.ndarray, pair: tuple[int, int]):
    """``(far, near)`` of a right/left pair of ``values`` (frames, keypoints, ...)."""
    r, left = values[:, pair[0]], values[:, pair[1]]
    lf = left_far.reshape((-1,) + (1,) * (r.ndim - 1))
    return np.where(lf, left, r), np.where(lf, r, left)


def budget(est: np.ndarray, truth: np.ndarray) -> dict:
    """One run's sums (they add over runs): per frame kind the frames and their error sum (mm),
    and on side views per arm joint the far and near error sums, the far and near offsets
    towards the camera on right-facing unswapped frames, and the counterfactual error sum."""
    err = pt.joint_errors(est, truth) * 1000.0  # (T, 13) over BODY
    answered = np.isfinite(err).all(axis=1)
    la_t, la_e = left_axis(truth), left_axis(est)
    yaw = np.degrees(np.arccos(np.clip(la_t[:, 0], -1.0, 1.0)))
    side = (yaw > SIDE[0]) & (yaw < SIDE[1])
    wrong = np.einsum("ti,ti->t", la_t, la_e) < 0
    swapped = pt.swapped_limbs(est, truth).any(axis=1)
    kind = np.select([wrong, swapped, side], [0, 1, 2], 3)
    frame_err = np.where(answered[:, None], err, 0.0).mean(axis=1)
    out = {"frames": int(answered.sum()), "err": float(np.where(answered, err.sum(1), 0).sum())}
    for k, name in enumerate(KINDS):
        m = answered & (kind == k)
        out[name] = [int(m.sum()), float(frame_err[m].sum())]
    left_far = la_t[:, 2] > 0  # the body's left axis points away from the camera
    on_side = answered & side
    clean = on_side & ~wrong & ~swapped
    closer = (truth[..., 2] - est[..., 2]) * 1000.0  # > 0: the estimate is nearer the camera
    counter = err.copy()
    for name, pair in ARM.items():
        ef, en = _far_near(err[:, [BODY.index(pair[0]), BODY.index(pair[1])]], left_far, (0, 1))
        cf, cn = _far_near(closer, left_far, pair)
        out["far " + name] = [float(ef[on_side].sum()), float(cf[clean].sum())]
        out["near " + name] = [float(en[on_side].sum()), float(cn[clean].sum())]
        far_col = np.where(left_far, BODY.index(pair[1]), BODY.index(pair[0]))
        counter[np.flatnonzero(on_side), far_col[on_side]] = en[on_side]
    out["side frames"], out["side clean frames"] = int(on_side.sum()), int(clean.sum())
    out["counterfactual err"] = float(np.where(answered[:, None], counter, 0).sum())
    return out


def detections(seq) -> dict:
    """Side-view 2D detections of the arms: per far/near joint, the detected frames' image
    error at the joint's depth (mm) summed, those frames, frames with more than 100 mm, and
    the side-view frames missed (confidence at most 0.1)."""
    gt = np.asarray(seq.joints3d, np.float64)
    kp, conf = np.asarray(seq.keypoints2d, np.float64), np.asarray(seq.confidence, np.float64)
    if kp.ndim == 4:  # (T, people, 18, 2): the tracked person is the first
        kp, conf = kp[:, 0], conf[:, 0]
    px = np.asarray(pt.project(seq.intrinsics, gt), np.float64)
    mm = np.linalg.norm(kp - px, axis=-1) * gt[..., 2] / float(seq.intrinsics.fx) * 1000.0
    la = left_axis(gt)
    yaw = np.degrees(np.arccos(np.clip(la[:, 0], -1.0, 1.0)))
    side = (yaw > SIDE[0]) & (yaw < SIDE[1])
    out = {"side frames": int(side.sum())}
    for name, pair in ARM.items():
        far_mm, near_mm = _far_near(mm, la[:, 2] > 0, pair)
        far_conf, near_conf = _far_near(conf, la[:, 2] > 0, pair)
        for which, e, c in (("far", far_mm, far_conf), ("near", near_mm, near_conf)):
            seen = side & (c > 0.1)
            over, missed = int((e[seen] > 100).sum()), int((side & ~seen).sum())
            out[f"{which} {name}"] = [float(e[seen].sum()), int(seen.sum()), over, missed]
    return out


def track(a) -> None:
    side, real, cmu = (
        None if t is None else parse_seeds(t)
        for t in (a.side_seeds, a.real_seeds, a.cmu_late_seeds)
    )
    todo = share([(c, occ) for c in clips(real, side, False, None, None, cmu) for occ in (0, 2)], a)
    with open(a.out, "a") as f:
        for (group, seed, motion, variety), occ in todo:
            seq = generate_clip(seed, motion, variety, occ)
            tr = pt.Tracker(seq.intrinsics, mode=a.mode, seed=a.tracker_seed, **settings(a.variant))
            res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
            est, truth = np.asarray(res.keypoints3d, np.float64), np.asarray(seq.joints3d)
            rec = {"group": group, "seed": seed, "occ": occ, "variant": a.variant,
                   "mode": a.mode, "tseed": a.tracker_seed, "D": pt.accuracy(est, truth).mean_mm,
                   "budget": budget(est, truth), "detections": detections(seq)}  # fmt: skip
            f.write(json.dumps(rec) + "\n")
            f.flush()
            print(group, seed, occ, a.variant, round(rec["D"], 1), flush=True)


def summary(files: list[str], out: str | None) -> None:
    recs = [json.loads(line) for name in files for line in open(name)]
    cells: dict = defaultdict(lambda: defaultdict(lambda: 0))
    for r in recs:
        c = cells[(r["variant"], r["group"], r["occ"])]
        c["runs"] += 1
        for key, v in r["budget"].items():
            c[key] = np.add(c[key], v)
        for key, v in r["detections"].items():
            c["det " + key] = np.add(c["det " + key], v)
    table = []
    print(
        "| variant | group | occ | runs | D | frames: wrong-facing / swapped / side / front-back "
        "| their error, mm | D with the far arm at the near arm's error |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (variant, group, occ), c in sorted(cells.items()):
        D = c["err"] / (13 * c["frames"])
        share_ = [c[k][0] / c["frames"] for k in KINDS]
        mean = [c[k][1] / max(c[k][0], 1) for k in KINDS]
        cf = c["counterfactual err"] / (13 * c["frames"])
        row = {"variant": variant, "group": group, "occ": occ, "runs": c["runs"], "D": D,
               "kinds": dict(zip(KINDS, zip(share_, mean, strict=True), strict=True)),
               "D far arm at near": cf, "arms": {}, "detections": {}}  # fmt: skip
        print(
            f"| {variant} | {group} | {occ} | {c['runs']} | {D:.1f} | "
            + " / ".join(f"{s:.0%}" for s in share_)
            + " | "
            + " / ".join(f"{m:.0f}" for m in mean)
            + f" | {cf:.1f} |"
        )
        for key in (f"{w} {j}" for j in ARM for w in ("far", "near")):
            e, closer = c[key]
            row["arms"][key] = {
                "err_mm": e / max(c["side frames"], 1),
                "closer_mm": closer / max(c["side clean frames"], 1),
            }
            de, n, over, missed = c["det " + key]
            row["detections"][key] = {"err_mm": de / max(n, 1), "over_100mm": over / max(n, 1),
                                      "missed": missed / max(c["det side frames"], 1)}  # fmt: skip
        table.append(row)
    print(
        "\nSide views, per arm joint: error (mm) / offset towards the camera on right-facing "
        "unswapped frames (mm) | its 2D detection's error at depth (mm), share over 100 mm, "
        "share missed"
    )
    for row in table:
        print(f"{row['variant']} {row['group']} occ {row['occ']}:")
        for key, v in row["arms"].items():
            d = row["detections"][key]
            print(
                f"  {key:14s} {v['err_mm']:6.0f} / {v['closer_mm']:+6.0f}   | {d['err_mm']:5.0f}"
                f" {d['over_100mm']:5.0%} {d['missed']:5.0%}"
            )
    if out:
        with open(out, "w") as f:
            json.dump({"files": files, "runs": len(recs), "table": table, "records": recs}, f)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("track")
    t.add_argument("out")
    t.add_argument("--variant", default="default", help="a decide.py variant")
    t.add_argument("--mode", choices=("offline", "online", "per-frame"), default="offline")
    t.add_argument("--tracker-seed", type=int, default=0)
    t.add_argument("--side-seeds")
    t.add_argument("--real-seeds")
    t.add_argument("--cmu-late-seeds")
    add_part_arguments(t)
    s = sub.add_parser("summary")
    s.add_argument("files", nargs="+")
    s.add_argument("--json")
    a = ap.parse_args()
    if a.cmd == "track":
        check_part(t, a)
        if a.side_seeds is None and a.cmu_late_seeds is None and a.real_seeds is None:
            t.error("give --side-seeds, --real-seeds or --cmu-late-seeds")
        track(a)
    else:
        summary(a.files, a.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
