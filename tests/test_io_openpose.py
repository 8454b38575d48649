"""OpenPose JSON: layouts, BODY_25 mapping, person choice, and bad files."""

import json

import numpy as np
import pytest

from posetrack.io import (
    BODY25_NAMES,
    COCO18_NAMES,
    InputError,
    read_openpose_json,
    write_openpose_json,
)


def _write(path, people, **extra):
    doc = {"version": 1.3, "people": people, **extra}
    path.write_text(json.dumps(doc))
    return path


def _person(xyc, person_id=-1):
    return {"person_id": [person_id], "pose_keypoints_2d": np.asarray(xyc, float).ravel().tolist()}


def _coco(center=(100.0, 100.0), size=50.0, conf=0.9, n=18):
    rng = np.random.default_rng(int(size))
    xy = np.asarray(center) + rng.uniform(-size / 2, size / 2, (n, 2))
    return np.concatenate([xy, np.full((n, 1), conf)], axis=1)


def test_coco18_file(tmp_path):
    xyc = _coco()
    xyc[3] = 0.0  # OpenPose writes 0, 0, 0 for a missing keypoint
    xyc[5] = [12.0, 13.0, 0.0]  # coordinates but zero confidence: still missing
    f = read_openpose_json(_write(tmp_path / "000012_keypoints.json", [_person(xyc)]))
    assert f.layout == "COCO-18" and f.num_people == 1 and f.person_index == 0 and f.observed
    assert f.keypoints2d.dtype == np.float32 and f.keypoints2d.shape == (18, 2)
    np.testing.assert_allclose(f.keypoints2d[0], xyc[0, :2], rtol=1e-6)
    assert f.confidence[3] == 0 and f.confidence[5] == 0
    assert np.all(f.keypoints2d[[3, 5]] == 0) and not np.isnan(f.keypoints2d).any()
    assert f.notes == ()


def test_body25_maps_to_the_right_coco18_indices(tmp_path):
    # Keypoint k of the BODY_25 person sits at (1000 + k, 2000 + k) with confidence (k + 1) / 100.
    k = np.arange(25.0)
    xyc = np.stack([1000 + k, 2000 + k, (k + 1) / 100], axis=1)
    f = read_openpose_json(_write(tmp_path / "1_keypoints.json", [_person(xyc)]))
    assert f.layout == "BODY_25"
    # Hand-written from the OpenPose docs: COCO-18 index -> BODY_25 index (8 = MidHip, 19-24 feet).
    expected = [0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18]
    np.testing.assert_array_equal(f.keypoints2d[:, 0], 1000 + np.array(expected))
    np.testing.assert_array_equal(f.keypoints2d[:, 1], 2000 + np.array(expected))
    np.testing.assert_allclose(f.confidence, (np.array(expected) + 1) / 100, rtol=1e-6)
    for coco_index, body25_index in enumerate(expected):
        assert COCO18_NAMES[coco_index] == BODY25_NAMES[body25_index]
    assert COCO18_NAMES[8] == "RHip" and f.keypoints2d[8, 0] == 1009  # BODY_25 RHip is 9


def test_zero_people_is_a_frame_without_observation(tmp_path):
    f = read_openpose_json(_write(tmp_path / "2_keypoints.json", []))
    assert f.num_people == 0 and f.person_index == -1 and not f.observed and f.layout is None
    assert np.all(f.confidence == 0)


def test_multi_person_picks_the_large_confident_one_and_reports_it(tmp_path):
    small_sure = _coco(center=(50, 50), size=20, conf=1.0)
    large = _coco(center=(200, 200), size=150, conf=0.6)
    path = _write(tmp_path / "000003_keypoints.json", [_person(small_sure, 4), _person(large, 7)])
    f = read_openpose_json(path)
    assert f.person_index == 1 and f.num_people == 2 and not f.ambiguous
    np.testing.assert_allclose(f.keypoints2d, large[:, :2], rtol=1e-6)
    assert f.scores[1] > f.scores[0]
    assert len(f.notes) == 1 and "chose people[1]" in f.notes[0] and path.name in f.notes[0]
    by_id = read_openpose_json(path, person_id=4)
    assert by_id.person_index == 0 and by_id.notes == ()
    absent = read_openpose_json(path, person_id=99)
    assert absent.person_index == -1 and not absent.observed and "99" in absent.notes[0]


def test_similar_people_are_flagged_ambiguous(tmp_path):
    a = _coco(center=(100, 100), size=80, conf=0.9)
    b = a.copy()
    b[:, 0] += 300
    b[:, 2] = 0.85
    f = read_openpose_json(_write(tmp_path / "4_keypoints.json", [_person(a), _person(b)]))
    assert f.person_index == 0 and f.ambiguous and "AMBIGUOUS" in f.notes[0]


