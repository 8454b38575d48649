"""``posetrack generate``: a recording folder the loader reads, never written over by accident."""

from __future__ import annotations

import contextlib
import io as stdio

import numpy as np
import pytest

from posetrack import io, synth
from posetrack.app._cli import build_parser, main

ARGS = ("--frames", "3", "--width", "64", "--height", "48", "--motion", "wave", "--quiet")


def run_cli(*args) -> tuple[int, str, str]:
    out, err = stdio.StringIO(), stdio.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def _load(folder):
    return io.load_recording(
        depth_dir=folder / "depth", keypoints_dir=folder / "keypoints",
        intrinsics_path=folder / "intrinsics.json", rgb=folder / "rgb",
    )  # fmt: skip


def test_generate_writes_a_recording_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "rec"
    code, stdout, stderr = run_cli("generate", out, *ARGS)
    assert code == 0, stderr
    assert stderr == ""  # --quiet: no progress at all
    assert "wrote 3 frames" in stdout
    rec = _load(out)
    assert len(rec) == 3 and rec.intrinsics.width == 64 and rec.observed.any()
    truth = np.load(out / "ground_truth.npz")
    assert truth["joints3d"].shape == (3, 18, 3)
    before = sorted(p.name for p in (out / "depth").iterdir())

    # A second run must not replace the folder unless asked to.
    marker = out / "mine.txt"
    marker.write_text("user data")
    code, stdout, stderr = run_cli("generate", out, *ARGS, "--seed", "1")
    assert code == 2 and "already exists" in stderr and "--overwrite" in stderr
    assert marker.read_text() == "user data"
    assert sorted(p.name for p in (out / "depth").iterdir()) == before

    code, _, stderr = run_cli("generate", out, *ARGS, "--seed", "1", "--overwrite")
    assert code == 0, stderr
    assert not marker.exists()
    assert not np.array_equal(np.load(out / "ground_truth.npz")["joints3d"], truth["joints3d"])


def test_generate_rejects_a_bad_occlusion_level_and_motion(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:  # argparse: exit 2 with a usage line
        main(["generate", str(tmp_path / "x"), *ARGS, "--occlusion", "7"])
    assert info.value.code == 2 and "--occlusion" in capsys.readouterr().err
    code, _, stderr = run_cli("generate", tmp_path / "y", *ARGS[:-3], "--motion", "moonwalk")
    assert code == 2 and "moonwalk" in stderr
    assert not (tmp_path / "y").exists()


def test_generate_help_lists_the_built_in_motions():
    sub = build_parser()._subparsers._group_actions[0].choices["generate"]
    help_text = next(a.help for a in sub._actions if a.dest == "motion")
    for name in synth.MOTIONS:
        assert name in help_text, name


def test_generate_progress_in_a_redirected_log_is_whole_lines(tmp_path):
    # stderr is a StringIO here, as it is a file with ``2> log.txt``: no carriage returns.
    code, _, stderr = run_cli("generate", tmp_path / "rec", *ARGS[:-1])
    assert code == 0, stderr
    assert "\r" not in stderr and stderr.endswith("\n")
    lines = stderr.splitlines()
    assert lines[0].startswith("generating:") and "0/3" in lines[0]
    assert lines[-1].startswith("generating:") and "3/3" in lines[-1]
