"""The tracker end to end on generated sequences: accuracy against the naive floor, no
recompilation per frame, track status, and bad input at the public boundary."""

import dataclasses
import os
import subprocess
import sys

import jax
import numpy as np
import pytest
from conftest import quick_refine

import posetrack as pt
from posetrack import LOST, NO_OBSERVATION, TRACKED, FitSettings, TrackerConfig, _programs, _tracker
from posetrack import _init as pt_init
from posetrack._so3 import quat_to_matrix


@pytest.fixture(scope="module")
def seq():
    # The demo's default sequence (noisy sensor and detector), shortened, at the 320x240 of
    # test_paper_claim and test_cli_track so the compiled programs are shared with them.
    return pt.synth.generate(0, motion="walk", n_frames=30, width=320, height=240)


LVM = pt.TrackerConfig.recommended("lvm")  # test_paper_claim's LVM: programs shared


def left(params):
    """The body's left-right axis in the camera frame (the root rotation's first column)."""
    return _tracker.quat_to_matrix(np.asarray(params[3:7], np.float64))[:, 0]


@pytest.fixture(scope="module")
def lvm_result(seq):
    return pt.track(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics, LVM)


def test_lvm_beats_naive_lifting_on_the_default_sequence(seq, lvm_result):
    acc = pt.accuracy(lvm_result.keypoints3d, seq.joints3d)
    plain = _tracker.lift_sequence(seq.depth, seq.keypoints2d, seq.confidence, seq.intrinsics)
    naive = pt.accuracy(pt.naive_lifting(*plain), seq.joints3d)
    assert acc.coverage == 1.0
    assert acc.mean_mm < 0.8 * naive.mean_mm, (acc.mean_mm, naive.mean_mm)
    assert acc.mean_mm < 80.0
    assert (lvm_result.status == TRACKED).mean() > 0.9
    assert np.isfinite(lvm_result.params).all()


def test_estimated_body_is_the_subjects_size(seq, lvm_result):
    """Shape estimation from the first frames finds the subject's bone lengths to ~10 %."""
    shape = lvm_result.shape
    truth = seq.subject
    assert abs(float(shape.thigh) - truth["thigh"]) / truth["thigh"] < 0.12
    assert abs(float(shape.upper_arm) - truth["upper_arm"]) / truth["upper_arm"] < 0.12


def test_no_recompilation_over_frames(seq):
    """``Tracker.update``'s compiled step is built once for a configuration and image size and
    reused for every later frame, and for another configuration that differs only in its float
    (traced) fields. (The step is an ahead-of-time compiled :class:`~posetrack._programs.Program`:
    a call whose input structure differs builds a new one, which its count would show.)"""
    step = _tracker.step
    config = LVM
    tracker = pt.Tracker(seq.intrinsics, config)
    tracker.estimate_shape(seq.depth[:5], seq.keypoints2d[:5], seq.confidence[:5])
    tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])
    built = step._cache_size()
    events = len(_programs.log())
    for t in range(1, 12):
        est, status = tracker.update(seq.depth[t], seq.keypoints2d[t], seq.confidence[t])
        assert est is not None and status in (TRACKED, LOST)
        assert est.deltas.shape == (config.n,)
        # The frame's results come back to the host in one transfer, as NumPy arrays.
        assert all(isinstance(x, np.ndarray) for x in jax.tree.leaves(est))
    # Float fields (exclusion ratios, sigmas, d_M, ...) are traced: a sweep reuses the step.
    other = config.replace(r=0.05, R=0.15, sigma_h=0.3, d_hmax=0.2, d_M=0.1, lost_delta=0.5)
    tracker2 = pt.Tracker(seq.intrinsics, other, shape=tracker.shape)
    for t in range(3):
        tracker2.update(seq.depth[t], seq.keypoints2d[t], seq.confidence[t])
    assert step._cache_size() == built
    assert [e.name for e in _programs.log()[events:]] == []


def test_static_fields_are_declared_static():
    """Switches, counts and sizes are pytree structure; the float fields are its leaves."""
    config = TrackerConfig()
    leaves = jax.tree.leaves(config)
    assert all(isinstance(v, float) for v in leaves)
    assert len(leaves) == 22
    a = TrackerConfig(sigma_h=0.3)
    b = TrackerConfig(sigma_h=0.7, depth_confidence=0.8, depth_confidence_far=1.0)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for static in (
        dict(num_hypotheses=3),
        dict(reseed=False),
        dict(score_width=80),
        dict(far_side_bound=True),
    ):
        assert jax.tree.structure(TrackerConfig(**static)) != jax.tree.structure(config)
    assert TrackerConfig(r=0).r == 0.0 and isinstance(TrackerConfig(r=0).r, float)


