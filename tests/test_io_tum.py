"""TUM RGB-D sequences: the lists, association by time stamp, depth scale 5000, the known
cameras, and the errors that name the list and the line."""

import contextlib
import io as stdio

import cv2
import numpy as np
import pytest

from posetrack import Intrinsics
from posetrack.io import (
    TUM_REGISTERED_DEPTH,
    InputError,
    associate_timestamps,
    load_recording,
    load_tum,
    read_tum_list,
    write_intrinsics_json,
    write_openpose_json,
)

W, H = 8, 6
T0 = 1305031102.0
# Colour at ~30 Hz; depth jittered around it. Colour image 2 has no depth within 0.02 s (its
# depth is 0.025 s away, and closer to colour image 3, which has a closer one), so depth image
# 2 pairs with nothing.
RGB_T = [round(T0 + 0.0333 * k, 6) for k in range(5)]
DEPTH_T = [round(t + dt, 6) for t, dt in zip(RGB_T, [0.004, -0.007, 0.025, 0.003, -0.002])]
#: The depth image each colour image pairs with (-1: none).
EXPECTED = [0, 1, -1, 3, 4]


def _stamp(t: float) -> str:
    return f"{t:.6f}"


def make_tum(folder, *, rgb_t=RGB_T, depth_t=DEPTH_T, size=(W, H), keypoints=True):
    """A TUM-shaped sequence: depth image j holds (1 + 0.1 j) m everywhere, at scale 5000;
    colour image k is grey level 10 k; keypoint 0 of frame k lies at x = k + 1."""
    w, h = size
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    rgb_lines = ["# color images", "# file: 'rgbd_dataset_test.bag'", "# timestamp filename"]
    for k, t in enumerate(rgb_t):
        name = f"rgb/{_stamp(t)}.png"
        cv2.imwrite(str(folder / name), np.full((h, w, 3), 10 * k, np.uint8))
        rgb_lines.append(f"{_stamp(t)} {name}")
    depth_lines = ["# depth maps", "# timestamp filename", ""]
    for j, t in enumerate(depth_t):
        name = f"depth/{_stamp(t)}.png"
        cv2.imwrite(str(folder / name), np.full((h, w), 5000 + 500 * j, np.uint16))
        depth_lines.append(f"{_stamp(t)} {name}")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if keypoints:
        (folder / "keypoints").mkdir()
        for k, t in enumerate(rgb_t):
            xy = np.full((18, 2), [w / 2, h / 2])
            xy[0, 0] = k + 1
            path = folder / "keypoints" / f"{_stamp(t)}_keypoints.json"
            write_openpose_json(path, xy, np.full(18, 0.9))
    k = Intrinsics.create(fx=8.0, fy=8.0, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
    write_intrinsics_json(folder / "intrinsics.json", k)
    return folder


def _load(folder, **kw):
    kw.setdefault("keypoints_dir", folder / "keypoints")
    kw.setdefault("intrinsics_path", folder / "intrinsics.json")
    return load_tum(folder, **kw)


def test_associate_is_one_to_one_closest_first():
    # Both colour stamps are within 0.02 s of the one depth stamp; the closer pair wins and
    # the other colour stamp stays unpaired (nearest-neighbour alone would pair both).
    assert associate_timestamps([0.0, 0.010], [0.006]).tolist() == [-1, 0]
    assert associate_timestamps([0.0, 0.010], [0.006], max_difference=0.005).tolist() == [-1, 0]
    assert associate_timestamps([0.0], [0.02]).tolist() == [-1]  # less than, not equal
    assert associate_timestamps([0.0, 1.0], [1.001, 0.019]).tolist() == [1, 0]
    assert associate_timestamps(RGB_T, DEPTH_T).tolist() == EXPECTED
    with pytest.raises(ValueError, match="max_difference"):
        associate_timestamps([0.0], [0.0], max_difference=0)


def test_sequence_is_paired_by_time_stamp_at_scale_5000(tmp_path):
    folder = make_tum(tmp_path / "seq")
    rec = _load(folder)
    assert rec.frame_ids.tolist() == [0, 1, 2, 3, 4]
    np.testing.assert_array_equal(rec.timestamps, np.array(RGB_T))
    assert rec.fps == pytest.approx(1 / 0.0333, rel=1e-3)
    for t, j in enumerate(EXPECTED):
        depth = rec.depth[t]
        assert depth.shape == (H, W)
        if j < 0:
            assert not depth.any() and not rec.observed[t]
        else:  # (5000 + 500 j) / 5000 m: depth image j, read at the benchmark's scale
            np.testing.assert_allclose(depth, 1.0 + 0.1 * j, rtol=1e-6)
            assert rec.observed[t]
        assert rec.keypoints2d[t, 0, 0] == pytest.approx(t + 1)  # the frame's own keypoints
        assert rec.rgb[t][0, 0, 0] == 10 * t  # colour is the sequence's rgb/
    (note,) = [n for n in rec.notes if n.startswith("TUM:")]
    assert "5 colour images" in note and "none close enough for 1 (2)" in note, note
    assert "1 depth image(s) unused" in note
    assert any(n.startswith("intrinsics: plain layout, 8x6") for n in rec.notes)


def test_lists_out_of_time_order_are_sorted(tmp_path):
    folder = make_tum(tmp_path / "seq")
    lines = (folder / "rgb.txt").read_text().splitlines()
    (folder / "rgb.txt").write_text("\n".join(lines[:3] + lines[3:][::-1]) + "\n")
    stamps, files = read_tum_list(folder / "rgb.txt")
    np.testing.assert_array_equal(stamps, np.array(RGB_T))
    assert [f.name for f in files] == [f"{_stamp(t)}.png" for t in RGB_T]
    assert _load(folder).keypoints2d[:, 0, 0].tolist() == [1, 2, 3, 4, 5]


def test_depth_scale_can_be_overridden(tmp_path):
    rec = _load(make_tum(tmp_path / "seq"), depth_scale=1000.0)
    np.testing.assert_allclose(rec.depth[0], 5.0, rtol=1e-6)


def test_wider_max_difference_pairs_the_late_depth(tmp_path):
    rec = _load(make_tum(tmp_path / "seq"), max_difference=0.03)
    assert rec.observed.all()
    np.testing.assert_allclose(rec.depth[2], 1.2, rtol=1e-6)


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("1305031102.175304", "expected 'timestamp filename'"),
        ("1305031102.175304 rgb/a.png extra", "not 3"),
        ("yesterday rgb/a.png", "not a number of seconds"),
        ("nan rgb/a.png", "not a number of seconds"),
        ("1305031102.9 rgb/missing.png", "does not exist"),
        (f"{_stamp(RGB_T[1])} rgb/{_stamp(RGB_T[1])}.png", "also on line 5"),
    ],
)
def test_malformed_list_line_names_file_and_line(tmp_path, line, match):
    folder = make_tum(tmp_path / "seq")
    lines = (folder / "rgb.txt").read_text().splitlines()
    lines.insert(6, line)  # line 7 of the file
    (folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=match) as info:
        _load(folder)
    err = info.value
    assert err.path == str(folder / "rgb.txt") and err.field == "line 7"
    assert str(err).startswith(f"{folder / 'rgb.txt'}: line 7: ")


