"""Frame numbering, pairing and load_recording on a folder shaped like the synthetic generator's."""

import json
import shutil

import cv2
import numpy as np
import pytest

from posetrack import Intrinsics
from posetrack.io import (
    InputError,
    format_ranges,
    frame_number,
    load_recording,
    read_manifest,
    read_rgb,
    write_depth_png,
    write_intrinsics_json,
    write_openpose_json,
    write_rgb,
)

W, H = 64, 48


def _person(rng, conf=0.9):
    xy = rng.uniform([10, 8], [W - 10, H - 8], (18, 2))
    return xy, np.full(18, conf)


def make_recording(folder, frames=range(6), *, rgb=True):
    """The synthetic generator's layout: depth/, rgb/, keypoints/, intrinsics.json."""
    rng = np.random.default_rng(0)
    for sub in ("depth", "rgb", "keypoints"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    k = Intrinsics.create(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=W, height=H)
    write_intrinsics_json(folder / "intrinsics.json", k)
    for t in frames:
        depth = np.full((H, W), 2.0 + 0.001 * t)
        depth[:4] = 0.0
        write_depth_png(folder / "depth" / f"{t:06d}.png", depth)
        if rgb:
            cv2.imwrite(str(folder / "rgb" / f"{t:06d}.png"), np.full((H, W, 3), t, np.uint8))
        write_openpose_json(folder / "keypoints" / f"{t:06d}_keypoints.json", *_person(rng))
    np.savez(folder / "ground_truth.npz", dummy=np.zeros(1))
    return folder


def _load(folder, **kw):
    return load_recording(
        depth_dir=folder / "depth",
        keypoints_dir=folder / "keypoints",
        intrinsics_path=folder / "intrinsics.json",
        **kw,
    )


@pytest.mark.parametrize(
    ("name", "number"),
    [
        ("000012.png", 12),
        ("frame_12.png", 12),
        ("000012_keypoints.json", 12),
        ("000012_rendered.png", 12),
        ("cam2_000012.png", 12),
        ("depth-0007.PNG", 7),
        ("background.png", None),
    ],
)
def test_frame_number_rule(name, number):
    assert frame_number(name) == number


def test_format_ranges():
    assert format_ranges([12, 3, 4, 5, 9]) == "3-5, 9, 12"
    assert format_ranges(range(0, 100, 2), max_ranges=3) == "0, 2, 4, ... (50 frames in 50 ranges)"


def test_loads_the_synthetic_generator_layout(tmp_path):
    folder = make_recording(tmp_path / "rec")
    rec = _load(folder)
    assert rec.frame_ids.tolist() == list(range(6)) and len(rec) == 6
    assert rec.keypoints2d.shape == (6, 18, 2) and rec.keypoints2d.dtype == np.float32
    assert rec.confidence.shape == (6, 18) and rec.observed.all()
    assert rec.intrinsics.width == W and rec.keypoint_layout == "COCO-18"
    assert rec.rgb is None and rec.fps is None
    depth = rec.depth[5]
    assert depth.shape == (H, W) and depth[10, 10] == pytest.approx(2.005, abs=1e-6)
    assert np.all(depth[:4] == 0)
    assert any("plain" in n for n in rec.notes)
    with pytest.raises(ValueError):
        rec.confidence[0, 0] = 1.0  # read-only
    rec = _load(folder, rgb=folder / "rgb")
    assert rec.rgb[3].shape == (H, W, 3) and rec.rgb[3][0, 0, 0] == 3


def test_folder_with_no_frames(tmp_path):
    folder = make_recording(tmp_path / "rec")
    shutil.rmtree(folder / "depth")
    (folder / "depth").mkdir()
    (folder / "depth" / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="no depth frames") as info:
        _load(folder)
    assert info.value.path == str(folder / "depth") and info.value.field == "frames"
    assert "notes.txt" in str(info.value)
    with pytest.raises(InputError, match="does not exist"):
        load_recording(depth_dir=tmp_path / "nope", intrinsics_path=folder / "intrinsics.json")


def test_depth_size_must_match_intrinsics(tmp_path):
    folder = make_recording(tmp_path / "rec")
    write_depth_png(folder / "depth" / "000003.png", np.ones((24, 32)))
    with pytest.raises(InputError) as info:
        _load(folder)
    message = str(info.value)
    assert info.value.path == str(folder / "depth" / "000003.png")
    assert "32x24" in message and "64x48" in message and "intrinsics.json" in message
    assert info.value.value == (32, 24)


def test_missing_frames_are_listed_or_allowed(tmp_path):
    folder = make_recording(tmp_path / "rec", frames=range(12))
    for t in (3, 4, 5, 9):
        (folder / "keypoints" / f"{t:06d}_keypoints.json").unlink()
    (folder / "depth" / "000011.png").unlink()
    with pytest.raises(InputError, match="3-5, 9") as info:
        _load(folder)
    assert "allow_missing" in str(info.value) and "lacks 1 frame(s): 11" in str(info.value)
    rec = _load(folder, allow_missing=True)
    assert rec.frame_ids.tolist() == list(range(12))
    assert np.flatnonzero(~rec.observed).tolist() == [3, 4, 5, 9, 11]
    assert np.all(rec.confidence[[3, 4, 5, 9]] == 0)
    assert np.all(rec.depth[11] == 0) and rec.depth[10].max() > 0
    assert any("allow_missing" in n for n in rec.notes)


def test_duplicate_frame_numbers(tmp_path):
    folder = make_recording(tmp_path / "rec")
    shutil.copy(folder / "depth" / "000002.png", folder / "depth" / "frame_2.png")
    with pytest.raises(InputError, match="frame 2 appears twice") as info:
        _load(folder)
    assert "000002.png" in str(info.value) and "frame_2.png" in str(info.value)
    assert info.value.value == 2


def test_file_without_a_number_is_named(tmp_path):
    folder = make_recording(tmp_path / "rec")
    shutil.copy(folder / "depth" / "000002.png", folder / "depth" / "background.png")
    with pytest.raises(InputError, match="no frame number") as info:
        _load(folder)
    assert info.value.value == "background.png"


def test_other_json_beside_openpose_files_is_ignored_with_a_note(tmp_path):
    folder = make_recording(tmp_path / "rec")
    (folder / "keypoints" / "params.json").write_text("{}")
    (folder / "keypoints" / "camera_3.json").write_text("{}")  # would collide with frame 3
    rec = _load(folder)
    assert rec.frame_ids.tolist() == list(range(6))
    assert any("ignored 2 file(s)" in n and "camera_3.json" in n for n in rec.notes), rec.notes


def test_json_without_the_openpose_suffix_is_still_read(tmp_path):
    folder = make_recording(tmp_path / "rec")
    for p in (folder / "keypoints").iterdir():
        p.rename(p.with_name(p.name.replace("_keypoints", "")))
    rec = _load(folder)
    assert rec.frame_ids.tolist() == list(range(6)) and rec.observed.all()
    assert not any("ignored" in n for n in rec.notes)


def test_bad_depth_file_is_caught_before_tracking(tmp_path):
    folder = make_recording(tmp_path / "rec")
    path = folder / "depth" / "000004.png"
    path.write_bytes(path.read_bytes()[:-30])
    with pytest.raises(InputError, match="truncated") as info:
        _load(folder)
    assert info.value.path == str(path)


def test_keypoints_outside_the_image_through_the_loader(tmp_path):
    folder = make_recording(tmp_path / "rec")
    xy, conf = _person(np.random.default_rng(1))
    xy[2] = [3 * W, H / 2]  # e.g. keypoints detected on a larger colour image
    write_openpose_json(folder / "keypoints" / "000001_keypoints.json", xy, conf)
    with pytest.raises(InputError, match="outside the 64x48 image"):
        _load(folder)
    rec = _load(folder, out_of_image="drop")
    assert rec.confidence[1, 2] == 0 and any("outside the image" in n for n in rec.notes)


def test_multi_person_and_nobody_are_reported(tmp_path):
    folder = make_recording(tmp_path / "rec")
    rng = np.random.default_rng(2)
    big, conf = _person(rng)
    small = 30 + 0.1 * (big - 30)
    write_openpose_json(
        folder / "keypoints" / "000002_keypoints.json",
        np.stack([small, big]), np.stack([conf, conf]), person_ids=[5, 6],
    )  # fmt: skip
    nobody = folder / "keypoints" / "000004_keypoints.json"
    write_openpose_json(nobody, np.zeros((0, 18, 2)), np.zeros((0, 18)))
    rec = _load(folder)
    assert rec.person_index[2] == 1 and rec.num_people[2] == 2
    np.testing.assert_allclose(rec.keypoints2d[2], big, rtol=1e-6)
    assert not rec.observed[4] and rec.observed[[0, 1, 2, 3, 5]].all()
    assert any("several people in 1 frame(s) (2)" in n for n in rec.notes)
    assert any("nobody detected in 1 frame(s) (4)" in n for n in rec.notes)
    # Every listed person, in file order, padded to the most people in a frame.
    assert rec.people2d.shape == (6, 2, 18, 2) and rec.people_confidence.shape == (6, 2, 18)
    np.testing.assert_allclose(rec.people2d[2], np.stack([small, big]), rtol=1e-6)
    np.testing.assert_allclose(rec.people2d[0, 0], rec.keypoints2d[0])
    assert not rec.people_confidence[[0, 1, 3, 5], 1].any() and not rec.people_confidence[4].any()
    rec = _load(folder, person_id=5)
    assert rec.person_index[2] == 0 and not rec.observed[[0, 1, 3, 4, 5]].any()
    assert rec.people2d.shape == (6, 1, 18, 2)
    np.testing.assert_allclose(rec.people2d[2, 0], small, rtol=1e-6)
    with pytest.raises(InputError, match="no keypoint file lists") as info:
        _load(folder, person_id=42)
    assert info.value.field == "person_id" and info.value.value == 42


def test_mixed_keypoint_layouts(tmp_path):
    folder = make_recording(tmp_path / "rec")
    body25 = np.zeros((25, 3))
    body25[:, :2], body25[:, 2] = [20.0, 20.0], 0.5
    doc = {"people": [{"pose_keypoints_2d": body25.ravel().tolist()}]}
    (folder / "keypoints" / "000003_keypoints.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="layout BODY_25 differs from COCO-18"):
        _load(folder)


def test_rgb_must_be_registered_to_depth(tmp_path):
    folder = make_recording(tmp_path / "rec")
    cv2.imwrite(str(folder / "rgb" / "000000.png"), np.zeros((2 * H, 2 * W, 3), np.uint8))
    with pytest.raises(InputError, match="registered") as info:
        _load(folder, rgb=folder / "rgb")
    assert info.value.value == (2 * W, 2 * H)


def test_rgb_video(tmp_path):
    folder = make_recording(tmp_path / "rec", rgb=False)
    video = tmp_path / "colour.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (W, H))
    assert writer.isOpened()
    for t in range(6):
        writer.write(np.full((H, W, 3), 40 * t, np.uint8))
    writer.release()
    rec = _load(folder, rgb=video)
    assert rec.fps == pytest.approx(30.0)
    frames = list(rec.rgb)
    assert len(frames) == 6 and frames[0].shape == (H, W, 3)
    assert abs(int(frames[5][10, 10, 0]) - 200) < 10 and abs(int(rec.rgb[2][10, 10, 0]) - 80) < 10
    (folder / "depth" / "000005.png").unlink()
    (folder / "keypoints" / "000005_keypoints.json").unlink()
    with pytest.raises(InputError, match="video has 6 frames but the recording has 5"):
        _load(folder, rgb=video)


def test_write_rgb_round_trip_keeps_rgb_order(tmp_path):
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    write_rgb(tmp_path / "c.png", image)
    np.testing.assert_array_equal(read_rgb(tmp_path / "c.png"), image)
    # On disk as any image tool sees it: OpenCV reads BGR, so the channels come reversed.
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "c.png"))[..., ::-1], image)
    with pytest.raises(ValueError, match="uint8"):
        write_rgb(tmp_path / "f.png", image.astype(np.float32))
    with pytest.raises(ValueError, match="uint8"):
        write_rgb(tmp_path / "g.png", image[..., 0])
    with pytest.raises(ValueError, match="cannot encode"):
        write_rgb(tmp_path / "c.notanimage", image)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.png"]


