"""The parts of the tracker step on their own (issue 11, item 6): landmark weights and subsets
(paper section 2.2), reseeding, the consensus refit and the dense refinement, each against an
expectation computed independently (NumPy / by hand), and eager vs ``jax.jit`` (and ``vmap``
vs a loop) on the core functions.

One small scene serves every test: a known pose rendered at 64x48, its landmarks with a few
planted defects, and three hypotheses' previous keypoints. Jitted callables are module-scoped
so each compiles once.
"""

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import _body as B
from posetrack import _select
from posetrack._depthobs import NO_FLOOR, tracker_landmarks
from posetrack._geometry import GEOMETRY_PARTNER, part_radii, partner_rest_lengths
from posetrack._render import DEFAULT_SHARPNESS
from posetrack._score import DEFAULT_D_M
from posetrack._select import consensus_set, geometry_distance, landmark_subsets, landmark_weights
from posetrack._step import TrackState, consensus_refit, landmark_agreement, reseed_hypotheses

FX = 60.0
INTR = pt.Intrinsics.create(fx=FX, fy=FX, cx=31.5, cy=23.5, width=64, height=48)
SHAPE = pt.BodyShape.default()
N = 3

R_ELBOW, L_WRIST, L_KNEE, R_SHOULDER, L_EAR = 3, 7, 12, 2, 17


def _true_pose():
    rng = np.random.default_rng(0)
    p = np.array(pt.facing_camera_params(2.5), np.float32)
    p[7:] += rng.normal(size=36).astype(np.float32) * 0.3
    return B.normalize_params(jnp.asarray(p))


def _kps(params):
    return np.asarray(pt.keypoints(SHAPE, params), np.float64)


def _project(points):
    """Pinhole projection by hand (NumPy) with the test camera."""
    points = np.asarray(points, np.float64)
    return np.stack(
        [FX * points[..., 0] / points[..., 2] + 31.5, FX * points[..., 1] / points[..., 2] + 23.5],
        -1,
    )


def _landmarks(points, detected, has_depth, uv=None):
    uv = _project(points) if uv is None else uv
    points = np.where(np.asarray(has_depth)[:, None], points, 0.0)
    return pt.Landmarks(
        keypoints2d=jnp.asarray(np.where(np.asarray(detected)[:, None], uv, 0.0), jnp.float32),
        confidence=jnp.asarray(detected, jnp.float32),
        points3d=jnp.asarray(points, jnp.float32),
        detected=jnp.asarray(detected),
        has_depth=jnp.asarray(has_depth),
    )


@pytest.fixture(scope="module")
def scene():
    """A known pose, its rendered depth and landmarks with planted defects, and 3 hypotheses.

    Landmarks are the true keypoints, except: the right elbow is 30 cm off (3D and 2D); the
    right shoulder and the left wrist are seen in 2D only (no depth); the left ear is not
    detected. Previous keypoints: each hypothesis is a slightly different pose; for hypothesis
    0 the left knee was 50 cm away (the landmark 'jumped'), for hypothesis 1 the left wrist
    (2D only) was 30 cm away.
    """
    true = _true_pose()
    M = _kps(true)
    a, b, r = pt.capsules(SHAPE, true)
    z, fg = pt.render_depth(pt.Capsules(a=a, b=b, radius=r), INTR, sharpness=None)
    depth = jnp.where(fg > 0, z, 0.0)
    obs = M.copy()
    obs[R_ELBOW] += [0.30, 0.0, 0.0]
    has = np.ones(18, bool)
    has[[R_SHOULDER, L_WRIST, L_EAR]] = False
    det = np.ones(18, bool)
    det[L_EAR] = False
    uv = _project(obs)
    lm = _landmarks(obs, det, has, uv)
    rng = np.random.default_rng(1)
    hyps = jnp.stack([
        B.normalize_params(true + jnp.asarray(rng.normal(size=43) * 0.03, jnp.float32))
        for _ in range(N)
    ])  # fmt: skip
    prev = np.stack([_kps(h) for h in hyps])
    prev[0, L_KNEE] += [0.0, 0.0, 0.5]
    prev[1, L_WRIST] += [0.3, 0.0, 0.0]
    return dict(
        true=true, M=M, depth=depth, lm=lm, hyps=hyps,
        previous=jnp.asarray(prev, jnp.float32), prev_np=prev,
    )  # fmt: skip


def _config(method, **kw):
    base = dict(
        method=method, num_hypotheses=N, r=0.05, R=0.15, sigma_g=0.5, sigma_h=0.5, d_hmax=0.45
    )
    return pt.TrackerConfig(**{**base, **kw})


