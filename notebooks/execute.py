"""Run the notebooks top to bottom and save them WITH their outputs (what GitHub shows).

Usage, from the repository root, in an environment with the ``test`` extra (nbclient,
ipykernel, matplotlib)::

    python notebooks/execute.py                  # all of them
    python notebooks/execute.py 02_mht_vs_lvm    # one

Each notebook runs in a kernel of this interpreter, in a temporary working folder (nothing is
written next to the notebooks), and is written back only if every cell succeeded. Timing
metadata is not recorded, so a re-run changes only what the cells print. The test suite
(``tests/test_notebooks.py``) checks the committed outputs and runs the notebooks again.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import nbclient
import nbformat

HERE = Path(__file__).resolve().parent


def execute(path: Path) -> None:
    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory(prefix="posetrack-nb-") as work:
        client = nbclient.NotebookClient(
            nb, kernel_name="python3", timeout=900, record_timing=False,
            resources={"metadata": {"path": work}},
        )  # fmt: skip
        client.execute()  # raises CellExecutionError (with the traceback) on any error
    nb.metadata.pop("widgets", None)
    nbformat.validate(nb)
    tmp = path.with_name(f".{path.name}.tmp")
    nbformat.write(nb, tmp)
    tmp.replace(path)  # a failed or interrupted run leaves the committed notebook as it was


def main(names: list[str]) -> int:
    paths = [HERE / (n if n.endswith(".ipynb") else f"{n}.ipynb") for n in names]
    paths = paths or sorted(HERE.glob("[0-9][0-9]_*.ipynb"))
    for path in paths:
        if not path.is_file():
            print(f"error: {path}: no such notebook", file=sys.stderr)
            return 2
    for path in paths:
        print(f"running {path.name} ...", file=sys.stderr, flush=True)
        execute(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
