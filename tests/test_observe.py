"""Lifting 2D keypoints to 3D on hand-made depth maps with known answers."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import Intrinsics
from posetrack._observe import Landmarks, confident_depth, lift_keypoints

INTR = Intrinsics.create(fx=100.0, fy=100.0, cx=39.5, cy=29.5, width=80, height=60)


@pytest.fixture(scope="module")
def lift():
    return jax.jit(lift_keypoints, static_argnames=("window", "min_valid", "rule"))


def _scene():
    """A wall at 3 m, a box at 1.5 m over columns 10..29, rows 10..39, some holes."""
    d = np.full((60, 80), 3.0, np.float32)
    d[10:40, 10:30] = 1.5
    d[20, 20] = 0.0  # a hole inside the box
    d[21, 21] = np.nan  # and a NaN
    d[22, 19] = 25.0  # out-of-range speck
    d[50:, 50:] = 0.0  # an invalid region
    return d


def _kp(points):
    kp = np.zeros((18, 2), np.float32)
    conf = np.zeros(18, np.float32)
    for i, (u, v, c) in enumerate(points):
        kp[i] = (u, v)
        conf[i] = c
    return kp, conf


def test_lifting_known_answers(lift):
    kp, conf = _kp(
        [
            (20.0, 21.0, 0.9),  # 0: in the box, window contains a hole, a NaN and a speck
            (60.0, 5.0, 0.8),  # 1: on the wall
            (55.0, 55.0, 0.9),  # 2: in the invalid region -> detected, no depth
            (20.0, 21.0, 0.05),  # 3: below the confidence threshold -> not detected
            (-5.0, 10.0, 0.9),  # 4: outside the image -> not detected
            (np.nan, 10.0, 0.9),  # 5: NaN coordinate -> not detected
        ]
    )
    lm = lift(
        jnp.asarray(_scene()), jnp.asarray(kp), jnp.asarray(conf), INTR, window=5, min_valid=3
    )
    detected = np.asarray(lm.detected)
    has_depth = np.asarray(lm.has_depth)
    np.testing.assert_array_equal(detected[:6], [True, True, True, False, False, False])
    np.testing.assert_array_equal(has_depth[:6], [True, True, False, False, False, False])
    assert not detected[6:].any()  # confidence 0
    P = np.asarray(lm.points3d)
    # Back-projection: X = (u - cx) / fx * z.
    np.testing.assert_allclose(
        P[0], [(20 - 39.5) / 100 * 1.5, (21 - 29.5) / 100 * 1.5, 1.5], atol=1e-5
    )
    np.testing.assert_allclose(
        P[1], [(60 - 39.5) / 100 * 3.0, (5 - 29.5) / 100 * 3.0, 3.0], atol=1e-5
    )
    assert np.all(P[~has_depth] == 0) and np.isfinite(P).all()


def test_median_picks_the_majority_surface(lift):
    """A keypoint at the box edge: the median follows the majority of valid depths."""
    kp, conf = _kp([(30.0, 25.0, 1.0), (29.0, 25.0, 1.0)])  # column 30 is wall, 29 is box
    lm = lift(
        jnp.asarray(_scene()), jnp.asarray(kp), jnp.asarray(conf), INTR, window=5, min_valid=3
    )
    z = np.asarray(lm.points3d)[:, 2]
    # Window over columns 28..32: 2 box columns, 3 wall columns -> wall; 27..31: 3 box -> box.
    assert z[0] == pytest.approx(3.0) and z[1] == pytest.approx(1.5)


def test_nearest_rule_reads_a_thin_limb_not_the_background(lift):
    """A limb 2 px wide at 2 m over a wall at 4 m: the median of the 5x5 window on it is the
    wall (10 of 25 pixels are limb), the nearest cluster is the limb; a speck nearer than
    the limb (one pixel at 1 m, two at 1.3 m: fewer than min_valid) is no cluster."""
    d = np.full((60, 80), 4.0, np.float32)
    d[:, 40:42] = 2.0
    d[30, 41], d[31, 41], d[29, 40] = 1.0, 1.3, 1.3
    kp, conf = _kp([(41.0, 30.0, 1.0), (60.0, 30.0, 1.0)])
    args = (jnp.asarray(d), jnp.asarray(kp), jnp.asarray(conf), INTR)
    median = lift(*args, window=5, min_valid=3, rule="median")
    nearest = lift(*args, window=5, min_valid=3, rule="nearest")
    assert float(median.points3d[0, 2]) == pytest.approx(4.0)
    assert float(nearest.points3d[0, 2]) == pytest.approx(2.0)
    # On a flat wall both read the wall.
    assert float(median.points3d[1, 2]) == float(nearest.points3d[1, 2]) == pytest.approx(4.0)
    np.testing.assert_array_equal(median.has_depth, nearest.has_depth)


def test_nearest_cluster_is_the_median_of_its_depths(lift):
    """Within the nearest cluster the reading is its median (an even count: the mean of the
    two middle values), not its minimum; depths beyond NEAREST_CLUSTER are not in it; and
    where the window's median lies less than NEAREST_JUMP behind the cluster it stays."""
    from posetrack._observe import NEAREST_CLUSTER, NEAREST_JUMP

    d = np.zeros((60, 80), np.float32)
    d[30, 38:42] = [2.0, 2.04, 2.1, 2.0 + NEAREST_CLUSTER + 0.01]  # cluster: 2.0, 2.04, 2.1
    d[31:33, 38:42] = 3.0  # the background: 8 of 12 valid depths, the median
    kp, conf = _kp([(40.0, 30.0, 1.0)])

    def z(rule):
        lm = lift(jnp.asarray(d), jnp.asarray(kp), jnp.asarray(conf), INTR, window=5,
                  min_valid=3, rule=rule)  # fmt: skip
        return float(lm.points3d[0, 2])

    assert z("median") == pytest.approx(3.0) and z("nearest") == pytest.approx(2.04)
    d[30, 42] = 2.12  # a fourth in the cluster: 2.04 and 2.1 in the middle
    assert z("nearest") == pytest.approx(2.07)
    d[31:33, 38:42] = 2.0 + NEAREST_JUMP - 0.05  # the rest nearer than the jump: the median
    assert z("nearest") == z("median") == pytest.approx(2.0 + NEAREST_JUMP - 0.05)


