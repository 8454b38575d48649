"""The motion model (``_smooth.py``), the motion metrics, and the tracker's three modes.

The smoother is checked against a ground truth it did not make: a smooth motion whose
per-frame estimates carry independent noise; the solver's block elimination against a dense
solve; the modes against each other on one generated clip.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import quick_refine

import posetrack as pt
from posetrack import _arbitration, _body, _limbs, _smooth, _tracker
from posetrack._observe import Landmarks

# -- metrics ----------------------------------------------------------------------------------


def _walk_truth(T=40):
    t = np.arange(T)[:, None, None]
    base = np.random.default_rng(0).normal(size=(1, 18, 3)) * 0.3 + [0.0, 0.0, 2.5]
    return base + 0.2 * np.sin(t / 6.0) * np.array([1.0, 0.0, 0.3])


def test_acceleration_error_ignores_offsets_and_counts_a_spike():
    g = _walk_truth()
    assert pt.acceleration_error(g + [0.05, -0.02, 0.1], g) == pytest.approx(0.0, abs=1e-6)
    est = g.copy()
    est[10, list(pt.BODY_JOINTS), 0] += 0.010  # a 10 mm jump in one frame
    # Triples centred at 9, 10, 11 see 10, 20, 10 mm; 38 triples in all.
    assert pt.acceleration_error(est, g) == pytest.approx(40.0 / 38.0, rel=1e-6)
    est[5] = np.nan  # triples with a missing frame are skipped
    assert np.isfinite(pt.acceleration_error(est, g))


def test_swapped_limbs_needs_the_swap_to_be_closer_by_the_margin():
    g = _walk_truth(5)
    g[:, 4] = g[:, 7] + [0.3, 0.0, 0.0]  # wrists 300 mm apart
    est = g.copy()
    est[2, [4, 7]] = g[2, [7, 4]]  # frame 2: wrists exchanged
    swapped = pt.swapped_limbs(est, g)
    assert swapped[2, 1] and swapped.sum() == 1
    assert pt.swapped_limb_frames(est, g) == 1
    assert pt.swapped_limb_frames(est, g, margin_mm=700.0) == 0  # 600 mm gain < 700


def test_swapped_limbs_takes_other_pairs():
    """``pairs`` (e.g. a left/right group's): the shoulders exchanged count there, not among
    the default limb pairs."""
    g = _walk_truth(5)
    g[:, 2] = g[:, 5] + [0.3, 0.0, 0.0]  # shoulders 300 mm apart
    est = g.copy()
    est[3, [2, 5]] = g[3, [5, 2]]
    torso = pt.swapped_limbs(est, g, pairs=pt.SIDE_GROUPS["torso"])
    assert torso.shape == (5, 2) and torso[3, 0] and torso.sum() == 1
    assert not pt.swapped_limbs(est, g).any()


def test_jitter_and_gaussian_filter():
    still = np.tile(_walk_truth(1), (20, 1, 1))
    assert pt.jitter(still) == pytest.approx(0.0, abs=1e-9)
    noisy = still + np.random.default_rng(1).normal(scale=0.01, size=still.shape)
    assert pt.jitter(pt.gaussian_smoothed(noisy, 2.0)) < 0.4 * pt.jitter(noisy)
    ramp = _walk_truth(30)
    ramp[12] = np.nan
    out = pt.gaussian_smoothed(ramp, 2.0)
    assert np.isnan(out[12]).all() and np.isfinite(out[13]).all()
    line = np.linspace(0, 1, 30)[:, None, None] * np.ones((1, 18, 3))
    np.testing.assert_allclose(pt.gaussian_smoothed(line, 2.0)[9:21], line[9:21], atol=1e-9)


# -- the solver -------------------------------------------------------------------------------


def test_block_tridiagonal_solve_matches_a_dense_solve():
    rng = np.random.default_rng(2)
    K, n = 5, 4
    D = rng.normal(size=(K, n, n))
    D = np.einsum("kij,klj->kil", D, D) + 8 * np.eye(n)
    U = rng.normal(size=(K, n, n))
    b = rng.normal(size=(K, n))
    dense = np.zeros((K * n, K * n))
    for k in range(K):
        dense[k * n : (k + 1) * n, k * n : (k + 1) * n] = D[k]
        if k + 1 < K:
            dense[k * n : (k + 1) * n, (k + 1) * n : (k + 2) * n] = U[k]
            dense[(k + 1) * n : (k + 2) * n, k * n : (k + 1) * n] = U[k].T
    f32 = [jnp.asarray(x, jnp.float32) for x in (D, U, b)]
    x = _smooth._block_tridiagonal_solve(*f32)
    np.testing.assert_allclose(
        np.asarray(x).reshape(-1), np.linalg.solve(dense, b.reshape(-1)), rtol=1e-4, atol=1e-5
    )


@pytest.fixture(scope="module")
def noisy_motion():
    """A smooth motion (root sway, an elbow bending) estimated per frame with 25 mm noise."""
    T = 32
    shape = pt.BodyShape.default(jnp.float32)
    rng = np.random.default_rng(3)
    base = np.asarray(pt.facing_camera_params(2.5), np.float32)
    truth = np.tile(base, (T, 1))
    t = np.arange(T)
    truth[:, 0] = 0.15 * np.sin(t / 5.0)
    truth[:, 2] = 2.5 + 0.1 * np.cos(t / 7.0)
    kp_true = np.asarray(jax.vmap(lambda p: pt.keypoints(shape, p))(jnp.asarray(truth)))
    est = truth.copy()
    est[:, :3] += rng.normal(scale=0.025, size=(T, 3))
    landmarks = Landmarks(
        keypoints2d=np.zeros((T, 18, 2), np.float32),
        confidence=np.ones((T, 18), np.float32),
        points3d=(kp_true + rng.normal(scale=0.025, size=kp_true.shape)).astype(np.float32),
        detected=np.ones((T, 18), bool),
        has_depth=np.ones((T, 18), bool),
    )
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=160.0, cy=120.0, width=320, height=240)
    intr = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), intr)
    return shape, intr, truth, kp_true, est, landmarks


def _smooth_window(noisy_motion, valid):
    shape, intr, _, _, est, lm = noisy_motion
    settings = pt.SmoothSettings()
    use3d, use2d = _smooth.consensus_masks(shape, intr, jnp.asarray(est), lm, 0.12)
    out = _smooth.smooth_window_jit(
        settings, shape, intr, jnp.asarray(est), jax.tree.map(jnp.asarray, lm), use3d, use2d,
        jnp.asarray(valid), jnp.asarray(30.0, jnp.float32), jnp.ones((len(est), 18)),
    )  # fmt: skip
    return np.asarray(out), np.asarray(jax.vmap(lambda p: pt.keypoints(shape, p))(out))


def test_smoother_recovers_a_smooth_motion_from_noisy_frames(noisy_motion):
    shape, _, _, kp_true, est, _ = noisy_motion
    kp_est = np.asarray(jax.vmap(lambda p: pt.keypoints(shape, p))(jnp.asarray(est)))
    _, kp_s = _smooth_window(noisy_motion, np.ones(len(est), bool))
    before = pt.accuracy(kp_est, kp_true).mean_mm
    after = pt.accuracy(kp_s, kp_true).mean_mm
    assert after < 0.7 * before, (before, after)
    assert pt.acceleration_error(kp_s, kp_true) < 0.2 * pt.acceleration_error(kp_est, kp_true)


def test_invalid_frames_are_returned_unchanged(noisy_motion):
    _, _, _, _, est, _ = noisy_motion
    valid = np.ones(len(est), bool)
    valid[:5] = False
    params, _ = _smooth_window(noisy_motion, valid)
    np.testing.assert_array_equal(params[:5], est[:5])
    assert np.abs(params[5:] - est[5:]).max() > 1e-3


def test_settings_reject_bad_values():
    with pytest.raises(ValueError, match="accel_std"):
        pt.SmoothSettings(accel_std=0.0)
    with pytest.raises(ValueError, match="window"):
        pt.SmoothSettings(window=7)
    with pytest.raises(ValueError, match="online_accel_std"):
        pt.SmoothSettings(online_accel_std=-1.0)
    with pytest.raises(ValueError, match="online_iterations"):
        pt.SmoothSettings(online_iterations=0)
    with pytest.raises(ValueError, match="outlier_distance"):
        pt.SmoothSettings(outlier_distance=0.0)
    with pytest.raises(ValueError, match="outlier_frames"):
        pt.SmoothSettings(outlier_frames=0)


def _limb_track(T=20):
    """Per-frame poses whose right elbow bends steadily, their (stand-in) keypoints moving
    smoothly, and full confidence."""
    params = np.tile(np.asarray(pt.facing_camera_params(2.5), np.float32), (T, 1))
    angle = np.linspace(0.0, 1.0, T)
    params[:, 15:19] = np.stack(  # right elbow (joint 3): a rotation about x
        [np.cos(angle / 2), np.sin(angle / 2), 0 * angle, 0 * angle], axis=1
    )
    kps = _walk_truth(T)
    return params, kps, np.ones((T, 18), np.float32), np.ones(T, bool)


def test_interpolated_start_replaces_only_the_outlying_limb_of_a_doubtful_frame():
    settings = pt.SmoothSettings()
    params, kps, conf, valid = _limb_track()
    kps[10, 4] += [0.0, -0.6, 0.0]  # the right wrist pulled 60 cm up at frame 10 ...
    params[10, 11:19] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]  # ... the arm with it
    # Confident: a real motion, kept.
    out, replaced = _smooth.interpolated_start(settings, params, kps, conf, valid)
    np.testing.assert_array_equal(out, params)
    assert not replaced.any()
    conf[10, 4] = 0.1  # the tracker doubted it
    out, replaced = _smooth.interpolated_start(settings, params, kps, conf, valid)
    assert replaced.sum() == 1 and replaced[10, 0]  # the right arm at frame 10, nothing else
    changed = np.flatnonzero((out != params).any(axis=0))
    assert set(changed) <= set(range(11, 19)), changed  # right shoulder and elbow only
    np.testing.assert_array_equal(np.delete(out, 10, axis=0), np.delete(params, 10, axis=0))
    # Halfway between its neighbours: the shoulder as at frames 9 and 11, the elbow between.
    np.testing.assert_allclose(out[10, 11:15], params[9, 11:15], atol=1e-6)
    mid = params[9, 15:19] + params[11, 15:19]
    np.testing.assert_allclose(out[10, 15:19], mid / np.linalg.norm(mid), atol=1e-6)
    # A frame without a pose is neither a neighbour nor changed; off means off.
    valid[9] = False
    out, _ = _smooth.interpolated_start(settings, params, kps, conf, valid)
    np.testing.assert_array_equal(out[9], params[9])
    mid = params[8, 15:19] + 2 * params[11, 15:19]  # frame 10 is a third of the way from 8
    np.testing.assert_allclose(out[10, 15:19], mid / np.linalg.norm(mid), atol=1e-6)
    off = dataclasses.replace(settings, outlier_distance=float("inf"))
    np.testing.assert_array_equal(_smooth.interpolated_start(off, params, kps, conf, valid)[0],
                                  params)  # fmt: skip


def test_interpolated_start_leaves_a_limb_without_a_neighbour_on_one_side():
    params, kps, conf, valid = _limb_track()
    kps[19, 10] += [0.5, 0.0, 0.0]  # the right ankle at the last frame
    conf[19, 10] = 0.0
    params[19, 27:35] = [0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]
    out, replaced = _smooth.interpolated_start(pt.SmoothSettings(), params, kps, conf, valid)
    np.testing.assert_array_equal(out, params)
    assert not replaced.any()


def test_smooth_sequence_starts_from_the_interpolated_start(monkeypatch):
    """The offline smoother's windows receive the repaired start (no compilation: the window
    program is replaced by one that records its input)."""
    settings = pt.SmoothSettings()
    params, kps, conf, valid = _limb_track()
    kps[10, 4] += [0.0, -0.6, 0.0]
    params[10, 11:19] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    conf[10, 4] = 0.1
    seen = []

    def window(settings, shape, intrinsics, p, *rest):
        seen.append(np.asarray(p))
        return p, jnp.zeros((p.shape[0], 18, 3))

    monkeypatch.setattr(_smooth, "smooth_window_program", window)
    lm = Landmarks(
        keypoints2d=np.zeros((20, 18, 2), np.float32), confidence=conf,
        points3d=kps.astype(np.float32), detected=np.ones((20, 18), bool),
        has_depth=np.ones((20, 18), bool),
    )  # fmt: skip
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=160.0, cy=120.0, width=320, height=240)
    _, _, interpolated = _smooth.smooth_sequence(
        settings, pt.BodyShape.default(jnp.float32), intr, params, lm, valid, fps=30.0,
        keypoints=kps, pose_confidence=conf,
    )  # fmt: skip
    expected, replaced = _smooth.interpolated_start(settings, params, kps, conf, valid)
    assert len(seen) == 1
    np.testing.assert_array_equal(seen[0][:20], expected)
    assert not np.array_equal(expected, params)
    # ... and says which limb it started from its neighbours, where (TrackResult.interpolated).
    np.testing.assert_array_equal(interpolated, replaced)
    assert pt.LIMB_NAMES[0] == "right arm" and np.flatnonzero(interpolated[:, 0]).tolist() == [10]
    assert not interpolated[:, 1:].any()


def test_crossfade_weights_hand_over_from_the_earlier_window():
    w = _smooth.crossfade_weights(16)
    assert w.shape == (16,) and np.all(np.diff(w) < 0)
    np.testing.assert_allclose(w[[0, -1]], [16 / 17, 1 / 17], rtol=1e-6)
    np.testing.assert_allclose(w + w[::-1], 1.0, rtol=1e-6)  # symmetric: neither edge favoured
    assert _smooth.crossfade_weights(0).shape == (0,)


def _random_poses(n, seed):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 43)).astype(np.float32)
    q = p[:, 3:].reshape(n, 10, 4)
    p[:, 3:] = (q / np.linalg.norm(q, axis=-1, keepdims=True)).reshape(n, 40)
    return p


def test_blend_params_interpolates_positions_and_rotations():
    a, b = _random_poses(3, 0), _random_poses(3, 1)
    w = np.array([[1.0], [0.0], [0.25]], np.float32)
    out = np.asarray(_smooth.blend_params(jnp.asarray(a), jnp.asarray(b), jnp.asarray(w)))
    # Weight 1 gives a's rotations (their signs b's: q and -q are one rotation), weight 0 b.
    np.testing.assert_allclose(out[0, :3], a[0, :3], atol=1e-6)
    sign = np.sign(np.sum(out[0, 3:].reshape(10, 4) * a[0, 3:].reshape(10, 4), -1))
    np.testing.assert_allclose(
        out[0, 3:].reshape(10, 4), sign[:, None] * a[0, 3:].reshape(10, 4), atol=1e-6
    )
    np.testing.assert_array_equal(
        sign * np.sum(a[0, 3:].reshape(10, 4) * b[0, 3:].reshape(10, 4), -1) >= 0, True
    )
    np.testing.assert_allclose(out[1], b[1], atol=1e-6)
    np.testing.assert_allclose(out[2, :3], 0.25 * a[2, :3] + 0.75 * b[2, :3], atol=1e-6)
    q = out[:, 3:].reshape(3, 10, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-6)
    # Each rotation lies on the shorter arc between the two, at a quarter of the way from b.
    ang = lambda x, y: 2 * np.arccos(np.clip(np.abs(np.sum(x * y, -1)), 0, 1))  # noqa: E731
    qa, qb = a[2, 3:].reshape(10, 4), b[2, 3:].reshape(10, 4)
    np.testing.assert_allclose(ang(q[2], qb) + ang(q[2], qa), ang(qa, qb), atol=1e-4)
    assert np.all(ang(q[2], qb) < ang(q[2], qa) + 1e-6)
    # q and -q are one rotation: flipping a's signs changes nothing.
    a_flipped = a.copy()
    a_flipped[:, 3:] *= -1
    out_f = _smooth.blend_params(jnp.asarray(a_flipped), jnp.asarray(b), jnp.asarray(w))
    np.testing.assert_allclose(np.asarray(out_f)[1:], out[1:], atol=1e-6)


def test_blend_window_blends_only_weighted_valid_frames_and_gives_their_keypoints():
    shape = pt.BodyShape.default(jnp.float32)
    P, prev = _random_poses(4, 2), _random_poses(4, 3)
    valid = jnp.asarray([True, True, False, True])
    weight = jnp.asarray([0.5, 0.0, 0.5, 0.0], jnp.float32)
    out, kps = _smooth.blend_window(shape, jnp.asarray(P), valid, jnp.asarray(prev), weight)
    out = np.asarray(out)
    np.testing.assert_array_equal(out[1:], P[1:])  # weight 0 or not valid: bit for bit
    half = _smooth.blend_params(jnp.asarray(prev[:1]), jnp.asarray(P[:1]), jnp.full((1, 1), 0.5))
    np.testing.assert_allclose(out[0], np.asarray(half)[0], atol=1e-6)
    model = np.stack([np.asarray(_body.keypoints(shape, jnp.asarray(p))) for p in out])
    np.testing.assert_allclose(np.asarray(kps), model, atol=1e-5)


def _recording_window(seen):
    """A stand-in for the window program: records its poses and the blend it was given,
    returns each frame's poses shifted by the call's number (so windows disagree)."""

    def window(settings, shape, intrinsics, p, lm, valid, fps, conf, kps, prev, prev_w):
        seen.append((np.asarray(p), np.asarray(prev), np.asarray(prev_w)))
        out = np.asarray(p).copy()
        out[:, 0] += len(seen)
        return jnp.asarray(out), jnp.zeros((p.shape[0], 18, 3))

    return window


@pytest.mark.parametrize("crossfade", [False, True])
def test_smooth_sequence_hands_each_window_the_last_ones_shared_frames(monkeypatch, crossfade):
    """Cut: each window's middle frames kept, no blend asked for. Cross-fade: each window
    after the first gets the earlier window's poses of the shared frames with
    :func:`crossfade_weights`, and keeps all its frames (the blend is done in the program)."""
    settings = pt.SmoothSettings(window=8, overlap=4, crossfade=crossfade)
    T = 14  # windows [0, 8) and [4, 12) ... [8, 14): three calls
    params = np.tile(_body.facing_camera_params_np(2.5), (T, 1))
    params[:, 1] = np.arange(T)
    seen = []
    monkeypatch.setattr(_smooth, "smooth_window_program", _recording_window(seen))
    kps = np.zeros((T, 18, 3), np.float32)
    lm = Landmarks(
        keypoints2d=np.zeros((T, 18, 2), np.float32), confidence=np.ones((T, 18), np.float32),
        points3d=kps, detected=np.ones((T, 18), bool), has_depth=np.ones((T, 18), bool),
    )  # fmt: skip
    intr = pt.Intrinsics.create(fx=525.0, fy=525.0, cx=160.0, cy=120.0, width=320, height=240)
    out, _, _ = _smooth.smooth_sequence(
        settings, pt.BodyShape.default(jnp.float32), intr, params, lm, np.ones(T, bool),
        fps=30.0, keypoints=kps,
    )  # fmt: skip
    assert len(seen) == 3
    assert not seen[0][2].any()
    shift = out[:, 0] - params[:, 0]  # which call's output each frame holds
    if not crossfade:
        assert all(not w.any() for _, _, w in seen)
        np.testing.assert_array_equal(shift, [1] * 6 + [2] * 4 + [3] * 4)
        return
    for k in (1, 2):
        _, prev, w = seen[k]
        np.testing.assert_allclose(w[:4], _smooth.crossfade_weights(4))
        assert not w[4:].any()
        start = 4 * k
        np.testing.assert_allclose(prev[:4, 0], params[start : start + 4, 0] + k)
        np.testing.assert_allclose(prev[:4, 1], np.arange(start, start + 4))
    np.testing.assert_array_equal(shift, [1] * 4 + [2] * 4 + [3] * 6)


def test_limb_names_follow_the_limbs_keypoints():
    """``LIMB_NAMES`` (summary.json's ``limbs_interpolated``) names each limb's keypoints."""
    for name, (*_, mid, end) in zip(pt.LIMB_NAMES, _limbs.LIMBS, strict=True):
        side, part = name.split()
        joints = ("elbow", "wrist") if part == "arm" else ("knee", "ankle")
        expect = tuple(f"{side}_{j}" for j in joints)
        assert (pt.KEYPOINT_NAMES[mid], pt.KEYPOINT_NAMES[end]) == expect, name


def test_keypoint_smoother_removes_noise_and_keeps_a_straight_line():
    rng = np.random.default_rng(3)
    T = 12
    line = np.linspace(0.0, 0.3, T)[:, None, None] * np.ones((1, 18, 3)) + [0.0, 0.0, 2.5]
    conf = jnp.full((T, 18), 0.8, jnp.float32)
    valid = jnp.ones(T, bool)
    w = pt.SmoothSettings().online_weight(30.0)
    # A straight line has no acceleration: the prior leaves it where it is.
    out = _smooth.smooth_keypoints(jnp.asarray(line, jnp.float32), conf, valid, w)
    np.testing.assert_allclose(np.asarray(out), line, atol=1e-4)
    noisy = line + rng.normal(scale=0.02, size=line.shape)
    out = np.asarray(_smooth.smooth_keypoints(jnp.asarray(noisy, jnp.float32), conf, valid, w))
    assert np.abs(out - line).mean() < 0.6 * np.abs(noisy - line).mean()
    # Frames outside the track come back unchanged and do not pull the others.
    valid = valid.at[:3].set(False)
    moved = noisy.copy()
    moved[:3] += 1.0
    a = np.asarray(_smooth.smooth_keypoints(jnp.asarray(moved, jnp.float32), conf, valid, w))
    b = np.asarray(_smooth.smooth_keypoints(jnp.asarray(noisy, jnp.float32), conf, valid, w))
    np.testing.assert_array_equal(a[:3], moved[:3].astype(np.float32))
    np.testing.assert_allclose(a[3:], b[3:], atol=1e-5)


def test_online_robust_smoothing_pulls_less_toward_an_outlying_frame():
    T = 12
    line = np.linspace(0.0, 0.3, T)[:, None, None] * np.ones((1, 18, 3)) + [0.0, 0.0, 2.5]
    kps = line.copy()
    kps[7, 4] += [0.4, 0.0, 0.0]  # the right wrist 40 cm off in one frame
    window = _smooth.OnlineWindow(
        keypoints=jnp.asarray(kps, jnp.float32), confidence=jnp.full((T, 18), 0.8),
        params=jnp.zeros((T, 43)), valid=jnp.ones(T, bool),
    )  # fmt: skip
    plain = np.asarray(_smooth._online_smooth(pt.SmoothSettings(online_robust=0.0), window, 30.0))
    robust = np.asarray(_smooth._online_smooth(pt.SmoothSettings(online_robust=0.05), window, 30.0))
    # the default smooths robustly (0.05 m)
    default = np.asarray(_smooth._online_smooth(pt.SmoothSettings(), window, 30.0))
    np.testing.assert_array_equal(default, robust)
    off = lambda x: np.linalg.norm(x[:, 4] - line[:, 4], axis=-1)  # noqa: E731
    # The neighbours of the outlying frame are pulled less toward it, and so is the frame.
    assert off(robust)[[5, 6, 8, 9]].max() < 0.5 * off(plain)[[5, 6, 8, 9]].max()
    assert off(robust)[7] < off(plain)[7]
    # Keypoints without an outlier are smoothed alike (a straight line stays straight).
    np.testing.assert_allclose(robust[:, 0], line[:, 0], atol=1e-4)
    with pytest.raises(ValueError, match="online_robust"):
        pt.SmoothSettings(online_robust=-0.1)


def test_pose_from_keypoints_recovers_a_pose_from_its_keypoints(noisy_motion):
    shape, _, truth, kp_true, est, _ = noisy_motion
    fit = jax.jit(_smooth.pose_from_keypoints, static_argnums=3)
    p = fit(shape, jnp.asarray(est[7]), jnp.asarray(kp_true[7]), 3)
    err = np.linalg.norm(np.asarray(pt.keypoints(shape, p)) - kp_true[7], axis=-1).max()
    start_err = np.linalg.norm(
        np.asarray(pt.keypoints(shape, jnp.asarray(est[7]))) - kp_true[7], axis=-1
    ).max()
    assert err < 2e-3 < start_err


def test_online_window_push_keeps_the_newest_frames_last():
    win = _smooth.OnlineWindow.empty(4)
    for i in range(6):
        win = win.push(jnp.full((18, 3), float(i)), jnp.ones(18), jnp.zeros(43), i % 2 == 0)
    np.testing.assert_array_equal(np.asarray(win.keypoints[:, 0, 0]), [2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(np.asarray(win.valid), [True, False, True, False])


# -- the tracker's modes ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def clip():
    return pt.synth.generate(531, motion="reach", n_frames=40, width=320, height=240)


@pytest.fixture(scope="module")
def modes(clip):
    args = (clip.depth, clip.keypoints2d, clip.confidence, clip.intrinsics)
    return {
        "per-frame": pt.track(*args, mode="per-frame"),
        "offline": pt.track(*args),
        "offline, kp shape": pt.track(*args, refine=None),
        "online": pt.track(*args, mode="online"),  # the default lag, ONLINE_LAG
        "online0": pt.track(*args, mode="online", lag=0),
    }


@pytest.fixture(scope="module")
def one_way(clip):
    """The offline mode with the forward pass alone (``both_ways=False``, the default): its
    tracker and result."""
    tr = pt.Tracker(clip.intrinsics, motion=pt.SmoothSettings(both_ways=False))
    return tr, tr.run(clip.depth, clip.keypoints2d, clip.confidence)


@pytest.fixture(scope="module")
def online_lag0_kp_shape(clip):
    """Online at lag 0 without the body-shape refinement."""
    return pt.track(
        clip.depth, clip.keypoints2d, clip.confidence, clip.intrinsics, mode="online", lag=0,
        refine=None,
    )  # fmt: skip


def test_online_refines_the_body_shape_causally(clip, modes, online_lag0_kp_shape):
    """Online, the body shape is refined once, after ``online_after`` tracked frames, on
    frames already seen: every frame up to then is what the tracker gives without the
    refinement (nothing from the future), the frames after use the refined shape."""
    args = (clip.depth, clip.keypoints2d, clip.confidence)
    # 8 frames, after 16 tracked frames.
    settings = quick_refine("online", online_after=16, online_first=0)
    tr = pt.Tracker(clip.intrinsics, mode="online", lag=0, refine=settings)
    res = tr.run(*args)
    plain = online_lag0_kp_shape
    used = tr.refine_report["frames_used"]
    assert len(used) == 8 and used.max() < 16 and tr.refine_s > 0
    tracked = np.flatnonzero(res.status == 0)
    at = int(tracked[15])  # the 16th tracked frame: the refinement ran after its update
    np.testing.assert_array_equal(res.keypoints3d[: at + 1], plain.keypoints3d[: at + 1])
    assert not np.array_equal(res.keypoints3d[at + 1 :], plain.keypoints3d[at + 1 :])
    before = plain.shape.to_dict()
    changed = [k for k, v in res.shape.to_dict().items() if abs(v - before[k]) > 1e-4]
    assert len(changed) >= 5, changed
    # The refinement the offline mode runs on frames spread over the whole clip and this one
    # start from the same shape and end near each other (the same person).
    off = modes["offline"].shape.to_dict()
    for k in ("torso", "shoulder_width", "upper_arm", "thigh"):
        assert abs(res.shape.to_dict()[k] - off[k]) < 0.15 * off[k], k


def test_a_run_reports_its_own_shape_refinement_only(clip):
    """A run that cannot refine (2 frames: fewer than the refinement needs) reports no
    refinement, not one a previous run of the same tracker left behind."""
    tr = pt.Tracker(clip.intrinsics)
    tr.refine_report, tr.refine_s = {"frames_used": np.arange(8)}, 5.0  # an earlier run's
    res = tr.run(clip.depth[:2], clip.keypoints2d[:2], clip.confidence[:2])
    assert (res.status == 0).all()
    assert tr.refine_report is None and tr.refine_s == 0.0


def test_online_refines_early_then_again_from_the_first_shape(clip, online_lag0_kp_shape):
    """``online_first``: a first refinement after 8 tracked frames (on those), the frames
    after it tracked with that shape, and the one after 16 frames starting again from the
    landmark-based shape (the same prior), on the best frames of all 16."""
    starts = []

    class Spy(pt.Tracker):
        def _refine_on(self, params, *rest):
            starts.append((self.shape.to_dict(), len(params), self._online_tracked))
            super()._refine_on(params, *rest)

    settings = quick_refine("online", online_first=8, online_after=16)
    tr = Spy(clip.intrinsics, mode="online", lag=0, refine=settings)
    res = tr.run(clip.depth, clip.keypoints2d, clip.confidence)
    plain = online_lag0_kp_shape
    assert [(n, t) for _, n, t in starts] == [(8, 8), (8, 16)]
    landmark_shape = plain.shape.to_dict()
    assert starts[0][0] == landmark_shape and starts[1][0] == landmark_shape
    used = tr.refine_report["frames_used"]  # the second refinement's frames
    assert len(used) == 8 and used.max() < 16
    assert len(tr.refine_report["online_first"]["frames_used"]) == 8
    assert tr.refine_report["online_first"]["frames_used"].max() < 8
    tracked = np.flatnonzero(res.status == 0)
    first, second = int(tracked[7]), int(tracked[15])
    np.testing.assert_array_equal(res.keypoints3d[: first + 1], plain.keypoints3d[: first + 1])
    between = slice(first + 1, second + 1)
    assert not np.array_equal(res.keypoints3d[between], plain.keypoints3d[between])
    assert res.shape.to_dict() != landmark_shape
    with pytest.raises(ValueError, match="online_first"):
        pt.ShapeFitSettings(frames=8, online_first=4)
    with pytest.raises(ValueError, match="online_first"):
        pt.ShapeFitSettings(frames=8, online_first=60, online_after=60)


def test_online_spread_runs_the_refinement_a_part_at_each_update(clip, online_lag0_kp_shape):
    """``online_spread``: no update runs a refinement whole; S updates each run a part of its
    steps, the frames until the update after the last part are tracked with the shape before
    it (here the landmark-based one: the same poses as without a refinement), and the shape
    taken up is the one the whole refinement finds (the same steps on the same frames)."""
    S = 4  # quick_refine's 20 steps: 5 a part
    seen = []

    class Spy(pt.Tracker):
        def update(self, *frame):
            out = super().update(*frame)
            pending = self._refining
            seen.append((pending.work.done if pending else None, self.shape.to_dict()))
            return out

    args = (clip.depth, clip.keypoints2d, clip.confidence)
    whole = Spy(clip.intrinsics, mode="online", lag=0, refine=quick_refine("online",
                online_after=16, online_first=0))  # fmt: skip
    whole.run(*args)
    by_whole, seen[:] = seen[:], []
    tr = Spy(clip.intrinsics, mode="online", lag=0, refine=quick_refine("online",
             online_after=16, online_first=0, online_spread=S))  # fmt: skip
    res = tr.run(*args)
    landmark_shape = online_lag0_kp_shape.shape.to_dict()
    at_whole = next(t for t, (_, sh) in enumerate(by_whole) if sh != landmark_shape)
    at = next(t for t, (_, sh) in enumerate(seen) if sh != landmark_shape)
    parts = [done for done, _ in seen if done is not None]
    assert parts == [5, 10, 15, 20], parts  # one part a frame, none whole
    assert [d for d, _ in seen[at - S : at]] == parts and seen[at][0] is None
    assert at >= at_whole + S
    plain = online_lag0_kp_shape.keypoints3d
    np.testing.assert_array_equal(res.keypoints3d[:at], plain[:at])
    assert not np.array_equal(res.keypoints3d[at + 1 :], plain[at + 1 :])
    # The parts and the whole are different compiled programs: their float rounding differs,
    # and 20 optimisation steps carry it to 0.1-0.5 mm on some CPUs (AMD EPYC family 26: up to
    # 0.53e-3 in a field, against the refinement's own move of 35e-3 over all fields; 1e-4
    # per field held on family 25). What must hold: the shape taken up is the whole
    # refinement's, not one part of the way from the landmark-based shape.
    fields = list(whole.shape.to_dict())
    got = np.array([res.shape.to_dict()[k] for k in fields])
    want = np.array([whole.shape.to_dict()[k] for k in fields])
    start = np.array([landmark_shape[k] for k in fields])
    assert np.linalg.norm(got - want) <= 0.1 * np.linalg.norm(want - start), (got, want)
    np.testing.assert_array_equal(
        tr.refine_report["frames_used"], whole.refine_report["frames_used"]
    )
    assert tr.refine_report["history"].shape == whole.refine_report["history"].shape
    assert 0 < tr.refine_s
    for bad in (-1, True, 2.0, 151):
        with pytest.raises(ValueError, match="online_spread"):
            pt.ShapeFitSettings(online_spread=bad)


def run_with_progress(tracker, clip):
    """``tracker.run`` over ``clip``: its result and the progress calls, (done, total) each."""
    calls = []
    res = tracker.run(
        clip.depth, clip.keypoints2d, clip.confidence,
        progress=lambda done, total, postfix="": calls.append((done, total)),
    )  # fmt: skip
    return res, calls


def test_offline_shape_prepass_is_the_first_frames_tracked_alone(clip, modes):
    """``offline_first``: the first 16 frames are tracked by a tracker as this one was made
    (its seed, no pre-pass) and the shape refined on them; the whole recording is then
    tracked from that shape and refined again, as two trackers by hand would do it. One
    progress bar counts the pre-pass's frames, then the recording's."""
    from posetrack import _shapefit

    settings = quick_refine("offline", offline_first=16)
    alone = dataclasses.replace(settings, offline_first=0)
    progs = (_shapefit._observe_frames, _shapefit.refine_shape_core)
    pre = pt.Tracker(clip.intrinsics, refine=alone).run(
        clip.depth[:16], clip.keypoints2d[:16], clip.confidence[:16]
    )  # fmt: skip
    before = [p._cache_size() for p in progs]  # the programs of a run without the pre-pass
    tr = pt.Tracker(clip.intrinsics, refine=settings)
    res, calls = run_with_progress(tr, clip)
    assert (tr.prepass_frames(40), tr.prepass_frames(16), tr.progress_frames(40)) == (16, 0, 56)
    assert [d for d, _ in calls] == list(range(1, 57)) and {t for _, t in calls} == {56}
    first = tr.refine_report["offline_first"]
    assert first["frames_used"].max() < 16 and tr.refine_report["frames_used"].max() >= 16
    assert tr.prepass_s > 0
    # Both refinements ran the programs of a run without it: the pre-pass compiles none.
    assert [p._cache_size() for p in progs] == before
    landmark_shape = modes["offline, kp shape"].shape.to_dict()
    assert pre.shape.to_dict() != landmark_shape  # the pre-pass refined it
    by_hand = pt.Tracker(clip.intrinsics, refine=alone, shape=pre.shape)
    hand = by_hand.run(clip.depth, clip.keypoints2d, clip.confidence)
    np.testing.assert_array_equal(res.keypoints3d, hand.keypoints3d)
    assert res.shape.to_dict() == hand.shape.to_dict() != pre.shape.to_dict()
    # Without the option (the default) nothing changes: a recording as long as the
    # pre-pass has none either.
    assert pt.Tracker(clip.intrinsics, refine=alone).prepass_frames(40) == 0
    assert pt.Tracker(clip.intrinsics, mode="online", refine=settings).prepass_frames(40) == 0
    with pytest.raises(ValueError, match="offline_first"):
        pt.ShapeFitSettings(frames=8, offline_first=4)


def test_the_refinement_schedule_is_not_part_of_its_program(clip):
    """When and on how many frames the tracker refines the shape (``frames``, the online and
    offline schedules, the pre-pass gate) does not reach the compiled refinement: trackers
    that differ only there run one program; a setting of the optimiser makes another."""
    base = pt.ShapeFitSettings.tracking("online")
    schedules = [
        base,
        dataclasses.replace(base, frames=6, online_first=0, online_after=30),
        dataclasses.replace(base, offline_first=40, offline_first_below=0.6),
    ]
    keys = {pt.Tracker(clip.intrinsics, refine=s)._refine_settings() for s in schedules}
    assert len(keys) == 1
    (key,) = keys
    assert (key.width, key.height, key.steps) == (base.width, base.height, base.steps)
    other = pt.Tracker(clip.intrinsics, refine=dataclasses.replace(base, steps=50))
    assert other._refine_settings() != key


def test_the_pre_pass_gate_keeps_clean_starts_as_the_default(clip, modes):
    """``offline_first_below``: where the first frames' observed keypoint share is not below
    the gate there is no pre-pass: the default's track exactly, its progress bar jumping over
    the pre-pass's frames; the share is reported."""
    share = pt.observed_share(clip.depth, clip.keypoints2d, clip.confidence, 16)
    assert 0.5 < share < 1  # a clean clip: most keypoints observed
    gated = dataclasses.replace(
        pt.ShapeFitSettings.tracking("offline"), offline_first=16, offline_first_below=share
    )  # fmt: skip
    tr = pt.Tracker(clip.intrinsics, refine=gated)
    res, calls = run_with_progress(tr, clip)
    assert tr.prepass_share == share and tr.prepass_s == 0
    assert "offline_first" not in tr.refine_report
    assert [d for d, _ in calls] == list(range(16, 57)) and {t for _, t in calls} == {56}
    np.testing.assert_array_equal(res.keypoints3d, modes["offline"].keypoints3d)
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="offline_first_below"):
            dataclasses.replace(gated, offline_first_below=bad)


