"""Dropping detections that jumped onto another keypoint (posetrack._duplicates): NumPy only."""

import numpy as np
import pytest

import posetrack as pt

FX = 300.0
Z = 3.0  # the person's depth: 1 px = 1 cm


def _standing(T: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A person facing the camera, keypoints (T, 18, 2) 1-2 cm apart at least, with 1 px
    jitter, all detected."""
    base = np.array([
        [160, 40], [160, 60], [140, 60], [130, 90], [125, 120], [180, 60], [190, 90],
        [195, 120], [150, 120], [148, 160], [147, 200], [170, 120], [172, 160], [173, 200],
        [156, 36], [164, 36], [150, 38], [170, 38],
    ], float)  # fmt: skip
    kp = base[None] + rng.normal(0.0, 1.0, (T, 18, 2))
    return kp, np.full((T, 18), 0.8)


def _run(kp, conf, settings=pt.DuplicateSettings()):
    f = pt.DuplicateFilter(FX, settings)
    p3 = np.zeros((18, 3))
    p3[:, 2] = Z
    out = [f.update(k, c, p3, np.ones(18, bool)) for k, c in zip(kp, conf)]
    return np.stack([o[0] for o in out]), np.stack([o[1] for o in out]), f


def test_an_ankle_stuck_on_the_neck_is_dropped_for_the_whole_episode():
    rng = np.random.default_rng(0)
    kp, conf = _standing(40, rng)
    # Frames 10-24: the left ankle (13) sits on the neck (1), 2-9 px off it (its own noise).
    off = rng.uniform(-6.0, 6.0, (15, 2))
    kp[10:25, 13] = kp[10:25, 1] + off
    conf[10:25, 13] = 0.55
    out_conf, dropped, f = _run(kp, conf)
    assert dropped[10:25, 13].all()
    assert not dropped[:10].any() and not dropped[25:].any()  # back where it was: kept
    assert not np.delete(dropped, 13, axis=1).any()  # the neck stayed
    assert (out_conf[10:25, 13] == 0).all() and (out_conf[25:, 13] == conf[25:, 13]).all()
    assert f.dropped_count == 15


def test_a_hand_brought_to_the_face_is_not_dropped():
    rng = np.random.default_rng(1)
    kp, conf = _standing(40, rng)
    # The right wrist (4) travels to the nose (0) over 20 frames (3 cm a frame) and stays.
    path = np.linspace(0.0, 1.0, 20)[:, None]
    start, end = kp[0, 4].copy(), kp[0, 0]
    kp[10:30, 4] = start + path * (end - start) + rng.normal(0, 1.0, (20, 2))
    kp[30:, 4] = kp[30:, 0] + rng.normal(0, 1.0, (10, 2))
    _, dropped, _ = _run(kp, conf)
    assert not dropped.any()


def test_a_snap_drops_the_keypoint_that_jumped_not_the_one_it_landed_on():
    rng = np.random.default_rng(2)
    kp, conf = _standing(30, rng)
    # Frames 12-17: the left wrist (7) reported on the right wrist (4), 70 cm away.
    kp[12:18, 7] = kp[12:18, 4] + rng.normal(0, 1.0, (6, 2))
    _, dropped, _ = _run(kp, conf)
    assert dropped[12:18, 7].all()
    assert not dropped[:, 4].any()
    assert dropped.sum() == 6


def test_coincident_from_the_start_and_unseen_keypoints_are_kept():
    rng = np.random.default_rng(3)
    kp, conf = _standing(20, rng)
    kp[:, 5] = kp[:, 2] + rng.normal(0, 1.0, (20, 2))  # side view: shoulders overlap
    conf[5:8, 7] = 0.0  # missed a few frames
    kp[5:8, 7] = 0.0
    _, dropped, _ = _run(kp, conf)
    assert not dropped.any()


def test_a_jump_long_unseen_is_allowed_by_the_speed():
    rng = np.random.default_rng(4)
    kp, conf = _standing(40, rng)
    # The left ankle is missed for 20 frames, then seen on the left knee's spot +40 cm away
    # from where it was: 20 frames x 5 cm allow it (no evidence that it jumped).
    conf[5:25, 13] = 0.0
    kp[25:, 13] = kp[25:, 12] + rng.normal(0, 1.0, (15, 2))
    _, dropped, _ = _run(kp, conf)
    assert not dropped.any()
    # With no allowance for unseen frames the same detections are a jump.
    _, dropped, _ = _run(kp, conf, pt.DuplicateSettings(speed=0.0))
    assert dropped[25:, 13].all()


def test_a_return_from_a_short_outlier_to_beside_another_keypoint_is_kept_once_settled():
    rng = np.random.default_rng(5)
    kp, conf = _standing(40, rng)
    # Frames 10-11: the nose (0) reported 1.1 m down the body, on no other keypoint (kept:
    # nothing shows it is wrong). From frame 12 it is back beside the eyes, where it belongs.
    kp[10:12, 0] = [160.0, 150.0]
    # A kept jump must hold 3 frames before it becomes where the nose is: the return is
    # measured from before the outlier, and kept.
    out_conf, dropped, _ = _run(kp, conf, pt.DuplicateSettings(settle=3))
    assert not dropped.any() and (out_conf == conf).all()
    # The default (settle 1): the outlier became the reference at once, the return was a jump
    # onto the eyes' spot, and the nose was withheld until the speed allowance covered 1.1 m.
    _, dropped, _ = _run(kp, conf)
    assert dropped[12:20, 0].all() and not np.delete(dropped, 0, axis=1).any()


def test_a_jump_that_holds_becomes_where_the_keypoint_is():
    rng = np.random.default_rng(6)
    kp, conf = _standing(40, rng)
    # The right wrist (4) moves 60 cm in one frame (frame 10) and stays (kept: on no other
    # keypoint). Once it has held there (settle frames), a left wrist (7) that then jumps onto
    # it is the one dropped, and the right wrist, which did not move, stays.
    held = 3
    start = 10 + held  # before the speed allowance alone would cover the 60 cm (frame 17)
    kp[10:, 4] += [0.0, 60.0]
    kp[start : start + 5, 7] = kp[start : start + 5, 4] + rng.uniform(-3.0, 3.0, (5, 2))
    _, dropped, _ = _run(kp, conf, pt.DuplicateSettings(settle=held))
    assert dropped[start : start + 5, 7].all() and not dropped[:, 4].any()
    assert dropped.sum() == 5
    # Not yet settled, the right wrist counts as jumped too: both stay on the first frame.
    _, dropped, _ = _run(kp, conf, pt.DuplicateSettings(settle=held + 2))
    assert not dropped[start].any()


@pytest.mark.parametrize(
    "kwargs, field",
    [({"radius": 0.0}, "radius"), ({"jump": -1.0}, "jump"), ({"speed": float("nan")}, "speed"),
     ({"min_confidence": 1.0}, "min_confidence"), ({"radius": True}, "radius"),
     ({"settle": 0}, "settle"), ({"settle": 2.0}, "settle")],
)  # fmt: skip
def test_settings_name_the_bad_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        pt.DuplicateSettings(**kwargs)


def test_tracker_modes_and_bad_argument():
    intr = pt.Intrinsics.create(fx=FX, fy=FX, cx=160.0, cy=120.0, width=320, height=240)
    assert pt.Tracker(intr, mode="online").duplicates == pt.DuplicateSettings()
    assert pt.Tracker(intr, mode="offline").duplicates == pt.DuplicateSettings()
    assert pt.Tracker(intr, mode="per-frame").duplicates is None
    assert pt.Tracker(intr, mode="online", duplicates=None).duplicates_dropped == 0
    with pytest.raises(TypeError, match="duplicates"):
        pt.Tracker(intr, mode="online", duplicates="yes")


@pytest.mark.parametrize("dup", [pt.DuplicateSettings(), None], ids=["filter", "none"])
def test_the_offline_left_right_pre_pass_reads_what_the_tracking_pass_fits(monkeypatch, dup):
    """Offline, the two-sided left/right pass reads the whole recording before tracking: with
    ``duplicates`` set it withholds the jumped detection as the tracking pass does (its own
    filter), without it reads the detections as given."""
    import posetrack._tracker as tracker_module

    rng = np.random.default_rng(3)
    kp, conf = _standing(30, rng)
    kp[10:25, 13] = kp[10:25, 1] + rng.uniform(-6.0, 6.0, (15, 2))  # left ankle on the neck
    depth = np.full((30, 240, 320), Z, np.float32)
    intr = pt.Intrinsics.create(fx=FX, fy=FX, cx=160.0, cy=120.0, width=320, height=240)
    seen = {}

    def spy(frames, fx, settings):
        seen["conf"] = np.stack([f[1] for f in frames])
        return np.zeros((len(frames), len(settings.groups)), bool)

    monkeypatch.setattr(tracker_module, "two_sided_exchanged", spy)
    t = pt.Tracker(intr, mode="offline", duplicates=dup)
    persons, exchanged, _ = t._two_sided_labels(depth, kp, conf)
    assert (persons == 0).all() and exchanged.shape == (30, len(t.sides.groups))
    withheld = seen["conf"] == 0
    if dup is None:
        assert not withheld.any()
    else:
        assert withheld[10:25, 13].all() and withheld.sum() == 15
