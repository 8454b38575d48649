"""Dividing a benchmark's runs between processes: ``--part P --parts N``.

Parts count from 0: with ``--parts 2`` the two processes are ``--part 0`` and ``--part 1``,
and process ``P`` takes every ``N``-th run from run ``P`` on. A part outside ``0 .. N-1`` is a
command-line error rather than a share: ``--part 1 --part 2`` of ``--parts 2`` once ran
every run but the first and nobody noticed until the records were counted (2026-12-04).

Plain Python, no imports: benchmarks import it as ``from parts import ...`` (run as scripts,
their folder is on ``sys.path``); tests load it by path.
"""


def add_part_arguments(ap) -> None:
    """``--part`` and ``--parts`` on an ``argparse`` parser."""
    ap.add_argument(
        "--part", type=int, default=0,
        help="this process's share of the runs, counting from 0 (0 .. PARTS-1; default 0)",
    )  # fmt: skip
    ap.add_argument("--parts", type=int, default=1, help="processes sharing the runs (default 1)")


def check_part(ap, a) -> None:
    """A command-line error (``ap.error``, exit status 2) unless ``1 <= a.parts`` and
    ``0 <= a.part < a.parts``."""
    if a.parts < 1:
        ap.error(f"--parts must be at least 1, got {a.parts}")
    if not 0 <= a.part < a.parts:
        ap.error(
            f"--part {a.part} with --parts {a.parts}: parts count from 0, so --part is one of "
            f"0 .. {a.parts - 1}"
        )


def share(items, a) -> list:
    """This process's runs of ``items``: every ``a.parts``-th from ``a.part`` on."""
    return list(items)[a.part :: a.parts]
