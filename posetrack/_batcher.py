"""Batchers: the compiled calls of B trackers as ONE vmapped call.

:func:`~posetrack.track_many` gives each sequence its own :class:`~posetrack.Tracker` in its own
worker thread; a batcher collects one call from every sequence in flight, stacks their
arguments on a new leading axis (padded to B with copies of the first, whose results are
dropped), runs the vmapped program once and hands each sequence its slice. The program
compiles once per (configuration, B, depth size, chunk length), never per sequence.

- :class:`StepBatcher`: :func:`~posetrack.tracker_step` of one frame per sequence
  (``step_many``; frame-by-frame and online tracking).
- :class:`ChunkBatcher`: :func:`~posetrack._chunk.track_chunk` over C frames per sequence
  (``chunk_many``; offline and per-frame tracking, as :meth:`Tracker.run
  <posetrack.Tracker.run>` steps one sequence alone): one call and one transfer per C frames
  of B sequences.

Lockstep: a batch runs when every sequence in flight has submitted its call. :meth:`submit`
returns as soon as the batch holding the call has been formed, with a :class:`Pending` share
of its results; the batch runs in the batcher's own thread, so every sequence's host work
(recording the previous chunk, preparing the next) overlaps the batched computation.
"""

from __future__ import annotations

import concurrent.futures
import threading
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from ._chunk import track_chunk
from ._config import TrackerConfig
from ._programs import Program, program
from ._step import tracker_step


@program("step_many")
def step_many(config: TrackerConfig, shape, intrinsics, floor, state, depth, kp2d, conf):
    """:func:`~posetrack.tracker_step` vmapped over a leading sequence axis of every argument
    but the configuration."""
    return jax.vmap(lambda *a: tracker_step(config, *a))(
        shape, intrinsics, floor, state, depth, kp2d, conf
    )


@program("chunk_many")
def chunk_many(
    config: TrackerConfig, shape, intrinsics, floor, state, lost_run, limits, run, lost_only,
    depth, kp2d, conf,
):  # fmt: skip
    """:func:`~posetrack._chunk.track_chunk` vmapped over a leading sequence axis of every
    argument but the configuration."""
    return jax.vmap(lambda *a: track_chunk(config, *a))(
        shape, intrinsics, floor, state, lost_run, limits, run, lost_only, depth, kp2d, conf
    )


class Pending:
    """One sequence's share of a submitted batch: :meth:`get` waits for the batch to finish
    and returns its slice of the results (NumPy arrays), or raises the batch's failure.

    A :class:`Pending` may be passed back as an argument of a later :meth:`Batcher.submit`
    (e.g. the track state a chunk leaves); it is resolved when that batch is formed."""

    def __init__(self, future: concurrent.futures.Future, index: int, pick: Callable = None):
        self._future, self._index, self._pick = future, index, pick

    def get(self) -> Any:
        out = self._future.result()
        if self._pick is not None:  # structural: pick the part first, slice only that
            out = self._pick(out)
        return jax.tree.map(lambda x: x[self._index], out)

    def part(self, pick: Callable) -> Pending:
        """The share of ``pick(results)``, e.g. ``pending.part(lambda r: r[0])``."""
        return Pending(self._future, self._index, pick)


def resolve(tree: Any) -> Any:
    """``tree`` with every :class:`Pending` leaf replaced by its results (waits for them)."""
    return jax.tree.map(
        lambda x: x.get() if isinstance(x, Pending) else x, tree,
        is_leaf=lambda x: isinstance(x, Pending),
    )  # fmt: skip


def _stack(trees: Sequence, batch: int):
    """Stack the slots' argument trees on a new leading axis, padded to ``batch`` with copies
    of the first (their results are dropped)."""
    trees = list(trees) + [trees[0]] * (batch - len(trees))
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