def test_missing_or_empty_lists(tmp_path):
    folder = make_tum(tmp_path / "seq")
    (folder / "depth.txt").write_text("# depth maps\n\n")
    with pytest.raises(InputError, match="lists no images") as info:
        _load(folder)
    assert info.value.path == str(folder / "depth.txt")
    (folder / "depth.txt").unlink()
    with pytest.raises(InputError, match="no depth.txt") as info:
        _load(folder)
    assert info.value.path == str(folder) and info.value.field == "depth.txt"
    with pytest.raises(InputError, match="does not exist"):
        load_tum(tmp_path / "nowhere")


def test_keypoint_files_must_match_the_colour_images(tmp_path):
    folder = make_tum(tmp_path / "seq")
    gone = folder / "keypoints" / f"{_stamp(RGB_T[3])}_keypoints.json"
    gone.rename(folder / "keypoints" / "1305031199.000000_keypoints.json")
    with pytest.raises(InputError, match="match no image of") as info:
        _load(folder)
    assert "1305031199.000000_keypoints.json" in str(info.value)
    (folder / "keypoints" / "1305031199.000000_keypoints.json").unlink()
    with pytest.raises(InputError, match="no keypoint file for 1 of the 5") as info:
        _load(folder)
    assert info.value.value == [3] and f"{_stamp(RGB_T[3])}_keypoints.json" in str(info.value)
    rec = _load(folder, allow_missing=True)
    assert rec.observed.tolist() == [True, True, False, False, True]
    assert any(n.startswith("allow_missing:") for n in rec.notes)