def first_dropped_detection(clip) -> int:
    """The first frame where the offline default's duplicate filter withholds a detection
    (replayed on the host on the detections the tracker follows; ``len(clip.depth)`` if
    none)."""
    tracker = pt.Tracker(clip.intrinsics)
    dups = tracker._new_duplicate_filter()
    args = (clip.depth, clip.keypoints2d, clip.confidence, len(clip.depth))
    for t, (_, cands, p) in enumerate(tracker._followed(*args)):
        _, dropped = dups.update(*cands.person(p), cands.points3d[p], cands.has_depth[p])
        if dropped.any():
            return t
    return len(clip.depth)


def test_offline_is_the_per_frame_track_smoothed(clip, modes, one_way):
    off, per = one_way[1], modes["per-frame"]
    assert off.mode == "offline" and per.per_frame_keypoints3d is None
    # Left/right relabelling runs offline by default (arbitrated by the depth), not per-frame,
    # and so does the filter of detections that jumped onto another keypoint: until the first
    # frame either changes, the per-frame pass is the paper's tracker.
    assert per.exchanged is None and off.exchanged is not None
    assert per.interpolated is None and off.interpolated.shape == (len(clip.depth), 4)
    exchanged = np.flatnonzero(off.exchanged.any(axis=1))
    first = min(exchanged[0] if len(exchanged) else len(clip.depth), first_dropped_detection(clip))
    assert first >= 10  # a check of the passes' equality, not of nothing
    np.testing.assert_array_equal(off.per_frame_keypoints3d[:first], per.keypoints3d[:first])
    gt = clip.joints3d
    assert pt.acceleration_error(off.keypoints3d, gt) < 0.5 * pt.acceleration_error(
        per.keypoints3d, gt
    )
    assert pt.accuracy(off.keypoints3d, gt).mean_mm < pt.accuracy(per.keypoints3d, gt).mean_mm


