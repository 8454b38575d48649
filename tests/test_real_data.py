"""End to end on a real Kinect v2 frame: BlazePose on a person crop -> lift -> fit -> checks.

Data: ``../shared/data/rgbd-pose3d-freiburg-sample`` (lmb-freiburg/rgbd-pose3d, one outdoor
frame, four people). It has NO licence: it is read in place and never copied into the repo; the
tests skip with a message when it (or the optional detector) is absent. There is no ground
truth, so the checks are plausibility checks: bone lengths in the human range, fitted joints
close to the lifted landmarks, and the fitted joints projecting onto the person's depth.

Frame facts (from its README): colour 960x540, depth 1920x1080 uint16 mm registered to colour,
colour pixel (u, v) = depth pixel (2u, 2v). Only ~10 % of the depth is valid (people at
2-4 m, almost no ground). Intrinsics: the repo's (approximate, for 1920x1080).

The person: the right-most man (checked shirt, holding papers, ~2.6 m away). ``CROP`` is a fixed
box around him in colour pixels, chosen by looking at color.png: it holds him head to feet with
margin and none of the other three people (the nearest, in the black hoodie, ends at u ~ 550).

Choices: keypoints go to depth resolution (``(kp + 0.5) * 2 - 0.5``, the pixel-centre mapping
``Intrinsics.scaled`` uses) rather than downsampling the depth, so the lifting sees the sensor's
own pixels. The Delta scoring size is 160x90 (12x12-pixel blocks of the 16:9 frame) instead of
the 4:3 default 160x120.
"""

import numpy as np
import pytest
from conftest import require_data

import posetrack
from posetrack import STATUS_NAMES, TRACKED, detect

SAMPLE = "rgbd-pose3d-freiburg-sample"

#: (top, bottom, left, right) in colour pixels: the right-most man (see the module docstring).
CROP = (100, 510, 570, 800)

#: The repo's intrinsics for the 1920x1080 registered depth (see the sample's README.txt).
REPO_K = dict(fx=1392.45, fy=944.87, cx=944.45, cy=546.71, width=1920, height=1080)

#: Human ranges, metres, for a standing adult (generous: the intrinsics are approximate).
BONE_RANGES = {
    "upper_arm": (0.20, 0.40),
    "forearm": (0.18, 0.35),
    "thigh": (0.30, 0.55),
    "shin": (0.30, 0.55),
    "torso": (0.40, 0.70),  # neck keypoint to the hips' midpoint
    "shoulder_width": (0.10, 0.25),  # half the shoulder-to-shoulder distance
    "hip_width": (0.05, 0.20),  # half the hip-to-hip distance
}
BONES = {"upper_arm": [(2, 3), (5, 6)], "forearm": [(3, 4), (6, 7)], "thigh": [(8, 9), (11, 12)]}
BONES["shin"] = [(9, 10), (12, 13)]

BODY = list(posetrack.BODY_JOINTS)  # the 13 body keypoints (neck .. ankles)


def _color_to_depth(uv):
    """Colour pixels (960x540) -> depth pixels (1920x1080), pixel centres kept consistent."""
    return (np.asarray(uv, np.float64) + 0.5) * 2.0 - 0.5


@pytest.fixture(scope="module")
def frame():
    folder = require_data(SAMPLE)
    if not detect.available():
        pytest.skip(f"the optional detector is not installed ({detect.INSTALL_HINT})")
    rgb = posetrack.io.read_rgb(folder / "color.png")
    depth = posetrack.io.read_depth(folder / "depth.png")  # metres, 0 = invalid
    assert rgb.shape == (540, 960, 3) and depth.shape == (1080, 1920)
    kp, conf = detect.detect_image(rgb, crop=CROP)
    intrinsics = posetrack.Intrinsics.create(**REPO_K)
    return dict(rgb=rgb, depth=depth, kp=kp, conf=conf, intrinsics=intrinsics)


