"""Where the test suite's time goes: XLA compilation, tracing and lowering, and the rest, per
module and per test, and how much of it the tracker's body-shape refinement takes.

The brief asks for a suite of about 10 minutes on 2 cores; `.ci/run` starts from an empty
compilation cache, so compilation is part of every CI run. This runs pytest in this process
with a small plugin: JAX's monitoring events give the seconds spent compiling
(``backend_compile``) and tracing / lowering (``jaxpr_trace`` + ``jaxpr_to_mlir_module``) during
each test (its fixtures' set-up included); ``Tracker._refine_on`` (a whole refinement) and
``Tracker._advance_refinement`` (one part of one spread over updates,
``ShapeFitSettings.online_spread``) are timed by wrapping them.
Work done in subprocesses (the command-line reliability tests, the notebooks' kernels) shows
as "rest". It prints one table per module (sorted by wall time) and the slowest tests, and
writes everything to JSON.

    python benchmarks/suite_time.py OUT.json [--cold] [-- PYTEST_ARGS...]

``--cold`` points the compilation cache and the program store at a new empty folder (what CI
sees); without it the session's cache (``.pytest_cache``) is used, as a second local run does.
PYTEST_ARGS default to the whole suite (``tests``); e.g. ``-- tests/test_smooth.py``.
Measured on a shared machine: compare modules within one run, not runs across machines.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_COMPILE = "/jax/core/compile/backend_compile_duration"
_TRACE = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
)


class SuiteClock:
    """pytest plugin: per test ``{compile, trace, refine, wall}`` seconds and its outcome."""

    def __init__(self):
        self.current = None
        self.tests: dict[str, dict] = {}

    def _row(self) -> dict | None:
        return None if self.current is None else self.tests[self.current]

    def on_event(self, event: str, duration: float, **_) -> None:
        row = self._row()
        if row is None:
            return
        if event == _COMPILE:
            row["compile"] += duration
        elif event in _TRACE:
            row["trace"] += duration

    def on_refine(self, seconds: float, finished: bool = True) -> None:
        """A refinement's seconds; ``finished``: it is done (counted once, not per part)."""
        row = self._row()
        if row is not None:
            row["refine"] += seconds
            row["refinements"] += int(finished)

    def pytest_configure(self, config):
        install(self)  # here, not before pytest starts: its plugins' modules load first

    def pytest_runtest_logstart(self, nodeid, location):
        self.current = nodeid
        self.tests[nodeid] = dict(
            compile=0.0, trace=0.0, refine=0.0, refinements=0, start=time.perf_counter()
        )

    def pytest_runtest_logreport(self, report):
        row = self.tests.get(report.nodeid)
        if row is not None and (report.when == "call" or report.outcome != "passed"):
            row["outcome"] = report.outcome

    def pytest_runtest_logfinish(self, nodeid, location):
        row = self.tests[nodeid]
        row["wall"] = time.perf_counter() - row.pop("start")
        self.current = None


def install(clock: SuiteClock) -> None:
    """Route JAX's compile events and the tracker's refinements to ``clock``."""
    import jax

    from posetrack import _tracker

    jax.monitoring.register_event_duration_secs_listener(clock.on_event)

    def timed(method, finished):
        """``method`` timed into ``clock``; ``finished(self)``: a refinement ended with it."""

        def wrapper(self, *args, **kwargs):
            t0 = time.perf_counter()
            try:
                return method(self, *args, **kwargs)
            finally:
                clock.on_refine(time.perf_counter() - t0, finished=finished(self))

        return wrapper

    T = _tracker.Tracker
    T._refine_on = timed(T._refine_on, lambda self: True)  # a whole refinement
    # One part of a refinement spread over updates; done when none is pending any more.
    T._advance_refinement = timed(T._advance_refinement, lambda self: self._refining is None)


