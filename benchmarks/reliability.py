"""Reliability of ``posetrack track``: memory over a long run, run-to-run identity, SIGKILL.

Three measurements, each on real ``python -m posetrack track`` processes with the shipped
configuration (MHT_h, N = 10, offline motion model, body shape refined against the depth) and
an overlay video, on a synthetic recording (``posetrack.synth``, 160x120 by default):

* **long run** (``--frames``, default 10,000): the resident memory (``VmRSS`` of
  ``/proc/PID/status``) of the tracking process, sampled every ``--every`` seconds from this
  process and tagged with the frame the progress bar last showed. Reported: RSS at frame 500
  and at the last frame, the growth between them (the README's target: < 50 MB), its slope
  (MB per 1,000 frames, least squares over the frames after 500), the peak (``VmHWM``:
  smoothing, refinement and writing come after the last frame) and frames per second while
  tracking. A 10,000-frame recording would take long to generate, so the benchmark generates
  ``--base-frames`` (default 300) and plays them forwards and backwards (0..299, 298..1, 0..)
  up to ``--frames``: the files are hard links, the motion stays continuous (it reverses at
  each end), and the tracker sees every frame as new.
* **same inputs, same bytes**: the base recording tracked twice, in two processes; every
  output file compared byte for byte (``summary.json`` without its timings).
* **SIGKILL**: ``--kills`` runs over the previous run's output folder, each killed at a random
  moment: half at a uniformly random time of a whole run, half at a random time while the
  outputs are being written (after the hidden folder they are built in appears). After each
  kill the folder must hold the previous outputs bit for bit, or (a run that finished before
  the kill) a complete new set; anything else counts as partial. A run afterwards must succeed.

A fresh compilation cache in a temporary folder (filled by the first run, so the long run and
the kills start warm), unless ``--cache`` names one.

Usage: python benchmarks/reliability.py [--frames 10000] [--kills 10]
       [--out benchmarks/results/reliability.json]
(``--frames 1000 --kills 2`` for a quick look.)
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from posetrack.app._export import without_timings  # noqa: E402

TARGET_GROWTH_MB = 50.0  # the README's promise, after the first 500 frames
START_FRAME = 500
PROGRESS = re.compile(r"(tracking|overlay)\s+(\d+)/(\d+)")
BUILDING = re.compile(r"\.out\.[A-Za-z0-9_]{8}\.tmp")  # atomic_dir's hidden folder for out/


def _env(cache: Path) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT), POSETRACK_CACHE_DIR=str(cache))


def _track_args(rec: Path, out: Path) -> list[str]:
    return [
        sys.executable, "-m", "posetrack", "track", "--depth", str(rec / "depth"),
        "--keypoints", str(rec / "keypoints"), "--intrinsics", str(rec / "intrinsics.json"),
        "--rgb", str(rec / "rgb"), "--out", str(out),
    ]  # fmt: skip


def _files(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _status_kb(pid: int) -> tuple[int, int] | None:
    """(VmRSS, VmHWM) of ``pid`` in KiB, or None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    try:
        return int(fields["VmRSS"].split()[0]), int(fields["VmHWM"].split()[0])
    except (KeyError, ValueError):  # a zombie has no memory lines
        return None


# -- recordings -------------------------------------------------------------------------------


def make_base(folder: Path, frames: int, width: int, height: int, seed: int) -> Path:
    import posetrack as pt

    seq = pt.synth.generate(seed, motion="walk", n_frames=frames, width=width, height=height)
    return pt.synth.save(seq, folder)


def make_long(base: Path, folder: Path, frames: int) -> Path:
    """``frames`` frames of ``base`` played forwards and backwards, as hard links."""
    n = len(list((base / "depth").glob("*.png")))
    cycle = list(range(n)) + list(range(n - 2, 0, -1))
    for sub in ("depth", "rgb", "keypoints"):
        (folder / sub).mkdir(parents=True)
    shutil.copy(base / "intrinsics.json", folder / "intrinsics.json")
    link = os.link
    for t in range(frames):
        src, dst = f"{cycle[t % len(cycle)]:06d}", f"{t:06d}"
        for sub, suffix in (("depth", ".png"), ("rgb", ".png"), ("keypoints", "_keypoints.json")):
            try:
                link(base / sub / f"{src}{suffix}", folder / sub / f"{dst}{suffix}")
            except OSError:  # no hard links on this file system: copies
                link = shutil.copy
                link(base / sub / f"{src}{suffix}", folder / sub / f"{dst}{suffix}")
    return folder


