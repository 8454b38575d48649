"""How far the torso's joints sit from the camera against the truth, per clip, beside the
generated body's girth (issue 12, a diagnosis; nothing in the tracker is chosen here).

The landmarks the tracker lifts lie on the body's surface; ``_geometry.surface_offsets``
pushes each one back along its ray by a depth tied to the model's limb radii (shoulder 1.1 x
the upper arm's, hip 1.35 x the thigh's, neck 0.6 x the torso's). Whether that depth follows
the person is what this reads: each tuning clip is tracked offline (the shipped tracker) with
and without the body-shape refinement, and the mean signed depth error (camera z, mm;
negative = too close to the camera) of the neck, shoulders and hips is printed for the
per-frame pass and the output (and each part's x / y / z error), with the generator's
girth (``subject["girth_scale"]``: every part radius and the torso's width and depth scale
with it) and the refined torso radius.

Tuning seeds only (``seeds.TUNING_SEEDS``); wide clips (``variety="wide"``), clean, 120
frames at 30 fps, 320x240; seeds below 1008 track ``tune.real_motion(seed)``, the others
``tune.PROCEDURAL[seed % 6]``.

    python benchmarks/depth_bias.py --seeds 1000-1013 --out benchmarks/results/depth_bias.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from seeds import TUNING_SEEDS, TUNING_TEXT, parse_seeds
from tune import PROCEDURAL, real_motion

import posetrack as pt
from posetrack.app import machine_info

#: COCO-18 neck, shoulders and hips.
TORSO = (1, 2, 5, 8, 11)
#: (name, ``pt.track`` keywords) of the two runs of each clip.
RUNS = (("refined", {}), ("landmark shape", {"refine": None}))


def clip_motion(seed: int) -> str:
    """The motion a seed's clip tracks (see the module docstring)."""
    return real_motion(seed) if seed < 1008 else PROCEDURAL[seed % len(PROCEDURAL)]


def generate_clip(seed: int):
    """``(motion, sequence)`` of a seed's clip: wide, clean, 120 frames at 30 fps, 320x240
    (this diagnosis's, ``torso_profile.py``'s and ``oracle_torso.py``'s)."""
    motion = clip_motion(seed)
    seq = pt.synth.generate(
        seed, motion=motion, n_frames=120, fps=30.0, occlusion_level=0, width=320, height=240,
        with_rgb=False, variety="wide",
    )  # fmt: skip
    return motion, seq


