"""``posetrack track`` end to end on folders written by ``posetrack.synth.save``.

The CLI runs in-process (``posetrack.app.main``) so every run shares one JAX compilation:
all runs here use the same image size (320x240) and tracker configuration.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io as stdio
import json
import shutil
import sys
import types

import cv2
import jax
import numpy as np
import pytest

import posetrack
from posetrack import _body as body
from posetrack import io
from posetrack._depthobs import NO_FLOOR
from posetrack.app._cli import _lag, _mode, _motion, _refine, build_parser, main
from posetrack.app._export import BVH_KEYPOINTS
from posetrack.app._overlay import video_codec

N_FRAMES = 16
METHOD, HYPOTHESES = "mht_h", 2
CONFIG = posetrack.TrackerConfig.recommended(METHOD, num_hypotheses=HYPOTHESES)  # as the CLI
VANISH_START, VANISH_MIDDLE = (0, 1), (7, 8, 9)  # frames whose keypoints are removed


def run_cli(*args: str) -> tuple[int, str, str]:
    """``posetrack <args>`` in-process: (exit code, stdout, stderr)."""
    out, err = stdio.StringIO(), stdio.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def track_args(rec, out, *extra) -> list[str]:
    return [
        "track", "--depth", rec / "depth", "--keypoints", rec / "keypoints",
        "--intrinsics", rec / "intrinsics.json", "--method", METHOD,
        "--hypotheses", str(HYPOTHESES), "--quiet", "--out", out, *extra,
    ]  # fmt: skip


def without_keypoints(args: list) -> list:
    i = args.index("--keypoints")
    return args[:i] + args[i + 2 :]


@pytest.fixture(scope="module")
def seq():
    return posetrack.synth.generate(0, motion="walk", n_frames=N_FRAMES, width=320, height=240)


@pytest.fixture(scope="module")
def rec(seq, tmp_path_factory):
    return posetrack.synth.save(seq, tmp_path_factory.mktemp("rec") / "rec")


@pytest.fixture(scope="module")
def lib_result(seq):
    return posetrack.track(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, CONFIG)


@pytest.fixture(scope="module")
def cli(rec, tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "out"
    code, stdout, stderr = run_cli(*track_args(rec, out, "--rgb", rec / "rgb"))
    assert code == 0, stderr
    return types.SimpleNamespace(out=out, stdout=stdout, stderr=stderr)


@pytest.fixture(scope="module")
def poses(cli):
    return io.read_poses_npz(cli.out / "poses.npz")


# -- accuracy ---------------------------------------------------------------------------------


def test_cli_reproduces_library_accuracy(cli, poses, lib_result, rec, seq):
    truth = np.load(rec / "ground_truth.npz")["joints3d"]
    np.testing.assert_allclose(truth, seq.joints3d)
    # Depth PNGs are exact in mm and the JSON keeps every float32 bit, so the only difference
    # is metres = mm * (1/1000) in the reader vs mm / 1000 in the tracker (1 ulp).
    np.testing.assert_allclose(poses["keypoints3d"], lib_result.keypoints3d, atol=1e-3)
    np.testing.assert_array_equal(poses["status"], lib_result.status_names)
    acc_cli = posetrack.accuracy(poses["keypoints3d"], truth)
    acc_lib = posetrack.accuracy(lib_result.keypoints3d, truth)
    assert abs(acc_cli.mean_mm - acc_lib.mean_mm) < 0.5
    assert acc_cli.coverage == 1.0
    assert acc_cli.mean_mm < 50.0, acc_cli


# -- outputs ----------------------------------------------------------------------------------


def test_poses_npz_fields(poses):
    T = N_FRAMES
    expected = {
        "keypoints3d": (np.float32, (T, 18, 3)),
        "confidence": (np.float32, (T, 18)),
        "params": (np.float64, (T, 43)),
        "delta": (np.float32, (T,)),
        "frame_ids": (np.int64, (T,)),
    }
    for key, (dtype, shape) in expected.items():
        assert poses[key].dtype == dtype and poses[key].shape == shape, key
    assert np.isfinite(poses["params"]).all()
    assert set(poses["status"]) <= set(io.STATUSES)
    np.testing.assert_array_equal(poses["frame_ids"], np.arange(T))
    assert "fps" not in poses  # a folder of images has no frame rate and none was given
    assert ((poses["confidence"] >= 0) & (poses["confidence"] <= 1)).all()


def test_joint_state_says_not_estimated_predicted_or_observed(cli, poses, lib_result):
    """``joint_state``: 0 exactly where a joint is NaN, 2 where its keypoint was detected in
    that frame, 1 where the tracker placed it without a detection (the recording hides
    keypoints, so all three occur or at least 1 and 2)."""
    state = poses["joint_state"]
    assert state.dtype == np.int8 and state.shape == (N_FRAMES, 18)
    assert list(poses["joint_state_names"]) == ["not_estimated", "predicted", "observed"]
    estimated = np.isfinite(poses["keypoints3d"]).all(axis=-1)
    np.testing.assert_array_equal(state == 0, ~estimated)
    detected = lib_result.detected & (lib_result.status != posetrack.NO_OBSERVATION)[:, None]
    np.testing.assert_array_equal(state[estimated] == 2, detected[estimated])
    assert (state == 1).any() and (state == 2).any()
    counts = json.loads((cli.out / "summary.json").read_text())["joint_state_counts"]
    assert counts == {n: int(np.sum(state == k)) for k, n in enumerate(posetrack.JOINT_STATES)}


def test_easymocap_layout(cli, poses):
    files = sorted(p.name for p in (cli.out / "keypoints3d").glob("*.json"))
    assert files == [f"{t:06d}.json" for t in range(N_FRAMES)]
    people = json.loads((cli.out / "keypoints3d" / "000005.json").read_text())
    assert len(people) == 1 and people[0]["id"] == 0
    rows = np.asarray(people[0]["keypoints3d"])
    assert rows.shape == (25, 4)  # BODY_25: EasyMocap's body25 skeleton
    coco = rows[list(io.BODY25_TO_COCO18)]
    np.testing.assert_allclose(coco[:, :3], poses["keypoints3d"][5], atol=2e-6)
    np.testing.assert_allclose(coco[:, 3], poses["confidence"][5], atol=2e-6)


def bvh_positions(path) -> tuple[list[str], np.ndarray]:
    """Joint and End Site positions of a BVH file, camera frame, metres.

    End Sites become extra joints without channels (named ``<parent>_end``), so the library's
    forward kinematics places them; ``camera_to_y_up`` is undone with C = diag(1, -1, -1).
    """
    bvh = io.read_bvh(path)
    names, parents = list(bvh.names), list(bvh.parents)
    offsets, channels = list(bvh.offsets), list(bvh.channels)
    for j, offset in sorted(bvh.end_sites.items()):
        names.append(f"{bvh.names[j]}_end")
        parents.append(j)
        offsets.append(offset)
        channels.append(())
    pos = io.bvh_forward_kinematics(np.asarray(parents), np.asarray(offsets), channels, bvh.motion)
    return names, pos / 100.0 * np.array([1.0, -1.0, -1.0])  # centimetres, y-up -> camera


def test_bvh_round_trip_matches_model_keypoints(cli, poses):
    summary = json.loads((cli.out / "summary.json").read_text())
    shape = posetrack.BodyShape.create(**summary["shape"])
    fk = np.asarray(jax.vmap(body.keypoints, in_axes=(None, 0))(shape, poses["params"]))
    names, pos = bvh_positions(cli.out / "motion.bvh")
    pairs = list(BVH_KEYPOINTS.items())
    assert len(pairs) == 13  # neck, shoulders, elbows, wrists, hips, knees, ankles: all joints
    for name, k in pairs:
        err = np.linalg.norm(pos[:, names.index(name)] - fk[:, k], axis=-1).max()
        assert err < 1e-3, (name, err)
    # ... and the tracked frames' keypoints in poses.npz are those of the same model.
    np.testing.assert_allclose(poses["keypoints3d"][:, body.BODY_JOINTS], fk[:, body.BODY_JOINTS],
                               atol=1e-4)  # fmt: skip


def test_overlay_has_every_frame(cli):
    video = cli.out / "overlay.mp4"
    assert video_codec(video) == "avc1"  # H.264: browsers and Jupyter play it
    capture = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    assert len(frames) == N_FRAMES
    assert frames[0].shape == (240, 320 + 240, 3)  # the image and the side view


def test_summary_and_printout(cli, poses):
    summary = json.loads((cli.out / "summary.json").read_text())
    counts = {s: int(np.sum(poses["status"] == s)) for s in io.STATUSES}
    assert summary["frames"] == N_FRAMES and summary["status_counts"] == counts
    assert summary["method"] == METHOD and summary["hypotheses"] == HYPOTHESES
    assert summary["config"]["num_hypotheses"] == HYPOTHESES
    assert summary["shape"]["thigh"] > 0.2
    assert summary["timing"]["track_s"] > 0 and summary["files"]["overlay"] == "overlay.mp4"
    assert (
        f"{N_FRAMES} frames: {counts['tracked']} tracked, {counts['lost']} lost, "
        f"{counts['no_observation']} without observation" in cli.stdout
    )
    assert f"wrote {cli.out}/" in cli.stdout
    assert "note: intrinsics: plain layout, 320x240" in cli.stderr
    assert "note: keypoints: COCO-18" in cli.stderr
    # Left/right relabelling runs offline by default; the clean clip needs none kept.
    assert summary["inputs"]["fix_sides"] is True and set(summary["sides_exchanged"]) == {
        "arms", "legs", "torso"
    }
    # No track loss on the clean clip: no re-initialisation overrode the detector's labels.
    assert summary["facing_kept_at_reinit"] == [] and "keeping the lost track" not in cli.stdout
    # Offline: per limb, the frames the motion model started from the neighbours' pose.
    assert set(summary["limbs_interpolated"]) == set(posetrack.LIMB_NAMES)
    assert all(isinstance(n, int) for n in summary["limbs_interpolated"].values())
    # Offline (the default) refines the body shape against the depth of a few frames.
    refit = summary["shape_refinement"]
    assert summary["inputs"]["refine_shape"] is True and refit["refined"] is True
    assert len(refit["refined_on_frames"]) >= 3 and max(refit["refined_on_frames"]) < N_FRAMES
    assert all(0.6 < v < 1.6 for k, v in refit["factors"].items() if k != "shoulder_drop")
    assert "body shape refined against the depth of" in cli.stdout


def edited_runs(rec, tmp_path, edit, variants) -> dict:
    """Frames 4-11 of the recording's keypoint files edited by ``edit(kp)`` (a list of 18
    ``[x, y, confidence]``, changed in place), then tracked once per ``name: extra flags`` of
    ``variants`` (no video): ``{name: (summary, stdout)}``."""
    edited = tmp_path / "keypoints"
    shutil.copytree(rec / "keypoints", edited)
    for f in sorted(edited.glob("*.json"))[4:12]:
        doc = json.loads(f.read_text())
        flat = doc["people"][0]["pose_keypoints_2d"]
        kp = [flat[3 * i : 3 * i + 3] for i in range(len(flat) // 3)]
        edit(kp)
        doc["people"][0]["pose_keypoints_2d"] = [v for k in kp for v in k]
        f.write_text(json.dumps(doc))
    runs = {}
    for name, extra in variants.items():
        args = track_args(rec, tmp_path / name, "--no-video", *extra)
        args[args.index("--keypoints") + 1] = edited
        code, stdout, stderr = run_cli(*args)
        assert code == 0, stderr
        runs[name] = (json.loads((tmp_path / name / "summary.json").read_text()), stdout)
    return runs


def test_fix_sides_undoes_a_detector_arm_swap(rec, tmp_path):
    # Arms exchanged by the detector in frames 4-11: undone by default (offline, the depth
    # agreeing) and with the flag, kept with --no-fix-sides.
    def swap_arms(kp):
        for a, b in posetrack.SIDE_GROUPS["arms"]:
            kp[a], kp[b] = kp[b], kp[a]

    variants = {
        "fix": ("--fix-sides", "--no-refine-shape"), "default": (), "off": ("--no-fix-sides",)
    }  # fmt: skip
    runs = edited_runs(rec, tmp_path, swap_arms, variants)
    summary, stdout = runs["fix"]
    assert summary["sides_exchanged"]["arms"] >= 6 and summary["sides_exchanged"]["legs"] == 0
    assert "left/right swaps of the detector undone (frames): arms" in stdout
    assert summary["shape_refinement"]["refined"] is False and "body shape" not in stdout
    summary, stdout = runs["default"]
    assert summary["inputs"]["fix_sides"] is True and summary["sides_exchanged"]["arms"] >= 6
    judged = summary["sides_arbitrated"]
    assert any(s["kept"] and s["start"] <= 4 < s["stop"] for s in judged), judged
    assert all(s["kept"] == (s["delta_exchanged"] < s["delta_detected"]) for s in judged)
    summary, stdout = runs["off"]
    assert summary["inputs"]["fix_sides"] is False
    assert summary["sides_exchanged"] is None and "undone" not in stdout


def test_a_keypoint_on_another_is_dropped_unless_kept(rec, tmp_path):
    # Frames 4-11: the left ankle reported on the neck (a detector's wrong peak). Offline
    # (the default) it is withheld while it stays there; --keep-duplicates fits it as given.
    def ankle_on_neck(kp):
        kp[13][:2] = [kp[1][0] + 2.0, kp[1][1] - 1.0]  # left ankle (13) on the neck (1)

    variants = {
        "default": ("--no-refine-shape",), "kept": ("--no-refine-shape", "--keep-duplicates")
    }  # fmt: skip
    runs = edited_runs(rec, tmp_path, ankle_on_neck, variants)
    summary, stdout = runs["default"]
    assert summary["inputs"]["drop_duplicates"] is True
    # The 8 of the ankle, and (this clip's detector outliers) 10 of a nose back from a
    # two-frame outlier beside the eyes (DuplicateSettings.settle).
    assert summary["detections_dropped"] == 18
    assert "keypoint detections dropped (jumped onto another keypoint): 18" in stdout
    summary, stdout = runs["kept"]
    assert summary["inputs"]["drop_duplicates"] is False and summary["detections_dropped"] == 0
    assert "detections dropped" not in stdout


# -- tracking over time -----------------------------------------------------------------------


def test_keypoints_vanish_then_return(seq, tmp_path):
    kp, conf = seq.keypoints2d.copy(), seq.confidence.copy()
    gone = list(VANISH_START + VANISH_MIDDLE)
    kp[gone], conf[gone] = 0.0, 0.0  # the detector found nobody: files with no people
    rec = posetrack.synth.save(
        dataclasses.replace(seq, keypoints2d=kp, confidence=conf), tmp_path / "rec"
    )
    code, _, stderr = run_cli(*track_args(rec, tmp_path / "out", "--no-video", "--no-refine-shape"))
    assert code == 0, stderr
    assert "note: keypoints: nobody detected in 5 frame(s) (0-1, 7-9)" in stderr
    poses = io.read_poses_npz(tmp_path / "out" / "poses.npz")
    status = poses["status"]
    assert (status[gone] == "no_observation").all()
    # Tracking resumes as soon as the person returns and holds. One later frame may be flagged
    # "lost": at frame 15 of this sequence both wrists lift onto the background (about 2 m of
    # depth error), the fitted pose is genuinely off, and "lost" is the honest flag for it.
    after = status[10:]
    assert after[0] == "tracked" and np.mean(after == "tracked") >= 0.8, after
    assert np.isfinite(poses["params"]).all()  # never a NaN pose, not even before frame 2
    # Before the first estimate nothing is known: NaN keypoints, zero confidence; in the gap
    # the last pose is held, with zero confidence.
    assert np.isnan(poses["keypoints3d"][list(VANISH_START)]).all()
    assert np.isfinite(poses["keypoints3d"][list(VANISH_MIDDLE)]).all()
    assert (poses["confidence"][gone] == 0).all()
    acc = posetrack.accuracy(poses["keypoints3d"][10:], seq.joints3d[10:])
    assert acc.mean_mm < 80.0, acc
    empty = json.loads((tmp_path / "out" / "keypoints3d" / "000000.json").read_text())
    assert empty == []  # EasyMocap: nobody estimated in that frame


def test_detector_on_the_wrong_spot_is_lost_then_recovered(seq, tmp_path):
    """The 2D detections jump 90 px sideways for 7 frames (a detector latched onto something
    else): they are farther from the track than the association gate, so they are not taken
    for the followed person (no fit: Delta NaN) and the frames are flagged lost; the track is
    dropped after lost_patience frames, and tracking recovers when the right keypoints
    return."""
    wrong = slice(4, 11)
    kp, conf = seq.keypoints2d.copy(), seq.confidence.copy()
    kp[wrong, :, 0] += 90.0
    inside = (kp[..., 0] >= 0) & (kp[..., 0] <= 319)
    kp, conf = np.where(inside[..., None], kp, 0.0), np.where(inside, conf, 0.0)
    rec = posetrack.synth.save(
        dataclasses.replace(seq, keypoints2d=kp, confidence=conf), tmp_path / "rec"
    )
    code, _, stderr = run_cli(*track_args(rec, tmp_path / "out", "--no-video", "--no-refine-shape"))
    assert code == 0, stderr
    poses = io.read_poses_npz(tmp_path / "out" / "poses.npz")
    status = poses["status"]
    assert (status[:4] == "tracked").all()
    assert (status[wrong] == "lost").all(), status
    assert np.isnan(poses["delta"][wrong]).all()
    assert (status[13:] == "tracked").all(), status
    acc = posetrack.accuracy(poses["keypoints3d"][13:], seq.joints3d[13:])
    assert acc.mean_mm < 150.0, acc
    assert np.isfinite(poses["params"]).all()


def test_allow_missing_flags_frames(rec, tmp_path):
    copy = tmp_path / "rec"
    shutil.copytree(rec, copy)
    (copy / "depth" / "000005.png").unlink()
    (copy / "keypoints" / "000012_keypoints.json").unlink()
    code, _, stderr = run_cli(*track_args(copy, tmp_path / "out", "--allow-missing", "--no-video",
                                          "--no-refine-shape"))  # fmt: skip
    assert code == 0, stderr
    status = io.read_poses_npz(tmp_path / "out" / "poses.npz")["status"]
    assert status[5] == "no_observation" and status[12] == "no_observation"
    assert (np.delete(status, [5, 12]) == "tracked").all()


def test_the_offline_work_after_the_bar_is_announced(rec, tmp_path):
    """Without --quiet the tracking bar is followed by a line saying what runs once it is
    full (offline: the body-shape refinement and the motion model, seconds on 2 cores); the
    per-frame mode has nothing after its bar."""

    def loud(out, *extra):
        return [a for a in track_args(rec, tmp_path / out, "--no-video", *extra) if a != "--quiet"]

    code, _, stderr = run_cli(*loud("offline", "--no-refine-shape"))
    assert code == 0, stderr
    lines = stderr.splitlines()
    i = lines.index(f"offline: smoothing the motion over all {N_FRAMES} frames")
    assert lines[i - 1].startswith(f"tracking: 100% {N_FRAMES}/{N_FRAMES}"), lines
    code, _, stderr = run_cli(*loud("per-frame", "--per-frame"))
    assert code == 0, stderr
    assert "tracking: 100%" in stderr and "offline:" not in stderr


def test_depth_overlay_without_rgb(rec, tmp_path):
    args = track_args(rec, tmp_path / "out", "--no-refine-shape", "--video-panel", "none")
    code, _, stderr = run_cli(*args)
    assert code == 0, stderr
    capture = cv2.VideoCapture(str(tmp_path / "out" / "overlay.mp4"))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == N_FRAMES
    assert capture.get(cv2.CAP_PROP_FRAME_WIDTH) == 320  # --video-panel none: the image alone


# -- --detect ---------------------------------------------------------------------------------


def fake_detect_module(monkeypatch, **attrs):
    """Install ``posetrack.detect`` as a stand-in module (None: not importable at all)."""
    module = None
    if attrs:
        module = types.ModuleType("posetrack.detect")
        module.__dict__.update(attrs)
    monkeypatch.setitem(sys.modules, "posetrack.detect", module)
    if module is None:  # `from . import detect` would find an already imported attribute
        monkeypatch.delattr(posetrack, "detect", raising=False)
    else:
        monkeypatch.setattr(posetrack, "detect", module, raising=False)


@pytest.mark.parametrize("installed", ["nothing", "no mediapipe"])
def test_detect_without_extra_says_how_to_install(installed, rec, tmp_path, monkeypatch):
    if installed == "nothing":
        fake_detect_module(monkeypatch)
    else:  # posetrack.detect imports, MediaPipe does not
        fake_detect_module(monkeypatch, available=lambda: False, detect_keypoints=None)
    args = without_keypoints(track_args(rec, tmp_path / "out", "--rgb", rec / "rgb", "--detect"))
    code, _, stderr = run_cli(*args)
    assert code == 2
    assert "pip install \".[detect]\"" in stderr and stderr.startswith("error: ")
    assert "note:" not in stderr  # failed before loading the recording
    assert not (tmp_path / "out").exists()


def test_detect_needs_rgb(rec, tmp_path):
    code, _, stderr = run_cli(*track_args(rec, tmp_path / "out"), "--detect")
    assert code == 2 and "--detect needs --rgb" in stderr


def test_detect_feeds_the_detector_output_to_the_tracker(seq, rec, cli, poses, tmp_path,
                                                         monkeypatch):  # fmt: skip
    calls = []

    def detect_keypoints(rgb_frames, *, progress=True):
        calls.append((len(rgb_frames), progress))
        np.testing.assert_array_equal(rgb_frames[3], seq.rgb[3])
        return seq.keypoints2d.copy(), seq.confidence.copy()

    fake_detect_module(monkeypatch, detect_keypoints=detect_keypoints)
    args = track_args(rec, tmp_path / "out", "--rgb", rec / "rgb", "--detect", "--no-video")
    code, _, stderr = run_cli(*without_keypoints(args))
    assert code == 0, stderr
    assert calls == [(N_FRAMES, False)]  # --quiet: no progress bar
    detected = io.read_poses_npz(tmp_path / "out" / "poses.npz")
    # Same 2D keypoints as the OpenPose files hold: the same track.
    np.testing.assert_allclose(detected["keypoints3d"], poses["keypoints3d"], atol=1e-5)
    # The detector's keypoints are saved as OpenPose JSON: a repeat needs no detector.
    saved = sorted((tmp_path / "out" / "keypoints2d").iterdir())
    assert [p.name for p in saved] == [f"{i:06d}_keypoints.json" for i in range(N_FRAMES)]
    frame5 = io.read_openpose_json(saved[5], out_of_image="drop")
    seen = seq.confidence[5] > 0
    np.testing.assert_allclose(frame5.confidence, seq.confidence[5], atol=1e-6)
    np.testing.assert_allclose(frame5.keypoints2d[seen], seq.keypoints2d[5][seen], atol=1e-3)
    again = track_args(rec, tmp_path / "again", "--no-video")
    again[again.index("--keypoints") + 1] = str(tmp_path / "out" / "keypoints2d")
    code, _, stderr = run_cli(*again)
    assert code == 0, stderr
    repeated = io.read_poses_npz(tmp_path / "again" / "poses.npz")
    np.testing.assert_array_equal(repeated["keypoints3d"], detected["keypoints3d"])


# -- bad input --------------------------------------------------------------------------------


def _truncate(rec):
    p = rec / "depth" / "000003.png"
    p.write_bytes(p.read_bytes()[:-2000])
    return "000003.png", "truncated"


def _eight_bit(rec):
    cv2.imwrite(str(rec / "depth" / "000004.png"), np.full((240, 320), 90, np.uint8))
    return "000004.png", "IHDR.bit_depth: is an 8-bit"


def _not_openpose(rec):
    (rec / "keypoints" / "000002_keypoints.json").write_text(json.dumps({"bodies": []}))
    return "000002_keypoints.json", "no 'people' key"


def _empty_json(rec):
    (rec / "keypoints" / "000002_keypoints.json").write_text("")
    return "000002_keypoints.json", "is empty (0 bytes)"


def _size_mismatch(rec):
    p = rec / "intrinsics.json"
    p.write_text(json.dumps({**json.loads(p.read_text()), "width": 640, "height": 480}))
    return "000000.png", "depth image is 320x240 but"


def _missing(rec):
    (rec / "depth" / "000005.png").unlink()
    (rec / "keypoints" / "000012_keypoints.json").unlink()
    return "lacks 1 frame(s): 5", "lacks 1 frame(s): 12"


def _no_frames(rec):
    shutil.rmtree(rec / "depth")
    (rec / "depth").mkdir()
    return "depth: frames", "no depth frames"


def _outside(rec):
    p = rec / "keypoints" / "000006_keypoints.json"
    data = json.loads(p.read_text())
    data["people"][0]["pose_keypoints_2d"][3 * 4] = 5000.0  # RWrist u
    p.write_text(json.dumps(data))
    return "000006_keypoints.json", "u=5000"


def _nan(rec):
    p = rec / "keypoints" / "000007_keypoints.json"
    data = json.loads(p.read_text())
    data["people"][0]["pose_keypoints_2d"][3 * 4 + 1] = float("nan")
    p.write_text(json.dumps(data))  # Python writes the non-standard literal NaN
    return "pose_keypoints_2d[13]", "is nan"


@pytest.mark.parametrize(
    "damage",
    [_truncate, _eight_bit, _not_openpose, _empty_json, _size_mismatch, _missing, _no_frames,
     _outside, _nan],
    ids=lambda f: f.__name__.strip("_"),
)  # fmt: skip
def test_bad_input_is_one_error_line_and_no_output(damage, rec, tmp_path):
    copy = tmp_path / "rec"
    shutil.copytree(rec, copy)
    expected = damage(copy)
    code, stdout, stderr = run_cli(*track_args(copy, tmp_path / "out"))
    assert code == 2
    assert stdout == ""
    lines = stderr.strip().splitlines()
    assert len([ln for ln in lines if ln.startswith("error: ")]) == 1, stderr
    assert "Traceback" not in stderr
    for text in expected:
        assert text in lines[-1], (text, lines[-1])
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["rec"]  # no hidden temporary folder either


def test_drop_outside_turns_the_error_into_a_missing_keypoint(rec, tmp_path):
    copy = tmp_path / "rec"
    shutil.copytree(rec, copy)
    _outside(copy)
    code, _, stderr = run_cli(*track_args(copy, tmp_path / "out", "--drop-outside", "--no-video",
                                          "--no-refine-shape"))  # fmt: skip
    assert code == 0, stderr
    assert "outside the image marked missing in 1 frame(s) (6)" in stderr
    assert io.read_poses_npz(tmp_path / "out" / "poses.npz")["status"][6] == "tracked"


def test_out_folder_with_foreign_data_is_refused_before_tracking(rec, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    code, _, stderr = run_cli(*track_args(rec, out))
    assert code == 2 and "not written by posetrack" in stderr
    assert "tracking" not in stderr  # failed before loading and tracking
    assert [p.name for p in out.iterdir()] == ["thesis.tex"]


# -- atomicity --------------------------------------------------------------------------------


def test_ctrl_c_while_tracking_writes_nothing(rec, tmp_path, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("posetrack._tracker.Tracker.run", interrupted)
    code, stdout, stderr = run_cli(*track_args(rec, tmp_path / "out"))
    assert code == 130 and "nothing was written" in stderr and stdout == ""
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_while_writing_leaves_the_previous_output(cli, rec, tmp_path, monkeypatch):
    out = tmp_path / "out"
    shutil.copytree(cli.out, out)
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("posetrack.app._export.write_overlay", interrupted)
    code, _, stderr = run_cli(*track_args(rec, out, "--no-refine-shape"))
    assert code == 130 and "interrupted" in stderr
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # temporary folder removed


def test_warmup_fills_the_cache_for_a_configuration():
    """``posetrack warmup`` builds the programs of a configuration into the cache (the
    session's: conftest points ``POSETRACK_CACHE_DIR`` into pytest's cache folder)."""
    from posetrack import _programs

    code, stdout, stderr = run_cli("warmup", "--size", "160x120", "--method", "lvm", "--per-frame")
    assert code == 0, stderr
    assert "warmup: lvm, 1 hypothesis, 160x120, per-frame: ready in" in stdout
    folder = _programs.cache_dir()
    assert folder is not None
    # ``posetrack track`` runs its steps in chunks (Tracker.chunk): that program, not update's.
    names = {p.name.split("-")[0] for p in folder.iterdir()}
    assert {"step_chunk", "lift", "initial_fit"} <= names


def test_warmup_needs_a_camera_and_a_sane_size():
    code, _, stderr = run_cli("warmup", "--method", "lvm")
    assert code == 2 and "--intrinsics FILE or --size WxH" in stderr
    with pytest.raises(SystemExit) as e, contextlib.redirect_stderr(stdio.StringIO()) as err:
        main(["warmup", "--size", "4x3"])
    assert e.value.code == 2 and "at least 8x8" in err.getvalue()


# -- --frame floor, TRC, H.264 ----------------------------------------------------------------


def test_floor_frame_outputs(rec, seq, cli, poses, tmp_path):
    out = tmp_path / "floor"
    code, stdout, stderr = run_cli(*track_args(rec, out, "--frame", "floor", "--rgb", rec / "rgb"))
    assert code == 0, stderr
    assert "(floor frame)" in stdout and "markers.trc" in stdout
    assert video_codec(out / "overlay.mp4") == "avc1"
    fl = io.read_poses_npz(out / "poses.npz")
    assert str(fl["frame"]) == "floor" and str(poses["frame"]) == "camera"
    np.testing.assert_allclose(poses["world_from_camera"], np.eye(4))
    M = fl["world_from_camera"]
    # The same track, moved rigidly: camera-frame poses map onto the floor-frame ones.
    cam = poses["keypoints3d"].astype(np.float64)
    np.testing.assert_allclose(cam @ M[:3, :3].T + M[:3, 3], fl["keypoints3d"], atol=1e-5)
    # Its y axis is the synthetic scene's floor normal, and heights are heights above it.
    n, d = seq.floor_plane[:3], seq.floor_plane[3]
    assert np.degrees(np.arccos(np.clip(M[1, :3] @ n, -1, 1))) < 3.0
    truth_height = seq.joints3d @ n + d
    err = np.nanmedian(np.abs(fl["keypoints3d"][..., 1] - truth_height))
    assert err < 0.06, err
    first = int(np.flatnonzero(fl["status"] == "tracked")[0])
    np.testing.assert_allclose(fl["params"][first, [0, 2]], 0.0, atol=1e-6)  # origin below
    assert 0.7 < fl["params"][first, 1] < 1.2  # a standing pelvis
    # Parameters pose the body in the floor frame; the BVH holds floor coordinates (y up).
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frame"]["name"] == "floor"
    shape = posetrack.BodyShape.create(**summary["shape"])
    fk = np.asarray(jax.vmap(body.keypoints, in_axes=(None, 0))(shape, fl["params"]))
    np.testing.assert_allclose(fl["keypoints3d"][:, body.BODY_JOINTS], fk[:, body.BODY_JOINTS],
                               atol=1e-4)  # fmt: skip
    names, pos = bvh_positions(out / "motion.bvh")
    pos = pos * np.array([1.0, -1.0, -1.0])  # bvh_positions maps y-up to the camera's axes
    err = np.linalg.norm(pos[:, names.index("RightFoot")] - fk[:, 10], axis=-1).max()
    assert err < 1e-3, err
    # The TRC has the floor-frame keypoints in metres, gaps where not estimated.
    trc = io.read_trc(out / "markers.trc")
    assert trc["units"] == "m" and trc["names"] == list(io.COCO18_NAMES)
    np.testing.assert_allclose(trc["markers"], fl["keypoints3d"], atol=2e-6)


def test_floor_frame_without_a_floor_is_one_error_line(rec, tmp_path, monkeypatch):
    monkeypatch.setattr("posetrack._tracker.Tracker._fit_floor", lambda self, d, p: NO_FLOOR)
    args = track_args(rec, tmp_path / "o", "--frame", "floor", "--no-video", "--no-refine-shape")
    code, _, stderr = run_cli(*args)
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert code == 2 and len(errors) == 1 and errors[0].startswith("error: floor frame: ")
    assert stderr.splitlines()[-1] == errors[0]
    assert not (tmp_path / "o").exists()


def test_version():
    with pytest.raises(SystemExit) as e, contextlib.redirect_stdout(stdio.StringIO()) as out:
        main(["--version"])
    assert e.value.code == 0 and out.getvalue().strip() == f"posetrack {posetrack.__version__}"


# -- keypoints at the wrong resolution ---------------------------------------------------------


@pytest.fixture(scope="module")
def half_size_rec(rec, tmp_path_factory):
    """The recording with OpenPose keypoints as if detected on half-size colour images."""
    half = tmp_path_factory.mktemp("half") / "rec"
    shutil.copytree(rec, half)
    for path in sorted((half / "keypoints").glob("*.json")):
        doc = json.loads(path.read_text())
        for person in doc["people"]:
            xyc = np.asarray(person["pose_keypoints_2d"], np.float64).reshape(-1, 3)
            xyc[:, :2] = (xyc[:, :2] + 0.5) * 0.5 - 0.5  # pixel centres stay centres
            person["pose_keypoints_2d"] = xyc.reshape(-1).tolist()
        path.write_text(json.dumps(doc))
    return half


def test_half_size_keypoints_are_refused_with_the_fix(half_size_rec, tmp_path):
    code, _, stderr = run_cli(*track_args(half_size_rec, tmp_path / "o", "--no-video"))
    assert code == 2 and "top-left quadrant" in stderr and "--keypoints-scale 2" in stderr
    assert stderr.count("error:") == 1 and not (tmp_path / "o").exists()


def test_keypoints_scale_rescales(half_size_rec, cli, poses, tmp_path):
    out = tmp_path / "o"
    code, _, stderr = run_cli(
        *track_args(half_size_rec, out, "--no-video", "--keypoints-scale", "2")
    )
    assert code == 0, stderr
    assert "multiplied by 2" in stderr
    scaled = io.read_poses_npz(out / "poses.npz")
    np.testing.assert_allclose(scaled["keypoints3d"], poses["keypoints3d"], atol=2e-3)
    # ... and 1 means "as they are": no refusal (the track then finds little).
    args = track_args(half_size_rec, tmp_path / "p", "--no-video", "--keypoints-scale", "1",
                      "--no-refine-shape")  # fmt: skip
    code, _, stderr = run_cli(*args)
    assert code == 0, stderr


@pytest.mark.parametrize("command", ["track", "track-many", "warmup"])
def test_online_flag_waits_the_default_lag_unless_told(command):
    required = {
        "track": ["--out", "o", "--depth", "d"],
        "track-many": ["--out", "o", "--manifest", "m.csv"],
        "warmup": ["--size", "320x240"],
    }[command]

    def parse(*flags):
        args = build_parser().parse_args([command, *required, *flags])
        return _mode(args), _lag(args)

    assert parse("--online") == ("online", posetrack.ONLINE_LAG) == ("online", 3)
    assert parse("--online", "0") == ("online", 0)
    assert parse("--online", "4") == ("online", 4)
    assert parse() == ("offline", 0) and parse("--per-frame") == ("per-frame", 0)


@pytest.mark.parametrize("command", ["track", "track-many", "warmup"])
def test_shape_prepass_flag_sets_the_offline_pre_pass_and_refuses_other_modes(command):
    required = {
        "track": ["--out", "o", "--depth", "d"],
        "track-many": ["--out", "o", "--manifest", "m.csv"],
        "warmup": ["--size", "320x240"],
    }[command]

    def refine(*flags):
        return _refine(build_parser().parse_args([command, *required, *flags]))

    assert refine() == "auto" and refine("--no-refine-shape") is None
    shipped = posetrack.ShapeFitSettings.tracking("offline")
    assert refine("--shape-prepass", "40") == dataclasses.replace(shipped, offline_first=40)
    for flag, match in (
        ("--online", "offline mode's"), ("--per-frame", "offline mode's"),
        ("--no-refine-shape", "does not go with --no-refine-shape"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=f"--shape-prepass 40 .*{match}"):
            refine("--shape-prepass", "40", flag)
    with pytest.raises(ValueError, match="--shape-prepass 4: .*offline_first must be 0 or >= "):
        refine("--shape-prepass", "4")
    # --shape-prepass-below X: the pre-pass's gate; it needs the pre-pass and a share in (0, 1].
    assert refine("--shape-prepass", "40", "--shape-prepass-below", "0.6") == dataclasses.replace(
        shipped, offline_first=40, offline_first_below=0.6
    )  # fmt: skip
    with pytest.raises(ValueError, match="--shape-prepass-below 0.6 gates .*needs --shape-prep"):
        refine("--shape-prepass-below", "0.6")
    with pytest.raises(ValueError, match="--shape-prepass 40 --shape-prepass-below 1.5: .*below"):
        refine("--shape-prepass", "40", "--shape-prepass-below", "1.5")


@pytest.mark.parametrize("command", ["track", "track-many"])
def test_both_ways_and_one_way_flags_set_the_offline_passes(command):
    required = {
        "track": ["--out", "o", "--depth", "d"],
        "track-many": ["--out", "o", "--manifest", "m.csv"],
    }[command]

    def motion(*flags):
        return _motion(build_parser().parse_args([command, *required, *flags]))

    assert motion() == posetrack.SmoothSettings()
    assert motion("--both-ways").both_ways is True
    assert motion("--one-way").both_ways is False
    for flags in (("--both-ways", "--online"), ("--one-way", "--per-frame")):
        with pytest.raises(ValueError, match=f"{flags[0]} applies offline only"):
            motion(*flags)
    with pytest.raises(SystemExit):  # one or the other
        build_parser().parse_args([command, *required, "--both-ways", "--one-way"])