def test_leg_terms_are_left_out_of_the_initial_fit_only(seq):
    """The limit on crossed legs and label-free legs (with their gates) hold in the step's fits
    and the offline smoother; the initial fit takes the detector's leg labels as they are
    (they tell it the facing: with either term a side view could start turned round)."""
    fit = TrackerConfig().fit
    residuals = dataclasses.replace(
        fit.residuals, leg_cross=10.0, leg_labels_free=True, leg_labels_free_sin=0.5,
        leg_labels_margin=4.0, leg_terms_min=10,
    )  # fmt: skip
    config = TrackerConfig(fit=dataclasses.replace(fit, residuals=residuals))
    tracker = pt.Tracker(seq.intrinsics, config, mode="offline")
    init = tracker._init_settings.residuals
    assert init.leg_cross == 0.0 and not init.leg_labels_free
    assert tracker._init_settings.max_steps == config.init_steps
    assert tracker.config.fit.residuals == residuals  # the step's fits keep both
    smoother = tracker._smoother.residuals
    assert smoother.leg_cross == 10.0 and smoother.leg_labels_free
    # ... with the fits' gates on the label-free legs
    assert (smoother.leg_labels_free_sin, smoother.leg_labels_margin) == (0.5, 4.0)
    assert smoother.leg_terms_min == 10


def test_frames_without_observation_hold_the_pose(seq):
    # The offline run passes through the body-shape refinement with the gaps in it (fewer steps).
    tracker = pt.Tracker(seq.intrinsics, LVM, refine=quick_refine())
    kp, conf, depth = seq.keypoints2d, seq.confidence.copy(), seq.depth.copy()
    conf[3:6] = 0.0  # all keypoints missing for three frames
    depth[7] = 0  # an all-invalid depth frame
    res = tracker.run(depth[:10], kp[:10], conf[:10], progress=False)
    assert list(res.status[3:6]) == [NO_OBSERVATION] * 3
    assert res.status[7] == NO_OBSERVATION
    assert np.isfinite(res.params).all() and np.isfinite(res.keypoints3d[1:10]).all()


def test_first_frames_without_observation_are_nan_not_garbage(seq):
    conf = seq.confidence[:6].copy()
    conf[:2] = 0.0
    res = pt.Tracker(
        seq.intrinsics, LVM, shape=pt.BodyShape.default()
    ).run(seq.depth[:6], seq.keypoints2d[:6], conf, progress=False)
    assert np.isnan(res.keypoints3d[:2]).all() and list(res.status[:2]) == [NO_OBSERVATION] * 2
    assert np.isfinite(res.keypoints3d[2:]).all()
    assert np.isfinite(res.params).all()  # parameters are never NaN


