"""Many recordings at once: ``track_many`` (batched steps), the manifest, ``posetrack
track-many`` (resumable, failures recorded, several processes, SIGKILL).

Small on purpose: 160x120, 10 frames, per-frame mode, B = 2, so the batched step compiles once
for the whole module (the subprocesses read it from the shared cache).
"""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import quick_refine

import posetrack as pt
from posetrack.app import main
from posetrack.io import InputError, read_manifest

ROOT = Path(__file__).resolve().parents[1]
W, H, T = 160, 120, 10


@pytest.fixture(scope="module")
def seqs():
    return [pt.synth.generate(s, n_frames=T, width=W, height=H, with_rgb=False) for s in range(3)]


@pytest.fixture(scope="module")
def folders(seqs, tmp_path_factory):
    root = tmp_path_factory.mktemp("many")
    for i, s in enumerate(seqs):
        pt.synth.save(s, root / f"rec{i}")
    return root


def _manifest(root: Path, rows: list[str], name="m.csv") -> Path:
    path = root / name
    path.write_text("name,depth,keypoints,intrinsics\n" + "".join(r + "\n" for r in rows))
    return path


def _row(name: str, rec: str) -> str:
    return f"{name},{rec}/depth,{rec}/keypoints,{rec}/intrinsics.json"


def test_track_many_equals_single_runs(seqs):
    """Batched steps (B = 2 over 3 sequences: one slot refilled) give each sequence the poses
    it gets alone, up to float rounding (D within 1 mm, same frame statuses)."""
    inputs = [(s.intrinsics, s.depth, s.keypoints2d, s.confidence) for s in seqs]
    done = []
    many = pt.track_many(inputs, batch=2, mode="per-frame", on_result=lambda i, r: done.append(i))
    assert sorted(done) == [0, 1, 2]
    for s, r in zip(seqs, many):
        alone = pt.track(s.depth, s.keypoints2d, s.confidence, s.intrinsics, mode="per-frame")
        np.testing.assert_array_equal(r.status, alone.status)
        d_many = np.nanmean(np.linalg.norm(r.keypoints3d - s.joints3d, axis=-1))
        d_alone = np.nanmean(np.linalg.norm(alone.keypoints3d - s.joints3d, axis=-1))
        assert abs(d_many - d_alone) < 1e-3, (d_many, d_alone)
        assert d_many < 0.1  # and both actually track


def test_track_many_batches_with_the_configuration_its_mode_runs(seqs, monkeypatch):
    """The batched step runs the configuration each tracker runs (``TrackerConfig.for_mode``:
    online, the far side's bound, left to the mode by the default, is on), not the one given:
    a batcher built from the given one would refuse every sequence (or run another program).
    The batcher is replaced by one that records its configuration and stops the run."""
    made = []

    class Recorder:
        def __init__(self, config, batch):
            made.append(config)
            raise RuntimeError("recorded")

    monkeypatch.setattr("posetrack._many.StepBatcher", Recorder)
    s = seqs[0]
    out = pt.track_many([(s.intrinsics, s.depth, s.keypoints2d, s.confidence)], mode="online",
                        errors="return")  # fmt: skip
    assert isinstance(out[0], RuntimeError) and len(made) == 1
    assert made[0].far_side_bound is True and made[0].bound_trusted is True
    assert made[0] == pt.TrackerConfig().for_mode("online")


def test_track_many_both_ways_equals_single_runs_and_counts_both_passes(seqs):
    """Offline with ``SmoothSettings(both_ways=True)`` inside a batch: the backward pass's
    chunks are batched like the forward's, each sequence gets what it gets alone, and the
    progress counts two passes of every frame."""
    inputs = [(s.intrinsics, s.depth, s.keypoints2d, s.confidence) for s in seqs[:2]]
    opts = dict(refine=None, motion=pt.SmoothSettings(both_ways=True))
    calls = []
    many = pt.track_many(inputs, batch=2, progress=lambda d, t, p: calls.append((d, t)), **opts)
    assert calls[-1] == (4 * T, 4 * T) and len(calls) == 4 * T
    for s, r in zip(seqs, many):
        tr = pt.Tracker(s.intrinsics, **opts)
        alone = tr.run(s.depth, s.keypoints2d, s.confidence)
        assert tr.both_ways_frames >= T - 2
        np.testing.assert_array_equal(r.status, alone.status)
        np.testing.assert_allclose(r.keypoints3d, alone.keypoints3d, atol=2e-3)


