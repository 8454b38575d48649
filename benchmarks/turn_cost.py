"""How many frames ``SideSettings.frontal_turns`` tracks twice (its cost, from 2D alone)

The offline turn judgement (``SideSettings(frontal_turns=X)``) tracks every turn it finds twice:
as labelled and mirrored. Which frames it finds depends only on the detections (the person
followed, the two-sided reading's arbitrated stretches, the detected shoulders' spread), not on
any fit, so this script reads them without tracking: the same calls ``Tracker.run`` makes before
its first fit (``Tracker._offline_plan``: the two-sided labelling, the arbitrated stretches,
the turns widened around them). It prints, per group and occlusion, the turns found and the
share of frames tracked twice, and with ``--check`` also tracks the first clip with a turn and
checks the count against :attr:`Tracker.turn_spans` (the frames actually tracked twice).
Decision clips of ``decide.py`` (tuning seeds).

    python benchmarks/turn_cost.py --turns 0.45 --side-seeds 2692-2707 --real-seeds 2708-2721
        --cmu-late-seeds 2722-2729 [--json OUT] [--check]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict

from decide import clips, generate_clip
from seeds import parse_seeds

import posetrack as pt


def turns_of(seq: pt.synth.SyntheticSequence, sides: pt.SideSettings) -> list[tuple[int, int]]:
    """The stretches ``[(start, stop), ...]`` an offline tracker with ``sides`` tracks twice on
    ``seq`` (``Tracker.run``'s own plan, before any fit)."""
    tr = pt.Tracker(seq.intrinsics, mode="offline", sides=sides)
    return tr._offline_plan(seq.depth, seq.keypoints2d, seq.confidence)[3]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--turns", type=float, default=0.45, help="SideSettings.frontal_turns")
    ap.add_argument("--side-seeds")
    ap.add_argument("--real-seeds")
    ap.add_argument("--cmu-late-seeds")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument(
        "--check", action="store_true", help="track the first clip with a turn and compare"
    )
    a = ap.parse_args()
    side, real, cmu = (
        None if t is None else parse_seeds(t)
        for t in (a.side_seeds, a.real_seeds, a.cmu_late_seeds)
    )
    if side is None and cmu is None:
        ap.error("give --side-seeds or --cmu-late-seeds (with --real-seeds if wanted)")
    sides = pt.SideSettings.for_mode("offline", frontal_turns=a.turns)
    checked = False
    rows, totals = [], defaultdict(lambda: [0, 0, 0, 0])  # runs, turns, twice, frames
    for group, seed, motion, variety in clips(real, side, False, None, None, cmu):
        for occ in (0, 2):
            seq = generate_clip(seed, motion, variety, occ)
            spans = turns_of(seq, sides)
            twice = sum(b - a for a, b in spans)
            rows.append({"group": group, "seed": seed, "occ": occ, "turns": spans, "twice": twice})
            tot = totals[(group, occ)]
            tot[0], tot[1], tot[2], tot[3] = (
                tot[0] + 1,
                tot[1] + len(spans),
                tot[2] + twice,
                (tot[3] + len(seq.depth)),
            )
            print(f"{group:12s} {seed} occ {occ}: {len(spans)} turns, {twice} frames", flush=True)
            if a.check and spans and not checked:
                checked = True
                tr = pt.Tracker(seq.intrinsics, mode="offline", sides=sides)
                tr.run(seq.depth, seq.keypoints2d, seq.confidence)
                tracked = [(s, e) for s, e, *_ in tr.turn_spans]
                if tracked != spans:
                    raise SystemExit(f"turn_spans {tracked} differ from the 2D reading {spans}")
                print("check: the tracker's turn_spans equal the 2D reading", flush=True)
    print("\n| group | occlusion | runs | turns | frames tracked twice | share |")
    print("|---|---|---|---|---|---|")
    all_twice = all_frames = 0
    for (group, occ), (n, turns, twice, frames) in sorted(totals.items()):
        print(f"| {group} | {occ} | {n} | {turns} | {twice} of {frames} | {twice / frames:.1%} |")
        all_twice, all_frames = all_twice + twice, all_frames + frames
    print(f"| all | | {len(rows)} | | {all_twice} of {all_frames} | {all_twice / all_frames:.1%} |")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"turns": a.turns, "rows": rows, "twice": all_twice, "frames": all_frames}, f)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