_REST = partner_rest_lengths(SHAPE)
_RADII = part_radii(SHAPE)
_geometry_distance = jax.jit(geometry_distance)


def reference_weights(config, lm, depth, prev):
    """(W, w) of section 2.2 written out in NumPy: min over the method's criteria; 2D weights
    l W + (1 - l) where F_i (for 2D-only landmarks: 1, or with ``temporal_2d`` the 2D temporal
    weight); d_g from :func:`geometry_distance` with each keypoint's partner taken from the
    observation where it has depth, else from the hypothesis' previous keypoints."""
    l = 0.33  # noqa: E741 (the paper's l)
    F = np.asarray(lm.has_depth)
    O = np.asarray(lm.points3d, np.float64)  # noqa: E741 (the paper's O_i)
    o = np.asarray(lm.keypoints2d, np.float64)
    n = prev.shape[0]
    if config.method == "lvm":
        return np.ones((n, 18)), np.ones((n, 18))
    W = np.full((n, 18), 1.0 - config.R)
    w = np.full((n, 18), 1.0 - config.r)
    if config.method in ("mht_g", "mht_h"):
        partner = np.asarray(GEOMETRY_PARTNER)
        for h in range(n):
            pts = np.where(F[partner][:, None], O[partner], prev[h][partner])
            pts = jnp.asarray(pts, jnp.float32)
            d_g = np.asarray(
                _geometry_distance(lm, pts, jnp.ones(18, bool), _REST, _RADII, depth, INTR),
                np.float64,
            )
            Wg = np.exp(-d_g / (2 * config.sigma_g**2))
            W[h] = np.minimum(W[h], Wg)
            w[h] = np.minimum(w[h], np.where(F, l * Wg + (1 - l), 1.0))
    if config.method == "mht_h":
        for h in range(n):
            d_h = np.minimum(np.linalg.norm(O - prev[h], axis=-1), config.d_hmax) / config.d_hmax
            Wh = np.exp(-d_h / (2 * config.sigma_h**2))
            W[h] = np.minimum(W[h], Wh)
            if config.temporal_2d:
                px = np.linalg.norm(_project(prev[h]) - o, axis=-1)
                d2 = px * np.maximum(prev[h][:, 2], 0.2) / FX
                d2 = np.minimum(d2, config.d_hmax) / config.d_hmax
                only2d = l * np.exp(-d2 / (2 * config.sigma_h**2)) + (1 - l)
            else:
                only2d = np.ones(18)
            w[h] = np.minimum(w[h], np.where(F, l * Wh + (1 - l), only2d))
    return W, w


# ---------------------------------------------------------------------------------------------
# Landmark weights (paper section 2.2)


@pytest.fixture(scope="module")
def weights_jit():
    return jax.jit(landmark_weights)


def _weights(weights_jit, config, s, lm=None, previous=None):
    lm = s["lm"] if lm is None else lm
    previous = s["previous"] if previous is None else previous
    W, w = weights_jit(config, SHAPE, INTR, s["depth"], lm, previous)
    return np.asarray(W, np.float64), np.asarray(w, np.float64)


def test_mht_r_weights_are_one_minus_the_exclusion_ratios(weights_jit, scene):
    W, w = _weights(weights_jit, _config("mht_r"), scene)
    assert W.shape == w.shape == (N, 18)
    np.testing.assert_allclose(W, 0.85, atol=1e-7)
    np.testing.assert_allclose(w, 0.95, atol=1e-7)


def test_mht_g_weights_are_min_of_random_and_geometry(weights_jit, scene):
    config = _config("mht_g")
    W, w = _weights(weights_jit, config, scene)
    W_ref, w_ref = reference_weights(config, scene["lm"], scene["depth"], scene["prev_np"])
    # The scene exercises both sides of the min: some W are geometry-limited, some by 1 - R.
    assert (W_ref < 0.85 - 0.05).any() and (np.isclose(W_ref, 0.85)).any()
    np.testing.assert_allclose(W, W_ref, atol=1e-5)
    np.testing.assert_allclose(w, w_ref, atol=1e-5)
    # The elbow 30 cm off its bone gets a low geometric weight.
    assert (W[:, R_ELBOW] < 0.5).all()
    # No depth: nothing for W^g to say about the 2D landmark (w = 1 - r).
    np.testing.assert_allclose(w[:, [R_SHOULDER, L_WRIST]], 0.95, atol=1e-7)


