"""Frames in chunks (:mod:`posetrack._chunk`): ``Tracker.run`` with up to ``chunk`` steps per
compiled call gives what one call per frame gives, bit for bit, through lost frames, frames
without the person, a dropped track and its re-initialisation; and the track-loss thresholds
compared in float32 on the device mean what the host's float64 comparisons mean."""

import numpy as np
import pytest
from conftest import quick_refine

import posetrack as pt
from posetrack import LOST, NO_OBSERVATION, TRACKED
from posetrack._chunk import status_limits, step_chunk

LVM = pt.TrackerConfig.recommended("lvm")  # test_tracker's: programs shared


def test_status_limits_mean_the_host_comparisons():
    rng = np.random.default_rng(0)
    for L in [0.85, 0.6, 1.0, 0.1, 1 / 3, *rng.uniform(0, 1, 200)]:
        cfg = LVM.replace(lost_delta=float(L), lost_agreement=float(L))
        d_lim, a_lim = status_limits(cfg)
        x32 = np.float32(L)
        # float32 values around the threshold, a few ulps either side
        vals = [x32]
        for _ in range(3):
            vals += [np.nextafter(vals[-1], np.float32(2)), np.nextafter(vals[0], np.float32(-1))]
        vals += [np.nextafter(v, np.float32(-1)) for v in vals]
        for v in vals:
            v = np.float32(v)
            assert (float(v) > float(L)) == bool(v > d_lim), (L, v, d_lim)
            assert (float(v) < float(L)) == bool(v < a_lim), (L, v, a_lim)
    # A plain float32 cast would not do: float32(0.1) > 0.1, so a delta equal to it is lost on
    # the host but would not be on the device.
    assert np.float32(0.1) > status_limits(LVM.replace(lost_delta=0.1))[0]


@pytest.fixture(scope="module")
def scene():
    """Two people; the followed one's keypoints removed for 9 frames while the other is in
    view (lost frames, a drop after ``lost_patience``, re-initialisation), and nobody at all
    for 3 frames: 40 frames, so the last chunk of 16 is partly padding."""
    seq = pt.synth.generate(
        520, motion="wave", n_frames=40, occlusion_level=1, width=320, height=240,
        with_rgb=False, bystander=True,
    )  # fmt: skip
    kp, conf = seq.people2d.copy(), seq.people_confidence.copy()
    both = [t for t in range(40) if (conf[t].sum(-1) > 0).sum() >= 2 and t >= 14]
    hidden = both[:9]
    assert len(hidden) == 9 and hidden[-1] < 36
    for t in hidden:
        conf[t, seq.people_index[t]] = 0.0
    conf[37:40] = 0.0
    return seq, kp, conf


def test_chunked_run_is_the_per_frame_run(scene):
    seq, kp, conf = scene
    results, drops = {}, {}
    for chunk in (1, 16):
        tracker = pt.Tracker(seq.intrinsics, LVM, mode="per-frame", chunk=chunk)
        dropped, drop = [], tracker._drop_track
        tracker._drop_track = lambda: (dropped.append(tracker._run_frame), drop())[1]
        results[chunk] = tracker.run(seq.depth, kp, conf, progress=None)
        drops[chunk] = dropped
    assert drops[1] and drops[16] == drops[1]  # the track was dropped, at the same frame
    one, chunked = results[1], results[16]
    # The scene exercises every path: tracked, lost (the person hidden) and a drop
    # (lost_patience lost frames), re-initialisation, frames with nobody in view.
    status = one.status
    assert (status == TRACKED).sum() > 20 and (status == NO_OBSERVATION).sum() >= 3
    assert (status == LOST).sum() >= LVM.lost_patience
    for name in ("keypoints3d", "params", "delta", "status", "confidence", "landmarks3d",
                 "has_depth", "person_index", "num_people"):  # fmt: skip
        a, b = getattr(one, name), getattr(chunked, name)
        assert np.array_equal(a, b, equal_nan=True), name
    # One program per configuration, image size and chunk: a recording of another length
    # (its last chunk padded differently) builds nothing new.
    built = step_chunk._cache_size()
    pt.Tracker(seq.intrinsics, LVM, mode="per-frame").run(seq.depth[:23], kp[:23], conf[:23])
    assert step_chunk._cache_size() == built


