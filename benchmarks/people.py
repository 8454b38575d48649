#!/usr/bin/env python
"""One person means one person: identity jumps with a second person walking through the view.

Each scene is a ``posetrack.synth`` recording with ``bystander=True``: the person to follow
acts in place (a built-in motion), a second random person walks across in front of them,
leaves the view and comes back (in front again or behind); the detector lists both people in
random order each frame, as OpenPose does without its tracker. Every scene is tracked three
ways with the shipped MHT_h:

* **follow** (the default): one person is chosen at the start and followed
  (``posetrack.Tracker``'s association, gate and re-acquisition);
* **per-frame**: ``follow=None``, each frame's most prominent detection (what the tracker did
  before, and what ``posetrack.io``'s per-frame choice still gives);
* **alone**: the same seed without the second person (same body, motion, room, sensor and
  detector noise where the bystander does not interfere): the reference D.

Identity per frame = whose ground truth the output is nearest (``posetrack.followed_identity``);
a jump = a change between consecutive estimated frames (``posetrack.identity_jumps``).

    python benchmarks/people.py                 # reported seeds 0-19 (~40 min on 2 cores)
    python benchmarks/people.py --quick         # 4 scenes
    python benchmarks/people.py --tuning        # tuning seeds 100-119 (what defaults may see)

Prints the table and writes ``people.json`` into ``--out`` (default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from seeds import REPORT_SEEDS, TUNING_SEEDS

import posetrack as pt
from posetrack.app import machine_summary

#: The followed person's motion cycles through these (walk_across: that person travels too),
#: and the occlusion level through 0, 1, 2 (occluders over the followed person).
MOTIONS = ("wave", "box", "reach", "squat", "walk", "turn", "walk_across")
LEVELS = (0, 1, 2)


def scene_result(
    seed: int,
    motion: str,
    level: int,
    frames: int,
    size: tuple[int, int],
    ablate: bool = False,
    config: pt.TrackerConfig | None = None,
    follow: pt.FollowSettings | None = None,
) -> dict:
    """Track one scene three ways; identity jumps and D of each. ``follow``: the follower's
    settings in the follow and alone runs (default ``FollowSettings()``)."""
    w, h = size
    kw = dict(motion=motion, n_frames=frames, width=w, height=h, with_rgb=False,
              occlusion_level=level)  # fmt: skip
    seq = pt.synth.generate(seed, bystander=True, **kw)
    alone = pt.synth.generate(seed, **kw)
    truth = np.concatenate([seq.joints3d[:, None], seq.others_joints3d], axis=1)
    config = config or pt.TrackerConfig()
    follow = follow or pt.FollowSettings()
    out: dict = {"seed": seed, "motion": motion, "level": level, "frames": frames}
    runs = {
        "follow": (seq.people2d, seq.people_confidence, follow, seq.joints3d),
        "per-frame": (seq.people2d, seq.people_confidence, None, seq.joints3d),
        "alone": (alone.keypoints2d, alone.confidence, follow, alone.joints3d),
    }
    if ablate:  # the other people's pixels left in the depth the tracker fits
        no_mask = dataclasses.replace(follow, mask_others=False)
        runs["follow, no mask"] = (seq.people2d, seq.people_confidence, no_mask, seq.joints3d)
    for name, (kp, conf, follower, gt) in runs.items():
        t0 = time.perf_counter()
        res = pt.track(seq.depth if name != "alone" else alone.depth, kp, conf,
                       seq.intrinsics, config, follow=follower, mode="per-frame")  # fmt: skip
        acc = pt.accuracy(res.keypoints3d, gt)
        ident = pt.followed_identity(res.keypoints3d, truth)
        out[name] = {
            "jumps": pt.identity_jumps(ident) if name != "alone" else 0,
            "jump_frames": np.flatnonzero(np.diff(ident[ident >= 0]) != 0).tolist()
            if name != "alone"
            else [],
            "frames_on_other": int(np.sum(ident > 0)) if name != "alone" else 0,
            "D_mm": acc.mean_mm,
            "coverage": acc.coverage,
            "lost": int(np.sum(res.status == pt.LOST)),
            "others_ignored": res.others_ignored,
            "seconds": time.perf_counter() - t0,
        }
    out["both_listed"] = int(np.sum((seq.people_confidence > 0).any(-1).sum(-1) >= 2))
    return out


def summarise(scenes: list[dict]) -> dict:
    total = sum(s["frames"] for s in scenes)
    summary = {}
    for name in [n for n in scenes[0] if n in ("follow", "per-frame", "follow, no mask")]:
        jumps = np.array([s[name]["jumps"] for s in scenes])
        ratio = np.array([s[name]["D_mm"] / s["alone"]["D_mm"] for s in scenes])
        summary[name] = {
            "scenes_without_jumps": float(np.mean(jumps == 0)),
            "jumps": int(jumps.sum()),
            "jumps_per_1000_frames": 1000.0 * jumps.sum() / total,
            "D_mm": float(np.mean([s[name]["D_mm"] for s in scenes])),
            "D_ratio_to_alone_mean": float(ratio.mean()),
            "D_ratio_to_alone_worst": float(ratio.max()),
            "worst_scene": scenes[int(ratio.argmax())]["seed"],
            "frames_on_other": int(sum(s[name]["frames_on_other"] for s in scenes)),
        }
    summary["alone"] = {"D_mm": float(np.mean([s["alone"]["D_mm"] for s in scenes]))}
    summary["frames"] = total
    return summary


def print_table(scenes: list[dict], summary: dict) -> None:
    print(f"{'seed':>5} {'motion':<11} {'occ':>3} {'both':>5} | {'jumps':>5} {'D':>6} "
          f"{'lost':>5} | {'jumps':>5} {'D':>6} | {'alone D':>7}")  # fmt: skip
    print(f"{'':>5} {'':<11} {'':>3} {'':>5} | {'follow':^18} | {'per-frame':^12} |")
    for s in scenes:
        f, p, a = s["follow"], s["per-frame"], s["alone"]
        print(f"{s['seed']:>5} {s['motion']:<11} {s['level']:>3} {s['both_listed']:>5} | "
              f"{f['jumps']:>5} {f['D_mm']:>6.1f} {f['lost']:>5} | {p['jumps']:>5} "
              f"{p['D_mm']:>6.1f} | {a['D_mm']:>7.1f}")  # fmt: skip
    for name in [n for n in summary if n not in ("alone", "frames")]:
        m = summary[name]
        print(f"{name:>10}: {m['scenes_without_jumps']:.0%} of scenes without a jump, "
              f"{m['jumps']} jumps ({m['jumps_per_1000_frames']:.2f} per 1000 frames), "
              f"D {m['D_mm']:.1f} mm = {m['D_ratio_to_alone_mean']:.2f}x alone on average, "
              f"worst {m['D_ratio_to_alone_worst']:.2f}x (seed {m['worst_scene']})")  # fmt: skip
    print(f"     alone: D {summary['alone']['D_mm']:.1f} mm; {summary['frames']} frames")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="4 scenes")
    ap.add_argument("--tuning", action="store_true", help="tuning seeds instead of reported")
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--start", type=int, default=0, help="skip this many seeds of the range")
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--ablate", action="store_true", help="also: follow without masking others")
    ap.add_argument(
        "--lost-agreement", type=float, help="TrackerConfig.lost_agreement (default: shipped)"
    )
    ap.add_argument(
        "--follow-band", type=float, help="FollowSettings.depth_band, m (default: shipped)"
    )
    ap.add_argument(
        "--alone-frames", type=int, help="FollowSettings.alone_frames (default: shipped)"
    )
    ap.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = ap.parse_args(argv)
    config = pt.TrackerConfig()
    if args.lost_agreement is not None:
        config = pt.TrackerConfig(lost_agreement=args.lost_agreement)
    changes = {"depth_band": args.follow_band, "alone_frames": args.alone_frames}
    changes = {k: v for k, v in changes.items() if v is not None}
    follow = pt.FollowSettings(**changes) if changes else None
    n = 4 if args.quick else args.scenes
    seeds = list(TUNING_SEEDS if args.tuning else REPORT_SEEDS)[args.start : args.start + n]
    print(machine_summary(), file=sys.stderr)
    scenes = []
    for i, seed in enumerate(seeds):
        k = args.start + i  # the motion and level follow the seed's place in its range
        motion, level = MOTIONS[k % len(MOTIONS)], LEVELS[k % len(LEVELS)]
        scenes.append(
            scene_result(seed, motion, level, args.frames, (320, 240), args.ablate, config, follow)
        )
        s = scenes[-1]
        print(f"[{i + 1}/{n}] seed {seed} {motion}: follow {s['follow']['jumps']} jumps "
              f"D {s['follow']['D_mm']:.1f}, per-frame {s['per-frame']['jumps']} jumps, alone D "
              f"{s['alone']['D_mm']:.1f}", file=sys.stderr, flush=True)  # fmt: skip
    summary = summarise(scenes)
    print_table(scenes, summary)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = "people" + ("_tuning" if args.tuning else "") + ("_quick" if args.quick else "")
    name += "_ablate" if args.ablate else ""
    name += f"_from{args.start}" if args.start else ""
    if args.lost_agreement is not None:
        name += f"_agree{args.lost_agreement:g}"
    if args.follow_band is not None:
        name += f"_follow{args.follow_band:g}"
    if args.alone_frames is not None:
        name += f"_alone{args.alone_frames}"
    doc = {"machine": machine_summary(), "seeds": seeds, "summary": summary, "scenes": scenes,
           "size": [320, 240], "config": "TrackerConfig() (shipped MHT_h)" if args.lost_agreement
           is None else f"TrackerConfig(lost_agreement={args.lost_agreement:g})",
           "follow": repr(follow or pt.FollowSettings())}  # fmt: skip
    tmp = out / f".{name}.json.tmp"
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(out / f"{name}.json")
    print(f"wrote {out / (name + '.json')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