@pytest.fixture(scope="module")
def fits(frame):
    """Single-frame LVM fits with the default body and with the body estimated from the frame."""
    depth, intr = frame["depth"], frame["intrinsics"]
    kp, conf = _color_to_depth(frame["kp"]), frame["conf"]
    config = posetrack.TrackerConfig.paper("lvm", score_height=90)

    tracker = posetrack.Tracker(intr, config)
    est, status = tracker.update(depth, kp, conf)
    assert est is not None, "the tracker could not initialise from the detected keypoints"
    out = {"default": (est, status, tracker.shape)}

    # Body shape from this one frame, by posetrack.estimate_shape on the tracker's landmarks
    # (one frame: at most 2 measurements per limb length). The tracker's landmarks carry the
    # surface-to-joint-centre offset, as estimate_shape expects.
    lm = est.landmarks
    shape, ratios = posetrack.estimate_shape(
        np.asarray(lm.points3d)[None], np.asarray(lm.has_depth)[None], min_samples=1
    )
    tracker2 = posetrack.Tracker(intr, config, shape=shape)
    est2, status2 = tracker2.update(depth, kp, conf)
    assert est2 is not None
    out["estimated"] = (est2, status2, shape)
    out["ratios"] = ratios
    return out


def test_detector_finds_the_person_in_the_crop(frame):
    kp, conf = frame["kp"], frame["conf"]
    top, bottom, left, right = CROP
    found = conf[BODY] > 0
    assert found.sum() >= 12, f"only {found.sum()} of 13 body keypoints detected: {conf}"
    ok = conf > 0
    assert np.all((kp[ok, 0] >= left - 0.5) & (kp[ok, 0] < right - 0.5))
    assert np.all((kp[ok, 1] >= top - 0.5) & (kp[ok, 1] < bottom - 0.5))
    # An upright person: nose above neck above hips above knees above ankles (image v grows down).
    v = kp[:, 1]
    assert v[0] < v[1] < 0.5 * (v[8] + v[11]) < 0.5 * (v[9] + v[12]) < 0.5 * (v[10] + v[13])
    # Neck = shoulder midpoint, with the smaller shoulder confidence.
    np.testing.assert_allclose(kp[1], 0.5 * (kp[2] + kp[5]), atol=1e-3)
    assert conf[1] == pytest.approx(min(conf[2], conf[5]))


def test_video_mode_agrees_with_single_image(frame):
    """detect_keypoints (tracking mode) on the repeated frame stays on the same person."""
    kp, conf = detect.detect_keypoints([frame["rgb"]] * 3, crop=CROP, progress=False)
    assert kp.shape == (3, 18, 2) and conf.shape == (3, 18)
    both = (conf > 0) & (frame["conf"] > 0)[None]
    assert both[:, BODY].sum() >= 3 * 12
    err = np.linalg.norm(kp - frame["kp"][None], axis=-1)[both]
    assert np.max(err) < 8.0, f"video-mode keypoints moved up to {np.max(err):.1f} px"


def test_landmarks_lift_onto_the_person(frame, fits):
    est, _, _ = fits["default"]
    lm = est.landmarks
    has_depth = np.asarray(lm.has_depth)
    assert has_depth[BODY].sum() >= 11, f"body landmarks with depth: {has_depth[BODY]}"
    z = np.asarray(lm.points3d)[BODY][has_depth[BODY], 2]
    assert np.all((z > 2.3) & (z < 3.1)), f"landmark depths {z} are not at the man (~2.6 m)"


@pytest.mark.parametrize("which", ["default", "estimated"])
def test_single_frame_fit_is_tracked(fits, which):
    est, status, _ = fits[which]
    assert status == TRACKED, f"status {STATUS_NAMES[status]}, Delta {float(est.delta):.3f}"
    assert np.all(np.isfinite(np.asarray(est.keypoints3d)))