def test_the_state_carries_the_loss_tests_verdict(scene):
    """``TrackState.trusted`` (what ``bound_trusted`` reads) is the status of the last frame
    that had an observation, the loss test's verdict, set by the host per frame and by the
    scan per chunk alike: never a second spelling of the test. The scene loses the track with
    a step (frames 33-34) and then sees nothing (35)."""
    seq, kp, conf = scene
    tracker = pt.Tracker(seq.intrinsics, LVM, mode="per-frame")
    verdicts, statuses = {}, {}
    for t in range(36):
        est, status = tracker.update(seq.depth[t], kp[t], conf[t])
        statuses[t] = status
        if est is not None and tracker._state is not None:
            verdicts[t] = bool(tracker._state.trusted)
            if status != NO_OBSERVATION:
                assert verdicts[t] == (status == TRACKED), t
    assert [statuses[t] for t in (32, 33, 34, 35)] == [TRACKED, LOST, LOST, NO_OBSERVATION]
    assert verdicts[32] and not verdicts[34] and not verdicts[35]
    for stop in (33, 36):  # the same frames in one chunked run (chunk 16): the same verdict
        chunked = pt.Tracker(seq.intrinsics, LVM, mode="per-frame", chunk=16)
        chunked.run(seq.depth[:stop], kp[:stop], conf[:stop], progress=None)
        assert bool(chunked._state.trusted) == verdicts[stop - 1], stop


def test_a_trackers_first_call_steps_one_frame(scene):
    """The first pose does not wait for a whole chunk's steps: a tracker's first call steps
    one frame, the later ones a chunk each (the poses are the per-frame run's, above)."""
    seq, kp, conf = scene
    tracker = pt.Tracker(seq.intrinsics, LVM, mode="per-frame", chunk=16)
    sizes, at_first_pose, dispatch = [], [], tracker._dispatch_chunk
    tracker._dispatch_chunk = lambda frames: (sizes.append(len(frames)), dispatch(frames))[1]

    def progress(done, total, postfix):
        if not at_first_pose:
            at_first_pose.append(list(sizes))

    tracker.run(seq.depth[:20], kp[:20], conf[:20], progress=progress)
    assert sizes == [1, 16, 3]
    # Reported as soon as that first step is read, before the host prepares the next chunk
    # (on a cold start that work, slowed by the programs traced beside it, cost ~1 s).
    assert at_first_pose[0] == [1]
    tracker.run(seq.depth[:20], kp[:20], conf[:20], progress=None)  # the track goes on
    assert sizes[3:] == [16, 4]


def test_chunk_must_be_a_positive_int(scene):
    seq = scene[0]
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="chunk must be an int >= 1"):
            pt.Tracker(seq.intrinsics, chunk=bad)


def test_chunked_offline_run_is_the_frame_by_frame_one():
    """Offline (the default mode): the left/right pre-pass, its stretches tracked twice from
    one state (two here, the first from frame 1), the refinement's frames and the motion model
    see the same forward pass, in chunks or frame by frame."""
    seq = pt.synth.generate(
        523, motion="wave", n_frames=40, occlusion_level=1, width=320, height=240,
        with_rgb=False, bystander=True,
    )  # fmt: skip
    out = {}
    for chunk in (1, 16):
        tracker = pt.Tracker(seq.intrinsics, LVM, chunk=chunk, refine=quick_refine())
        res = tracker.run(seq.depth, seq.people2d, seq.people_confidence, progress=None)
        out[chunk] = res, tracker.side_spans, tracker.side_span_groups
    (one, spans_one, groups_one), (chunked, spans, groups) = out[1], out[16]
    assert len(spans_one) >= 2 and spans == spans_one
    # Which groups each stretch judged: those its exchanged reading exchanged, as kept.
    assert len(groups) == len(spans) and all(g.any() for g in groups)
    np.testing.assert_array_equal(np.stack(groups), np.stack(groups_one))
    for (start, stop, *_, kept), g in zip(spans, groups, strict=True):
        if kept:
            np.testing.assert_array_equal(g, chunked.exchanged[start:stop].any(axis=0))
    for name in ("keypoints3d", "params", "per_frame_keypoints3d", "status", "exchanged"):
        a, b = getattr(one, name), getattr(chunked, name)
        assert np.array_equal(a, b, equal_nan=True), name
