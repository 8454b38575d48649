"""Tests of the synthetic RGB-D generator (posetrack.synth). Small images, few frames."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

import posetrack.synth as ps
from posetrack import io
from posetrack.synth import _mocap, _skeleton

W, H = 160, 120
# Rigid distances (the shoulder width is not: the clavicles move).
BONES = ((2, 3), (3, 4), (5, 6), (6, 7), (8, 9), (9, 10), (11, 12), (12, 13), (8, 11), (1, 2),
         (1, 5), (14, 15), (0, 16))


def _gen(seed=0, **kw):
    kw.setdefault("n_frames", 8)
    kw.setdefault("width", W)
    kw.setdefault("height", H)
    return ps.generate(seed, **kw)


def _bone_lengths(j3d: np.ndarray) -> np.ndarray:
    return np.stack([np.linalg.norm(j3d[:, a] - j3d[:, b], axis=-1) for a, b in BONES], 1)


def _require_data(sub: str) -> Path:
    root = ps.data_root()
    if root is None or not (root / sub).is_dir():
        where = os.environ.get("POSETRACK_DATA") or str(
            Path(_mocap.__file__).resolve().parents[2] / ".." / "shared" / "data")
        pytest.skip(f"real motion data folder missing: {Path(where) / sub}")
    return root


# --- output contract --------------------------------------------------------------------


def test_shapes_dtypes_and_conventions():
    seq = _gen(1, motion="box", n_frames=6, occlusion_level=1)
    T = 6
    assert seq.depth.shape == (T, H, W) and seq.depth.dtype == np.uint16
    assert seq.rgb.shape == (T, H, W, 3) and seq.rgb.dtype == np.uint8
    assert seq.keypoints2d.shape == (T, 18, 2) and seq.keypoints2d.dtype == np.float32
    assert seq.confidence.shape == (T, 18) and seq.confidence.dtype == np.float32
    assert seq.joints3d.shape == (T, 18, 3) and seq.joints3d.dtype == np.float64
    assert seq.visible.shape == (T, 18) and seq.visible.dtype == bool
    assert seq.occluder_masks.shape == (T, H, W) and seq.occluder_masks.dtype == bool
    assert (seq.intrinsics.width, seq.intrinsics.height) == (W, H)
    assert float(seq.intrinsics.fx) == pytest.approx(525.0 * W / 640)
    assert seq.fps == 30.0 and seq.meta["motion"] == "box" and seq.meta["seed"] == 1
    assert 1.55 <= seq.subject["height"] <= 1.95
    # Depth: 0 = invalid, else inside the sensor range (mm).
    d = seq.depth[seq.depth > 0]
    assert d.min() >= 500 and d.max() <= 5500
    # Confidence in [0, 1]; misses are (0, 0, 0) like OpenPose.
    assert seq.confidence.min() >= 0 and seq.confidence.max() <= 1
    miss = seq.confidence == 0
    assert np.all(seq.keypoints2d[miss] == 0)
    # Person 2-3.5 m (up to 4.2 m to fit in the image) in front of the camera.
    z = seq.joints3d[..., 2]
    assert 1.6 < z.mean() < 4.5


def test_deterministic_and_seed_dependent():
    a = _gen(7, motion="wave", occlusion_level=2)
    b = _gen(7, motion="wave", occlusion_level=2)
    for name in ("depth", "rgb", "keypoints2d", "confidence", "joints3d", "visible",
                 "occluder_masks"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    c = _gen(8, motion="wave", occlusion_level=2)
    assert not np.array_equal(a.depth, c.depth)
    assert a.subject["height"] != c.subject["height"]


def test_options_do_not_change_the_subject_or_motion():
    # Independent random streams: occluders/sensor/detector settings leave the body alone.
    a = _gen(3, motion="squat", occlusion_level=0)
    b = _gen(3, motion="squat", occlusion_level=3, sensor_noise=False, detector_noise=False)
    np.testing.assert_array_equal(a.joints3d, b.joints3d)
    assert a.subject == b.subject


def test_bad_arguments_raise_before_work():
    with pytest.raises(ValueError, match="occlusion_level"):
        ps.generate(0, occlusion_level=5)
    with pytest.raises(ValueError, match="motion"):
        ps.generate(0, motion="moonwalk")
    with pytest.raises(ValueError, match="n_frames"):
        ps.generate(0, n_frames=0)
    with pytest.raises(ValueError, match="fps"):
        ps.generate(0, fps=float("nan"))


# --- detector model ---------------------------------------------------------------------


def test_keypoints_are_gt_projections_without_detector_noise():
    seq = _gen(2, motion="reach", detector_noise=False, n_frames=6)
    K = np.array([[float(seq.intrinsics.fx), 0, float(seq.intrinsics.cx)],
                  [0, float(seq.intrinsics.fy), float(seq.intrinsics.cy)], [0, 0, 1]])
    p = seq.joints3d @ K.T
    uv = p[..., :2] / p[..., 2:]
    det = seq.confidence > 0
    assert det.mean() > 0.9
    np.testing.assert_allclose(seq.keypoints2d[det], uv[det], atol=1e-3)


def test_detector_noise_statistics_match_config():
    rng = np.random.default_rng(0)
    T, w = 4000, 320
    gt = np.tile(np.linspace(40, 200, 18)[None, :, None], (T, 1, 2))
    cfg = ps.DetectorConfig(outlier_rate=0.0, swap_rate=0.0, p_miss_visible=0.0, rho=0.5)
    ones, zeros = np.ones((T, 18)), np.zeros((T, 18))
    kp, conf = ps.simulate_detector(rng, gt, ones, zeros, ones.astype(bool), width=w,
                                    height=240, config=cfg)
    err = kp - gt
    expected = cfg.sigma_px * w / 640
    assert np.std(err) == pytest.approx(expected, rel=0.05)
    assert abs(np.mean(err)) < 0.05 * expected
    lag1 = np.corrcoef(err[1:, :, 0].ravel(), err[:-1, :, 0].ravel())[0, 1]
    assert lag1 == pytest.approx(cfg.rho, abs=0.05)
    assert np.all(conf > 0) and conf.mean() == pytest.approx(cfg.conf_visible, abs=0.02)
    # Fully occluded keypoints: mostly missed, lower confidence, larger errors.
    kp2, conf2 = ps.simulate_detector(np.random.default_rng(1), gt, ones, ones,
                                      ones.astype(bool), width=w, height=240, config=cfg)
    miss = conf2 == 0
    assert miss.mean() == pytest.approx(cfg.p_miss_occluder, abs=0.03)
    assert conf2[~miss].mean() < conf.mean() - 0.3
    assert np.all(kp2[miss] == 0)


def test_detector_outliers_and_swaps_happen():
    T = 3000
    gt = np.random.default_rng(1).uniform(20, 300, size=(1, 18, 2)).repeat(T, 0)
    ones = np.ones((T, 18))
    vis = ones.astype(bool)
    # Gross outliers: elsewhere on the body, with a plausible (not certain) confidence.
    cfg = ps.DetectorConfig(outlier_rate=0.01, swap_rate=0.0, p_miss_visible=0.0)
    kp, conf = ps.simulate_detector(np.random.default_rng(0), gt, ones, 0 * ones, vis,
                                    width=320, height=320, config=cfg)
    far = np.linalg.norm(kp - gt, axis=-1) > 5 * cfg.sigma_px
    assert 0.005 < far.mean() < 0.1
    assert np.all(conf[far] <= 0.7 + 1e-6)
    # Left/right swaps: the right wrist reported where the left one is, for a few frames.
    cfg = ps.DetectorConfig(outlier_rate=0.0, swap_rate=0.01, p_miss_visible=0.0)
    kp, conf = ps.simulate_detector(np.random.default_rng(0), gt, ones, 0 * ones, vis,
                                    width=320, height=320, config=cfg)
    swapped = np.linalg.norm(kp[:, 4] - gt[:, 7], axis=-1) < 5 * cfg.sigma_px
    assert 0.01 < swapped.mean() < 0.2
    np.testing.assert_array_equal(swapped, np.linalg.norm(kp[:, 7] - gt[:, 4], axis=-1)
                                  < 5 * cfg.sigma_px)
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, swapped.astype(int), 0])))[::2]
    assert runs.mean() > 2  # episodes last several frames


# --- sensor model -----------------------------------------------------------------------


def test_sensor_noise_grows_with_depth_on_a_flat_wall():
    cfg = ps.SensorConfig(holes_per_frame=0.0)
    fx = fy = 262.5
    stds = []
    for z in (1.5, 3.5):
        clean = np.full((H, W), z)
        out = ps.simulate_sensor(np.random.default_rng(0), clean, fx=fx, fy=fy, cx=79.5,
                                 cy=59.5, config=cfg)
        ok = out > 0
        assert ok.mean() > 0.99
        err = out[ok] / 1000.0 - z
        stds.append(err.std())
        expected = np.sqrt(cfg.sigma(np.array(z)) ** 2 + cfg.quantization_step(z) ** 2 / 12)
        assert stds[-1] == pytest.approx(expected, rel=0.35)
        assert abs(err.mean()) < 0.3 * expected
    assert stds[1] > 2.5 * stds[0]
    # Out of range -> 0.
    far = ps.simulate_sensor(np.random.default_rng(0), np.full((H, W), 7.0), fx=fx, fy=fy,
                             cx=79.5, cy=59.5, config=cfg)
    assert np.all(far == 0)


def test_sensor_quantisation_steps_grow_as_z_squared():
    cfg = ps.SensorConfig(noise_a=0.0, noise_b=0.0, holes_per_frame=0.0)
    zs = np.linspace(2.9, 3.1, W)[None, :].repeat(H, 0)
    out = ps.simulate_sensor(np.random.default_rng(0), zs, fx=100.0, fy=100.0, cx=80, cy=60,
                             config=cfg)
    levels = np.unique(out[out > 0]).astype(float) / 1000
    steps = np.diff(levels)
    assert np.median(steps) == pytest.approx(float(cfg.quantization_step(3.0)), rel=0.1)


def test_projector_shadow_band_left_of_foreground():
    z = np.full((H, W), 5.0)
    z[30:90, 70:100] = 2.0
    fx = 262.5
    sh = ps.projector_shadow(z, fx, 0.075)
    expected = fx * 0.075 * (1 / 2.0 - 1 / 5.0)  # px
    row = sh[60]
    cols = np.nonzero(row)[0]
    assert cols.size > 0 and cols.max() < 70  # on the left of the box, not on it
    assert cols.size == pytest.approx(expected, abs=1.5)
    assert not sh[:30].any() and not sh[90:].any()


def test_generated_depth_has_kinect_artifacts():
    noisy = _gen(4, motion="idle", n_frames=3)
    clean = _gen(4, motion="idle", n_frames=3, sensor_noise=False)
    pm = clean.person_mask
    # Same geometry; invalid pixels appear only with the sensor model (edges, shadows, holes).
    assert (noisy.depth == 0).mean() > (clean.depth == 0).mean() + 0.005
    both = (noisy.depth > 0) & (clean.depth > 0) & pm
    diff = noisy.depth[both].astype(float) - clean.depth[both]
    assert 2 < np.median(np.abs(diff)) < 40  # mm: axial noise + quantisation at 2-4 m
    # Jagged silhouettes: some body-edge pixels take the background depth (lateral noise).
    assert 0.001 < np.mean(np.abs(diff) > 300) < 0.1


# --- the Fig. 2 lifting error comes from the rendering --------------------------------------


@pytest.mark.parametrize("motion", ["walk_across", "box"])
def test_lifting_gt_projection_lands_in_front_of_joint(motion):
    seq = _gen(5, motion=motion, n_frames=10, sensor_noise=False, detector_noise=False)
    uv = np.round(seq.joints2d).astype(int)
    gaps, per_joint = [], {}
    for t in range(seq.n_frames):
        for k in range(1, 14):  # body joints (the face points lie on the surface)
            if not seq.visible[t, k]:
                continue
            u, v = uv[t, k]
            if not seq.person_mask[t, v, u] or seq.depth[t, v, u] == 0:
                continue
            gap = seq.joints3d[t, k, 2] - seq.depth[t, v, u] / 1000.0
            gaps.append(gap)
            per_joint.setdefault(k, []).append(gap)
    gaps = np.array(gaps)
    assert gaps.size > 50
    assert np.mean(gaps > 0) > 0.95  # the seen surface is in front of the joint centre
    assert 0.02 < np.median(gaps) < 0.12  # ~ the limb/torso radius
    # Thick parts (hips, neck) lift farther in front than thin ones (wrists).
    thick = np.median(per_joint.get(8, []) + per_joint.get(11, []) + per_joint.get(1, []))
    thin = np.median(per_joint.get(4, []) + per_joint.get(7, []))
    assert thick > thin


def test_face_keypoints_lie_on_the_surface():
    seq = _gen(6, motion="idle", n_frames=4, sensor_noise=False, detector_noise=False,
               yaw_deg=0.0)
    uv = np.round(seq.joints2d).astype(int)
    t = np.arange(seq.n_frames)
    k = 0  # nose
    d = seq.depth[t, uv[t, k, 1], uv[t, k, 0]] / 1000.0
    assert np.all(np.abs(seq.joints3d[t, k, 2] - d) < 0.02)


# --- occluders ----------------------------------------------------------------------------


def test_occlusion_coverage_increases_with_level():
    cover = []
    for level in range(5):
        c = []
        for seed in (9, 19, 29):
            seq = _gen(seed, motion="walk", n_frames=10, occlusion_level=level,
                       sensor_noise=False)
            pm = seq.person_mask
            c.append((seq.occluder_masks & pm).sum() / pm.sum())
            assert np.all(seq.depth[seq.occluder_masks] == 0)
            assert np.all(seq.rgb[seq.occluder_masks] == 0)
        cover.append(np.mean(c))
    assert cover[0] == 0
    assert all(b > a for a, b in zip(cover, cover[1:], strict=False)), cover
    assert 0.04 < cover[1] < 0.35 and cover[4] > 0.3


def test_occluders_persist_instead_of_flickering():
    seq = _gen(10, motion="idle", n_frames=20, occlusion_level=3, sensor_noise=False,
               detector_noise=False, with_rgb=False)
    m = seq.occluder_masks
    inter = (m[1:] & m[:-1]).sum(axis=(1, 2))
    union = (m[1:] | m[:-1]).sum(axis=(1, 2))
    assert np.median(inter / union) > 0.8


def test_occluded_keypoints_are_mostly_missed():
    seq = _gen(11, motion="box", n_frames=20, occlusion_level=4)
    uv = np.round(seq.joints2d).astype(int)
    under = np.zeros(seq.visible.shape, bool)
    for t in range(seq.n_frames):
        for k in range(18):
            u, v = uv[t, k]
            if 0 <= u < W and 0 <= v < H:
                under[t, k] = seq.occluder_masks[t, v, u]
    assert under.sum() > 10
    assert not seq.visible[under].any()
    assert (seq.confidence[under] == 0).mean() > 0.5
    assert (seq.confidence[seq.visible] > 0).mean() > 0.9


def test_self_occlusion_lowers_visibility_and_confidence():
    seq = _gen(12, motion="turn", n_frames=60, width=W, height=H)
    hidden = ~seq.visible & (seq.meta["occluded_fraction"] == 0)
    assert hidden.sum() > 10  # turning to a side view hides the far side
    assert seq.confidence[hidden].mean() < seq.confidence[seq.visible].mean() - 0.15


# --- motion and retargeting -----------------------------------------------------------------


@pytest.mark.parametrize("motion", ps.MOTIONS)
def test_procedural_motions_keep_bone_lengths_and_feet_on_floor(motion):
    seq = _gen(13, motion=motion, n_frames=30, sensor_noise=False, detector_noise=False,
               with_rgb=False)
    L = _bone_lengths(seq.joints3d)
    assert np.all(L.std(axis=0) < 1e-9)
    # Smooth: joint accelerations stay human (< 60 m/s^2 at 30 fps).
    acc = np.diff(seq.joints3d, 2, axis=0) * seq.fps**2
    assert np.abs(acc).max() < 60
    # Ankles never below the floor (floor plane in the camera frame).
    n, d = seq.floor_plane[:3], seq.floor_plane[3]
    ankle_h = seq.joints3d[:, [10, 13]] @ n + d
    assert ankle_h.min() > 0.03


def test_subjects_vary_with_seed():
    h = [ps.generate(s, n_frames=1, width=64, height=48).subject for s in range(6)]
    heights = [x["height"] for x in h]
    assert max(heights) - min(heights) > 0.1
    assert len({round(x["upper_arm"] / x["height"], 4) for x in h}) > 3


def _angle(a, b, c):
    u, v = a - b, c - b
    cos = np.sum(u * v, -1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_cmu_retarget_keeps_joint_angles_and_bone_lengths():
    root = _require_data("cmu-mocap-bvh-subject131")
    seq = _gen(14, motion="cmu:131_02", n_frames=24, sensor_noise=False, detector_noise=False,
               with_rgb=False, motion_start=3.0)
    assert np.all(_bone_lengths(seq.joints3d).std(axis=0) < 1e-9)
    bvh = io.read_bvh(root / "cmu-mocap-bvh-subject131" / "131_02.bvh")
    pos = io.bvh_forward_kinematics(bvh.parents, bvh.offsets, bvh.channels, bvh.motion)
    fps = 1.0 / bvh.frame_time
    idx = np.round((3.0 + np.arange(24) / 30.0) * fps).astype(int)
    p = {n: pos[idx, bvh.names.index(n)] for n in ("LeftHip", "LeftKnee", "LeftAnkle",
                                                   "RightShoulder", "RightElbow", "RightWrist")}
    knee_data = _angle(p["LeftHip"], p["LeftKnee"], p["LeftAnkle"])
    knee_gen = _angle(seq.joints3d[:, 11], seq.joints3d[:, 12], seq.joints3d[:, 13])
    elbow_data = _angle(p["RightShoulder"], p["RightElbow"], p["RightWrist"])
    elbow_gen = _angle(seq.joints3d[:, 2], seq.joints3d[:, 3], seq.joints3d[:, 4])
    assert np.max(np.abs(knee_data - knee_gen)) < 2.0
    assert np.max(np.abs(elbow_data - elbow_gen)) < 2.0
    # The generated subject keeps its own proportions, not CMU's.
    thigh_gen = np.linalg.norm(seq.joints3d[0, 11] - seq.joints3d[0, 12])
    assert thigh_gen == pytest.approx(seq.subject["thigh"], rel=1e-9)


@pytest.mark.parametrize("name", ["msr:a02_s01_e01", "utk:s01_e01:waveHands"])
def test_kinect_motions_retarget_with_constant_bones(name):
    _require_data("msr-action3d-skeleton3d" if name.startswith("msr") else
                  "utkinect-action3d-joints")
    assert name in ps.list_real_motions()
    seq = _gen(15, motion=name, n_frames=20, sensor_noise=False, detector_noise=False,
               with_rgb=False)
    assert np.all(_bone_lengths(seq.joints3d).std(axis=0) < 1e-9)
    n, d = seq.floor_plane[:3], seq.floor_plane[3]
    assert (seq.joints3d[:, [10, 13]] @ n + d).min() > 0.03
    assert seq.visible.mean() > 0.6


def test_msr_torso_is_upright_despite_its_spine_marker():
    # MSR Action3D's spine joint lies ~40 degrees off the hip-neck line; built from it, the
    # pelvis tipped back ~35 degrees and the chest forward ~50 (a contorted torso).
    _require_data("msr-action3d-skeleton3d")
    m, _, _ = _mocap.load_markers("msr:a05_s02_e01")
    mid_hip = 0.5 * (m["hip_l"] + m["hip_r"])
    axis = m["neck"] - mid_hip
    raw = np.median(_angle(m["spine"], mid_hip, m["neck"]))
    assert raw > _mocap.SPINE_MAX_DEG  # the data's marker: the case being handled
    spine = _mocap.torso_spine(m)
    assert np.max(_angle(spine, mid_hip, m["neck"])) < 1e-3  # on the hip-neck line
    assert np.allclose(np.sum((spine - mid_hip) * axis, -1),
                       np.sum((m["spine"] - mid_hip) * axis, -1))  # at the marker's height
    subject = _skeleton.sample_subject(np.random.default_rng(0))
    R, _ = _mocap.retarget(m, subject)
    pelvis_y = R[:, _mocap.SEG["pelvis"], :, 1]
    chest_y = R[:, _mocap.SEG["chest"], :, 1]
    bend = np.degrees(np.arccos(np.clip(np.sum(pelvis_y * chest_y, -1), -1, 1)))
    assert np.median(bend) < 10.0
    # UTKinect's spine marker is on the line already: kept as it is.
    _require_data("utkinect-action3d-joints")
    u, _, _ = _mocap.load_markers("utk:s01_e01:waveHands")
    assert _mocap.torso_spine(u) is u["spine"]


def test_kinect_legs_are_relabelled_where_they_cross_their_hips():
    # Frames 1 and 2 have the knee chain (knee, ankle, toe) labelled against the hips, frame 3
    # only the ankle and toe against the knees; frame 0 is right; frame 4 has the knees
    # crossed by less than the margin (a narrow stance): left as it is.
    hip_l, hip_r = np.array([0.1, 1.0, 0.0]), np.array([-0.1, 1.0, 0.0])
    right = {"hip_l": hip_l, "hip_r": hip_r, "knee_l": [0.12, 0.55, 0.0],
             "knee_r": [-0.12, 0.55, 0.0], "ankle_l": [0.12, 0.1, 0.0],
             "ankle_r": [-0.12, 0.1, 0.0], "toe_l": [0.12, 0.0, 0.15],
             "toe_r": [-0.12, 0.0, 0.15]}  # fmt: skip
    m = {k: np.tile(np.asarray(v, float), (5, 1)) for k, v in right.items()}
    for j in ("knee", "ankle", "toe"):  # frames 1, 2: the whole leg chain exchanged
        m[f"{j}_l"][1:3], m[f"{j}_r"][1:3] = right[f"{j}_r"], right[f"{j}_l"]
    for j in ("ankle", "toe"):  # frame 3: below the knee only
        m[f"{j}_l"][3], m[f"{j}_r"][3] = right[f"{j}_r"], right[f"{j}_l"]
    m["knee_l"][4], m["knee_r"][4] = [-0.005, 0.55, 0.0], [0.005, 0.55, 0.0]
    fixed, counts = _mocap._consistent_legs(m)
    assert counts == [2, 1]
    for k in right:
        assert np.allclose(fixed[k][:4], right[k]), k
        assert np.array_equal(fixed[k][4], m[k][4]), k  # within the margin: unchanged
    assert m["knee_l"][1][0] < 0  # the input is not modified


def test_msr_subject_two_stands_on_uncrossed_legs():
    # MSR Action3D's Kinect tracker labels subject 2's knees against the hips (the thighs
    # through each other on every frame); loaded, the knees sit on their own hips' sides.
    _require_data("msr-action3d-skeleton3d")
    m, _, info = _mocap.load_markers("msr:a05_s02_e01")
    assert info["knees_relabelled"] == len(m["knee_l"])
    lateral = m["hip_l"] - m["hip_r"]
    assert np.all(np.sum((m["knee_l"] - m["knee_r"]) * lateral, -1) > 0)
    assert np.all(np.sum((m["ankle_l"] - m["ankle_r"]) * lateral, -1) > 0)


def test_data_root_respects_env(tmp_path, monkeypatch):
    monkeypatch.setenv("POSETRACK_DATA", str(tmp_path))
    assert ps.data_root() == tmp_path.resolve()
    assert ps.list_real_motions() == []
    monkeypatch.setenv("POSETRACK_DATA", str(tmp_path / "missing"))
    assert ps.data_root() is None
    assert ps.list_real_motions() == []
    with pytest.raises(FileNotFoundError, match="POSETRACK_DATA"):
        ps.generate(0, motion="cmu:131_01", n_frames=2, width=64, height=48)


# --- writing ---------------------------------------------------------------------------------


def test_save_writes_recording_layout_readable_back(tmp_path):
    seq = _gen(16, motion="wave", n_frames=3, occlusion_level=1)
    dest = ps.save(seq, tmp_path / "rec")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]  # no temp folder left
    for t in range(3):
        d = cv2.imread(str(dest / "depth" / f"{t:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert d.dtype == np.uint16
        np.testing.assert_array_equal(d, seq.depth[t])
        rgb = cv2.cvtColor(cv2.imread(str(dest / "rgb" / f"{t:06d}.png")), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(rgb, seq.rgb[t])
        js = json.loads((dest / "keypoints" / f"{t:06d}_keypoints.json").read_text())
        assert js["version"] == 1.3
        (person,) = js["people"]
        assert person["person_id"] == [-1]
        flat = np.asarray(person["pose_keypoints_2d"]).reshape(18, 3)
        np.testing.assert_allclose(flat[:, :2], seq.keypoints2d[t], atol=1e-4)
        np.testing.assert_allclose(flat[:, 2], seq.confidence[t], atol=1e-6)
    intr = json.loads((dest / "intrinsics.json").read_text())
    assert intr == seq.intrinsics.to_dict()
    gt = np.load(dest / "ground_truth.npz")
    np.testing.assert_array_equal(gt["joints3d"], seq.joints3d)
    np.testing.assert_array_equal(gt["visible"], seq.visible)
    assert float(gt["fps"]) == seq.fps
    with pytest.raises(FileExistsError):
        ps.save(seq, dest)
    ps.save(seq, dest, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_save_is_atomic_on_failure(tmp_path, monkeypatch):
    seq = _gen(17, n_frames=3)
    import posetrack.synth._write as wr

    calls = {"n": 0}
    real = wr.write_depth_png

    def flaky(path, depth, **kw):
        calls["n"] += 1
        if calls["n"] > 2:
            raise OSError("disk full")
        return real(path, depth, **kw)

    monkeypatch.setattr(wr, "write_depth_png", flaky)
    with pytest.raises(OSError, match="disk full"):
        ps.save(seq, tmp_path / "rec")
    assert calls["n"] == 3
    assert list(tmp_path.iterdir()) == []


def test_frame_without_detections_is_saved_with_no_person(tmp_path):
    seq = _gen(18, motion="wave", n_frames=2, with_rgb=False)
    conf = seq.confidence.copy()
    conf[1] = 0.0
    dest = ps.save(dataclasses.replace(seq, confidence=conf), tmp_path / "rec")
    js = json.loads((dest / "keypoints" / "000001_keypoints.json").read_text())
    assert js == {"version": 1.3, "people": []}
    assert not (dest / "rgb").exists()
    rec = io.load_recording(depth_dir=dest / "depth", keypoints_dir=dest / "keypoints",
                            intrinsics_path=dest / "intrinsics.json")
    assert list(rec.num_people) == [1, 0] and list(rec.observed) == [True, False]


def test_overwrite_replaces_only_a_folder_written_by_posetrack(tmp_path):
    seq = _gen(19, n_frames=1, with_rgb=False)
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"not ours")
    with pytest.raises(FileExistsError, match="not written by posetrack"):
        ps.save(seq, foreign, overwrite=True)
    assert (foreign / "holiday.jpg").read_bytes() == b"not ours"


# --- geometry internals ----------------------------------------------------------------------


def _round_cone_sdf_ish(p: np.ndarray, a, b, ra, rb) -> np.ndarray:
    """min over the segment of |p - c(s)| - r(s): <= 0 exactly inside the convex hull of the
    two spheres (dense s grid; error < 1 mm here)."""
    s = np.linspace(0, 1, 401)
    c = a[None] + s[:, None] * (b - a)[None]
    r = ra + s * (rb - ra)
    d = np.linalg.norm(p[:, None, :] - c[None], axis=-1) - r[None]
    return d.min(axis=1)


def test_round_cone_ray_cast_is_exact():
    from posetrack.synth._surface import _hit_round_cone

    rng = np.random.default_rng(0)
    n_hit = 0
    for _ in range(12):
        a = rng.uniform([-0.3, -0.3, 2.0], [0.3, 0.3, 3.0])
        b = a + rng.normal(size=3) * 0.25
        ra, rb = rng.uniform(0.03, 0.09), rng.uniform(0.02, 0.07)
        centre = 0.5 * (a + b)
        rays = centre / centre[2] + rng.normal(size=(16, 3)) * 0.04
        rays[:, 2] = 1.0
        t = _hit_round_cone(rays[None], np.sum(rays**2, -1)[None], a, b, ra, rb)[0]
        ts = np.linspace(1.0, 4.0, 401)
        for r, th in zip(rays, t, strict=True):
            f = _round_cone_sdf_ish(ts[:, None] * r[None], a, b, ra, rb)
            if np.isinf(th):
                assert np.all(f > -1e-3)
                continue
            n_hit += 1
            assert np.all(f[ts < th - 0.006] > -1e-3)  # nothing nearer
            pts = np.array([(th - 0.002) * r, (th + 0.002) * r])
            fa, fb = _round_cone_sdf_ish(pts, a, b, ra, rb)
            assert fa > -1e-3 and fb < 1e-3
    assert n_hit > 40


def test_ellipsoid_ray_cast_is_exact():
    from posetrack._so3 import axis_angle
    from posetrack.synth._surface import _hit_ellipsoid

    rng = np.random.default_rng(1)
    for _ in range(10):
        c = rng.uniform([-0.3, -0.3, 2.0], [0.3, 0.3, 3.0])
        R = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
        radii = rng.uniform(0.03, 0.2, size=3)
        rays = c / c[2] + rng.normal(size=(1, 20, 3)) * 0.7 * radii.min() / c[2]
        rays[..., 2] = 1.0
        t = _hit_ellipsoid(rays, c, R, radii)[0]
        hit = np.isfinite(t)
        assert hit.any()
        p = t[hit, None] * rays[0, hit]
        q = (p - c) @ R / radii
        np.testing.assert_allclose(np.sum(q**2, -1), 1.0, atol=1e-9)
        # Nearest root: just before it the ray is outside, just after inside.
        for dt, outside in ((-1e-3, True), (1e-3, False)):
            q = ((t[hit, None] + dt) * rays[0, hit] - c) @ R / radii
            assert np.all((np.sum(q**2, -1) > 1) == outside)


def test_hallucinated_limbs_stay_attached_to_their_parent():
    T = 400
    rng = np.random.default_rng(3)
    gt = np.tile(rng.uniform(60, 260, size=(1, 18, 2)), (T, 1, 1))
    gt[:, 3] = gt[:, 2] + [0, 50]  # right elbow 50 px below the shoulder
    gt[:, 4] = gt[:, 3] + [30, 40]  # right wrist 50 px from the elbow
    self_vis = np.ones((T, 18))
    self_vis[:, 4] = 0.0  # the wrist is hidden behind the body
    cfg = ps.DetectorConfig(p_miss_self=0.0, outlier_rate=0.0, swap_rate=0.0, sigma_px=0.0)
    kp, conf = ps.simulate_detector(rng, gt, self_vis, np.zeros((T, 18)),
                                    np.ones((T, 18), bool), width=640, height=480, config=cfg)
    both = (conf[:, 3] > 0) & (conf[:, 4] > 0)
    assert both.mean() > 0.9
    dist_to_gt = np.linalg.norm(kp[both, 4] - gt[both, 4], axis=-1)
    bone = np.linalg.norm(kp[both, 4] - kp[both, 3], axis=-1)
    assert np.median(dist_to_gt) > 5  # wrong ...
    assert np.all((bone > 0.75 * 50) & (bone < 1.25 * 50))  # ... but plausible
    assert conf[:, 4].mean() < conf[:, 3].mean() - 0.2


# --- variety="wide" ---------------------------------------------------------------------


def _runs(on: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and lengths of the runs of True in a (T,) bool array."""
    e = np.diff(np.r_[0, on.astype(int), 0])
    starts = np.flatnonzero(e == 1)
    return starts, np.flatnonzero(e == -1) - starts


