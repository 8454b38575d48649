"""The notebooks in notebooks/ run top to bottom and say what they should.

Each notebook is executed with nbclient in a kernel running this interpreter (a kernel spec
pointing at ``sys.executable`` is written into a temporary JUPYTER_PATH, so a fresh venv with
the test extra works without ``ipykernel install``). Any cell error fails the test. The last
cell of each notebook prints one ``RESULT key=value ...`` line, which the test parses and
checks (accuracy against naive lifting, eager vs jit, files read back, ...).

The kernels use the test session's program cache (``POSETRACK_CACHE_DIR``, set by conftest;
each notebook calls ``posetrack.enable_cache()``), so a configuration that an earlier test or
notebook compiled loads instead of compiling again; with the cache off they share a temporary
one. Nothing is written into the repository.

The notebooks are committed WITH their outputs (``notebooks/execute.py`` runs them in place), so
a reader on GitHub sees the pictures; the committed RESULT line must pass the same checks as a
fresh run.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = ("01_quick_start.ipynb", "02_mht_vs_lvm.ipynb", "03_your_own_data.ipynb")
KERNEL_NAME = "posetrack-test-python"

nbformat = pytest.importorskip(
    "nbformat", reason="notebook tests need nbformat, nbclient and ipykernel (the test extra)"
)


def test_notebooks_are_numbered_and_listed():
    found = sorted(p.name for p in NOTEBOOK_DIR.glob("*.ipynb"))
    assert found == sorted(NOTEBOOKS), f"notebooks/ holds {found}; update NOTEBOOKS"
    for name in found:
        assert re.fullmatch(r"\d\d_[a-z0-9_]+\.ipynb", name), name


def result_line(nb, name: str) -> dict[str, str]:
    """The key=value pairs of the one ``RESULT`` line a notebook's outputs print."""
    text = "".join(
        out.get("text", "")
        for cell in nb.cells
        if cell.cell_type == "code"
        for out in cell.outputs
        if out.output_type == "stream" and out.get("name") == "stdout"
    )
    lines = [line for line in text.splitlines() if line.startswith("RESULT ")]
    assert len(lines) == 1, f"{name}: expected one RESULT line, got {lines}"
    return dict(item.split("=", 1) for item in lines[0].split()[1:])


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_is_committed_with_its_outputs(name):
    """A reader on GitHub sees the pictures: every code cell ran, in order, without error, and
    what the committed outputs say passes the same checks as a fresh run (below). Refresh them
    with ``python notebooks/execute.py`` after changing a notebook."""
    nb = nbformat.read(NOTEBOOK_DIR / name, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code[0].source.startswith("# Parameters"), f"{name}: first code cell is not Parameters"
    counts = [c.execution_count for c in code]
    assert counts == list(range(1, len(code) + 1)), f"{name}: not run top to bottom: {counts}"
    kinds = [out.output_type for c in code for out in c.outputs]
    assert "error" not in kinds, f"{name}: a committed cell failed"
    images = [
        o for c in code for o in c.outputs if any(k.startswith("image/") for k in o.get("data", {}))
    ]
    assert images, f"{name}: no pictures in the committed outputs"
    CHECKS[name](result_line(nb, name))


@pytest.fixture(scope="module")
def kernel(tmp_path_factory):
    """Name of a kernel spec that runs ``sys.executable``, in a temporary JUPYTER_PATH."""
    pytest.importorskip("nbclient", reason="notebook tests need nbclient (the test extra)")
    pytest.importorskip("ipykernel", reason="notebook tests need ipykernel (the test extra)")
    root = tmp_path_factory.mktemp("jupyter")
    from posetrack import _programs

    store = _programs.cache_dir()  # the session's (conftest), None when off
    cache = str(root / "posetrack-cache" if store is None else store.parent)
    spec_dir = root / "data" / "kernels" / KERNEL_NAME
    spec_dir.mkdir(parents=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "posetrack tests",
        "language": "python",
        "env": {
            "POSETRACK_CACHE_DIR": cache,
            "JAX_NUMPY_RANK_PROMOTION": "raise",  # as tests/conftest.py
            "IPYTHONDIR": str(root / "ipython"),
        },
    }
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JUPYTER_PATH", str(root / "data"))
        mp.setenv("JUPYTER_RUNTIME_DIR", str(root / "runtime"))
        mp.setenv("IPYTHONDIR", str(root / "ipython"))
        yield KERNEL_NAME


def run_notebook(name: str, kernel_name: str, workdir: Path) -> dict[str, str]:
    """Execute a notebook; return the key=value pairs of its ``RESULT`` line."""
    import nbclient

    nb = nbformat.read(NOTEBOOK_DIR / name, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        kernel_name=kernel_name,
        timeout=600,
        startup_timeout=120,
        resources={"metadata": {"path": str(workdir)}},
    )
    before = sorted(NOTEBOOK_DIR.iterdir())
    client.execute()  # raises CellExecutionError (with the cell's traceback) on any error
    assert sorted(NOTEBOOK_DIR.iterdir()) == before, f"{name} wrote into {NOTEBOOK_DIR}"
    return result_line(nb, name)


def check_01(r: dict[str, str]) -> None:
    D, naive = float(r["D_mm"]), float(r["naive_mm"])
    assert float(r["coverage"]) == 1.0
    assert D < 0.8 * naive, r  # the tracker beats lifting each keypoint on its own
    assert D < 80.0, r
    assert float(r["jit_vs_eager"]) < 1e-3, r  # same fit with and without jit
    assert float(r["vmap_vs_single"]) < 1e-3, r  # hypothesis 0 of the vmap = the single fit
    assert int(r["tracked"]) >= 0.8 * int(r["frames"]), r


def check_02(r: dict[str, str]) -> None:
    # The Delta maps drawn in the notebook are the tracker's Eq. (3), recomputed by hand from
    # public functions. If this fails, the tracker's scoring changed: update section 3 of 02.
    assert float(r["delta_match"]) < 1e-3, r
    # Both trackers beat naive lifting, averaged over the occlusion levels.
    naive = [float(v) for v in r["naive_mm"].split(",")]
    for method in ("lvm_mm", "mht_mm"):
        D = [float(v) for v in r[method].split(",")]
        assert len(D) == len(naive) >= 2, r
        assert sum(D) < sum(naive), (method, r)


def check_03(r: dict[str, str]) -> None:
    D, naive = float(r["D_mm"]), float(r["naive_mm"])
    assert D < 0.8 * naive, r
    # Tracking the files gives what tracking the arrays gives.
    assert abs(D - float(r["D_memory_mm"])) < 1.0, r
    # The BVH read back reproduces the saved 3D keypoints (forward kinematics, in mm).
    assert float(r["bvh_vs_npz_mm"]) < 1.0, r
    assert int(r["json_files"]) == int(r["frames"]), r
    files = "keypoints3d,markers.trc,motion.bvh,overlay.mp4,poses.npz,summary.json"
    assert r["files"] == files, r


CHECKS = dict(zip(NOTEBOOKS, (check_01, check_02, check_03), strict=True))


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_runs_and_says_what_it_should(kernel, tmp_path, name):
    CHECKS[name](run_notebook(name, kernel, tmp_path))
