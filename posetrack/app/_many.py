"""``posetrack track-many``: every recording of a manifest, B at a time, resumable.

Each recording's outputs go to ``DIR/<name>/``, written atomically when it is done (the files
of ``posetrack track``). ``DIR/summary.json`` lists every recording: done (with its status
counts), failed (with the error) or not yet run; it is rewritten, under a file lock, as each
recording finishes, so several processes may share ``DIR``. A re-run over the same ``DIR``
skips the recordings already done and redoes the rest; a killed run loses only what was in
flight (never a half-written folder).

With ``--num-processes P --process-id I --coordinator HOST:PORT`` the processes join JAX's
multi-controller runtime (``jax.distributed.initialize``); process I tracks rows I, I + P,
I + 2P, ... of the manifest.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import sys
import time
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: one process per DIR
    fcntl = None

SUMMARY = "summary.json"
#: The hidden folders ``posetrack.io.atomic_dir`` builds ``DIR/<name>`` in.
_BUILDING = re.compile(r"\.(.+)\.(?:[A-Za-z0-9_]{8}|[0-9a-f]{12}\.old)\.tmp")


def _settings(args, config, mode: str, both_ways: bool = False) -> dict[str, Any]:
    """What a finished recording must have been tracked with to be skipped on a re-run
    (``both_ways`` only where on: one-way results of older versions still match; its value
    names the fusion, so results of the first one, recorded as ``true``, are tracked again)."""
    out = {"method": config.method, "hypotheses": config.n, "mode": mode, "seed": args.seed}
    if args.shape_prepass:  # only where on, as both_ways: older results still match
        out["shape_prepass"] = args.shape_prepass
        if args.shape_prepass_below is not None:
            out["shape_prepass_below"] = args.shape_prepass_below
    return {**out, "both_ways": "smoothed tracks fused"} if both_ways else out


def _done(folder: Path) -> dict | None:
    """The ``summary.json`` of a finished recording's folder, or None."""
    try:
        return json.loads((folder / SUMMARY).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


@contextlib.contextmanager
def _locked(out: Path):
    """Exclusive access to ``DIR/summary.json`` among the processes sharing ``DIR``."""
    with open(out / ".summary.lock", "a") as fh:
        if fcntl is not None:
            fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(fh, fcntl.LOCK_UN)


def _record(out: Path, manifest: Path, names: list[str], updates: dict[str, dict]) -> dict:
    """Merge ``updates`` (name -> entry) into ``DIR/summary.json`` and rewrite it atomically."""
    from ..io import atomic_write_text

    with _locked(out):
        # Every writer of summary.json holds the lock, so a temporary file of it found now was
        # left by a writer that died mid-write (SIGKILL): safe to delete.
        for stale in out.glob(f".{SUMMARY}.*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()
        try:
            data = json.loads((out / SUMMARY).read_text(encoding="utf-8"))
            known = data.get("recordings", {})
        except (OSError, ValueError):
            known = {}
        rec = {name: known.get(name, {"status": "pending"}) for name in names}
        rec.update(updates)
        counts = {s: sum(r["status"] == s for r in rec.values()) for s in ("done", "failed")}
        counts["pending"] = len(rec) - counts["done"] - counts["failed"]
        data = {"manifest": os.path.abspath(manifest), "counts": counts, "recordings": rec}
        atomic_write_text(out / SUMMARY, json.dumps(data, indent=1) + "\n")
    return data


def _join_processes(args) -> tuple[int, int]:
    """``(process_count, process_index)``, after ``jax.distributed.initialize`` when asked."""
    given = [args.num_processes, args.process_id, args.coordinator]
    if all(v is None for v in given):
        return 1, 0
    if any(v is None for v in given):
        raise ValueError(
            "--num-processes, --process-id and --coordinator go together (all three or none)"
        )
    if args.num_processes < 1 or not 0 <= args.process_id < args.num_processes:
        raise ValueError(
            f"--process-id must be in 0..{args.num_processes - 1} and --num-processes >= 1, "
            f"got {args.process_id} of {args.num_processes}"
        )
    import jax

    try:
        jax.distributed.initialize(
            coordinator_address=args.coordinator, num_processes=args.num_processes,
            process_id=args.process_id,
        )  # fmt: skip
    except RuntimeError as e:  # coordinator unreachable, a process missing: not a traceback
        raise OSError(f"--coordinator {args.coordinator}: {e}") from None
    return jax.process_count(), jax.process_index()


def track_many_command(args) -> int:
    from .. import io
    from .._many import track_many
    from .._tracker import prepass_frames, run_passes
    from ._cli import (
        _followed_detections,
        _lag,
        _mode,
        _motion,
        _person_summary,
        _refine,
        _tracker_config,
    )
    from ._export import check_output_dir, save_results, status_counts
    from ._progress import ProgressBar

    t_start = time.perf_counter()
    # First: JAX's runtime must be joined before anything starts its backend.
    count, index = _join_processes(args)
    config = _tracker_config(args)
    mode = _mode(args)
    motion = _motion(args)
    refine = _refine(args)  # flags that do not go together: before any file is read
    if args.batch < 1:
        raise ValueError(f"--batch must be >= 1, got {args.batch}")
    manifest = Path(args.manifest)
    rows = io.read_manifest(manifest)  # every row checked before any tracking
    out = Path(args.out)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise FileExistsError(f"{out}: exists and is not a folder")
    settings = _settings(args, config, mode, run_passes(mode, motion, 2) == 2)  # both ways?
    todo, skipped = [], []
    for row in rows:
        folder = out / row.name
        check_output_dir(folder)
        done = _done(folder)
        if done is None:
            todo.append(row)
            continue
        was = done.get("track_many", {}).get("settings")
        if was != settings:
            raise ValueError(
                f"{manifest}: row {row.line} ({row.name}): {folder} was tracked with "
                f"{was or 'other settings'}, this run uses {settings}; delete the folder or "
                "choose another --out"
            )
        skipped.append(row)
    position = {r.name: i for i, r in enumerate(rows)}  # names are unique
    todo = [r for r in todo if position[r.name] % count == index]
    out.mkdir(parents=True, exist_ok=True)
    # What a killed run left half-built (atomic_dir's hidden folders; each row has one owner
    # process, so no other process is building these).
    mine = {r.name for r in todo}
    for entry in out.iterdir():
        stale = _BUILDING.fullmatch(entry.name)
        if stale and stale.group(1) in mine:
            shutil.rmtree(entry, ignore_errors=True)
    names = [r.name for r in rows]
    _record(out, manifest, names, {r.name: {"status": "done"} for r in skipped})
    share = f" (process {index} of {count})" if count > 1 else ""
    print(
        f"{len(rows)} recordings in {manifest}: {len(skipped)} already done in {out}, "
        f"{len(todo)} to track{share}, {args.batch} at a time",
        file=sys.stderr,
    )
    loaded: dict[int, Any] = {}

    def loader(k: int):
        def load():
            row = todo[k]
            rec = io.load_recording(
                depth_dir=row.depth, keypoints_dir=row.keypoints,
                intrinsics_path=row.intrinsics_path, rgb=row.rgb, depth_scale=row.depth_scale,
            )  # fmt: skip
            loaded[k] = rec
            return rec

        return load

    failed: list[str] = []

    def finished(k: int, result) -> None:
        row = todo[k]
        rec = loaded.pop(k, None)
        if isinstance(result, BaseException):
            failed.append(row.name)
            msg = f"{type(result).__name__}: {result}" if not isinstance(result, ValueError) \
                else str(result)  # fmt: skip
            print(f"\nerror: {row.name} (row {row.line}): {msg}", file=sys.stderr)
            _record(out, manifest, names, {row.name: {"status": "failed", "error": msg}})
            return
        info = {
            "inputs": {
                "depth": str(row.depth), "keypoints": str(row.keypoints),
                "rgb": None if row.rgb is None else str(row.rgb),
                "intrinsics": str(row.intrinsics_path), "depth_scale": row.depth_scale,
                "seed": args.seed, "mode": mode,
            },
            "notes": list(rec.notes),
            "person": _person_summary(result, rec.frame_ids, "auto"),
            "track_many": {
                "manifest": os.path.abspath(manifest), "row": row.line, "settings": settings,
            },
        }  # fmt: skip
        save_results(
            out / row.name, result, intrinsics=rec.intrinsics, frame_ids=rec.frame_ids,
            fps=rec.fps, rgb=rec.rgb, depth=rec.depth, video=not args.no_video,
            video_panel=None if args.video_panel == "none" else args.video_panel,
            detections=_followed_detections(result, rec.people2d, rec.people_confidence),
            info=info, progress=False,
        )  # fmt: skip
        counts = status_counts(result.status)
        _record(out, manifest, names, {row.name: {"status": "done", **counts}})

    bar = None if args.quiet else ProgressBar("tracking")
    # Rows of one depth size share a batch: group them (stable within a size).
    order = sorted(range(len(todo)), key=lambda k: (todo[k].intrinsics.shape, k))
    track_many(
        [loader(k) for k in order], config, batch=args.batch, seed=args.seed, mode=mode,
        progress=bar, errors="return",
        total_frames=sum(  # the shape pre-pass's frames, then each pass's
            prepass_frames(mode, refine, r.frames) + r.frames * run_passes(mode, motion, r.frames)
            for r in todo
        ),
        on_result=lambda i, res: finished(order[i], res),
        refine=refine, lag=_lag(args), motion=motion,
    )  # fmt: skip
    summary = _record(out, manifest, names, {})
    c = summary["counts"]
    print(
        f"\n{len(todo) - len(failed)} tracked, {len(failed)} failed, {len(skipped)} skipped "
        f"(done before) in {time.perf_counter() - t_start:.1f} s; {out}/{SUMMARY}: "
        f"{c['done']} done, {c['failed']} failed, {c['pending']} pending"
    )
    return 2 if failed else 0