def test_bad_variety_raises_naming_it():
    with pytest.raises(ValueError, match=r"variety.*'medium'"):
        ps.generate(0, variety="medium")


def test_wide_is_deterministic_per_seed_and_keeps_the_standard_draws():
    kw = dict(motion="wave", n_frames=6, width=80, height=60)
    a, b = ps.generate(5, variety="wide", **kw), ps.generate(5, variety="wide", **kw)
    for name in ("depth", "rgb", "keypoints2d", "confidence", "joints3d", "visible"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.meta["wide"] == b.meta["wide"] and a.meta["variety"] == "wide"
    std = ps.generate(5, **kw)
    assert std.meta["variety"] == "standard" and std.meta["wide"] is None
    # Same subject stream (height, colours), widened body and camera on top of it.
    assert a.subject["height"] == std.subject["height"]
    assert a.subject["colors"] == std.subject["colors"]
    assert a.subject["girth_scale"] != std.subject["girth_scale"]
    assert a.meta["scene"]["camera_height"] != std.meta["scene"]["camera_height"]
    assert a.meta["detector"]["sigma_px"] != std.meta["detector"]["sigma_px"]
    assert not np.array_equal(a.joints3d, std.joints3d)


def test_wide_varies_body_camera_and_noise_more_than_standard():
    def spread(variety):
        seqs = [ps.generate(s, n_frames=1, width=64, height=48, with_rgb=False,
                            variety=variety) for s in range(10)]
        rows = [(q.meta["scene"]["camera_height"], q.meta["scene"]["tilt_deg"],
                 q.subject["girth_scale"], q.meta["sensor"]["noise_a"],
                 q.meta["sensor"]["holes_per_frame"], q.meta["detector"]["sigma_px"],
                 q.meta["detector"]["p_miss_self"], q.meta["detector"]["swap_rate"])
                for q in seqs]
        return np.ptp(np.array(rows), axis=0), np.std(np.array(rows), axis=0), seqs

    std, std_sd, _ = spread("standard")
    wide, wide_sd, seqs = spread("wide")
    assert std[0] < 0.4 and wide[0] > 0.8  # camera height, m
    assert wide[1] > 15 > std[1]  # pitch, deg
    assert wide_sd[2] > 1.3 * std_sd[2]  # girth scale
    assert np.all(std[3:] == 0) and np.all(wide[3:] > 0)  # sensor/detector constants
    assert wide[3] > 0.5 * ps.SensorConfig().noise_a
    assert wide[5] > ps.DetectorConfig().sigma_px
    assert len({q.meta["detector"]["noise_family"] for q in seqs}) > 1
    for q in seqs:  # every draw is recorded, and the configs used are the drawn ones
        w = q.meta["wide"]
        assert w["sensor_applied"] and w["detector_applied"]
        assert q.meta["sensor"]["noise_a"] == pytest.approx(
            ps.SensorConfig().noise_a * w["depth_noise_scale"])
        assert q.subject["variation_girth"] == w["body"]["girth"]
        assert 0.6 <= w["camera"]["height"] <= 2.2 and abs(w["camera"]["roll_deg"]) <= 5
        assert 0 <= q.meta["scene"]["tilt_deg"] <= 35 + 1e-9


def test_wide_leaves_explicit_sensor_and_detector_alone():
    det = ps.DetectorConfig(sigma_px=1.0)
    q = ps.generate(2, n_frames=1, width=64, height=48, variety="wide", detector=det,
                    sensor=ps.SensorConfig())
    assert q.meta["detector"] == dataclasses.asdict(det)
    assert q.meta["sensor"] == dataclasses.asdict(ps.SensorConfig())
    assert not q.meta["wide"]["detector_applied"] and not q.meta["wide"]["sensor_applied"]
    assert q.meta["wide"]["jitter_scale"] > 0  # the draw is still reported


def test_body_variation_changes_exactly_what_it_says():
    from posetrack.synth._skeleton import SEG, BodyVariation, sample_subject

    def subject(variation):
        return sample_subject(np.random.default_rng(4), variation=variation)

    base, same = subject(None), subject(BodyVariation())
    np.testing.assert_array_equal(base.offsets, same.offsets)
    assert base.primitives == same.primitives
    v = BodyVariation(girth=1.3, upper_arm=1.1, shoulder_width=1.2, shoulder_drop=0.05,
                      torso_shift=0.02)
    wide = subject(v)
    assert wide.height == base.height
    assert wide.dims["girth_scale"] == pytest.approx(1.3 * base.dims["girth_scale"])
    assert wide.dims["upper_arm"] == pytest.approx(1.1 * base.dims["upper_arm"])
    assert wide.dims["forearm"] == base.dims["forearm"]
    r_sh = SEG["r_upper_arm"]
    assert wide.offsets[r_sh, 1] == pytest.approx(-0.05) and base.offsets[r_sh, 1] == 0
    assert wide.offsets[r_sh, 0] == pytest.approx(1.2 * base.offsets[r_sh, 0])
    prim = {p.name: p for p in base.primitives}
    wprim = {p.name: p for p in wide.primitives}
    assert wprim["r_thigh"].ra == pytest.approx(1.3 * prim["r_thigh"].ra)
    assert wprim["chest"].centre[2] == pytest.approx(prim["chest"].centre[2] + 0.02)
    body = np.arange(1, 14)  # the face keypoints' radius is fixed
    np.testing.assert_allclose(wide.kpt_radius[body], 1.3 * base.kpt_radius[body])


def _static_layout(T):
    gt = np.random.default_rng(1).uniform(20, 300, size=(1, 18, 2)).repeat(T, 0)
    ones = np.ones((T, 18))
    return gt, ones, ones.astype(bool)


def test_wide_detector_swaps_last_many_frames():
    T = 1500
    gt, ones, vis = _static_layout(T)
    longest = []
    for seed in range(4):
        meta = ps.generate(seed, n_frames=1, width=64, height=48, with_rgb=False,
                           variety="wide").meta
        lo, hi = meta["detector"]["swap_lengths"]
        assert lo >= 5 and hi >= 12
        # The drawn config, with only its limb swaps left on, on a static far-apart layout.
        cfg = dataclasses.replace(
            ps.DetectorConfig(**meta["detector"]), p_miss_visible=0.0, outlier_rate=0.0,
            body_swap_rate=0.0, snap_rate=0.0, sigma_px=1.0)
        kp, _ = ps.simulate_detector(np.random.default_rng(seed), gt, ones, 0 * ones, vis,
                                     width=320, height=320, config=cfg)
        lengths = []
        for r, left in ((4, 7), (10, 13)):
            swapped = np.linalg.norm(kp[:, r] - gt[:, left], axis=-1) < 5
            starts, n = _runs(swapped)
            lengths += list(n[starts + n < T])  # complete episodes only
        assert len(lengths) > 3 and min(lengths) >= lo, seed
        longest.append(max(lengths))
    assert max(longest) > 12
    # The standard detector's swaps are short (geometric, mean 4 frames).
    cfg = ps.DetectorConfig(p_miss_visible=0.0, outlier_rate=0.0, swap_rate=0.01)
    kp, _ = ps.simulate_detector(np.random.default_rng(0), gt, ones, 0 * ones, vis,
                                 width=320, height=320, config=cfg)
    _, n = _runs(np.linalg.norm(kp[:, 4] - gt[:, 7], axis=-1) < 5 * cfg.sigma_px)
    assert np.median(n) < 5


def test_whole_body_swaps_and_limb_snaps():
    T = 2000
    gt, ones, vis = _static_layout(T)
    off = dict(p_miss_visible=0.0, outlier_rate=0.0, swap_rate=0.0, sigma_px=1.0,
               swap_lengths=(5, 20))

    def near(kp, k, j):
        return np.linalg.norm(kp[:, k] - gt[:, j], axis=-1) < 5

    cfg = ps.DetectorConfig(body_swap_rate=0.01, **off)
    kp, _ = ps.simulate_detector(np.random.default_rng(0), gt, ones, 0 * ones, vis,
                                 width=320, height=320, config=cfg)
    body = near(kp, 2, 5)  # right shoulder reported on the left one
    assert 0.03 < body.mean() < 0.5
    for r, left in ((2, 5), (4, 7), (8, 11), (13, 10), (16, 17)):  # all pairs at once
        np.testing.assert_array_equal(near(kp, r, left), body)
    assert _runs(body)[1].min() >= 5
    cfg = ps.DetectorConfig(snap_rate=0.01, **off)
    kp, conf = ps.simulate_detector(np.random.default_rng(0), gt, ones, 0 * ones, vis,
                                    width=320, height=320, config=cfg)
    on_left = near(kp, 4, 7) & near(kp, 7, 7)  # both wrists on the left one
    on_right = near(kp, 4, 4) & near(kp, 7, 4)
    assert on_left.any() and on_right.any()
    assert np.all(near(kp, 3, 6)[on_left])  # the elbow goes with the wrist
    assert not np.any(near(kp, 2, 5) | near(kp, 5, 2))  # shoulders stay


@pytest.mark.parametrize("family", ["student_t", "laplace"])
def test_heavy_tailed_detector_noise_keeps_sigma(family):
    T = 6000
    gt, ones, vis = _static_layout(T)
    kw = dict(outlier_rate=0.0, swap_rate=0.0, p_miss_visible=0.0, rho=0.0, noise_dof=5.0,
              hallucination_deg=0.0)
    errs = {}
    for fam in ("gaussian", family):
        cfg = ps.DetectorConfig(noise_family=fam, **kw)
        kp, _ = ps.simulate_detector(np.random.default_rng(0), gt, ones, 0 * ones, vis,
                                     width=640, height=640, config=cfg)
        errs[fam] = (kp - gt).ravel() / cfg.sigma_px
    kurt = {k: np.mean(e**4) / np.mean(e**2) ** 2 - 3 for k, e in errs.items()}
    assert np.std(errs[family]) == pytest.approx(1.0, rel=0.08)
    assert abs(kurt["gaussian"]) < 0.2 and kurt[family] > 1.5
    with pytest.raises(ValueError, match="noise_family"):
        ps.DetectorConfig(noise_family="cauchy")


def test_cli_generate_passes_variety(tmp_path):
    from posetrack.app._cli import main

    out = tmp_path / "rec"
    args = ["generate", str(out), "--frames", "2", "--width", "64", "--height", "48",
            "--seed", "3", "--quiet", "--variety", "wide"]
    assert main(args) == 0
    gt = np.load(out / "ground_truth.npz")
    ref = ps.generate(3, n_frames=2, width=64, height=48, variety="wide")
    np.testing.assert_allclose(gt["joints3d"], ref.joints3d)
    with pytest.raises(SystemExit):
        main([*args[:-1], "medium"])
