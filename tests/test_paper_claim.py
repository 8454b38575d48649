"""The paper's claim, guarded: MHT_h beats LVM under occlusion, by a margin a broken tracker loses.

Makris & Argyros report MHT_h's mean joint error D 26 % below LVM's (66 vs 89 mm, their Table 2)
because each hypothesis fits a subset of the landmarks drawn with the weights W^g, W^h of
section 2.2 (which should leave out the bad ones), and Delta (Eq. (3)) picks the hypothesis
that matches the depth. This module checks both on 8 generated occluded clips, with margins
chosen from measurements of the healthy tracker and of sabotaged ones (below), so a broken
selection, weighting or scoring fails it.

Clips: ``pt.synth.generate`` with the procedural motions (no data set needed), 320x240, 40
frames, occlusion levels 2 and 3, seeds 500-507 (``TEST_SEEDS`` of ``benchmarks/seeds.py``:
neither reported by the accuracy benchmark nor tuned on). LVM is
``TrackerConfig.recommended("lvm")``; MHT_h is the shipped ``TrackerConfig()``; all three
with the paper's lifting (``lift_band=0``). Since 2026-11-28 the shipped lifting ignores
window depths more than 0.7 m behind the torso (``lift_band``), which removes most of the
background liftings that the weighted subsets used to leave out, for LVM too: with it (CI
on a clean clone, 2-core Intel Xeon) LVM's mean D here was 98.4 mm and MHT_h's 79.2 (D ratio
0.805, lower on 6 of 8 clips), and W^h off still failed the D margin, so that margin no
longer separated a healthy tracker from sabotage (a). Re-measured with the band
(2026-11-29, tracker seeds +0 / +1000 / +2000, Intel Xeon): healthy D ratio .805 .767 .794
(6-7 of 8 clips), draw ratio .477 .488 .489; (a) D ratio .866 .870 .844 (6-8 of 8), draw
ratio .946 .947 .955. The draw ratio still separates them widely; the D ratio leaves 0.04
between the healthy worst and the sabotage's best, and the clip count not at all. The test
keeps the lifting the margins were measured on; what the band does to MHT_h's gain is in
the README (Beyond the paper).

Asserted:

* accuracy: MHT_h's mean D <= 0.80 x LVM's, and lower than LVM's on >= 7 of the 8 clips;
* selection: over all frames, hypotheses and body joints with depth, MHT_h draws the bad 3D
  landmarks (lifted more than 15 cm from the true joint: occluder hits, detector outliers and
  swaps; 11 % of them here) at <= 0.6 x the rate it draws the good ones. Recorded through the
  public ``Tracker.update`` (``FrameEstimate.used3d``) in the same runs as the accuracy;
* discrimination, in CI: MHT_h with W^h switched off (``sigma_h=1e6``, so W^h = 1; a traced
  tunable, no recompile) fails both margins.

Measured (2-core AMD EPYC, jax 0.10.2, CPU), D in mm per clip (motion:seed:level):

| clip | LVM | MHT_h | MHT_h, sigma_h=1e6 | paper's MHT_h (not asserted) |
|---|---|---|---|---|
| walk:500:2 | 103.1 | 77.0 | 111.3 | 73.7 |
| box:501:3 | 173.5 | 127.6 | 151.9 | 117.6 |
| wave:502:2 | 117.8 | 73.1 | 107.4 | 85.5 |
| reach:503:3 | 134.8 | 103.3 | 135.6 | 118.0 |
| squat:504:2 | 131.8 | 125.3 | 152.8 | 137.8 |
| turn:505:3 | 129.9 | 77.9 | 122.3 | 84.7 |
| walk:506:3 | 160.2 | 114.0 | 132.7 | 105.5 |
| wave:507:3 | 104.6 | 53.9 | 67.2 | 91.3 |
| mean (/ LVM) | 132.0 | 94.0 (0.712) | 122.7 (0.929) | 101.8 (0.771) |
| lower than LVM | - | 8/8 | 5/8 | 7/8 |

The two asserted quantities for the healthy tracker and for sabotaged ones (throwaway
monkeypatches of the private step, never committed): D ratio = mean D / LVM's mean D (clips
where D < LVM's); draw ratio = draw rate of bad / of good 3D landmarks. Several values: the
same clips re-run with tracker seeds +0, +1000, +2000, ... (the random subsets change, the
clips do not), the spread a change of platform or float rounding could cause.

| MHT_h variant | D ratio | draw ratio |
|---|---|---|
| healthy | .712 .670 .653 .716 .624 (8/8) | .367 .381 .363 |
| (a) W^h off: sigma_h=1e6 (= MHT_g's weights) | .929 .877 .867 .888 .863 (5-8/8) | .923 .940 |
| (b) Delta a constant (always hypothesis 0) | .996 (5/8) | - |
| (b') Delta pseudo-random (any hypothesis) | 1.349 (0/8) | - |
| (c) every hypothesis draws all its landmarks | 1.319 (0/8) | 1.000 |
| (c') a uniformly random subset of the weighted draw's size | .756 .773 .805 (7-8/8) | .875 .887 |
| (c'') weights inverted (least likely first) | 1.158 (1/8) | 1.333 |

(b) and (b') leave the selection alone, so only the accuracy test can see them. (c') passes
the accuracy test on 2 of 3 tracker seeds: N = 10 hypotheses, reseeding and the consensus
refit (a refit of the winner on every landmark near it) recover most of what the weights
give, and the subset's size still carries W^h; only the selection test sees it. The paper's
MHT_h alone (N = 5, r = R = 0, no reseeding or consensus refit; last column of the first
table) catches (c') on accuracy too (D ratio .914 .921 .929 against its healthy .771-.828),
but costs a third compiled tracker; the selection test does it for free.

Margins: D ratio 0.80, between the healthy worst (0.716) and the closest sabotage it must
catch ((a), 0.863): slack 0.08 and 0.06. Draw ratio 0.6, between 0.381 and 0.875 ((c')):
slack 0.2 and more. The clip count (7 of 8; healthy always 8) guards against one catastrophic
clip hidden in a good mean; it does not separate (a) on its own.

Cost: two compiled trackers (LVM and MHT_h; the sabotaged MHT_h shares MHT_h's compiled step)
and 24 tracks of 40 frames, most of it compilation: 90 s (89 s of CPU) cold, on the 2-core
machine while other jobs kept its load average at 3-3.5; 10 s of it generates the clips.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import posetrack as pt

_SEEDS_PY = Path(__file__).resolve().parents[1] / "benchmarks" / "seeds.py"


def _test_seeds() -> range:
    spec = importlib.util.spec_from_file_location("benchmarks_seeds", _SEEDS_PY)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.TEST_SEEDS


#: (motion, occlusion level) of each clip; clip i has seed TEST_SEEDS[i].
CLIPS = (
    ("walk", 2), ("box", 3), ("wave", 2), ("reach", 3),
    ("squat", 2), ("turn", 3), ("walk", 3), ("wave", 3),
)  # fmt: skip
SIZE = (320, 240)
FRAMES = 40

D_MARGIN = 0.80
MIN_CLIPS_BETTER = 7
DRAW_MARGIN = 0.6
BAD_LANDMARK_M = 0.15

#: The paper's lifting (``lift_band=0``) for all three: the margins were set on it (below).
PAPER_LIFTING = {"lift_band": 0.0}
CONFIGS = {
    "LVM": pt.TrackerConfig.recommended("lvm", **PAPER_LIFTING),
    "MHT_h": pt.TrackerConfig(**PAPER_LIFTING),
    "MHT_h without W^h": pt.TrackerConfig(sigma_h=1e6, **PAPER_LIFTING),
}


class RecordingTracker(pt.Tracker):
    """The public tracker, keeping which 3D landmarks each hypothesis drew in each frame."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.used3d: dict[int, np.ndarray] = {}  # frame -> (hyp, kpt) bool
        self._frame = 0

    def update(self, depth, keypoints2d, confidence):
        est, status = super().update(depth, keypoints2d, confidence)
        if est is not None:
            self.used3d[self._frame] = np.asarray(est.used3d)
        self._frame += 1
        return est, status


