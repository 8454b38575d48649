"""Progress bars for long loops: tqdm in terminals and notebooks, plain lines in log files.

Where the bar goes decides how it is drawn:

* a terminal (the stream's ``isatty()``): tqdm's bar, redrawn in place on stderr;
* a Jupyter kernel (writing to the kernel's own stderr/stdout): ``tqdm.auto``, a widget when
  ipywidgets is installed, else the same text bar (Jupyter renders carriage returns);
* anything else (``2> log.txt``, a pipe, CI logs, an ``io.StringIO``): whole lines and no
  carriage return, because a file keeps every redraw (up to ten a second, all on one
  ``\\r``-joined line that log viewers show as garbage). One line at the start, one each
  time another tenth of the work is done or :data:`LOG_EVERY_S` seconds have passed, one at
  the end, e.g. ``tracking:  40% 4/10 [00:01<00:01,  3.10frames/s, delta 0.21]``.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from collections.abc import Iterable, Iterator
from typing import IO, TypeVar

from tqdm import tqdm as _tqdm

T = TypeVar("T")

LOG_EVERY_S = 30.0
"""In a log file, the longest gap between two progress lines, s (a sign of life on long runs)."""


def _is_notebook_stream(stream) -> bool:
    """Whether ``stream`` is a Jupyter kernel's stdout/stderr (``ipykernel.iostream.OutStream``),
    which shows carriage-return redraws correctly and can show a widget instead."""
    return type(stream).__module__.startswith("ipykernel.")


class _LineWriter:
    """Progress as whole lines (no carriage return) for streams that are not terminals.

    The same surface as the few tqdm methods used here (``update``, ``total``,
    ``set_postfix_str``, ``close``), with tqdm's own text formatting.
    """

    def __init__(self, label: str, total: int | None, unit: str, stream: IO[str]):
        self.label, self.total, self.unit, self.stream = label, total, unit, stream
        self.n = 0
        self.postfix = ""
        self._start = self._last = time.perf_counter()
        self._next_tenth = 1  # the next multiple of total/10 that earns a line
        self._closed = False
        self._write()

    def _write(self) -> None:
        elapsed = time.perf_counter() - self._start
        line = _tqdm.format_meter(
            self.n, self.total, elapsed, ncols=0, prefix=self.label, unit=self.unit,
            postfix=self.postfix or None,
        )  # fmt: skip
        self.stream.write(line + "\n")
        self.stream.flush()
        self._last = time.perf_counter()
        self._written = (self.n, self.postfix)

    def update(self, k: int = 1) -> None:
        self.n += k
        if self.total:
            if self.n * 10 < self._next_tenth * self.total:
                if time.perf_counter() - self._last < LOG_EVERY_S:
                    return
            elif self.n >= self.total:
                return  # close() writes the final line
            self._next_tenth = self.n * 10 // self.total + 1
        elif time.perf_counter() - self._last < LOG_EVERY_S:
            return
        self._write()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = s

    def refresh(self) -> None:
        pass  # lines are written on progress only

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._written != (self.n, self.postfix):  # else the last line says it all
                self._write()


def _columns(stream) -> int:
    """The terminal width behind ``stream`` (0 when it reports none), or 80 if unknown."""
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, ValueError, OSError):
        return 80


def _open(label: str, total: int | None, unit: str, stream: IO[str] | None):
    """A started bar: tqdm on a terminal or in a notebook, a :class:`_LineWriter` otherwise."""
    stream = sys.stderr if stream is None else stream
    options = dict(total=total, desc=label, unit=unit, file=stream, dynamic_ncols=True)
    if _is_notebook_stream(stream):
        # tqdm.auto warns once when ipywidgets is missing and then draws the text bar, which is
        # what we want anyway: keep the notebook free of that warning.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from tqdm.auto import tqdm as auto_tqdm
        return auto_tqdm(**options)
    isatty = getattr(stream, "isatty", None)
    try:
        terminal = bool(isatty and isatty())
    except (ValueError, OSError):  # a closed or detached stream
        terminal = False
    if terminal:
        if _columns(stream) <= 0:  # a pseudo-terminal with no size: tqdm would draw nothing
            options.update(ncols=80, nrows=24, dynamic_ncols=False)
        return _tqdm(**options)
    return _LineWriter(label, total, unit, stream)


class Progress:
    """``for x in Progress(items, "tracking"): ...`` shows how far the loop has got.

    A tqdm bar on a terminal or in Jupyter; whole lines, no carriage return, when stderr is
    a file or a pipe (see the module docstring). A plain pass-through when ``enabled`` is False.

    Args:
        items: what to iterate over.
        label: the bar's name (``"detecting"``).
        total: the number of items; None takes ``len(items)`` when there is one.
        enabled: False: draw nothing.
        unit: what an item is, for the rate (``frames/s``).
        stream: where to draw; None: ``sys.stderr`` at iteration time.
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
        self.stream = stream
        self.postfix = ""

    def __iter__(self) -> Iterator[T]:
        if not self.enabled:
            yield from self.items
            return
        bar = _open(self.label, self.total, self.unit, self.stream)
        try:
            for item in self.items:
                yield item
                if self.postfix:
                    bar.set_postfix_str(self.postfix, refresh=False)
                bar.update(1)
        finally:
            bar.close()  # also on break and errors: the line ends, the cursor starts a new one


class ProgressBar:
    """A progress callback ``bar(done, total, postfix)`` that draws like :class:`Progress`.

    Pass it where the core takes a callback
    (``Tracker.run(..., progress=ProgressBar("tracking"))``):
    the core never draws, the application layer does. The bar starts at the first call and
    ends (its line finished) when ``done == total``; a later call starts a new one.

    Args:
        label: the bar's name.
        unit: what is counted, for the rate.
        stream: where to draw; None: ``sys.stderr`` at the first call.
    """

    def __init__(self, label: str, *, unit: str = "frames", stream=None):
        self.label = label
        self.unit = unit
        self.stream = stream
        self._bar = None

    def __call__(self, done: int, total: int, postfix: str = "") -> None:
        if self._bar is None:
            self._bar = _open(self.label, total, self.unit, self.stream)
        bar = self._bar
        if bar.total != total:  # track-many learns the total as recordings start
            bar.total = total
        if postfix:
            bar.set_postfix_str(postfix, refresh=False)
        if done > bar.n:
            bar.update(done - bar.n)
        if done >= total:
            bar.close()
            self._bar = None


def note_when_done(progress, note: str, stream=None):
    """A progress callback that calls ``progress(done, total, postfix)`` and then, the first
    time ``done`` reaches ``total``, writes ``note`` on a line of its own (``stream``; None:
    ``sys.stderr`` then): what a command says about work that runs after the last counted
    unit, e.g. the offline mode's body-shape refinement and motion model, a few seconds on
    2 CPU cores after the tracking bar has filled."""
    said = False

    def call(done: int, total: int, postfix: str = "") -> None:
        nonlocal said
        progress(done, total, postfix)
        if done >= total and not said:
            said = True
            print(note, file=stream or sys.stderr, flush=True)

    return call
