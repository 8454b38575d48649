"""The detector's left/right swaps are undone before fitting (posetrack._sides)."""

import numpy as np
import pytest

import posetrack as pt

FX = 300.0
ARMS = pt.SIDE_GROUPS["arms"]
LEGS = pt.SIDE_GROUPS["legs"]
TORSO = pt.SIDE_GROUPS["torso"]


def _walk(T: int = 80, seed: int = 0):
    """A person 3 m away moving smoothly: (T, 18, 2) pixels, confidences, lifted points."""
    rng = np.random.default_rng(seed)
    base = np.zeros((18, 2))
    x = {2: -25, 3: -40, 4: -50, 5: 25, 6: 40, 7: 50, 8: -12, 9: -15, 10: -17, 11: 12, 12: 15,
         13: 17}  # fmt: skip
    y = {2: -60, 3: -30, 4: 0, 5: -60, 6: -30, 7: 0, 8: 0, 9: 45, 10: 90, 11: 0, 12: 45, 13: 90}
    for k in x:
        base[k] = (160 + x[k], 120 + y[k])
    t = np.arange(T)[:, None, None]
    kp = base[None] + np.concatenate(
        [np.sin(t / 9.0) * 8, np.cos(t / 7.0) * 5], axis=-1
    )  # slow sway of the whole body
    kp[:, [4, 7], 1] += 15 * np.sin(np.arange(T) / 5.0)[:, None]  # the wrists move more
    kp = kp + rng.normal(0, 0.7, kp.shape)
    conf = np.full((T, 18), 0.8)
    p3 = np.zeros((T, 18, 3))
    p3[..., 2] = 3.0
    p3[..., :2] = (kp - 160) / FX * 3.0
    return kp, conf, p3, np.ones((T, 18), bool)


def _swap(kp, conf, frames, pairs):
    kp, conf = kp.copy(), conf.copy()
    for a, b in pairs:
        kp[frames, a], kp[frames, b] = kp[frames, b].copy(), kp[frames, a].copy()
        conf[frames, a], conf[frames, b] = conf[frames, b].copy(), conf[frames, a].copy()
    return kp, conf


def _frames(kp, conf, p3, has):
    """Per frame, what SideLabeller.update and two_sided_exchanged take."""
    return [(kp[t], conf[t], p3[t], has[t]) for t in range(len(kp))]


def _run(kp, conf, p3, has, settings=pt.SideSettings()):
    lab = pt.SideLabeller(FX, settings)
    out = [lab.update(*frame) for frame in _frames(kp, conf, p3, has)]
    return (np.stack([o[0] for o in out]), np.stack([o[1] for o in out]),
            np.stack([o[2] for o in out]))  # fmt: skip


def test_an_arm_swap_episode_is_undone_and_nothing_else_moves():
    kp, conf, p3, has = _walk()
    sw = np.arange(20, 45)
    bad_kp, bad_conf = _swap(kp, conf, sw, ARMS)
    out_kp, out_conf, ex = _run(bad_kp, bad_conf, p3, has)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 0]), sw)
    assert not ex[:, 1].any()  # legs untouched
    np.testing.assert_array_equal(out_kp, kp)
    np.testing.assert_array_equal(out_conf, conf)


def test_legs_and_arms_are_labelled_independently():
    kp, conf, p3, has = _walk()
    kp2, conf2 = _swap(kp, conf, np.arange(10, 18), ARMS)
    kp2, conf2 = _swap(kp2, conf2, np.arange(40, 60), LEGS)
    _, _, ex = _run(kp2, conf2, p3, has)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 0]), np.arange(10, 18))
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 1]), np.arange(40, 60))


def test_a_swap_seen_on_one_side_only_is_still_undone():
    # During the swap the (true) left wrist and elbow are missed: the detector reports the
    # right arm under the left labels and nothing under the right ones.
    kp, conf, p3, has = _walk()
    sw = np.arange(30, 40)
    bad_kp, bad_conf = _swap(kp, conf, sw, ARMS)
    bad_conf[np.ix_(sw, [3, 4])] = 0.0
    bad_kp[np.ix_(sw, [3, 4])] = 0.0
    _, out_conf, ex = _run(bad_kp, bad_conf, p3, has)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 0]), sw)
    assert (out_conf[np.ix_(sw, [6, 7])] == 0).all() and (out_conf[np.ix_(sw, [3, 4])] > 0).all()