def torso_depth_bias(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean signed camera-z error (mm) of the torso keypoints over the frames with an
    estimate; negative: closer to the camera than the truth."""
    ok = np.isfinite(estimate).all(axis=(1, 2))
    return float(((estimate - truth)[ok][:, TORSO, 2]).mean() * 1000)


#: The torso keypoints by part, for the per-part errors.
PARTS = {"neck": (1,), "shoulders": (2, 5), "hips": (8, 11)}


def part_errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, list[float]]:
    """Per part of :data:`PARTS`: the mean signed camera-frame error (x, y, z; mm) over the
    frames with an estimate (camera y points down: negative y = too high; negative z = too
    close to the camera)."""
    ok = np.isfinite(estimate).all(axis=(1, 2))
    err = (estimate - truth)[ok] * 1000
    return {name: err[:, list(k)].mean(axis=(0, 1)).tolist() for name, k in PARTS.items()}


def measure(seed: int) -> dict:
    """One clip: girth, and per run the output's and the per-frame pass's torso depth bias,
    D (body joints, mm) and the tracker's torso radius."""
    motion, seq = generate_clip(seed)
    out = {"seed": seed, "motion": motion, "girth": float(seq.subject["girth_scale"])}
    for name, kwargs in RUNS:
        res = pt.track(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, seed=0, **kwargs)
        out[name] = {
            "output_torso_z_mm": torso_depth_bias(res.keypoints3d, seq.joints3d),
            "per_frame_torso_z_mm": torso_depth_bias(res.per_frame_keypoints3d, seq.joints3d),
            "D_mm": pt.accuracy(res.keypoints3d, seq.joints3d).mean_mm,
            "part_xyz_mm": part_errors(res.keypoints3d, seq.joints3d),
            "torso_radius_m": float(res.shape.torso_radius),
            "shape": {k: float(v) for k, v in res.shape.to_dict().items()},
        }
    return out


def table(clips: list[dict]) -> str:
    lines = [
        "seed  motion                   girth | torso z mm: output refined / landmark shape, "
        "per-frame | torso radius m | D mm refined / landmark shape",
    ]
    for c in clips:
        r, s = c["refined"], c["landmark shape"]
        lines.append(
            f"{c['seed']:5d} {c['motion'][:24]:24s} {c['girth']:5.2f} | "
            f"{r['output_torso_z_mm']:7.1f} {s['output_torso_z_mm']:7.1f} "
            f"{r['per_frame_torso_z_mm']:7.1f} | {r['torso_radius_m']:.3f} | "
            f"{r['D_mm']:6.1f} {s['D_mm']:6.1f}"
        )
    g = np.array([c["girth"] for c in clips])
    if len(clips) > 2:
        for key in ("output_torso_z_mm", "per_frame_torso_z_mm"):
            z = np.array([c["refined"][key] for c in clips])
            slope, icpt = np.polyfit(g, z, 1)
            lines.append(
                f"refined {key}: correlation with girth {np.corrcoef(g, z)[0, 1]:+.2f}, "
                f"fit {icpt:+.1f} {slope:+.1f} x girth"
            )
        for name in PARTS:
            e = np.array([c["refined"]["part_xyz_mm"][name] for c in clips])
            slope, icpt = np.polyfit(g, e[:, 2], 1)
            lines.append(
                f"refined {name}: mean x / y / z error {e[:, 0].mean():+.1f} / "
                f"{e[:, 1].mean():+.1f} / {e[:, 2].mean():+.1f} mm (y down), z fit "
                f"{icpt:+.1f} {slope:+.1f} x girth"
            )
        radius = np.array([c["refined"]["torso_radius_m"] for c in clips])
        slope, icpt = np.polyfit(g, radius, 1)
        lines.append(f"refined torso radius: {icpt:.3f} {slope:+.3f} x girth m")
    return "\n".join(lines)


def run_diagnosis(argv: list[str] | None, doc: str, name: str, measure_clip, make_table) -> int:
    """The command line of a per-clip tuning diagnosis (this one, ``torso_profile.py``):
    ``--seeds`` (tuning seeds only, else exit status 2 before any work) and ``--out``; each
    seed measured by ``measure_clip(seed)`` (progress on stderr), ``make_table(clips)``
    printed and, with ``--out``, written with the clips as JSON."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--seeds", default="1000-1013", help="tuning seeds, e.g. 1000-1013")
    ap.add_argument("--out", help="write the clips and the table here (JSON)")
    a = ap.parse_args(argv)
    seeds = parse_seeds(a.seeds)
    if not all(s in TUNING_SEEDS for s in seeds):
        print(f"error: --seeds: tuning seeds only ({TUNING_TEXT})", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    clips = []
    for i, seed in enumerate(seeds):
        clips.append(measure_clip(seed))
        print(f"[{i + 1}/{len(seeds)}] seed {seed} done", file=sys.stderr, flush=True)
    text = make_table(clips)
    print(text)
    if a.out:
        Path(a.out).write_text(json.dumps({
            "benchmark": name, "seeds": seeds, "clips": clips, "table": text,
            "seconds": time.perf_counter() - t0, "machine": machine_info(),
        }, indent=1))  # fmt: skip
        print(f"wrote {a.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_diagnosis(argv, __doc__, "depth_bias", measure, table)


if __name__ == "__main__":
    raise SystemExit(main())