def test_offline_both_ways_fuses_a_backward_pass_with_the_forward_one(clip, modes, one_way):
    """``SmoothSettings(both_ways=True)``: the forward pass is the one-way run's (the
    default's); a second pass from the last frame back is smoothed on its own and fused with
    the forward pass's smoothed track; one progress bar counts both passes; the tracker is
    left as the forward pass left it."""
    args = (clip.depth, clip.keypoints2d, clip.confidence)
    T, gt = len(clip.depth), clip.joints3d
    one_way, one = one_way
    np.testing.assert_array_equal(one.keypoints3d, modes["offline"].keypoints3d)  # default
    calls = []
    both = pt.SmoothSettings(both_ways=True)
    tr = pt.Tracker(clip.intrinsics, motion=both)
    res = tr.run(*args, progress=lambda done, total, postfix="": calls.append((done, total)))
    assert calls == [(t, 2 * T) for t in range(1, 2 * T + 1)]
    # With and without a progress callback (pt.track: none).
    quiet = pt.track(*args, clip.intrinsics, motion=both)
    np.testing.assert_array_equal(res.keypoints3d, quiet.keypoints3d)
    assert one_way.both_ways_frames == 0 and T - 2 <= tr.both_ways_frames <= T
    # The forward pass's per-frame estimates are the one-way run's.
    np.testing.assert_array_equal(res.per_frame_keypoints3d, one.per_frame_keypoints3d)
    moved = np.linalg.norm(res.keypoints3d - one.keypoints3d, axis=-1).mean(axis=1)
    assert (moved > 1e-3).sum() >= T // 2  # a second track fused in, not the first again
    # The fused keypoints are those of the fused poses.
    model = jax.vmap(lambda p: pt.keypoints(res.shape, p))(jnp.asarray(res.params, jnp.float32))
    np.testing.assert_allclose(res.keypoints3d, np.asarray(model), atol=1e-4)
    np.testing.assert_array_equal(tr.state.best, one_way.state.best)
    assert tr.person == one_way.person
    d_both, d_one = (pt.accuracy(r.keypoints3d, gt).mean_mm for r in (res, one))
    assert d_both < 1.25 * d_one