def test_wrong_keypoint_count(tmp_path):
    path = _write(tmp_path / "000012_keypoints.json", [{"pose_keypoints_2d": [1.0] * 53}])
    with pytest.raises(InputError) as info:
        read_openpose_json(path)
    assert str(info.value) == (
        f"{path}: people[0].pose_keypoints_2d: has 53 numbers; expected 54 (COCO-18) or 75 "
        "(BODY_25)"
    )
    assert info.value.field == "people[0].pose_keypoints_2d" and info.value.value == 53


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_nan_and_inf_in_json(tmp_path, literal):
    values = [10.0] * 54
    text = json.dumps({"people": [{"pose_keypoints_2d": values}]})
    text = text.replace("10.0, 10.0, 10.0]", f"10.0, 10.0, {literal}]")  # last confidence
    path = tmp_path / "5_keypoints.json"
    path.write_text(text)
    with pytest.raises(InputError, match="finite") as info:
        read_openpose_json(path)
    assert info.value.field == "people[0].pose_keypoints_2d[53]"
    assert not np.isfinite(info.value.value)


@pytest.mark.parametrize(
    ("content", "field", "match"),
    [
        ("", "file", "empty"),
        ("   \n", "file", "empty"),
        ("{\"people\": [", "line 1 column 13", "not valid JSON"),
        ("<html>", "line 1 column 1", "not valid JSON"),
        ("[1, 2, 3]", "people", "not an OpenPose"),
        ('{"version": 1.3}', "people", "no 'people' key"),
        ('{"people": {"a": 1}}', "people", "not an OpenPose"),
        ('{"people": [[1, 2]]}', "people[0]", "expected an object"),
        ('{"people": [{"face_keypoints_2d": []}]}', "people[0].pose_keypoints_2d", "missing"),
        ('{"people": [{"pose_keypoints_2d": "1,2,3"}]}', "people[0].pose_keypoints_2d", "list"),
    ],
)
def test_not_openpose(tmp_path, content, field, match):
    path = tmp_path / "6_keypoints.json"
    path.write_text(content)
    with pytest.raises(InputError, match=match) as info:
        read_openpose_json(path)
    assert info.value.field == field and str(path) in str(info.value)


def test_non_numeric_and_negative_values(tmp_path):
    values = [1.0] * 54
    values[7] = "12"
    path = _write(tmp_path / "7_keypoints.json", [{"pose_keypoints_2d": values}])
    with pytest.raises(InputError, match="expected a number") as info:
        read_openpose_json(path)
    assert info.value.field == "people[0].pose_keypoints_2d[7]" and info.value.value == "12"
    values[7], values[8] = 1.0, -0.5
    _write(path, [{"pose_keypoints_2d": values}])
    with pytest.raises(InputError, match="negative"):
        read_openpose_json(path)


def test_keypoints_outside_the_image(tmp_path):
    xyc = _coco(center=(100, 100), size=40)
    xyc[4] = [-5.0, 50.0, 0.8]  # 5 px outside: within the margin, kept
    xyc[7] = [900.0, 50.0, 0.7]  # far outside a 640x480 image
    xyc[9] = [2000.0, 2000.0, 0.0]  # missing: never checked
    path = _write(tmp_path / "000012_keypoints.json", [_person(xyc)])
    with pytest.raises(InputError, match="outside the 640x480 image") as info:
        read_openpose_json(path, image_size=(640, 480))
    assert info.value.field == "people[0].pose_keypoints_2d[21:23]"
    assert info.value.value == (900.0, 50.0) and "LWrist" in str(info.value)
    f = read_openpose_json(path, image_size=(640, 480), out_of_image="drop")
    assert f.dropped == (7,) and f.confidence[7] == 0 and np.all(f.keypoints2d[7] == 0)
    assert f.confidence[4] > 0 and f.keypoints2d[4, 0] == -5.0
    assert "LWrist" in f.notes[0]
    assert read_openpose_json(path, image_size=(1000, 480)).confidence[7] > 0


def test_write_openpose_json_round_trip(tmp_path):
    xyc = _coco()
    kp, conf = xyc[:, :2].copy(), xyc[:, 2].copy()
    kp[2], conf[2] = np.nan, 0.0  # a missing keypoint may be NaN in memory
    path = tmp_path / "000000_keypoints.json"
    write_openpose_json(path, kp, conf)
    doc = json.loads(path.read_text())
    assert doc["people"][0]["person_id"] == [-1]
    assert doc["people"][0]["pose_keypoints_2d"][6:9] == [0.0, 0.0, 0.0]
    f = read_openpose_json(path)
    np.testing.assert_allclose(f.keypoints2d[3:], kp[3:], rtol=1e-6)
    np.testing.assert_allclose(f.confidence, conf, rtol=1e-6)
    write_openpose_json(path, np.zeros((0, 18, 2)), np.zeros((0, 18)))
    assert read_openpose_json(path).num_people == 0
    with pytest.raises(ValueError, match="confidence > 0"):
        write_openpose_json(path, np.full((18, 2), np.nan), np.ones(18))
    with pytest.raises(ValueError, match="expected"):
        write_openpose_json(path, np.zeros((17, 2)), np.ones(17))