def test_lift_rule_is_validated_and_reaches_the_tracker_lifting():
    kp, conf = _kp([])
    with pytest.raises(ValueError, match="rule"):
        lift_keypoints(jnp.zeros((60, 80)), jnp.asarray(kp), jnp.asarray(conf), INTR, rule="min")
    with pytest.raises(ValueError, match="lift_rule"):
        pt.TrackerConfig(lift_rule="min")
    from posetrack._body import BodyShape
    from posetrack._depthobs import tracker_landmarks

    d = np.full((60, 80), 4.0, np.float32)
    d[:, 40:42] = 2.0
    kp, conf = _kp([(41.0, 30.0, 1.0)])
    z = {}
    for rule in ("median", "nearest"):
        cfg = pt.TrackerConfig(lift_rule=rule, surface_offset=False)
        lm = tracker_landmarks(cfg, BodyShape.default(), INTR, jnp.asarray(d), kp, conf)
        z[rule] = float(lm.points3d[0, 2])
    assert z == {"median": pytest.approx(4.0), "nearest": pytest.approx(2.0)}


def _torso_scene():
    """A torso (a block at 3 m, rows 10..49, columns 20..39), an arm 2 px wide at 3.3 m
    (columns 50..51) and the wall at 4.6 m: 10 of a 5x5 window on the arm are arm."""
    d = np.full((60, 80), 4.6, np.float32)
    d[10:50, 20:40] = 3.0
    d[:, 50:52] = 3.3
    torso = [(25.0, 15.0), (35.0, 15.0), (25.0, 45.0), (35.0, 45.0), (30.0, 12.0)]
    kp, conf = np.zeros((18, 2), np.float32), np.zeros(18, np.float32)
    for j, uv in zip((2, 5, 8, 11, 1), torso):
        kp[j], conf[j] = uv, 1.0
    kp[4], conf[4] = (51.0, 30.0), 1.0  # the wrist on the arm's edge
    kp[7], conf[7] = (60.0, 30.0), 1.0  # a wrist over the wall only
    return d, kp, conf