def summarise(tests: dict[str, dict]) -> dict:
    """Per-module sums, sorted by wall time, and the totals."""
    modules: dict[str, dict] = collections.defaultdict(
        lambda: dict(tests=0, compile=0.0, trace=0.0, refine=0.0, wall=0.0)
    )
    for nodeid, row in tests.items():
        m = modules[nodeid.split("::")[0]]
        m["tests"] += 1
        for k in ("compile", "trace", "refine", "wall"):
            m[k] += row.get(k, 0.0)
    for m in modules.values():
        m["rest"] = m["wall"] - m["compile"] - m["trace"]
    ordered = dict(sorted(modules.items(), key=lambda kv: -kv[1]["wall"]))
    total = {k: sum(m[k] for m in ordered.values()) for k in ("compile", "trace", "refine", "wall")}
    total["rest"] = total["wall"] - total["compile"] - total["trace"]
    return {"modules": ordered, "total": total}


def print_tables(summary: dict, tests: dict[str, dict], top: int) -> None:
    head = (
        f"{'module':42s} {'tests':>5s} {'wall':>7s} {'compile':>8s} {'trace':>6s} {'rest':>7s} "
        f"{'refine':>7s}"
    )
    print(head)
    print("-" * len(head))
    rows = list(summary["modules"].items()) + [("total", {**summary["total"], "tests": len(tests)})]
    for name, m in rows:
        print(
            f"{name:42s} {m['tests']:5d} {m['wall']:7.1f} {m['compile']:8.1f} {m['trace']:6.1f} "
            f"{m['rest']:7.1f} {m['refine']:7.1f}"
        )
    print(f"\nslowest {top} tests (seconds; wall includes fixture set-up):")
    for nodeid, row in sorted(tests.items(), key=lambda kv: -kv[1].get("wall", 0.0))[:top]:
        print(
            f"{row.get('wall', 0.0):7.1f} compile {row['compile']:5.1f} trace {row['trace']:5.1f} "
            f"refine {row['refine']:5.1f} ({row['refinements']})  {nodeid}"
        )


def _rounded(x):
    """``x`` with every float rounded to milliseconds (the record stays small)."""
    if isinstance(x, float):
        return round(x, 3)
    if isinstance(x, dict):
        return {k: _rounded(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_rounded(v) for v in x]
    return x


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, pytest_args = argv, []
    if "--" in argv:
        ours, pytest_args = argv[: argv.index("--")], argv[argv.index("--") + 1 :]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="JSON file to write")
    parser.add_argument("--cold", action="store_true", help="start from an empty compilation cache")
    parser.add_argument("--top", type=int, default=25, help="slowest tests listed")
    args = parser.parse_args(ours)
    if args.out.suffix != ".json":
        parser.error(f"OUT must be a .json file, got {args.out}")
    if args.cold:
        os.environ["POSETRACK_CACHE_DIR"] = tempfile.mkdtemp(prefix="posetrack-suite-cold-")
    import pytest

    clock = SuiteClock()
    os.chdir(ROOT)
    t0 = time.perf_counter()
    code = pytest.main(["-q", *(pytest_args or ["tests"])], plugins=[clock])
    elapsed = time.perf_counter() - t0
    summary = summarise(clock.tests)
    print()
    print_tables(summary, clock.tests, args.top)
    print(f"\npytest exit code {int(code)}, {elapsed:.0f} s in all (collection included)")
    import subprocess

    from posetrack.app._machine import machine_info
    from posetrack.io import atomic_write_text

    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    record = {
        "what": "test-suite time per module and test (benchmarks/suite_time.py)",
        "machine": machine_info(),
        "commit": commit or None,
        "cold": args.cold,
        "pytest_args": pytest_args or ["tests"],
        "exit_code": int(code),
        "seconds": elapsed,
        **summary,
        "tests": clock.tests,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps(_rounded(record), indent=1))  # never half-written
    print(f"wrote {args.out}")
    return int(code)


if __name__ == "__main__":
    raise SystemExit(main())
