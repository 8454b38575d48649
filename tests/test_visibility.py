"""Self-occlusion of lifted landmarks (``_visibility.py``): a side view whose far arm hangs
behind the torso, with the far wrist's landmark lifted onto the torso's surface (as the depth
camera sees it) or seen where it really is; each case's expectation follows from the scene."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import _body as B
from posetrack._depthobs import NO_FLOOR
from posetrack._geometry import surface_offsets
from posetrack._observe import depth_bounds
from posetrack._rotation import quat_multiply
from posetrack._visibility import far_side, self_occluded, side_view_bounds

INTR = pt.Intrinsics.create(fx=280.0, fy=280.0, cx=159.5, cy=119.5, width=320, height=240)
SHAPE = pt.BodyShape.default(jnp.float32)
R_WRIST, L_WRIST, L_ELBOW = 4, 7, 6
MARGIN, TOL = 0.1, 0.06


def _project(p):
    p = np.asarray(p, np.float64)
    return np.stack([280.0 * p[:, 0] / p[:, 2] + 159.5, 280.0 * p[:, 1] / p[:, 2] + 119.5], -1)


@pytest.fixture(scope="module")
def side():
    """The rest pose at 2.5 m turned 90 degrees about the vertical: one arm toward the
    camera side, the other behind the torso. Returns the pose, its keypoints, the rendered
    depth and which wrist is the far one."""
    p = pt.facing_camera_params(2.5, jnp.float32)
    half = np.pi / 4  # a 90 degree turn about the camera's y axis
    yaw = jnp.asarray([np.cos(half), 0.0, np.sin(half), 0.0], jnp.float32)
    p = B.normalize_params(p.at[3:7].set(quat_multiply(yaw, p[3:7])))
    kps = np.asarray(pt.keypoints(SHAPE, p), np.float64)
    a, b, r = B.capsules(SHAPE, p)
    depth, _ = pt.render_depth(pt.Capsules(a=a, b=b, radius=r), INTR, sharpness=None)
    far = L_WRIST if kps[L_WRIST, 2] > kps[R_WRIST, 2] else R_WRIST
    near = R_WRIST + L_WRIST - far
    return p, kps, np.asarray(depth), far, near


def _landmarks(kps, points3d):
    uv = _project(kps)
    return pt.Landmarks(
        keypoints2d=jnp.asarray(uv, jnp.float32),
        confidence=jnp.ones(18, jnp.float32),
        points3d=jnp.asarray(points3d, jnp.float32),
        detected=jnp.ones(18, bool),
        has_depth=jnp.ones(18, bool),
    )


@pytest.fixture(scope="module")
def occluded():
    return jax.jit(self_occluded)


def _seen_at(depth, kps, i):
    """The rendered surface depth at keypoint i's pixel (what the sensor sees there)."""
    u, v = np.round(_project(kps)[i]).astype(int)
    return float(depth[v, u])


def test_the_scene_hides_the_far_wrist(side):
    _, kps, depth, far, near = side
    # The premise of the other tests: the far wrist's pixel shows a surface well in front of
    # it (the torso), the near wrist's shows the wrist itself.
    assert _seen_at(depth, kps, far) < kps[far, 2] - 0.15
    assert abs(_seen_at(depth, kps, near) - kps[near, 2]) < 0.06


def test_a_landmark_lifted_onto_the_occluder_is_dropped(side, occluded):
    p, kps, depth, far, near = side
    off = np.asarray(surface_offsets(SHAPE))
    pts = kps.copy()  # every landmark where lifting puts it: the seen surface + offset
    pts[:, 2] = [_seen_at(depth, kps, i) + off[i] for i in range(18)]
    hidden = np.asarray(occluded(SHAPE, p, _landmarks(kps, pts), INTR, off, MARGIN, TOL))
    far_arm = (3, 4) if far == R_WRIST else (6, 7)  # elbow, wrist
    assert hidden[list(far_arm)].all()
    # Nothing of the near arm or the face can be hidden (their own surfaces are seen).
    near_arm = (2, 3, 4) if near == R_WRIST else (5, 6, 7)
    assert not hidden[list(near_arm) + [0, 14, 15, 16, 17]].any()