def test_bad_input_names_the_argument(seq):
    tracker = pt.Tracker(seq.intrinsics, LVM)
    d, k, c = seq.depth[0], seq.keypoints2d[0], seq.confidence[0]
    with pytest.raises(ValueError, match="keypoints2d"):
        tracker.update(d, k[:17], c)
    with pytest.raises(ValueError, match="confidence"):
        tracker.update(d, k, c[:, None])
    with pytest.raises(ValueError, match="depth dtype"):
        tracker.update(d.astype(np.int32), k, c)
    with pytest.raises(ValueError, match="depth is empty"):
        tracker.update(np.zeros((0, 0), np.uint16), k, c)
    with pytest.raises(ValueError, match="does not match the intrinsics"):
        tracker.update(d[:100], k, c)
    with pytest.raises(ValueError, match="fx"):
        pt.Intrinsics.create(fx=float("nan"), fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    bad = dataclasses.replace(seq.intrinsics, fx=seq.intrinsics.fx * np.nan)
    with pytest.raises(ValueError, match="not physical"):
        pt.Tracker(bad)
    with pytest.raises(ValueError, match="method"):
        pt.TrackerConfig(method="mht_x")
    # NaN keypoints are missing keypoints, not NaN poses.
    k_nan = k.copy()
    k_nan[4] = np.nan
    est, status = tracker.update(d, k_nan, c)
    assert np.isfinite(np.asarray(est.params)).all()


def test_config_fit_default_depends_on_method():
    """MHT ships with plain squares (its subsets keep outliers out); LVM and every paper
    setting keep Eq. (1)'s sum of norms; an explicit FitSettings is kept as given."""
    assert TrackerConfig().fit.residuals.loss == "l2"
    assert TrackerConfig(method="mht_g").fit.residuals.loss == "l2"
    assert TrackerConfig(method="lvm").fit.residuals.loss == "l1"
    for method in ("lvm", "mht_r", "mht_g", "mht_h"):
        assert TrackerConfig.paper(method).fit.residuals.loss == "l1"
    assert TrackerConfig(fit=FitSettings(max_steps=5)).fit == FitSettings(max_steps=5)
    assert TrackerConfig().fit.max_steps == 4
    assert TrackerConfig(method="lvm").fit.max_steps == FitSettings().max_steps
    # replace() rebuilds the config: the resolved settings survive it.
    assert TrackerConfig(sigma_h=0.3).replace(r=0.1).fit == TrackerConfig().fit
    with pytest.raises(ValueError, match="TrackerConfig.fit"):
        TrackerConfig(fit="l2")


def test_a_quick_reinitialisation_keeps_the_lost_tracks_facing(seq):
    """Right after a track loss, a frame whose detections are a whole-body left/right swap
    (the person read as facing away) restarts the track facing as before the loss, not turned
    round, with ``reinit_keep_facing`` (5 by default); with 0, or after a user's ``reset``, it
    turns round."""
    flip = _tracker._BODY_FLIP
    swapped = (seq.depth[1], seq.keypoints2d[1][flip], seq.confidence[1][flip])

    plain = pt.Tracker(seq.intrinsics, LVM, mode="per-frame")
    assert plain.initialize(seq.depth[1], seq.keypoints2d[1], seq.confidence[1])
    for keep in (15, 0):
        tracker = pt.Tracker(seq.intrinsics, LVM.replace(reinit_keep_facing=keep), mode="per-frame")
        assert tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])[1] == TRACKED
        before = np.asarray(tracker.state.best)
        tracker._drop_track()  # what lost_patience lost frames in a row do
        assert tracker.initialize(*swapped)
        after = np.asarray(tracker.state.best)
        assert tracker.reinit_flips == (1 if keep else 0)
        if keep:  # the swap undone: the pose the true labels give
            assert left(before) @ left(after) > 0.5
            np.testing.assert_allclose(after, np.asarray(plain.state.best), atol=1e-5)
        else:
            assert left(before) @ left(after) < -0.5
    # Through update(): the frame's index is recorded (where the detector's labels were
    # overridden), and the count follows it.
    tracker = pt.Tracker(seq.intrinsics, LVM.replace(reinit_keep_facing=5), mode="per-frame")
    tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])
    tracker._drop_track()
    tracker.update(*swapped)
    assert tracker.reinit_flip_frames == (1,) and tracker.reinit_flips == 1
    tracker = pt.Tracker(seq.intrinsics, LVM.replace(reinit_keep_facing=15), mode="per-frame")
    tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])
    tracker.reset()  # a new person: nothing to keep
    assert tracker.initialize(*swapped) and tracker.reinit_flips == 0
    with pytest.raises(ValueError, match="reinit_keep_facing"):
        TrackerConfig(reinit_keep_facing=-1)