@pytest.mark.parametrize("temporal_2d", [False, True])
def test_mht_h_weights_add_temporal_continuity(weights_jit, scene, temporal_2d):
    config = _config("mht_h", temporal_2d=temporal_2d)
    W, w = _weights(weights_jit, config, scene)
    W_ref, w_ref = reference_weights(config, scene["lm"], scene["depth"], scene["prev_np"])
    np.testing.assert_allclose(W, W_ref, atol=1e-5)
    np.testing.assert_allclose(w, w_ref, atol=1e-5)
    # The knee that 'jumped' 50 cm from hypothesis 0's previous knee: low W^h for that
    # hypothesis only (d_h = 1: exp(-1 / (2 * 0.5^2)) = e^-2).
    assert W[0, L_KNEE] == pytest.approx(np.exp(-2.0), abs=1e-5)
    assert (W[1:, L_KNEE] > 0.5).all()
    assert w[0, L_KNEE] == pytest.approx(0.33 * np.exp(-2.0) + 0.67, abs=1e-5)
    Wg, _ = _weights(weights_jit, _config("mht_g"), scene)
    assert (W <= Wg + 1e-6).all()  # a min over more criteria
    # The 2D-only left wrist, 30 cm from hypothesis 1's previous wrist: the paper gives it no
    # temporal term; temporal_2d gives it one, for hypothesis 1 only.
    if temporal_2d:
        assert w[1, L_WRIST] < 0.8 and (w[[0, 2], L_WRIST] > 0.9).all()
    else:
        np.testing.assert_allclose(w[:, L_WRIST], 0.95, atol=1e-7)


def test_lvm_weights_are_all_one(weights_jit, scene):
    W, w = _weights(weights_jit, _config("lvm"), scene)
    assert (W == 1.0).all() and (w == 1.0).all()


# ---------------------------------------------------------------------------------------------
# Landmark subsets

NUM_KEYS = 2000
KEYS = jax.random.split(jax.random.PRNGKey(11), NUM_KEYS)


@pytest.fixture(scope="module")
def subsets_many():
    """landmark_subsets over many keys (the weights do not depend on the key: computed once).
    Every test uses MHT_h at the same shapes: one compilation."""
    many = jax.vmap(landmark_subsets, in_axes=(None, 0, None, None, None, None, None))
    return jax.jit(eqx.debug.assert_max_traces(many, max_traces=1))


def _subsets(subsets_many, config, s, lm=None, previous=None):
    lm = s["lm"] if lm is None else lm
    previous = s["previous"] if previous is None else previous
    u3, u2 = subsets_many(config, KEYS, SHAPE, INTR, s["depth"], lm, previous)
    return np.asarray(u3), np.asarray(u2)


def test_subset_counts_are_floor_of_the_weights_and_only_available(subsets_many, scene):
    config = _config("mht_h", temporal_2d=True)
    lm = scene["lm"]
    F, f = np.asarray(lm.has_depth), np.asarray(lm.detected)
    u3, u2 = _subsets(subsets_many, config, scene)
    W_ref, w_ref = reference_weights(config, lm, scene["depth"], scene["prev_np"])
    S, s = (W_ref * F).sum(1), (w_ref * f).sum(1)
    # (no sum within rounding of an integer, so floor is unambiguous)
    assert (np.abs(S - np.round(S)) > 1e-3).all() and (np.abs(s - np.round(s)) > 1e-3).all()
    assert u3.shape == (NUM_KEYS, N, 18)
    assert (u3.sum(-1) == np.floor(S)[None]).all()
    assert (u2.sum(-1) == np.floor(s)[None]).all()
    assert not (u3 & ~F).any() and not (u2 & ~f).any()


def test_zero_weight_landmark_is_never_drawn(subsets_many, scene):
    """Previous keypoints equal to the landmarks except hypothesis 0's knee, 50 cm away; with
    sigma_h = 0.1 its W^h is exp(-50): never drawn for hypothesis 0, often for the others."""
    config = _config("mht_h", sigma_h=0.1, sigma_g=1.5)
    M = np.asarray(scene["lm"].points3d, np.float64)
    prev = np.where(np.asarray(scene["lm"].has_depth)[None, :, None], M[None], scene["prev_np"])
    prev[0, L_KNEE] += [0.0, 0.0, 0.5]
    u3, _ = _subsets(subsets_many, config, scene, previous=jnp.asarray(prev, jnp.float32))
    freq = u3.mean(0)
    assert freq[0, L_KNEE] == 0.0
    assert (freq[1:, L_KNEE] > 0.5).all()


def _inclusion_probabilities(weights, k):
    """Exact P(item drawn) for k draws without replacement, each with probability proportional
    to the remaining weights (sequential weighted sampling), by enumerating the orderings."""
    n = len(weights)
    p = np.zeros(n)
    for order in itertools.permutations(range(n), k):
        prob, left = 1.0, weights.sum()
        for i in order:
            prob *= weights[i] / left
            left -= weights[i]
        p[list(order)] += prob
    return p