def test_a_landmark_where_the_joint_really_is_stays(side, occluded):
    p, kps, _, far, _ = side
    off = np.asarray(surface_offsets(SHAPE))
    # (b): seen at the joint's own depth (e.g. a far arm visible past the torso's edge).
    hidden = np.asarray(occluded(SHAPE, p, _landmarks(kps, kps), INTR, off, MARGIN, TOL))
    assert not hidden.any()


def test_a_limb_seen_in_front_of_the_occluder_stays(side, occluded):
    """(c), the way back: the model holds the arm behind the torso, but the sensor saw a
    surface 15 cm in front of the torso's: the real arm is there, its landmark must stay."""
    p, kps, depth, far, _ = side
    off = np.asarray(surface_offsets(SHAPE))
    pts = kps.copy()
    pts[far, 2] = _seen_at(depth, kps, far) - 0.15 + off[far]
    hidden = np.asarray(occluded(SHAPE, p, _landmarks(kps, pts), INTR, off, MARGIN, TOL))
    assert not hidden[far]
    # ... and with the tolerance widened past that gap it would be dropped (the test bites).
    hidden = np.asarray(occluded(SHAPE, p, _landmarks(kps, pts), INTR, off, MARGIN, 0.2))
    assert hidden[far]


@pytest.fixture(scope="module")
def facing():
    p = pt.facing_camera_params(2.5, jnp.float32)
    kps = np.asarray(pt.keypoints(SHAPE, p), np.float64)
    a, b, r = B.capsules(SHAPE, p)
    depth, _ = pt.render_depth(pt.Capsules(a=a, b=b, radius=r), INTR, sharpness=None)
    return p, kps, np.asarray(depth)


def test_facing_the_camera_nothing_is_hidden(facing, occluded):
    """Every landmark lifted from the rendered surface (as a camera would): each joint's own
    part is what is seen, and a part that holds its joint (the pelvis around a hip) does not
    hide it."""
    p, kps, depth = facing
    off = np.asarray(surface_offsets(SHAPE))
    pts = kps.copy()
    pts[:, 2] = [_seen_at(depth, kps, i) + off[i] for i in range(18)]
    hidden = np.asarray(occluded(SHAPE, p, _landmarks(kps, pts), INTR, off, MARGIN, TOL))
    assert not hidden.any()


def test_a_detection_off_its_joint_is_not_hidden_by_what_it_landed_on(facing, occluded):
    """(a): a wrist the model holds beside the hip, detected on the belly and lifted onto it:
    the seen surface lies well in front of the model's wrist and on another part, but the
    model's own ray to the wrist is clear, so the landmark stays (it may be wrong; the
    subsets and Delta deal with outliers)."""
    p, kps, depth = facing
    off = np.asarray(surface_offsets(SHAPE))
    uv = _project(kps)
    belly = 0.5 * (kps[8] + kps[11]) + np.asarray([0.0, -0.1, 0.0])  # between the hips, higher
    uv[L_WRIST] = _project(belly[None])[0]
    u, v = np.round(uv[L_WRIST]).astype(int)
    seen = float(depth[v, u])
    assert seen < kps[L_WRIST, 2] - MARGIN  # premise: (b) and (c) would flag it
    pts = kps.copy()
    pts[L_WRIST] = belly
    pts[L_WRIST, 2] = seen + off[L_WRIST]
    lm = _landmarks(kps, pts)
    lm = pt.Landmarks(
        keypoints2d=jnp.asarray(uv, jnp.float32), confidence=lm.confidence,
        points3d=lm.points3d, detected=lm.detected, has_depth=lm.has_depth,
    )  # fmt: skip
    hidden = np.asarray(occluded(SHAPE, p, lm, INTR, off, MARGIN, TOL))
    assert not hidden[L_WRIST]


@pytest.fixture(scope="module")
def step():
    return jax.jit(pt.tracker_step)


