"""Which of the wide generator's factors costs the tracker what (issue 12, a diagnosis).

The "wide" variety of ``posetrack.synth.generate`` changes four things at once against the
standard clip of the same seed: the body (girth, limb lengths, shoulder and hip width,
shoulder drop, torso shift), the camera (height, tilt, roll), the sensor (depth noise,
dropouts) and the detector (jitter, noise family, misses, outliers, swaps, snaps; see
``posetrack.synth._variety``). This runs each tuning clip as the standard clip, the wide clip,
and the wide clip with one factor put back to the standard (``body``, ``camera``, ``sensor``,
``detector``), tracked by the shipped offline (or ``--mode online``) tracker, and prints D per
form, the change against the wide clip, and per body part (head and shoulders, elbows and
wrists, hips, knees and ankles).
``--detector-parts``: the wide clip with one group of the detector's errors put back at a
time (noise, misses, outliers, swaps, snaps; :data:`DETECTOR_PARTS`).

Tuning seeds only (wide real motion 150-157 with ``tune.REAL``, as ``decide.py``); clean
clips by default (``--occlusion 2`` for the occluded ones); 120 frames at 30 fps, 320x240.

    python benchmarks/wide_factors.py --out benchmarks/results/wide_factors.json
    python benchmarks/wide_factors.py --part 0 --parts 2 --out A.json  # two processes
    python benchmarks/wide_factors.py --merge A.json B.json --out benchmarks/results/...
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from parts import add_part_arguments, check_part, share
from seeds import TUNING_SEEDS
from tune import REAL

import posetrack as pt
from posetrack.app import machine_info
from posetrack.synth import _generate
from posetrack.synth._detector import DetectorConfig
from posetrack.synth._sensor import SensorConfig
from posetrack.synth._skeleton import BodyVariation

SEEDS = tuple(range(150, 158))
FORMS = ("standard", "wide", "wide, standard body", "wide, standard camera",
         "wide, standard sensor", "wide, standard detector")  # fmt: skip
#: ``--detector-parts``: the wide clip with one group of the detector's error parameters put
#: back to the standard detector's (``DetectorConfig`` field names).
DETECTOR_PARTS = {
    "noise": ("sigma_px", "rho", "noise_family", "noise_dof"),
    "misses": ("p_miss_visible", "p_miss_self", "p_miss_face", "p_miss_occluder"),
    "outliers": ("outlier_rate", "outlier_frames"),
    "swaps": ("swap_rate", "swap_lengths", "body_swap_rate"),
    "snaps": ("snap_rate",),
    # The two halves of "swaps": an arm's or leg's pair exchanged (episode lengths kept: the
    # body swaps and snaps draw theirs from them too), and the whole body read facing away.
    "limb swaps": ("swap_rate",),
    "body swaps": ("body_swap_rate",),
}
DETECTOR_FORMS = ("wide", *(f"wide, standard detector {g}" for g in DETECTOR_PARTS))
#: COCO-18 indices of the body parts reported (the 13 body joints of ``pt.accuracy``).
PARTS = {"neck+shoulders": (1, 2, 5), "elbows+wrists": (3, 4, 6, 7), "hips": (8, 11),
         "knees+ankles": (9, 10, 12, 13)}  # fmt: skip
_DRAW = _generate.draw_wide


def generate(seed: int, motion: str, occlusion: int, form: str, frames: int = 120):
    """The clip of ``seed`` in ``form`` (one of :data:`FORMS`), ``frames`` long."""
    kw: dict = {}
    patch = None
    if form == "wide, standard sensor":
        kw["sensor"] = SensorConfig()
    elif form == "wide, standard detector":
        kw["detector"] = DetectorConfig()
    elif form.startswith("wide, standard detector "):
        # The wide clip's detector (as generate records it) with one group of fields as the
        # standard detector has them.
        wide = pt.synth.generate(seed, motion=motion, n_frames=1, with_rgb=False, variety="wide")
        std = DetectorConfig()
        group = DETECTOR_PARTS[form.removeprefix("wide, standard detector ")]
        kw["detector"] = dataclasses.replace(
            DetectorConfig(**wide.meta["detector"]), **{f: getattr(std, f) for f in group}
        )
    elif form == "wide, standard body":
        patch = {"body": BodyVariation()}
    elif form == "wide, standard camera":
        patch = {"camera": None}  # make_scene's own draw
    if patch is not None:
        _generate.draw_wide = lambda rng: dataclasses.replace(_DRAW(rng), **patch)
    try:
        return pt.synth.generate(
            seed, motion=motion, n_frames=frames, fps=30.0, occlusion_level=occlusion,
            width=320, height=240, with_rgb=False,
            variety="standard" if form == "standard" else "wide", **kw,
        )  # fmt: skip
    finally:
        _generate.draw_wide = _DRAW


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mode", choices=("offline", "online"), default="offline")
    ap.add_argument("--occlusion", type=int, default=0)
    ap.add_argument(
        "--detector-parts", action="store_true",
        help="the wide clip with one group of detector errors put back at a time",
    )  # fmt: skip
    add_part_arguments(ap)
    ap.add_argument(
        "--forms", default=None, help="a subset of the forms, separated by ';' (names hold commas)"
    )
    ap.add_argument("--merge", nargs="*", default=None, help="JSON files of parts to merge")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "wide_factors.json"))
    a = ap.parse_args()
    check_part(ap, a)
    assert all(s in TUNING_SEEDS for s in SEEDS)
    forms = DETECTOR_FORMS if a.detector_parts else FORMS
    if a.forms:
        wanted = [f.strip() for f in a.forms.split(";")]
        unknown = [f for f in wanted if f not in forms]
        if unknown:
            ap.error(f"--forms: {unknown} are none of {forms}")
        forms = tuple(f for f in forms if f in wanted)
    if a.merge:
        runs = [r for f in a.merge for r in json.loads(Path(f).read_text())["runs"]]
    else:
        runs = []
        todo = share([(i, s, f) for i, s in enumerate(SEEDS) for f in forms], a)
        t0 = time.perf_counter()
        for i, seed, form in todo:
            motion = REAL[i % len(REAL)]
            seq = generate(seed, motion, a.occlusion, form)
            est = pt.track(
                seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, mode=a.mode
            ).keypoints3d  # fmt: skip
            err = pt.joint_errors(est, seq.joints3d, joints=tuple(range(18))) * 1000
            run = {
                "seed": seed, "motion": motion, "form": form,
                "D_mm": pt.accuracy(est, seq.joints3d).mean_mm,
                **{p: float(np.nanmean(err[:, list(j)])) for p, j in PARTS.items()},
            }  # fmt: skip
            runs.append(run)
            print(f"[{time.perf_counter() - t0:5.0f}s] {json.dumps(run)}", file=sys.stderr)
    table = {}
    for form in forms:
        rs = [r for r in runs if r["form"] == form]
        if not rs:
            continue
        table[form] = {k: float(np.mean([r[k] for r in rs])) for k in ("D_mm", *PARTS)}
        table[form]["clips"] = len(rs)
    if "wide" in table:
        wide = {(r["seed"]): r["D_mm"] for r in runs if r["form"] == "wide"}
        for form in table:
            d = [
                r["D_mm"] - wide[r["seed"]] for r in runs if r["form"] == form and r["seed"] in wide
            ]
            table[form]["vs_wide_mm"] = float(np.mean(d)) if d else None
            table[form]["clips_better_than_wide"] = int(np.sum(np.asarray(d) < -1.0))
    print(f"\n{a.mode}, occlusion {a.occlusion}, wide real tuning clips {SEEDS[0]}-{SEEDS[-1]}")
    print(f"{'form':26s} {'D mm':>6s} {'vs wide':>8s} {'better':>6s} "
          + " ".join(f"{p:>14s}" for p in PARTS))  # fmt: skip
    for form, v in table.items():
        vs = "" if v.get("vs_wide_mm") is None else f"{v['vs_wide_mm']:+8.1f}"
        print(f"{form:26s} {v['D_mm']:6.1f} {vs:>8s} {v.get('clips_better_than_wide', 0):6d} "
              + " ".join(f"{v[p]:14.1f}" for p in PARTS))  # fmt: skip
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps({
        "benchmark": "wide_factors", "mode": a.mode, "occlusion": a.occlusion, "seeds": SEEDS,
        "table": table, "runs": runs, "machine": machine_info(),
    }, indent=1))  # fmt: skip
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