class Run:
    """One configuration on one clip: D (mm) and the draw counts of bad and good landmarks."""

    def __init__(self, seq, config, seed):
        # The paper's claim is about per-frame estimates (no motion model). chunk=1: run()
        # goes through update() frame by frame, where the draws are recorded (chunked, the
        # same poses, but no update() calls).
        tracker = RecordingTracker(seq.intrinsics, config, seed=seed, mode="per-frame", chunk=1)
        res = tracker.run(seq.depth, seq.keypoints2d, seq.confidence, progress=False)
        acc = pt.accuracy(res.keypoints3d, seq.joints3d)
        assert acc.coverage == 1.0, acc.coverage
        assert len(tracker.used3d) > FRAMES // 2, "Tracker.run no longer goes through update()"
        self.d_mm = acc.mean_mm
        body = np.zeros(18, bool)
        body[list(pt.BODY_JOINTS)] = True
        err = np.linalg.norm(res.landmarks3d - seq.joints3d, axis=-1)  # (frame, kpt) metres
        self.drawn = {"bad": 0, "good": 0}
        self.offered = {"bad": 0, "good": 0}
        for t, used in tracker.used3d.items():
            seen = res.has_depth[t] & body
            for kind, mask in (
                ("bad", err[t] > BAD_LANDMARK_M),
                ("good", err[t] <= BAD_LANDMARK_M),
            ):
                self.drawn[kind] += int(used[:, seen & mask].sum())
                self.offered[kind] += int((seen & mask).sum()) * used.shape[0]


