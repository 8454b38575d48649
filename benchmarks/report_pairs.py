"""The report stage of a decision: tracker variants on one report set's clips with several
tracker seeds, as JSON lines in ``decide.py``'s format (``paired.py`` reads both).

``decide.py`` runs tuning clips only; a candidate that meets its tuning rule is then read on
the four report sets of ``motion.py`` (``--set``: standard, wide, real, real-wide: 12 clips
each, ``REPORT_SEEDS`` 0-11, at occlusion 0 and 2, 120 frames, 320x240). One tracker seed
decides little there (benchmarks/README.md, "A side view hides the far arm": the seed alone
moves a clip's D by 30-80 mm where its track comes apart), so each clip is tracked with the
tracker seeds given, and a variant's tracker-seed-0 rows that ``motion.py`` already stored
can be read in instead of tracked again (``--stored VARIANT=FILE:ROW``; ``pt.track``'s seed
is 0): ``ROW`` is a row of the file's clips (``"MHT_h online L=3"``) or, for the pose-weight
runs' files, a key of each clip (``cand``).

    python benchmarks/report_pairs.py OUT.jsonl --set wide --mode offline \\
        --stored default=benchmarks/results/motion_pose_weight_wide.json:cand \\
        --stored "far1.0=benchmarks/results/motion_far_wide.json:MHT_h offline, far side gated"
    python benchmarks/report_pairs.py OUT.jsonl --set wide --mode offline \\
        --variants default,far1.0 --tracker-seeds 1
    python benchmarks/paired.py OUT.jsonl --candidate far1.0

Variants as ``decide.py`` names them. Never tune on what this prints: it is the report.
"""

from __future__ import annotations

import argparse
import json

from decide import settings, track
from motion import report_clips
from paired import join
from parts import add_part_arguments, check_part, share

#: ``--set``: (``posetrack.synth`` variety, ``motion.py --motions``) of each report set.
SETS = {
    "standard": ("standard", "procedural"),
    "wide": ("wide", "procedural"),
    "real": ("standard", "real"),
    "real-wide": ("wide", "real"),
}


def stored_records(spec: str, clips: list[tuple[int, str]], group: str) -> list[dict]:
    """Tracker-seed-0 records of one variant from a stored ``motion.py`` result: ``spec`` is
    ``VARIANT=FILE:ROW``. The file's clips must be the set's (seed, motion) in order."""
    name, eq, rest = spec.partition("=")
    path, colon, row = rest.partition(":")
    if not (eq and colon and name and row):
        raise SystemExit(f"error: --stored {spec!r}: expected VARIANT=FILE:ROW")
    try:
        with open(path) as f:
            stored = json.load(f)["clips"]
    except (OSError, ValueError, KeyError) as e:
        raise SystemExit(f"error: --stored {path}: not a motion.py result ({e})") from None
    want = [(seed, motion, occ) for seed, motion in clips for occ in (0, 2)]
    have = [(c["seed"], c["motion"], c["occlusion"]) for c in stored]
    if have != want:
        raise SystemExit(
            f"error: --stored {path}: its clips {have[:3]}... are not the set's {want[:3]}..."
        )
    out = []
    for c in stored:
        values = c["rows"].get(row) if "rows" in c else c.get(row)
        if values is None:
            keys = list(c["rows"]) if "rows" in c else [k for k in c if isinstance(c[k], dict)]
            raise SystemExit(f"error: --stored {path}: no row {row!r} (it has {keys})")
        out.append({
            "group": group, "seed": c["seed"], "motion": c["motion"], "occ": c["occlusion"],
            "tseed": 0, name: {
                "D": values["D_mm"], "cov": values["coverage"], "swaps": values["swap_frames"],
                "accel": values["accel_mm"], "stored": f"{path}:{row}",
            },
        })  # fmt: skip
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", help="JSON lines, appended to")
    ap.add_argument("--set", choices=tuple(SETS), required=True)
    ap.add_argument("--mode", choices=("offline", "online", "per-frame"), required=True)
    ap.add_argument("--variants", default="", help="decide.py's variant names to track")
    ap.add_argument("--tracker-seeds", default="1")
    ap.add_argument(
        "--stored", action="append", default=[],
        help="VARIANT=FILE:ROW: that variant's tracker-seed-0 rows from a motion.py result",
    )  # fmt: skip
    add_part_arguments(ap)
    a = ap.parse_args()
    check_part(ap, a)
    variety, motions = SETS[a.set]
    try:
        clips = report_clips(12, 0, motions)
    except ValueError as e:
        ap.error(str(e))
    group = f"report {a.set}"
    variants = {v: settings(v, a.mode) for v in a.variants.split(",") if v}
    if not variants and not a.stored:
        ap.error("nothing to do: give --variants to track or --stored rows to read")
    stored = join([(r, spec) for spec in a.stored for r in stored_records(spec, clips, group)])
    seeds = [int(s) for s in a.tracker_seeds.split(",")] if variants else []
    todo = share([((group, seed, motion, variety), occ, ts) for seed, motion in clips
                  for occ in (0, 2) for ts in seeds], a)  # fmt: skip
    with open(a.out, "a") as f:
        f.writelines(json.dumps(rec) + "\n" for rec in stored)
    track(todo, variants, a.mode, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