def test_subset_frequencies_follow_the_weights(subsets_many, scene):
    """Five 3D landmarks whose previous keypoints lie 0-45 cm away (W^h from 1 to e^-2); over
    2000 fixed keys each is drawn as often as sequential weighted sampling without
    replacement predicts (computed exactly). Sampling standard error <= 0.011."""
    config = _config("mht_h", R=0.0, sigma_g=5.0)
    lm0 = scene["lm"]
    avail = np.array([1, 5, 8, 11, 9])
    has = np.zeros(18, bool)
    has[avail] = True
    M = scene["M"]
    lm = _landmarks(M, np.asarray(lm0.detected), has)
    prev = np.repeat(M[None], N, 0)
    offsets = np.array([[0.0, 0.1, 0.2, 0.3, 0.45], [0.45, 0.3, 0.0, 0.0, 0.1], [0.05] * 5])
    prev[:, avail, 0] += offsets
    u3, _ = _subsets(subsets_many, config, scene, lm=lm, previous=jnp.asarray(prev, jnp.float32))
    W_ref, _ = reference_weights(config, lm, scene["depth"], prev)
    for h in range(N):
        w = W_ref[h, avail]
        k = int(np.floor(w.sum()))
        assert 1 <= k < len(avail)  # a real choice
        expected = _inclusion_probabilities(w, k)
        np.testing.assert_allclose(u3[:, h, avail].mean(0), expected, atol=0.045)


def test_hypotheses_draw_different_subsets(subsets_many, scene):
    # (MHT_h with flat criteria, W = 1 - R: the same compiled sampler as the other tests.)
    config = _config("mht_h", R=0.3, r=0.3, sigma_g=50.0, sigma_h=50.0)
    u3, u2 = _subsets(subsets_many, config, scene)
    differ3 = (u3 != u3[:, :1]).any(axis=(1, 2))  # some hypothesis differs from hypothesis 0
    differ2 = (u2 != u2[:, :1]).any(axis=(1, 2))
    assert differ3.mean() > 0.9 and differ2.mean() > 0.9
    # ... and every landmark is drawn by some key (no fixed ordering).
    F = np.asarray(scene["lm"].has_depth)
    assert (u3.any(axis=(0, 1)) == F).all()


def test_lvm_selects_every_available_landmark(scene):
    lm = scene["lm"]
    u3, u2 = landmark_subsets(
        _config("lvm"), KEYS[0], SHAPE, INTR, scene["depth"], lm, scene["previous"]
    )
    assert (np.asarray(u3) == np.asarray(lm.has_depth)[None]).all()
    assert (np.asarray(u2) == np.asarray(lm.detected)[None]).all()


def test_all_landmarks_hypothesis_takes_every_landmark_and_leaves_the_others(scene):
    """Opt-in: hypothesis 0 fits every landmark (as LVM); the other hypotheses keep the
    weighted draws they get without it (same key)."""
    lm, args = scene["lm"], (KEYS[0], SHAPE, INTR, scene["depth"], scene["lm"], scene["previous"])
    on = _config("mht_h", all_landmarks_hypothesis=True)
    a3, a2 = map(np.asarray, landmark_subsets(on, *args))
    b3, b2 = map(np.asarray, landmark_subsets(_config("mht_h"), *args))
    assert (a3[0] == np.asarray(lm.has_depth)).all() and (a2[0] == np.asarray(lm.detected)).all()
    assert b3[0].sum() < a3[0].sum()  # without it, hypothesis 0 draws a subset
    assert (a3[1:] == b3[1:]).all() and (a2[1:] == b2[1:]).all()


# ---------------------------------------------------------------------------------------------
# The agreement read by the track-loss test


def test_agreement_counts_plausible_landmarks_only(scene):
    lm, true_kps = scene["lm"], _kps(_true_pose())
    # 15 landmarks with depth; the right ankle lies 0.63 m behind their median depth in this
    # pose, so 14 count; the planted elbow is 30 cm off: 13 of 14 agree.
    assert float(landmark_agreement(true_kps, lm, 0.12)) == pytest.approx(13 / 14)
    # Three more keypoints missed their thin limbs and were lifted onto a wall 0.8 m behind:
    # no pose can agree with them, so they leave the count instead of failing the pose.
    pts = np.asarray(lm.points3d).copy()
    pts[[4, 12, 13], 2] += 0.8
    walled = eqx.tree_at(lambda m: m.points3d, lm, jnp.asarray(pts))
    assert float(landmark_agreement(true_kps, walled, 0.12)) == pytest.approx(10 / 11)
    # A pose 30 cm off everywhere still agrees with none of the plausible ones.
    assert float(landmark_agreement(true_kps + 0.3, walled, 0.12)) == 0.0
    # Nothing with depth: nothing to disagree with.
    none = eqx.tree_at(lambda m: m.has_depth, lm, jnp.zeros(18, bool))
    assert float(landmark_agreement(true_kps, none, 0.12)) == 1.0