def test_body_depth_limit_is_the_torso_median_plus_the_band():
    body_depth_limit = pt.body_depth_limit

    d, kp, conf = _torso_scene()
    lm = lift_keypoints(jnp.asarray(d), jnp.asarray(kp), jnp.asarray(conf), INTR)
    assert float(body_depth_limit(lm, 0.7)) == pytest.approx(3.7)
    assert float(body_depth_limit(lm, 0.0)) == 10.0  # off
    assert float(body_depth_limit(lm, 9.0)) == 10.0  # never beyond max_depth
    no_torso = Landmarks(lm.keypoints2d, lm.confidence, lm.points3d, lm.detected,
                         lm.has_depth.at[jnp.array([1, 2, 5, 8, 11])].set(False))  # fmt: skip
    assert float(body_depth_limit(no_torso, 0.7)) == 10.0
    # The torso's median, not its mean: one torso keypoint on the wall does not move it.
    lm2 = lift_keypoints(jnp.asarray(d), jnp.asarray(kp).at[1].set((60.0, 12.0)),
                         jnp.asarray(conf), INTR)  # fmt: skip
    assert float(body_depth_limit(lm2, 0.7)) == pytest.approx(3.7)


def test_lift_band_reads_the_limb_or_nothing_instead_of_the_wall():
    """The tracker's lifting with ``lift_band``: the wrist on the arm's edge reads the arm
    (the wall, 15 of its 25 pixels, is beyond the band), the wrist over the wall alone keeps
    its 2D detection but no depth; the torso is unchanged; 0 is the plain lifting."""
    from posetrack._body import BodyShape
    from posetrack._depthobs import tracker_landmarks

    d, kp, conf = _torso_scene()

    def lifted(band):
        cfg = pt.TrackerConfig(lift_band=band, surface_offset=False)
        return tracker_landmarks(cfg, BodyShape.default(), INTR, jnp.asarray(d), kp, conf)

    plain, banded = lifted(0.0), lifted(0.7)
    assert float(plain.points3d[4, 2]) == pytest.approx(4.6)
    assert float(banded.points3d[4, 2]) == pytest.approx(3.3)
    assert bool(plain.has_depth[7]) and not bool(banded.has_depth[7])
    assert bool(banded.detected[7])
    torso = np.array([1, 2, 5, 8, 11])
    np.testing.assert_array_equal(plain.points3d[torso], banded.points3d[torso])
    with pytest.raises(ValueError, match="lift_band"):
        pt.TrackerConfig(lift_band=-0.1)


def test_even_count_median_and_min_valid(lift):
    d = np.zeros((60, 80), np.float32)
    d[30, 40], d[30, 41] = 2.0, 2.2  # only two valid pixels in the window
    kp, conf = _kp([(40.0, 30.0, 1.0)])
    lm = lift(jnp.asarray(d), jnp.asarray(kp), jnp.asarray(conf), INTR, window=5, min_valid=2)
    assert bool(lm.has_depth[0]) and float(lm.points3d[0, 2]) == pytest.approx(2.1)
    lm = lift(jnp.asarray(d), jnp.asarray(kp), jnp.asarray(conf), INTR, window=5, min_valid=3)
    assert not bool(lm.has_depth[0])


def test_depth_offset_moves_along_the_ray():
    kp, conf = _kp([(60.0, 5.0, 0.8)])
    d = jnp.asarray(_scene())
    plain = lift_keypoints(d, jnp.asarray(kp), jnp.asarray(conf), INTR)
    pushed = lift_keypoints(d, jnp.asarray(kp), jnp.asarray(conf), INTR, depth_offset=0.1)
    p0, p1 = np.asarray(plain.points3d[0]), np.asarray(pushed.points3d[0])
    np.testing.assert_allclose(np.linalg.norm(p1 - p0), 0.1, atol=1e-5)
    np.testing.assert_allclose(np.cross(p0, p1), 0, atol=1e-5)  # same ray
    assert p1[2] > p0[2]


def test_even_window_is_rejected():
    kp, conf = _kp([])
    with pytest.raises(ValueError, match="window"):
        lift_keypoints(jnp.zeros((60, 80)), jnp.asarray(kp), jnp.asarray(conf), INTR, window=4)


