"""Does Delta tell ``reinit_check_tracked``'s right flips from its wrong ones? (a diagnosis)

``TrackerConfig.reinit_check_tracked`` replaces a side view's re-initialisation fit that
faces away from the last tracked pose by the fit of the exchanged landmarks. It is right
exactly as often as the last tracked pose faces the right way (benchmarks/README.md, "A
facing check against the last tracked pose"). This script re-tracks the runs its offline
screen changed (``results/decide_tracked25.json``: tuning seeds 2222-2251), and at every
firing records both fits' Delta (Eq. (3), the tracker's own scoring of this frame's depth)
and whether each faces as the truth does (the shoulders' and hips' left axis, seen from
above), then prints how a margin rule "keep the exchanged fit unless its Delta is worse by
more than m" would have sorted them. Tuning seeds only; the spy wraps private tracker
functions and changes nothing it reads.

    python benchmarks/flip_delta.py OUT.json [--part 0 --parts 2]
        [--screen results/decide_tracked25.json --variant tracked25]

``--screen``/``--variant`` name another offline screen (e.g. a ``reinit_check_delta`` one's
JSONL) whose changed runs to re-track; the re-tracking is always the default tracker's.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from decide import cmu_late, generate_clip
from parts import add_part_arguments, check_part, share

import posetrack as pt
import posetrack._tracker as tracker_module
from posetrack import _body as body

SCREEN = Path(__file__).parent / "results" / "decide_tracked25.json"
MARGINS = (0.0, 0.005, 0.01, 0.015, 0.02, 0.05)


def changed_runs(
    screen: Path = SCREEN, variant: str = "tracked25"
) -> list[tuple[int, str, str, int, int]]:
    """``(seed, motion, variety, occlusion, tracker seed)`` of the runs an offline screen
    (``decide.py``'s JSON with ``"records"``, or its JSONL, one record a line) changed:
    ``variant``'s D differs from the default's."""
    text = screen.read_text()
    recs = (json.loads(text)["records"] if screen.suffix == ".json"
            else [json.loads(line) for line in text.splitlines() if line.strip()])  # fmt: skip
    return [
        (r["seed"], r["motion"],
         "wide" if r["group"] == "walk_across" else cmu_late(r["seed"])[3], r["occ"], r["tseed"])
        for r in recs if r["default"]["D"] != r[variant]["D"]
    ]  # fmt: skip


def left_axis(k: np.ndarray) -> np.ndarray:
    """The body's left direction in the camera's x-z plane from COCO-18 shoulders and hips
    (``(..., 18, 3)`` keypoints -> ``(..., 3)`` unit vectors, y = 0; ``facing.py``'s
    ``facing_error_deg`` reads the shoulders alone, which a side view's far shoulder makes
    noisier)."""
    k = np.asarray(k, np.float64)
    v = ((k[..., 5, :] - k[..., 2, :]) + (k[..., 11, :] - k[..., 8, :])) * np.array([1.0, 0, 1])
    return v / (np.linalg.norm(v, axis=-1, keepdims=True) + 1e-9)


def spy(events: list) -> None:
    """Wrap the tracker's re-initialisation so that each firing of the check appends the
    frame, both fits' Delta and their keypoints to ``events``."""
    init, turned_fit, fit = (
        tracker_module.Tracker._initialize, tracker_module.Tracker._turned_fit,
        tracker_module.initial_fit,
    )  # fmt: skip
    seen: dict = {}

    def fit_spy(*a, **k):
        out = fit(*a, **k)
        seen.setdefault("fits", []).append(np.asarray(out[0].params, np.float64))
        return out

    def turned_spy(self, params, has_depth):
        test = turned_fit(self, params, has_depth)
        seen["fired"] = seen.get("fired", False) or test is not None
        return test

    def init_spy(self, depth_m, kp, conf):
        seen.clear()
        ok = init(self, depth_m, kp, conf)
        if seen.get("fired") and len(seen.get("fits", ())) == 2:
            fits = np.stack(seen["fits"])
            delta = tracker_module.score_fits(
                self.config, self.shape, self.intrinsics, self._floor,
                np.asarray(depth_m, np.float32), fits.astype(np.float32),
            )  # fmt: skip
            kps = [np.asarray(body.keypoints(self.shape, jnp.asarray(p, jnp.float32)))
                   for p in fits]  # fmt: skip
            events.append((self._frames_seen - 1, [float(d) for d in delta], kps))
        return ok

    tracker_module.initial_fit = fit_spy
    tracker_module.Tracker._turned_fit = turned_spy
    tracker_module.Tracker._initialize = init_spy


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", help="JSON: one row per firing (this process's runs)")
    ap.add_argument("--screen", type=Path, default=SCREEN,
                    help="the offline screen whose changed runs to re-track (.json or .jsonl)")
    ap.add_argument("--variant", default="tracked25",
                    help="the screen's variant: a run changed where its D differs")  # fmt: skip
    add_part_arguments(ap)
    a = ap.parse_args()
    check_part(ap, a)
    events: list = []
    spy(events)
    rows = []
    for seed, motion, variety, occ, ts in share(changed_runs(a.screen, a.variant), a):
        seq = generate_clip(seed, motion, variety, occ)
        events.clear()
        config = pt.TrackerConfig(reinit_check_tracked=25)
        pt.Tracker(seq.intrinsics, config, mode="offline", seed=ts).run(
            seq.depth, seq.keypoints2d, seq.confidence
        )
        for frame, delta, kps in events:
            truth = left_axis(np.asarray(seq.joints3d[min(frame, len(seq.joints3d) - 1)]))
            plain, exchanged = (float(left_axis(k) @ truth) for k in kps)
            kind = ("right" if exchanged > 0 >= plain else
                    "wrong" if plain > 0 >= exchanged else "neither")  # fmt: skip
            rows.append({
                "seed": seed, "motion": motion, "occ": occ, "tseed": ts, "frame": frame,
                "delta_plain": delta[0], "delta_exchanged": delta[1],
                "truth_dot_plain": plain, "truth_dot_exchanged": exchanged, "flip": kind,
            })  # fmt: skip
            print(json.dumps(rows[-1]), flush=True)
    Path(a.out).write_text(json.dumps(rows, indent=1) + "\n")
    print(table(rows))
    return 0


def table(rows: list[dict]) -> str:
    """How the margin rule sorts the firings: right flips kept, wrong ones refused."""
    diff = {k: [r["delta_exchanged"] - r["delta_plain"] for r in rows if r["flip"] == k]
            for k in ("right", "wrong", "neither")}  # fmt: skip
    lines = [f"firings: {', '.join(f'{k} {len(v)}' for k, v in diff.items())}",
             "margin m   right flips kept   wrong flips refused"]  # fmt: skip
    for m in MARGINS:
        kept = sum(d <= m for d in diff["right"])
        refused = sum(d > m for d in diff["wrong"])
        lines.append(f"{m:8.3f}   {kept:4d} / {len(diff['right']):<4d}       "
                     f"{refused:4d} / {len(diff['wrong'])}")  # fmt: skip
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
