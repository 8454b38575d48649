"""Does the depth map show how thick a person is? (issue 12, a diagnosis; nothing in the
tracker is chosen here.)

The tracker's torso is round: one radius sets its width and its depth, and thick bodies are
tracked too close to the camera (``depth_bias.py``). Whether the data carry the body's girth
at all is what this reads, with the sensor's depth and the detector's keypoints only (what
the tracker has), on the frames where the person faces the camera (the shoulders' 2D
distance at least 0.55 of the neck-to-mid-hip distance; all five torso keypoints detected
at confidence 0.3 or more): across the torso, 45 % of the way from the neck to the mid-hip,
the depth is walked outward on both sides until it jumps by more than 8 cm or has no value.

* ``width_m``: twice the shorter side's extent, in metres at the centre's depth (an arm
  held against the torso lengthens one side; the shorter side is the torso's);
* ``dz_mm``: how far behind the centre the surface lies at 70 % of that half-width (for an
  elliptical cross-section of half-depth b, 0.29 b).

Medians over every second frame of a clip, beside the generator's girth
(``subject["girth_scale"]``), and their correlations with it over the clips. Tuning seeds
only (``seeds.TUNING_SEEDS``); wide clips, clean, 120 frames at 30 fps, 320x240; seeds below
1008 track ``tune.real_motion(seed)``, the others ``tune.PROCEDURAL[seed % 6]``.

    python benchmarks/torso_profile.py --seeds 1000-1013 --out benchmarks/results/torso_profile.json
"""

from __future__ import annotations

import numpy as np
from depth_bias import generate_clip, run_diagnosis

#: The shoulders' 2D distance over the neck-to-mid-hip distance from which a frame faces the
#: camera.
FACING_RATIO = 0.55
#: A depth step larger than this (metres) ends the torso.
EDGE_JUMP = 0.08


def window_depth(depth_m: np.ndarray, point: np.ndarray) -> float:
    """Median of the valid depths (metres) of the 3x3 pixels around ``point`` (u, v); NaN
    outside the image or with fewer than 3 valid ones."""
    u, v = int(round(point[0])), int(round(point[1]))
    h, w = depth_m.shape
    if not (1 <= u < w - 1 and 1 <= v < h - 1):
        return float("nan")
    win = depth_m[v - 1 : v + 2, u - 1 : u + 2].ravel()
    win = win[win > 0]
    return float(np.median(win)) if win.size >= 3 else float("nan")


def frame_profile(
    depth_m: np.ndarray, kp: np.ndarray, conf: np.ndarray, fx: float
) -> tuple[float, float] | None:
    """``(width_m, dz_m)`` of one frame (module docstring), or None where it does not face the
    camera, misses a torso keypoint or the torso is too narrow to read."""
    if min(conf[[1, 2, 5, 8, 11]]) < 0.3:
        return None
    neck, mid_hip = kp[1], 0.5 * (kp[8] + kp[11])
    length = np.linalg.norm(mid_hip - neck)
    if length < 1.0 or np.linalg.norm(kp[2] - kp[5]) < FACING_RATIO * length:
        return None
    axis = (mid_hip - neck) / length
    lateral = np.array([axis[1], -axis[0]])
    centre = neck + 0.45 * (mid_hip - neck)
    zc = window_depth(depth_m, centre)
    if not np.isfinite(zc):
        return None
    extent = []
    for sign in (1.0, -1.0):
        prev, k = zc, 1
        while k < 80:
            z = window_depth(depth_m, centre + sign * k * lateral)
            if not np.isfinite(z) or abs(z - prev) > EDGE_JUMP:
                break
            prev, k = z, k + 1
        extent.append(k - 1)
    half = min(extent)
    if half < 3:
        return None
    sides = [window_depth(depth_m, centre + s * 0.7 * half * lateral) for s in (1.0, -1.0)]
    if not np.all(np.isfinite(sides)):
        return None
    return 2 * half * zc / fx, float(np.mean(sides)) - zc


def measure(seed: int) -> dict:
    """One clip: girth, facing frames read, median width (m) and dz (mm)."""
    motion, seq = generate_clip(seed)
    fx = float(seq.intrinsics.fx)
    rows = [
        frame_profile(seq.depth[t].astype(np.float64) / 1000, seq.keypoints2d[t],
                      seq.confidence[t], fx)
        for t in range(0, seq.depth.shape[0], 2)
    ]  # fmt: skip
    rows = [r for r in rows if r is not None]
    out = {"seed": seed, "motion": motion, "girth": float(seq.subject["girth_scale"]),
           "frames": len(rows)}  # fmt: skip
    if rows:
        arr = np.asarray(rows)
        out["width_m"] = float(np.median(arr[:, 0]))
        out["dz_mm"] = float(np.median(arr[:, 1]) * 1000)
    return out


def table(clips: list[dict], min_frames: int = 5) -> str:
    """The clips and the correlations with girth of those with ``min_frames`` or more."""
    lines = ["seed  motion                   girth frames | width m   dz mm"]
    for c in clips:
        tail = (f"{c['width_m']:.3f} {c['dz_mm']:7.1f}" if c["frames"] >= min_frames
                else "too few facing frames")  # fmt: skip
        lines.append(
            f"{c['seed']:5d} {c['motion'][:24]:24s} {c['girth']:5.2f} {c['frames']:6d} | {tail}"
        )
    ok = [c for c in clips if c["frames"] >= min_frames]
    if len(ok) > 2:
        g = np.array([c["girth"] for c in ok])
        for key in ("width_m", "dz_mm"):
            x = np.array([c[key] for c in ok])
            lines.append(f"{key}: correlation with girth {np.corrcoef(g, x)[0, 1]:+.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return run_diagnosis(argv, __doc__, "torso_profile", measure, table)


if __name__ == "__main__":
    raise SystemExit(main())