def test_offline_refines_the_body_shape_and_places_the_shoulders_better(clip, modes):
    off, kp_shape, per = modes["offline"], modes["offline, kp shape"], modes["per-frame"]
    # Landmark-based shape for the per-frame pass and refine=None; refined against the depth
    # by default (offline only).
    assert kp_shape.shape.to_dict() == per.shape.to_dict()
    changed = [k for k, v in off.shape.to_dict().items() if abs(v - per.shape.to_dict()[k]) > 1e-4]
    assert len(changed) >= 5, changed
    np.testing.assert_array_equal(off.per_frame_keypoints3d, kp_shape.per_frame_keypoints3d)
    gt = clip.joints3d
    shoulders = (2, 5)
    err = {
        name: float(np.nanmean(pt.joint_errors(modes[name].keypoints3d, gt, joints=shoulders)))
        for name in ("offline", "offline, kp shape")
    }
    assert err["offline"] < err["offline, kp shape"], err
    assert pt.accuracy(off.keypoints3d, gt).mean_mm < pt.accuracy(kp_shape.keypoints3d, gt).mean_mm


def test_prepare_builds_the_refinement_programs_the_run_uses(clip, modes):
    """``Tracker.prepare`` (and ``posetrack warmup``) build the refinement's two programs from
    argument signatures alone; they must be the very programs a run calls, or a warm start
    would compile again. The default offline run (``modes``) built them: prepare adds none."""
    from posetrack import _shapefit

    progs = (_shapefit._observe_frames, _shapefit.refine_shape_core)
    assert modes["offline"] is not None
    before = [p._cache_size() for p in progs]
    assert min(before) >= 1
    pt.Tracker(clip.intrinsics).prepare()
    assert [p._cache_size() for p in progs] == before


