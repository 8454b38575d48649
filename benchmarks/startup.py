"""Time to first pose: where a new process's start-up goes, cold and warm.

Each measurement is a fresh Python process that imports posetrack, turns the cache on
(``posetrack.enable_cache``, as the command line does), loads a short synthetic recording from
an ``.npz`` and tracks it with the shipped configuration (``posetrack.track``'s defaults: MHT_h,
N = 10, offline motion model; ``--mode online``: the causal model at its default lag, as a live
camera would run it). The clock starts when the process is launched. Python reads
posetrack's bytecode as from an installed package (compiled once, before the first process).

* **cold**: an empty cache folder (nothing compiled, nothing traced);
* **warm**: the same folder again, filled by the cold process before it.

Reported per depth resolution (320x240, 640x480, 1920x1080): seconds from launch to the import
done, to the first pose (the first frame's estimate: body shape from the first frames, the
initialisation fit and one tracker step) and to the whole result (30 frames); the tracing and
XLA-compilation (or cache-load) seconds of every compiled program (``posetrack._programs.log``;
programs build in background threads, so these overlap); the steady per-frame step. The cold
and the warm run must give the same poses bit for bit (``same_poses``).

The command line on the issue's case (150 frames at 320x240, ``posetrack track --no-video``) is
measured the same way, cold and warm, from launch to exit.

Online (``--mode online``), ``first_published_s`` is when the first pose is published: the
frame ``lag`` frames after the first one has been tracked (``Tracker.lagged``).

Usage: python benchmarks/startup.py [--quick] [--mode offline|online] [--chunk C]
[--in-batch] [--out benchmarks/results/startup.json]
(``--quick``: 320x240 only, no command line rows.)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESOLUTIONS = ((320, 240), (640, 480), (1920, 1080))
FRAMES = 30
SEED = 7  # any clip: the timings do not depend on the motion


def _child(npz: str, cache: str, launched: float, mode: str, chunk: str, in_batch: str) -> None:
    """One measured process (``--child``): prints one JSON line."""
    t_import0 = time.time()
    import numpy as np

    import posetrack as pt
    from posetrack import _programs

    t_import = time.time()
    pt.enable_cache(cache)
    data = np.load(npz)
    intr = pt.Intrinsics(
        fx=float(data["fx"]), fy=float(data["fy"]), cx=float(data["cx"]), cy=float(data["cy"]),
        width=int(data["width"]), height=int(data["height"]),
    )  # fmt: skip
    depth, kp, conf = data["depth"], data["keypoints2d"], data["confidence"]
    t_loaded = time.time()
    first: list[float] = []

    def progress(done, total, postfix):
        first.append(time.time())

    # --in-batch: the consensus refit inside the batch (TrackerConfig.consensus_in_batch).
    config = pt.TrackerConfig(consensus_in_batch=True) if in_batch == "1" else None
    tracker = pt.Tracker(intr, config, mode=mode, chunk=int(chunk) if chunk else pt.RUN_CHUNK)
    result = tracker.run(depth, kp, conf, progress=progress)
    t_done = time.time()
    np.save(npz.replace(".npz", f"-{os.getpid()}.npy"), result.keypoints3d)
    print(json.dumps({
        "interpreter_s": t_import0 - launched,
        "import_s": t_import - launched,
        "loaded_s": t_loaded - launched,
        "first_pose_s": first[0] - launched,
        "first_published_s": first[tracker.lag] - launched,  # lag 0 offline
        "result_s": t_done - launched,
        "ms_per_frame": result.ms_per_frame,
        "smooth_s": tracker.smooth_s,
        "poses": npz.replace(".npz", f"-{os.getpid()}.npy"),
        "programs": [
            {"name": e.name, "source": e.source, "trace_s": round(e.trace_s, 3),
             "compile_s": round(e.compile_s, 3), "ready_s": round(e.done - launched, 2)}
            for e in _programs.log()
        ],
    }))  # fmt: skip


def _child_env() -> dict:
    """The measured processes' environment: this checkout first on the path, and Python's
    bytecode read as an installed package's is (``pip install`` byte-compiles the package;
    :func:`_compile_bytecode` does it here). A shell with ``PYTHONDONTWRITEBYTECODE=1`` (this
    project's machines) would otherwise compile posetrack's sources at every import (0.3 s)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _compile_bytecode() -> None:
    """Byte-compile this checkout's package (``__pycache__``, git-ignored) as ``pip install``
    does, once before the measured processes."""
    import compileall

    compileall.compile_dir(str(ROOT / "posetrack"), quiet=1)


def _run_child(npz: Path, cache: Path, mode: str, chunk: int | None, in_batch: bool) -> dict:
    env = _child_env()
    launched = time.time()
    proc = subprocess.run(
        [sys.executable, __file__, "--child", str(npz), str(cache), repr(launched), mode,
         str(chunk or ""), "1" if in_batch else "0"],
        capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    if proc.returncode:
        raise RuntimeError(f"child failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _make_clip(folder: Path, width: int, height: int) -> Path:
    import numpy as np

    import posetrack as pt

    seq = pt.synth.generate(SEED, n_frames=FRAMES, width=width, height=height)
    path = folder / f"clip-{width}x{height}.npz"
    i = seq.intrinsics
    np.savez(
        path, depth=seq.depth, keypoints2d=seq.keypoints2d, confidence=seq.confidence,
        fx=float(i.fx), fy=float(i.fy), cx=float(i.cx), cy=float(i.cy), width=i.width,
        height=i.height,
    )  # fmt: skip
    return path


def _cli_rows(folder: Path) -> list[dict]:
    """``posetrack generate`` + ``posetrack track --no-video``, cold then warm."""
    env = dict(_child_env(), POSETRACK_CACHE_DIR=str(folder / "cli-cache"))
    clip = folder / "cli-clip"
    subprocess.run(
        [sys.executable, "-m", "posetrack", "generate", str(clip), "--frames", "150",
         "--width", "320", "--height", "240", "--seed", str(SEED), "--quiet"],
        check=True, env=env, capture_output=True,
    )  # fmt: skip
    rows = []
    for run in ("cold", "warm"):
        t0 = time.time()
        proc = subprocess.run(
            [sys.executable, "-m", "posetrack", "track", "--depth", str(clip / "depth"),
             "--keypoints", str(clip / "keypoints"), "--intrinsics",
             str(clip / "intrinsics.json"), "--no-video", "--quiet", "--out",
             str(folder / f"cli-out-{run}")],
            env=env, capture_output=True, text=True, check=False,
        )  # fmt: skip
        if proc.returncode:
            raise RuntimeError(f"posetrack track failed:\n{proc.stderr[-3000:]}")
        rows.append({"run": run, "wall_s": round(time.time() - t0, 2)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--mode", choices=("offline", "online"), default="offline")
    ap.add_argument(
        "--chunk",
        type=int,
        default=None,
        help="Tracker(chunk=...): frames per compiled call (default: RUN_CHUNK)",
    )
    ap.add_argument(
        "--in-batch",
        action="store_true",
        help="the consensus refit inside the batch (TrackerConfig(consensus_in_batch=True))",
    )
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "startup.json"))
    args = ap.parse_args()
    import numpy as np

    from posetrack.app import machine_info

    resolutions = RESOLUTIONS[:1] if args.quick else RESOLUTIONS
    _compile_bytecode()
    rows = []
    with tempfile.TemporaryDirectory(prefix="posetrack-startup-") as tmp:
        folder = Path(tmp)
        for width, height in resolutions:
            npz = _make_clip(folder, width, height)
            cache = folder / f"cache-{width}x{height}"
            runs = {
                run: _run_child(npz, cache, args.mode, args.chunk, args.in_batch)
                for run in ("cold", "warm")
            }
            a, b = (np.load(runs[r]["poses"]) for r in ("cold", "warm"))
            same = bool(np.array_equal(a, b, equal_nan=True))
            for run, r in runs.items():
                rows.append({
                    "resolution": f"{width}x{height}", "run": run,
                    **{k: round(v, 2) for k, v in r.items() if k.endswith("_s")},
                    "ms_per_frame": round(r["ms_per_frame"], 1),
                    "same_poses": same, "programs": r["programs"],
                })  # fmt: skip
        cli = [] if args.quick or args.mode != "offline" else _cli_rows(folder)

    print(
        f"\nTime to first pose, new process, shipped configuration ({args.mode}), {FRAMES} frames"
    )
    print(f"{'depth':>10} {'run':>5} {'import':>7} {'1st pose':>9} {'published':>10} {'result':>7} "
          f"{'ms/frame':>9} {'traced s':>9} {'XLA/load s':>11} {'same':>5}")  # fmt: skip
    for r in rows:
        traced = sum(p["trace_s"] for p in r["programs"])
        compiled = sum(p["compile_s"] for p in r["programs"])
        print(
            f"{r['resolution']:>10} {r['run']:>5} {r['import_s']:7.2f} {r['first_pose_s']:9.2f} "
            f"{r['first_published_s']:10.2f} "
            f"{r['result_s']:7.2f} {r['ms_per_frame']:9.1f} {traced:9.2f} {compiled:11.2f} "
            f"{str(r['same_poses']):>5}"
        )
    by = {(r["resolution"], r["run"]): r["first_pose_s"] for r in rows}
    if ("1920x1080", "cold") in by:
        for run in ("cold", "warm"):
            ratio = by[("1920x1080", run)] / by[("640x480", run)]
            print(f"1920x1080 / 640x480 first pose, {run}: {ratio:.2f}x")
    for r in cli:
        print(
            f"posetrack track, 150 frames 320x240, {r['run']}: {r['wall_s']:.1f} s launch to exit"
        )
    record = {
        "benchmark": "startup",
        "frames": FRAMES,
        "mode": args.mode,
        "chunk": args.chunk,
        "in_batch": args.in_batch,
        "machine": machine_info(),
        "rows": rows,
        "cli_150_frames_320x240": cli,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        _child(*sys.argv[2:4], float(sys.argv[4]), *sys.argv[5:8])
    else:
        main()
