"""Levenberg-Marquardt fits (Eq. (1)-(2)), initialisation and body-shape estimation, checked
against known ground truth."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from posetrack import Intrinsics, project
from posetrack import _body as B
from posetrack import _so3 as S
from posetrack._fit import FitSettings, fit_hypotheses, fit_pose
from posetrack._init import estimate_shape, initial_pose
from posetrack._observe import Landmarks, as_bounds, depth_bounds, without_depth
from posetrack._residuals import (
    ResidualSettings,
    landmark_residuals,
    pixel_scale,
    regulariser_residuals,
)

INTR = Intrinsics.create(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)


def _true_pose(seed: int) -> jnp.ndarray:
    rng = np.random.default_rng(seed)
    p = np.asarray(B.facing_camera_params(2.6), np.float64)
    p[3:] += rng.normal(size=40) * 0.25
    p[:3] += rng.normal(size=3) * 0.2
    return jnp.asarray(p, jnp.float32)


def _landmarks(shape, params, *, depth_missing=()):
    M = B.keypoints(shape, params)
    has = np.ones(18, bool)
    has[list(depth_missing)] = False
    return Landmarks(
        keypoints2d=project(INTR, M),
        confidence=jnp.ones(18),
        points3d=jnp.where(jnp.asarray(has)[:, None], M, 0.0),
        detected=jnp.ones(18, bool),
        has_depth=jnp.asarray(has),
    )


@pytest.fixture(scope="module")
def fit_jit():
    return jax.jit(fit_pose, static_argnames=("settings",))


@pytest.mark.parametrize("loss", ["l1", "l2"])
def test_lm_recovers_known_pose_from_noise_free_landmarks(fit_jit, loss):
    shape = B.BodyShape.default()
    settings = FitSettings(max_steps=30, residuals=ResidualSettings(loss=loss))
    for seed in range(3):
        true = _true_pose(seed)
        start = true + 0.04 * jax.random.normal(jax.random.PRNGKey(seed), (43,))
        all_ = jnp.ones(18, bool)
        res = fit_jit(
            start, shape, _landmarks(shape, true), INTR, use3d=all_, use2d=all_, settings=settings
        )
        err = np.linalg.norm(
            np.asarray(B.keypoints(shape, res.params) - B.keypoints(shape, true)), axis=-1
        )
        assert bool(res.ok)
        assert err.max() < 0.005, f"seed {seed}: max keypoint error {err.max() * 1000:.2f} mm"
        # Keypoints seen only in 2D: their depth along the ray is ambiguous, their image is not.
        two_d = (4, 10, 16)
        lm = _landmarks(shape, true, depth_missing=two_d)
        res = fit_jit(start, shape, lm, INTR, use3d=all_, use2d=all_, settings=settings)
        px = np.linalg.norm(
            np.asarray(project(INTR, B.keypoints(shape, res.params)) - lm.keypoints2d), axis=-1
        )
        err = np.linalg.norm(
            np.asarray(B.keypoints(shape, res.params) - B.keypoints(shape, true)), axis=-1
        )
        assert px.max() < 0.5, f"seed {seed}: reprojection error {px.max():.2f} px"
        assert np.delete(err, two_d).max() < 0.005


def test_a_depth_bound_costs_only_a_joint_in_front_of_it():
    """``as_bounds`` with ``ResidualSettings(depth_bounds=True)``: the right wrist's and hip's
    lifted depth 10 cm in front of / behind the true joint. A bound in front of the joint
    (the surface seen in front of a hidden joint) costs nothing; one behind it costs the
    10 cm in the depth slot alone, and only where the keypoint is fitted in 2D; the 2D
    residuals are those of the keypoint without depth, and a keypoint with depth fitted in 3D
    is unchanged."""
    shape = B.BodyShape.default()
    true = _true_pose(3)
    lm = _landmarks(shape, true)
    wrist, hip = 4, 8
    pts = lm.points3d.at[wrist, 2].add(-0.1).at[hip, 2].add(0.1)
    lm = dataclasses.replace(lm, points3d=pts)
    mask = jnp.zeros(18, bool).at[jnp.array([wrist, hip])].set(True)
    bounded = as_bounds(lm, mask)
    assert np.asarray(depth_bounds(bounded)).tolist() == np.asarray(mask).tolist()
    assert not np.asarray(depth_bounds(without_depth(lm, mask))).any()
    assert not np.asarray(depth_bounds(lm)).any()  # plain landmarks carry no bound
    mpp = pixel_scale(true, shape, INTR)

    def res(landmarks, use2d, bounds=True):
        use3d = landmarks.has_depth
        settings = ResidualSettings(loss="l2", depth_bounds=bounds)
        e = landmark_residuals(
            true, shape, landmarks, INTR, use3d=use3d, use2d=use2d & ~use3d,
            metres_per_pixel=mpp, settings=settings,
        )  # fmt: skip
        return np.asarray(e)

    all_ = jnp.ones(18, bool)
    e = res(bounded, all_)
    assert e[wrist, :3].tolist() == [0.0, 0.0, 0.0]  # behind its bound: free
    np.testing.assert_allclose(e[hip, :3], [0.0, 0.0, 0.1], atol=1e-5)  # 10 cm in front
    plain_2d = res(without_depth(lm, mask), all_)
    np.testing.assert_array_equal(e[:, 3:], plain_2d[:, 3:])
    others = np.ones(18, bool)
    others[[wrist, hip]] = False
    np.testing.assert_array_equal(e[others], res(lm, all_)[others])
    # Not fitted in 2D (a subset left it out): no bound either.
    assert not res(bounded, all_.at[hip].set(False))[hip].any()
    # Without ResidualSettings.depth_bounds (the default) a bound is a 2D-only keypoint.
    np.testing.assert_array_equal(res(bounded, all_, bounds=False), plain_2d)


def test_masks_exclude_landmarks():
    """A landmark that is excluded must not pull the fit: corrupt it and exclude it."""
    shape = B.BodyShape.default()
    true = _true_pose(7)
    lm = _landmarks(shape, true)
    bad = lm.points3d.at[4].add(jnp.array([0.4, 0.0, 0.0]))  # right wrist 40 cm off
    lm = dataclasses.replace(lm, points3d=bad, keypoints2d=lm.keypoints2d.at[4].add(80.0))
    use = jnp.ones(18, bool)
    start = true + 0.02 * jax.random.normal(jax.random.PRNGKey(0), (43,))
    settings = FitSettings(max_steps=30)
    fits = fit_hypotheses(
        jnp.stack([start, start]), shape, lm, INTR,
        use3d=jnp.stack([use, use.at[4].set(False)]),
        use2d=jnp.stack([use, use.at[4].set(False)]),
        settings=settings,
    )  # fmt: skip
    wrist = np.asarray(jax.vmap(lambda p: B.keypoints(shape, p))(fits.params))[:, 4]
    true_wrist = np.asarray(B.keypoints(shape, true))[4]
    assert np.linalg.norm(wrist[0] - true_wrist) > 0.1  # used: pulled away
    assert np.linalg.norm(wrist[1] - true_wrist) < 0.03  # excluded: the forearm stays put


def test_no_landmarks_returns_start_pose_not_nan(fit_jit):
    shape = B.BodyShape.default()
    true = _true_pose(3)
    lm = _landmarks(shape, true)
    none = jnp.zeros(18, bool)
    res = fit_jit(true, shape, lm, INTR, use3d=none, use2d=none, settings=FitSettings())
    assert np.isfinite(np.asarray(res.params)).all()
    np.testing.assert_allclose(
        np.asarray(B.keypoints(shape, res.params)), np.asarray(B.keypoints(shape, true)), atol=1e-3
    )


def test_initialisation_from_observations_alone(fit_jit):
    """No ground-truth start: initial_pose from landmarks, then LM, recovers the pose."""
    shape = B.BodyShape.default()
    for seed in range(4):
        rng = np.random.default_rng(seed)
        p = np.asarray(B.facing_camera_params(2.5), np.float64)
        # a person turned up to 60 degrees, limbs moved moderately
        yaw = rng.uniform(-1.0, 1.0)
        p[3:7] = [0.0, np.cos(yaw / 2), 0.0, np.sin(yaw / 2)]  # pi about x, then yaw
        p[7:] += rng.normal(size=36) * 0.15
        true = jnp.asarray(p, jnp.float32)
        lm = _landmarks(shape, true)
        p0 = initial_pose(np.asarray(lm.points3d), np.asarray(lm.has_depth), shape)
        assert p0 is not None
        all_ = jnp.ones(18, bool)
        res = fit_jit(
            jnp.asarray(p0, jnp.float32),
            shape,
            lm,
            INTR,
            use3d=all_,
            use2d=all_,
            settings=FitSettings(max_steps=60),
        )
        err = np.linalg.norm(
            np.asarray(B.keypoints(shape, res.params) - B.keypoints(shape, true)), axis=-1
        )
        assert err[list(B.BODY_JOINTS)].max() < 0.01, f"seed {seed}: {err.max() * 1000:.1f} mm"


def test_initial_pose_needs_a_torso():
    shape = B.BodyShape.default()
    lm = _landmarks(shape, _true_pose(0))
    has = np.zeros(18, bool)
    has[[3, 4, 9]] = True  # an elbow, a wrist and a knee only
    assert initial_pose(np.asarray(lm.points3d), has, shape) is None


def test_shape_estimation_recovers_a_different_person():
    truth = B.BodyShape.create(
        upper_arm=0.33,
        forearm=0.28,
        thigh=0.48,
        shin=0.46,
        torso=0.58,
        shoulder_width=0.2,
        hip_width=0.12,
    )
    pts, flags = [], []
    rng = np.random.default_rng(0)
    for seed in range(10):
        M = np.asarray(B.keypoints(truth, _true_pose(seed)))
        M = M + rng.normal(size=M.shape) * 0.005  # 5 mm noise
        has = rng.uniform(size=18) > 0.2
        pts.append(M)
        flags.append(has)
    est, ratios = estimate_shape(np.stack(pts), np.stack(flags))
    for field in ("upper_arm", "forearm", "thigh", "shin", "torso", "shoulder_width", "hip_width"):
        assert abs(float(getattr(est, field)) - float(getattr(truth, field))) < 0.015, field
    assert ratios["size"] > 1.05  # a larger person than the default


def test_shape_estimation_rejects_bad_shapes():
    with pytest.raises(ValueError, match="frame, 18, 3"):
        estimate_shape(np.zeros((4, 17, 3)), np.zeros((4, 17), bool))


def _about_x(deg: float) -> np.ndarray:
    return S.matrix_to_quat(S.rx(np.radians(deg)))


def _about_y(deg: float) -> np.ndarray:  # a thigh's twist about its own axis
    return S.matrix_to_quat(S.ry(np.radians(deg)))


def _with_joint(params, slot: int, quat) -> jnp.ndarray:
    p = np.asarray(params, np.float64).copy()
    p[3 + 4 * slot : 7 + 4 * slot] = quat
    return jnp.asarray(p, jnp.float32)


def test_leg_limits_zero_inside_the_range_and_pinned_to_the_model():
    """The limits read the model's own convention: a knee bent so that the ankle goes back
    (the body's -z) costs nothing, bent the other way it does; a hip's twist about the thigh
    costs past 45 degrees."""
    from posetrack._residuals import leg_limit_residuals

    shape = B.BodyShape.default()
    rest = np.zeros(43)
    rest[3::4] = 1.0  # every quaternion the identity: the body frame is the camera's
    ankle = np.asarray(B.keypoints(shape, jnp.asarray(rest, jnp.float32)))[13]
    back = _with_joint(rest, 9, _about_x(60.0))
    fore = _with_joint(rest, 9, _about_x(-30.0))
    assert np.asarray(B.keypoints(shape, back))[13, 2] < ankle[2] - 0.3  # goes back
    assert np.asarray(B.keypoints(shape, fore))[13, 2] > ankle[2] + 0.15  # goes forward
    np.testing.assert_array_equal(np.asarray(leg_limit_residuals(back)), 0.0)
    r = np.asarray(leg_limit_residuals(fore))
    assert r[3] > 0.3 and np.delete(r, 3).max() == 0.0  # the left knee's forward term only
    np.testing.assert_array_equal(
        np.asarray(leg_limit_residuals(_with_joint(rest, 6, _about_y(30)))), 0
    )
    assert np.asarray(leg_limit_residuals(_with_joint(rest, 6, _about_y(-90))))[0] > 0.2
    side = S.matrix_to_quat(S.rz(np.radians(40.0)))  # 40 degrees sideways
    assert np.asarray(leg_limit_residuals(_with_joint(rest, 7, side)))[4] > 0.3


def test_neck_limit_costs_only_a_head_turned_past_80_degrees_about_the_torso():
    """The neck limit reads the model's convention: turning the neck's quaternion about the
    body's y axis turns the face (the nose goes behind the neck at 180 degrees); up to 80
    degrees, and any nod or tilt, costs nothing; past it the cost grows with the turn."""
    from posetrack._residuals import neck_limit_residuals

    shape = B.BodyShape.default()
    rest = np.zeros(43)
    rest[3::4] = 1.0
    kp = np.asarray(B.keypoints(shape, jnp.asarray(rest, jnp.float32)))
    back = np.asarray(B.keypoints(shape, _with_joint(rest, 1, _about_y(180.0))))
    assert (kp[0] - kp[1])[2] > 0.08 and (back[0] - back[1])[2] < -0.08  # nose behind

    def cost(quat):
        return float(neck_limit_residuals(_with_joint(rest, 1, quat))[0])

    assert cost(_about_y(75.0)) == 0.0 and cost(_about_y(-75.0)) == 0.0
    assert cost(_about_x(60.0)) == 0.0 and cost(S.matrix_to_quat(S.rz(np.radians(40)))) == 0.0
    turned = [cost(_about_y(d)) for d in (90.0, 130.0, 180.0)]
    assert 0.0 < turned[0] < turned[1] < turned[2]
    assert cost(_about_y(-130.0)) == pytest.approx(turned[1], abs=1e-6)


def test_leg_limits_choose_the_backward_knee_an_ankle_seen_in_2d_allows(fit_jit):
    """An ankle seen only in 2D fits a shank folded toward the camera as well as the true one
    folded away (the depth ambiguity along its ray). From a start folded 20 degrees forward
    the paper's model folds on forward; with the limits the fit bends the knee back through
    straight, the way knees bend."""
    shape = B.BodyShape.default()
    true = _with_joint(B.facing_camera_params(2.6), 9, _about_x(60.0))
    # Put the ankle on the optical axis: the forward fold's ankle then projects to the same
    # pixel exactly (it differs from the true one in depth only).
    shift = np.zeros(43, np.float32)
    shift[:2] = -np.asarray(B.keypoints(shape, true))[13, :2]
    true = true + shift
    start = _with_joint(B.facing_camera_params(2.6), 9, _about_x(-20.0)) + shift
    lm = _landmarks(shape, true, depth_missing=(13,))
    all_ = jnp.ones(18, bool)
    truth = np.asarray(B.keypoints(shape, true))[13]
    errs = {}
    for w in (0.0, 1.0):
        settings = FitSettings(max_steps=30, residuals=ResidualSettings(loss="l2", leg_limits=w))
        res = fit_jit(start, shape, lm, INTR, use3d=all_, use2d=all_, settings=settings)
        errs[w] = np.linalg.norm(np.asarray(B.keypoints(shape, res.params))[13] - truth)
    assert errs[0.0] > 0.2, f"without limits the ankle should fold toward the camera: {errs}"
    assert errs[1.0] < 0.03, f"with limits the ankle should be found: {errs}"


def test_leg_cross_costs_only_legs_crossed_to_the_other_side():
    """The crossing limit reads the model's convention (the root's x is the subject's left):
    legs straight or spread cost nothing; a left thigh swung across past the right leg costs
    the metres by which its knee and its ankle crossed, however the body is turned."""
    from posetrack._residuals import leg_cross_residuals

    shape = B.BodyShape.default()
    rest = np.zeros(43)
    rest[3::4] = 1.0
    zero = np.asarray(leg_cross_residuals(jnp.asarray(rest, jnp.float32), shape))
    np.testing.assert_array_equal(zero, 0.0)
    swing = S.matrix_to_quat(S.rz(np.radians(30.0)))  # the left thigh out to the left
    spread = leg_cross_residuals(_with_joint(rest, 8, swing), shape)
    np.testing.assert_array_equal(np.asarray(spread), 0.0)
    for turn in (0.0, 90.0, -140.0):
        root = S.matrix_to_quat(S.ry(np.radians(turn)))
        across = _with_joint(_with_joint(rest, 0, root), 8, S.matrix_to_quat(S.rz(np.radians(-40))))
        kp = np.asarray(B.keypoints(shape, across))
        left_axis = np.asarray(S.ry(np.radians(turn)))[:, 0]
        want = [(kp[9] - kp[12]) @ left_axis, (kp[10] - kp[13]) @ left_axis]
        assert 0.03 < want[0] < want[1]  # the knee crossed by a little, the ankle by more
        got = np.asarray(leg_cross_residuals(across, shape))
        np.testing.assert_allclose(got, want, atol=1e-5)
    with pytest.raises(ValueError, match="leg_cross"):
        ResidualSettings(leg_cross=-1.0)


def test_leg_cross_keeps_a_side_view_from_following_exchanged_leg_labels(fit_jit):
    """A side view whose knee and ankle labels the detector exchanged: the paper's model
    fits them by swinging each thigh across the body (the far knee in front of the near one,
    the hips where they were); with the limit the legs stay on their own sides."""
    from posetrack._residuals import leg_cross_residuals

    shape = B.BodyShape.default()
    true = np.asarray(B.facing_camera_params(2.6), np.float64)
    face = np.asarray(S.quat_to_matrix(jnp.asarray(true[3:7])))
    true[3:7] = S.matrix_to_quat(face @ np.asarray(S.ry(np.radians(80.0))))
    true = jnp.asarray(true, jnp.float32)
    lm = _landmarks(shape, true)
    swap = np.asarray(B.flip_labels((9, 10, 12, 13)))
    lm = dataclasses.replace(lm, keypoints2d=lm.keypoints2d[swap], points3d=lm.points3d[swap])
    all_ = jnp.ones(18, bool)
    crossed = {}
    for w in (0.0, 10.0):
        settings = FitSettings(max_steps=30, residuals=ResidualSettings(loss="l2", leg_cross=w))
        res = fit_jit(true, shape, lm, INTR, use3d=all_, use2d=all_, settings=settings)
        crossed[w] = float(np.max(np.asarray(leg_cross_residuals(res.params, shape))))
    assert crossed[0.0] > 0.1, f"the paper's model should cross the legs: {crossed}"
    assert crossed[10.0] < 0.03, f"with the limit the legs should stay apart: {crossed}"
    # Fitted label-free (each knee and ankle pair whichever way round is closer), the
    # exchanged labels cost the true pose nothing: the legs stay where they are.
    free = FitSettings(max_steps=30, residuals=ResidualSettings(loss="l2", leg_labels_free=True))
    res = fit_jit(true, shape, lm, INTR, use3d=all_, use2d=all_, settings=free)
    legs = [9, 10, 12, 13]
    fitted, truth = (np.asarray(B.keypoints(shape, p))[legs] for p in (res.params, true))
    off = fitted - truth
    assert np.abs(off).max() < 0.01, off
    assert float(np.max(np.asarray(leg_cross_residuals(res.params, shape)))) == 0.0


def test_label_free_legs_only_side_on_with_a_turn_threshold():
    """``leg_labels_free_sin``: a pose facing the camera is held to the detector's leg labels
    (they carry its facing); turned side-on, exchanged leg labels cost it nothing."""
    shape = B.BodyShape.default()
    swap = np.asarray(B.flip_labels((9, 10, 12, 13)))
    all_ = jnp.ones(18, bool)
    legs = np.array([9, 10, 12, 13])

    def leg_cost(turn_deg, **kw):
        true = np.asarray(B.facing_camera_params(2.6), np.float64)
        face = np.asarray(S.quat_to_matrix(jnp.asarray(true[3:7])))
        true[3:7] = S.matrix_to_quat(face @ np.asarray(S.ry(np.radians(turn_deg))))
        true = jnp.asarray(true, jnp.float32)
        lm = _landmarks(shape, true)
        lm = dataclasses.replace(lm, keypoints2d=lm.keypoints2d[swap], points3d=lm.points3d[swap])
        mpp = pixel_scale(true, shape, INTR)
        r = landmark_residuals(
            true, shape, lm, INTR, use3d=all_, use2d=jnp.zeros(18, bool),
            metres_per_pixel=mpp, settings=ResidualSettings(loss="l2", **kw),
        )  # fmt: skip
        return float(np.abs(np.asarray(r)[legs]).max())

    for turn in (0.0, 80.0):
        assert leg_cost(turn) > 0.05  # as labelled, the exchanged legs cost the true pose
        assert leg_cost(turn, leg_labels_free=True) < 1e-5  # label-free in every pose
    gated = dict(leg_labels_free=True, leg_labels_free_sin=0.5)
    assert leg_cost(0.0, **gated) == pytest.approx(leg_cost(0.0))  # facing: labels hold
    assert leg_cost(80.0, **gated) < 1e-5  # side-on: either way round
    with pytest.raises(ValueError, match="leg_labels_free_sin"):
        ResidualSettings(leg_labels_free_sin=1.0)


def test_label_free_legs_keep_the_detected_labels_within_the_margin():
    """``leg_labels_margin``: a leg pair is taken the other way round only where that is
    cheaper than the labels as detected by the margin; within it the labels hold."""
    shape = B.BodyShape.default()
    true = jnp.asarray(B.facing_camera_params(2.6), jnp.float32)
    lm = _landmarks(shape, true)
    swap = np.asarray(B.flip_labels((9, 10, 12, 13)))
    legs = np.array([9, 10, 12, 13])
    # Exchanged leg labels, 3 cm off: the exchanged reading costs (3 cm)^2 per keypoint, the
    # labels as detected about a hip width squared (~40 times more).
    points = np.asarray(lm.points3d)[swap]
    points[legs, 0] += 0.03
    lm = dataclasses.replace(lm, points3d=jnp.asarray(points))

    def leg_residual(**kw):
        r = landmark_residuals(
            true, shape, lm, INTR, use3d=jnp.ones(18, bool), use2d=jnp.zeros(18, bool),
            metres_per_pixel=pixel_scale(true, shape, INTR),
            settings=ResidualSettings(loss="l2", **kw),
        )  # fmt: skip
        return float(np.linalg.norm(np.asarray(r)[legs, :3], axis=-1).max())

    labelled = leg_residual()
    assert labelled > 0.1
    for margin in (1.0, 4.0):  # exchanged: 3 cm off
        assert leg_residual(leg_labels_free=True, leg_labels_margin=margin) < 0.031
    assert leg_residual(leg_labels_free=True, leg_labels_margin=1000.0) == pytest.approx(labelled)
    with pytest.raises(ValueError, match="leg_labels_margin"):
        ResidualSettings(leg_labels_margin=0.5)
    # leg_terms_min: label-free only on frames with that many landmarks on depth (all
    # 18 here); one fewer and the labels hold.
    assert leg_residual(leg_labels_free=True, leg_terms_min=18) < 0.031
    lm = dataclasses.replace(lm, has_depth=lm.has_depth.at[4].set(False))
    assert leg_residual(leg_labels_free=True, leg_terms_min=18) == pytest.approx(labelled)
    with pytest.raises(ValueError, match="leg_terms_min"):
        ResidualSettings(leg_terms_min=19)
    # ... and the limit on crossed legs the same way: a left thigh swung across the right leg
    # costs at 18 landmarks on depth, nothing at 17.
    crossed = _with_joint(true, 8, S.matrix_to_quat(S.rz(np.radians(-40))))
    settings = ResidualSettings(leg_cross=10.0, leg_terms_min=18)
    full = jnp.ones(18, bool)
    reg = regulariser_residuals(crossed, crossed, settings, shape, full)
    assert float(jnp.abs(reg[-2:]).max()) > 0.05
    reg = regulariser_residuals(crossed, crossed, settings, shape, full.at[4].set(False))
    assert float(jnp.abs(reg[-2:]).max()) == 0.0