class Batcher:
    """Runs one call of every sequence in flight as one batched call of ``fn`` (a vmapped
    program taking ``(config, *per-sequence arguments)``).

    A sequence :meth:`join`\\ s, :meth:`submit`\\ s its calls (from its own thread) and
    :meth:`leave`\\ s when it has none left. A batch is formed as soon as every joined
    sequence has a call waiting; it runs in the batcher's thread, one batch at a time.
    """

    def __init__(self, fn: Program | Callable, config: TrackerConfig, batch: int):
        if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
            raise ValueError(f"{type(self).__name__}: batch must be an int >= 1, got {batch!r}")
        self.fn, self.config, self.batch = fn, config, int(batch)
        self._cv = threading.Condition()
        self._active: set[int] = set()
        self._pending: dict[int, tuple] = {}
        self._formed: dict[int, Pending] = {}
        self._next = 0
        self._prepared = False
        self._runner = concurrent.futures.ThreadPoolExecutor(
            max_workers=1, thread_name_prefix=f"posetrack-{type(self).__name__}"
        )  # fmt: skip

    def join(self) -> int:
        """A new sequence in flight; returns its slot."""
        with self._cv:
            if len(self._active) >= self.batch:
                raise RuntimeError(
                    f"{type(self).__name__}: more than {self.batch} sequences in flight"
                )  # fmt: skip
            slot, self._next = self._next, self._next + 1
            self._active.add(slot)
            return slot

    def leave(self, slot: int) -> None:
        """The sequence in ``slot`` submits no more calls (idempotent)."""
        with self._cv:
            self._active.discard(slot)
            self._maybe_form()

    def close(self) -> None:
        """Let the batcher's thread end once the batches submitted have run."""
        self._runner.shutdown(wait=False)

    def prepare(self, args: tuple) -> None:
        """Start compiling the batched program in the background, from one sequence's
        (abstract) arguments ``(config, *per-sequence arguments)``."""
        with self._cv:
            if self._prepared:
                return
            self._prepared = True
        config, *rest = args
        batched = jax.tree.map(
            lambda x: jax.ShapeDtypeStruct((self.batch, *np.shape(x)), x.dtype), tuple(rest)
        )
        self.fn.prepare(config, *batched, background=True)

    def submit(self, slot: int, config: TrackerConfig, *args) -> Pending:
        """Queue this sequence's call; returns once its batch is formed (every sequence in
        flight has submitted), not when it has run."""
        if config is not self.config and config != self.config:
            raise ValueError(
                f"{type(self).__name__}: every sequence must use the batcher's configuration"
            )  # fmt: skip
        with self._cv:
            if slot not in self._active:
                raise RuntimeError(f"{type(self).__name__}: slot {slot} has not joined")
            if slot in self._pending:
                raise RuntimeError(f"{type(self).__name__}: slot {slot} has a call waiting")
            self._pending[slot] = args
            self._maybe_form()
            self._cv.wait_for(lambda: slot in self._formed)
            return self._formed.pop(slot)

    def _maybe_form(self) -> None:
        """Form the batch if every sequence in flight has a call waiting, and hand it to the
        batcher's thread (the caller holds the lock)."""
        if not self._pending or len(self._pending) < len(self._active):
            return
        slots = sorted(self._pending)
        args = [self._pending.pop(s) for s in slots]
        future = self._runner.submit(self._run, args)
        for i, s in enumerate(slots):
            self._formed[s] = Pending(future, i)
        self._cv.notify_all()

    def _run(self, args: list[tuple]):
        # The arguments may hold the results of the batch before this one (run before: the
        # batcher's thread runs batches in order).
        args = resolve(args)
        return jax.device_get(self.fn(self.config, *_stack(args, self.batch)))


class StepBatcher(Batcher):
    """The tracker steps of the sequences in flight (one frame each) as one batched call."""

    def __init__(self, config: TrackerConfig, batch: int):
        super().__init__(step_many, config, batch)

    def step(self, slot: int, config, shape, intrinsics, floor, state, depth, kp2d, conf):
        """This sequence's step (same arguments and results as the tracker's ``step``; the
        results are NumPy arrays). Blocks until the batch has run."""
        return self.submit(
            slot, config, shape, intrinsics, floor, state, depth, kp2d, conf
        ).get()  # fmt: skip


class ChunkBatcher(Batcher):
    """:func:`~posetrack._chunk.track_chunk` of the sequences in flight (C frames each) as one
    batched call (:meth:`submit` takes its arguments after the configuration)."""

    def __init__(self, config: TrackerConfig, batch: int):
        super().__init__(chunk_many, config, batch)
