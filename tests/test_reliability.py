"""``posetrack track`` under SIGKILL, a read-only or full disk, and run to run.

The promises of the README's "Reliability" section: a killed run leaves the previous outputs
(or nothing), never a half-written set; a disk that refuses the outputs gives one ``error:``
line that names the output folder and the system's reason, and leaves nothing; the same
inputs give byte-identical files. ``benchmarks/reliability.py`` measures the same on a long
run (memory) and over more kills.

Real processes for what only a real process shows (SIGKILL, two runs); the disk errors run
in-process. The clip and tracker configuration are those of ``tests/test_cli_track.py``
(320x240, mht_h with 2 hypotheses), so the compiled programs come from the shared cache. A
real read-only or full disk is a small tmpfs, mounted where the tests run as root with the
right to mount (else those cases are skipped; root ignores folder permissions); simulated
errors from the OS calls cover the same paths everywhere.
"""

from __future__ import annotations

import contextlib
import errno
import io as stdio
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import posetrack
from posetrack import io
from posetrack.app._cli import main
from posetrack.app._export import without_timings
from posetrack.app._overlay import _finished_mp4, write_video

ROOT = Path(__file__).resolve().parents[1]
N_FRAMES, WIDTH, HEIGHT = 16, 320, 240  # as tests/test_cli_track.py: shared programs
METHOD, HYPOTHESES = "mht_h", "2"
# atomic_dir's hidden folder for DIR/out: .out.<8 random characters>.tmp
BUILDING = re.compile(r"\.out\.[A-Za-z0-9_]{8}\.tmp")


def track_args(rec: Path, out: Path, *extra: str) -> list[str]:
    return [
        "track", "--depth", str(rec / "depth"), "--keypoints", str(rec / "keypoints"),
        "--intrinsics", str(rec / "intrinsics.json"), "--rgb", str(rec / "rgb"),
        "--method", METHOD, "--hypotheses", HYPOTHESES, "--out", str(out), *extra,
    ]  # fmt: skip


def run_cli(*args: str) -> tuple[int, str, str]:
    """``posetrack <args>`` in-process: (exit code, stdout, stderr)."""
    out, err = stdio.StringIO(), stdio.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return code, out.getvalue(), err.getvalue()