def test_agreement_takes_leg_pairs_either_way_round_with_label_free_legs(scene):
    """With the fits' label-free legs, a knee (ankle) pair whose landmarks the detector
    exchanged agrees with the pose as it was fitted; as labelled, both count against it."""
    lm, true_kps = scene["lm"], _kps(_true_pose())
    assert float(np.linalg.norm(true_kps[9] - true_kps[12])) > 0.12  # knees told apart
    assert all(bool(lm.has_depth[i]) for i in (9, 12))
    pts = np.asarray(lm.points3d).copy()
    pts[[9, 12]] = pts[[12, 9]]
    exchanged = eqx.tree_at(lambda m: m.points3d, lm, jnp.asarray(pts))
    assert float(landmark_agreement(true_kps, exchanged, 0.12)) == pytest.approx(11 / 14)
    assert float(landmark_agreement(true_kps, exchanged, 0.12, True)) == pytest.approx(13 / 14)
    # Gated (ResidualSettings.leg_labels_free_sin: a traced side-on test), closed: as labelled.
    off = landmark_agreement(true_kps, exchanged, 0.12, jnp.asarray(False))
    assert float(off) == pytest.approx(11 / 14)
    on = landmark_agreement(true_kps, exchanged, 0.12, jnp.asarray(True))
    assert float(on) == pytest.approx(13 / 14)
    # Labels as detected: the same count either way; the arms are not label-free.
    assert float(landmark_agreement(true_kps, lm, 0.12, True)) == pytest.approx(13 / 14)
    pts[[3, 6]] = pts[[6, 3]]
    arms = eqx.tree_at(lambda m: m.points3d, lm, jnp.asarray(pts))
    assert float(landmark_agreement(true_kps, arms, 0.12, True)) < 13 / 14


# ---------------------------------------------------------------------------------------------
# Reseeding

PARAMS4 = jnp.asarray(np.random.default_rng(2).normal(size=(4, 43)), jnp.float32)
CHOSEN = jnp.asarray(np.random.default_rng(3).normal(size=43), jnp.float32)


@pytest.fixture(scope="module")
def reseed_jit():
    counted = eqx.debug.assert_max_traces(reseed_hypotheses, max_traces=1)
    return counted, jax.jit(counted)


@pytest.mark.parametrize(
    "deltas, margin, replaced",
    [
        ([0.30, 0.10, 0.50, 0.20], 0.15, {0, 2}),  # above best + margin: 0 and 2
        ([0.30, 0.10, 0.50, 0.20], 0.05, {0, 2, 3}),
        ([0.12, 0.10, 0.20, 0.11], 0.15, {2}),  # none above the margin: still the worst
        ([0.30, 0.10, 0.50, 0.20], 1.0, {2}),
    ],
)
def test_reseed_replaces_the_worst_and_those_beyond_the_margin(
    reseed_jit, deltas, margin, replaced
):
    _, step = reseed_jit
    config = _config("mht_h", reseed_margin=margin)
    deltas = jnp.asarray(deltas, jnp.float32)
    out = np.asarray(step(config, PARAMS4, deltas, jnp.argmin(deltas), CHOSEN))
    for h in range(4):
        expected = CHOSEN if h in replaced else PARAMS4[h]
        np.testing.assert_array_equal(out[h], np.asarray(expected), err_msg=f"hypothesis {h}")


def test_reseed_margin_is_traced(reseed_jit):
    """Several margins, one trace (``assert_max_traces`` raises on a second)."""
    counted, step = reseed_jit
    deltas = jnp.asarray([0.30, 0.10, 0.50, 0.20], jnp.float32)
    outs = [
        np.asarray(step(_config("mht_h", reseed_margin=m), PARAMS4, deltas, jnp.int32(1), CHOSEN))
        for m in (0.05, 0.15, 0.5)
    ]
    assert eqx.debug.get_num_traces(counted) == 1
    assert not np.array_equal(outs[0], outs[1]) and not np.array_equal(outs[1], outs[2])


