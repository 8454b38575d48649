"""Outputs: poses .npz, EasyMocap JSON, and atomicity when a write is interrupted."""

import json
import os

import numpy as np
import pytest

import posetrack.io._export as export_module
from posetrack.io import (
    MARKER_NAME,
    InputError,
    atomic_dir,
    atomic_open,
    atomic_write_bytes,
    read_poses_npz,
    write_easymocap,
    write_poses_npz,
)


def _poses(n=5, seed=0):
    rng = np.random.default_rng(seed)
    kp = rng.normal([0, 0, 2.5], 0.3, (n, 18, 3))
    conf = rng.uniform(0.2, 1.0, (n, 18))
    kp[1, 4], conf[1, 4] = np.nan, 0.0
    kp[2], conf[2] = np.nan, 0.0  # a frame with nothing estimated
    return dict(
        keypoints3d=kp,
        confidence=conf,
        params=rng.normal(size=(n, 43)),
        delta=rng.uniform(size=n),
        status=["tracked", "tracked", "no_observation", "lost", "tracked"][:n],
        fps=30.0,
        frame_ids=np.arange(10, 10 + n),
    )


def _leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def test_write_poses_npz_contents(tmp_path):
    poses = _poses()
    path = tmp_path / "out" / "poses.npz"
    write_poses_npz(path, **poses)
    with np.load(path, allow_pickle=False) as f:
        assert f["keypoints3d"].dtype == np.float32 and f["keypoints3d"].shape == (5, 18, 3)
        assert f["status"].tolist() == poses["status"] and f["status"].dtype.kind == "U"
        assert f["frame_ids"].tolist() == [10, 11, 12, 13, 14] and float(f["fps"]) == 30.0
        np.testing.assert_array_equal(f["params"], poses["params"])
        assert np.isnan(f["keypoints3d"][2]).all() and f["joint_names"][8] == "RHip"
    data = read_poses_npz(path)
    assert str(data["format"]) == "posetrack-poses"
    write_poses_npz(path, **{**poses, "fps": None, "status": [0, 0, 2, 1, 0]})
    data = read_poses_npz(path)
    assert "fps" not in data and data["status"].tolist() == poses["status"]


def test_no_nan_pose_values(tmp_path):
    path = tmp_path / "poses.npz"
    poses = _poses()
    poses["params"][3, 7] = np.nan
    with pytest.raises(ValueError, match=r"params\[3, 7\] = nan \(frame 13\)"):
        write_poses_npz(path, **poses)
    poses = _poses()
    poses["keypoints3d"][0, 2, 1] = np.nan
    with pytest.raises(ValueError, match="partly NaN"):
        write_poses_npz(path, **poses)
    poses = _poses()
    poses["keypoints3d"][0, 2] = np.nan
    with pytest.raises(ValueError, match="confidence is"):
        write_poses_npz(path, **poses)
    with pytest.raises(ValueError, match="status"):
        write_poses_npz(path, **{**_poses(), "status": ["tracked", "ok", "lost", "lost", "lost"]})
    with pytest.raises(ValueError, match="increase"):
        write_poses_npz(path, **{**_poses(), "frame_ids": np.array([0, 1, 1, 2, 3])})
    assert not path.exists() and _leftovers(tmp_path) == []


