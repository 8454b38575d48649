"""The seed ranges of the tuning protocol: what is reported, what is tuned on, what tests use.

A default of the tracker may be chosen by looking at ``TUNING_SEEDS`` only; ``REPORT_SEEDS``
are what ``accuracy.py`` reports and ``TEST_SEEDS`` what the test suite asserts on, so a
number in the README is never measured on the sequences a default was picked on. The three
ranges are disjoint (checked on import). See benchmarks/README.md, "Tuning protocol".

A seed of ``posetrack.synth.generate`` fixes everything random in a generated sequence (the
subject's body, the room, sensor noise, the detector's misses, outliers and left/right swaps,
the occluders); the motion and the occlusion level are separate arguments.

Plain Python, no imports: benchmarks import it as ``from seeds import ...`` (run as scripts,
their folder is on ``sys.path``); tests load it by path.
"""

#: Reported by ``accuracy.py``: the i-th clip gets seed ``REPORT_SEEDS[i]`` (0-17 today).
REPORT_SEEDS = range(0, 100)

#: The only seeds ``tune.py`` and ``decide.py`` evaluate; the shipped defaults were tuned on
#: 100-102. Widened on 2026-12-02 by 1000-1999 when every seed of 100-199 had been used by
#: some decision (a decision should look at clips no earlier decision looked at), and on
#: 2026-12-05 by 2000-9999 when 1000-1983 had been (screens sized for rare events and seed-
#: pooled screens take hundreds of fresh clips).
TUNING_SEEDS = (*range(100, 200), *range(1000, 10000))

#: ``TUNING_SEEDS`` in words, for messages.
TUNING_TEXT = "100-199, 1000-9999"

#: Seeds the test suite's accuracy assertions use (``tests/test_paper_claim.py``: 500-507).
TEST_SEEDS = range(500, 600)

RANGES = {"REPORT_SEEDS": REPORT_SEEDS, "TUNING_SEEDS": TUNING_SEEDS, "TEST_SEEDS": TEST_SEEDS}


def parse_seeds(text: str) -> list[int]:
    """Seeds from a command line: ``"100-111"``, ``"131"`` or ``"100,104,110-112"``."""
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def check_disjoint() -> None:
    """Raise ``ValueError`` naming the two ranges that share a seed, if any do."""
    names = list(RANGES)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            shared = set(RANGES[a]) & set(RANGES[b])
            if shared:
                raise ValueError(f"seed ranges {a} and {b} overlap: {sorted(shared)[:5]} ...")


check_disjoint()
