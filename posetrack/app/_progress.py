"""A dependency-free progress bar for long loops (stderr, redrawn in place)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


class Progress:
    """``for x in Progress(items, "tracking"): ...`` prints ``tracking  42/100 [####  ] 12.3 fps``.

    Disabled (a plain pass-through) when ``enabled`` is False; draws at most ~10 times a second
    so it never costs measurable time. Works in terminals and notebooks (carriage return).
    """

    def __init__(
        self,
        items: Iterable[T],
        label: str,
        *,
        total: int | None = None,
        enabled: bool = True,
        unit: str = "frames",
        stream=None,
    ):
        self.items = items
        self.label = label
        self.total = (
            total if total is not None else (len(items) if hasattr(items, "__len__") else None)
        )
        self.enabled = enabled
        self.unit = unit
        self.stream = stream or sys.stderr
        self.postfix = ""

    def __iter__(self) -> Iterator[T]:
        if not self.enabled:
            yield from self.items
            return
        start = last = time.perf_counter()
        n = 0
        self._draw(0, 0.0)
        for item in self.items:
            yield item
            n += 1
            now = time.perf_counter()
            if now - last > 0.1 and n != self.total:
                self._draw(n, now - start)
                last = now
        self._draw(n, time.perf_counter() - start)
        self.stream.write("\n")
        self.stream.flush()

    def _draw(self, n: int, elapsed: float) -> None:
        line = _line(self.label, n, self.total, elapsed, self.unit, self.postfix)
        self.stream.write(line)
        self.stream.flush()


def _line(label: str, n: int, total: int | None, elapsed: float, unit: str, postfix: str) -> str:
    """One redraw: ``\rtracking  42/100 [####  ] 12.3 frames/s postfix``."""
    rate = n / elapsed if elapsed > 0 else 0.0
    if total:
        width = 24
        filled = int(width * n / max(total, 1))
        bar = f"{n:>5}/{total} [{'#' * filled}{' ' * (width - filled)}]"
    else:
        bar = f"{n:>5}"
    extra = f" {postfix}" if postfix else ""
    return f"\r{label} {bar} {rate:6.1f} {unit}/s{extra}   "


class ProgressBar:
    """A progress callback ``bar(done, total, postfix)`` that draws like :class:`Progress`.

    Pass it where the core takes a callback
    (``Tracker.run(..., progress=ProgressBar("tracking"))``):
    the core never draws, the application layer does. The line ends when ``done == total``.
    """

    def __init__(self, label: str, *, unit: str = "frames", stream=None):
        self.label = label
        self.unit = unit
        self.stream = stream or sys.stderr
        self._start: float | None = None
        self._last = 0.0

    def __call__(self, done: int, total: int, postfix: str = "") -> None:
        now = time.perf_counter()
        if self._start is None:
            self._start = now
        if done < total and now - self._last < 0.1:
            return
        self._last = now
        self.stream.write(_line(self.label, done, total, now - self._start, self.unit, postfix))
        self.stream.flush()
        if done >= total:
            self.stream.write("\n")
            self.stream.flush()
