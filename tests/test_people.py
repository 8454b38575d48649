"""One person means one person: a second person walks through the view (issue 15).

Generated two-person scenes (``posetrack.synth.generate(..., bystander=True)``): the person to
follow acts in place, a second person walks across in front, leaves and comes back; the
detector lists both in random order. The shipped tracker must stay on the first person; the
per-frame choice it replaced (``follow=None``, the most prominent detection each frame) must
not, which shows these tests can fail.
"""

import json

import numpy as np
import pytest

import posetrack as pt
from posetrack.app._cli import main

SIZE = (320, 240)
FRAMES, FPS = 48, 12.0  # 4 s: the second person crosses the view and comes back
SCENES = ((520, "wave"), (521, "box"))  # test seeds (benchmarks/seeds.py: 500-599)


def _truth(seq) -> np.ndarray:
    return np.concatenate([seq.joints3d[:, None], seq.others_joints3d], axis=1)


@pytest.fixture(scope="module")
def scenes():
    out = []
    for seed, motion in SCENES:
        kw = dict(motion=motion, n_frames=FRAMES, fps=FPS, width=SIZE[0], height=SIZE[1],
                  with_rgb=False)  # fmt: skip
        out.append((pt.synth.generate(seed, bystander=True, **kw), pt.synth.generate(seed, **kw)))
    return out


@pytest.fixture(scope="module")
def tracked(scenes):
    """(follow, per-frame, alone) results per scene, with the shipped configuration.

    Per-frame poses (no motion model): the association is what is tested, and smoothing over
    time would blur the very hops the per-frame choice is expected to make."""
    config = pt.TrackerConfig()
    mode = "per-frame"
    out = []
    for seq, alone in scenes:
        kp, conf = seq.people2d, seq.people_confidence
        follow = pt.track(seq.depth, kp, conf, seq.intrinsics, config, mode=mode)
        per_frame = pt.track(seq.depth, kp, conf, seq.intrinsics, config, follow=None, mode=mode)
        solo = pt.track(
            alone.depth, alone.keypoints2d, alone.confidence, alone.intrinsics, config, mode=mode
        )
        out.append((follow, per_frame, solo))
    return out


def test_scenes_really_have_two_people_competing(scenes):
    for seq, _ in scenes:
        both = (seq.people_confidence > 0).any(-1).sum(-1) >= 2
        assert both.sum() >= 8, "the second person is hardly in view: the test would be idle"
        # In some frames the second person is the more prominent detection.
        score = np.stack([pt.detection_score(k, c) for k, c in
                          zip(seq.people2d, seq.people_confidence)])  # fmt: skip
        other_wins = both & (score.argmax(1) != seq.people_index)
        assert other_wins.sum() >= 3


def test_the_track_stays_on_the_first_person(scenes, tracked):
    for (seq, _), (follow, per_frame, _) in zip(scenes, tracked):
        ident = pt.followed_identity(follow.keypoints3d, _truth(seq))
        assert pt.identity_jumps(ident) == 0 and not (ident > 0).any(), ident
        # The followed detection is the first person's wherever one was taken.
        taken = follow.person_index >= 0
        assert (follow.person_index[taken] == seq.people_index[taken]).all()
        assert follow.others_ignored >= 8
        # The per-frame choice hops to the second person: these scenes can fail the test.
        ident_pf = pt.followed_identity(per_frame.keypoints3d, _truth(seq))
        assert pt.identity_jumps(ident_pf) >= 2, ident_pf


def test_followed_persons_accuracy_close_to_the_scene_without_the_second(scenes, tracked):
    for (seq, alone), (follow, per_frame, solo) in zip(scenes, tracked):
        d = pt.accuracy(follow.keypoints3d, seq.joints3d).mean_mm
        d_alone = pt.accuracy(solo.keypoints3d, alone.joints3d).mean_mm
        d_per_frame = pt.accuracy(per_frame.keypoints3d, seq.joints3d).mean_mm
        assert d <= 1.25 * d_alone + 5.0, (d, d_alone)
        assert d_per_frame > d + 20.0, (d_per_frame, d)


def test_only_other_people_in_view_is_lost_not_reacquired(scenes):
    """Remove the first person's detections for 10 frames while the second is in view: the
    frames are lost (pose held), never estimated on the second person."""
    seq, _ = scenes[0]
    both = np.flatnonzero((seq.people_confidence > 0).any(-1).sum(-1) >= 2)
    gap = both[(both >= 10)][:10]
    assert len(gap) >= 6
    kp, conf = seq.people2d.copy(), seq.people_confidence.copy()
    conf[gap, seq.people_index[gap]] = 0.0
    # The body-shape refinement (after tracking) plays no part in who is followed: off.
    res = pt.track(seq.depth, kp, conf, seq.intrinsics, pt.TrackerConfig(), refine=None)
    assert (res.status[gap] == pt.LOST).all(), res.status[gap]
    assert (res.person_index[gap] == -1).all()
    ident = pt.followed_identity(res.keypoints3d, _truth(seq))
    assert not (ident > 0).any(), ident
    later = np.arange(gap[-1] + 4, FRAMES)
    assert (res.status[later] == pt.TRACKED).mean() >= 0.8  # picked up again afterwards


def test_cli_reports_the_person_followed(scenes, tmp_path):
    seq, _ = scenes[1]
    rec = pt.synth.save(seq, tmp_path / "rec")
    out = tmp_path / "out"
    code = main([
        "track", "--depth", str(rec / "depth"), "--keypoints", str(rec / "keypoints"),
        "--intrinsics", str(rec / "intrinsics.json"), "--out", str(out), "--no-video",
        "--quiet", "--hypotheses", "2", "--no-refine-shape",
    ])  # fmt: skip
    assert code == 0
    person = json.loads((out / "summary.json").read_text())["person"]
    assert person["rule"] == "auto" and person["max_people"] == 2
    assert person["frames_others_ignored"] >= 8
    index = np.array(person["person_index"])
    taken = index >= 0
    assert (index[taken] == seq.people_index[taken]).all()