def test_shape_refinement_is_offline_and_online_and_checked(clip):
    tr = pt.Tracker(clip.intrinsics)
    assert tr.refine == pt.ShapeFitSettings.tracking("offline")
    online = pt.Tracker(clip.intrinsics, mode="online").refine
    assert online == pt.ShapeFitSettings.tracking("online")
    # Offline the radii's common factor is free; online it is not (benchmarks/README.md).
    assert tr.refine.girth_prior_sigma == 1.0 and online.girth_prior_sigma is None
    assert dataclasses.replace(tr.refine, girth_prior_sigma=None) == online
    with pytest.raises(ValueError, match="mode"):
        pt.ShapeFitSettings.tracking("per-frame")
    assert pt.Tracker(clip.intrinsics, mode="per-frame").refine is None
    # A shape given by the caller is kept as given.
    assert pt.Tracker(clip.intrinsics, shape=pt.BodyShape.default()).refine is None
    with pytest.raises(ValueError, match="per-frame"):
        pt.Tracker(clip.intrinsics, mode="per-frame", refine=pt.ShapeFitSettings())
    with pytest.raises(ValueError, match="online_after"):
        pt.ShapeFitSettings(frames=8, online_after=4)
    with pytest.raises(TypeError, match="refine"):
        pt.Tracker(clip.intrinsics, refine="yes")
    with pytest.raises(ValueError, match="frames"):
        pt.ShapeFitSettings(frames=0)


def test_online_with_lag_fills_every_frame_and_differs_from_per_frame(clip, modes):
    on, per = modes["online"], modes["per-frame"]
    # Online waits ONLINE_LAG (3) frames by default (the CLI's --online too); lag=0 does not.
    assert (on.mode, on.lag, modes["online0"].lag, per.lag) == ("online", 3, 0, 0)
    assert pt.ONLINE_LAG == 3 and pt.Tracker(clip.intrinsics, mode="online").lag == 3
    assert pt.Tracker(clip.intrinsics).lag == 0  # offline waits for nothing
    have = np.isfinite(per.keypoints3d).all(axis=(1, 2))
    assert np.isfinite(on.keypoints3d[have]).all()
    assert np.abs(on.keypoints3d[have] - per.keypoints3d[have]).max() > 1e-3