def test_reinit_check_fit_keeps_the_facing_where_the_last_frame_was_already_swapped(seq):
    """Where the detector's whole-body swap began before the loss (the last tracked frame's
    shoulders and hips already exchanged), the keep-facing test's 2D half cannot see it and the
    re-initialisation turns round; with ``reinit_check_fit`` the fit's facing is checked
    against the pose at the loss and the exchanged landmarks' fit is kept instead."""
    flip = _tracker._BODY_FLIP
    swapped = (seq.depth[1], seq.keypoints2d[1][flip], seq.confidence[1][flip])

    def restart(later: int = 0, **changes):
        """Track frame 0, lose it (its detections already the whole-body swap), restart
        ``later`` frames on from the swapped frame 1; the tracker and its pose before."""
        config = LVM.replace(reinit_keep_facing=5, **changes)
        tracker = pt.Tracker(seq.intrinsics, config, mode="per-frame")
        assert tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])[1] == TRACKED
        before = np.asarray(tracker.state.best)
        tracker._last_tracked_kp = (seq.keypoints2d[0][flip], seq.confidence[0][flip])
        tracker._drop_track()
        tracker._frames_seen += later
        assert tracker.initialize(*swapped)
        return tracker, before

    plain = pt.Tracker(seq.intrinsics, LVM, mode="per-frame")
    assert plain.initialize(seq.depth[1], seq.keypoints2d[1], seq.confidence[1])
    for check in (False, True):
        tracker, before = restart(reinit_check_fit=check)
        after = np.asarray(tracker.state.best)
        assert tracker.reinit_flips == (1 if check else 0)
        if check:
            assert left(before) @ left(after) > 0.5
            np.testing.assert_allclose(after, np.asarray(plain.state.best), atol=1e-5)
        else:
            assert left(before) @ left(after) < -0.5
    # The restart 8 frames after the loss: past reinit_keep_facing's 5, so the check looks only
    # with its own, longer window (reinit_check_frames).
    for frames, keeps in ((None, False), (15, True)):
        tracker, before = restart(8, reinit_check_fit=True, reinit_check_frames=frames)
        facing = left(before) @ left(np.asarray(tracker.state.best))
        assert (facing > 0.5) if keeps else (facing < -0.5), (frames, facing)
        assert tracker.reinit_flips == int(keeps)
    with pytest.raises(ValueError, match="reinit_check_fit"):
        TrackerConfig(reinit_check_fit=1)
    for bad in (-1, True, 2.0):
        with pytest.raises(ValueError, match="reinit_check_frames"):
            TrackerConfig(reinit_check_frames=bad)


def test_reinit_check_tracked_keeps_the_last_tracked_facing_on_a_frame_with_one_pair(seq):
    """A re-initialisation on a frame whose detections are the whole-body swap and that shows
    one left/right pair only (a side view) turns the person round by default; with
    ``reinit_check_tracked`` the fit, facing away from the last tracked pose, is replaced by
    the exchanged landmarks' fit, within that many frames of it and on such frames only."""
    flip = _tracker._BODY_FLIP
    conf = np.array(seq.confidence[1], copy=True)[flip]
    one_pair = conf.copy()
    one_pair[11] = 0.0  # the left hip unseen: the shoulders are the only pair
    kp = seq.keypoints2d[1][flip]

    def restart(frames: int, confidence, later: int = 0):
        config = LVM.replace(reinit_keep_facing=0, reinit_check_tracked=frames)
        tracker = pt.Tracker(seq.intrinsics, config, mode="per-frame")
        assert tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])[1] == TRACKED
        before = np.asarray(tracker.state.best)
        tracker._drop_track()
        tracker._frames_seen += later
        assert tracker.initialize(seq.depth[1], kp, confidence)
        return left(before) @ left(np.asarray(tracker.state.best)), tracker.reinit_flips

    for frames, confidence, later, keeps in (
        (0, one_pair, 0, False),  # off: turned round
        (10, one_pair, 0, True),
        (10, one_pair, 11, False),  # too long after the last tracked frame
        (10, conf, 0, False),  # both pairs seen: the frame's own reading stands
    ):
        facing, flips = restart(frames, confidence, later)
        assert (facing > 0.5) if keeps else (facing < -0.5), (frames, later, facing)
        assert flips == int(keeps)
    for bad in (-1, True, 2.0):
        with pytest.raises(ValueError, match="reinit_check_tracked"):
            TrackerConfig(reinit_check_tracked=bad)


