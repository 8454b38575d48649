"""Many recordings at once: the tracker step of B sequences as ONE vmapped call per frame.

:func:`track_many` runs up to B sequences side by side. Each keeps its own host-side
:class:`~posetrack.Tracker` (body shape, initialisation, track loss, person following, the
offline motion model), exactly as :func:`~posetrack.track` runs it, in its own worker thread.
Only the per-frame step is shared: a :class:`StepBatcher` collects the step of every sequence
in flight, stacks them and runs ``jax.vmap(tracker_step)`` once (``step_many``), so the N
hypotheses of B sequences are fitted and scored in one jitted call. The batch is padded to B,
so the program compiles once per (configuration, B, depth size) and never per sequence.

Lockstep: a batch runs when every sequence in flight has asked for its step. Sequences of
different depth sizes cannot share a program; each size has its own batcher (sort inputs by
size for full batches). Results equal tracking each sequence alone up to float rounding of
the batched program (``tests/test_many.py``).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import jax
import numpy as np

from ._camera import Intrinsics
from ._config import TrackerConfig
from ._programs import program, serial_execution
from ._step import tracker_step
from ._tracker import ProgressCallback, Tracker, TrackResult


@program("step_many")
def step_many(config: TrackerConfig, shape, intrinsics, floor, state, depth, kp2d, conf):
    """:func:`~posetrack.tracker_step` vmapped over a leading sequence axis of every argument
    but the configuration."""
    return jax.vmap(lambda *a: tracker_step(config, *a))(
        shape, intrinsics, floor, state, depth, kp2d, conf
    )


def _stack(trees: Sequence, batch: int):
    """Stack the slots' argument trees on a new leading axis, padded to ``batch`` with copies
    of the first (their results are dropped)."""
    trees = list(trees) + [trees[0]] * (batch - len(trees))
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


class StepBatcher:
    """Runs the tracker steps of the sequences in flight as one batched call.

    A sequence :meth:`join`\\ s, calls :meth:`step` once per frame (from its own thread; the
    call blocks until the batch has run) and :meth:`leave`\\ s when it has no frames left.
    The batch runs as soon as every joined sequence is waiting in :meth:`step`.
    """

    def __init__(self, config: TrackerConfig, batch: int):
        if batch < 1:
            raise ValueError(f"StepBatcher: batch must be >= 1, got {batch}")
        self.config, self.batch = config, int(batch)
        self._cv = threading.Condition()
        self._active: set[int] = set()
        self._pending: dict[int, tuple] = {}
        self._results: dict[int, Any] = {}
        self._next = 0
        self._prepared = False

    def join(self) -> int:
        """A new sequence in flight; returns its slot."""
        with self._cv:
            if len(self._active) >= self.batch:
                raise RuntimeError(f"StepBatcher: more than {self.batch} sequences in flight")
            slot, self._next = self._next, self._next + 1
            self._active.add(slot)
            return slot

    def leave(self, slot: int) -> None:
        """The sequence in ``slot`` asks for no more steps (idempotent)."""
        with self._cv:
            self._active.discard(slot)
            self._maybe_run()

    def prepare(self, step_args: tuple) -> None:
        """Start compiling the batched step in the background, from one sequence's
        (abstract) step arguments: ``(config, shape, intrinsics, floor, state, depth, kp,
        conf)``."""
        with self._cv:
            if self._prepared:
                return
            self._prepared = True
        config, *rest = step_args
        batched = jax.tree.map(
            lambda x: jax.ShapeDtypeStruct((self.batch, *np.shape(x)), x.dtype), tuple(rest)
        )
        step_many.prepare(config, *batched, background=True)

    def step(self, slot: int, config, shape, intrinsics, floor, state, depth, kp2d, conf):
        """This sequence's step (same arguments and results as the tracker's ``step``; the
        results are NumPy arrays)."""
        if config is not self.config and config != self.config:
            raise ValueError("StepBatcher: every sequence must use the batcher's configuration")
        with self._cv:
            if slot not in self._active:
                raise RuntimeError(f"StepBatcher: slot {slot} has not joined")
            self._pending[slot] = (shape, intrinsics, floor, state, depth, kp2d, conf)
            self._maybe_run()
            self._cv.wait_for(lambda: slot in self._results)
            out = self._results.pop(slot)
        if isinstance(out, BaseException):
            raise out
        return out

    def _maybe_run(self) -> None:
        """Run the batch if every sequence in flight is waiting (caller holds the lock)."""
        if not self._pending or len(self._pending) < len(self._active):
            return
        slots = sorted(self._pending)
        args = [self._pending.pop(s) for s in slots]
        try:
            out = jax.device_get(step_many(self.config, *_stack(args, self.batch)))
            for i, s in enumerate(slots):
                self._results[s] = jax.tree.map(lambda x, i=i: x[i], out)
        except Exception as e:  # every waiting sequence sees the failure
            for s in slots:
                self._results[s] = e
        self._cv.notify_all()


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
    """Track many sequences, ``batch`` at a time, each frame's steps as one batched call.

    Every sequence is tracked as :func:`posetrack.track` would track it alone (same ``seed``,
    same host-side logic); only the tracker step runs batched (:class:`StepBatcher`), so
    results agree with single runs up to float rounding.

    Args:
        sequences: :data:`SequenceInput` items.
        config: the tracker configuration shared by all (default: the shipped one).
        batch: sequences in flight at once (B).
        seed: the hypotheses' random seed of every sequence.
        progress: ``progress(frames_done, total, postfix)`` after every frame of any
            sequence (``total``: ``total_frames``, else the frames of the sequences started).
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
    batchers: dict[tuple[int, int], StepBatcher] = {}
    lock = threading.Lock()
    counts = {"done": 0, "total": 0, "finished": 0}

    def batcher_for(intr: Intrinsics) -> StepBatcher:
        with lock:
            key = (intr.width, intr.height)
            if key not in batchers:
                batchers[key] = StepBatcher(config, batch)
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
        with lock:
            counts["total"] += len(depths)
        tracker = Tracker(intr, config, seed=seed, **tracker_options)
        batcher = batcher_for(tracker.intrinsics)
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
    with serial_execution():
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    if errors == "raise":
        for r in results:
            if isinstance(r, BaseException):
                raise r
    return results