def _intri_yml(path, cameras):
    """EasyMocap-style intri.yml (no image size) written by cv2.FileStorage."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("names", list(cameras))
    for name, (fx, cx, cy) in cameras.items():
        fs.write(f"K_{name}", np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1]]))
        fs.write(f"dist_{name}", np.array([[0.05, 0, 0, 0, 0]]))
    fs.release()
    return path


def test_intrinsics_without_a_size_take_the_depth_images(tmp_path):
    folder = make_recording(tmp_path / "rec")
    intri = _intri_yml(folder / "intri.yml", {"01": (60.0, 31.5, 23.5), "02": (70.0, 30.0, 20.0)})
    rec = load_recording(
        depth_dir=folder / "depth", keypoints_dir=folder / "keypoints",
        intrinsics_path=f"{intri}#02",
    )  # fmt: skip
    k = rec.intrinsics
    assert (k.width, k.height, float(k.fx), float(k.cx)) == (W, H, 70.0, 30.0)
    assert rec.notes[0].startswith("intrinsics: EasyMocap intri.yml, camera 02 (OpenCV YAML)")
    assert "64x48 from the depth images (000000.png;" in rec.notes[0], rec.notes[0]
    assert any("dist_02" in n and "ignored" in n for n in rec.notes)
    with pytest.raises(InputError, match="holds 2 cameras") as info:
        load_recording(depth_dir=folder / "depth", intrinsics_path=intri)
    assert info.value.path == str(intri) and f"{intri}#01" in str(info.value)
    # Every depth image must then have the first one's size.
    write_depth_png(folder / "depth" / "000003.png", np.ones((24, 32)))
    with pytest.raises(InputError, match="first depth image") as info:
        load_recording(depth_dir=folder / "depth", intrinsics_path=f"{intri}#01")
    assert info.value.path == str(folder / "depth" / "000003.png")
    assert info.value.value == (32, 24) and "64x48" in str(info.value)


def test_manifest_row_chooses_a_camera_of_a_sizeless_file(tmp_path):
    folder = make_recording(tmp_path / "rec")
    _intri_yml(folder / "intri.yml", {"01": (60.0, 31.5, 23.5), "02": (70.0, 30.0, 20.0)})
    manifest = tmp_path / "m.csv"
    manifest.write_text(
        "name,depth,keypoints,intrinsics\n"
        "a,rec/depth,rec/keypoints,rec/intri.yml#02\n"
        "b,rec/depth,rec/keypoints,rec/intrinsics.json\n"
    )
    a, b = read_manifest(manifest)
    assert str(a.intrinsics_path) == f"{folder / 'intri.yml'}#02"
    assert (a.intrinsics.width, a.intrinsics.height, float(a.intrinsics.fx)) == (W, H, 70.0)
    assert b.intrinsics.fx == 60.0
    manifest.write_text("name,depth,keypoints,intrinsics\na,rec/depth,rec/keypoints,rec/intri.yml")
    with pytest.raises(InputError, match=r"row 2 \(a\): intrinsics: .*holds 2 cameras"):
        read_manifest(manifest)
