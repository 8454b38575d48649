"""The package's layering (README, "How the code is laid out"), read from the import
statements: the core never imports io, synth, detect or app; io and synth take from the core
only the modules named here."""

from __future__ import annotations

import ast
from pathlib import Path

import posetrack as pt
from posetrack.io import _export

#: The source tree (not the installed copy: the check reads the code this checkout ships).
ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "posetrack"
SUBPACKAGES = ("io", "synth", "detect", "app")
#: The core modules each subpackage may import (beside its own modules and the public API's
#: subpackages named in the README): io and synth read and write camera intrinsics, io's
#: OpenPose reader picks the person with the tracker's detection score, and both rotate with
#: the NumPy rotation module.
CORE_ALLOWED = {"io": {"_so3", "_camera", "_associate"}, "synth": {"_so3", "_camera"}}


def _imports(path: Path, package: Path = PACKAGE) -> list[str]:
    """The posetrack modules ``path`` (a file below ``package``) imports, as dotted names
    below the package (``"io._export"``, ``"_camera"``; ``"io"`` for ``from posetrack import
    io``)."""
    here = list(path.relative_to(package).parts[:-1])
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [a.name.split(".", 1)[1] for a in node.names if a.name.startswith("posetrack.")]
        elif isinstance(node, ast.ImportFrom):
            mod = [m for m in (node.module or "").split(".") if m]
            if node.level:
                base = here[: len(here) - node.level + 1]
            elif mod[:1] == ["posetrack"]:
                base, mod = [], mod[1:]
            else:
                continue
            if mod:
                out.append(".".join(base + mod))
            else:  # from . import x, y
                out += [".".join(base + [a.name]) for a in node.names]
    return out


def _layer(name: str) -> str:
    top = name.split(".")[0]
    return top if top in SUBPACKAGES else "core"


def _modules(layer: str) -> list[Path]:
    if layer == "core":
        return [p for p in PACKAGE.glob("*.py") if p.name not in ("__init__.py", "__main__.py")]
    return sorted((PACKAGE / layer).rglob("*.py"))


def test_the_import_reader_resolves_relative_and_absolute_imports(tmp_path):
    # the reader is what the layering tests stand on: a wrong resolution would pass anything
    (tmp_path / "io").mkdir()
    f = tmp_path / "io" / "_x.py"
    f.write_text(
        "from .._camera import Intrinsics\nfrom ._atomic import atomic_open\n"
        "from posetrack.synth import generate\nimport posetrack._so3\nfrom .. import app\n"
        "import numpy as np\nfrom jax import numpy\n"
    )
    assert _imports(f, tmp_path) == ["_camera", "io._atomic", "synth", "_so3", "app"]
    assert [_layer(n) for n in _imports(f, tmp_path)] == ["core", "io", "synth", "core", "app"]


def test_the_core_never_imports_io_synth_detect_or_app():
    bad = [
        f"{p.name} imports {name}"
        for p in _modules("core")
        for name in _imports(p)
        if _layer(name) != "core"
    ]
    assert not bad, bad


def test_io_and_synth_take_from_the_core_only_what_the_readme_names():
    bad = []
    for layer, allowed in CORE_ALLOWED.items():
        for p in _modules(layer):
            for name in _imports(p):
                if _layer(name) == "core" and name.split(".")[0] not in allowed:
                    bad.append(f"{layer}/{p.name} imports {name}")
                if _layer(name) in ("detect", "app"):
                    bad.append(f"{layer}/{p.name} imports {name}")
    assert not bad, bad


def test_the_joint_state_names_agree_between_the_result_and_its_file_writer():
    assert pt.JOINT_STATES == _export.JOINT_STATE_NAMES


def test_every_core_module_is_named_in_the_readme_layout_table():
    readme = (ROOT / "README.md").read_text()
    (row,) = [line for line in readme.splitlines() if line.startswith("| `posetrack/` (the core)")]
    missing = [p.stem for p in _modules("core") if f"`{p.stem}`" not in row]
    assert not missing, f"README's layout table does not name {missing}"