def test_labels_that_never_jump_are_kept_even_when_arms_cross():
    # The wrists pass through each other (a real crossing): no jump, no relabelling.
    kp, conf, p3, has = _walk()
    T = len(kp)
    s = np.linspace(-1, 1, T)
    kp[:, 4, 0] = 160 + 50 * s
    kp[:, 7, 0] = 160 - 50 * s
    kp[:, 7, 1] = kp[:, 4, 1]
    _, _, ex = _run(kp, conf, p3, has)
    assert not ex.any()


def test_a_swap_longer_than_the_jumps_are_worth_is_left_alone():
    # From frame 20 to the end the labels stay exchanged: after ~jump/switch_cost frames the
    # exchanged reading is no longer the cheaper one, and the detector's labels are taken.
    kp, conf, p3, has = _walk(T=200)
    bad_kp, bad_conf = _swap(kp, conf, np.arange(20, 200), ARMS)
    _, _, ex = _run(bad_kp, bad_conf, p3, has, pt.SideSettings(switch_cost=0.02))
    assert ex[20:40, 0].all()
    assert not ex[-20:, 0].any()


def test_a_whole_body_swap_is_undone_only_with_the_torso_group():
    # A detector reading the person as facing the other way exchanges every pair at once.
    kp, conf, p3, has = _walk()
    sw = np.arange(25, 40)
    bad_kp, bad_conf = _swap(kp, conf, sw, ARMS + LEGS + TORSO)
    online = pt.SideSettings.for_mode("online")
    out_kp, out_conf, ex = _run(bad_kp, bad_conf, p3, has, online)
    assert online.groups == ("arms", "legs", "torso")
    for g in range(3):
        np.testing.assert_array_equal(np.flatnonzero(ex[:, g]), sw)
    np.testing.assert_array_equal(out_kp, kp)
    np.testing.assert_array_equal(out_conf, conf)
    # Offline (read from both directions) the default reads all three groups exchanged too.
    offline = pt.SideSettings.for_mode("offline")
    ex = pt.two_sided_exchanged(_frames(bad_kp, bad_conf, p3, has), FX, offline)
    for g in range(3):
        np.testing.assert_array_equal(np.flatnonzero(ex[:, g]), sw)
    # Arms and legs alone: the shoulders and hips stay exchanged.
    out_kp, _, ex = _run(bad_kp, bad_conf, p3, has, pt.SideSettings(groups=("arms", "legs")))
    limbs = [k for pair in ARMS + LEGS for k in pair]
    np.testing.assert_array_equal(out_kp[:, limbs], kp[:, limbs])
    right, left = [r for r, _ in TORSO], [lt for _, lt in TORSO]
    np.testing.assert_array_equal(out_kp[sw][:, right + left], kp[sw][:, left + right])