def test_track_many_shape_prepass_steps_in_its_slot_and_counts_its_frames(seqs):
    """Offline with a shape pre-pass (``ShapeFitSettings.offline_first``) inside a batch: the
    pre-pass's chunks are batched in the sequence's own slot (which stays held for the
    recording's pass after it), each sequence gets what it gets alone up to float rounding,
    and the progress counts the pre-pass's frames too. Two refinements (Adam on the shape)
    carry the rounding further than the steps alone do: measured on a 2-core Intel Xeon, the
    shapes within 1.1 mm, keypoints within 7.5 mm, D within 0.3 mm; on a 2-core AMD EPYC
    (2026-12-04) the shapes within 1.5 mm, and in one sequence a 1.5 mm shape difference
    took the MHT's random walk elsewhere (per-frame keypoints 119 mm apart, the smoothed
    output 57 mm in one keypoint) with D within 0.6 mm. So the keypoints are compared by
    their median difference (a slot mixed up with another recording's is decimetres off
    everywhere) and a bound on the largest, not element by element. The refinements take 20
    Adam steps instead of the default's 100: the slots and the comparisons are the same, and
    the test takes 11.5 s instead of 39 (2-core AMD EPYC, compilation cache warm)."""
    # 8 frames: a pre-pass of 8 of the 10; quick_refine's 20 steps
    opts = dict(refine=quick_refine("offline", offline_first=T - 2))
    inputs = [(s.intrinsics, s.depth, s.keypoints2d, s.confidence) for s in seqs]
    calls = []
    many = pt.track_many(inputs, batch=2, progress=lambda d, t, p: calls.append((d, t)), **opts)
    assert calls[-1] == (3 * (2 * T - 2),) * 2 and len(calls) == 3 * (2 * T - 2)
    for s, r in zip(seqs, many):
        tr = pt.Tracker(s.intrinsics, **opts)
        alone = tr.run(s.depth, s.keypoints2d, s.confidence)
        assert tr.refine_report["offline_first"] is not None
        np.testing.assert_array_equal(r.status, alone.status)
        diff = np.abs(r.keypoints3d - alone.keypoints3d)
        assert np.nanmedian(diff) < 0.005 and np.nanmax(diff) < 0.1, (
            np.nanmedian(diff), np.nanmax(diff))  # fmt: skip
        d_many = np.nanmean(np.linalg.norm(r.keypoints3d - s.joints3d, axis=-1))
        d_alone = np.nanmean(np.linalg.norm(alone.keypoints3d - s.joints3d, axis=-1))
        assert abs(d_many - d_alone) < 1e-3, (d_many, d_alone)
        for k, v in alone.shape.to_dict().items():
            assert abs(r.shape.to_dict()[k] - v) < 3e-3, k


def test_batched_chunks_drop_and_reinitialise_as_alone(seqs, monkeypatch):
    """Inside a batch of chunks (B = 2, chunk 16) a track dropped in its second chunk (the
    followed person hidden while a bystander is in view) throws away its queued third chunk
    and re-initialises, as the sequence's run alone does; the other sequence (a shorter one)
    is unaffected."""
    seq = pt.synth.generate(
        520, motion="wave", n_frames=40, occlusion_level=1, width=W, height=H, with_rgb=False,
        bystander=True,
    )  # fmt: skip
    kp, conf = seq.people2d, seq.people_confidence.copy()
    for t in range(14, 23):  # both people in view from frame 9: the followed one hidden
        conf[t, seq.people_index[t]] = 0.0
    conf[37:] = 0.0  # nobody
    inputs = [(seq.intrinsics, seq.depth, kp, conf)]
    inputs.append((seqs[1].intrinsics, seqs[1].depth, seqs[1].keypoints2d, seqs[1].confidence))
    drops, drop = [], pt.Tracker._drop_track  # the frame of every drop

    def record(tracker):
        drops.append(tracker._run_frame)
        drop(tracker)

    monkeypatch.setattr(pt.Tracker, "_drop_track", record)
    many = pt.track_many(inputs, batch=2, mode="per-frame")
    batched, drops[:] = sorted(drops), []
    for (intr, depth, k, c), r in zip(inputs, many):
        alone = pt.Tracker(intr, mode="per-frame").run(depth, k, c)
        np.testing.assert_array_equal(r.status, alone.status)
        assert np.nanmax(np.abs(r.keypoints3d - alone.keypoints3d)) < 1e-3
    assert batched == drops  # the same drop, at the same frame
    # The first sequence went through every path: lost, a drop (lost_patience lost frames in
    # a row), tracked again after it, and frames with nobody.
    st = many[0].status
    assert drops == [18] and (st[14:23] == pt.LOST).all()
    assert (st[23:37] == pt.TRACKED).sum() > 8 and (st[37:] == pt.NO_OBSERVATION).all()


