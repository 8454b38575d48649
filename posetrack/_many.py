"""Many recordings at once: the tracker steps of B sequences as ONE vmapped call per chunk
of frames (or per frame).

:func:`track_many` runs up to B sequences side by side. Each keeps its own host-side
:class:`~posetrack.Tracker` (body shape, initialisation, track loss, person following, the
offline motion model), exactly as :func:`~posetrack.track` runs it, in its own worker thread.
Only the compiled steps are shared (:mod:`posetrack._batcher`): offline and per-frame, a
:class:`~posetrack.ChunkBatcher` runs the chunks of C frames of every sequence in flight as one
``jax.vmap`` of the chunk's ``lax.scan`` (``chunk_many``; the tracker's ``chunk``, default
:data:`~posetrack.RUN_CHUNK`); online, or with ``chunk=1``, a :class:`~posetrack.StepBatcher`
runs one frame of each (``step_many``). Either way the N hypotheses of B sequences are fitted
and scored in one jitted call; the batch is padded to B, so the program compiles once per
(configuration, B, depth size, chunk) and never per sequence.

Lockstep: a batch runs when every sequence in flight has submitted its call. Sequences of
different depth sizes cannot share a program; each size has its own batcher (sort inputs by
size for full batches). Results equal tracking each sequence alone up to float rounding of
the batched program (``tests/test_many.py``).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ._batcher import Batcher, ChunkBatcher, StepBatcher
from ._camera import Intrinsics
from ._config import TrackerConfig
from ._programs import serial_execution
from ._result import TrackResult
from ._tracker import ProgressCallback, Tracker

SequenceInput = Any
"""One sequence for :func:`track_many`: a :class:`posetrack.io.Recording`, a tuple
``(intrinsics, depths, keypoints2d, confidence)``, or a function of no arguments returning
either (read when its turn comes, so a long list does not sit in memory)."""


def _unpack(item: SequenceInput) -> tuple[Intrinsics, Any, np.ndarray, np.ndarray]:
    if callable(item):
        item = item()
    if isinstance(item, tuple) and len(item) == 4:
        return item
    people = getattr(item, "people2d", None)
    if people is not None:  # a Recording: every person listed, frames without observation off
        conf = item.people_confidence
        conf = np.where(item.observed[:, None, None], conf, np.float32(0))
        return item.intrinsics, item.depth, people, conf
    raise TypeError(
        "track_many: a sequence must be a posetrack.io.Recording, a tuple (intrinsics, depths, "
        f"keypoints2d, confidence) or a function returning one, got {type(item).__name__}"
    )


def track_many(
    sequences: Iterable[SequenceInput],
    config: TrackerConfig | None = None,
    *,
    batch: int = 8,
    seed: int = 0,
    progress: ProgressCallback | None = None,
    total_frames: int | None = None,
    on_result: Callable[[int, TrackResult | BaseException], None] | None = None,
    errors: str = "raise",
    **tracker_options,
) -> list[TrackResult | BaseException]:
    """Track many sequences, ``batch`` at a time, their steps as one batched call per chunk of
    frames (or per frame: online, or ``chunk=1``).

    Every sequence is tracked as :func:`posetrack.track` would track it alone (same ``seed``,
    same host-side logic); only the compiled steps run batched (:class:`ChunkBatcher`, or
    :class:`StepBatcher` frame by frame), so results agree with single runs up to float
    rounding.

    Args:
        sequences: :data:`SequenceInput` items.
        config: the tracker configuration shared by all (default: the shipped one).
        batch: sequences in flight at once (B).
        seed: the hypotheses' random seed of every sequence.
        progress: ``progress(frames_done, total, postfix)`` after every frame of any
            sequence (``total``: ``total_frames``, else the frames of the sequences started;
            offline with ``SmoothSettings(both_ways=True)`` each frame counts twice, once per
            pass, and a shape pre-pass's frames count too: give ``total_frames`` as
            :meth:`Tracker.progress_frames <posetrack.Tracker.progress_frames>` counts).
        on_result: ``on_result(index, result_or_error)`` as each sequence finishes (in a
            worker thread), e.g. to write its files at once.
        errors: ``"raise"``: after every sequence has run, re-raise the first failure;
            ``"return"``: leave the exception in the returned list.
        tracker_options: keyword arguments of :class:`~posetrack.Tracker` (``mode``,
            ``person``, ``refine``, ...).

    Returns:
        One :class:`~posetrack.TrackResult` (or exception) per sequence, in input order.
    """
    if errors not in ("raise", "return"):
        raise ValueError(f"track_many: errors must be 'raise' or 'return', got {errors!r}")
    if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
        raise ValueError(f"track_many: batch must be an int >= 1, got {batch!r}")
    config = config or TrackerConfig()
    items = list(sequences)
    results: list[Any] = [None] * len(items)
    todo: queue.SimpleQueue = queue.SimpleQueue()
    for i in range(len(items)):
        todo.put(i)
    batchers: dict[tuple[int, int, bool], Batcher] = {}
    lock = threading.Lock()
    counts = {"done": 0, "total": 0, "finished": 0}

    def batcher_for(tracker: Tracker) -> Batcher:
        with lock:
            intr, chunked = tracker.intrinsics, tracker._chunked
            key = (intr.width, intr.height, chunked)
            if key not in batchers:
                # The tracker's configuration as its mode runs it (TrackerConfig.for_mode).
                batchers[key] = (ChunkBatcher if chunked else StepBatcher)(tracker.config, batch)
            return batchers[key]

    def report(done, total, postfix):
        if progress is None:
            return
        with lock:
            counts["done"] += 1
            total_now = total_frames or counts["total"]
            progress(counts["done"], total_now, f"{counts['finished']}/{len(items)} sequences")

    def track_one(i: int) -> TrackResult:
        intr, depths, kp, conf = _unpack(items[i])
        items[i] = None  # let a loaded recording go once tracked
        tracker = Tracker(intr, config, seed=seed, **tracker_options)
        with lock:  # progress counts every pass (offline: a shape pre-pass, both ways)
            counts["total"] += tracker.progress_frames(len(depths))
        batcher = batcher_for(tracker)
        slot = batcher.join()
        tracker._batched = (batcher, slot)
        try:
            return tracker.run(depths, kp, conf, progress=report)
        finally:
            batcher.leave(slot)

    def worker():
        while True:
            try:
                i = todo.get_nowait()
            except queue.Empty:
                return
            try:
                res: Any = track_one(i)
            except Exception as e:
                res = e
            results[i] = res
            with lock:
                counts["finished"] += 1
            if on_result is not None:
                try:
                    on_result(i, res)
                except Exception as e:  # e.g. the disk filled while writing its files
                    results[i] = e

    threads = [
        threading.Thread(target=worker, name=f"posetrack-many-{k}", daemon=True)
        for k in range(min(batch, max(len(items), 1)))
    ]
    try:
        with serial_execution():
            for t in threads:
                t.start()
            for t in threads:
                t.join()
    finally:
        for b in batchers.values():
            b.close()
    if errors == "raise":
        for r in results:
            if isinstance(r, BaseException):
                raise r
    return results
