"""The compiled-program store (``posetrack._programs``): what a warm start reads from disk.

A stored program must give the same numbers bit for bit, must never be reused for anything that
changes the program (structure, static settings, code, library versions), must survive bad files,
and must be built once even when a background thread and a caller ask for it together. The
functions here are tiny, so these tests compile in milliseconds; ``test_tracker_poses_*`` runs the
real tracker on a short clip.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import threading
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import posetrack as pt
from posetrack import _programs
from posetrack._programs import Program


@pytest.fixture
def store(tmp_path):
    """The store in a fresh folder for one test; restored afterwards."""
    saved = _programs.cache_dir()
    saved_cfg = jax.config.jax_compilation_cache_dir
    root = pt.enable_cache(tmp_path / "cache")
    yield root / "programs"
    _programs._store["dir"] = saved
    jax.config.update("jax_compilation_cache_dir", saved_cfg)


@dataclasses.dataclass(frozen=True)
class Scale:
    factor: float


def _affine(settings: Scale, x, y):
    return {"sum": jnp.sin(x) * settings.factor + y, "n": jnp.sum(x > 0)}


def _fresh(name: str, fn=_affine) -> Program:
    return Program(fn, name, static_argnums=(0,))


def test_stored_program_is_reused_across_instances_and_gives_the_same_bits(store):
    x, y = jnp.linspace(-1.0, 1.0, 7), jnp.float32(0.5)
    first = _fresh("affine")
    out1 = first(Scale(2.0), x, y)
    assert [e.source for e in _programs.log() if e.name == "affine"][-1] == "stored now"
    assert len(list(store.glob("affine-*.jaxprog"))) == 1
    second = _fresh("affine")  # a new process would start like this: nothing in memory
    out2 = second(Scale(2.0), x, y)
    assert [e.source for e in _programs.log() if e.name == "affine"][-1] == "stored"
    plain = jax.jit(_affine, static_argnums=0)(Scale(2.0), x, y)
    for a, b in ((out1, out2), (out1, plain)):
        assert np.array_equal(np.asarray(a["sum"]), np.asarray(b["sum"]))
        assert int(a["n"]) == int(b["n"])


class _Gains(eqx.Module):
    weight: float  # a Python scalar leaf, as TrackerConfig's floats
    offset: jax.Array


def _gained(g: _Gains, x):
    return g.weight * x + g.offset


def test_arguments_kept_by_identity_are_never_stale():
    # A Program keeps small immutable modules flattened (found again by identity) and reads
    # everything else afresh: results must equal jax.jit's on every call, a NumPy array
    # changed in place included, and the kept arguments stay bounded.
    prog = Program(_gained, "gained")
    plain = jax.jit(_gained)
    g = _Gains(weight=0.5, offset=jnp.arange(3.0))
    x = np.ones(3, np.float32)
    for k in range(3):
        x[:] = k  # same NumPy object, new values
        np.testing.assert_array_equal(np.asarray(prog(g, x)), np.asarray(plain(g, x)))
    other = _Gains(weight=2.0, offset=jnp.zeros(3))  # a new module: its own values
    np.testing.assert_array_equal(np.asarray(prog(other, x)), np.asarray(plain(other, x)))
    assert id(g) in prog._args and prog._cache_size() == 1  # kept, one compiled program
    for k in range(3 * _programs._ARGS_KEPT):
        prog(_Gains(weight=float(k), offset=jnp.ones(3)), x)
    assert len(prog._args) <= _programs._ARGS_KEPT
    big = _Gains(weight=1.0, offset=jnp.zeros(_programs._ARG_SIZE_KEPT + 1))
    prog(big, np.ones(_programs._ARG_SIZE_KEPT + 1, np.float32))
    assert id(big) not in prog._args  # a depth-map-sized argument is not held


def test_anything_that_changes_the_program_gets_a_new_file(store, monkeypatch):
    x, y = jnp.linspace(-1.0, 1.0, 7), jnp.float32(0.5)
    _fresh("keys")(Scale(2.0), x, y)
    _fresh("keys")(Scale(3.0), x, y)  # static setting
    _fresh("keys")(Scale(2.0), jnp.linspace(-1.0, 1.0, 8), y)  # shape
    _fresh("keys")(Scale(2.0), x.astype(jnp.int32), y)  # dtype
    assert len(list(store.glob("keys-*.jaxprog"))) == 4
    # A new JAX (or posetrack source, or equinox...) never reads an old program.
    monkeypatch.setattr(_programs, "environment_key", lambda: "another jax version")
    prog = _fresh("keys")
    out = prog(Scale(2.0), x, y)
    assert _programs.log()[-1].source == "stored now"
    assert len(list(store.glob("keys-*.jaxprog"))) == 5
    assert np.allclose(out["sum"], jnp.sin(x) * 2.0 + 0.5)


def test_environment_key_covers_code_and_versions():
    key = _programs.environment_key()
    _programs.environment_key.cache_clear()
    try:
        assert _programs.environment_key() == key  # deterministic
    finally:
        _programs.environment_key.cache_clear()


def test_a_corrupt_or_foreign_file_is_ignored_and_rewritten(store):
    x, y = jnp.arange(3.0), jnp.float32(1.0)
    _fresh("corrupt")(Scale(1.0), x, y)
    (path,) = store.glob("corrupt-*.jaxprog")
    path.write_bytes(b"not a program")
    out = _fresh("corrupt")(Scale(1.0), x, y)
    assert _programs.log()[-1].source == "stored now"
    assert np.allclose(out["sum"], jnp.sin(x) + 1.0)
    assert path.read_bytes() != b"not a program"
    assert not list(store.glob(".tmp-*"))  # no half-written leftovers


def test_the_serialiser_of_the_store_is_installed():
    """jax.export imports ``flatbuffers`` to serialise and jax does not require it: a fresh
    install without it traced every program again on each start (14 s warm instead of 2)."""
    import flatbuffers  # noqa: F401  (a posetrack dependency for this reason)

    exported = jax.export.export(jax.jit(jnp.sin))(jax.ShapeDtypeStruct((2,), jnp.float32))
    assert jax.export.deserialize(exported.serialize()).call(jnp.ones(2)).shape == (2,)


def test_a_store_that_cannot_serialise_says_so_once_and_still_computes(store, monkeypatch):
    def missing(self, *args, **kwargs):
        raise ImportError("Please install 'flatbuffers' in order to use Exported serialization")

    monkeypatch.setattr(jax.export.Exported, "serialize", missing)
    monkeypatch.setattr(_programs, "_STORE_WARNED", threading.Event())
    x, y = jnp.arange(3.0), jnp.float32(1.0)
    with pytest.warns(RuntimeWarning, match="flatbuffers"):
        out = _fresh("unserialisable")(Scale(1.0), x, y)
    assert _programs.log()[-1].source == "jit"
    assert np.allclose(out["sum"], jnp.sin(x) + 1.0)
    assert not list(store.glob("unserialisable-*")) and not list(store.glob(".tmp-*"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the second program is not warned about again
        _fresh("unserialisable2")(Scale(1.0), x, y)


@pytest.mark.parametrize(
    "seed", [0, 1, 7, 2**31 - 1, 2**31, 2**32 - 1, 2**32 + 5, 2**62, -1, -(2**40), np.int64(9)]
)
def test_a_key_made_on_the_host_is_jaxs_key(seed):
    a, b = jax.random.PRNGKey(seed), _programs.device_key(seed)
    assert np.array_equal(np.asarray(a), np.asarray(b))
    assert (a.shape, a.dtype, a.weak_type) == (b.shape, b.dtype, b.weak_type)


def test_without_a_store_nothing_is_written(tmp_path):
    saved = _programs.cache_dir()
    _programs._store["dir"] = None
    try:
        out = _fresh("nostore")(Scale(1.0), jnp.arange(3.0), jnp.float32(0.0))
        assert _programs.log()[-1].source == "jit"
        assert np.allclose(out["sum"], jnp.sin(jnp.arange(3.0)))
    finally:
        _programs._store["dir"] = saved
    assert pt.enable_cache("off") is None and _programs.cache_dir() is None
    _programs._store["dir"] = saved


def test_background_preparation_builds_once(store):
    """A caller that needs the program while a thread builds it waits instead of building it
    again (the tracker's first frame and its background compile)."""
    calls = []

    def slow(settings, x, y):
        calls.append(1)  # once per trace
        time.sleep(0.3)
        return _affine(settings, x, y)

    prog = _fresh("slow", slow)
    x, y = jnp.arange(4.0), jnp.float32(2.0)
    prog.prepare(Scale(1.0), jax.ShapeDtypeStruct((4,), jnp.float32), y, background=True)
    results = []
    threads = [threading.Thread(target=lambda: results.append(prog(Scale(1.0), x, y)))
               for _ in range(3)]  # fmt: skip
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and prog._cache_size() == 1
    assert all(np.allclose(r["sum"], jnp.sin(x) + 2.0) for r in results)
    prog.wait_traced(Scale(1.0), x, y, timeout=1.0)  # already traced: returns at once


def test_a_failing_build_raises_where_the_program_is_needed(store):
    def broken(settings, x, y):
        raise ValueError("broken on purpose")

    prog = _fresh("broken", broken)
    prog.prepare(Scale(1.0), jnp.arange(2.0), jnp.float32(0.0), background=True)
    with pytest.raises(ValueError, match="broken on purpose"):
        prog(Scale(1.0), jnp.arange(2.0), jnp.float32(0.0))


@pytest.fixture(scope="module")
def clip():
    return pt.synth.generate(11, n_frames=8, occlusion_level=1)


def test_tracker_poses_are_the_same_with_and_without_the_store(clip, tmp_path):
    """The shipped tracker from stored programs (a warm start) gives the poses of a plain
    start, bit for bit. Runs the real step: its first build here is the compile of the test."""
    config = pt.TrackerConfig.paper("mht_h", num_hypotheses=3)

    def run():
        return pt.track(
            clip.depth, clip.keypoints2d, clip.confidence, clip.intrinsics, config,
            mode="per-frame",
        ).keypoints3d  # fmt: skip

    from posetrack import _chunk, _tracker

    saved = (_programs.cache_dir(), jax.config.jax_compilation_cache_dir)
    try:
        pt.enable_cache(tmp_path / "c")
        first = run()  # traces, stores
        _chunk.step_chunk._ready.clear()  # forget what is in memory: read back from the store
        _tracker.lift._ready.clear()
        _tracker.initial_fit._ready.clear()
        second = run()
        assert {e.source for e in _programs.log()[-3:]} == {"stored"}
    finally:
        _programs._store["dir"] = saved[0]
        jax.config.update("jax_compilation_cache_dir", saved[1])
    assert np.array_equal(first, second, equal_nan=True)


_EXIT_WHILE_BUILDING = """
import jax, jax.numpy as jnp
import posetrack as pt
from posetrack._programs import Program

pt.enable_cache("off")

def heavy(x):  # ~1-2 s of XLA compilation on a CPU
    for i in range(100):
        x = jnp.tanh(x @ x.T * 1e-3 + i)[:, ::-1] + jnp.cumsum(x, axis=i % 2)
    return x

arg = jax.ShapeDtypeStruct((16, 16), jnp.float32)
prog = Program(heavy, "exit_while_building")
prog.prepare(arg, background=True)
prog.wait_traced(arg)  # the builder is inside XLA now
print("leaving", flush=True)
"""


def test_leaving_while_a_program_builds_exits_cleanly():
    """A process that ends while a background builder is compiling (an online run shorter
    than the frames before its body-shape refinement; an error in the first frames) exits
    with its own status: it used to abort ("terminate called ...", 134) once XLA returned
    into a finalising interpreter."""
    proc = subprocess.run(
        [sys.executable, "-c", _EXIT_WHILE_BUILDING], capture_output=True, text=True,
        timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "leaving" and "terminate called" not in proc.stderr