def test_estimated_shape_is_human(fits):
    ratios = fits["ratios"]
    for field in ("upper_arm", "forearm", "thigh", "shin", "torso"):
        assert np.isfinite(ratios[field]), f"{field} was not measured: {ratios}"
    shape = fits["estimated"][2].to_dict()
    for field, (lo, hi) in BONE_RANGES.items():
        assert lo <= shape[field] <= hi, f"estimated {field} = {shape[field]:.3f} m"


@pytest.mark.parametrize("which", ["default", "estimated"])
def test_fitted_bones_are_human(fits, which):
    est, _, shape = fits[which]
    X = np.asarray(est.keypoints3d, np.float64)
    lengths = {k: [np.linalg.norm(X[a] - X[b]) for a, b in pairs] for k, pairs in BONES.items()}
    lengths["torso"] = [np.linalg.norm(X[1] - 0.5 * (X[8] + X[11]))]
    lengths["shoulder_width"] = [0.5 * np.linalg.norm(X[2] - X[5])]
    lengths["hip_width"] = [0.5 * np.linalg.norm(X[8] - X[11])]
    for name, values in lengths.items():
        lo, hi = BONE_RANGES[name]
        assert all(lo <= v <= hi for v in values), f"{name}: {values}"
    for name in BONES:  # the limbs of the fitted model are the shape's (rigid segments)
        np.testing.assert_allclose(lengths[name], float(getattr(shape, name)), atol=2e-3)
    stature = np.linalg.norm(X[0] - 0.5 * (X[10] + X[13]))  # nose to the ankles' midpoint
    assert 1.35 < stature < 1.85, f"nose to ankles {stature:.2f} m"


@pytest.mark.parametrize(
    "which, max_dist, max_median",
    # The default adult is wider at shoulders and hips than this man measures, so its joints
    # sit further from the landmarks than the estimated body's.
    [("default", 0.20, 0.10), ("estimated", 0.15, 0.05)],
)
def test_fitted_joints_are_near_the_lifted_landmarks(fits, which, max_dist, max_median):
    est, _, _ = fits[which]
    X = np.asarray(est.keypoints3d)
    P = np.asarray(est.landmarks.points3d)
    F = np.asarray(est.landmarks.has_depth)
    body = np.zeros(18, bool)
    body[BODY] = True
    dist = np.linalg.norm(X - P, axis=-1)[F & body]
    assert dist.max() < max_dist, f"fitted-landmark distances (m): {np.round(dist, 3)}"
    assert np.median(dist) < max_median, f"fitted-landmark distances (m): {np.round(dist, 3)}"


@pytest.mark.parametrize("which", ["default", "estimated"])
def test_fitted_joints_project_onto_the_persons_depth(frame, fits, which):
    est, _, _ = fits[which]
    depth, intr = frame["depth"], frame["intrinsics"]
    X = np.asarray(est.keypoints3d, np.float64)
    P = np.asarray(est.landmarks.points3d)
    F = np.asarray(est.landmarks.has_depth)
    person_z = float(np.median(P[BODY][F[BODY], 2]))
    top, bottom, left, right = (2 * v for v in CROP)  # the crop in depth pixels
    mask = np.zeros(depth.shape, bool)
    mask[top:bottom, left:right] = np.abs(depth[top:bottom, left:right] - person_z) < 0.4
    rows, cols = np.nonzero(mask)  # the person's depth pixels
    uv = np.asarray(posetrack.project(intr, X))
    for i in BODY:
        name = posetrack.KEYPOINT_NAMES[i]
        u, v = uv[i]
        assert left <= u < right and top <= v < bottom, f"{name} projects outside the crop"
        d = np.hypot(cols - u, rows - v)
        near = d < 25  # 25 depth pixels ~ 5 cm at 2.6 m
        assert near.any(), f"{name}: nearest person depth pixel {d.min():.0f} px away"
        # The joint centre lies behind the surface the sensor sees, by up to a limb's thickness.
        behind = X[i, 2] - np.median(depth[rows[near], cols[near]])
        assert -0.10 < behind < 0.25, f"{name} is {behind:+.2f} m behind the local depth"