def _side_step(side, step, config, conf, trusted=True, with_state=False):
    """One jitted step on the side view, the far wrist lifted from the rendered depth onto
    the torso; W^h made to favour drawing its landmark. ``trusted``: the state's
    ``TrackState.trusted``; ``with_state``: return ``(new state, estimate)``."""
    p, kps, depth, far, _ = side
    n = config.n
    off = np.asarray(surface_offsets(SHAPE))
    previous = kps.copy()
    # W^h compares with the hypotheses' previous keypoints: put the far wrist's where its
    # landmark will be, so the temporal weight favours drawing it.
    previous[far, 2] = _seen_at(depth, kps, far) + off[far]
    state = pt.TrackState(
        hypotheses=jnp.tile(p[None], (n, 1)),
        previous=jnp.tile(jnp.asarray(previous, jnp.float32)[None], (n, 1, 1)),
        best=p,
        key=jax.random.PRNGKey(0),
        trusted=jnp.asarray(trusted),
    )
    kp2d = jnp.asarray(_project(kps), jnp.float32)
    floor = jnp.asarray(NO_FLOOR, jnp.float32)
    out = step(config, SHAPE, INTR, floor, state, jnp.asarray(depth), kp2d, jnp.asarray(conf))
    return out if with_state else out[1]


#: Static fields shared by the step tests (one compiled program for all of them).
GATED = pt.TrackerConfig(occlusion_gate=True, score_width=80, score_height=60)


def test_the_step_fits_an_unconfident_keypoint_in_2d_only(side, step):
    """``TrackerConfig.depth_confidence``: the far wrist, detected at 0.5 where the rest of
    the body is at 0.9 (a detector's guess behind the torso), loses its 3D landmark in every
    hypothesis at ratio 0.8, and is fitted in 2D; at ratio 0 (the paper) the even hypotheses
    draw it."""
    _, kps, _, far, _ = side
    conf = np.full(18, 0.9, np.float32)
    conf[far] = 0.5
    est = _side_step(side, step, GATED.replace(depth_confidence=0.8), conf)
    assert not bool(est.landmarks.has_depth[far]) and bool(est.landmarks.detected[far])
    used3d, used2d = np.asarray(est.used3d), np.asarray(est.used2d)
    assert not used3d[:, far].any()
    assert used2d[: GATED.n, far].sum() >= 6  # drawn as 2D (subsets may leave a few out)
    paper = _side_step(side, step, GATED.replace(depth_confidence=0.0), conf)
    assert bool(paper.landmarks.has_depth[far])
    assert np.asarray(paper.used3d)[0::2, far].sum() >= 3


def test_far_side_flags_the_limbs_turned_away_and_nothing_facing(side, facing):
    p, kps, _, far, near = side
    flags = np.asarray(jax.jit(far_side)(p))
    far_limbs = [3, 4, 9, 10] if far == R_WRIST else [6, 7, 12, 13]
    assert flags[far_limbs].all()
    assert flags.sum() == 4  # not the near limbs, the torso or the face
    # Turned 90 degrees the other way about the vertical, the other side is the far one.
    half = -np.pi / 4
    yaw = jnp.asarray([np.cos(half), 0.0, np.sin(half), 0.0], jnp.float32)
    front = facing[0]
    other = np.asarray(
        far_side(B.normalize_params(front.at[3:7].set(quat_multiply(yaw, front[3:7]))))
    )
    assert other.sum() == 4
    assert other[[3, 4, 9, 10]].all() == (far != R_WRIST)
    assert other[[6, 7, 12, 13]].all() == (far == R_WRIST)
    # Facing the camera no side is turned away.
    assert not np.asarray(far_side(front)).any()
    # With the torso: the far side's shoulder and hip too, nothing else.
    torso = np.asarray(far_side(p, torso=True))
    far_torso = [2, 8] if far == R_WRIST else [5, 11]
    assert torso[far_limbs + far_torso].all() and torso.sum() == 6
    assert not np.asarray(far_side(front, torso=True)).any()
    # The bounds of a side view: those but the legs, the far eye and ear and the neck (with
    # the legs: the far knee and ankle too); facing: none.
    bounds = np.asarray(side_view_bounds(p))
    far_face = [14, 16] if far == R_WRIST else [15, 17]
    far_arm, far_legs = far_limbs[:2], far_limbs[2:]
    assert bounds[far_arm + far_torso + far_face + [1]].all() and bounds.sum() == 7
    with_legs = np.asarray(side_view_bounds(p, legs=True))
    assert with_legs[far_legs].all() and with_legs.sum() == 9
    assert not np.asarray(side_view_bounds(front)).any()
    # Turned 45 degrees (sine 0.71): a side view at 0.5, not at far_side_bound's 0.75.
    eighth = np.pi / 8
    yaw45 = jnp.asarray([np.cos(eighth), 0.0, np.sin(eighth), 0.0], jnp.float32)
    p45 = B.normalize_params(front.at[3:7].set(quat_multiply(yaw45, front[3:7])))
    assert np.asarray(side_view_bounds(p45, 0.5)).sum() == 7
    assert not np.asarray(side_view_bounds(p45, 0.75)).any()