def test_online_moves_more_smoothly_than_per_frame(clip, modes):
    gt = clip.joints3d
    per = pt.acceleration_error(modes["per-frame"].keypoints3d, gt)
    for name in ("online", "online0"):
        acc = pt.acceleration_error(modes[name].keypoints3d, gt)
        assert acc < 0.7 * per, (name, acc, per)
        # Smoothing may cost a causal filter a little accuracy, never much.
        D = pt.accuracy(modes[name].keypoints3d, gt).mean_mm
        assert D < 1.15 * pt.accuracy(modes["per-frame"].keypoints3d, gt).mean_mm + 5.0


def test_tracker_rejects_bad_motion_arguments(clip):
    with pytest.raises(ValueError, match="mode"):
        pt.Tracker(clip.intrinsics, mode="smooth")
    with pytest.raises(ValueError, match="lag"):
        pt.Tracker(clip.intrinsics, mode="online", lag=-1)
    with pytest.raises(ValueError, match="online_window"):
        pt.Tracker(clip.intrinsics, mode="online", lag=12)
    with pytest.raises(ValueError, match="fps"):
        pt.Tracker(clip.intrinsics, fps=0.0)


def test_an_arm_swap_of_the_detector_is_undone_and_does_not_lock_in(clip, modes):
    # Frames 12-27: the detector reports the right arm as the left one and vice versa.
    kp, conf = clip.keypoints2d.copy(), clip.confidence.copy()
    sw = np.arange(12, 28)
    for a, b in pt.SIDE_GROUPS["arms"]:
        kp[sw, a], kp[sw, b] = clip.keypoints2d[sw, b], clip.keypoints2d[sw, a]
        conf[sw, a], conf[sw, b] = clip.confidence[sw, b], clip.confidence[sw, a]
    args = (clip.depth, kp, conf, clip.intrinsics)
    # Offline default (both directions, arbitrated by the depth); the shape refinement with
    # fewer steps, in both runs (what is compared is the relabelling).
    fixed = pt.track(*args, refine=quick_refine())
    raw = pt.track(*args, sides=None, refine=quick_refine())
    assert raw.exchanged is None
    seen = (conf[sw][:, [3, 4, 6, 7]] > 0.1).any(axis=1)
    assert fixed.exchanged[sw[seen], 0].mean() > 0.9
    assert fixed.exchanged[:12, 0].sum() + fixed.exchanged[28:, 0].sum() <= 2
    gt = clip.joints3d
    assert (
        pt.swapped_limb_frames(fixed.keypoints3d, gt)
        <= pt.swapped_limb_frames(modes["offline"].keypoints3d, gt) + 1
    )  # as few as without the detector's swap
    d_fixed = pt.accuracy(fixed.keypoints3d, gt).mean_mm
    d_raw = pt.accuracy(raw.keypoints3d, gt).mean_mm
    print(f"D with relabelling {d_fixed:.1f} mm, without {d_raw:.1f} mm")
    assert d_fixed <= d_raw + 1.0


def test_the_depth_refuses_an_exchange_the_2d_reading_got_wrong(clip, modes, monkeypatch):
    """Offline, each stretch the two-sided labelling reads exchanged is tracked both ways and
    kept by Delta. Here the pre-pass is made to misread correct arm labels in frames 10-19
    (what 2D continuity does on occluded side views): arbitrated, the depth refuses it and
    the track is the one without relabelling, bit for bit; taken as read, it costs accuracy."""
    T = len(clip.depth)

    def misread(self, depths, keypoints2d, confidence):
        wrong = np.zeros((T, len(self.sides.groups)), bool)  # one column per group
        wrong[10:20, 0] = True
        return np.zeros(T, np.int64), wrong, []

    monkeypatch.setattr(pt.Tracker, "_two_sided_labels", misread)
    args = (clip.depth, clip.keypoints2d, clip.confidence, clip.intrinsics)
    tr = pt.Tracker(clip.intrinsics, refine=None)
    judged = tr.run(*args[:3])
    assert [s[:2] for s in tr.side_spans] == [(10, 25)]
    start, stop, delta_as, delta_ex, kept = tr.side_spans[0]
    assert not kept and delta_ex > delta_as, tr.side_spans
    assert not judged.exchanged.any()
    plain = pt.track(*args, refine=None, sides=None)
    np.testing.assert_array_equal(judged.per_frame_keypoints3d, plain.per_frame_keypoints3d)
    np.testing.assert_array_equal(judged.keypoints3d, plain.keypoints3d)
    taken = pt.track(*args, refine=None, sides=pt.SideSettings(arbitrate=False))
    _misreading_taken_as_read_costs(
        taken, taken.per_frame_keypoints3d, judged.per_frame_keypoints3d, clip.joints3d
    )


def test_a_turn_is_kept_mirrored_only_where_the_depth_prefers_it(clip, monkeypatch):
    """``SideSettings.frontal_turns``: a turn's frames are tracked as labelled and again with
    every labelling mirrored (each group and the face exchanged), from the same state, and
    the lower Delta summed keeps its tracking. The detector swaps the whole body in frames
    12-27 (the person read as facing away) and the pre-pass reads nothing exchanged, as in a
    swap that starts and ends in a side view: the mirrored tracking is kept and undoes it.
    Without the swap the labelled tracking is kept, bit for bit the run without turns."""
    T = len(clip.depth)
    kp, conf = clip.keypoints2d.copy(), clip.confidence.copy()
    sw = np.arange(12, 28)
    flip = _body.flip_labels(range(18))  # every left/right pair, the face's included
    kp[sw], conf[sw] = clip.keypoints2d[sw][:, flip], clip.confidence[sw][:, flip]
    found: list = []

    def reading(self, depths, keypoints2d, confidence):
        return np.zeros(T, np.int64), np.zeros((T, len(self.sides.groups)), bool), found

    monkeypatch.setattr(pt.Tracker, "_two_sided_labels", reading)
    sides = pt.SideSettings.for_mode("offline", frontal_turns=0.5)
    runs = {}
    for swapped, turns in ((True, [(12, 28)]), (True, []), (False, [(12, 28)]), (False, [])):
        found[:] = turns
        tr = pt.Tracker(clip.intrinsics, refine=None, sides=sides)
        runs[swapped, bool(turns)] = tr.run(clip.depth, *((kp, conf) if swapped else
                                                         (clip.keypoints2d, clip.confidence)))
        assert [s[:2] for s in tr.turn_spans] == turns
        if turns:
            assert tr.turn_spans[0][4] == swapped, tr.turn_spans
    gt = clip.joints3d
    mirrored, labelled = runs[True, True], runs[True, False]
    assert mirrored.exchanged[sw].all() and not mirrored.exchanged[:12].any()
    assert pt.accuracy(mirrored.keypoints3d, gt).mean_mm < pt.accuracy(
        labelled.keypoints3d, gt).mean_mm - 5.0
    assert pt.swapped_limb_frames(mirrored.keypoints3d, gt) <= pt.swapped_limb_frames(
        labelled.keypoints3d, gt)
    kept, plain = runs[False, True], runs[False, False]
    np.testing.assert_array_equal(kept.keypoints3d, plain.keypoints3d)
    assert not kept.exchanged.any()
    # A mirrored tracking must lead by turn_margin a frame: by 1.0 (more than Delta's range)
    # never, and the labelled tracking stays, bit for bit.
    found[:] = [(12, 28)]
    strict = dataclasses.replace(sides, turn_margin=1.0)
    tr = pt.Tracker(clip.intrinsics, refine=None, sides=strict)
    np.testing.assert_array_equal(tr.run(clip.depth, kp, conf).keypoints3d, labelled.keypoints3d)
    assert not tr.turn_spans[0][4]


def test_each_groups_exchange_is_judged_on_its_own_with_arbitrate_groups(clip, monkeypatch):
    """The detector swaps the arms in frames 12-27; the pre-pass reads the arms right and the
    legs wrongly exchanged there. Decided together, the legs' misreading rides along with the
    arms' true exchange (their Delta summed beats the detections'); with
    ``arbitrate_groups`` each group's exchange is also tracked alone and the arms' wins."""
    T = len(clip.depth)
    kp, conf = clip.keypoints2d.copy(), clip.confidence.copy()
    sw = np.arange(12, 28)
    for a, b in pt.SIDE_GROUPS["arms"]:
        kp[sw, a], kp[sw, b] = clip.keypoints2d[sw, b], clip.keypoints2d[sw, a]
        conf[sw, a], conf[sw, b] = clip.confidence[sw, b], clip.confidence[sw, a]

    def reading(self, depths, keypoints2d, confidence):
        r = np.zeros((T, len(self.sides.groups)), bool)
        r[12:28, :2] = True  # arms (right) and legs (wrong)
        return np.zeros(T, np.int64), r, []

    monkeypatch.setattr(pt.Tracker, "_two_sided_labels", reading)
    gt, out = clip.joints3d, {}
    for alone in (False, True):
        sides = pt.SideSettings.for_mode("offline", arbitrate_groups=alone)
        tr = pt.Tracker(clip.intrinsics, refine=None, sides=sides)
        res = tr.run(clip.depth, kp, conf)
        assert [s[:2] for s in tr.side_spans] == [(12, 33)] and tr.side_spans[0][4]
        out[alone] = res, tr.side_span_groups[0]
    (together, g_together), (alone, g_alone) = out[False], out[True]
    assert g_together.tolist()[:2] == [True, True] and together.exchanged[sw, 1].all()
    assert g_alone.tolist()[:2] == [True, False]
    assert alone.exchanged[sw, 0].all() and not alone.exchanged[:, 1].any()
    assert pt.swapped_limb_frames(alone.keypoints3d, gt) < pt.swapped_limb_frames(
        together.keypoints3d, gt
    )
    d_alone = pt.accuracy(alone.keypoints3d, gt).mean_mm
    d_together = pt.accuracy(together.keypoints3d, gt).mean_mm
    print(f"D {d_together:.1f} mm decided together, {d_alone:.1f} per group")
    assert d_alone < d_together - 5.0


