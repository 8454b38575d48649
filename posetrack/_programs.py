"""Compiled programs that outlive the process: the tracker's jitted functions, kept on disk.

JAX's persistent compilation cache saves XLA's compilation, but a new process still traces the
Python (optimistix' solver loops, the renderer) and lowers it before it can look the program
up: about 5 s of the tracker's warm start. A :class:`Program` also keeps the traced program, as
a ``jax.export`` artefact (StableHLO), so a warm start goes from the file straight to the
compilation cache.

**Keys.** A stored program is used only if everything that went into it is the same: the
function, the input structure (shapes, dtypes, static settings: a :class:`TrackerConfig`'s
static fields are part of its structure), the source of every ``posetrack`` core module, the
versions of jax, jaxlib, equinox, optimistix and lineax, the backend and device kind and the x64
switch. Anything else is a new key (a new file); a file that cannot be read is ignored and
rewritten. Whether a compiled executable fits this machine and its XLA options is decided by
JAX's own cache, as for any jitted function. The stored program is the StableHLO the function
lowers to, so the poses are the same bit for bit (``tests/test_programs.py``).

(Storing the XLA executables themselves, ``jax.experimental.serialize_executable``, would save
another 0.5 s; loading one in a thread while another program ran crashed the process.)

**Ahead of time.** :meth:`Program.prepare` builds the program for abstract inputs
(``jax.ShapeDtypeStruct``), optionally in a background thread: ``Tracker`` starts the step's
compilation while the body shape is estimated and the track initialised.

The store is off until :func:`enable_cache` names a folder (the command line does so; see the
README). Off, a :class:`Program` is an ahead-of-time compiled ``jax.jit``.
"""

from __future__ import annotations

import atexit
import collections
import concurrent.futures
import contextlib
import copyreg
import dataclasses
import functools
import hashlib
import importlib.metadata
import os
import pickle
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

#: Bump when the file layout changes.
_FORMAT = 1

_CORE = Path(__file__).resolve().parent

_store: dict[str, Path | None] = {"dir": None}
#: Set once the user was told that programs cannot be stored (a missing module).
_STORE_WARNED = threading.Event()


@dataclasses.dataclass(frozen=True)
class ProgramEvent:
    """How one program was made ready (``log()``; the start-up benchmark reads it)."""

    name: str
    source: str
    """"stored" (read from the store), "stored now" (traced and compiled, then written to the
    store) or "jit" (traced and compiled; no store, or it could not be written)."""
    trace_s: float
    """Tracing and lowering, or reading the stored program."""
    compile_s: float
    """XLA compilation, or loading it from JAX's compilation cache."""
    done: float = 0.0
    """``time.time()`` when it was ready."""


_log: list[ProgramEvent] = []

# Runs of programs from several threads at once (track_many's workers) go one at a time: two
# big vmapped programs executing together on XLA's CPU thread pool were seen to hang here,
# a known wedge of that pool (PyAutoFit issue 1530; jax issue 25861).
_serial = {"depth": 0}
_serial_lock = threading.Lock()
_run_lock = threading.Lock()


@contextlib.contextmanager
def serial_execution():
    """Within this block, every :class:`Program` run waits for the previous one to finish
    (whatever thread started it) and returns finished results."""
    with _serial_lock:
        _serial["depth"] += 1
    try:
        yield
    finally:
        with _serial_lock:
            _serial["depth"] -= 1


def device_f32(x) -> jax.Array:
    """``x`` as a float32 JAX array, converted on the host and copied to the device: the values
    of ``jnp.asarray(x, float32)`` without an eager conversion, which JAX compiles (or, warm,
    loads from the cache) as a small program per input type: on a cold start each such
    compilation waits behind the big programs compiling in the background."""
    return jax.device_put(np.asarray(x, np.float32))


