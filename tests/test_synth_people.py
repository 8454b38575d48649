"""Two-person scenes in posetrack.synth: a bystander crossing the view, leaving and returning.

One 60-frame 160x120 clip at 15 fps (4 s: pass 1 in front, pass 2 behind for this seed), made
once per module with and without the bystander.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest

import posetrack.synth as ps
from posetrack import io

W, H, T, FPS, SEED = 160, 120, 60, 15.0, 6
NEW_FIELDS = ("people2d", "people_confidence", "people_index", "others_joints3d")

# sha256 of generate(3, motion="wave", n_frames=6, width=160, height=120), computed on the
# generator BEFORE two-person scenes were added (commit 2ac0d52): the option must not change
# any single-person output. (A NumPy or platform change that alters float rounding would
# change these too; then recompute them from a checkout of that commit.)
BEFORE = {
    "depth": "b7e008cfe5e3d99cdf28861a9c93240adaadb8a300c1d8f9584da01dcf8a3351",
    "keypoints2d": "ee9a7ef5eb3d1592b4ccccc1f74ae5dd759b0bcfb7ae9e3e90f4eacaf496e086",
    "confidence": "526759ad9e14f51f655bf76a9f40df1f2c6e8b7d83b930e81b3ff46bb2a3246f",
    "joints3d": "49db73f1847e4b57dfa06026a4903d0cd674d33982b9310a1009d2821ae14585",
    "rgb": "5dbe5c22fa5b1dc161df28710c21eaf2416020eb0da758fbb5218b74a7d1fad3",
    "visible": "181fcc5c3e67808d4b6930fd755bfa9a83fa0f3e94a720211e86d1c40256234c",
    "person_mask": "9ad9f27049c732f47cb19ab5798a2835169e0dcee78f9e8aedd19d8d037d25ed",
}


@pytest.fixture(scope="module")
def pair() -> tuple[ps.SyntheticSequence, ps.SyntheticSequence]:
    """(without, with) bystander, same seed and arguments."""
    kw = dict(motion="wave", n_frames=T, fps=FPS, width=W, height=H)
    return ps.generate(SEED, **kw), ps.generate(SEED, bystander=True, **kw)


def _bystander_slot(seq: ps.SyntheticSequence) -> np.ndarray:
    """(T,) slot of the bystander in people2d, -1 where it is not listed."""
    listed = np.any(seq.people_confidence > 0, axis=-1)
    n = listed.sum(axis=1)
    main = seq.people_index
    slot = np.full(seq.n_frames, -1)
    slot[(n == 2)] = 1 - main[n == 2]
    slot[(n == 1) & (main < 0)] = 0
    return slot


def test_single_person_output_is_bit_identical_to_before():
    seq = ps.generate(3, motion="wave", n_frames=6, width=160, height=120)
    for name, digest in BEFORE.items():
        data = np.ascontiguousarray(getattr(seq, name))
        assert hashlib.sha256(data.tobytes()).hexdigest() == digest, name
    off = ps.generate(3, motion="wave", n_frames=6, width=160, height=120, bystander=False)
    for name in (*BEFORE, *NEW_FIELDS):
        np.testing.assert_array_equal(getattr(off, name), getattr(seq, name), err_msg=name)
    assert seq.meta["bystander"] is None


def test_single_person_people_fields(pair):
    one, _ = pair
    assert one.people2d.shape == (T, 1, 18, 2) and one.people2d.dtype == np.float32
    assert one.people_confidence.shape == (T, 1, 18)
    assert one.others_joints3d.shape == (T, 0, 18, 3)
    np.testing.assert_array_equal(one.people2d[:, 0], one.keypoints2d)
    np.testing.assert_array_equal(one.people_confidence[:, 0], one.confidence)
    np.testing.assert_array_equal(one.people_index, np.where(one.confidence.any(-1), 0, -1))


def test_constructing_without_people_fields_derives_one_person(pair):
    one, _ = pair
    fields = {f.name: getattr(one, f.name) for f in dataclasses.fields(one)
              if f.name not in NEW_FIELDS}
    seq = ps.SyntheticSequence(**fields)
    for name in NEW_FIELDS:
        np.testing.assert_array_equal(getattr(seq, name), getattr(one, name), err_msg=name)
        assert getattr(seq, name).dtype == getattr(one, name).dtype, name


def test_two_person_shapes_and_meta(pair):
    _, two = pair
    assert two.people2d.shape == (T, 2, 18, 2) and two.people2d.dtype == np.float32
    assert two.people_confidence.shape == (T, 2, 18)
    assert two.people_confidence.dtype == np.float32
    assert two.people_index.shape == (T,) and two.people_index.dtype == np.int64
    assert two.others_joints3d.shape == (T, 1, 18, 3) and two.others_joints3d.dtype == np.float64
    assert two.keypoints2d.shape == (T, 18, 2) and two.person_mask.shape == (T, H, W)
    b = two.meta["bystander"]
    assert 1.55 <= b["height"] <= 1.95 and 0.8 <= b["speed"] <= 2.0
    p1, p2 = b["passes"]
    assert p1["side"] == "front" and p1["direction"] == -p2["direction"]
    assert p1["depth"] >= 1.2 and p1["depth"] < two.meta["scene"]["person_distance"] - 0.59
    assert p1["frames"][1] < p2["frames"][0]  # out of view in between


def test_people_index_points_at_the_main_person_and_padding_comes_last(pair):
    _, two = pair
    listed = np.any(two.people_confidence > 0, axis=-1)
    n = listed.sum(axis=1)
    for t in range(T):
        assert list(listed[t]) == [True] * n[t] + [False] * (2 - n[t]), t
        assert not two.people2d[t, n[t]:].any() and not two.people_confidence[t, n[t]:].any()
        i = two.people_index[t]
        if i < 0:
            assert not two.confidence[t].any(), t
        else:
            np.testing.assert_array_equal(two.people2d[t, i], two.keypoints2d[t])
            np.testing.assert_array_equal(two.people_confidence[t, i], two.confidence[t])


def test_bystander_enters_leaves_and_returns(pair):
    _, two = pair
    seen = _bystander_slot(two) >= 0
    p1, p2 = two.meta["bystander"]["passes"]
    assert not seen[: p1["frames"][0]].any()  # waits out of view
    assert seen[p1["frames"][0]:p1["frames"][1]].any()
    assert not seen[p1["frames"][1]:p2["frames"][0]].any()  # gone between the passes
    assert seen[p2["frames"][0]:].any()  # back again


def test_detection_order_is_random(pair):
    _, two = pair
    both = np.any(two.people_confidence > 0, axis=-1).all(axis=1)
    assert both.sum() >= 10
    assert set(two.people_index[both]) == {0, 1}


def test_bystander_in_front_hides_the_main_person(pair):
    one, two = pair
    drop = one.visible.mean(axis=1) - two.visible.mean(axis=1)
    assert drop.max() >= 0.2
    assert drop.min() >= 0.0  # another person can only hide keypoints
    # Its pixels only ever disappear from the main person's mask.
    assert not (two.person_mask & ~one.person_mask).any()
    assert (one.person_mask & ~two.person_mask).sum() > 100
    # The hidden keypoints are missed more and trusted less than in the same clip alone.
    hid = one.visible & ~two.visible
    assert hid.sum() >= 10
    assert (two.confidence[hid] == 0).mean() > (one.confidence[hid] == 0).mean()
    assert two.confidence[hid].mean() < one.confidence[hid].mean() - 0.1


def test_nothing_changes_before_the_bystander_enters(pair):
    one, two = pair
    start = two.meta["bystander"]["passes"][0]["frames"][0]
    assert start >= 3
    for name in ("depth", "rgb", "keypoints2d", "confidence", "visible", "person_mask"):
        np.testing.assert_array_equal(getattr(two, name)[:start], getattr(one, name)[:start],
                                      err_msg=name)
    np.testing.assert_array_equal(two.joints3d, one.joints3d)


def test_bystander_behind_is_hidden_by_the_main_person(pair):
    one, two = pair
    p2 = two.meta["bystander"]["passes"][1]
    assert p2["side"] == "behind"
    s, e = p2["frames"]
    np.testing.assert_array_equal(two.visible[s:e], one.visible[s:e])
    assert two.meta["bystander"]["hidden_fraction"][s:e].max() > 0.3


def test_others_joints3d_project_onto_the_bystander_detections(pair):
    _, two = pair
    slot = _bystander_slot(two)
    K = two.intrinsics
    fx, fy, cx, cy = float(K.fx), float(K.fy), float(K.cx), float(K.cy)
    err = []
    for t in np.nonzero(slot >= 0)[0]:
        p = two.others_joints3d[t, 0]
        uv = np.stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy], -1)
        good = two.people_confidence[t, slot[t]] > 0.6
        err += list(np.linalg.norm(two.people2d[t, slot[t]][good] - uv[good], axis=-1))
    err = np.asarray(err)
    assert err.size >= 50
    assert np.median(err) < 2.0 and np.mean(err < 6.0) > 0.9, np.percentile(err, [50, 90])


def test_save_writes_every_listed_person(pair, tmp_path):
    _, two = pair
    dest = ps.save(dataclasses.replace(two, rgb=None), tmp_path / "rec")
    both = np.nonzero(np.any(two.people_confidence > 0, axis=-1).all(axis=1))[0]
    t = int(both[0])
    path = dest / "keypoints" / f"{t:06d}_keypoints.json"
    frame = io.read_openpose_json(path, image_size=(W, H))
    assert frame.num_people == 2
    people = json.loads(path.read_text())["people"]
    for i, person in enumerate(people):
        assert person["person_id"] == [-1]
        flat = np.asarray(person["pose_keypoints_2d"]).reshape(18, 3)
        np.testing.assert_allclose(flat[:, :2], two.people2d[t, i], atol=1e-4)
        np.testing.assert_allclose(flat[:, 2], two.people_confidence[t, i], atol=1e-6)
    gt = np.load(dest / "ground_truth.npz")
    np.testing.assert_array_equal(gt["people_index"], two.people_index)
    np.testing.assert_array_equal(gt["others_joints3d"], two.others_joints3d)
    np.testing.assert_array_equal(gt["joints3d"], two.joints3d)