def test_online_each_groups_exchange_is_judged_on_its_own_with_online_groups(clip, monkeypatch):
    """Online, the detector swaps the arms in frames 12-27 and the forward pass reads the
    arms (right) and the legs (wrong) newly exchanged at frame 12. Judged together, the
    legs' misreading takes the arms' true exchange down with it (or rides along); with
    ``online_groups`` each group's exchange is also tracked alone and the arms' alone is
    kept. Without it the arbitration is the shipped one (no reading alone is tracked)."""
    T = len(clip.depth)
    sw = np.arange(12, 28)
    kp, conf = _arm_swap(clip, sw)

    def reading(self, keypoints2d, confidence, points3d, has_depth):
        # Which frame: the one whose keypoints these are.
        t = int(np.argmin(np.abs(np.nan_to_num(kp) - np.nan_to_num(keypoints2d)).sum((1, 2))))
        ex = np.zeros(len(self._slots), bool)
        ex[:2] = 12 <= t < 28  # arms (right) and legs (wrong)
        return (*self.relabel(keypoints2d, confidence, ex), ex)

    monkeypatch.setattr(pt.SideLabeller, "update", reading)
    runs = _online_pair(clip, kp, conf, "online_groups", (False, True), [])
    k = pt.ONLINE_LAG + 1
    gt = clip.joints3d
    (together, spans_together), (alone, spans_alone) = runs[False], runs[True]
    assert [s[:2] for s in spans_alone][:1] == [(12, 12 + k)] and spans_alone[0][4]
    assert [s[:2] for s in spans_together][:1] == [(12, 12 + k)]
    # Together: both groups' exchange or neither; alone: the arms' only, all through the swap.
    assert together.exchanged[12, 0] == together.exchanged[12, 1]
    assert alone.exchanged[sw, 0].all() and not alone.exchanged[:, 1].any()
    d_alone = pt.accuracy(alone.keypoints3d, gt).mean_mm
    d_together = pt.accuracy(together.keypoints3d, gt).mean_mm
    print(f"D {d_together:.1f} mm judged together, {d_alone:.1f} per group")
    assert pt.swapped_limb_frames(alone.keypoints3d, gt) < pt.swapped_limb_frames(
        together.keypoints3d, gt
    )
    assert d_alone < d_together - 5.0
    assert T == len(alone.exchanged)


def _misreading_taken_as_read_costs(taken, taken_kps, judged_kps, gt):
    """The arm labels misread in frames 10-19, taken as read, cost >10 mm over frames 10-24
    against the arbitrated track."""
    assert taken.exchanged[10:20, 0].all()
    d_taken = pt.accuracy(taken_kps[10:25], gt[10:25]).mean_mm
    d_judged = pt.accuracy(judged_kps[10:25], gt[10:25]).mean_mm
    print(f"frames 10-24: D {d_judged:.1f} mm arbitrated, {d_taken:.1f} taken as read")
    assert d_judged < d_taken - 10.0


def _arm_swap(clip, frames):
    """The clip's keypoints with the detector's right and left arm exchanged in ``frames``."""
    kp, conf = clip.keypoints2d.copy(), clip.confidence.copy()
    for a, b in pt.SIDE_GROUPS["arms"]:
        kp[frames, a], kp[frames, b] = clip.keypoints2d[frames, b], clip.keypoints2d[frames, a]
        conf[frames, a], conf[frames, b] = clip.confidence[frames, b], clip.confidence[frames, a]
    return kp, conf


def test_online_the_depth_keeps_a_detector_swap_it_sees(clip, modes):
    """Online with ``sides``, the stretch the forward labelling newly reads exchanged is
    tracked both ways for lag + 1 frames and the depth keeps the exchange; the body-shape
    refinement that comes due meanwhile runs after the decision, on frames seen before it."""
    sw = np.arange(12, 28)
    kp, conf = _arm_swap(clip, sw)
    refine = quick_refine("online", online_after=13, online_first=0)
    tr = pt.Tracker(clip.intrinsics, mode="online", sides=pt.SideSettings(), refine=refine)
    fixed = tr.run(clip.depth, kp, conf)
    raw = pt.track(
        clip.depth, kp, conf, clip.intrinsics, mode="online", sides=None,
        refine=quick_refine("online"),
    )  # fmt: skip
    k = pt.ONLINE_LAG + 1
    assert [s[:2] for s in tr.side_spans][:1] == [(12, 12 + k)], tr.side_spans
    start, stop, delta_as, delta_ex, kept = tr.side_spans[0]
    assert kept and delta_ex < delta_as
    assert len(tr.side_span_groups) == len(tr.side_spans)
    assert tr.side_span_groups[0].tolist() == [True, False]  # the arms, of (arms, legs)
    seen = (conf[sw][:, [3, 4, 6, 7]] > 0.1).any(axis=1)
    assert fixed.exchanged[sw[seen], 0].mean() > 0.9
    assert tr.refine_report is not None and tr.refine_report["frames_used"].max() < 13
    gt = clip.joints3d
    n_fixed = pt.swapped_limb_frames(fixed.keypoints3d, gt)
    assert n_fixed <= pt.swapped_limb_frames(modes["online"].keypoints3d, gt) + 1
    assert n_fixed < pt.swapped_limb_frames(raw.keypoints3d, gt)


def _online_pair(clip, kp, conf, field: str, values: tuple, calls: list) -> dict:
    """Online runs (refine off) with ``SideSettings.for_mode("online", field=value)`` for each
    value: ``{value: (result, side_spans)}``. ``calls`` (what a monkeypatched labeller method
    records) must still be empty after the first value's run."""
    runs = {}
    for i, value in enumerate(values):
        sides = pt.SideSettings.for_mode("online", **{field: value})
        tr = pt.Tracker(clip.intrinsics, mode="online", sides=sides, refine=None)
        runs[value] = tr.run(clip.depth, kp, conf), tr.side_spans
        if i == 0:
            assert calls == []
    return runs


def test_online_a_kept_exchange_anchors_the_labelling(clip, monkeypatch):
    """With ``SideSettings.online_anchor`` the forward labelling is anchored to an exchange
    the depth kept, once, at the judgement's end, for the judged groups only; where the 2D
    margin already holds the exchange (a clean arm swap) nothing else changes, bit for bit.
    Without it (the default) the labelling is never anchored."""
    sw = np.arange(12, 28)
    kp, conf = _arm_swap(clip, sw)
    calls = []
    anchor = pt.SideLabeller.anchor

    def recorded(self, groups, margin):
        calls.append((self.settings.groups, np.array(groups), margin))
        anchor(self, groups, margin)

    monkeypatch.setattr(pt.SideLabeller, "anchor", recorded)
    runs = _online_pair(clip, kp, conf, "online_anchor", (0.0, 0.5), calls)
    k = pt.ONLINE_LAG + 1
    assert [s[:2] for s in runs[0.5][1]][:1] == [(12, 12 + k)] and runs[0.5][1][0][-1]
    assert len(calls) == 1, calls
    groups, judged, margin = calls[0]
    assert groups == ("arms", "legs", "torso") and judged.tolist() == [True, False, False]
    assert margin == 0.5
    (plain, plain_spans), (anchored, anchored_spans) = runs[0.0], runs[0.5]
    assert plain_spans == anchored_spans
    np.testing.assert_array_equal(anchored.exchanged, plain.exchanged)
    np.testing.assert_array_equal(anchored.keypoints3d, plain.keypoints3d)