def test_read_poses_npz_rejects_other_files(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(InputError, match="not a readable"):
        read_poses_npz(tmp_path / "x.npz")
    np.savez(tmp_path / "y.npz", a=np.zeros(2))
    with pytest.raises(InputError, match="not a posetrack poses file"):
        read_poses_npz(tmp_path / "y.npz")


class Crash(Exception):
    pass


@pytest.mark.parametrize("interrupt", [Crash, KeyboardInterrupt])
def test_crash_mid_write_keeps_the_old_npz(tmp_path, monkeypatch, interrupt):
    path = tmp_path / "poses.npz"
    write_poses_npz(path, **_poses(seed=1))
    old = path.read_bytes()
    real_savez = np.savez

    def savez_then_crash(f, **arrays):
        real_savez(f, **arrays)
        f.flush()  # the partial file really is on disk when the crash comes
        raise interrupt("power cut")

    monkeypatch.setattr(export_module.np, "savez", savez_then_crash)
    with pytest.raises(interrupt):
        write_poses_npz(path, **_poses(seed=2))
    assert path.read_bytes() == old and _leftovers(tmp_path) == []
    fresh = tmp_path / "fresh.npz"
    with pytest.raises(interrupt):
        write_poses_npz(fresh, **_poses(seed=2))
    assert not fresh.exists() and _leftovers(tmp_path) == []


def test_atomic_write_bytes_partial_write(tmp_path, monkeypatch):
    path = tmp_path / "a.bin"
    atomic_write_bytes(path, b"old complete content")

    def replace_fails(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", replace_fails)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(path, b"new")
    assert path.read_bytes() == b"old complete content" and _leftovers(tmp_path) == []


def test_atomic_file_permissions_follow_umask(tmp_path):
    path = tmp_path / "a.txt"
    atomic_write_bytes(path, b"x")
    mask = os.umask(0o022)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_easymocap_layout(tmp_path):
    poses = _poses()
    kp, conf, ids = poses["keypoints3d"], poses["confidence"], poses["frame_ids"]
    out = write_easymocap(tmp_path / "out", kp, conf, ids)
    assert out == tmp_path / "out" / "keypoints3d"
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    assert names == [f"{i:06d}.json" for i in range(10, 15)]
    doc = json.loads((out / "000010.json").read_text())
    assert len(doc) == 1 and doc[0]["id"] == 0
    rows = np.array(doc[0]["keypoints3d"])
    assert rows.shape == (25, 4)
    np.testing.assert_allclose(rows[0, :3], poses["keypoints3d"][0, 0], atol=1e-6)
    mid = 0.5 * (poses["keypoints3d"][0, 8] + poses["keypoints3d"][0, 11])
    np.testing.assert_allclose(rows[8, :3], mid, atol=1e-6)  # BODY_25 MidHip
    np.testing.assert_allclose(rows[9, :3], poses["keypoints3d"][0, 8], atol=1e-6)  # RHip
    assert np.all(rows[19:] == 0)
    assert json.loads((out / "000012.json").read_text()) == []
    frame1 = np.array(json.loads((out / "000011.json").read_text())[0]["keypoints3d"])
    assert frame1[4].tolist() == [0, 0, 0, 0]
    coco = write_easymocap(tmp_path / "coco", kp, conf, ids, layout="coco18")
    rows = json.loads((coco / "000010.json").read_text())[0]["keypoints3d"]
    assert np.array(rows).shape == (18, 4)


def test_easymocap_rerun_replaces_the_folder_cleanly(tmp_path):
    poses = _poses()
    out = write_easymocap(tmp_path, poses["keypoints3d"], poses["confidence"], poses["frame_ids"])
    short = _poses(seed=3)
    write_easymocap(tmp_path, short["keypoints3d"][:2], short["confidence"][:2], np.array([0, 1]))
    assert sorted(p.name for p in out.iterdir()) == [MARKER_NAME, "000000.json", "000001.json"]
    assert _leftovers(tmp_path) == []


def test_easymocap_crash_keeps_the_old_folder(tmp_path, monkeypatch):
    poses = _poses()
    out = write_easymocap(tmp_path, poses["keypoints3d"], poses["confidence"], poses["frame_ids"])
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    calls = []
    real_dumps = json.dumps

    def dumps_crash_on_third(obj):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real_dumps(obj)

    monkeypatch.setattr(export_module.json, "dumps", dumps_crash_on_third)
    new = _poses(seed=5)
    with pytest.raises(KeyboardInterrupt):
        write_easymocap(tmp_path, new["keypoints3d"], new["confidence"], new["frame_ids"])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert _leftovers(tmp_path) == []
    calls.clear()
    with pytest.raises(KeyboardInterrupt):
        write_easymocap(tmp_path / "fresh", new["keypoints3d"], new["confidence"], new["frame_ids"])
    assert not (tmp_path / "fresh" / "keypoints3d").exists()
    assert _leftovers(tmp_path / "fresh") == []


def test_atomic_dir_never_replaces_foreign_folders(tmp_path):
    target = tmp_path / "keypoints3d"
    target.mkdir()
    (target / "precious.json").write_text("{}")
    with pytest.raises(FileExistsError, match="not written by posetrack"):
        with atomic_dir(target) as tmp:
            (tmp / "a.json").write_text("[]")
    assert (target / "precious.json").exists() and _leftovers(tmp_path) == []
    (target / "precious.json").unlink()  # an empty folder may be replaced
    with atomic_dir(target) as tmp:
        (tmp / "a.json").write_text("[]")
    assert (target / "a.json").exists() and (target / MARKER_NAME).exists()


def test_files_inside_atomic_dir_are_written_in_place_without_fsync(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd))[1])
    target = tmp_path / "out"
    with atomic_dir(target) as tmp:
        for k in range(3):
            atomic_write_bytes(tmp / "sub" / f"{k}.bin", b"%d" % k)
        assert sorted(p.name for p in (tmp / "sub").iterdir()) == ["0.bin", "1.bin", "2.bin"]
        assert synced == []  # no temporary files, no per-file fsync: the folder is synced once
        with pytest.raises(RuntimeError):
            with atomic_open(tmp / "sub" / "3.bin") as f:
                f.write(b"partial")
                raise RuntimeError("interrupted")
        assert not (tmp / "sub" / "3.bin").exists()  # a failed write leaves no partial file
    assert [(target / "sub" / f"{k}.bin").read_bytes() for k in range(3)] == [b"0", b"1", b"2"]
    assert len(synced) >= 5  # 3 files + the folders, by atomic_dir before the rename
    synced.clear()
    atomic_write_bytes(target / "sub" / "0.bin", b"new")  # outside a build: the atomic path
    assert (target / "sub" / "0.bin").read_bytes() == b"new" and len(synced) == 2