def test_reinit_check_delta_keeps_the_exchange_only_within_its_margin_on_delta(seq):
    """With ``reinit_check_delta`` the tracked check's exchanged fit replaces the plain one
    only if its Delta is at most the plain fit's plus the margin: the Deltas it weighs are
    recorded, the exchanged one is the kept pose's Delta against the frame, and a margin just
    under their gap refuses the exchange (the person is left turned round)."""
    flip = _tracker._BODY_FLIP
    conf = np.array(seq.confidence[1], copy=True)[flip]
    conf[11] = 0.0  # the shoulders are the only left/right pair
    kp = seq.keypoints2d[1][flip]

    def restart(margin: float):
        config = LVM.replace(
            reinit_keep_facing=0, reinit_check_tracked=10, reinit_check_delta=margin
        )
        tracker = pt.Tracker(seq.intrinsics, config, mode="per-frame")
        assert tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])[1] == TRACKED
        before = np.asarray(tracker.state.best)
        tracker._drop_track()
        assert tracker.initialize(seq.depth[1], kp, conf)
        return tracker, left(before) @ left(np.asarray(tracker.state.best))

    tracker, facing = restart(1e3)  # any Delta: as without a margin
    assert facing > 0.5 and tracker.reinit_flips == 1
    ((frame, plain, exchanged),) = tracker.reinit_check_deltas
    assert frame == 0 and np.isfinite(plain) and np.isfinite(exchanged)
    best = np.asarray(tracker.state.best, np.float32)[None]
    depth = _tracker.check_depth(tracker.intrinsics, seq.depth[1], tracker.depth_scale, "test")
    again = _tracker.score_fits(
        tracker.config, tracker.shape, tracker.intrinsics, tracker.floor, depth, best
    )
    np.testing.assert_allclose(float(again[0]), exchanged, rtol=1e-4, atol=1e-6)

    tracker, facing = restart(exchanged - plain - 1e-4)
    assert facing < -0.5 and tracker.reinit_flips == 0
    assert len(tracker.reinit_check_deltas) == 1
    for bad in (float("nan"), float("inf"), True, "0.02"):
        with pytest.raises(ValueError, match="reinit_check_delta"):
            TrackerConfig(reinit_check_delta=bad)


BENT = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])  # 90 degrees about x, wxyz