def test_online_the_labeller_is_told_each_frames_pose(clip, monkeypatch):
    """With ``SideSettings.online_model`` the online tracker tells the labeller every tracked
    frame's pose, projected (what the next frame's reading asks near a tie); on a clean arm
    swap, where the forward margin is never near a tie, the output is the same bit for bit.
    Without it (0) the labeller is never told."""
    sw = np.arange(12, 28)
    kp, conf = _arm_swap(clip, sw)
    told = []
    refer = pt.SideLabeller.refer

    def recorded(self, keypoints2d):
        told.append(None if keypoints2d is None else np.array(keypoints2d))
        refer(self, keypoints2d)

    monkeypatch.setattr(pt.SideLabeller, "refer", recorded)
    runs = _online_pair(clip, kp, conf, "online_model", (0.0, 0.1), told)
    (plain, plain_spans), (told_run, told_spans) = runs[0.0], runs[0.1]
    # One call per step (a judged frame is tracked twice), a pose for every tracked one.
    k = pt.ONLINE_LAG + 1
    assert len(told) == len(clip.depth) + k * len(told_spans), (len(told), told_spans)
    assert all(t is not None for t in told)
    assert plain_spans == told_spans
    np.testing.assert_array_equal(told_run.exchanged, plain.exchanged)
    np.testing.assert_array_equal(told_run.keypoints3d, plain.keypoints3d)
    # What it is told is the frame's own pose (update's estimate at lag 3), projected.
    sides = pt.SideSettings.for_mode("online", online_model=0.1)
    tr = pt.Tracker(clip.intrinsics, mode="online", sides=sides, refine=None)
    for t in range(5):
        est, status = tr.update(clip.depth[t], kp[t], conf[t])
    assert status == pt.TRACKED
    K, k3 = clip.intrinsics, np.asarray(est.keypoints3d, np.float64)
    uv = np.stack([K.fx * k3[:, 0] / k3[:, 2] + K.cx, K.fy * k3[:, 1] / k3[:, 2] + K.cy], -1)
    np.testing.assert_allclose(told[-1], uv, atol=1e-3)


def _misread(monkeypatch, clip, arms: range, legs: range) -> None:
    """Make the forward labelling read correct labels exchanged: arms in frames ``arms``, legs
    in frames ``legs`` (2D continuity does so on occluded side views)."""
    update = pt.SideLabeller.update

    def misread(self, keypoints2d, confidence, points3d, has_depth):
        kp, conf, ex = update(self, keypoints2d, confidence, points3d, has_depth)
        t = int(np.argmin(np.abs(clip.keypoints2d - keypoints2d).sum(axis=(1, 2))))
        if t in arms or t in legs:
            ex = np.array([t in arms, t in legs])
            kp, conf = self.relabel(keypoints2d, confidence, ex)
        return kp, conf, ex

    monkeypatch.setattr(pt.SideLabeller, "update", misread)


@pytest.fixture(scope="module")
def online_plain(clip):
    """Online, no left/right relabelling, no body-shape refinement."""
    args = (clip.depth, clip.keypoints2d, clip.confidence, clip.intrinsics)
    return pt.track(*args, mode="online", sides=None, refine=None)


def test_online_the_depth_refuses_a_misreading_before_it_is_published(
    clip, online_plain, monkeypatch
):
    """Online, a forward labelling that misreads correct arm labels in frames 10-19 is tracked
    both ways (here over 2 frames, fewer than the default lag + 1), the depth refuses it and
    the exchange stays vetoed while it is read: the track is the one without relabelling, bit
    for bit. Taken as read, it costs accuracy."""
    _misread(monkeypatch, clip, arms=range(10, 20), legs=range(0))
    args = (clip.depth, clip.keypoints2d, clip.confidence)
    k = 2
    sides = pt.SideSettings(online_frames=k)
    tr = pt.Tracker(clip.intrinsics, mode="online", sides=sides, refine=None)
    judged = tr.run(*args)
    assert [s[:2] for s in tr.side_spans] == [(10, 10 + k)], tr.side_spans
    assert not tr.side_spans[0][-1]
    assert not judged.exchanged.any()
    np.testing.assert_array_equal(judged.keypoints3d, online_plain.keypoints3d)
    taken = pt.track(
        *args, clip.intrinsics, mode="online", refine=None,
        sides=pt.SideSettings(arbitrate=False),
    )  # fmt: skip
    _misreading_taken_as_read_costs(taken, taken.keypoints3d, judged.keypoints3d, clip.joints3d)


def test_online_a_misreading_inside_a_judgement_waits_for_its_own(clip, online_plain, monkeypatch):
    """A group newly read exchanged while another group's exchange is being judged (legs from
    frame 12, inside the judgement of the arms over frames 10-13) is not taken unjudged: it
    stays as detected until that judgement ends and is then judged on its own. Both
    misreadings are refused, and the track is the one without relabelling, bit for bit."""
    _misread(monkeypatch, clip, arms=range(10, 20), legs=range(12, 20))
    tr = pt.Tracker(clip.intrinsics, mode="online", sides=pt.SideSettings(), refine=None)
    judged = tr.run(clip.depth, clip.keypoints2d, clip.confidence)
    k = pt.ONLINE_LAG + 1
    assert [s[:2] for s in tr.side_spans] == [(10, 10 + k), (10 + k, 10 + 2 * k)], tr.side_spans
    assert not any(s[-1] for s in tr.side_spans) and not judged.exchanged.any()
    np.testing.assert_array_equal(judged.keypoints3d, online_plain.keypoints3d)


def test_online_an_exchange_the_2d_reading_drops_at_once_is_not_kept(
    clip, online_plain, monkeypatch
):
    """Online, a forward labelling that reads the arms exchanged in one frame only (frame 10:
    a detector outlier's jump) is judged over lag + 1 frames; even where the depth would keep
    it (here made to), the exchanged reading held it in fewer than
    ``SideSettings.online_min_held`` of them, so the detections' labels stay: the track is
    the one without relabelling, bit for bit. With ``online_min_held=1`` the depth alone
    decides and keeps it; an exchange read through the whole stretch is kept either way."""
    for module in (_tracker, _arbitration):  # the offline rule and the online judgement's
        monkeypatch.setattr(module, "prefer_exchanged", lambda *a: True)
    args = (clip.depth, clip.keypoints2d, clip.confidence)
    k = pt.ONLINE_LAG + 1
    _misread(monkeypatch, clip, arms=range(10, 11), legs=range(0))
    for held, kept in ((2, False), (1, True)):
        sides = pt.SideSettings(online_min_held=held)
        tr = pt.Tracker(clip.intrinsics, mode="online", sides=sides, refine=None)
        judged = tr.run(*args)
        assert [s[:2] for s in tr.side_spans] == [(10, 10 + k)], tr.side_spans
        assert tr.side_spans[0][-1] == kept
        assert judged.exchanged[10, 0] == kept
        if not kept:
            np.testing.assert_array_equal(judged.keypoints3d, online_plain.keypoints3d)
    _misread(monkeypatch, clip, arms=range(10, 20), legs=range(0))
    tr = pt.Tracker(
        clip.intrinsics, mode="online", sides=pt.SideSettings(online_min_held=2), refine=None
    )
    judged = tr.run(*args)
    assert tr.side_spans[0][:2] == (10, 10 + k) and tr.side_spans[0][-1]
    assert judged.exchanged[10:20, 0].all()


def test_online_run_records_a_judged_stretch_as_the_kept_reading_saw_it(clip, monkeypatch):
    """Where the depth's preference turns during a judgement (here: as detected while fewer
    than lag + 1 frames are judged, exchanged at the decision), the frames before the
    decision were returned as the reading that led then; ``run`` records them as the kept
    reading saw them: the labels exchanged in every judged frame."""
    k = pt.ONLINE_LAG + 1
    for module in (_tracker, _arbitration):  # the offline rule and the online judgement's
        monkeypatch.setattr(module, "prefer_exchanged", lambda a, b, m: len(b) >= k)
    _misread(monkeypatch, clip, arms=range(10, 20), legs=range(0))
    tr = pt.Tracker(clip.intrinsics, mode="online", sides=pt.SideSettings(), refine=None)
    judged = tr.run(clip.depth, clip.keypoints2d, clip.confidence)
    assert tr.side_spans[0][:2] == (10, 10 + k) and tr.side_spans[0][-1]
    assert judged.exchanged[10 : 10 + k, 0].all() and not judged.exchanged[:10].any()


def test_online_an_ankle_reported_on_the_neck_is_dropped_not_fitted(clip):
    """Frames 12-27: the detector reports the left ankle on the neck (its own few pixels of
    noise, an ordinary confidence). Online (duplicates on by default) the tracker drops it
    and keeps the ankle where the leg is; without the filter the shank folds up to reach it."""
    kp, conf = clip.keypoints2d.copy(), clip.confidence.copy()
    ep = np.arange(12, 28)
    kp[ep, 13] = kp[ep, 1] + np.random.default_rng(0).uniform(-3.0, 3.0, (len(ep), 2))
    conf[ep, 13] = 0.55
    errs, dropped = {}, {}
    for name, dup in (("filter", "auto"), ("none", None)):
        t = pt.Tracker(
            clip.intrinsics, mode="online", duplicates=dup, refine=quick_refine("online")
        )
        r = t.run(clip.depth, kp, conf)
        errs[name] = np.linalg.norm(r.keypoints3d[ep, 13] - clip.joints3d[ep, 13], axis=-1)
        dropped[name] = t.duplicates_dropped
    print({k: float(v.mean()) for k, v in errs.items()}, dropped)
    assert dropped["none"] == 0 and dropped["filter"] >= len(ep)
    assert errs["filter"].max() < 0.1  # m
    assert errs["none"].mean() > 0.3  # the fold the filter prevents
