"""Shared test set-up.

Rank promotion raises (catches silent broadcasting bugs). Tests that need float64 precision
(finite differences, references) enable x64 inside their own module via the `x64` fixture or
compute in NumPy; the library itself runs in float32 where it casts explicitly.
"""

import dataclasses
import os
from pathlib import Path

import jax
import pytest

import posetrack

jax.config.update("jax_numpy_rank_promotion", "raise")


def pytest_configure(config):
    """Keep JAX's persistent compilation cache inside pytest's own cache folder.

    The command-line tests call ``posetrack``'s ``main()`` in-process, which turns on the
    persistent cache (``~/.cache/posetrack/jax`` by default) for the rest of the session; tests
    must not write into the user's home. Here the cache goes to ``.pytest_cache/d/posetrack-jax``
    (git-ignored; ``pytest --cache-clear`` empties it) and is on from the first test, so a second
    local run reuses the compiled programs. ``-p no:cacheprovider`` runs without one. A
    ``POSETRACK_CACHE_DIR`` set by the user wins.
    """
    if "POSETRACK_CACHE_DIR" in os.environ:
        path = os.environ["POSETRACK_CACHE_DIR"]
    elif getattr(config, "cache", None) is not None:
        path = str(config.cache.mkdir("posetrack-jax"))
    else:
        path = "off"
    os.environ["POSETRACK_CACHE_DIR"] = path
    posetrack.enable_cache()  # what the command line does, now for every test


_DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
DATA_ROOT = Path(os.environ.get("POSETRACK_DATA", _DEFAULT_DATA)).resolve()


@pytest.fixture
def x64():
    """Run a test with float64 enabled, restoring the previous setting afterwards."""
    prev = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", prev)


def require_data(sub: str) -> Path:
    """Path of a data set under ../shared/data, or skip the test saying which folder is absent."""
    path = DATA_ROOT / sub
    if not path.exists():
        pytest.skip(f"real data not available: {path} is absent (set POSETRACK_DATA)")
    return path


#: Adam steps of :func:`quick_refine` (the tracker's own: 100).
QUICK_REFINE_STEPS = 20


def quick_refine(mode: str = "offline", **changes) -> posetrack.ShapeFitSettings:
    """The tracker's body-shape refinement in ``mode`` (``ShapeFitSettings.tracking``) with
    :data:`QUICK_REFINE_STEPS` Adam steps, for tests whose runs pass through the refinement
    but test something else (when it runs, on which frames, what follows from it): the same
    code path at a fifth of the steps (~0.5 s instead of ~2.5 s a run on 2 cores). Every such
    test shares one compiled program per mode (``changes`` to the schedule, such as
    ``offline_first`` or ``online_after``, are the tracker's, not the program's). Tests of what
    the refinement finds use the tracker's own settings."""
    base = posetrack.ShapeFitSettings.tracking(mode)
    return dataclasses.replace(base, steps=QUICK_REFINE_STEPS, **changes)
