"""The tuning protocol's seed ranges (benchmarks/seeds.py): reported, tuning and test seeds never
overlap, accuracy.py reports only reported seeds, tune.py refuses every other seed, and the
tuning clips are not the reported ones. No tracking: these run in seconds."""

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

import posetrack as pt

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load(name: str):
    """Import benchmarks/<name>.py (not a package) with its folder on sys.path, as when the
    script runs (``from seeds import ...``)."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location(
            f"benchmarks_{name}", BENCHMARKS / f"{name}.py"
        )
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


@pytest.fixture(scope="module")
def seeds():
    return load("seeds")


def test_seed_ranges_are_disjoint(seeds):
    names = list(seeds.RANGES)
    assert names == ["REPORT_SEEDS", "TUNING_SEEDS", "TEST_SEEDS"]
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            assert not set(seeds.RANGES[a]) & set(seeds.RANGES[b]), (a, b)
    seeds.check_disjoint()


def test_tuning_seeds_in_words_are_the_tuning_seeds(seeds):
    assert seeds.parse_seeds(seeds.TUNING_TEXT) == list(seeds.TUNING_SEEDS)


def test_overlapping_ranges_are_refused(seeds, monkeypatch):
    monkeypatch.setitem(seeds.RANGES, "TEST_SEEDS", range(95, 105))
    with pytest.raises(ValueError, match="REPORT_SEEDS and TUNING_SEEDS|overlap"):
        seeds.check_disjoint()


def test_accuracy_benchmark_reports_only_report_seeds(seeds):
    accuracy = load("accuracy")
    for quick in (False, True):
        pairs = accuracy.sequences(quick)
        assert pairs, quick
        used = [s for _, s in pairs]
        assert all(s in seeds.REPORT_SEEDS for s in used), used
        assert len(set(used)) == len(used), "one seed per clip"


def test_tune_refuses_every_seed_outside_the_tuning_range(seeds):
    tune = load("tune")
    tune.check_seeds([seeds.TUNING_SEEDS[0], seeds.TUNING_SEEDS[-1]])
    for bad in (seeds.REPORT_SEEDS[0], 17, seeds.TEST_SEEDS[0], seeds.TUNING_SEEDS[-1] + 1):
        with pytest.raises(ValueError, match="not tuning seeds"):
            tune.check_seeds([seeds.TUNING_SEEDS[0], bad])
    for quick in (False, True):
        assert all(s in seeds.TUNING_SEEDS for _, s in tune.sequences(quick))
    with pytest.raises(ValueError, match="seed-offset"):
        tune.sequences(False, seed_offset=len(seeds.TUNING_SEEDS))
    assert tune.main(["--seed-offset", "-1"]) == 2


def test_tuning_clips_are_not_the_reported_clips():
    accuracy, tune = load("accuracy"), load("tune")
    assert not set(tune.REAL) & set(accuracy.REAL)


def test_the_late_cmu_clips_start_after_the_report_clips_end(seeds):
    """``decide.py --cmu-late-seeds``: the report sets' CMU recordings, from after the last
    frame any report clip shows, on tuning seeds only, without playing back."""
    decide = load("decide")
    late = decide.clips(None, None, False, None, None, list(range(1346, 1352)))
    assert {(c[2], c[3]) for c in late} == {
        (f"{m}@{decide.CMU_LATE_START}", v) for m in decide.CMU for v in ("wide", "standard")
    }
    assert all(c[0] == "cmu late" and c[1] in seeds.TUNING_SEEDS for c in late)
    assert decide.split_start(late[0][2]) == (decide.CMU[1346 % 3], decide.CMU_LATE_START)
    assert decide.split_start("cmu:131_01") == ("cmu:131_01", 0.0)
    # The report clips: 120 frames at 30 fps from 0 s (motion.run_clip and decide.track).
    assert decide.CMU_LATE_START > 119 / 30.0
    assert set(decide.CMU) <= set(load("accuracy").REAL)
    with pytest.raises(SystemExit, match="--cmu-late-seeds.*not tuning seeds"):
        decide.clips(None, None, False, None, None, [7])
    available = set(pt.synth.list_real_motions())
    if not set(decide.CMU) <= available:
        pytest.skip("the CMU recordings are not in $POSETRACK_DATA or ../shared/data")
    from posetrack.synth._mocap import real_motion
    from posetrack.synth._skeleton import sample_subject

    subject = sample_subject(np.random.default_rng(0))
    for name in decide.CMU:  # 120 frames from the late start, none played back
        clip = real_motion(name, subject, n_frames=120, fps=30.0, start=decide.CMU_LATE_START)
        assert clip.info["looped"] is False, name


def test_a_screen_cut_short_resumes_from_its_whole_records(tmp_path, monkeypatch):
    """``decide.py``: the runs already in the output with every variant are skipped, a last
    line cut off mid-write is removed, a bad line elsewhere is an error naming it."""
    decide = load("decide")
    out = tmp_path / "screen.jsonl"
    both = {"group": "walk_across", "seed": 2958, "occ": 0, "tseed": 0, "default": {}, "v": {}}
    one = {**both, "tseed": 1}
    del one["v"]  # a record of an earlier screen without the candidate: not this one's
    out.write_text(json.dumps(both) + "\n" + json.dumps(one) + "\n" + '{"group": "wal')
    assert decide.recorded(str(out), ["default", "v"]) == {("walk_across", 2958, 0, 0)}
    assert out.read_text().splitlines() == [json.dumps(both), json.dumps(one)]

    def no_clip(*args):
        raise AssertionError("a recorded run was tracked again")

    monkeypatch.setattr(decide, "generate_clip", no_clip)
    clip = ("walk_across", 2958, "walk_across", "wide")
    decide.track([(clip, 0, 0)], {"default": {}, "v": {}}, "offline", str(out))
    assert len(out.read_text().splitlines()) == 2  # nothing appended
    with pytest.raises(AssertionError, match="tracked again"):  # tseed 1 lacks the candidate
        decide.track([(clip, 0, 1)], {"default": {}, "v": {}}, "offline", str(out))
    out.write_text("not json\n" + json.dumps(both) + "\n")
    with pytest.raises(SystemExit, match="screen.jsonl, line 1: not a JSON record"):
        decide.recorded(str(out), ["default"])
    assert decide.recorded(str(tmp_path / "none.jsonl"), ["default"]) == set()


def test_the_decision_runs_run_on_tuning_seeds_only(seeds):
    decide = load("decide")
    used = [seed for _, seed, _, _ in decide.clips()]
    assert len(used) == 20 and len(set(used)) == 20
    assert all(s in seeds.TUNING_SEEDS for s in used), used
    assert decide.settings("kept") == {"duplicates": None}
    assert decide.settings("default") == {}
    assert decide.settings("inbatch")["config"].consensus_in_batch
    assert not decide.settings("norefit")["config"].consensus_refit
    assert decide.settings("settle5")["duplicates"].settle == 5
    assert decide.settings("sides:arms+torso")["sides"].groups == ("arms", "torso")
    for bad in ("settle", "sides:arms+elbows"):
        with pytest.raises(SystemExit, match="settleN|groups"):
            decide.settings(bad)
    two = decide.settings("twopass10")  # the radii's prior off, the recording tracked twice
    assert two["refine"].radius_prior_sigma == 10.0 and two[decide._SECOND_PASS] is True
    assert two["refine"].prior_sigma == pt.ShapeFitSettings.tracking().prior_sigma
    with pytest.raises(SystemExit, match="twopass"):
        decide.settings("twopass-1")
    girth = decide.settings("girth1")["refine"]  # the radii's common factor free, not each
    assert girth.girth_prior_sigma == 1.0 and girth.radius_prior_sigma is None
    with pytest.raises(SystemExit, match="girth"):
        decide.settings("girth0")
    pre = decide.settings("prepass40")["refine"]  # the first 40 frames tracked alone first
    assert pre.offline_first == 40 and pre.radius_prior_sigma == 10.0
    radii = decide.settings("prepass40r")["refine"].fields  # the lengths as measured
    assert radii and all(f.endswith("_radius") for f in radii) and "thigh" not in radii
    shipped = decide.settings("prepass40g")["refine"]  # the mode's own refinement: girth
    assert shipped == dataclasses.replace(pt.ShapeFitSettings.tracking(), offline_first=40)
    for bad in ("prepass", "prepass5", "prepass4x", "prepass40rr", "prepass40gr", "prepassg"):
        with pytest.raises(SystemExit, match="prepassN"):
            decide.settings(bad)
    with pytest.raises(SystemExit, match="offline"):  # the pre-pass is offline's alone
        decide.settings("prepass40g", "online")
    # --real-seeds: wide real motion clips of tuning seeds, never report seeds.
    real = decide.clips([100, 107])
    assert [c[1] for c in real] == [100, 107] and {c[3] for c in real} == {"wide"}
    n = len(decide.REAL)
    assert [c[2] for c in real] == [decide.REAL[100 % n], decide.REAL[107 % n]]
    with pytest.raises(SystemExit, match="not tuning seeds"):
        decide.clips([0, 100])
    # --side-seeds: wide walk_across clips (a side view) added, of tuning seeds only.
    side = decide.clips(None, [103, 111])
    assert len(side) == 22 and side[-2:] == [
        ("walk_across", 103, "walk_across", "wide"),
        ("walk_across", 111, "walk_across", "wide"),
    ]
    with pytest.raises(SystemExit, match="--side-seeds.*not tuning seeds"):
        decide.clips(None, [6])
    # --real-seeds, --procedural-seeds, --standard-seeds: those clips instead of the 40.
    mixed = decide.clips([176], [196], True, [173], [168])
    assert mixed == [
        ("wide real", 176, decide.real_motion(176), "wide"),
        ("wide procedural", 173, decide.PROCEDURAL[173 % 6], "wide"),
        ("standard", 168, decide.PROCEDURAL[168 % 6], "standard"),
        ("walk_across", 196, "walk_across", "wide"),
    ]
    assert decide.clips(None, [196], False, [173]) == [mixed[1], mixed[3]]
    assert decide.clips(None, [196], False) == mixed[-1:]
    for option, args in (("--procedural-seeds", (None, None, True, [50])),
                         ("--standard-seeds", (None, None, True, None, [99]))):  # fmt: skip
        with pytest.raises(SystemExit, match=f"{option}.*not tuning seeds"):
            decide.clips(*args)
    far = decide.settings("far1.0")["config"]
    assert far.depth_confidence_far == 1.0 and far.depth_confidence == 0.0
    assert decide.settings("band0.5")["config"].lift_band == 0.5


def test_the_wide_factor_runs_put_back_one_factor_each(seeds):
    """benchmarks/wide_factors.py: tuning seeds only; each "wide, standard X" form is the wide
    clip with exactly that factor as the standard clip has it, the others still drawn wide."""
    wf = load("wide_factors")
    assert all(s in seeds.TUNING_SEEDS for s in wf.SEEDS)
    clip = {f: wf.generate(150, "walk", 0, f, frames=6) for f in wf.FORMS}
    assert clip["standard"].meta["wide"] is None
    wide = clip["wide"].meta["wide"]
    assert wide["camera"] is not None and wide["sensor_applied"] and wide["detector_applied"]
    body = clip["wide, standard body"].meta["wide"]
    assert body["body"] == dataclasses.asdict(wf.BodyVariation()) != wide["body"]
    assert {k: v for k, v in body.items() if k != "body"} == {
        k: v for k, v in wide.items() if k != "body"
    }
    camera = clip["wide, standard camera"].meta["wide"]
    assert camera["camera"] is None and camera["body"] == wide["body"]
    assert not clip["wide, standard sensor"].meta["wide"]["sensor_applied"]
    assert clip["wide, standard sensor"].meta["wide"]["detector_applied"]
    assert not clip["wide, standard detector"].meta["wide"]["detector_applied"]
    # The truth moves with the body and the camera only.
    np.testing.assert_array_equal(clip["wide, standard sensor"].joints3d, clip["wide"].joints3d)
    assert not np.allclose(clip["wide, standard camera"].joints3d, clip["wide"].joints3d)
    std = dataclasses.asdict(wf.DetectorConfig())
    for group, fields in wf.DETECTOR_PARTS.items():
        det = wf.generate(150, "walk", 0, f"wide, standard detector {group}", frames=2)
        assert (
            det.meta["detector"]
            == {k: std[k] if k in fields else v for k, v in clip["wide"].meta["detector"].items()}
            != clip["wide"].meta["detector"]
        ), group
    # The patch is undone: a wide clip after the forms is the wide clip.
    np.testing.assert_array_equal(
        wf.generate(150, "walk", 0, "wide", frames=6).keypoints2d, clip["wide"].keypoints2d
    )


def test_the_facing_runs_count_turned_round_frames_on_tuning_seeds_only(seeds, monkeypatch):
    """benchmarks/facing.py: the facing error is the angle about the vertical between the
    estimated and the true shoulder line (a body turned round: 180 degrees, a lean: 0), and
    the script refuses seeds outside the tuning range before tracking anything."""
    fc = load("facing")
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(5, 18, 3))
    turned = truth.copy()
    turned[:, :, [0, 2]] *= -1  # 180 degrees about the camera's vertical (y) axis
    leaning = truth.copy()
    leaning[:, :, 1] += rng.normal(size=(5, 18))  # heights change, the facing does not
    np.testing.assert_allclose(fc.facing_error_deg(turned, truth), 180.0, atol=1e-6)
    np.testing.assert_allclose(fc.facing_error_deg(leaning, truth), 0.0, atol=1e-6)
    nan = truth.copy()
    nan[2] = np.nan
    assert np.isnan(fc.facing_error_deg(nan, truth)[2])
    monkeypatch.setattr(sys, "argv", ["facing.py", "--seeds", "0-3"])
    with pytest.raises(SystemExit):
        fc.main()


def test_the_loss_diagnosis_pairs_frames_and_keeps_to_its_seed_ranges(seeds, monkeypatch):
    """benchmarks/losses.py: D_pair compares two versions on the frames both estimated only
    (-1: not estimated), and tuning kinds refuse report seeds (report-real the reverse) before
    tracking anything."""
    ls = load("losses")

    def record(err, status, coverage):
        return {"seed": 100, "occ": 0, "kind": "real", "mode": "offline", "motion": "m",
                "D": float(np.mean([e for e in err if e >= 0])), "coverage": coverage,
                "status": status, "err": err}  # fmt: skip

    before = record([10.0, -1.0, -1.0, 30.0], [0, 1, 1, 0], 0.5)
    after = record([12.0, 90.0, 80.0, 20.0], [0, 1, 0, 0], 1.0)
    out = ls.compare([before], [after])
    c = out["clips"][0]
    assert c["D_pair_before"] == pytest.approx(20.0) and c["D_pair_after"] == pytest.approx(16.0)
    assert c["D_after"] == pytest.approx(50.5)  # the frames answered only after count in D
    assert (c["lost_before"], c["lost_after"]) == (2, 1)
    for argv in (["--kind", "real", "--seeds", "0-3"], ["--kind", "report-real", "--seeds", "100"]):
        monkeypatch.setattr(sys, "argv", ["losses.py", *argv, "--out", "/nonexistent/x"])
        with pytest.raises(SystemExit):
            ls.main()


def _record(group, seed, occ, tseed, base_d, cand_d, swaps=(0, 0), accel=(3.0, 3.0)):
    return {
        "group": group, "seed": seed, "motion": "walk", "occ": occ, "tseed": tseed,
        "default": {"D": base_d, "swaps": swaps[0], "cov": 1.0, "accel": accel[0]},
        "far1.0": {"D": cand_d, "swaps": swaps[1], "cov": 0.9, "accel": accel[1]},
    }  # fmt: skip


def _write(path, records):
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return str(path)


def test_the_paired_change_averages_each_run_over_its_tracker_seeds(tmp_path):
    paired = load("paired")
    records = [
        # run A: seed 0 gains 30 mm, seed 1 loses 10 -> change -10; baseline spread sd(100, 60)
        _record("standard", 168, 0, 0, 100.0, 70.0, (2, 1), (3.0, 5.0)),
        _record("standard", 168, 0, 1, 60.0, 70.0, (0, 3), (4.0, 4.0)),
        # run B: no change on either seed
        _record("standard", 169, 0, 0, 40.0, 40.0),
        _record("standard", 169, 0, 1, 40.0, 40.0),
        # run C (occluded): +2 on both seeds
        _record("standard", 168, 2, 0, 50.0, 52.0),
        _record("standard", 168, 2, 1, 54.0, 56.0),
    ]
    runs = paired.run_changes(
        paired.load([_write(tmp_path / "r.jsonl", records)]), "default", "far1.0"
    )
    by = {(r["seed"], r["occ"]): r for r in runs}
    assert by[168, 0]["change"] == pytest.approx(-10.0)
    assert by[168, 0]["base_D"] == pytest.approx(80.0) and by[168, 0]["candidate_D"] == 70.0
    assert by[168, 0]["spread"] == pytest.approx(np.std([100.0, 60.0], ddof=1))
    assert (by[168, 0]["base_swaps"], by[168, 0]["candidate_swaps"]) == (2, 4)
    # acceleration error and coverage: each variant's mean over the run's tracker seeds
    assert (by[168, 0]["base_accel"], by[168, 0]["candidate_accel"]) == (3.5, 4.5)
    assert (by[168, 0]["base_cov"], by[168, 0]["candidate_cov"]) == (1.0, 0.9)
    rows = dict(paired.table(runs))
    assert list(rows) == ["standard, clean", "standard, occlusion 2", "all"]
    clean = rows["standard, clean"]
    assert clean["change"] == pytest.approx(-5.0) and clean["runs"] == 2
    assert clean["se"] == pytest.approx(np.std([-10.0, 0.0], ddof=1) / np.sqrt(2))
    assert clean["t"] == pytest.approx(-5.0 / clean["se"])
    assert (clean["better"], clean["worse"]) == (1, 0)
    every = rows["all"]
    assert every["change"] == pytest.approx((-10.0 + 0.0 + 2.0) / 3)
    assert (every["base_swaps"], every["candidate_swaps"]) == (2, 4)
    assert every["base_accel"] == pytest.approx((3.5 + 3.0 + 3.0) / 3)
    assert every["candidate_accel"] == pytest.approx((4.5 + 3.0 + 3.0) / 3)


def test_the_coverage_clause_fails_on_a_consistent_or_a_large_loss_and_not_on_noise():
    paired = load("paired")

    def runs(changes):  # (group, occ, coverage change) per run; the baseline answers 0.95
        return [{"group": g, "occ": o, "base_cov": 0.95, "candidate_cov": 0.95 + c}
                for g, o, c in changes]  # fmt: skip

    noise = [("wide", 0, c) for c in (-0.004, 0.003, -0.002, 0.002)]
    assert paired.coverage_clause(runs(noise))["holds"]
    # (a) the mean over all runs: small but consistent (t <= -2), or large whatever its t
    consistent = [("wide", 0, c) for c in (-0.004, -0.003, -0.005, -0.004)]
    clause = paired.coverage_clause(runs(consistent))
    assert not clause["holds"] and clause["all"]["t"] <= -2 and clause["failing_cells"] == []
    assert not paired.coverage_clause(runs([("wide", 0, -0.05), ("wide", 0, 0.01)]))["holds"]
    # (b) one cell: below -0.025 with t <= -1.5, or below -0.06 whatever its t
    cell = [("side", 2, c) for c in (-0.03, -0.035, -0.03)] + [("wide", 0, 0.01)] * 12
    clause = paired.coverage_clause(runs(cell))
    assert not clause["holds"] and clause["failing_cells"] == ["side, occlusion 2"]
    assert clause["worst_cell"]["label"] == "side, occlusion 2"
    spread = [("side", 2, c) for c in (-0.10, 0.05)] + [("wide", 0, 0.01)] * 12
    assert paired.coverage_clause(runs(spread))["holds"]  # -0.025 mean, t -0.33: noise
    large = [("side", 2, c) for c in (-0.15, 0.02)] + [("wide", 0, 0.01)] * 12
    assert paired.coverage_clause(runs(large))["failing_cells"] == ["side, occlusion 2"]


def test_the_null_rule_counts_how_often_sign_flips_fail_a_cell_or_pass_the_mean():
    # Each run's change flipped in sign at random: with every run of a cell at +3 mm the cell
    # fails only where no sign flipped (1/4 with two runs), the mean passes only where both
    # did (1/4); two such cells: 1 - (3/4)^2. A cell at (+3, +1) has t 2 at its worst, so it
    # fails 1/4 of flips at t >= 2 and never at t >= 2.5.
    paired = load("paired")

    def runs(cells):
        return [{"group": g, "occ": 0, "change": c} for g, cs in cells for c in cs]

    one = paired.null_rule(runs([("side", (3.0, 3.0))]), flips=4000, cell_t=(1.0,))
    assert one["cell_fails"]["1.0"] == pytest.approx(0.25, abs=0.03)
    assert one["mean_passes"]["1.0"] == pytest.approx(0.25, abs=0.03)
    two = paired.null_rule(runs([("side", (3.0, 3.0)), ("wide", (3.0, 3.0))]), flips=4000)
    assert two["cell_fails"]["1.0"] == pytest.approx(1 - 0.75**2, abs=0.03)
    t = paired.null_rule(runs([("side", (3.0, 1.0))]), flips=4000, cell_t=(1.0, 2.0, 2.5))
    assert t["cell_fails"]["1.0"] == pytest.approx(0.25, abs=0.03)
    assert t["cell_fails"]["2.0"] == pytest.approx(0.25, abs=0.03)
    assert t["cell_fails"]["2.5"] == 0.0
    # the 1 mm floor: a cell at (+1, +1) is never worse by more than 1 mm
    assert paired.null_rule(runs([("side", (1.0, 1.0))]), flips=500)["cell_fails"]["1.0"] == 0


def test_the_rule_of_2026_12_07_fails_each_clause_on_its_own():
    paired = load("paired")

    def records(changes, group="wide", occ=0, swaps=10, accel=3.0, cov=1.0, wall=1.0):
        # one tracker seed per run: the baseline at 50 mm, the candidate at 50 + change
        return [{
            "group": group, "seed": 100 + i, "motion": "walk", "occ": occ, "tseed": 0,
            "default": {"D": 50.0, "swaps": 10, "cov": 1.0, "accel": 3.0, "s": 10.0},
            "cand": {"D": 50.0 + c, "swaps": swaps, "cov": cov, "accel": accel, "s": 10.0 * wall},
        } for i, c in enumerate(changes)]  # fmt: skip

    def verdict(recs, stage="screen", wall_max=None):
        runs = paired.run_changes(recs, "default", "cand")
        return paired.rule_verdict(runs, recs, stage, wall_max, "default", "cand")

    gain = [-3.0, -2.5, -3.5, -2.8, -3.2, -3.0]
    ok = verdict(records(gain), wall_max=1.3)
    assert ok["passed"] and ok["wall_ratio"] == 1.0 and set(ok["clauses"]) >= {"mean", "wall"}
    # the mean: below 0 but t above -2 fails a screen and passes a report stage
    weak = [-3.0, 2.9, -3.0, 2.9, -3.0, 2.9]
    assert verdict(records(weak), wall_max=1.3)["clauses"] == {**ok["clauses"], "mean": False}
    assert verdict(records(weak), "report")["passed"]
    # a cell worse by more than 1 mm with t >= 2, while the mean over all runs still gains
    cell = records(gain * 3) + records([2.0, 3.0, 2.5], group="side", occ=2)
    out = verdict(cell)
    assert not out["passed"] and out["failing_cells"] == ["side, occlusion 2"]
    assert out["clauses"]["mean"]
    # one swapped-limb frame more a run: a screen fails, a report stage allows up to 10 %
    assert verdict(records(gain, swaps=11))["clauses"]["swaps"] is False
    assert verdict(records(gain, swaps=11), "report")["passed"]
    assert not verdict(records(gain, swaps=12), "report")["passed"]
    # acceleration up by more than 10 %, coverage lost, the wall-time budget
    assert verdict(records(gain, accel=3.4))["clauses"]["accel"] is False
    assert verdict(records(gain, cov=0.9))["clauses"]["coverage"] is False
    assert verdict(records(gain, wall=1.4), wall_max=1.3)["clauses"]["wall"] is False
    with pytest.raises(ValueError, match="stage"):
        verdict(records(gain), "final")


def test_the_paired_change_reads_a_missing_acceleration_as_nan():
    # records written before the acceleration error was recorded still join; their mean is nan
    paired = load("paired")
    old = _record("standard", 168, 0, 0, 50.0, 40.0)
    del old["default"]["accel"]
    (run,) = paired.run_changes([old], "default", "far1.0")
    assert np.isnan(run["base_accel"]) and run["candidate_accel"] == 3.0
    assert run["change"] == -10.0


def _alone_record(seed, tseed, base, cand, shared):
    """One decide.py record of ``default`` and ``alone30``: ``base`` and ``cand`` are (D,
    coverage, swaps), ``shared`` (frames, candidate D, baseline D, candidate swaps, baseline
    swaps) on the frames both answered."""
    return {
        "group": "walk_across", "seed": seed, "motion": "walk", "occ": 2, "tseed": tseed,
        "default": {"D": base[0], "cov": base[1], "swaps": base[2], "accel": 4.0},
        "alone30": {"D": cand[0], "cov": cand[1], "swaps": cand[2], "accel": 5.0,
                    "shared": {"vs": "default", "frames": shared[0], "D": shared[1],
                               "base_D": shared[2], "swaps": shared[3],
                               "base_swaps": shared[4]}},
    }  # fmt: skip


def test_the_changed_runs_of_a_rare_event_and_the_frames_only_the_candidate_answers():
    paired = load("paired")
    rec = _alone_record
    records = [
        rec(1, 0, (50.0, 1.0, 0), (50.0, 1.0, 0), (10, 50.0, 50.0, 0, 0)),  # not changed
        # 4 of 10 frames answered -> 10; the shared 4 at 90 mm, the own 10 at 66 mm, so the
        # 6 new frames hold (66 * 10 - 90 * 4) / 6 = 50 mm
        rec(2, 0, (100.0, 0.4, 2), (66.0, 1.0, 1), (4, 90.0, 100.0, 1, 2)),
        rec(3, 0, (40.0, 1.0, 0), (70.0, 1.0, 3), (10, 70.0, 40.0, 3, 0)),  # same frames, worse
    ]
    rows = {r["seed"]: r for r in paired.changed(records, "default", "alone30", frames=10)}
    assert set(rows) == {2, 3}
    assert (rows[2]["base_frames"], rows[2]["candidate_frames"]) == (4, 10)
    assert rows[2]["change"] == pytest.approx(-10.0) and rows[2]["new_D"] == pytest.approx(50.0)
    assert rows[3]["change"] == pytest.approx(30.0) and np.isnan(rows[3]["new_D"])
    assert (rows[3]["base_swaps"], rows[3]["candidate_swaps"]) == (0, 3)


def test_the_pooled_changed_runs_average_the_seeds_that_share_enough_frames():
    paired = load("paired")
    rec = _alone_record
    same = ((50.0, 1.0, 0), (50.0, 1.0, 0), (100, 50.0, 50.0, 0, 0))
    records = [
        rec(1, 0, *same), rec(1, 1, *same),  # unchanged: counts in the mean at 0
        # seed 0: 100 -> 100 frames, 10 mm worse on them; seed 1: 20 -> 100 frames, but only
        # 20 shared (< 30): its -40 does not count, so the run's change is +10, not -15; its
        # 80 new frames hold (60 * 100 - 90 * 20) / 80 = 52.5 mm
        rec(2, 0, (40.0, 1.0, 1), (50.0, 1.0, 3), (100, 50.0, 40.0, 3, 1)),
        rec(2, 1, (130.0, 0.2, 0), (60.0, 1.0, 2), (20, 90.0, 130.0, 2, 0)),
        # both seeds answer 100 -> 97 frames (3 % fewer), 20 and 0 mm better
        rec(3, 0, (80.0, 1.0, 0), (60.0, 0.97, 0), (97, 60.0, 80.0, 0, 0)),
        rec(3, 1, (70.0, 1.0, 0), (70.0, 0.97, 0), (97, 70.0, 70.0, 0, 0)),
    ]  # fmt: skip
    rows, totals = paired.pooled_changed(records, "default", "alone30", frames=100)
    rows = {r["seed"]: r for r in rows}
    assert set(rows) == {2, 3}
    assert rows[2]["change"] == pytest.approx(10.0) and rows[2]["seeds_counted"] == 1
    assert (rows[2]["base_frames"], rows[2]["candidate_frames"]) == (120, 200)
    assert rows[2]["swaps"] == [1, 5] and rows[2]["own_swaps"] == [1, 5]
    assert rows[3]["change"] == pytest.approx(-10.0) and rows[3]["seeds_changed"] == 2
    assert totals["runs"] == 3 and totals["changed"] == 2 and totals["fewer_2pct"] == 1
    assert totals["mean_change"] == pytest.approx(0.0)  # (0 + 10 - 10) / 3
    assert (totals["worse_5mm"], totals["better_5mm"]) == (1, 1)
    assert totals["worst_change"] == pytest.approx(10.0)
    assert totals["new_frames"] == 80 and totals["new_D"] == pytest.approx(52.5)
    # every seed of the changed runs, frame-weighted: (5000 + 1800 + 5820 + 6790) / 314
    assert totals["changed_shared_D"] == pytest.approx(19410 / 314)
    assert totals["accel"] == [4.0, 5.0]
    # a seed short of frames in every seed leaves the run out of the mean
    rows, totals = paired.pooled_changed(records, "default", "alone30", 100, min_shared=101)
    assert all(np.isnan(r["change"]) for r in rows) and totals["runs_counted"] == 0


def test_the_paired_change_refuses_repeated_or_incomplete_runs(tmp_path):
    paired = load("paired")
    twice = _write(tmp_path / "twice.jsonl", [_record("standard", 168, 0, 0, 1.0, 2.0)] * 2)
    with pytest.raises(SystemExit, match=r"twice.jsonl:2: .*seed 0 variant 'default' again.*:1"):
        paired.load([twice])
    # A variant run later beside stored ones joins their records.
    later = _record("standard", 168, 0, 0, 1.0, 5.0)
    later["other"] = later.pop("far1.0")
    del later["default"]
    both = paired.load([_write(tmp_path / "a.jsonl", [_record("standard", 168, 0, 0, 1.0, 2.0)]),
                        _write(tmp_path / "b.jsonl", [later])])  # fmt: skip
    assert len(both) == 1 and both[0]["other"]["D"] == 5.0 and both[0]["far1.0"]["D"] == 2.0
    short = [_record("standard", 168, 0, t, 1.0, 2.0) for t in (0, 1)]
    short.append(_record("standard", 169, 0, 0, 1.0, 2.0))
    with pytest.raises(SystemExit, match=r"incomplete \(tracker seeds \[0, 1\].*169 occ 0: \[0\]"):
        paired.run_changes(short, "default", "far1.0")
    with pytest.raises(SystemExit, match="has no variant 'far0.5'"):
        paired.run_changes(short, "default", "far0.5")


def test_the_report_stage_reads_stored_seed_zero_rows_of_the_same_clips(tmp_path):
    report = load("report_pairs")
    clips = report.report_clips(2, 0, "procedural")
    assert clips == [(0, "walk"), (1, "box")]

    def row(d):
        return {"D_mm": d, "coverage": 1.0, "swap_frames": 3, "accel_mm": 4.0}

    stored = [
        {"seed": s, "motion": m, "occlusion": o, "rows": {"MHT_h offline": row(10.0 * s + o)}}
        for s, m in clips
        for o in (0, 2)
    ]
    (tmp_path / "m.json").write_text(json.dumps({"clips": stored}))
    weight = [{"seed": c["seed"], "motion": c["motion"], "occlusion": c["occlusion"],
               "cand": row(1.0)} for c in stored]  # fmt: skip
    (tmp_path / "w.json").write_text(json.dumps({"clips": weight}))
    recs = report.join(
        [(r, "w") for r in report.stored_records(f"default={tmp_path / 'w.json'}:cand", clips,
                                                  "report standard")]
        + [(r, "m") for r in report.stored_records(f"far1.0={tmp_path / 'm.json'}:MHT_h offline",
                                                    clips, "report standard")]
    )  # fmt: skip
    assert len(recs) == 4 and {r["tseed"] for r in recs} == {0}
    box = next(r for r in recs if r["seed"] == 1 and r["occ"] == 2)
    assert box["far1.0"]["D"] == 12.0 and box["default"]["D"] == 1.0
    assert box["far1.0"]["swaps"] == 3 and box["group"] == "report standard"
    with pytest.raises(SystemExit, match=r"m.json: no row 'MHT_h online L=3' \(it has"):
        report.stored_records(f"x={tmp_path / 'm.json'}:MHT_h online L=3", clips, "g")
    with pytest.raises(SystemExit, match=r"m.json: its clips .* are not the set's"):
        report.stored_records(f"x={tmp_path / 'm.json'}:MHT_h offline", clips[::-1], "g")
    with pytest.raises(SystemExit, match="expected VARIANT=FILE:ROW"):
        report.stored_records(str(tmp_path / "m.json"), clips, "g")


def test_the_seed_means_show_how_a_reported_mean_moves_with_the_tracker_seed():
    paired = load("paired")
    records = [
        _record("standard", 168, 0, 0, 10.0, 0.0),
        _record("standard", 168, 0, 1, 30.0, 0.0),
        _record("standard", 169, 0, 0, 20.0, 0.0),
        _record("standard", 169, 0, 1, 20.0, 0.0),
        _record("standard", 168, 2, 0, 50.0, 0.0),
        _record("standard", 168, 2, 1, 40.0, 0.0),
    ]
    rows = dict(paired.seed_means(records, "default"))
    assert list(rows) == ["standard, clean", "standard, occlusion 2", "all"]
    clean = rows["standard, clean"]
    assert clean["D_by_tseed"] == {0: 15.0, 1: 25.0} and clean["runs"] == 2
    assert clean["spread"] == pytest.approx(np.std([10.0, 30.0], ddof=1) / 2)
    assert rows["all"]["D_by_tseed"] == pytest.approx({0: 80 / 3, 1: 30.0})
    with pytest.raises(SystemExit, match="incomplete"):
        paired.seed_means(records[:-1], "default")


def test_the_depth_bias_diagnosis_keeps_to_tuning_seeds_and_signs_its_error(seeds, capsys):
    """benchmarks/depth_bias.py refuses every seed outside the tuning range before tracking,
    and reads a torso that is too close to the camera as negative (frames without an
    estimate skipped)."""
    db = load("depth_bias")
    for bad in (seeds.REPORT_SEEDS[0], seeds.TEST_SEEDS[0], seeds.TUNING_SEEDS[-1] + 1):
        assert db.main(["--seeds", f"1000,{bad}"]) == 2
        assert "tuning seeds only" in capsys.readouterr().err
    truth = np.zeros((3, 18, 3))
    truth[..., 2] = 2.5
    est = truth.copy()
    est[:, list(db.TORSO), 2] -= 0.04  # 40 mm nearer
    est[:, 4, 2] += 1.0  # a wrist far off: not a torso keypoint
    est[2] = np.nan
    assert db.torso_depth_bias(est, truth) == pytest.approx(-40.0)
    assert db.clip_motion(1000) == load("tune").real_motion(1000)
    assert db.clip_motion(1008) == "walk"


def test_the_torso_profile_diagnosis_reads_width_and_depth_of_an_elliptical_torso(seeds, capsys):
    """benchmarks/torso_profile.py refuses seeds outside the tuning range, and on a facing
    torso of elliptical cross-section (half-width 40 px, half-depth 10 cm) reads its width
    and how far behind the centre the surface lies at 70 % of the half-width (0.29 x 10 cm)."""
    tp = load("torso_profile")
    assert tp.main(["--seeds", f"1000,{seeds.REPORT_SEEDS[0]}"]) == 2
    assert "tuning seeds only" in capsys.readouterr().err
    fx, zc, a, b = 300.0, 2.5, 40, 0.1
    depth = np.zeros((240, 320))
    u = np.arange(320) - 160.0
    inside = np.abs(u) < a + 0.5
    profile = zc + b * (1 - np.sqrt(np.clip(1 - (u / (a + 0.5)) ** 2, 0, 1)))
    depth[:, inside] = profile[inside]
    kp = np.zeros((18, 2))
    kp[1], kp[8], kp[11] = (160, 60), (150, 180), (170, 180)
    kp[2], kp[5] = (120, 60), (200, 60)
    conf = np.ones(18)
    width, dz = tp.frame_profile(depth, kp, conf, fx)
    assert width == pytest.approx(2 * a * zc / fx, rel=0.05)
    assert dz == pytest.approx(b * (1 - np.sqrt(1 - 0.7**2)), abs=0.003)
    kp[2], kp[5] = (150, 60), (170, 60)  # turned sideways: shoulders close in the image
    assert tp.frame_profile(depth, kp, conf, fx) is None
    conf[8] = 0.1  # a hip missed
    kp[2], kp[5] = (120, 60), (200, 60)
    assert tp.frame_profile(depth, kp, conf, fx) is None


def test_the_torso_oracle_keeps_to_tuning_seeds_and_replaces_only_the_radii(
    seeds, capsys, monkeypatch
):
    """benchmarks/oracle_torso.py refuses seeds outside the tuning range; its oracle shape is
    the tracker's landmark-based shape with the torso radius set to the generated chest's
    half-depth (0.106 x girth) and, in the all-radii run, every other radius x girth (the
    lengths untouched)."""
    ot = load("oracle_torso")
    assert ot.main(["--seeds", f"1000,{seeds.REPORT_SEEDS[0]}"]) == 2
    assert "tuning seeds only" in capsys.readouterr().err
    import posetrack._tracker as tracker_module

    start = pt.BodyShape.create(thigh=0.5, thigh_radius=0.08)
    monkeypatch.setattr(tracker_module, "estimate_shape", lambda *a, **k: (start, {"size": 1.0}))
    torso_only = ot._with_radii(1.5, every_radius=False)()[0].to_dict()
    every = ot._with_radii(1.5, every_radius=True)()[0].to_dict()
    for values in (torso_only, every):
        assert values["torso_radius"] == pytest.approx(0.106 * 1.5)
        assert values["thigh"] == pytest.approx(0.5)
    assert torso_only["thigh_radius"] == pytest.approx(0.08)
    assert every["thigh_radius"] == pytest.approx(0.12)
    assert every["head_radius"] == pytest.approx(1.5 * start.to_dict()["head_radius"])


def test_benchmark_parts_share_every_run_once_and_refuse_a_part_out_of_range(capsys):
    # --part/--parts divide a benchmark's runs between processes; parts count from 0, and
    # "--part 1, --part 2 of --parts 2" once silently skipped the first run.
    import argparse

    parts = load("parts")
    ap = argparse.ArgumentParser()
    parts.add_part_arguments(ap)
    runs = list(range(11))
    for n in (1, 2, 3):
        shares = []
        for p in range(n):
            a = ap.parse_args(["--part", str(p), "--parts", str(n)])
            parts.check_part(ap, a)
            shares += parts.share(runs, a)
        assert sorted(shares) == runs
    for bad in (["--part", "2", "--parts", "2"], ["--part", "-1"], ["--parts", "0"]):
        with pytest.raises(SystemExit) as e:
            parts.check_part(ap, ap.parse_args(bad))
        assert e.value.code == 2
    assert "count from 0" in capsys.readouterr().err


def test_shared_frame_measures_leave_out_frames_only_one_version_answered():
    # decide.py's "shared" and paired.py --shared: a version that answers a hard frame the
    # baseline did not is not charged for it there (its coverage says so instead).
    tune, paired = load("tune"), load("paired")
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(6, 18, 3)) + np.array([0.0, 0.0, 3.0])
    base = truth + 0.01
    cand = truth + 0.01
    base[4:] = np.nan  # the baseline lost frames 4-5
    cand[4] = truth[4] + 0.5  # the candidate answered them, frame 4 badly
    s = tune.shared_measures(cand, base, truth)
    assert s["frames"] == 4 and abs(s["D"] - s["base_D"]) < 1e-9
    assert pt.accuracy(cand, truth).mean_mm > s["D"] + 50  # over its own frames it is charged
    rec = {"group": "g", "seed": 1, "motion": "m", "occ": 0, "tseed": 0,
           "default": {"D": 10.0, "swaps": 0}, "cand": {"D": 99.0, "swaps": 3,
           "shared": {"vs": "default", **s}}}  # fmt: skip
    own = paired.run_changes([rec], "default", "cand")[0]
    both = paired.run_changes([rec], "default", "cand", shared=True)[0]
    assert own["change"] == 89.0 and own["candidate_swaps"] == 3
    assert abs(both["change"]) < 1e-9 and both["candidate_swaps"] == s["swaps"]
    rec["cand"]["shared"]["vs"] = "lvm"  # measured against another variant
    with pytest.raises(SystemExit, match="no shared-frame measures against 'default'"):
        paired.run_changes([rec], "default", "cand", shared=True)


def test_suite_time_sums_each_module_and_splits_off_compilation():
    """benchmarks/suite_time.py: per-module sums of its tests, "rest" = wall - compile - trace,
    modules sorted by wall time, and the totals over all modules."""
    suite_time = load("suite_time")
    row = dict(refinements=0, outcome="passed")
    tests = {
        "tests/test_a.py::one": dict(row, compile=2.0, trace=1.0, refine=0.5, wall=5.0),
        "tests/test_a.py::two": dict(row, compile=0.0, trace=0.0, refine=0.0, wall=1.0),
        "tests/test_b.py::one": dict(row, compile=7.0, trace=0.5, refine=3.0, wall=9.0),
    }
    s = suite_time.summarise(tests)
    assert list(s["modules"]) == ["tests/test_b.py", "tests/test_a.py"]
    a = s["modules"]["tests/test_a.py"]
    assert (a["tests"], a["wall"], a["compile"], a["refine"]) == (2, 6.0, 2.0, 0.5)
    assert a["rest"] == 3.0 and s["modules"]["tests/test_b.py"]["rest"] == 1.5
    assert s["total"] == dict(compile=9.0, trace=1.5, refine=3.5, wall=15.0, rest=4.5)
