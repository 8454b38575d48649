"""Progress bars (``posetrack.app.Progress`` / ``ProgressBar``): tqdm on a terminal, whole lines
without carriage returns when stderr is a file or a pipe, nothing at all when disabled."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from posetrack import synth
from posetrack.app import Progress, ProgressBar, _progress


class FakeTerminal(io.StringIO):
    def isatty(self):
        return True


def _lines(text: str) -> list[str]:
    assert "\r" not in text, repr(text)
    assert text.endswith("\n"), repr(text)
    return text.splitlines()


def test_redirected_stream_gets_whole_lines_and_a_final_count():
    stream = io.StringIO()
    items = list(range(25))
    assert list(Progress(items, "tracking", stream=stream)) == items
    lines = _lines(stream.getvalue())
    assert lines[0].startswith("tracking:") and "0/25" in lines[0]
    assert "25/25" in lines[-1] and "100%" in lines[-1]
    # One at the start, one per tenth crossed (9 of them before the end), one at the end.
    assert len(lines) == 11, lines
    counts = [int(line.split("/")[0].split()[-1]) for line in lines]
    assert counts == sorted(counts) and counts[-1] == 25


def test_a_real_file_as_stderr_gets_no_carriage_return(tmp_path):
    log = tmp_path / "log.txt"
    with open(log, "w") as f, contextlib.redirect_stderr(f):  # ``2> log.txt``
        for _ in Progress(range(7), "overlay"):
            pass
        bar = ProgressBar("tracking")
        for done in range(1, 5):
            bar(done, 4, "delta 0.25")
    lines = _lines(log.read_bytes().decode())  # read_text() would turn "\r" into "\n"
    assert "7/7" in [line for line in lines if line.startswith("overlay")][-1]
    assert "4/4" in lines[-1] and "delta 0.25" in lines[-1]


def test_callback_form_ends_the_line_when_done_equals_total():
    stream = io.StringIO()
    bar = ProgressBar("tracking", stream=stream)
    for done in range(1, 10):
        bar(done, 10, f"delta {done / 10:.1f}")
    assert "10/10" not in stream.getvalue()  # not finished: no final line yet
    bar(10, 10, "delta 1.0")
    lines = _lines(stream.getvalue())
    assert "10/10" in lines[-1] and "delta 1.0" in lines[-1]
    # A second run through the same callback starts a new bar (at 0/3) and ends it too.
    n_before = len(lines)
    for done in range(1, 4):
        bar(done, 3, "")
    lines = _lines(stream.getvalue())
    assert "0/3" in lines[n_before] and "3/3" in lines[-1]


def test_unknown_length_and_slow_progress_get_timed_lines(monkeypatch):
    monkeypatch.setattr(_progress, "LOG_EVERY_S", 0.0)  # every update is "a long time later"
    stream = io.StringIO()
    for _ in Progress((i for i in range(5)), "detecting", stream=stream):
        pass
    lines = _lines(stream.getvalue())
    assert len(lines) == 1 + 5  # the start, then one per item by time; close() adds no copy
    assert lines[-1].startswith("detecting: 5frames")


def test_a_loop_left_early_still_ends_its_line():
    stream = io.StringIO()
    for i in Progress(range(10), "overlay", stream=stream):
        if i == 3:
            break
    lines = _lines(stream.getvalue())
    assert "3/10" in lines[-1]  # items 0-2 done; item 3 was handed out but never finished


def test_disabled_writes_nothing(tmp_path):
    stream = io.StringIO()
    assert list(Progress(range(5), "x", enabled=False, stream=stream)) == list(range(5))
    assert stream.getvalue() == ""


def test_a_terminal_gets_the_redrawn_tqdm_bar():
    stream = FakeTerminal()
    for _ in Progress(range(10), "tracking", stream=stream):
        pass
    text = stream.getvalue()
    assert "\r" in text and text.endswith("\n")  # redrawn in place, then the line ends
    assert "10/10" in text.rsplit("\r", 1)[-1]


def test_a_jupyter_stream_goes_to_tqdm_auto():
    # ipykernel's OutStream renders carriage returns (and tqdm.auto may draw a widget there).
    stream = type("OutStream", (io.StringIO,), {"__module__": "ipykernel.iostream"})()
    bar = _progress._open("tracking", 3, "frames", stream)
    try:
        assert not isinstance(bar, _progress._LineWriter)
    finally:
        bar.close()


def test_synth_progress_true_prints_plain_lines(capsys):
    synth.generate(0, motion="wave", n_frames=3, width=64, height=48, with_rgb=False,
                   progress=True)  # fmt: skip
    err = capsys.readouterr().err
    lines = _lines(err)
    assert lines[-1].startswith("posetrack.synth: frame 3/3")


def test_synth_progress_callback_gets_every_frame():
    calls = []
    synth.generate(0, motion="wave", n_frames=3, width=64, height=48, with_rgb=False,
                   progress=lambda done, total, postfix: calls.append((done, total)))  # fmt: skip
    assert calls == [(1, 3), (2, 3), (3, 3)]


@pytest.mark.parametrize("total", [1, 3, 10, 37])
def test_tenth_lines_never_repeat_a_count(total):
    stream = io.StringIO()
    bar = ProgressBar("x", stream=stream)
    for done in range(1, total + 1):
        bar(done, total)
    lines = _lines(stream.getvalue())
    counts = [int(line.split("/")[0].split()[-1]) for line in lines]
    assert counts[0] == 0 and counts[-1] == total
    assert len(counts) == len(set(counts)) <= 12
    assert np.all(np.diff(counts) > 0)


@pytest.mark.parametrize("stream_type", [io.StringIO, FakeTerminal])
def test_a_total_that_grows_is_followed(stream_type):
    # track-many without a known total learns it as recordings start.
    stream = stream_type()
    bar = ProgressBar("tracking", stream=stream)
    for done, total in [(1, 2), (2, 5), (3, 5), (4, 7), (5, 7), (6, 7), (7, 7)]:
        bar(done, total, "")
    last = stream.getvalue().rstrip("\n").rsplit("\r", 1)[-1].splitlines()[-1]
    assert "7/7" in last and "100%" in last


def test_a_note_follows_the_bar_once_when_it_fills():
    """``note_when_done``: every call reaches the bar first; the note is written once, on its
    own line after the bar's last, when done reaches total."""
    stream = io.StringIO()
    bar = ProgressBar("tracking", stream=stream)
    progress = _progress.note_when_done(bar, "offline: smoothing the motion", stream=stream)
    for done in range(1, 5):
        progress(done, 4, "delta 0.30")
        assert ("offline" in stream.getvalue()) == (done == 4)
    lines = _lines(stream.getvalue())
    assert lines[-1] == "offline: smoothing the motion"
    assert lines[-2].startswith("tracking: 100% 4/4")
    # A callback called again at the end still gets every call; the note is not repeated.
    calls, notes = [], io.StringIO()
    progress = _progress.note_when_done(lambda *c: calls.append(c), "done", stream=notes)
    for done in (1, 2, 2, 2):
        progress(done, 2)
    assert calls == [(1, 2, ""), (2, 2, ""), (2, 2, ""), (2, 2, "")]
    assert notes.getvalue() == "done\n"