def test_far_side_2d_fits_the_far_side_in_2d_at_full_confidence(side, step):
    """``far_side_2d``: every keypoint detected at the same confidence (no gap for
    ``depth_confidence_far`` to use); the far wrist, shoulder and hip lose their 3D
    landmarks in every hypothesis and stay detected, the near ones keep theirs; without the
    switch the far ones keep theirs too."""
    _, _, _, far, near = side
    far_torso = [2, 8] if far == R_WRIST else [5, 11]
    near_torso = [5, 11] if far == R_WRIST else [2, 8]
    conf = np.full(18, 0.9, np.float32)
    est = _side_step(side, step, GATED.replace(far_side_2d=True), conf)
    has, det = np.asarray(est.landmarks.has_depth), np.asarray(est.landmarks.detected)
    assert not has[[far, *far_torso]].any() and det[[far, *far_torso]].all()
    assert has[[near, *near_torso]].all()
    assert not np.asarray(est.used3d)[:, [far, *far_torso]].any()
    plain = _side_step(side, step, GATED, conf)
    assert np.asarray(plain.landmarks.has_depth)[[far, *far_torso]].all()


def test_far_side_bound_keeps_the_far_sides_depth_as_a_bound(side, step):
    """``far_side_bound``: the far wrist, shoulder, hip, eye and ear and the neck are fitted
    in 2D (no hypothesis draws their 3D landmarks) and keep their lifted points as bounds
    (the near side's surface seen on their pixels); the near ones keep their depth. Lifted
    onto the near side, those landmarks disagree with the true pose, which lowers the
    agreement of the plain step; as bounds they leave the agreement share. Too few landmarks
    left with depth: no bounds."""
    _, _, _, far, near = side
    far_torso = [1, 2, 8, 14, 16] if far == R_WRIST else [1, 5, 11, 15, 17]
    near_torso = [5, 11, 15, 17] if far == R_WRIST else [2, 8, 14, 16]
    conf = np.full(18, 0.9, np.float32)
    est = _side_step(side, step, GATED.replace(far_side_bound=True), conf)
    plain = _side_step(side, step, GATED, conf)
    far_all = [far, *far_torso]
    bounds = np.asarray(depth_bounds(est.landmarks))
    assert bounds[far_all].all() and not bounds[[near, *near_torso]].any()
    assert np.asarray(est.landmarks.has_depth)[[near, *near_torso]].all()
    np.testing.assert_array_equal(est.landmarks.points3d, plain.landmarks.points3d)
    assert not np.asarray(est.used3d)[:, far_all].any()
    assert np.asarray(plain.landmarks.has_depth)[far_all].all()
    # (The far knee and ankle keep their depth: in this rest pose they hide behind the near
    # leg and still disagree, which a walking person's legs rarely do.)
    assert float(est.agreement) > float(plain.agreement) + 0.2
    # Fewer landmarks with depth besides the bounded ones than bound_min_landmarks (here 11
    # of 18 remain): the landmarks are used as lifted.
    few = _side_step(side, step, GATED.replace(far_side_bound=True, bound_min_landmarks=12), conf)
    assert not np.asarray(depth_bounds(few.landmarks)).any()
    np.testing.assert_array_equal(few.landmarks.has_depth, plain.landmarks.has_depth)
    with pytest.raises(ValueError, match="bound_min_landmarks"):
        GATED.replace(bound_min_landmarks=-1)
    with pytest.raises(ValueError, match="bound_turn_sin"):
        GATED.replace(bound_turn_sin=1.5)
    assert GATED.replace(far_side_bound=True).fit.residuals.depth_bounds
    assert not GATED.fit.residuals.depth_bounds
    with pytest.raises(ValueError, match="far_side_2d and far_side_bound"):
        GATED.replace(far_side_2d=True, far_side_bound=True)


