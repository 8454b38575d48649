"""``posetrack._export`` (tracker result -> files) and ``posetrack._overlay`` from Python."""

from __future__ import annotations

import json

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

import posetrack
from posetrack import _body as body
from posetrack import io
from posetrack.app import SkeletonPanel
from posetrack.app._export import (
    DEFAULT_FPS,
    bvh_from_params,
    bvh_from_result,
    output_frame,
    save_results,
)
from posetrack.app._overlay import GIF_MAX_WIDTH, overlay_frame, video_codec, write_video
from posetrack.app._panel import FLOOR
from posetrack.app._viz import GREEN, GREY, RED

N_FRAMES = 16
# Same sequence size and configuration as test_cli_track.py: one JAX compilation per session.
CONFIG = posetrack.TrackerConfig.recommended("mht_h", num_hypotheses=2)


@pytest.fixture(scope="module")
def seq():
    return posetrack.synth.generate(0, motion="walk", n_frames=N_FRAMES, width=320, height=240)


@pytest.fixture(scope="module")
def result(seq):
    return posetrack.track(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, CONFIG)


def save(out, result, seq, **kwargs):
    kwargs.setdefault("depth", seq.depth)
    return save_results(out, result, intrinsics=seq.intrinsics, **kwargs)


def strict_json(path):
    def refuse(name):
        raise ValueError(f"{path}: non-standard JSON constant {name}")

    return json.loads(path.read_text(), parse_constant=refuse)


def files_of(folder):
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


# -- BVH --------------------------------------------------------------------------------------


# The skeleton itself (T-pose, offsets, random-pose round trip, bvhio): test_bvh_skeleton.py.


def test_bvh_from_result_is_the_tracked_motion(result):
    motion = bvh_from_result(result)
    assert motion.root_positions.shape == (N_FRAMES, 3)
    assert motion.local_rotations_wxyz.shape == (N_FRAMES, 19, 4)
    np.testing.assert_allclose(motion.root_positions, result.params[:, :3])
    np.testing.assert_allclose(np.linalg.norm(motion.local_rotations_wxyz, axis=-1), 1.0)


def test_bvh_in_the_floor_frame_stands_on_the_floor(result, seq, tmp_path):
    """With the floor frame the root height is the pelvis's height above the floor (about
    1 m for this synthetic adult: 1.04 m measured, 1.02-1.03 m true) and the toes reach down
    to the floor (1-2 cm above it measured)."""
    world = output_frame(result, "floor")
    path = tmp_path / "floor.bvh"
    io.write_bvh(path, **bvh_from_result(result, world)._asdict(), fps=30, camera_to_y_up=True)
    bvh = io.read_bvh(path)
    tracked = result.status == 0
    assert tracked.sum() >= N_FRAMES - 2
    hips_m = bvh.motion[tracked, 1] / 100.0  # Yposition of the root, centimetres in the file
    n, d = seq.floor_plane[:3], seq.floor_plane[3]
    truth = (seq.joints3d[:, [8, 11]].mean(axis=1) @ n + d)[tracked]  # the true hips' centre
    assert np.all((hips_m > 0.75) & (hips_m < 1.2)), hips_m  # a standing adult's hips
    assert np.median(np.abs(hips_m - truth)) < 0.03, (hips_m, truth)
    # The lower foot's toe End Site is near the floor in every tracked frame.
    pos, rot = io.bvh_world_transforms(bvh.parents, bvh.offsets, bvh.channels, bvh.motion)
    toes = [
        pos[:, j, 1] + np.einsum("tk,k->t", rot[:, j, 1], bvh.end_sites[j])
        for j in (bvh.names.index("RightFoot"), bvh.names.index("LeftFoot"))
    ]
    lowest_m = np.minimum(*toes)[tracked] / 100.0
    assert np.all((lowest_m > -0.03) & (lowest_m < 0.06)), lowest_m


