"""Shared test set-up.

Rank promotion raises (catches silent broadcasting bugs). Tests that need float64 precision
(finite differences, references) enable x64 inside their own module via the `x64` fixture or
compute in NumPy; the library itself runs in float32 where it casts explicitly.
"""

import os
from pathlib import Path

import jax
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")

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
