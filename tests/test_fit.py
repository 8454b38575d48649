"""Levenberg-Marquardt fits (Eq. (1)-(2)), initialisation and body-shape estimation, checked
against known ground truth."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from posetrack import Intrinsics, project
from posetrack import _body as B
from posetrack._fit import FitSettings, fit_hypotheses, fit_pose
from posetrack._init import estimate_shape, initial_pose
from posetrack._observe import Landmarks
from posetrack._residuals import ResidualSettings

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