def test_for_mode_gives_the_trackers_defaults():
    assert pt.SideSettings.for_mode("offline").groups == ("arms", "legs", "torso")
    assert pt.SideSettings.for_mode("offline") == pt.SideSettings.for_mode("online")
    assert pt.SideSettings.for_mode("per-frame") == pt.SideSettings()
    tuned = pt.SideSettings.for_mode("online", switch_cost=0.02)
    assert tuned.groups == ("arms", "legs", "torso") and tuned.switch_cost == 0.02
    assert pt.SideSettings.for_mode("online", groups=("arms",)).groups == ("arms",)
    with pytest.raises(ValueError, match="mode must be"):
        pt.SideSettings.for_mode("live")
    intr = pt.Intrinsics.create(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
    assert pt.Tracker(intr, mode="online").sides == pt.SideSettings.for_mode("online")
    assert pt.Tracker(intr, mode="offline").sides == pt.SideSettings.for_mode("offline")
    assert pt.Tracker(intr, mode="per-frame").sides is None


def test_settings_and_labeller_reject_bad_values():
    with pytest.raises(ValueError, match="groups"):
        pt.SideSettings(groups=("arms", "tail"))
    with pytest.raises(ValueError, match="switch_cost"):
        pt.SideSettings(switch_cost=0.0)
    with pytest.raises(ValueError, match="speed"):
        pt.SideSettings(speed=float("nan"))
    with pytest.raises(ValueError, match="online_frames"):
        pt.SideSettings(online_frames=0)
    with pytest.raises(ValueError, match="online_rejudge"):
        pt.SideSettings(online_rejudge=2.5)
    with pytest.raises(ValueError, match="online_min_held"):
        pt.SideSettings(online_min_held=0)
    with pytest.raises(ValueError, match="online_anchor"):
        pt.SideSettings(online_anchor=-0.1)
    with pytest.raises(ValueError, match="online_model"):
        pt.SideSettings(online_model=-0.1)
    with pytest.raises(ValueError, match="online_model_age"):
        pt.SideSettings(online_model_age=-1)
    with pytest.raises(ValueError, match="fx"):
        pt.SideLabeller(0.0)
    with pytest.raises(TypeError, match="SideSettings"):
        pt.SideLabeller(FX, {"switch_cost": 0.01})


def test_an_anchor_holds_an_exchange_that_coinciding_sides_left_ambiguous():
    """While the right arm is reported on the left one, both labellings fit the detections
    alike and the forward pass forgets which side is which: it misses the swap that follows
    and reads the swap's end as an exchange. Anchored to the exchange where it starts (as the
    online tracker does when the depth keeps it, ``SideSettings.online_anchor``), it holds the
    exchange to the swap's end and no longer."""
    kp, conf, p3, has = _walk()
    together, swapped = np.arange(20, 35), np.arange(35, 56)
    for a, b in ARMS:
        kp[together, a] = kp[together, b] + 1.0
    bad_kp, bad_conf = _swap(kp, conf, swapped, ARMS)
    reads = {}
    for anchored in (False, True):
        lab = pt.SideLabeller(FX)
        ex = []
        for t in range(len(kp)):
            ex.append(lab.update(bad_kp[t], bad_conf[t], p3[t], has[t])[2])
            if anchored and t == swapped[0]:
                lab.anchor(np.array([True, False]), 0.5)
                assert lab.margin[0] <= -0.5 and lab.margin[1] > 0.5  # the legs untouched
        reads[anchored] = np.stack(ex)[:, 0]
    free, held = reads[False], reads[True]
    assert free[swapped[1:]].mean() < 0.2 and free[56:70].mean() > 0.8, free.astype(int)
    assert held[swapped[1:]].all() and not held[56:].any(), held.astype(int)


def test_the_trackers_pose_reads_the_labels_where_the_forward_pass_is_at_a_tie():
    """The anchor's scene: the right arm reported on the left one leaves the forward pass
    without memory, so it misses the swap that follows. Told the tracker's pose each frame
    (``refer``; here the true keypoints: a pose that followed the right labels), the reading
    follows it where the forward margin is near a tie (``online_model``), and the pose's age
    limit and the confident forward pass both hold it back. (Within a tie the forward
    margin drifts toward "as detected" by ``switch_cost`` a frame, so the pose decides for
    about ``online_model / switch_cost`` frames: 10 here.)"""
    kp, conf, p3, has = _walk()
    truth = kp.copy()
    together, swapped = np.arange(20, 35), np.arange(35, 43)
    for a, b in ARMS:
        kp[together, a] = kp[together, b] + 1.0
    bad_kp, bad_conf = _swap(kp, conf, swapped, ARMS)

    def read(settings, refer=lambda t: truth[t]):
        lab = pt.SideLabeller(FX, settings)
        ex, margins = [], []
        for t in range(len(kp)):
            ex.append(lab.update(bad_kp[t], bad_conf[t], p3[t], has[t])[2])
            margins.append(lab.margin.copy())
            lab.refer(refer(t))
        return np.stack(ex)[:, 0], np.stack(margins)[:, 0]

    free, margin = read(pt.SideSettings())
    assert free[swapped[1:]].mean() < 0.2  # the forward pass alone misses the swap
    assert np.abs(margin[swapped]).max() < 0.1  # ... at a tie
    held, _ = read(pt.SideSettings(online_model=0.1))
    assert held[swapped].all() and not held[43:].any(), held.astype(int)
    assert (held[:35] == free[:35]).all()  # coinciding detections: the pose cannot tell
    # A pose older than online_model_age frames is not asked.
    stale, _ = read(pt.SideSettings(online_model=0.1), lambda t: truth[t] if t < 30 else None)
    assert (stale == free).all()
    # A pose that says "exchanged" everywhere moves only the near-tie frames: before the
    # detections coincided the forward pass is sure of the labels.
    turned = _swap(truth, conf, np.arange(len(kp)), ARMS)[0]
    wrong, _ = read(pt.SideSettings(online_model=0.1), lambda t: turned[t])
    assert not wrong[1:20].any() and (np.abs(margin[1:20]) >= 0.1).all()


def test_reset_forgets_the_past():
    kp, conf, p3, has = _walk()
    bad_kp, bad_conf = _swap(kp, conf, np.arange(20, 80), ARMS)
    lab = pt.SideLabeller(FX)
    for t in range(25):
        lab.update(bad_kp[t], bad_conf[t], p3[t], has[t])
    assert lab.exchanged[0]
    lab.reset()
    # A new track starting inside the swap has nothing to compare with: labels as detected.
    assert not lab.update(bad_kp[25], bad_conf[25], p3[25], has[25])[2].any()


def test_two_sided_labelling_undoes_swaps_in_the_middle_and_at_the_end():
    kp, conf, p3, has = _walk()
    mid, end = np.arange(30, 40), np.arange(70, 80)
    bad_kp, bad_conf = _swap(kp, conf, mid, ARMS)
    bad_kp, bad_conf = _swap(bad_kp, bad_conf, end, LEGS)
    ex = pt.two_sided_exchanged(_frames(bad_kp, bad_conf, p3, has), FX)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 0]), mid)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 1]), end)


