"""What a torso as deep as the person's would buy: the shipped tracker against the same tracker
whose landmark-based body shape carries the generated body's own chest half-depth as its
``torso_radius`` (issue 12, a diagnosis with an oracle; nothing in the tracker is chosen here).

``depth_bias.py`` finds thick bodies tracked too close to the camera and the refined torso
radius barely following the body's girth. This bounds that lever from above: the torso
radius the tracker starts from (and the body-shape refinement's prior is centred on) is set
to the generator's chest ellipsoid's front-to-back semi-axis, ``0.106 x girth_scale`` m
(``posetrack.synth._skeleton.sample_subject``): information no tracker has, so the
"oracle" column is a ceiling, not a method. The "oracle_all" run also multiplies every other
part radius (arms, legs, head; the lifting's surface offsets and the pelvis and shoulder
capsules follow them) by the generated body's girth: the whole body's thickness known.
Everything else is the shipped offline tracker (``pt.track``, tracker seed 0), with its
refinement after the pass.

Tuning seeds only, the clips of ``depth_bias.py`` (wide, clean, 120 frames at 30 fps,
320x240). Per clip: D (13 body joints, mm), the torso keypoints' mean signed depth error (mm;
negative = too close to the camera), each part's x / y / z error and the refined torso
radius.

    python benchmarks/oracle_torso.py --seeds 1000-1013 --out benchmarks/results/oracle_torso.json
"""

from __future__ import annotations

import numpy as np
from depth_bias import PARTS, generate_clip, part_errors, run_diagnosis, torso_depth_bias

import posetrack as pt
import posetrack._tracker as tracker_module

#: The generator's chest ellipsoid's front-to-back semi-axis per unit of girth, metres.
CHEST_HALF_DEPTH = 0.106
#: The runs of each clip (see the module docstring).
RUNS = ("shipped", "oracle", "oracle_all")


def _with_radii(girth: float, every_radius: bool):
    """``estimate_shape`` (the tracker's landmark-based shape) with ``torso_radius`` replaced
    by the generated chest's half-depth and, with ``every_radius``, every other part radius
    multiplied by the generated body's girth."""
    original = tracker_module.estimate_shape

    def patched(*args, **kwargs):
        shape, ratios = original(*args, **kwargs)
        values = shape.to_dict()
        if every_radius:
            values = {k: v * girth if k.endswith("_radius") else v for k, v in values.items()}
        values["torso_radius"] = CHEST_HALF_DEPTH * girth
        return pt.BodyShape.create(**values), ratios

    return patched


def measure(seed: int) -> dict:
    """One clip tracked as shipped, with the oracle torso radius and with every radius."""
    motion, seq = generate_clip(seed)
    girth = float(seq.subject["girth_scale"])
    out = {"seed": seed, "motion": motion, "girth": girth,
           "oracle_torso_radius_m": CHEST_HALF_DEPTH * girth}  # fmt: skip
    original = tracker_module.estimate_shape
    estimates = (
        original,
        _with_radii(girth, every_radius=False),
        _with_radii(girth, every_radius=True),
    )
    for name, estimate in zip(RUNS, estimates):
        tracker_module.estimate_shape = estimate
        try:
            res = pt.track(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, seed=0)
        finally:
            tracker_module.estimate_shape = original
        out[name] = {
            "D_mm": pt.accuracy(res.keypoints3d, seq.joints3d).mean_mm,
            "torso_z_mm": torso_depth_bias(res.keypoints3d, seq.joints3d),
            "part_xyz_mm": part_errors(res.keypoints3d, seq.joints3d),
            "torso_radius_m": float(res.shape.torso_radius),
        }
    return out


def table(clips: list[dict]) -> str:
    lines = [
        "seed  motion                   girth | D mm shipped / oracle / all radii | torso z mm "
        "shipped / oracle / all radii | torso radius m shipped / oracle (start)",
    ]
    for c in clips:
        s, o, a = c["shipped"], c["oracle"], c["oracle_all"]
        lines.append(
            f"{c['seed']:5d} {c['motion'][:24]:24s} {c['girth']:5.2f} | {s['D_mm']:6.1f} "
            f"{o['D_mm']:6.1f} {a['D_mm']:6.1f} | {s['torso_z_mm']:7.1f} {o['torso_z_mm']:7.1f} "
            f"{a['torso_z_mm']:7.1f} | "
            f"{s['torso_radius_m']:.3f} {o['torso_radius_m']:.3f} "
            f"({c['oracle_torso_radius_m']:.3f})"
        )
    g = np.array([c["girth"] for c in clips])
    for label, keep in (("all", g > 0), ("girth > 1.1", g > 1.1)):
        if not keep.any():
            continue
        sel = [c for c, k in zip(clips, keep) if k]
        for run in RUNS[1:]:
            d = np.array([[c["shipped"]["D_mm"], c[run]["D_mm"]] for c in sel])
            z = np.array([[c["shipped"]["torso_z_mm"], c[run]["torso_z_mm"]] for c in sel])
            lines.append(
                f"{label} ({len(sel)} clips), shipped -> {run}: D {d[:, 0].mean():.2f} -> "
                f"{d[:, 1].mean():.2f} mm (better / worse by > 2 mm: "
                f"{(d[:, 1] < d[:, 0] - 2).sum()} / {(d[:, 1] > d[:, 0] + 2).sum()}), torso z "
                f"{z[:, 0].mean():+.1f} -> {z[:, 1].mean():+.1f} mm"
            )
    for name in PARTS:
        e = [np.mean([c[r]["part_xyz_mm"][name][2] for c in clips]) for r in RUNS]
        lines.append(f"{name}: mean z error " + " / ".join(f"{v:+.1f}" for v in e) + " mm")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return run_diagnosis(argv, __doc__, "oracle_torso", measure, table)


if __name__ == "__main__":
    raise SystemExit(main())