def device_key(seed) -> jax.Array:
    """``jax.random.PRNGKey(seed)``, made on the host where its bits are known (the default
    threefry implementation, 32-bit mode: ``[0, seed mod 2**32]``): the eager op is a small
    program, compiled on a cold start before the tracker's programs can start, loaded from
    the cache warm (~0.1 s). Anything else is left to JAX."""
    if (
        isinstance(seed, (int, np.integer))
        and not isinstance(seed, bool)
        and -(2**63) <= int(seed) < 2**63
        and not jax.config.jax_enable_x64
        and str(jax.config.jax_default_prng_impl) == "threefry2x32"
    ):
        return jax.device_put(np.array([0, int(seed) % 2**32], np.uint32))
    return jax.random.PRNGKey(seed)


def log() -> list[ProgramEvent]:
    """Every program made ready in this process, in order."""
    return list(_log)


def enable_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Keep compiled programs on disk: JAX's compilation cache in ``path/jax``, the traced
    programs in ``path/programs``. A warm start (a new process after one that ran the same
    configuration) then takes seconds instead of tens of seconds.

    Args:
        path: the folder; default ``$POSETRACK_CACHE_DIR`` or ``~/.cache/posetrack``.
            ``"off"`` turns both caches off.

    Returns:
        The folder in use, or ``None`` when off or not writable (then nothing is cached and
        nothing fails).
    """
    if path is None:
        path = os.environ.get(
            "POSETRACK_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "posetrack")
        )
    path = os.fspath(path)
    if path.lower() in ("off", "none", "0", ""):
        _store["dir"] = None
        return None
    root = Path(path)
    try:
        (root / "jax").mkdir(parents=True, exist_ok=True)
        (root / "programs").mkdir(parents=True, exist_ok=True)
    except OSError:
        _store["dir"] = None
        return None  # read-only home: run without a cache
    jax.config.update("jax_compilation_cache_dir", str(root / "jax"))
    # Every program, however small: a warm start should compile nothing.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _store["dir"] = root / "programs"
    return root


def cache_dir() -> Path | None:
    """The folder of the stored programs (``None``: the store is off)."""
    return _store["dir"]


@functools.cache
def environment_key() -> str:
    """Everything outside a program's arguments that decides what it compiles to."""
    h = hashlib.sha256()
    for f in sorted(_CORE.glob("*.py")):  # the core modules (the app layer is never traced)
        h.update(f.name.encode())
        h.update(f.read_bytes())
    for pkg in ("jax", "jaxlib", "equinox", "optimistix", "lineax"):
        try:
            version = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            version = "?"
        h.update(f"{pkg}={version};".encode())
    device = jax.devices()[0]
    h.update(
        f"{jax.default_backend()};{device.device_kind};{device.client.platform_version};"
        f"x64={jax.config.jax_enable_x64};format={_FORMAT}".encode()
    )
    return h.hexdigest()


#: Arguments a :class:`Program` keeps flattened, per program (the most recently used).
_ARGS_KEPT = 16
#: ... if they hold at most this many numbers (a tracker state, not a depth map).
_ARG_SIZE_KEPT = 1 << 16


def _on_device(x, aval: jax.ShapeDtypeStruct):
    """A Python scalar as the device array the program would make of it (same dtype and weak
    type), so it is not transferred again every call; arrays unchanged."""
    if isinstance(x, jax.Array):
        return x
    d = jax.device_put(x)
    return d if _aval(d) == aval else x


def _aval(x) -> jax.ShapeDtypeStruct:
    if isinstance(x, jax.ShapeDtypeStruct):
        return x
    a = jax.typeof(x)
    return jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type)


def _register_sentinels() -> None:
    """Let equinox's "missing field" sentinel pickle as itself (it appears in the structure of
    every equinox module; a copy would compare unequal and the program would never be found).
    If equinox moves it, stored programs fail their round-trip check and are not written."""
    try:
        from equinox._module._flatten import MISSING
    except ImportError:  # pragma: no cover - depends on equinox internals
        return
    copyreg.pickle(type(MISSING), lambda _: "MISSING")


_register_sentinels()