def test_torso_with_limbs_reads_the_torso_exchanged_only_beside_a_limb():
    kp, conf, p3, has = _walk()
    body, torso = np.arange(20, 30), np.arange(50, 58)
    bad_kp, bad_conf = _swap(kp, conf, body, ARMS + LEGS + TORSO)  # a whole-body swap
    bad_kp, bad_conf = _swap(bad_kp, bad_conf, torso, TORSO)  # the torso alone
    frames = _frames(bad_kp, bad_conf, p3, has)
    groups = ("arms", "legs", "torso")
    ex = pt.two_sided_exchanged(frames, FX, pt.SideSettings(groups=groups))
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 2]), np.concatenate([body, torso]))
    ex = pt.two_sided_exchanged(frames, FX, pt.SideSettings(groups=groups, torso_with_limbs=True))
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 2]), body)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 0]), body)
    with pytest.raises(ValueError, match="torso_with_limbs"):
        pt.SideSettings(torso_with_limbs=1)


def test_two_sided_labelling_skips_frames_without_the_person_and_checks_its_margin():
    kp, conf, p3, has = _walk()
    mid = np.arange(30, 40)
    bad_kp, bad_conf = _swap(kp, conf, mid, ARMS)
    frames = _frames(bad_kp, bad_conf, p3, has)
    frames[35] = None  # nobody followed in that frame: read as detected, the rest unchanged
    ex = pt.two_sided_exchanged(frames, FX)
    np.testing.assert_array_equal(np.flatnonzero(ex[:, 0]), np.setdiff1d(mid, [35]))
    # A margin above what the swap's two jumps are worth leaves it alone.
    assert not pt.two_sided_exchanged(frames, FX, pt.SideSettings(two_sided_margin=5.0)).any()
    with pytest.raises(ValueError, match="two_sided_margin"):
        pt.SideSettings(two_sided_margin=-0.1)


def test_arbitration_spans_cover_each_exchange_and_the_frames_after_it():
    ex = np.zeros((30, 2), bool)
    ex[3:5, 0] = True  # arms, then legs 2 frames after the arms' span ends: one span
    ex[10:12, 1] = True
    ex[20, 0] = True  # its span is cut at the end of the recording... not here: 20 + 1 + 5
    ex[28, 1] = True  # ... here
    assert pt.arbitration_spans(ex, 5) == [(3, 17), (20, 26), (28, 30)]
    assert pt.arbitration_spans(ex, 0) == [(3, 5), (10, 12), (20, 21), (28, 29)]
    assert pt.arbitration_spans(np.zeros((7, 2), bool), 5) == []