@pytest.fixture(scope="module")
def clips():
    seeds = _test_seeds()
    out = []
    for i, (motion, level) in enumerate(CLIPS):
        seed = seeds[i]
        seq = pt.synth.generate(
            seed, motion=motion, n_frames=FRAMES, occlusion_level=level,
            width=SIZE[0], height=SIZE[1], with_rgb=False,
        )  # fmt: skip
        out.append((f"{motion}:{seed}:{level}", seed, seq))
    return out


@pytest.fixture(scope="module")
def runs(clips):
    """``runs(name)``: the configuration's :class:`Run` on every clip, computed once."""
    cache: dict[str, list[Run]] = {}

    def get(name: str) -> list[Run]:
        if name not in cache:
            cache[name] = [Run(seq, CONFIGS[name], seed) for _, seed, seq in clips]
        return cache[name]

    return get


def d_ratio(runs, clips, name) -> tuple[float, int, str]:
    """(mean D / LVM's mean D, clips where D < LVM's, a report for the failure message)."""
    mine = np.array([r.d_mm for r in runs(name)])
    lvm = np.array([r.d_mm for r in runs("LVM")])
    table = ", ".join(f"{c}: {a:.0f} vs {b:.0f}" for (c, _, _), a, b in zip(clips, mine, lvm))
    report = f"{name}: mean D {mine.mean():.1f} vs LVM {lvm.mean():.1f} mm ({table})"
    return float(mine.mean() / lvm.mean()), int((mine < lvm).sum()), report


def draw_ratio(runs, name) -> tuple[float, str]:
    """(draw rate of bad 3D landmarks / draw rate of good ones, a report), over all clips."""
    rate = {
        kind: sum(r.drawn[kind] for r in runs(name)) / sum(r.offered[kind] for r in runs(name))
        for kind in ("bad", "good")
    }
    report = f"{name}: drew {rate['bad']:.3f} of the bad, {rate['good']:.3f} of the good landmarks"
    return rate["bad"] / rate["good"], report


def test_mht_h_beats_lvm_under_occlusion(runs, clips):
    ratio, better, report = d_ratio(runs, clips, "MHT_h")
    assert ratio <= D_MARGIN, f"D ratio {ratio:.3f} > {D_MARGIN}; {report}"
    assert better >= MIN_CLIPS_BETTER, f"lower on only {better}/{len(CLIPS)} clips; {report}"


def test_mht_h_leaves_the_bad_landmarks_out(runs):
    ratio, report = draw_ratio(runs, "MHT_h")
    assert ratio <= DRAW_MARGIN, f"draw ratio {ratio:.3f} > {DRAW_MARGIN}; {report}"


def test_without_temporal_weights_both_margins_are_lost(runs, clips):
    """W^h = 1 (sigma_h huge) must fail both tests above: they measure what W^h does."""
    ratio, _, report = d_ratio(runs, clips, "MHT_h without W^h")
    assert ratio > D_MARGIN, f"D ratio {ratio:.3f} <= {D_MARGIN}; {report}"
    ratio, report = draw_ratio(runs, "MHT_h without W^h")
    assert ratio > DRAW_MARGIN, f"draw ratio {ratio:.3f} <= {DRAW_MARGIN}; {report}"


def test_clips_use_test_seeds_only(clips):
    seeds = _test_seeds()
    assert all(seed in seeds for _, seed, _ in clips)