def test_reseed_off_or_single_hypothesis_leaves_params():
    deltas = jnp.asarray([0.30, 0.10, 0.50, 0.20], jnp.float32)
    off = reseed_hypotheses(_config("mht_h", reseed=False), PARAMS4, deltas, 1, CHOSEN)
    np.testing.assert_array_equal(np.asarray(off), np.asarray(PARAMS4))
    one = reseed_hypotheses(_config("mht_h"), PARAMS4[:1], deltas[:1], 0, CHOSEN)
    np.testing.assert_array_equal(np.asarray(one), np.asarray(PARAMS4[:1]))


# ---------------------------------------------------------------------------------------------
# Consensus refit


ONE = jnp.float32(1.0)


def _refit(config, lm, chosen, chosen_delta, sign, offset, truth):
    """consensus_refit with a deterministic, jittable scorer: ``sign * mean keypoint error to
    truth + offset`` (sign +1: closer to the truth scores better; -1: worse; 0: a constant)."""

    def score(p):
        assert p.shape == (1, 43)
        kp = jax.vmap(lambda x: B.keypoints(SHAPE, x))(p)
        return sign * jnp.mean(jnp.linalg.norm(kp - truth[None], axis=-1), axis=-1) + offset

    return consensus_refit(config, SHAPE, INTR, lm, chosen, chosen_delta, score)


@pytest.fixture(scope="module")
def refit_jit():
    return jax.jit(eqx.debug.assert_max_traces(_refit, max_traces=1))


@pytest.fixture(scope="module")
def refit_case():
    """The true keypoints as landmarks (all with depth), but the right elbow 40 cm off (3D and
    2D) and the left knee 30 cm off in depth only (its 2D is right); the winner a few cm off
    the truth. ``clean``: the same landmarks with the outliers removed by hand."""
    true = _true_pose()
    M = _kps(true)
    obs = M.copy()
    obs[R_ELBOW] += [0.40, 0.0, 0.0]
    uv = _project(obs)
    obs[L_KNEE] += [0.0, 0.0, 0.30]
    lm = _landmarks(obs, np.ones(18, bool), np.ones(18, bool), uv)
    det, has = np.ones(18, bool), np.ones(18, bool)
    det[R_ELBOW] = has[R_ELBOW] = has[L_KNEE] = False
    clean = _landmarks(obs, det, has, uv)
    noise = np.random.default_rng(4).normal(size=43) * 0.02
    noise[:3] = [0.02, -0.01, 0.02]
    start = B.normalize_params(true + jnp.asarray(noise, jnp.float32))
    return dict(
        M=M, truth=jnp.asarray(M, jnp.float32), lm=lm, clean=clean, start=start,
        e0=_err(start, M),
    )  # fmt: skip


def _err(params, M):
    return np.linalg.norm(_kps(params) - M, axis=-1)


def test_consensus_refit_excludes_outliers_and_approaches_the_truth(refit_jit, refit_case):
    c = refit_case
    config = _config("mht_h", consensus_distance=0.12)
    e0 = c["e0"]
    assert e0.max() < 0.08  # the start agrees with every inlier (within consensus_distance)
    d0 = jnp.float32(e0.mean())
    pose, delta = refit_jit(config, c["lm"], c["start"], d0, 1.0, 0.0, c["truth"])
    e1 = _err(pose, c["M"])
    # (b) closer to the truth than the start, (c) kept, with the refit's own Delta.
    assert e1.mean() < 0.5 * e0.mean(), (e0.mean(), e1.mean())
    assert float(delta) == pytest.approx(e1.mean(), abs=1e-4)
    # (a) the outliers did not pull: the same refit as with the outliers removed by hand
    # (the elbow's 3D and 2D, the knee's 3D but not its 2D) ...
    ref, _ = refit_jit(config, c["clean"], c["start"], d0, 1.0, 0.0, c["truth"])
    np.testing.assert_allclose(_kps(pose), _kps(ref), atol=1e-4)
    assert e1[R_ELBOW] < 0.03 and e1[L_KNEE] < 0.03
    # ... where a consensus set taking everything (10 m) lets them pull (the check has teeth).
    # (A constant scorer, so that this worse refit is kept.)
    everything, _ = refit_jit(
        config.replace(consensus_distance=10.0), c["lm"], c["start"], ONE, 0.0, 0.0, c["truth"]
    )
    e_all = _err(everything, c["M"])
    assert e_all[R_ELBOW] > 0.05 and e_all[L_KNEE] > 0.05


