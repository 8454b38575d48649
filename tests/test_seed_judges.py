"""The seed-judge look's arithmetic (benchmarks/seed_judges.py): which seed a judge picks, its
gain against a random seed and the windowed splice, on hand-made runs. No tracking."""

import numpy as np
import pytest
from test_seeds import load


@pytest.fixture(scope="module")
def sj():
    return load("seed_judges")


def _run(seed: int, tseed: int, D: float, judge: float, err=None, acc=None) -> dict:
    row = {"group": "g", "seed": seed, "occ": 0, "tseed": tseed, "D": D, "j": judge}
    if err is not None:
        row.update(err_t=list(err), acc_t=list(acc))
    return row


def test_a_judge_that_ranks_right_picks_the_oracle(sj):
    # three clips; D 40/50, 60/54, 30/30.5 for seeds 0/1
    rows = [
        _run(1, 0, 40.0, 1.0), _run(1, 1, 50.0, 2.0),
        _run(2, 0, 60.0, 3.0), _run(2, 1, 54.0, 1.0),
        _run(3, 0, 30.0, 0.5), _run(3, 1, 30.5, 0.7),
    ]  # fmt: skip
    pairs = sj._pairs(rows)
    s = sj.judge_summary(pairs, "j")
    assert s["right"] == 3 and s["big"] == 2 and s["right_big"] == 2
    # pick 40, 54, 30 against the means 45, 57, 30.25
    assert s["pick_vs_random"] == pytest.approx(np.mean([-5.0, -3.0, -0.25]))
    assert s["pick_vs_random"] == pytest.approx(s["oracle_vs_random"])
    assert s["corr"] > 0.9
    # the same judge reversed picks the worse seed every time
    for r in rows:
        r["j"] = -r["j"]
    bad = sj.judge_summary(sj._pairs(rows), "j")
    assert bad["right"] == 0 and bad["pick_vs_random"] == pytest.approx((5.0 + 3.0 + 0.25) / 3)


def test_a_run_without_its_other_seed_is_an_error_naming_it(sj):
    rows = [_run(1, 0, 40.0, 1.0), _run(1, 1, 50.0, 2.0), _run(2, 0, 60.0, 3.0)]
    with pytest.raises(SystemExit, match=r"\('g', 2, 0\).*\[0\]"):
        sj._pairs(rows)


def test_the_splice_keeps_the_calmer_seed_per_window(sj):
    T = 8
    # seed 0 right (10 mm) in the first half, apart (50 mm, shaking) in the second; seed 1
    # the other way round
    err0 = [10.0] * 4 + [50.0] * 4
    err1 = [50.0] * 4 + [10.0] * 4
    acc0 = [1.0] * 3 + [9.0] * 3  # frames 1..6
    acc1 = [9.0] * 3 + [1.0] * 3
    rows = [_run(1, 0, 30.0, 0.0, err0, acc0), _run(1, 1, 30.0, 0.0, err1, acc1)]
    assert len(err0) == T and len(acc0) == T - 2
    s = sj.splice_summary(sj._pairs(rows), 4)
    assert s["window"] == 4
    assert s["pick_vs_random"] == pytest.approx(10.0 - 30.0)
    assert s["oracle_vs_random"] == pytest.approx(10.0 - 30.0)
    # one window over the whole clip cannot splice: both seeds accelerate alike on average
    whole = sj.splice_summary(sj._pairs(rows), T)
    assert whole["pick_vs_random"] == pytest.approx(0.0)