def test_track_many_keeps_going_past_a_bad_sequence(seqs):
    s = seqs[0]
    bad = (s.intrinsics, s.depth, s.keypoints2d[:-1], s.confidence[:-1])  # lengths disagree
    good = (s.intrinsics, s.depth, s.keypoints2d, s.confidence)
    res = pt.track_many([bad, good], batch=2, mode="per-frame", errors="return")
    assert isinstance(res[0], ValueError) and "keypoint frames" in str(res[0])
    assert isinstance(res[1], pt.TrackResult)
    with pytest.raises(ValueError, match="keypoint frames"):
        pt.track_many([bad], batch=2, mode="per-frame")
    with pytest.raises(ValueError, match="batch"):
        pt.track_many([good], batch=0)


@pytest.mark.parametrize(
    "text, match",
    [
        ("name,depth,keypoints\n", "no column 'intrinsics'"),
        ("name,depth,keypoints,intrinsics,colour\n", "unknown or repeated column 'colour'"),
        ("name,depth,keypoints,intrinsics\n", "lists no recording"),
        ("name,depth,keypoints,intrinsics\n" + _row("a", "rec0") + "\n" + _row("a", "rec1"),
         r"row 3 \(a\): name: 'a' is also the name of row 2"),
        ("name,depth,keypoints,intrinsics\n" + _row("../x", "rec0"), "is not a folder name"),
        ("name,depth,keypoints,intrinsics\n" + _row("a", "nowhere"),
         r"row 2 \(a\): depth: .*nowhere/depth: no such folder"),
        ("name,depth,keypoints,intrinsics,depth_scale\n" + _row("a", "rec0") + ",-5",
         r"row 2 \(a\): depth_scale: must be a positive number"),
        ("name,depth,keypoints,intrinsics\na,rec0/depth,rec0/keypoints,rec0/depth\n",
         r"row 2 \(a\): intrinsics: .*not a file"),
    ],
)  # fmt: skip
def test_manifest_errors_name_row_and_column(folders, text, match):
    path = folders / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=match):
        read_manifest(path)


def test_manifest_resolves_relative_paths(folders):
    rows = read_manifest(_manifest(folders, [_row("a", "rec0"), _row("b", "rec1")]))
    assert [r.name for r in rows] == ["a", "b"]
    assert rows[0].depth == folders / "rec0" / "depth" and rows[0].frames == T
    assert rows[1].intrinsics.width == W and rows[1].depth_scale == 1000.0


def _cli(*extra: str) -> list[str]:
    return ["track-many", "--batch", "2", "--per-frame", "--no-video", "--quiet", *extra]


def test_cli_tracks_resumes_and_records_failures(folders, capsys):
    manifest = _manifest(folders, [_row("a", "rec0"), _row("b", "rec1"), _row("c", "rec2")])
    out = folders / "out"
    assert main(_cli("--manifest", str(manifest), "--out", str(out))) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 3, "failed": 0, "pending": 0}
    for name, rec in zip("abc", ("rec0", "rec1", "rec2")):
        one = json.loads((out / name / "summary.json").read_text())
        assert one["frames"] == T and one["track_many"]["row"] == "abc".index(name) + 2
        assert (out / name / "poses.npz").is_file() and (out / name / "motion.bvh").is_file()
    stamp = (out / "a" / "poses.npz").stat().st_mtime_ns

    # A re-run skips what is done; a new row that fails to load is recorded, not fatal.
    rec3 = folders / "rec3"
    pt.synth.save(pt.synth.generate(9, n_frames=T, width=W, height=H, with_rgb=False), rec3)
    bad = sorted((rec3 / "keypoints").iterdir())[4]
    bad.write_text('{"people": [{"pose_keypoints_2d": [1, 2]}]}')
    manifest = _manifest(folders, [_row("a", "rec0"), _row("b", "rec1"), _row("c", "rec2"),
                                   _row("d", "rec3")])  # fmt: skip
    capsys.readouterr()
    assert main(_cli("--manifest", str(manifest), "--out", str(out))) == 2
    err = capsys.readouterr().err
    assert "3 already done" in err and f"{bad.name}" in err and "row 5" in err
    assert (out / "a" / "poses.npz").stat().st_mtime_ns == stamp
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 3, "failed": 1, "pending": 0}
    assert "has 2 numbers" in summary["recordings"]["d"]["error"]
    assert not (out / "d").exists()

    # Other settings than the finished folders': refused before anything runs.
    args = _cli("--manifest", str(manifest), "--out", str(out))
    args.remove("--per-frame")
    assert main(args) == 2
    assert "was tracked with" in capsys.readouterr().err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _spawn(args: list[str], log: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        [sys.executable, "-m", "posetrack", *args], stdout=log.open("w"),
        stderr=subprocess.STDOUT, env=env,
    )  # fmt: skip