def test_consensus_refit_is_kept_only_if_delta_is_not_worse(refit_jit, refit_case):
    """The same refit scored 'worse' (sign -1): the winner and its Delta come back unchanged;
    a refit scoring equal (a constant scorer) is kept."""
    c = refit_case
    config = _config("mht_h")
    d0 = jnp.float32(-c["e0"].mean())
    pose, delta = refit_jit(config, c["lm"], c["start"], d0, -1.0, 0.0, c["truth"])
    np.testing.assert_array_equal(np.asarray(pose), np.asarray(c["start"]))
    assert float(delta) == float(d0)
    pose, delta = refit_jit(config, c["lm"], c["start"], jnp.float32(0.25), 0.0, 0.25, c["truth"])
    assert float(delta) == 0.25
    assert _err(pose, c["M"]).mean() < 0.5 * c["e0"].mean()


# ---------------------------------------------------------------------------------------------
# The consensus refit inside the batch (TrackerConfig.consensus_in_batch)


def test_consensus_in_batch_fits_the_previous_output_beside_the_hypotheses(scene):
    """One frame of the step with ``consensus_in_batch``: every hypothesis starts turned away
    from the camera a metre off, the previous output near the truth. The output is the
    previous output refitted on its consensus set (computed here with ``fit_pose`` on its
    own), fitted and scored in the same batch as the hypotheses, and it takes the best
    hypothesis' place."""
    true, M = scene["true"], scene["M"]
    config = _config("mht_h", consensus_in_batch=True, score_width=64)
    turn = B.normalize_params(jnp.asarray(pt.facing_camera_params(3.5), jnp.float32))
    turn = turn.at[3:7].set(jnp.asarray([0.0, 0.0, 1.0, 0.0]))  # facing away
    far = jnp.stack([turn.at[0].add(0.3 * k - 0.3) for k in range(N)])
    noise = np.random.default_rng(6).normal(size=43) * 0.02
    best = B.normalize_params(true + jnp.asarray(noise, jnp.float32))
    state = TrackState(
        hypotheses=far, previous=jax.vmap(lambda p: pt.keypoints(SHAPE, p))(far), best=best,
        key=jax.random.PRNGKey(0),
    )  # fmt: skip
    kp2d = jnp.asarray(_project(M), jnp.float32)
    conf = jnp.ones(18, jnp.float32)
    floor = jnp.asarray(NO_FLOOR, jnp.float32)
    _, est = jax.jit(pt.tracker_step)(config, SHAPE, INTR, floor, state, scene["depth"], kp2d, conf)
    lm = tracker_landmarks(config, SHAPE, INTR, scene["depth"], kp2d, conf)
    use3d, use2d = consensus_set(lm, pt.keypoints(SHAPE, best), INTR, config.consensus_distance)
    ref = jax.jit(pt.fit_pose, static_argnames="settings")(
        best, SHAPE, lm, INTR, use3d=use3d, use2d=use2d, settings=config.fit
    )
    np.testing.assert_allclose(_kps(est.params), _kps(ref.params), atol=2e-3)
    assert _err(est.params, M).mean() < 0.05  # lifted at 64x48: a few cm from the truth
    b = int(est.best)
    np.testing.assert_array_equal(np.asarray(est.hypotheses[b]), np.asarray(est.params))
    assert float(est.delta) <= float(np.min(np.delete(np.asarray(est.deltas), b)))
    # The hypotheses themselves stayed far off (the check has teeth: they could not win).
    others = [_err(h, M).mean() for i, h in enumerate(est.hypotheses) if i != b]
    assert min(others) > 0.2, others


# ---------------------------------------------------------------------------------------------
# Dense refinement

REFINE_STEPS = 10


def _refine(params, lm, use3d, use2d, z_d, z_fg, weight):
    """refine_pose at the test camera (scoring at the same 64x48), ``weight`` traced."""
    return pt.refine_pose(
        params, SHAPE, lm, INTR, use3d=use3d, use2d=use2d, z_d=z_d, z_fg=z_fg,
        score_intrinsics=INTR, steps=REFINE_STEPS, weight=weight, sharpness=DEFAULT_SHARPNESS,
        d_M=DEFAULT_D_M, settings=pt.FitSettings(max_steps=REFINE_STEPS),
    )  # fmt: skip


@pytest.fixture(scope="module")
def refine_jit():
    return jax.jit(eqx.debug.assert_max_traces(_refine, max_traces=1))