def spawn(args: list[str], **kwargs) -> subprocess.Popen:
    """``python -m posetrack <args>`` in a new process (the session's cache, this checkout)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "posetrack", *args], env=env, **kwargs)


def files(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` (hidden ones too): relative path -> bytes."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def one_error_line(stderr: str) -> str:
    """The only line of ``stderr``, which must be an ``error:`` line (no traceback, no notes)."""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    return lines[0]


@pytest.fixture(scope="module")
def rec(tmp_path_factory) -> Path:
    seq = posetrack.synth.generate(0, motion="walk", n_frames=N_FRAMES, width=WIDTH,
                                   height=HEIGHT)  # fmt: skip
    return posetrack.synth.save(seq, tmp_path_factory.mktemp("rec") / "rec")


@pytest.fixture(scope="module")
def runs(rec, tmp_path_factory) -> list[Path]:
    """Two complete runs of the same command, each in its own process."""
    root = tmp_path_factory.mktemp("runs")
    outs = [root / "first" / "out", root / "second" / "out"]
    for out in outs:
        done = subprocess.run(
            [sys.executable, "-m", "posetrack", *track_args(rec, out, "--quiet")],
            env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True,
            timeout=900,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
    return outs


# -- run to run -------------------------------------------------------------------------------


def test_same_inputs_give_byte_identical_outputs(runs):
    first, second = (files(out) for out in runs)
    assert first.keys() == second.keys()
    assert first["poses.npz"] == second["poses.npz"]  # the promise, byte for byte
    differ = [k for k in first if k != "summary.json" and first[k] != second[k]]
    assert differ == []  # keypoints3d/*.json, motion.bvh, markers.trc, overlay.mp4 too
    assert without_timings(json.loads(first["summary.json"])) == without_timings(
        json.loads(second["summary.json"])
    )
    # Not trivially equal: the poses moved, so a difference would have shown.
    kp = io.read_poses_npz(runs[0] / "poses.npz")["keypoints3d"]
    assert np.nanmax(np.abs(np.diff(kp, axis=0))) > 0.005


# -- SIGKILL ----------------------------------------------------------------------------------


def kill_when(proc: subprocess.Popen, ready, timeout: float = 600.0) -> None:
    """SIGKILL ``proc`` as soon as ``ready()`` is true (polled every millisecond)."""
    deadline = time.monotonic() + timeout
    while not ready():
        assert proc.poll() is None, "the run ended before it could be killed"
        assert time.monotonic() < deadline
        time.sleep(0.001)
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def test_sigkill_leaves_the_previous_outputs_never_a_partial_set(runs, rec, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(runs[0], out)
    before = files(out)

    # 1. Killed while tracking (the "tracking N frames" line is printed after loading; the
    # outputs are written after tracking, smoothing and the body-shape refinement).
    proc = spawn(track_args(rec, out, "--quiet"), stderr=subprocess.PIPE, text=True)
    kill_when(proc, lambda: "tracking" in proc.stderr.readline())
    proc.stderr.close()
    assert files(out) == before  # untouched, bit for bit
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # killed before it wrote anything

    # 2. Killed while writing: as soon as the hidden folder the outputs are built in appears
    # (this run's poses are never kept: the body-shape refinement, which only delays the
    # writing, is off).
    proc = spawn(track_args(rec, out, "--quiet", "--no-refine-shape"), stderr=subprocess.DEVNULL)
    kill_when(proc, lambda: any(BUILDING.fullmatch(p) for p in os.listdir(tmp_path)))
    left = [p for p in tmp_path.iterdir() if p.name != "out"]
    assert len(left) == 1 and BUILDING.fullmatch(left[0].name), left  # it was mid-write
    assert files(out) == before  # the previous set, not a mix

    # 3. A re-run succeeds and writes the same poses (the half-built folder is left alone: it
    # is never at the output's name, and is safe to delete).
    proc = spawn(track_args(rec, out, "--quiet"), stderr=subprocess.PIPE, text=True)
    _, stderr = proc.communicate(timeout=900)
    assert proc.returncode == 0, stderr
    after = files(out)
    assert after.keys() == before.keys()
    assert all(after[k] == before[k] for k in before if k != "summary.json")


# -- a disk that refuses the outputs ----------------------------------------------------------


@contextlib.contextmanager
def tmpfs(folder: Path, options: str):
    """A tmpfs at ``folder`` (root on Linux with the right to mount), else skip."""
    folder.mkdir()
    if sys.platform != "linux" or os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("a real read-only or full disk needs root on Linux (mount -t tmpfs)")
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=True)


def refuse(monkeypatch, below: Path, code: int, calls=("open", "mkdir")) -> None:
    """Make the OS calls ``calls`` fail with ``code`` for paths below ``below``."""
    for name in calls:
        real = getattr(os, name)

        def failing(path, *args, _real=real, **kwargs):
            if str(os.path.abspath(os.fsdecode(path))).startswith(str(below)):
                raise OSError(code, os.strerror(code), os.fsdecode(path))
            return _real(path, *args, **kwargs)

        monkeypatch.setattr(os, name, failing)


@pytest.mark.parametrize("how", ["tmpfs", "simulated", "permissions"])
def test_read_only_output_is_one_error_line_before_tracking(how, rec, tmp_path, monkeypatch):
    disk, reason = tmp_path / "disk", errno.EROFS
    with contextlib.ExitStack() as stack:
        if how == "tmpfs":
            stack.enter_context(tmpfs(disk, "size=1m,ro"))
        elif how == "simulated":
            disk.mkdir()
            refuse(monkeypatch, disk, errno.EROFS)
        else:
            if os.geteuid() == 0:
                pytest.skip("root ignores folder permissions (the tmpfs case covers it)")
            disk.mkdir()
            disk.chmod(0o555)
            stack.callback(disk.chmod, 0o755)
            reason = errno.EACCES
        out = disk / "new" / "out"  # missing folders on the way: the nearest one is checked
        code, stdout, stderr = run_cli(*track_args(rec, out))
        line = one_error_line(stderr)  # nothing before it: it failed before loading
        assert code == 1 and stdout == ""
        assert f"cannot write {out}: {os.strerror(reason)}" in line, line
        assert list(disk.iterdir()) == []


def test_full_disk_is_one_error_line_and_leaves_nothing(rec, tmp_path):
    with tmpfs(tmp_path / "disk", "size=64k") as disk:
        out = disk / "out"
        code, stdout, stderr = run_cli(*track_args(rec, out, "--quiet", "--no-refine-shape"))
        assert code == 1 and stdout == ""
        *before, line = stderr.strip().splitlines()
        assert line == (
            f"error: cannot write {out}: No space left on device (nothing was written there; "
            "an earlier output in that folder is unchanged)"
        )
        # Before it only the usual notes and "tracking" line: no FFmpeg output, no traceback.
        assert all(ln.startswith(("note: ", "tracking ")) for ln in before), stderr
        assert list(disk.iterdir()) == []  # the half-built folder is gone, the space free


def test_disk_full_while_writing_keeps_the_previous_outputs(runs, rec, tmp_path, monkeypatch):
    """Simulated: the disk fills up at ``markers.trc`` (``write`` raises ENOSPC and names no
    file, as the OS reports it), with poses, keypoints and BVH already in the half-built
    folder."""
    out = tmp_path / "out"
    shutil.copytree(runs[0], out)
    before = files(out)

    class Full(stdio.StringIO):
        def write(self, data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def full_open(file, mode="r", *args, **kwargs):
        if "w" in mode and os.fspath(file).endswith("markers.trc"):
            return Full()
        return open(file, mode, *args, **kwargs)

    monkeypatch.setattr("posetrack.io._atomic.open", full_open, raising=False)
    code, _, stderr = run_cli(*track_args(rec, out, "--quiet", "--no-refine-shape"))
    line = stderr.strip().splitlines()[-1]
    assert code == 1 and "Traceback" not in stderr
    assert line.startswith(f"error: cannot write {out}: No space left on device"), line
    assert files(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_video_cut_short_by_a_full_disk_is_an_error_not_a_file(tmp_path):
    """Neither video writer reports a failure: a file without its index used to be kept."""
    frames = [np.full((48, 64, 3), 40 * i, np.uint8) for i in range(6)]
    good = write_video(tmp_path / "v", frames, fps=10.0, size=(64, 48), formats=("mp4",))
    assert _finished_mp4(good)
    data = good.read_bytes()
    for cut in (len(data) // 2, len(data) - 1):
        (tmp_path / "cut.mp4").write_bytes(data[:cut])
        assert not _finished_mp4(tmp_path / "cut.mp4")
    with tmpfs(tmp_path / "disk", "size=12k") as disk:
        noisy = [np.random.default_rng(i).integers(0, 255, (120, 160, 3), np.uint8)
                 for i in range(30)]  # fmt: skip
        with pytest.raises(OSError) as info:
            write_video(disk / "v", noisy, fps=10.0, size=(160, 120), formats=("mp4",))
        assert info.value.errno == errno.ENOSPC
        assert list(disk.iterdir()) == []


# -- long runs --------------------------------------------------------------------------------


def test_nearest_estimated_frame_needs_no_frames_squared_table():
    """Regression: ``Tracker.run`` gave frames without an estimate the nearest estimated pose
    through an (all frames x estimated frames) table of distances: 1.6 GB for 5 s at the end
    of a 10,000-frame run (``benchmarks/reliability.py``), terabytes at a million frames."""
    from posetrack._tracker import nearest_index

    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 40))
        have = np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))
        brute = have[np.abs(np.arange(n)[:, None] - have[None]).argmin(axis=1)]
        np.testing.assert_array_equal(nearest_index(have, n), brute)
    n = 1_000_000
    have = np.arange(3, n, 5)  # the table: 1e6 x 2e5 x 8 bytes = 1.6 TB
    got = nearest_index(have, n)
    np.testing.assert_array_equal(got[:9], [3, 3, 3, 3, 3, 3, 8, 8, 8])
    assert got[-1] == have[-1] and np.abs(got - np.arange(n)).max() <= 3
