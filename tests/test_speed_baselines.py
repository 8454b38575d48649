"""Correctness of the baselines in ``benchmarks/speed.py`` (not their timing).

The speed benchmark compares the batched tracker step with (a) a Python loop over hypotheses,
(b) scipy's Levenberg-Marquardt on posetrack's residuals and JAX Jacobian with the tracker's
step cap ("scipy_equal") and (c) scipy's Levenberg-Marquardt on a NumPy model with finite
differences, run to convergence ("scipy_converged"). Those comparisons mean something only if
the baselines compute the same thing: the NumPy forward kinematics and residuals equal
posetrack's, the converged scipy fit reaches a known pose, the capped scipy fit does exactly the
tracker fit's number of evaluations and gets as close to the landmarks, and the loop selects the
same pose with the same Delta as the batched step from the same state.
"""

import importlib.util
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack._fit import FitSettings, fit_pose, fit_problem, fit_residuals
from posetrack._residuals import ResidualSettings, landmark_residuals

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "speed.py"


@pytest.fixture(scope="module")
def speed():
    spec = importlib.util.spec_from_file_location("posetrack_bench_speed", _PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve annotations through sys.modules
    spec.loader.exec_module(module)
    return module


def _random_pose(rng, *, scale=0.6):
    """A pose 2-4 m in front of the camera with random, non-unit joint quaternions (wxyz)."""
    q = np.tile([1.0, 0.0, 0.0, 0.0], (10, 1)) + rng.normal(0.0, scale, (10, 4))
    q[0] = [0.0, 1.0, 0.0, 0.0] + rng.normal(0.0, 0.2, 4)  # facing the camera, roughly
    q *= rng.uniform(0.5, 2.0, (10, 1))
    t = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), rng.uniform(2.0, 4.0)])
    return np.concatenate([t, q.reshape(-1)])


def _shape(rng, dtype):
    fields = pt.BodyShape.default().to_dict()
    return pt.BodyShape.create(dtype, **{k: v * rng.uniform(0.85, 1.15) for k, v in fields.items()})


def test_numpy_fk_matches_posetrack_keypoints(speed, x64):
    rng = np.random.default_rng(0)
    for i in range(25):
        shape = _shape(rng, jnp.float64)
        s = shape.to_dict()
        joint_offs, kp_offs = speed.np_joint_offsets(s), speed.np_keypoint_offsets(s)
        params = _random_pose(rng, scale=0.6 if i % 3 else 1e-4)  # also near-identity joints
        ours = speed.np_keypoints(params, joint_offs, kp_offs)
        ref = np.asarray(pt.keypoints(shape, jnp.asarray(params)))
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)
        # q and -q are the same rotation (wxyz sign ambiguity).
        flipped = params.copy()
        flipped[3:] = -flipped[3:]
        np.testing.assert_allclose(
            speed.np_keypoints(flipped, joint_offs, kp_offs), ref, rtol=0, atol=1e-9
        )


def test_numpy_residuals_match_posetrack_l2_residuals(speed, x64):
    """The scipy baseline minimises exactly posetrack's Eq. (1) residuals in their l2 form."""
    rng = np.random.default_rng(1)
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
    settings = ResidualSettings(loss="l2")
    for _ in range(10):
        shape = _shape(rng, jnp.float64)
        model = speed.NumpyResiduals(shape, intr, settings)
        truth, start, params = (_random_pose(rng) for _ in range(3))
        M = model.keypoints(truth)
        lm_np = {
            "points3d": M + rng.normal(0.0, 0.02, M.shape),
            "keypoints2d": model.project(M) + rng.normal(0.0, 3.0, (18, 2)),
            "detected": rng.random(18) < 0.9,
        }
        lm_np["has_depth"] = lm_np["detected"] & (rng.random(18) < 0.7)
        use3d, use2d = rng.random(18) < 0.8, rng.random(18) < 0.8
        s0, u3, u2, mpp = model.setup(start, lm_np, use3d, use2d)
        ours = model(params, s0, lm_np, u3, u2, mpp)

        lm = pt.Landmarks(
            keypoints2d=jnp.asarray(lm_np["keypoints2d"]),
            confidence=jnp.ones(18),
            points3d=jnp.asarray(lm_np["points3d"]),
            detected=jnp.asarray(lm_np["detected"]),
            has_depth=jnp.asarray(lm_np["has_depth"]),
        )
        # As fit_pose builds its residual function.
        _, args = fit_problem(
            jnp.asarray(start), shape, lm, intr,
            use3d=jnp.asarray(use3d), use2d=jnp.asarray(use2d), residuals=settings,
        )  # fmt: skip
        ref = np.asarray(fit_residuals(jnp.asarray(params), args))
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)


def test_scipy_baseline_recovers_a_known_pose(speed, x64):
    """Noise-free landmarks of a known pose, start 20 cm / ~0.3 rad away: scipy's LM on the
    NumPy model finds the pose (up to the weak pull toward the start)."""
    rng = np.random.default_rng(2)
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
    shape = pt.BodyShape.default(jnp.float64)
    model = speed.NumpyResiduals(shape, intr)
    truth = speed.np_normalize_params(_random_pose(rng, scale=0.3))
    M = model.keypoints(truth)
    lm = {
        "points3d": M,
        "keypoints2d": model.project(M),
        "detected": np.ones(18, bool),
        "has_depth": np.arange(18) % 4 != 0,  # some keypoints 2D only
    }
    start = truth + np.concatenate([[0.2, -0.1, 0.1], rng.normal(0.0, 0.08, 40)])
    assert np.abs(model.keypoints(start) - M).max() > 0.1
    params, evals = model.fit(start, lm, np.ones(18, bool), np.ones(18, bool))
    assert evals > 43  # at least one finite-difference Jacobian
    err = np.linalg.norm(model.keypoints(params) - M, axis=-1)
    assert err.max() < 2e-3, err.max()