def test_refine_pose_moves_toward_the_truth(refine_jit, scene):
    """Landmarks on the torso only; the arms and legs bent off the truth (limb keypoints ~17 cm
    off) are seen only in the rendered depth of the true pose. Refining brings the limbs much
    closer; the same refinement with the depth term weighted ~0 hardly moves them (so it is
    the depth that does it)."""
    true = scene["true"]
    z_d, z_fg = pt.observation_maps(scene["depth"], INTR, center=true[:3])
    assert float(z_fg.sum()) > 200
    noise = np.zeros(43)
    rng = np.random.default_rng(1)
    noise[:3] = [0.03, -0.02, 0.03]
    noise[11:27] = rng.normal(size=16) * 0.25  # shoulders and elbows
    noise[27:43] = rng.normal(size=16) * 0.15  # hips and knees
    start = B.normalize_params(true + jnp.asarray(noise, jnp.float32))
    M = scene["M"]
    lm = _landmarks(M, np.ones(18, bool), np.ones(18, bool))
    torso = np.zeros(18, bool)
    torso[[1, 2, 5, 8, 11]] = True
    limbs = [3, 4, 6, 7, 9, 10, 12, 13]
    args = (lm, jnp.asarray(torso), jnp.zeros(18, bool), z_d, z_fg)
    out = refine_jit(start, *args, 2.0)
    blind = refine_jit(start, *args, 1e-8)
    assert np.isfinite(np.asarray(out)).all()
    e0, e1, e_blind = (_err(p, M)[limbs].mean() for p in (start, out, blind))
    assert e1 < 0.7 * e0, (e0, e1)
    assert e1 < 0.8 * e_blind, (e_blind, e1)
    assert _err(out, M).mean() < 0.7 * _err(start, M).mean()


def test_refine_pose_without_any_evidence_is_finite(refine_jit, scene):
    """No landmark used (their coordinates NaN, as garbage behind the masks) and an empty
    observation (depth NaN, no foreground): a finite pose, the start, with unit quaternions."""
    none = jnp.zeros(18, bool)
    garbage = pt.Landmarks(
        keypoints2d=jnp.full((18, 2), jnp.nan, jnp.float32), confidence=jnp.zeros(18),
        points3d=jnp.full((18, 3), jnp.nan, jnp.float32), detected=none, has_depth=none,
    )  # fmt: skip
    empty = jnp.zeros((48, 64), jnp.float32)
    start = scene["hyps"][0]
    out = np.asarray(refine_jit(start, garbage, none, none, empty + jnp.nan, empty, 2.0))
    assert np.isfinite(out).all()
    np.testing.assert_allclose(np.linalg.norm(out[3:].reshape(10, 4), axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(_kps(out), _kps(start), atol=1e-3)


# ---------------------------------------------------------------------------------------------
# Eager vs jit, vmap vs loop
#
# Not here, by cost: eager (``jax.disable_jit``) runs of ``consensus_refit`` (~45 s) and
# ``tracker_step`` (~5 min) on 2 cores, and ``fit_hypotheses`` vs a loop of ``fit_pose`` (two
# more LM compiles), which tests/test_speed_baselines.py covers through the loop baseline
# against the batched step.


def test_landmark_weights_eager_equals_jit(weights_jit, scene, monkeypatch):
    config = _config("mht_h", temporal_2d=True)
    args = (config, SHAPE, INTR, scene["depth"], scene["lm"], scene["previous"])
    # The body's rest lengths (forward kinematics, tested in test_body.py) precomputed: op by
    # op, FK alone would take most of this test's time.
    monkeypatch.setattr(_select, "partner_rest_lengths", lambda shape: _REST)
    with jax.disable_jit():
        eager = landmark_weights(*args)
    for e, j in zip(eager, weights_jit(*args), strict=True):
        np.testing.assert_allclose(np.asarray(e), np.asarray(j), atol=1e-6)


def test_landmark_weights_batch_equals_loop_over_hypotheses(weights_jit, scene):
    """Each hypothesis' weights depend on its own previous keypoints only."""
    config = _config("mht_h", temporal_2d=True)
    batched = _weights(weights_jit, config, scene)
    for h in range(N):
        one = _weights(weights_jit, config, scene, previous=scene["previous"][h : h + 1])
        for b, o in zip(batched, one, strict=True):
            np.testing.assert_allclose(b[h], o[0], atol=1e-6)


def test_reseed_eager_equals_jit(reseed_jit):
    _, step = reseed_jit
    config = _config("mht_h")
    deltas = jnp.asarray([0.30, 0.10, 0.50, 0.20], jnp.float32)
    best = jnp.argmin(deltas)
    with jax.disable_jit():
        eager = reseed_hypotheses(config, PARAMS4, deltas, best, CHOSEN)
    jitted = step(config, PARAMS4, deltas, best, CHOSEN)
    np.testing.assert_array_equal(np.asarray(eager), np.asarray(jitted))