def test_bound_trusted_bounds_only_behind_a_pose_that_passed_the_loss_test(side, step):
    """``bound_trusted``: behind a previous output that passed the track-loss test
    (``TrackState.trusted``) the far side's depth is a bound as with ``far_side_bound``
    alone; behind one that failed it the landmarks are used as lifted. The step passes the
    flag on; the frame's status sets it."""
    _, _, _, far, _ = side
    conf = np.full(18, 0.9, np.float32)
    bound = GATED.replace(far_side_bound=True)
    cfg = bound.replace(bound_trusted=True)
    alone = _side_step(side, step, bound, conf)
    plain = _side_step(side, step, GATED, conf)
    new, est = _side_step(side, step, cfg, conf, trusted=True, with_state=True)
    np.testing.assert_array_equal(depth_bounds(est.landmarks), depth_bounds(alone.landmarks))
    assert np.asarray(depth_bounds(est.landmarks))[far]
    passed_on, doubted = _side_step(side, step, cfg, conf, trusted=False, with_state=True)
    assert not np.asarray(depth_bounds(doubted.landmarks)).any()
    np.testing.assert_array_equal(doubted.landmarks.has_depth, plain.landmarks.has_depth)
    np.testing.assert_array_equal(doubted.landmarks.points3d, plain.landmarks.points3d)
    # The step passes the flag on: the frame's status (host or chunked scan) sets it
    # (tests/test_chunk.py).
    assert bool(new.trusted) and not bool(passed_on.trusted)
    with pytest.raises(ValueError, match="bound_trusted"):
        GATED.replace(bound_trusted=True)


def test_the_far_side_gate_spares_the_near_sides_unconfident_keypoint(side, step):
    """``depth_confidence_far``: both wrists detected at 0.5 (the body at 0.9); the far one
    (behind the torso in the previous output) loses its 3D landmark, the near one keeps it;
    without the switch both lose it."""
    _, _, _, far, near = side
    conf = np.full(18, 0.9, np.float32)
    conf[[far, near]] = 0.5
    est = _side_step(side, step, GATED.replace(depth_confidence_far=0.8), conf)
    has = np.asarray(est.landmarks.has_depth)
    assert not has[far] and has[near]
    assert not np.asarray(est.used3d)[:, far].any()
    both = _side_step(side, step, GATED.replace(depth_confidence=0.8), conf)
    assert not np.asarray(both.landmarks.has_depth)[[far, near]].any()


def test_the_far_side_gate_is_validated():
    assert pt.TrackerConfig().depth_confidence_far == 0.0  # off: the paper's lifting
    for bad in (-0.1, 1.5, float("nan"), True):
        with pytest.raises(ValueError, match="TrackerConfig.depth_confidence_far"):
            pt.TrackerConfig(depth_confidence_far=bad)


def test_the_step_leaves_hidden_landmarks_to_every_other_hypothesis(side, step):
    """``TrackerConfig.occlusion_gate`` in the jitted step: the far wrist, lifted from the
    rendered depth onto the torso, is fitted in 2D only by the odd hypotheses, while the even
    ones draw its 3D landmark as usual (so the gate, not the temporal weight, kept it out)."""
    _, kps, _, far, _ = side
    est = _side_step(side, step, GATED, np.ones(18, np.float32))
    lm = est.landmarks
    assert bool(lm.has_depth[far])  # the landmark itself is kept (the even ones may use it)
    assert float(lm.points3d[far, 2]) < kps[far, 2] - 0.15  # lifted onto the torso
    used3d, used2d = np.asarray(est.used3d), np.asarray(est.used2d)
    assert not used3d[1::2, far].any()
    assert used2d[1::2, far].all()
    assert used3d[0::2, far].sum() >= 3