#: XLA options on CPU. LLVM's -O1 instead of -O3 cut the tracker step's compilation by about a
#: fifth with the same per-frame time and the same poses bit for bit (``benchmarks/startup.py``,
#: ``tests/test_programs.py``).
CPU_OPTIONS = {"xla_backend_optimization_level": 1}
#: For programs that run a handful of times per recording (lifting for the body shape, the
#: initialisation fit) or take well under a millisecond a frame (the online motion model):
#: XLA's older loop emitters compile in half the time and run a little slower (the tracker
#: step 15 %: ``benchmarks/compile_options.py``; it keeps the default), which costs
#: milliseconds.
CPU_OPTIONS_RARE = {**CPU_OPTIONS, "xla_cpu_use_fusion_emitters": False}


def compiler_options(rare: bool) -> dict | None:
    """The XLA options a :class:`Program` compiles with on this backend (none off CPU)."""
    if jax.default_backend() != "cpu":
        return None
    return dict(CPU_OPTIONS_RARE if rare else CPU_OPTIONS)


class Program:
    """A jitted function compiled once per input structure, kept on disk when the store is on.

    Call it like the function (``static_argnums`` as for ``jax.jit``: hashable arguments with
    a stable ``repr``, part of the key). One instance is shared by every caller, so a
    configuration compiles once per process. ``rare``: the program runs a few times per
    recording, or costs next to nothing when it runs, so it compiles for compile time
    (:data:`CPU_OPTIONS_RARE`).
    """

    def __init__(
        self, fn: Callable, name: str, *, static_argnums: Sequence[int] = (), rare: bool = False
    ):
        self.fn = fn
        self.name = name
        self.static_argnums = tuple(static_argnums)
        self.rare = rare
        self._ready: dict = {}
        self._pending: dict = {}
        self._lowered: dict = {}
        self._lock = threading.Lock()
        self._args: collections.OrderedDict = collections.OrderedDict()
        functools.update_wrapper(self, fn)

    def _signature(self, args):
        static = tuple(args[i] for i in self.static_argnums)
        parts = [self._dynamic(a) for i, a in enumerate(args) if i not in self.static_argnums]
        tree = tuple(p[0] for p in parts)
        leaves = [x for p in parts for x in p[1]]
        avals = tuple(a for p in parts for a in p[2])
        sig = (tree, static, tuple((a.shape, a.dtype, a.weak_type) for a in avals))
        return sig, static, leaves, tree, avals

    def _dynamic(self, arg) -> tuple:
        """``(treedef, leaves, avals)`` of one argument. A small equinox module whose leaves
        are all JAX arrays or Python scalars is immutable: it is flattened once, its scalars
        put on the device once (a tracker passes the same configuration, body shape and
        camera every frame: 0.3 ms and 15 transfers a step saved), and found again by
        identity. Anything else, e.g. a NumPy array that may change in place, or a depth map
        (not to be held), is read afresh every call."""
        with self._lock:
            hit = self._args.get(id(arg))
            if hit is not None and hit[0] is arg:
                self._args.move_to_end(id(arg))
                return hit[1:]
        leaves, tree = jax.tree.flatten(arg)
        avals = tuple(_aval(x) for x in leaves)
        if (
            isinstance(arg, eqx.Module)
            and all(isinstance(x, (jax.Array, bool, int, float)) for x in leaves)
            and sum(a.size for a in avals) <= _ARG_SIZE_KEPT
        ):
            leaves = [_on_device(x, a) for x, a in zip(leaves, avals)]
            with self._lock:
                self._args[id(arg)] = (arg, tree, leaves, avals)
                while len(self._args) > _ARGS_KEPT:
                    self._args.popitem(last=False)
        return tree, leaves, avals

    def __call__(self, *args):
        sig, static, leaves, tree, avals = self._signature(args)
        ready = self._ready.get(sig)
        if ready is None:
            ready = self._ensure(sig, static, tree, avals)
        compiled, out_tree = ready
        if _serial["depth"]:
            with _run_lock:
                return jax.tree.unflatten(out_tree, jax.block_until_ready(compiled(*leaves)))
        return jax.tree.unflatten(out_tree, compiled(*leaves))

    def prepare(self, *args, background: bool = False) -> None:
        """Make the program for these arguments ready (``jax.ShapeDtypeStruct`` leaves
        allowed). ``background=True`` does it in a daemon thread and returns at once; a call
        that needs the program meanwhile waits for it instead of building it twice."""
        if background:
            prepare_in_background([(self, args)])
            return
        sig, static, _, tree, avals = self._signature(args)
        self._ensure(sig, static, tree, avals)

    def wait_traced(self, *args, timeout: float | None = None) -> None:
        """Wait until the program for these arguments has been traced (or read from the
        store), or has failed. Tracing is Python and holds the interpreter: a caller that
        would trace something else meanwhile only slows both down; compiling runs beside."""
        sig = self._signature(args)[0]
        self._lowered_event(sig).wait(timeout)

    def _lowered_event(self, sig) -> threading.Event:
        with self._lock:
            event = self._lowered.get(sig)
            if event is None:
                event = self._lowered[sig] = threading.Event()
                if sig in self._ready:
                    event.set()
            return event

    def _cache_size(self) -> int:
        """Programs built so far (one per input structure), as ``jax.jit``'s."""
        return len(self._ready)

    def lower(self, *args):
        """``jax.jit(fn).lower(*args)`` (for memory analysis; bypasses the store)."""
        return jax.jit(self.fn, static_argnums=self.static_argnums).lower(*args)

    def _ensure(self, sig, static, tree, avals):
        """The ready program for ``sig``: built here, or by the thread already building it."""
        with self._lock:
            ready = self._ready.get(sig)
            if ready is not None:
                return ready
            future = self._pending.get(sig)
            owner = future is None
            if owner:
                future = concurrent.futures.Future()
                self._pending[sig] = future
        if not owner:
            return future.result()
        try:
            ready = self._build(static, tree, avals, self._lowered_event(sig))
        except BaseException as e:
            self._lowered_event(sig).set()
            with self._lock:
                self._pending.pop(sig, None)
            future.set_exception(e)
            raise
        with self._lock:
            self._ready[sig] = ready
            self._pending.pop(sig, None)
        future.set_result(ready)
        return ready

    # -- building ---------------------------------------------------------------------------

    def _flat(self, static, tree, out: list):
        """The function of the flat dynamic leaves; records its output structure in ``out``."""
        counts = [t.num_leaves for t in tree]

        def flat(*leaves):
            dynamic, start = [], 0
            for t, n in zip(tree, counts):
                dynamic.append(jax.tree.unflatten(t, leaves[start : start + n]))
                start += n
            parts, statics = iter(dynamic), iter(static)
            args = [
                next(statics) if i in self.static_argnums else next(parts)
                for i in range(len(static) + len(dynamic))
            ]
            res_leaves, res_tree = jax.tree.flatten(self.fn(*args))
            out.append(res_tree)
            return res_leaves

        return flat

    def _key(self, static, tree, avals) -> str:
        text = repr(
            (self.name, environment_key(), str(tree), repr(static),
             [(a.shape, str(a.dtype), a.weak_type) for a in avals])
        )  # fmt: skip
        return hashlib.sha256(text.encode()).hexdigest()[:40]

    def _build(self, static, tree, avals, traced: threading.Event):
        options = compiler_options(self.rare)
        folder = cache_dir()
        t0 = time.perf_counter()
        out: list = []
        if folder is None:
            lowered = jax.jit(self._flat(static, tree, out)).lower(*avals)
            out_tree, source = out[0], "jit"
        else:
            path = folder / f"{self.name}-{self._key(static, tree, avals)}.jaxprog"
            loaded = _read(path)
            if loaded is not None:
                exported, out_tree = loaded
                source = "stored"
            else:
                exported = jax.export.export(jax.jit(self._flat(static, tree, out)))(*avals)
                out_tree = out[0]
                source = "stored now" if _write(path, exported, out_tree) else "jit"
            lowered = jax.jit(exported.call).lower(*avals)
        traced.set()
        t1 = time.perf_counter()
        compiled = lowered.compile(options)
        _log.append(
            ProgramEvent(self.name, source, t1 - t0, time.perf_counter() - t1, time.time())
        )
        return compiled, out_tree