def test_camera_from_the_folder_name(tmp_path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg2_xyz", size=(640, 480), keypoints=False)
    rec = load_tum(folder)
    k = rec.intrinsics
    assert (k.width, k.height) == (640, 480)
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], TUM_REGISTERED_DEPTH, rtol=1e-6)
    (note,) = [n for n in rec.notes if n.startswith("intrinsics:")]
    assert "freiburg2" in note and "folder name" in note and "520.9" in note
    assert rec.keypoint_layout is None and rec.observed.sum() == 4


def test_no_intrinsics_and_no_camera_in_the_name(tmp_path):
    folder = make_tum(tmp_path / "my_sequence", keypoints=False)
    with pytest.raises(InputError, match="names no TUM camera") as info:
        load_tum(folder)
    assert info.value.path == str(folder) and info.value.field == "intrinsics"
    assert "--intrinsics" in str(info.value)


def test_known_camera_against_images_of_another_size(tmp_path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_walking", keypoints=False)
    with pytest.raises(InputError, match="TUM camera") as info:
        load_tum(folder)
    assert info.value.value == (W, H) and "640x480" in str(info.value)


def test_load_recording_refuses_a_tum_folder(tmp_path):
    folder = make_tum(tmp_path / "seq")
    for depth_dir in (folder, folder / "depth"):
        with pytest.raises(InputError, match="TUM RGB-D sequence") as info:
            load_recording(depth_dir=depth_dir, intrinsics_path=folder / "intrinsics.json")
        assert "--tum" in str(info.value) and "load_tum" in str(info.value)


def _cli(*args):
    from posetrack.app._cli import main

    out, err = stdio.StringIO(), stdio.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def test_cli_tum_bad_input_is_one_error_line(tmp_path):
    folder = make_tum(tmp_path / "my_sequence")
    for args, text in [
        (("--tum", folder, "--keypoints", folder / "keypoints"), "names no TUM camera"),
        (("--tum", folder, "--rgb", folder / "rgb"), "--rgb is not used with --tum"),
        (("--depth", folder / "depth", "--keypoints", folder / "keypoints"), "--intrinsics"),
        (
            ("--depth", folder / "depth", "--intrinsics", folder / "intrinsics.json",
             "--keypoints", folder / "keypoints"),
            "TUM RGB-D sequence",
        ),
    ]:  # fmt: skip
        code, stdout, stderr = _cli("track", *args, "--quiet", "--out", tmp_path / "out")
        assert code == 2 and stdout == "", stderr
        errors = [line for line in stderr.splitlines() if line.startswith("error: ")]
        assert len(errors) == 1 and text in errors[0], stderr
        assert not (tmp_path / "out").exists()


def test_cli_tum_defaults_to_scale_5000(tmp_path, monkeypatch):
    import posetrack.io

    seen = {}

    def stop(folder, **kw):
        seen.update(kw, folder=folder)
        raise InputError(folder, "test", None, "stopped before tracking")

    monkeypatch.setattr(posetrack.io, "load_tum", stop)
    folder = make_tum(tmp_path / "seq")
    args = ("track", "--tum", folder, "--keypoints", folder / "keypoints", "--out", tmp_path / "o")
    code, _, stderr = _cli(*args)
    assert code == 2 and "stopped before tracking" in stderr
    assert seen["depth_scale"] == 5000.0 and seen["max_difference"] == 0.02
    assert seen["intrinsics_path"] is None
    code, _, _ = _cli(*args, "--depth-scale", "1000", "--tum-max-difference", "0.03")
    assert seen["depth_scale"] == 1000.0 and seen["max_difference"] == 0.03


def test_cli_tum_loads_the_sequence_before_tracking(tmp_path, monkeypatch):
    seen = {}

    def run(self, depth, kp2d, conf, progress=None):  # stands in for tracking: no JAX here
        seen.update(depth=depth, conf=conf, intrinsics=self.intrinsics)
        raise KeyboardInterrupt

    monkeypatch.setattr("posetrack._tracker.Tracker.run", run)
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg1_test", size=(640, 480))
    args = ("track", "--tum", folder, "--keypoints", folder / "keypoints", "--quiet")
    code, stdout, stderr = _cli(*args, "--out", tmp_path / "o")
    assert code == 130 and stdout == "" and not (tmp_path / "o").exists(), stderr
    assert "note: intrinsics: TUM freiburg1 (from the folder name" in stderr
    assert "none close enough for 1 (2)" in stderr
    assert seen["depth"].scale == 5000.0 and len(seen["depth"]) == 5
    assert float(seen["intrinsics"].fx) == pytest.approx(TUM_REGISTERED_DEPTH[0])
    assert not seen["conf"][2].any()  # the frame without depth carries no keypoints