# -- the long run -----------------------------------------------------------------------------


def long_run(rec: Path, out: Path, cache: Path, frames: int, every: float) -> dict:
    """One tracking process, its RSS sampled from here; see the module docstring."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        _track_args(rec, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(cache)
    )
    seen = {"phase": "loading", "frame": 0}
    tail: list[str] = []

    def read_progress() -> None:  # the progress bar redraws with \r: keep the latest count
        pending = ""
        while chunk := os.read(proc.stderr.fileno(), 65536):
            pending += chunk.decode(errors="replace")
            for match in PROGRESS.finditer(pending):
                seen.update(phase=match[1], frame=int(match[2]))
            tail.append(pending[-200:])
            pending = pending[-64:]  # a count split across two reads is found next time

    reader = threading.Thread(target=read_progress, daemon=True)
    reader.start()
    samples: list[dict] = []
    hwm = 0
    while proc.poll() is None:
        status = _status_kb(proc.pid)
        if status is not None:
            rss, hwm = status
            phase = seen["phase"]
            if phase == "tracking" and seen["frame"] >= frames:
                phase = "after tracking"  # smoothing, body-shape refinement, then writing
            if phase == "overlay":
                phase = "writing"
            samples.append({
                "t_s": round(time.perf_counter() - t0, 2), "phase": phase,
                "frame": {"loading": 0, "tracking": seen["frame"]}.get(phase, frames),
                "rss_mb": round(rss / 1024, 1),
            })  # fmt: skip
        time.sleep(every)
    stdout = proc.stdout.read().decode()
    reader.join(timeout=5)
    wall = time.perf_counter() - t0
    if proc.returncode:
        raise RuntimeError(f"posetrack track failed ({proc.returncode}):\n{''.join(tail)[-3000:]}")
    summary = json.loads((out / "summary.json").read_text())
    tracking = [s for s in samples if s["phase"] == "tracking"]
    start_frame = START_FRAME if frames >= 2 * START_FRAME else frames // 4
    after = [s for s in tracking if s["frame"] >= start_frame]
    if len(after) < 2:
        raise RuntimeError(f"too few samples after frame {start_frame}: use a smaller --every")
    first, last = after[0], after[-1]
    n = len(after)
    mean_f = sum(s["frame"] for s in after) / n
    mean_r = sum(s["rss_mb"] for s in after) / n
    var_f = sum((s["frame"] - mean_f) ** 2 for s in after)
    slope = sum((s["frame"] - mean_f) * (s["rss_mb"] - mean_r) for s in after) / var_f
    later = [s["rss_mb"] for s in samples if s["phase"] in ("after tracking", "writing")]
    begins: dict[str, float] = {}  # phase -> its first sample's time
    for s in samples:
        begins.setdefault(s["phase"], s["t_s"])
    ends = list(begins.values())[1:] + [wall]
    counts = summary["status_counts"]
    return {
        "frames": frames,
        "start_frame": start_frame,
        "rss_start": {"frame": first["frame"], "mb": first["rss_mb"]},
        "rss_end": {"frame": last["frame"], "mb": last["rss_mb"]},
        "growth_mb": round(last["rss_mb"] - first["rss_mb"], 1),
        "target_growth_mb": TARGET_GROWTH_MB,
        "slope_mb_per_1000_frames": round(slope * 1000, 2),
        "rss_min_max_after_start_mb": [min(s["rss_mb"] for s in after),
                                       max(s["rss_mb"] for s in after)],  # fmt: skip
        "rss_max_after_tracking_mb": max(later) if later else None,
        "peak_rss_mb": round(hwm / 1024, 1),
        "tracking_frames_per_s": round(
            (last["frame"] - first["frame"]) / max(last["t_s"] - first["t_s"], 1e-9), 1
        ),
        "ms_per_frame_steady": round(summary["timing"]["ms_per_frame_steady"], 2),
        "track_s": round(summary["timing"]["track_s"], 1),
        "write_s": round(summary["timing"]["write_s"], 1),
        "wall_s": round(wall, 1),
        "phase_s": {k: round(b - a, 1) for (k, a), b in zip(begins.items(), ends)},
        "tracked_share": round(counts["tracked"] / frames, 4),
        "status_counts": counts,
        "stdout_last_line": stdout.strip().splitlines()[-1] if stdout.strip() else "",
        "samples": samples,
    }


# -- same inputs, same bytes; SIGKILL ---------------------------------------------------------


def twice(rec: Path, root: Path, cache: Path) -> tuple[Path, dict]:
    """The base recording tracked in two processes; returns the first output and the result."""
    outs, walls = [root / "a" / "out", root / "b" / "out"], []
    for out in outs:
        t0 = time.perf_counter()
        proc = subprocess.run(_track_args(rec, out) + ["--quiet"], env=_env(cache),
                              capture_output=True, text=True)  # fmt: skip
        if proc.returncode:
            raise RuntimeError(f"posetrack track failed:\n{proc.stderr[-3000:]}")
        walls.append(round(time.perf_counter() - t0, 1))
    a, b = (_files(out) for out in outs)
    different = sorted(
        k for k in a.keys() | b.keys() if k != "summary.json" and a.get(k) != b.get(k)
    )
    import hashlib

    return outs[0], {
        "frames": len(list((rec / "depth").glob("*.png"))),
        "files_compared": len(a),
        "poses_npz_identical": a["poses.npz"] == b["poses.npz"],
        "poses_npz_sha256": [hashlib.sha256(x["poses.npz"]).hexdigest()[:16] for x in (a, b)],
        "files_different": different,
        "summary_identical_without_times": (
            without_timings(json.loads(a["summary.json"]))
            == without_timings(json.loads(b["summary.json"]))
        ),
        "wall_s": walls,  # the first run compiles (fresh cache)
        "write_s": json.loads(a["summary.json"])["timing"]["write_s"],
    }


def kills(
    rec: Path, previous: Path, root: Path, cache: Path, n: int, seed: int, whole: float
) -> dict:
    """``n`` runs over a copy of ``previous``, each killed at a random moment (``whole``:
    seconds of a whole run, launch to exit, warm cache)."""
    rng = random.Random(seed)
    work = root / "kills"
    work.mkdir()
    out = work / "out"
    shutil.copytree(previous, out)
    before = _files(out)
    summary = json.loads(before["summary.json"])
    write_s = summary["timing"]["write_s"]
    trials = []
    for i in range(n):
        proc = subprocess.Popen(_track_args(rec, out) + ["--quiet"], env=_env(cache),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        t0 = time.perf_counter()
        if i % 2 == 0:  # any moment of a run
            delay = rng.uniform(0.0, whole)
            while proc.poll() is None and time.perf_counter() - t0 < delay:
                time.sleep(0.001)
        else:  # while the outputs are written
            delay = rng.uniform(0.0, 0.5 * write_s)  # the folder lives for most of write_s
            while proc.poll() is None and not any(BUILDING.fullmatch(p) for p in os.listdir(work)):
                time.sleep(0.001)
            t1 = time.perf_counter()
            while proc.poll() is None and time.perf_counter() - t1 < delay:
                time.sleep(0.001)
        writing = any(BUILDING.fullmatch(p) for p in os.listdir(work))
        finished = proc.poll() is not None
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        after = _files(out) if out.exists() else {}
        if after == before:
            outcome = "previous"
        elif after.keys() == before.keys() and all(
            after[k] == before[k] for k in before if k != "summary.json"
        ):
            outcome = "new complete"
        elif not after:
            outcome = "nothing"
        else:
            outcome = "partial"
        left = [p.name for p in work.iterdir() if p.name != "out"]
        if writing:
            phase = "writing"
        elif outcome == "new complete":
            phase = "finished" if finished else "after writing"
        else:
            phase = "loading/tracking"
        trials.append({
            "kill_at_s": round(time.perf_counter() - t0, 2), "phase": phase,
            "outcome": outcome, "left_behind": left,
        })  # fmt: skip
        for name in left:  # a killed writer's hidden folder: safe to delete
            shutil.rmtree(work / name)
        if outcome != "previous":
            before = after if outcome == "new complete" else before
    proc = subprocess.run(_track_args(rec, out) + ["--quiet"], env=_env(cache),
                          capture_output=True, text=True)  # fmt: skip
    return {
        "trials": trials,
        "outcomes": {k: sum(t["outcome"] == k for t in trials)
                     for k in ("previous", "new complete", "nothing", "partial")},  # fmt: skip
        "killed_while_writing": sum(t["phase"] == "writing" for t in trials),
        "rerun_exit_code": proc.returncode,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=10_000, help="long run (default: 10000)")
    ap.add_argument("--base-frames", type=int, default=300, help="generated frames (300)")
    ap.add_argument("--size", default="160x120", help="WxH of the recording (160x120)")
    ap.add_argument("--kills", type=int, default=10, help="SIGKILL trials (default: 10)")
    ap.add_argument("--every", type=float, default=0.25, help="RSS sampling period, s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", help="compilation cache folder (default: a fresh one)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "reliability.json"))
    args = ap.parse_args()
    if not Path("/proc/self/status").is_file():
        sys.exit("reliability.py reads /proc/PID/status (Linux)")
    width, height = (int(v) for v in args.size.lower().split("x"))

    from posetrack.app import machine_info

    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="posetrack-reliability-") as tmp:
        root = Path(tmp)
        cache = Path(args.cache) if args.cache else root / "cache"
        t0 = time.perf_counter()
        base = make_base(root / "base", args.base_frames, width, height, args.seed)
        long = make_long(base, root / "long", args.frames)
        prepared_s = time.perf_counter() - t0
        print(f"recordings: {args.base_frames} frames generated, {args.frames} linked "
              f"({prepared_s:.0f} s)", flush=True)  # fmt: skip
        previous, same = twice(base, root, cache)
        print(f"same inputs, same bytes: {same['poses_npz_identical']}", flush=True)
        killed = kills(base, previous, root, cache, args.kills, args.seed, same["wall_s"][1])
        print(f"SIGKILL: {killed['outcomes']}", flush=True)
        long_result = long_run(long, root / "long-out" / "out", cache, args.frames, args.every)

    r = long_result
    print(f"\nposetrack track, {args.frames} frames {args.size} (the first {args.base_frames} "
          "played forwards and backwards), MHT_h N=10, offline, overlay video")  # fmt: skip
    print(f"| RSS at frame {r['rss_start']['frame']} | RSS at frame {r['rss_end']['frame']} | "
          "growth | slope | peak (incl. writing) | tracking | tracked |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    print(f"| {r['rss_start']['mb']:.0f} MB | {r['rss_end']['mb']:.0f} MB | "
          f"{r['growth_mb']:+.1f} MB (target < {TARGET_GROWTH_MB:.0f}) | "
          f"{r['slope_mb_per_1000_frames']:+.2f} MB / 1000 frames | {r['peak_rss_mb']:.0f} MB | "
          f"{r['tracking_frames_per_s']:.1f} frames/s ({r['ms_per_frame_steady']:.1f} ms step) | "
          f"{100 * r['tracked_share']:.1f} % |")  # fmt: skip
    print(f"wall {r['wall_s']:.0f} s; seconds per phase (from the samples): {r['phase_s']}")
    print(f"\nsame inputs twice ({same['frames']} frames, two processes): poses.npz identical "
          f"{same['poses_npz_identical']}; {same['files_compared']} files compared, different: "
          f"{same['files_different'] or 'none'} (summary.json without times identical: "
          f"{same['summary_identical_without_times']})")  # fmt: skip
    o = killed["outcomes"]
    print(f"SIGKILL, {args.kills} runs ({killed['killed_while_writing']} while writing): "
          f"previous outputs {o['previous']}, a complete new set {o['new complete']}, nothing "
          f"{o['nothing']}, partial {o['partial']}; the run after: exit "
          f"{killed['rerun_exit_code']}")  # fmt: skip
    total = time.perf_counter() - t_start
    print(f"benchmark: {total:.0f} s")
    record = {
        "benchmark": "reliability",
        "machine": machine_info(),
        "load_average_end": list(os.getloadavg()),
        "size": args.size,
        "base_frames": args.base_frames,
        "long_run": long_result,
        "same_inputs": same,
        "sigkill": killed,
        "benchmark_s": round(total, 1),
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