def _turning(ratios, torso: float = 60.0):
    """Frames of a person whose shoulders stand ``ratio`` x ``torso`` pixels apart (the
    neck-to-hips distance ``torso``); a NaN ratio: the shoulders not detected."""
    frames = []
    for r in ratios:
        kp, conf = np.zeros((18, 2)), np.full(18, 0.8)
        kp[1] = (160.0, 100.0)
        kp[8], kp[11] = (150.0, 100.0 + torso), (170.0, 100.0 + torso)
        half = 0.0 if np.isnan(r) else r * torso / 2
        kp[2], kp[5] = (160.0 - half, 100.0), (160.0 + half, 100.0)
        if np.isnan(r):
            conf[[2, 5]] = 0.0
        frames.append((kp, conf, np.zeros((18, 3)), np.zeros(18, bool)))
    return frames


def test_frontal_turns_run_from_a_side_view_through_a_frontal_one_to_the_next_side_view():
    nan = float("nan")
    # Side view 0-3, turning 4-5, frontal 6-9 (one frame unseen), side view 10-12, then a
    # turn that lasts to the end.
    ratios = [0.05, 0.1, 0.0, 0.15, 0.3, 0.4, 0.6, 0.7, nan, 0.7, 0.1, 0.05, 0.1, 0.3, 0.6, 0.7]
    assert pt.frontal_turns(_turning(ratios), 0.5) == [(3, 10), (12, 16)]
    # Never as far apart as asked: no turn; frontal from the start: none before a side view.
    assert pt.frontal_turns(_turning(ratios), 0.8) == []
    assert pt.frontal_turns(_turning([0.7, 0.7, 0.1, 0.1, 0.7]), 0.5) == [(3, 5)]
    # Frames without the person keep the last ratio, like unseen shoulders.
    frames = _turning([0.1, 0.6, 0.6, 0.1])
    frames[2] = None
    assert pt.frontal_turns(frames, 0.5) == [(0, 3)]
    with pytest.raises(ValueError, match="frontal_turns"):
        pt.SideSettings(frontal_turns=0.1)  # not above the overlap's ratio
    with pytest.raises(ValueError, match="frontal_turns"):
        pt.SideSettings(frontal_turns=float("inf"))


def test_a_turn_takes_in_the_arbitrated_stretches_across_its_ends():
    from posetrack._tracker import _turns_around

    spans = {2: 6, 20: 26, 40: 44}
    # 5 and 22 fall inside stretches: the turn widens to take them whole; 40-44 is inside.
    assert _turns_around([(5, 22), (38, 50)], spans) == [(2, 26), (38, 50)]
    # turns that overlap once widened are one
    assert _turns_around([(3, 10), (12, 21)], {2: 6, 9: 14, 20: 26}) == [(2, 26)]
    assert _turns_around([(10, 15)], spans) == [(10, 15)]


def test_prefer_exchanged_needs_a_lower_delta_on_the_same_frames():
    a = np.array([0.30, 0.40, np.nan, 0.35])
    assert pt.prefer_exchanged(a, a - 0.05, 0.0)
    assert not pt.prefer_exchanged(a, a - 0.05, 0.2)  # 0.15 lower: not by the margin
    assert not pt.prefer_exchanged(a, a, 0.0)  # a tie keeps the detections' labels
    lost = a - 0.1
    lost[3] = np.nan  # the exchanged reading lost a frame the other estimated
    assert not pt.prefer_exchanged(a, lost, 0.0)
    assert not pt.prefer_exchanged(np.full(3, np.nan), np.full(3, np.nan), 0.0)
    with pytest.raises(ValueError, match="arbitrate_after"):
        pt.SideSettings(arbitrate_after=-1)
    with pytest.raises(ValueError, match="arbitrate"):
        pt.SideSettings(arbitrate=1)
    with pytest.raises(ValueError, match="arbitrate_groups"):
        pt.SideSettings(arbitrate_groups="yes")
