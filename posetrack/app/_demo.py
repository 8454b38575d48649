"""``posetrack demo``: generate a sequence, track it, print a table, write pictures.

Offline and self-contained: the sequence comes from ``posetrack.synth`` (a body, sensor and
detector model that differ from the tracker's own; see its docstring).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from .._camera import project
from .._config import TrackerConfig
from .._metrics import accuracy, naive_lifting
from .._result import TrackResult
from .._tracker import Tracker, lift_sequence
from ._machine import machine_summary
from ._progress import ProgressBar
from ._viz import (
    GREEN,
    RED,
    colorize_depth,
    contact_sheet,
    crop_box,
    draw_skeleton,
    put_label,
    write_gif,
    write_png,
)


def _pictures(seq, result: TrackResult, *, every: int, label: str) -> list[np.ndarray]:
    """Depth (grey, near = bright) with the true (green) and estimated (red) skeletons, cropped
    to the person over the whole sequence and scaled to 240 px high."""
    import cv2

    intr = seq.intrinsics
    gt_uv = np.asarray(project(intr, seq.joints3d))
    top, bottom, left, right = crop_box(gt_uv, seq.depth.shape[1:])
    scale = 240 / (bottom - top)
    frames = []
    for t in range(0, len(seq.depth), every):
        img = colorize_depth(seq.depth[t].astype(np.float32) / 1000.0, near=1.0, far=5.0, gray=True)
        img = cv2.resize(
            img[top:bottom, left:right], None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA
        )
        offset = np.array([left, top])
        img = draw_skeleton(img, (gt_uv[t] - offset) * scale, color=GREEN)
        if np.isfinite(result.keypoints3d[t]).all():
            est_uv = np.asarray(project(intr, result.keypoints3d[t]))
            img = draw_skeleton(img, (est_uv - offset) * scale, color=RED)
        frames.append(put_label(img, f"{label} #{t}"))
    return frames


def run_demo(
    out_dir: str | Path = "posetrack-demo",
    *,
    frames: int = 60,
    methods: tuple[str, ...] = ("lvm", "mht_h"),
    occlusion_levels: tuple[int, ...] = (0, 2),
    motion: str = "walk",
    seed: int = 0,
    progress: bool = True,
    stream=sys.stdout,
) -> dict:
    """Run the demo; returns the numbers it printed (also written to ``out_dir/results.json``)."""
    from .. import synth

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    pictures: list[np.ndarray] = []
    gif_frames: list[np.ndarray] = []
    for level in occlusion_levels:
        t0 = time.perf_counter()
        seq = synth.generate(
            seed, motion=motion, n_frames=frames, occlusion_level=level,
            progress=ProgressBar(f"generating occl {level}") if progress else None,
        )
        gen_s = time.perf_counter() - t0
        naive = None
        for method in methods:
            config = TrackerConfig.recommended(method)
            # The paper's comparison (LVM vs MHT_h) is per frame; the motion model that
            # `posetrack track` adds by default is measured by benchmarks/motion.py.
            tracker = Tracker(seq.intrinsics, config, seed=seed, mode="per-frame")
            bar = ProgressBar(f"{method:5s} occl {level}") if progress else None
            res = tracker.run(seq.depth, seq.keypoints2d, seq.confidence, progress=bar)
            acc = accuracy(res.keypoints3d, seq.joints3d)
            if naive is None:
                plain = lift_sequence(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics)
                naive = accuracy(naive_lifting(*plain), seq.joints3d)
            rows.append(
                {
                    "occlusion": level,
                    "method": method,
                    "N": config.n,
                    **acc.row(),
                    "naive_D_mean_mm": naive.mean_mm,
                    "ms_per_frame": res.ms_per_frame,
                    "compile_s": res.compile_s,
                    "generate_s": gen_s,
                    "lost_frames": int(np.sum(res.status == 1)),
                }
            )
            every = max(1, frames // 8)
            pictures += _pictures(seq, res, every=every, label=f"{method} occl {level}")[:8]
            if level == occlusion_levels[-1] and method == methods[-1]:
                gif_frames = _pictures(seq, res, every=1, label=f"{method} occl {level}")
    header = (
        f"{'occl':>4} {'method':>6} {'N':>3} {'D mean':>7} {'D std':>6} {'est.':>5} {'C50':>5} "
        f"{'C100':>5} "
        f"{'C150':>5} {'naive D':>8} {'ms/frame':>8} {'compile s':>9}"
    )
    lines = [
        f"posetrack demo: {frames} frames of '{motion}' per occlusion level, seed {seed}",
        f"machine: {machine_summary()}",
        "(D in mm over 13 body joints, computed on the estimated ones; est. = share of joints "
        "estimated; C_j(d) = share of joints within d mm)",
        header,
        "-" * len(header),
    ]
    for r in rows:
        lines.append(
            f"{r['occlusion']:>4} {r['method']:>6} {r['N']:>3} {r['D_mean_mm']:7.1f} "
            f"{r['D_std_mm']:6.1f} {r['coverage']:5.2f} {r['C_50mm']:5.2f} {r['C_100mm']:5.2f} "
            f"{r['C_150mm']:5.2f} "
            f"{r['naive_D_mean_mm']:8.1f} {r['ms_per_frame']:8.1f} {r['compile_s']:9.1f}"
        )
    sheet = contact_sheet(pictures, columns=8)
    write_png(out / "contact_sheet.png", sheet)
    write_gif(out / "tracking.gif", gif_frames, fps=10)
    from ..io import atomic_write_text

    result = {
        "machine": machine_summary(), "frames": frames, "motion": motion, "seed": seed,
        "rows": rows,
    }  # fmt: skip
    atomic_write_text(out / "results.json", json.dumps(result, indent=2))
    lines.append("")
    lines.append(f"pictures: {out.resolve() / 'contact_sheet.png'} (green = truth, red = estimate)")
    lines.append(f"          {out.resolve() / 'tracking.gif'}")
    lines.append(f"numbers:  {out.resolve() / 'results.json'}")
    print("\n".join(lines), file=stream)
    return result