def _read(path: Path):
    """``(Exported, out_tree)`` from a stored file, or ``None`` (absent, unreadable, foreign)."""
    try:
        with open(path, "rb") as f:
            record = pickle.load(f)
        if record.get("format") != _FORMAT:
            return None
        return jax.export.deserialize(bytearray(record["exported"])), record["out_tree"]
    except FileNotFoundError:
        return None
    except Exception:  # a truncated or foreign file: trace afresh and overwrite it
        return None


def _write(path: Path, exported, out_tree) -> bool:
    """Store atomically (a reader sees the old file, the new one or none). Returns whether it
    was stored: not when the output structure does not survive pickling or the disk refuses."""
    try:
        if pickle.loads(pickle.dumps(out_tree)) != out_tree:
            return False
        data = pickle.dumps(
            {"format": _FORMAT, "exported": bytes(exported.serialize()), "out_tree": out_tree}
        )
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".jaxprog")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return True
    except ImportError as e:
        # jax.export's serialisation needs ``flatbuffers`` (a posetrack dependency, not a
        # jax one): say once why warm starts will trace again instead of failing silently.
        if not _STORE_WARNED.is_set():
            _STORE_WARNED.set()
            warnings.warn(
                f"posetrack: traced programs are not stored ({e}); every start traces them "
                "again. `pip install flatbuffers` turns the store on.",
                RuntimeWarning,
                stacklevel=2,
            )
        return False
    except Exception:
        return False