def test_scipy_equal_work_fit_does_the_tracker_fits_work_and_gets_as_close(speed, x64):
    """Baseline (b): ``max_nfev = max_steps`` makes scipy evaluate the residuals and the
    Jacobian exactly ``max_steps`` times each (as optimistix' ``max_steps`` does), and its fit
    gets about as close to the landmarks as posetrack's ``fit_pose`` from the same start with
    the same masks: it is neither crippled nor given more work."""
    rng = np.random.default_rng(3)
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
    shape = pt.BodyShape.default(jnp.float64)
    settings = FitSettings(max_steps=4, residuals=ResidualSettings(loss="l2"))
    fitter = speed.ScipyEqualFit(shape, intr, settings)
    model = speed.NumpyResiduals(shape, intr)
    fit = jax.jit(fit_pose, static_argnames="settings")

    def cost(params, start, lm, use3d, use2d):
        """``FitResult.cost`` of ``params`` for the problem ``fit_pose`` builds."""
        _, args = fit_problem(
            start, shape, lm, intr, use3d=use3d, use2d=use2d, residuals=settings.residuals
        )
        _, _, _, u3, u2, mpp, _, _ = args
        r = landmark_residuals(
            jnp.asarray(speed.np_normalize_params(np.asarray(params))), shape, lm, intr,
            use3d=u3, use2d=u2, metres_per_pixel=mpp, settings=settings.residuals,
        )  # fmt: skip
        return float(jnp.sum(r * r))

    ratios = []
    for _ in range(6):
        truth = speed.np_normalize_params(_random_pose(rng, scale=0.3))
        M = model.keypoints(truth)
        detected = rng.random(18) < 0.9
        lm = pt.Landmarks(
            keypoints2d=jnp.asarray(model.project(M) + rng.normal(0.0, 2.0, (18, 2))),
            confidence=jnp.ones(18),
            points3d=jnp.asarray(M + rng.normal(0.0, 0.01, M.shape)),
            detected=jnp.asarray(detected),
            has_depth=jnp.asarray(detected & (rng.random(18) < 0.8)),
        )
        use3d = jnp.asarray(rng.random(18) < 0.8)
        use2d = jnp.asarray(rng.random(18) < 0.8)
        # A tracking-like start: a few centimetres and degrees away.
        start = jnp.asarray(truth + np.concatenate([rng.normal(0.0, 0.05, 3),
                                                    rng.normal(0.0, 0.08, 40)]))  # fmt: skip
        ours = fit(start, shape, lm, intr, use3d=use3d, use2d=use2d, settings=settings)
        theirs = fitter.fit(start, lm, use3d, use2d)
        # The budget: 4 residual evaluations (start + 3 trial points), 3 Jacobians in MINPACK
        # and scipy's final one; optimistix' 4 steps evaluate both at the start + 3 points.
        assert fitter.nfev[-1] == 4 and fitter.fun_calls[-1] == 4
        assert fitter.njev[-1] <= 3 and fitter.jac_calls[-1] == fitter.njev[-1] + 1
        assert int(ours.num_steps) == 4
        c0 = cost(start, start, lm, use3d, use2d)
        c_scipy = cost(theirs, start, lm, use3d, use2d)
        np.testing.assert_allclose(cost(ours.params, start, lm, use3d, use2d), float(ours.cost),
                                   rtol=1e-9)  # fmt: skip
        assert c_scipy < 0.1 * c0, (c_scipy, c0)  # it did real work
        ratios.append(c_scipy / float(ours.cost))
    # Comparable: on no problem much worse than posetrack's fit after the same work.
    assert max(ratios) < 2.0, ratios


def test_loop_baseline_selects_what_the_batched_step_selects(speed):
    """Same state, masks and starts: the loop over hypotheses (baseline a) and the batched
    step pick the same hypothesis with the same pose and Delta, two frames in a row.

    Without the consensus refit, which both run through the same library function
    (``consensus_refit``) and which would double the compile time of this test.
    """
    frames = speed.Frames.make(4)
    config = pt.TrackerConfig.paper(
        "mht_h", num_hypotheses=3, r=0.05, R=0.15, consensus_refit=False
    )
    batched = speed.StepRunner(frames, config)
    loop = speed.LoopRunner(frames, config)
    assert jnp.array_equal(batched.state.hypotheses, loop.state.hypotheses)
    for t in (1, 2):
        batched.advance(t)
        loop.advance(t)
        est = batched.last
        chosen, chosen_delta, best, kp = loop.last
        assert int(est.best) == best
        np.testing.assert_allclose(float(est.delta), float(chosen_delta), atol=1e-5)
        np.testing.assert_allclose(np.asarray(est.keypoints3d), np.asarray(kp), atol=1e-4)
        # The hypotheses differ (the subsets are random), so the selection was a real choice.
        assert np.ptp(np.asarray(est.deltas)) > 0
        # And the carried states agree (reseed, previous keypoints, key).
        np.testing.assert_allclose(
            np.asarray(batched.state.hypotheses), np.asarray(loop.state.hypotheses), atol=1e-4
        )
        assert np.array_equal(np.asarray(batched.state.key), np.asarray(loop.state.key))