def test_reinit_partial_frames_restarts_from_the_last_tracked_pose_without_a_pair(seq):
    """After a loss, a frame that shows neither both shoulders nor both hips (the far side
    hidden, as in a side view) cannot orient a new body: by default the re-initialisation
    waits; with ``reinit_partial_frames`` it starts from the last tracked pose, moved onto the
    landmarks it sees, within that many frames of it only (never from a pose judged lost),
    and fits the seen joints; with ``reinit_partial_axes`` it takes that pose's facing only
    (the limbs, a hidden one included, from the frame as at any start), and keeps the restart
    only where its Delta passes the loss test."""
    far = [5, 6, 7, 11, 12, 13]  # left shoulder, elbow, wrist, hip, knee, ankle
    conf = np.array(seq.confidence[1], copy=True)
    conf[far] = 0.0
    frame = (seq.depth[1], seq.keypoints2d[1], conf)

    def restart(
        frames: int, later: int = 0, status: int = TRACKED, axes: bool = False, gate=None
    ):
        config = LVM.replace(reinit_partial_frames=frames, reinit_partial_axes=axes)
        if status == LOST:  # every frame fails the loss test
            config = config.replace(lost_delta=0.0)
        tracker = pt.Tracker(seq.intrinsics, config, mode="per-frame")
        assert tracker.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])[1] == status
        before = np.asarray(tracker.state.best)
        tracker._drop_track()  # what lost_patience lost frames in a row do
        tracker._frames_seen += later
        # The hidden left forearm bent in the last tracked pose: where the restart takes it
        # from (no landmark of it is seen to move it).
        last = tracker._last_tracked_pose
        if last is not None:
            bent = np.array(last[1], np.float64)
            bent[7 + 4 * 4 : 7 + 4 * 5] = BENT
            tracker._last_tracked_pose = (last[0], bent, *last[2:])
        if gate is not None:  # the loss test's Delta threshold, from here on
            tracker.config = tracker.config.replace(lost_delta=gate)
        return tracker, before, tracker.initialize(*frame)

    assert not restart(0)[2]  # the default waits for a pair
    assert not restart(10, later=11)[2]  # too long after the last tracked frame
    assert not restart(10, status=LOST)[2]  # no tracked pose to start from
    seen = [i for i in range(14) if i not in far]
    for axes in (False, True):  # the whole last tracked pose, or its facing only
        assert not restart(10, later=11, axes=axes)[2]
        tracker, before, ok = restart(10, axes=axes)
        assert ok
        after = np.asarray(tracker.state.best)
        assert left(before) @ left(after) > 0.9
        fitted = np.asarray(pt.keypoints(tracker.shape, after))[seen]
        error = np.linalg.norm(fitted - seq.joints3d[1][seen], axis=-1)
        assert np.median(error) < 0.08, error
        # the whole pose keeps the hidden forearm's bend; the facing alone does not
        kept = abs(float(after[7 + 16 : 7 + 20] @ BENT)) > np.cos(np.radians(10) / 2)
        assert kept != axes
        # a restart from the facing alone must also score as a tracked frame would (Delta at
        # most lost_delta); the whole pose's is judged by the next frames only
        assert restart(10, axes=axes, gate=0.0)[2] != axes
    # The start itself: a pose moved by the seen landmarks' mean offset.
    P = np.zeros((18, 3))
    P[3] = [1.0, 2.0, 3.0]
    moved = _tracker.pose_moved_onto(before, P - [0.1, 0.0, 0.0], P, np.arange(18) == 3)
    np.testing.assert_allclose(moved[:3] - before[:3], [0.1, 0.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(moved[3:], before[3:])
    assert _tracker.pose_moved_onto(before, P, P, np.zeros(18, bool)) is None
    for bad in (-1, True, 2.0):
        with pytest.raises(ValueError, match="reinit_partial_frames"):
            TrackerConfig(reinit_partial_frames=bad)
    with pytest.raises(ValueError, match="reinit_partial_axes"):
        TrackerConfig(reinit_partial_axes=1)


def test_initial_pose_takes_the_facing_it_is_given_without_a_left_right_pair(seq):
    """A side view's landmarks (no left/right pair) cannot orient a body: ``initial_pose``
    gives up, unless told the axes (a lost track's), which it then takes as they are, turned
    either way, with the root placed from the landmarks it sees."""
    points = np.asarray(seq.joints3d[1], np.float64)
    has_depth = np.ones(18, bool)
    has_depth[[5, 6, 7, 11, 12, 13]] = False  # the left side hidden
    shape = pt_init.BodyShape.default(np.float64)
    assert pt_init.initial_pose(points, has_depth, shape) is None
    for sign in (1.0, -1.0):
        left_axis = sign * np.array([0.6, 0.0, 0.8])
        up_axis = np.array([0.0, -1.0, 0.0])
        p0 = pt_init.initial_pose(points, has_depth, shape, axes=(left_axis, up_axis))
        R = quat_to_matrix(p0[3:7])
        np.testing.assert_allclose(R[:, 0], left_axis, atol=1e-9)
        np.testing.assert_allclose(R[:, 1], up_axis, atol=1e-9)
        # no hip pair: the root sits a torso length below the neck, along the given up axis
        np.testing.assert_allclose(p0[:3], points[1] - float(shape.torso) * up_axis)
    few = np.zeros(18, bool)
    few[[2, 8]] = True  # two landmarks place nothing
    assert pt_init.initial_pose(points, few, shape, axes=(left_axis, up_axis)) is None


def test_exchanged_since_reads_the_torso_of_the_last_tracked_frame(seq):
    """The 2D half of the re-initialisation's facing test: a whole-body swap's shoulders and
    hips sit on the other side's last positions; a limb's swap, or a frame where neither
    shoulders nor hips are seen in both, is not read as one."""
    kp, conf = seq.keypoints2d[0], seq.confidence[0]
    later = seq.keypoints2d[2]  # the person moved a little
    assert _tracker.exchanged_since(kp, conf, later[_tracker._BODY_FLIP], conf)
    assert not _tracker.exchanged_since(kp, conf, later, conf)
    arms = pt.SIDE_GROUPS["arms"]
    limb = np.arange(18)
    for right, left_ in arms:
        limb[[right, left_]] = limb[[left_, right]]
    assert not _tracker.exchanged_since(kp, conf, later[limb], conf)
    unseen = conf.copy()
    unseen[[2, 5, 8, 11]] = 0.0
    assert not _tracker.exchanged_since(kp, conf, later[_tracker._BODY_FLIP], unseen)


def test_paper_config_is_the_paper_method_alone():
    """``TrackerConfig.paper`` switches off every addition of this project; ``recommended``
    keeps the paper's (N, r, R) with them on."""
    for method, n in (("lvm", 1), ("mht_r", 20), ("mht_g", 5), ("mht_h", 5)):
        paper, ours = TrackerConfig.paper(method), TrackerConfig.recommended(method)
        assert paper.is_paper() and paper.n == n and paper.fit.residuals.loss == "l1"
        assert not paper.surface_offset and not paper.temporal_2d and not paper.use_floor
        assert not paper.reseed and not paper.consensus_refit and not paper.invalid_is_unknown
        assert not ours.is_paper()
        if method != "mht_h":
            assert (ours.n, ours.r, ours.R) == (paper.n, paper.r, paper.R)
    assert TrackerConfig.paper("mht_r").r == 0.05 and TrackerConfig.paper("mht_r").R == 0.15
    assert TrackerConfig.paper("mht_h", num_hypotheses=3).n == 3
    assert set(pt.BEYOND_THE_PAPER) <= set(TrackerConfig.__dataclass_fields__)


def test_the_far_sides_bound_is_decided_by_the_mode_unless_given():
    """``far_side_bound`` and ``bound_trusted`` left at ``None`` are decided by the tracker's
    mode (``TrackerConfig.for_mode``): the gated bound online, nothing offline and per-frame;
    values given stay in every mode, ``far_side_2d`` (its alternative) keeps it off, and the
    paper's method never gets it. ``Tracker.config`` is the decided configuration."""
    default = TrackerConfig()
    assert default.far_side_bound is None and default.bound_trusted is None
    online = default.for_mode("online")
    assert online.far_side_bound is True and online.bound_trusted is True
    assert online.fit.residuals.depth_bounds  # what the bound turns on in the fits
    for mode in ("offline", "per-frame"):
        off = default.for_mode(mode)
        assert off.far_side_bound is False and off.bound_trusted is False
        assert not off.fit.residuals.depth_bounds
    given = TrackerConfig(far_side_bound=True)
    assert given.for_mode("offline").bound_trusted is False  # ungated offline, as before
    assert given.for_mode("online").bound_trusted is True
    assert TrackerConfig(far_side_bound=False).for_mode("online").far_side_bound is False
    assert TrackerConfig(far_side_2d=True).for_mode("online").far_side_bound is False
    ungated = TrackerConfig(far_side_bound=True, bound_trusted=False).for_mode("online")
    assert ungated.bound_trusted is False
    assert TrackerConfig.paper("lvm").for_mode("online").far_side_bound is False
    assert TrackerConfig.paper("mht_h").for_mode("online").is_paper()
    with pytest.raises(ValueError, match="mode must be"):
        default.for_mode("live")
    with pytest.raises(ValueError, match="far_side_bound must be True, False or None"):
        TrackerConfig(far_side_bound="online")
    with pytest.raises(ValueError, match="bound_trusted gates far_side_bound"):
        TrackerConfig(bound_trusted=True)
    intr = pt.Intrinsics.create(fx=300.0, fy=300.0, cx=80.0, cy=60.0, width=160, height=120)
    assert pt.Tracker(intr, mode="online").config == online
    assert pt.Tracker(intr, default, mode="offline").config.far_side_bound is False


_COUNT_LOWERINGS = """
import traceback
import jax.monitoring
from jax._src import dispatch
import posetrack as pt

lowered = []

def count(name, secs, **kw):
    if name == dispatch.JAXPR_TO_MLIR_MODULE_EVENT:  # one per program JAX lowers
        stack = [f.name for f in traceback.extract_stack()]
        lowered.append("Program" if "_build" in stack else kw.get("fun_name"))

jax.monitoring.register_event_duration_secs_listener(count)
seq = pt.synth.generate(0, n_frames=3, width=320, height=240, with_rgb=False)
config = pt.TrackerConfig.recommended("lvm")
del lowered[:]  # the generator's own
tracker = pt.Tracker(seq.intrinsics, config, mode="per-frame")
print("construct", len(lowered))
del lowered[:]
for t in range(3):
    tracker.update(seq.depth[t], seq.keypoints2d[t], seq.confidence[t])
assert tracker.initialized
print("frames", [name for name in lowered if name != "Program"])
"""


def test_a_new_tracker_and_its_first_frames_compile_next_to_nothing():
    """Constructing the first tracker of a process and tracking its first frames are on the
    path to the first pose: inputs are converted on the host, and the track's random key is
    split inside the initialisation program, instead of in small eager JAX programs (each a
    compilation cold, queued behind the step's; a cache load warm). Counted in a fresh
    process (the tracker's own programs aside): the random key's seeding only (was 14 at
    construction and 6 in the first three frames)."""
    run = subprocess.run([sys.executable, "-c", _COUNT_LOWERINGS], env=dict(os.environ),
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert run.returncode == 0, run.stderr
    lines = dict(line.split(" ", 1) for line in run.stdout.strip().splitlines())
    assert int(lines["construct"]) <= 2, run.stdout
    assert lines["frames"] == "[]", run.stdout