#: Set at interpreter exit: the background builders start no further program.
_LEAVING = threading.Event()
_BUILDER_NAME = "posetrack-prepare"


@atexit.register
def _finish_building() -> None:
    """At interpreter exit, wait for the program each background builder is compiling and
    start no other. A daemon thread still inside XLA when the interpreter finalises aborts
    the whole process ("terminate called ...", exit code 134) after its work is done, e.g. an
    online run shorter than the frames before its body-shape refinement, whose programs were
    still building. The wait is at most one program's compilation."""
    _LEAVING.set()
    for thread in threading.enumerate():
        if thread.name == _BUILDER_NAME:
            thread.join()


#: What :func:`prepare_now` and :func:`prepare_in_background` take: ``(program, args)``, or a
#: function returning such pairs (when working out the arguments' shapes is itself tracing).
Job = tuple[Program, tuple] | Callable[[], list]


def _pairs(job: Job) -> list:
    return job() if callable(job) else [job]


def prepare_now(jobs: Sequence[Job]) -> None:
    """``program.prepare(*args)`` for each job, here and now, in order."""
    for job in jobs:
        for prog, args in _pairs(job):
            prog.prepare(*args)


def prepare_in_background(jobs: Sequence[Job]) -> None:
    """:func:`prepare_now` in a daemon thread (a function job is called there); returns at
    once. A caller that needs one of the programs meanwhile waits for it. A failure ends the
    thread quietly: it is raised where the program is needed (that caller builds it again),
    not printed by the thread. At interpreter exit the thread finishes the program in hand
    and stops (:func:`_finish_building`)."""

    def work():
        for job in jobs:
            try:
                for prog, args in _pairs(job):
                    if _LEAVING.is_set():
                        return
                    prog.prepare(*args)
            except Exception:
                return

    threading.Thread(target=work, name=_BUILDER_NAME, daemon=True).start()


def program(
    name: str, *, static_argnums: Sequence[int] = (), rare: bool = False
) -> Callable[[Callable], Program]:
    """Decorator: ``@program("step")`` makes a :class:`Program`."""

    def wrap(fn: Callable) -> Program:
        return Program(fn, name, static_argnums=static_argnums, rare=rare)

    return wrap