def _landmarks(confidence):
    conf = jnp.asarray(confidence, jnp.float32)
    return Landmarks(
        keypoints2d=jnp.full((18, 2), 10.0), confidence=conf,
        points3d=jnp.tile(jnp.asarray([0.1, 0.2, 2.5]), (18, 1)),
        detected=conf > 0.1, has_depth=conf > 0.1,
    )  # fmt: skip


def test_confident_depth_drops_depth_below_the_ratio_of_the_body_median():
    conf = np.full(18, 0.85, np.float32)
    conf[7] = 0.6  # 0.6 < 0.8 * 0.85 = 0.68: inferred, not seen
    conf[6] = 0.7  # above the ratio: kept
    conf[0] = 0.3  # the nose is not a body keypoint: its low confidence sets no median
    conf[11] = 0.0  # not detected: stays without depth
    lm = confident_depth(_landmarks(conf), 0.8)
    kept = np.asarray(lm.has_depth)
    assert not kept[7] and kept[6] and not kept[0] and not kept[11]
    assert kept[[1, 2, 3, 4, 5, 8, 9, 10, 12, 13]].all()
    assert np.asarray(lm.detected)[[0, 7]].all()  # the 2D detections stay
    np.testing.assert_array_equal(np.asarray(lm.points3d[7]), 0.0)
    np.testing.assert_allclose(np.asarray(lm.points3d[6]), [0.1, 0.2, 2.5])


def test_confident_depth_follows_the_detectors_scale_and_is_off_at_zero():
    conf = np.full(18, 0.85, np.float32)
    conf[7] = 0.6
    # A detector whose confidences run lower overall: the same ratios, the same decision.
    assert not bool(confident_depth(_landmarks(conf * 0.5), 0.8).has_depth[7])
    assert bool(confident_depth(_landmarks(conf), 0.0).has_depth[7])
    # No body keypoint detected (only the face): nothing to compare with, nothing dropped.
    face = np.zeros(18, np.float32)
    face[[0, 14, 15]] = 0.2
    assert np.asarray(confident_depth(_landmarks(face), 0.8).has_depth)[[0, 14, 15]].all()


def test_depth_confidence_is_validated():
    assert pt.TrackerConfig().depth_confidence == 0.0  # off: the paper's lifting
    assert pt.TrackerConfig(depth_confidence=1).depth_confidence == 1.0
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="TrackerConfig.depth_confidence"):
            pt.TrackerConfig(depth_confidence=bad)


def test_observed_share_counts_confident_keypoints_on_depth():
    """The shape pre-pass's gate: a keypoint counts where its confidence is above 0.3, its
    coordinates finite, and the depth at its pixel (rounded, clipped into the image) > 0."""
    depth = np.zeros((4, 6), np.float32)
    depth[1, 2] = depth[3, 5] = 1.5
    depth[0, 0] = np.nan
    kp = np.array([
        [2.2, 0.8],  # on depth: counts
        [1.6, 0.6],  # (2, 1) rounded: counts
        [2.0, 1.0],  # on depth, confidence 0.3: not above it
        [9.0, 7.0],  # outside, clipped to (5, 3): depth there counts
        [np.nan, 1.0],  # not finite
        [0.0, 0.0],  # NaN depth
        [4.0, 2.0],  # no depth
        [2.0, 1.0],
    ])  # fmt: skip
    conf = np.array([0.9, 0.31, 0.3, 0.8, 0.9, 0.9, 0.9, 0.9])
    assert pt.observed_share([depth], [kp], [conf], 1) == 4 / 8
    # Frames beyond the first ``frames`` are not read; a frame with nothing counts zero.
    none = np.zeros_like(conf)
    assert pt.observed_share([depth, depth], [kp, kp], [conf, none], 2) == 4 / 16
    assert pt.observed_share([depth, depth], [kp, kp], [conf, none], 1) == 4 / 8
    with pytest.raises(ValueError, match="frames must be >= 1"):
        pt.observed_share([depth], [kp], [conf], 0)
    # Several people's detections a frame: the best-observed person's.
    people_kp, people_conf = np.stack([kp, kp]), np.stack([none, conf])
    assert pt.observed_share([depth], [people_kp], [people_conf], 1) == 4 / 8
    assert pt.observed_share([depth], [people_kp[:0]], [people_conf[:0]], 1) == 0