def test_two_processes_share_the_manifest_once(folders):
    """Two processes on 127.0.0.1 (jax.distributed) split the rows; together they track each
    once, with the poses of a single-process run."""
    manifest = _manifest(folders, [_row("a", "rec0"), _row("b", "rec1"), _row("c", "rec2")],
                         "m2.csv")  # fmt: skip
    out = folders / "out2"
    port = _free_port()
    procs = [
        _spawn(
            _cli(
                "--manifest",
                str(manifest),
                "--out",
                str(out),
                "--num-processes",
                "2",
                "--process-id",
                str(i),
                "--coordinator",
                f"127.0.0.1:{port}",
            ),
            folders / f"p{i}.log",
        )  # fmt: skip
        for i in range(2)
    ]
    for p in procs:
        assert p.wait(timeout=600) == 0, (folders / "p0.log").read_text() + (
            folders / "p1.log"
        ).read_text()
    logs = [(folders / f"p{i}.log").read_text() for i in range(2)]
    assert "2 to track (process 0 of 2)" in logs[0]
    assert "1 to track (process 1 of 2)" in logs[1]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 3, "failed": 0, "pending": 0}
    single = folders / "out"  # the single-process run of the test above, same settings
    if not (single / "c" / "poses.npz").is_file():
        pytest.skip("the single-process run did not run first")
    for name in "abc":
        a = np.load(out / name / "poses.npz")["keypoints3d"]
        b = np.load(single / name / "poses.npz")["keypoints3d"]
        np.testing.assert_allclose(a, b, atol=1e-3)


def test_sigkill_loses_only_the_batch_in_flight(folders):
    rows = [_row(n, f"rec{i % 3}") for i, n in enumerate("pqrstu")]
    manifest = _manifest(folders, rows, "m3.csv")
    out = folders / "out3"
    log = folders / "k.log"
    proc = _spawn(_cli("--manifest", str(manifest), "--out", str(out)), log)
    deadline = time.time() + 600
    while not any((out / n / "summary.json").is_file() for n in "pqrstu"):
        assert proc.poll() is None, log.read_text()
        assert time.time() < deadline, log.read_text()
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = {n for n in "pqrstu" if (out / n).exists()}
    assert finished and len(finished) < 6
    for n in finished:  # never half-written: a folder is there only when complete
        assert (out / n / "summary.json").is_file() and (out / n / pt.io.MARKER_NAME).is_file()
    stamps = {n: (out / n / "poses.npz").stat().st_mtime_ns for n in finished}
    proc = _spawn(_cli("--manifest", str(manifest), "--out", str(out)), log)
    assert proc.wait(timeout=600) == 0, log.read_text()
    assert f"{len(finished)} already done" in log.read_text()
    assert {n: (out / n / "poses.npz").stat().st_mtime_ns for n in finished} == stamps
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 6, "failed": 0, "pending": 0}
    assert not list(out.glob(".*.tmp"))  # the killed run's unfinished folders are gone


def test_summary_rewrite_removes_a_killed_writers_temporary_file(tmp_path):
    # SIGKILL while summary.json was being replaced leaves its hidden temporary file; the next
    # writer holds the lock every writer takes, so it knows the file is orphaned.
    from posetrack.app._many import _record

    orphan = tmp_path / ".summary.json.ab12cd34.tmp"
    orphan.write_text('{"half": ')
    other = tmp_path / ".rec0.ab12cd34.tmp"  # a recording's folder in the making: not ours
    other.mkdir()
    data = _record(tmp_path, tmp_path / "m.csv", ["a", "b"], {"a": {"status": "done"}})
    assert data["counts"] == {"done": 1, "failed": 0, "pending": 1}
    assert not orphan.exists() and other.is_dir()
    assert json.loads((tmp_path / "summary.json").read_text()) == data


def test_resume_settings_name_the_both_ways_fusion():
    """A re-run skips only recordings tracked as it would track them: one-way results carry
    no ``both_ways`` key (older one-way results still match), both-ways results name the
    fusion, so those of the first fusion (recorded as ``true``) do not match."""
    from types import SimpleNamespace

    from posetrack.app._many import _settings

    args = SimpleNamespace(seed=3, shape_prepass=0, shape_prepass_below=None)
    config = pt.TrackerConfig()
    one = _settings(args, config, "offline")
    both = _settings(args, config, "offline", both_ways=True)
    assert "both_ways" not in one and {k: v for k, v in both.items() if k != "both_ways"} == one
    assert both["both_ways"] not in (True, False, None)
    # --shape-prepass N: named where on (results tracked without it still match without it).
    pre = _settings(SimpleNamespace(seed=3, shape_prepass=40, shape_prepass_below=None), config,
                    "offline")  # fmt: skip
    assert "shape_prepass" not in one and pre == {**one, "shape_prepass": 40}
    gated = SimpleNamespace(seed=3, shape_prepass=40, shape_prepass_below=0.6)
    assert _settings(gated, config, "offline") == {**pre, "shape_prepass_below": 0.6}