def test_bvh_rejects_nan_params(result):
    bad = result.params.copy()
    bad[4, 9] = np.nan
    with pytest.raises(ValueError, match=r"params\[4, 9\]"):
        bvh_from_params(result.shape, bad)


# -- save_results -----------------------------------------------------------------------------


def test_save_results_writes_every_output(result, seq, tmp_path):
    out = tmp_path / "out"
    saved = save(out, result, seq, fps=15.0, frame_ids=np.arange(N_FRAMES) + 100,
                 info={"inputs": {"who": "test"}, "timing": {"track_s": 1.5}})  # fmt: skip
    assert saved.overlay == out / "overlay.mp4" and saved.bvh == out / "motion.bvh"
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    assert names == ["keypoints3d", "markers.trc", "motion.bvh", "overlay.mp4", "poses.npz",
                     "summary.json"]  # fmt: skip
    poses = io.read_poses_npz(saved.poses)
    assert float(poses["fps"]) == 15.0
    np.testing.assert_array_equal(poses["frame_ids"], np.arange(N_FRAMES) + 100)
    assert (out / "keypoints3d" / "000100.json").is_file()
    assert io.read_bvh(saved.bvh).frame_time == pytest.approx(1 / 15)
    capture = cv2.VideoCapture(str(saved.overlay))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == N_FRAMES
    assert capture.get(cv2.CAP_PROP_FPS) == pytest.approx(15.0)
    assert capture.get(cv2.CAP_PROP_FRAME_WIDTH) == 320 + 240  # the side view beside it
    summary = strict_json(out / "summary.json")
    assert summary == saved.summary
    assert summary["inputs"] == {"who": "test"}
    assert summary["timing"]["track_s"] == 1.5 and summary["timing"]["compile_s"] > 0
    assert summary["frame_ids"] == {"first": 100, "last": 115} and summary["fps"] == 15.0
    assert sum(summary["status_counts"].values()) == N_FRAMES


def test_unknown_fps_is_not_invented(result, seq, tmp_path):
    saved = save(tmp_path / "out", result, seq, video=False)
    assert "fps" not in io.read_poses_npz(saved.poses)
    assert io.read_bvh(saved.bvh).frame_time == pytest.approx(1 / DEFAULT_FPS)
    assert saved.summary["fps"] is None and saved.overlay is None


def test_crash_in_bvh_writer_leaves_no_folder(result, seq, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr("posetrack.app._export.write_bvh", broken)
    with pytest.raises(RuntimeError, match="disk on fire"):
        save(tmp_path / "out", result, seq)
    assert list(tmp_path.iterdir()) == []  # neither the folder nor a temporary one


def test_interrupt_keeps_the_previous_complete_output(result, seq, tmp_path, monkeypatch):
    out = tmp_path / "out"
    save(out, result, seq)
    before = files_of(out)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("posetrack.app._export.write_overlay", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save(out, result, seq, fps=60.0)
    assert files_of(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_rerun_replaces_the_folder_as_a_whole(result, seq, tmp_path):
    out = tmp_path / "out"
    save(out, result, seq)
    assert (out / "overlay.mp4").is_file()
    save(out, result, seq, video=False)
    assert not (out / "overlay.mp4").exists()  # no stale file from the previous run
    assert strict_json(out / "summary.json")["files"]["overlay"] is None


def test_foreign_folder_is_never_replaced(result, seq, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not written by posetrack"):
        save(out, result, seq)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(depth=None), "needs rgb or depth"),
        (dict(frame_ids=np.arange(3)), r"frame_ids must be \(16,\)"),
        (dict(fps=0.0), "fps must be positive"),
        (dict(frame_ids=np.arange(N_FRAMES)[::-1].copy()), "increase strictly"),
        (dict(video_panel="front"), "video_panel must be one of"),
    ],
)
def test_bad_arguments_fail_before_writing(result, seq, tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        save(tmp_path / "out", result, seq, **kwargs)
    assert list(tmp_path.iterdir()) == []


# -- overlay ----------------------------------------------------------------------------------


def test_gif_fallback_has_every_frame_and_is_scaled(tmp_path):
    frames = [np.full((300, 640, 3), 20 * i, np.uint8) for i in range(5)]
    path = write_video(tmp_path / "v", iter(frames), fps=10.0, size=(640, 300), formats=("gif",))
    assert path == tmp_path / "v.gif"
    images = iio.imread(path, index=None)
    assert images.shape[:3] == (5, 225, GIF_MAX_WIDTH)


def test_mp4v_when_ffmpeg_cannot_run(result, seq, tmp_path, monkeypatch):
    monkeypatch.setattr("posetrack.app._overlay._H264Writer.ok", property(lambda self: False))
    saved = save(tmp_path / "out", result, seq)
    assert saved.overlay == tmp_path / "out" / "overlay.mp4"
    assert video_codec(saved.overlay) == "mp4v"
    capture = cv2.VideoCapture(str(saved.overlay))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == N_FRAMES


def test_gif_when_no_mp4_writer_opens(result, seq, tmp_path, monkeypatch):
    monkeypatch.setattr("posetrack.app._overlay._H264Writer.ok", property(lambda self: False))
    monkeypatch.setattr("posetrack.app._overlay._Mp4Writer.ok", property(lambda self: False))
    saved = save(tmp_path / "out", result, seq)
    assert saved.overlay == tmp_path / "out" / "overlay.gif"
    assert not (tmp_path / "out" / "overlay.mp4").exists()
    assert len(iio.imread(saved.overlay, index=None)) == N_FRAMES
    assert saved.summary["files"]["overlay"] == "overlay.gif"


def test_overlay_panel_draws_the_floor_the_tracker_found(result, seq, tmp_path):
    assert result.floor is not None  # the synthetic room has a floor in view
    saved = save(tmp_path / "out", result, seq, video_panel="side")
    capture = cv2.VideoCapture(str(saved.overlay))
    ok, frame = capture.read()
    capture.release()
    assert ok and frame.shape == (240, 320 + 240, 3)
    panel = SkeletonPanel(result.keypoints3d, result.status, height=240, floor=result.floor)
    row = round(panel.pixel_of(0.0, 0.0)[1])
    left, _, right, _ = panel.box
    line = frame[row, 320 + left : 320 + right, ::-1].astype(int)  # BGR -> RGB
    assert (np.abs(line - FLOOR).sum(-1) < 60).mean() > 0.8
    no_floor = save(tmp_path / "out2", result, seq, video_panel=None)
    assert cv2.VideoCapture(str(no_floor.overlay)).get(cv2.CAP_PROP_FRAME_WIDTH) == 320


def test_odd_sized_mp4_is_written(tmp_path):
    frames = [np.full((121, 161, 3), 40 * i, np.uint8) for i in range(4)]
    path = write_video(tmp_path / "v", iter(frames), fps=10.0, size=(161, 121))
    capture = cv2.VideoCapture(str(path))
    assert path.suffix == ".mp4" and int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 4


@pytest.mark.parametrize("status, colour", [(0, GREEN), (1, RED), (2, GREY)])
def test_overlay_frame_colours_the_skeleton_by_status(status, colour):
    intr = posetrack.Intrinsics.create(fx=300, fy=300, cx=160, cy=120, width=320, height=240)
    kp = np.asarray(body.keypoints(body.BodyShape.default(), body.facing_camera_params(3.0)))
    black = np.zeros((240, 320, 3), np.uint8)
    img = overlay_frame(black, kp, intr, status=status, delta=0.3, frame_id=7)
    below_label = img[30:]  # the label band sits at the top
    assert (np.abs(below_label.astype(int) - colour).sum(-1) < 30).sum() > 100
    nothing = overlay_frame(black, np.full((18, 3), np.nan), intr, status=2, delta=np.nan,
                            frame_id=7)  # fmt: skip
    assert not nothing[30:].any()  # no estimate: nothing drawn, never a NaN crash
