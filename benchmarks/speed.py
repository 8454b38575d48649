#!/usr/bin/env python
"""Speed of one tracker step: batched LVM and MHT_h against a Python loop and scipy (issue 4).

Every measured configuration runs on the same generated sequence (``posetrack.synth``, motion
"walk", seed 0, 640x480 uint16 depth) from the same initial pose; one frame is:

* ``lvm`` / ``mht_h``: ``posetrack._tracker._jit_step`` exactly as ``Tracker.update`` calls it
  (lifting, landmark weights and subset sampling, N LM fits, the 640x480 -> scoring-size
  downsample and observation maps, N renders + Delta, selection, consensus refit, reseed): one
  jitted call with the float32 depth in metres transferred from the host on each call, then
  ``jax.block_until_ready``. The state is carried from frame to frame as the Tracker does.
* ``loop`` (baseline a, the paper's serial implementation): the same frame with a Python loop
  over the hypotheses: a jitted single-hypothesis ``fit_pose`` and a jitted single-hypothesis
  ``render_and_score`` per hypothesis (plus one jitted call for lifting + subset sampling, one
  for the observation maps, one for the consensus refit, one for the state update). The
  hypotheses' results stay on the device until the argmin (the most favourable loop: no
  per-hypothesis host sync). Same masks and starts as the batched step: same result.
* ``scipy`` (baseline b, what a Python user would write): per hypothesis
  ``scipy.optimize.least_squares(method="lm")`` with a NumPy forward model (:func:`np_keypoints`,
  this file) and scipy's default finite-difference Jacobian and tolerances, on the residuals of
  Eq. (1) in their plain least-squares form (``ResidualSettings(loss="l2")``: same masks, same
  2D scaling and the same two regularisers as posetrack, but squares instead of the smoothed
  norms, which a finite-difference Jacobian would differentiate through). Lifting, subset
  sampling and each hypothesis' render + Delta reuse posetrack's jitted functions (the point of
  this baseline is the fitting cost); the consensus refit is another scipy fit. Measured on a
  few frames only (``--scipy-frames``, default 3) at N in {1, 5, 20}: it is slow.

Timing: the configurations of one resolution are interleaved frame by frame (round robin), so
a neighbour's load hits them alike and the ratios printed are measured under the same
conditions. ``ms_median`` is the median over ``--frames`` frames after ``--warmup`` frames;
``compile_s`` is the first call's wall time (trace + compile + one run) minus ``ms_median``.

Breakdown (LVM, and MHT_h at N in ``--breakdown-ns``, default 5 and 20 at 160x120, 20 at
320x240): after the timed frames the step's parts are replayed as separately jitted functions
on the recorded inputs of the same frames: ``lift_select``
(lifting + landmark weights + sampling), ``fits`` (the N vmapped LM fits), ``obs`` (downsample
+ observation maps), ``render`` (N renders + Delta), ``refit`` (consensus refit: one fit + one
render). ``rest_ms`` = step - sum of the parts (argmin, keypoints, reseed, dispatch; negative
when XLA fuses the parts better in the whole step than apart).

Memory: ``xla_temp_MB`` / ``xla_args_MB`` / ``xla_out_MB`` are the compiled step's buffer sizes
from XLA's ``memory_analysis()`` (CPU has no device memory statistics; this is what the
executable allocates per call); ``maxrss_MB`` is the process' peak resident set
(``resource.getrusage``) after the configuration was compiled and run, ``maxrss_delta_MB`` its
growth during that (0 when it fit in memory peaked earlier; configurations are compiled in
increasing N).

Host overhead (160x120; LVM, MHT_h N=5 and 20): ``update_ms`` is the median wall time of the public
``Tracker.update`` (input checks, uint16 -> float32 conversion, transfer, step, host syncs) and
``run_ms_per_frame`` the wall time of ``Tracker.run`` over the sequence divided by its frames
(adds the per-frame conversions of the results to NumPy).

Usage::

    python benchmarks/speed.py               # full table, ~5 min on 2 cores
    python benchmarks/speed.py --quick       # N in {1, 5, 20}, 160x120, scipy N=5 on 1 frame,
                                             # no breakdown: ~90 s on a quiet 2-core machine
    python benchmarks/speed.py --json speed.json

Never run two benchmarks at once on a 2-core machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import sys
import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

import posetrack as pt
from posetrack import _body
from posetrack._depthobs import observation_maps
from posetrack._fit import fit_hypotheses, fit_pose
from posetrack._machine import machine_info
from posetrack._observe import Landmarks
from posetrack._residuals import ResidualSettings
from posetrack._step import (
    ConfigView,
    TrackerConfig,
    TrackState,
    _consensus_refit,
    _landmarks,
    _reseed,
    _score,
    _selection,
    score_depth,
)
from posetrack._tracker import Tracker, _check_frame, _jit_step
from posetrack.io._atomic import atomic_write_text

DTYPE = jnp.float32
RESOLUTIONS = ((160, 120), (320, 240))
NS = (1, 5, 10, 20, 50, 100)  # 10: the shipped default

# =============================================================================================
# NumPy forward model and Eq. (1) residuals (baseline b).
# =============================================================================================


def np_joint_offsets(shape: dict[str, float]) -> np.ndarray:
    """(10, 3) origin of each kinematic frame in its parent's frame, metres (rest pose)."""
    s = shape
    sh_y = s["torso"] - s["shoulder_drop"]
    return np.array(
        [
            [0.0, 0.0, 0.0],  # root
            [0.0, s["torso"], 0.0],  # neck
            [-s["shoulder_width"], sh_y, 0.0],  # right shoulder
            [0.0, -s["upper_arm"], 0.0],  # right elbow
            [s["shoulder_width"], sh_y, 0.0],  # left shoulder
            [0.0, -s["upper_arm"], 0.0],  # left elbow
            [-s["hip_width"], 0.0, 0.0],  # right hip
            [0.0, -s["thigh"], 0.0],  # right knee
            [s["hip_width"], 0.0, 0.0],  # left hip
            [0.0, -s["thigh"], 0.0],  # left knee
        ]
    )


def np_keypoint_offsets(shape: dict[str, float]) -> np.ndarray:
    """(18, 3) each COCO-18 keypoint in the frame it rides on (``KEYPOINT_FRAMES``), metres."""
    k = shape["head_scale"]
    nose, eye, ear = (np.asarray(v) for v in (_body._NOSE, _body._EYE, _body._EAR))
    flip = np.array([-1.0, 1.0, 1.0])
    zero = np.zeros(3)
    wrist = np.array([0.0, -shape["forearm"], 0.0])
    ankle = np.array([0.0, -shape["shin"], 0.0])
    return np.stack(
        [
            k * nose, zero,
            zero, zero, wrist, zero, zero, wrist,
            zero, zero, ankle, zero, zero, ankle,
            k * eye * flip, k * eye, k * ear * flip, k * ear,
        ]
    )  # fmt: skip


def np_quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations of (n, 4) wxyz quaternions of any norm (0 -> identity).

    Written for speed on tiny arrays (one NumPy call per matrix entry, no ``np.stack``): the
    scipy baseline calls the forward model ~400 times per fit.
    """
    sq = np.einsum("ij,ij->i", q, q)
    ok = sq > 1e-12
    q = q / np.sqrt(np.where(ok, sq, 1.0))[:, None]
    if not ok.all():
        q[~ok] = (1.0, 0.0, 0.0, 0.0)
    w, x, y, z = q.T
    R = np.empty((len(q), 3, 3))
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    R[:, 0, 0] = 1.0 - 2.0 * (yy + zz)
    R[:, 0, 1] = 2.0 * (xy - wz)
    R[:, 0, 2] = 2.0 * (xz + wy)
    R[:, 1, 0] = 2.0 * (xy + wz)
    R[:, 1, 1] = 1.0 - 2.0 * (xx + zz)
    R[:, 1, 2] = 2.0 * (yz - wx)
    R[:, 2, 0] = 2.0 * (xz - wy)
    R[:, 2, 1] = 2.0 * (yz + wx)
    R[:, 2, 2] = 1.0 - 2.0 * (xx + yy)
    return R


_PARENTS = np.asarray(_body.JOINT_PARENTS)
_KP_FRAMES = np.asarray(_body.KEYPOINT_FRAMES)
# The kinematic tree by depth (root; its children; their children): one batched matmul per level.
_LEVELS = [np.flatnonzero(_PARENTS == 0)]
_LEVELS.append(np.flatnonzero(np.isin(_PARENTS, _LEVELS[0])))
assert sorted(np.concatenate([[0], *_LEVELS]).tolist()) == list(range(10)), "tree deeper than 3"


def np_keypoints(params: np.ndarray, joint_offs: np.ndarray, kp_offs: np.ndarray) -> np.ndarray:
    """Forward kinematics of the 43-parameter model in NumPy: (18, 3) keypoints, metres.

    ``params``: root translation, root quaternion, 9 joint quaternions (wxyz, any norm);
    ``joint_offs`` / ``kp_offs`` from :func:`np_joint_offsets` / :func:`np_keypoint_offsets`.
    """
    params = np.asarray(params, np.float64)
    R = np_quat_to_matrix(params[3:].reshape(10, 4))
    Rw = np.empty((10, 3, 3))
    c = np.empty((10, 3))
    Rw[0], c[0] = R[0], params[:3]
    for level in _LEVELS:  # world frame of each joint from its parent's
        par = _PARENTS[level]
        Rw[level] = np.matmul(Rw[par], R[level])
        c[level] = c[par] + np.matmul(Rw[par], joint_offs[level][:, :, None])[:, :, 0]
    return c[_KP_FRAMES] + np.matmul(Rw[_KP_FRAMES], kp_offs[:, :, None])[:, :, 0]


def np_normalize_params(params: np.ndarray) -> np.ndarray:
    """Unit quaternions with w >= 0 (posetrack's ``normalize_params``)."""
    q = params[3:].reshape(10, 4)
    n = np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
    q = np.where(n > 1e-6, q / np.where(n > 1e-6, n, 1.0), [1.0, 0.0, 0.0, 0.0])
    q = np.where(q[:, :1] < 0, -q, q)
    return np.concatenate([params[:3], q.reshape(-1)])


class NumpyResiduals:
    """Eq. (1) residuals of posetrack's ``fit_pose`` in NumPy, plain least squares ("l2").

    The same vector as ``posetrack._fit._residual_fn`` with ``ResidualSettings(loss="l2")``:
    per keypoint 3 metric 3D components then 2 pixel components scaled to metres at the start
    pose's depth (masked as in ``fit_pose``), then ``unit_weight (|q|^2 - 1)`` for the 10
    quaternions and ``prior_weight (x - x_start)``.
    """

    def __init__(
        self,
        shape: pt.BodyShape,
        intrinsics: pt.Intrinsics,
        settings: ResidualSettings = ResidualSettings(loss="l2"),
    ):
        if settings.loss != "l2":
            raise ValueError("NumpyResiduals implements the plain least-squares form only")
        s = {k: float(v) for k, v in shape.to_dict().items()}
        self.joint_offs = np_joint_offsets(s)
        self.kp_offs = np_keypoint_offsets(s)
        self.fx, self.fy = float(intrinsics.fx), float(intrinsics.fy)
        self.cx, self.cy = float(intrinsics.cx), float(intrinsics.cy)
        self.settings = settings
        self.calls = 0  # residual evaluations, finite-difference ones included
        self.fit_seconds: list[float] = []  # wall time of each fit

    def keypoints(self, params):
        return np_keypoints(params, self.joint_offs, self.kp_offs)

    def project(self, P):
        z = np.maximum(P[:, 2], 1e-3)
        return np.stack([self.fx * P[:, 0] / z + self.cx, self.fy * P[:, 1] / z + self.cy], -1)

    def setup(self, start, lm: dict, use3d, use2d):
        """Masks and scales fixed during one fit (as ``fit_pose`` computes them)."""
        use3d = np.asarray(use3d, bool) & lm["has_depth"]
        use2d = np.asarray(use2d, bool) & lm["detected"] & ~use3d
        start = np_normalize_params(np.asarray(start, np.float64))
        z = self.keypoints(start)[:, 2]
        mpp = np.clip(z, 0.2, 20.0) / np.sqrt(self.fx * self.fy)
        return start, use3d, use2d, mpp

    def __call__(self, params, start, lm, use3d, use2d, mpp):
        self.calls += 1
        M = self.keypoints(params)
        e3 = (M - lm["points3d"]) * use3d[:, None]
        e2 = (self.project(M) - lm["keypoints2d"]) * (use2d * mpp)[:, None]
        q = params[3:].reshape(10, 4)
        unit = self.settings.unit_weight * (np.sum(q * q, axis=-1) - 1.0)
        prior = self.settings.prior_weight * (params - start)
        return np.concatenate([np.concatenate([e3, e2], -1).reshape(-1), unit, prior])

    def fit(self, start, lm: dict, use3d, use2d) -> tuple[np.ndarray, int]:
        """``scipy.optimize.least_squares(method="lm")`` from ``start`` with scipy's default
        finite-difference Jacobian and tolerances. Returns (normalised params, residual
        evaluations including the finite-difference ones)."""
        from scipy.optimize import least_squares

        t0 = time.perf_counter()
        start, use3d, use2d, mpp = self.setup(start, lm, use3d, use2d)
        calls = self.calls
        sol = least_squares(self, start, method="lm", args=(start, lm, use3d, use2d, mpp))
        params = np_normalize_params(sol.x)
        if not np.all(np.isfinite(params)):
            params = start
        self.fit_seconds.append(time.perf_counter() - t0)
        return params, self.calls - calls


def landmarks_to_numpy(lm: Landmarks) -> dict[str, np.ndarray]:
    return {
        "points3d": np.asarray(lm.points3d, np.float64),
        "keypoints2d": np.asarray(lm.keypoints2d, np.float64),
        "has_depth": np.asarray(lm.has_depth, bool),
        "detected": np.asarray(lm.detected, bool),
    }


# =============================================================================================
# Jitted pieces of tracker_step: the baselines' shared parts and the breakdown.
# =============================================================================================


def _one(static: TrackerConfig) -> TrackerConfig:
    """The static config of the parts that do not depend on N or the method (one compile per
    resolution for them, shared by every N)."""
    return dataclasses.replace(static, method="mht_h", num_hypotheses=1)


@partial(jax.jit, static_argnums=0)
def lift_select(static, tunables, shape, intrinsics, state, depth, kp2d, conf):
    """Lifting + landmark weights + subset sampling (the start of ``tracker_step``)."""
    config = ConfigView(static, tunables)
    key, key_next = jax.random.split(state.key)
    lm = _landmarks(config, shape, intrinsics, depth, kp2d, conf)
    use3d, use2d = _selection(config, key, shape, intrinsics, depth, lm, state.previous)
    return lm, use3d, use2d, key_next


@partial(jax.jit, static_argnums=0)
def observe(static, tunables, intrinsics, floor, best, depth):
    """The 640x480 -> scoring-size downsample and the observation maps of Eq. (3)."""
    config = ConfigView(static, tunables)
    small, small_intr = score_depth(depth, intrinsics, config)
    known = (small > 0).astype(small.dtype) if config.invalid_is_unknown else None
    z_d, z_fg = observation_maps(
        small, small_intr, center=best[:3], radius=config.body_range, floor=(floor[:3], floor[3])
    )
    return z_d, z_fg, known, small_intr


@partial(jax.jit, static_argnums=0)
def fits_batched(static, shape, intrinsics, lm, hypotheses, use3d, use2d):
    """The N vmapped LM fits of the step."""
    return fit_hypotheses(
        hypotheses, shape, lm, intrinsics, use3d=use3d, use2d=use2d, settings=static.fit
    )


def _render(static, tunables, shape, small_intr, params, z_d, z_fg, known):
    return _score(ConfigView(static, tunables), shape, params, z_d, z_fg, small_intr, known)


#: The N renders + Delta of the step.
render_batched = jax.jit(_render, static_argnums=0)


@partial(jax.jit, static_argnums=0)
def fit_one(settings, start, shape, intrinsics, lm, use3d, use2d):
    """One hypothesis' fit (baseline a)."""
    return fit_pose(start, shape, lm, intrinsics, use3d=use3d, use2d=use2d, settings=settings)


@partial(jax.jit, static_argnums=0)
def score_one(static, tunables, shape, small_intr, params, z_d, z_fg, known):
    """One hypothesis' render + Delta (baselines a and b)."""
    return _render(static, tunables, shape, small_intr, params[None], z_d, z_fg, known)[0]


@partial(jax.jit, static_argnums=0)
def refit_one(static, tunables, shape, intrinsics, lm, chosen, chosen_delta, z_d, z_fg,
              small_intr, known):  # fmt: skip
    """The consensus refit of the winner: one fit + one render + Delta."""
    config = ConfigView(static, tunables)
    return _consensus_refit(
        config, shape, intrinsics, lm, chosen, chosen_delta, z_d, z_fg, small_intr, known
    )


@partial(jax.jit, static_argnums=0)
def finish(static, tunables, shape, params, deltas, best, chosen, chosen_delta, key_next):
    """The end of ``tracker_step``: reseed and the next state (baselines a and b)."""
    params = params.at[best].set(chosen)
    hyps = _reseed(ConfigView(static, tunables), params, deltas, best, chosen)
    kps = jax.vmap(lambda p: _body.keypoints(shape, p))(hyps)
    state = TrackState(hypotheses=hyps, previous=kps, best=chosen, key=key_next)
    return state, kps[best]


# =============================================================================================
# Runners: one per measured configuration; ``step(t)`` processes frame t and returns seconds.
# =============================================================================================


@dataclasses.dataclass
class Frames:
    """The sequence, checked and converted once (float32 metres, as ``Tracker.update`` does)."""

    seq: object
    depth: list
    kp: list
    conf: list
    shape: pt.BodyShape
    intrinsics: pt.Intrinsics

    @staticmethod
    def make(n_frames: int, seed: int = 0, motion: str = "walk") -> Frames:
        seq = pt.synth.generate(seed, motion=motion, n_frames=n_frames, with_rgb=False)
        intr = jax.tree.map(lambda x: jnp.asarray(x, DTYPE), seq.intrinsics)
        conv = [
            _check_frame(intr, seq.depth[t], seq.keypoints2d[t], seq.confidence[t], 1000.0, "b")
            for t in range(n_frames)
        ]
        probe = Tracker(seq.intrinsics, TrackerConfig())
        probe.estimate_shape(seq.depth[:15], seq.keypoints2d[:15], seq.confidence[:15])
        return Frames(seq, [c[0] for c in conv], [c[1] for c in conv], [c[2] for c in conv],
                      probe.shape, intr)  # fmt: skip

    def __len__(self):
        return len(self.depth)


class Runner:
    method = ""

    def __init__(self, frames: Frames, config: TrackerConfig, *, max_frames: int | None = None):
        self.frames = frames
        self.config = config
        self.tracker = Tracker(frames.seq.intrinsics, config, shape=frames.shape)
        ok = self.tracker._initialize(frames.depth[0], frames.kp[0], frames.conf[0])
        if not ok:
            raise RuntimeError("benchmark sequence: initialisation failed on frame 0")
        self.static, self.tunables = self.tracker._split
        self.state: TrackState = self.tracker._state
        self.max_frames = max_frames
        self.times: list[float] = []
        self.first_call_s = float("nan")
        self.lost = 0
        self.inputs: list = []  # (state before, t) of the timed frames
        self.record_inputs = False
        self.extra: dict = {}

    @property
    def n(self):
        return self.config.n

    @property
    def resolution(self):
        return f"{self.config.score_width}x{self.config.score_height}"

    def args(self, t):
        f = self.frames
        return (self.tracker.shape, f.intrinsics, self.tracker._floor, self.state,
                f.depth[t], f.kp[t], f.conf[t])  # fmt: skip

    def wants(self, k_timed: int) -> bool:
        return self.max_frames is None or k_timed < self.max_frames

    #: Untimed frames after the compiling call (None: the benchmark's ``--warmup``).
    warmup: int | None = None
    #: Whether ``measure`` makes a first (compiling) call on frame 1.
    compile_call = True

    def timed(self, t: int, record: bool) -> float:
        if record and self.record_inputs:
            self.inputs.append((self.state, t))
        t0 = time.perf_counter()
        self.advance(t)
        return time.perf_counter() - t0

    def _accept(self, state, num_3d, delta):
        if int(num_3d) >= self.config.min_landmarks:
            self.state = state
        if float(delta) > self.config.lost_delta:
            self.lost += 1


class StepRunner(Runner):
    """``_jit_step`` as ``Tracker.update`` calls it."""

    def __init__(self, frames, config, **kw):
        super().__init__(frames, config, **kw)
        self.method = config.method
        self.record_inputs = True

    def advance(self, t):
        state, est = _jit_step(self.static, self.tunables, *self.args(t))
        jax.block_until_ready(est)
        self.last = est
        self._accept(state, est.num_3d, est.delta)

    def compile_count(self):
        return _jit_step._cache_size()

    def memory(self, t):
        compiled = _jit_step.lower(self.static, self.tunables, *self.args(t)).compile()
        ma = compiled.memory_analysis()
        mb = 1.0 / 2**20
        return {
            "xla_temp_MB": round(ma.temp_size_in_bytes * mb, 2),
            "xla_args_MB": round(ma.argument_size_in_bytes * mb, 2),
            "xla_out_MB": round(ma.output_size_in_bytes * mb, 2),
        }


class LoopRunner(Runner):
    """Baseline (a): the same frame, a Python loop over hypotheses."""

    method = "loop"

    def prepare(self, t):
        f = self.frames
        shape = self.tracker.shape
        lm, use3d, use2d, key_next = lift_select(
            self.static, self.tunables, shape, f.intrinsics, self.state, f.depth[t], f.kp[t],
            f.conf[t],
        )  # fmt: skip
        obs = observe(_one(self.static), self.tunables, f.intrinsics, self.tracker._floor,
                      self.state.best, f.depth[t])  # fmt: skip
        return lm, use3d, use2d, key_next, obs

    def finish(self, params, deltas, lm, obs, key_next):
        """Selection, consensus refit, reseed; ``deltas`` on the host."""
        shape = self.tracker.shape
        best = int(np.argmin(deltas))
        chosen, chosen_delta = params[best], jnp.asarray(deltas[best], DTYPE)
        if self.config.consensus_refit and self.config.method != "lvm":
            z_d, z_fg, known, small_intr = obs
            chosen, chosen_delta = refit_one(
                _one(self.static), self.tunables, shape, self.frames.intrinsics, lm, chosen,
                chosen_delta, z_d, z_fg, small_intr, known,
            )  # fmt: skip
        state, kp = finish(self.static, self.tunables, shape, params, jnp.asarray(deltas, DTYPE),
                           best, chosen, chosen_delta, key_next)  # fmt: skip
        jax.block_until_ready(state)
        self.last = (chosen, chosen_delta, best, kp)
        self._accept(state, jnp.sum(lm.has_depth), chosen_delta)

    def advance(self, t):
        shape, intr = self.tracker.shape, self.frames.intrinsics
        lm, use3d, use2d, key_next, obs = self.prepare(t)
        z_d, z_fg, known, small_intr = obs
        s1 = _one(self.static)
        params, deltas = [], []
        for h in range(self.n):
            res = fit_one(self.static.fit, self.state.hypotheses[h], shape, intr, lm,
                          use3d[h], use2d[h])  # fmt: skip
            params.append(res.params)
            deltas.append(score_one(s1, self.tunables, shape, small_intr, res.params, z_d, z_fg,
                                    known))  # fmt: skip
        self.finish(jnp.stack(params), np.asarray(jnp.stack(deltas)), lm, obs, key_next)


class ScipyRunner(LoopRunner):
    """Baseline (b): scipy LM with a NumPy model per hypothesis; posetrack's render + Delta."""

    method = "scipy"
    warmup = 0
    #: No compiling call: its jitted parts (lifting, scorer, refit masks) are the loop
    #: baseline's, compiled before it; scipy itself has nothing to compile.
    compile_call = False

    def __init__(self, frames, config, **kw):
        import scipy.optimize  # noqa: F401  (imported here, not inside the first timed frame)

        super().__init__(frames, config, **kw)
        self.model = NumpyResiduals(frames.shape, frames.intrinsics)
        self.nfev: list[int] = []

    def advance(self, t):
        shape = self.tracker.shape
        lm, use3d, use2d, key_next, obs = self.prepare(t)
        z_d, z_fg, known, small_intr = obs
        s1 = _one(self.static)
        lm_np = landmarks_to_numpy(lm)
        use3d, use2d = np.asarray(use3d), np.asarray(use2d)
        starts = np.asarray(self.state.hypotheses, np.float64)
        params, deltas = [], []
        for h in range(self.n):
            p, nfev = self.model.fit(starts[h], lm_np, use3d[h], use2d[h])
            self.nfev.append(nfev)
            params.append(p)
            deltas.append(float(score_one(s1, self.tunables, shape, small_intr,
                                          jnp.asarray(p, DTYPE), z_d, z_fg, known)))  # fmt: skip
        deltas = np.asarray(deltas)
        best = int(np.argmin(deltas))
        chosen, chosen_delta = params[best], deltas[best]
        if self.config.consensus_refit and self.config.method != "lvm":
            chosen, chosen_delta = self.consensus_refit(chosen, chosen_delta, lm_np, obs)
        state, kp = finish(self.static, self.tunables, shape, jnp.asarray(np.stack(params), DTYPE),
                           jnp.asarray(deltas, DTYPE), best, jnp.asarray(chosen, DTYPE),
                           jnp.asarray(chosen_delta, DTYPE), key_next)  # fmt: skip
        jax.block_until_ready(state)
        self.last = (chosen, chosen_delta, best, kp)
        self._accept(state, lm_np["has_depth"].sum(), chosen_delta)

    def consensus_refit(self, chosen, chosen_delta, lm, obs):
        """``_consensus_refit`` with the scipy fit (inlier masks as there)."""
        z_d, z_fg, known, small_intr = obs
        m = self.model
        M = m.keypoints(chosen)
        tau = self.config.consensus_distance
        d3 = np.linalg.norm(M - lm["points3d"], axis=-1)
        d2 = (np.linalg.norm(m.project(M) - lm["keypoints2d"], axis=-1)
              * np.maximum(M[:, 2], 0.2) / np.sqrt(m.fx * m.fy))  # fmt: skip
        use3d, use2d = lm["has_depth"] & (d3 < tau), lm["detected"] & (d2 < tau)
        p, nfev = m.fit(chosen, lm, use3d, use2d)
        self.nfev.append(nfev)
        d = float(score_one(_one(self.static), self.tunables, self.tracker.shape, small_intr,
                            jnp.asarray(p, DTYPE), z_d, z_fg, known))  # fmt: skip
        return (p, d) if d <= chosen_delta else (chosen, chosen_delta)


# =============================================================================================
# Measurement.
# =============================================================================================


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def _time_replay(fn, inputs) -> tuple[float, float, list]:
    """(first call s, median ms over the rest, outputs) of ``fn(i)`` for every recorded input."""
    t0 = time.perf_counter()
    outs = [jax.block_until_ready(fn(0))]
    first = time.perf_counter() - t0
    times = []
    for i in range(1, len(inputs)):
        t0 = time.perf_counter()
        outs.append(jax.block_until_ready(fn(i)))
        times.append(time.perf_counter() - t0)
    return first, 1e3 * float(np.median(times)), outs


def breakdown(r: StepRunner) -> dict:
    """Replay the step's parts as separate jitted functions on the recorded frames."""
    f = r.frames
    sh, intr, floor = r.tracker.shape, f.intrinsics, r.tracker._floor
    st, tu = r.static, r.tunables
    ins = r.inputs
    out = {}
    _, out["lift_select_ms"], ls = _time_replay(
        lambda i: lift_select(st, tu, sh, intr, ins[i][0], f.depth[ins[i][1]], f.kp[ins[i][1]],
                              f.conf[ins[i][1]]), ins)  # fmt: skip
    _, out["fits_ms"], fits = _time_replay(
        lambda i: fits_batched(st, sh, intr, ls[i][0], ins[i][0].hypotheses, ls[i][1],
                               ls[i][2]), ins)  # fmt: skip
    steps = np.stack([np.asarray(x.num_steps) for x in fits])
    out["lm_steps_mean"] = round(float(steps.mean()), 2)
    out["lm_steps_max"] = int(steps.max())
    _, out["obs_ms"], obs = _time_replay(
        lambda i: observe(_one(st), tu, intr, floor, ins[i][0].best, f.depth[ins[i][1]]), ins
    )
    _, out["render_ms"], deltas = _time_replay(
        lambda i: render_batched(st, tu, sh, obs[i][3], fits[i].params, *obs[i][:3]), ins
    )
    parts = ["lift_select_ms", "fits_ms", "obs_ms", "render_ms"]
    if r.config.consensus_refit and r.config.method != "lvm":

        def refit(i):
            b = int(np.argmin(np.asarray(deltas[i])))
            return refit_one(_one(st), tu, sh, intr, ls[i][0], fits[i].params[b], deltas[i][b],
                             obs[i][0], obs[i][1], obs[i][3], obs[i][2])  # fmt: skip

        _, out["refit_ms"], _ = _time_replay(refit, ins)
        parts.append("refit_ms")
    out = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in out.items()}
    out["rest_ms"] = round(float(np.median(r.times)) * 1e3 - sum(out[p] for p in parts), 3)
    return out


def host_overhead(r: StepRunner, n_frames: int) -> dict:
    """What ``Tracker.update`` and ``Tracker.run`` add to the step, per frame.

    Paired within each call, so robust to a neighbour's load: the Tracker records the wall time
    of its own ``_jit_step`` call + ``block_until_ready`` (``_step_times``); the overhead is the
    public call's wall time minus that (input checks, uint16 -> float32 conversion, status
    logic and its host syncs; in ``run`` also the per-frame conversions of the results).
    """
    seq = r.frames.seq
    T = min(n_frames, len(r.frames))
    tr = Tracker(seq.intrinsics, r.config, shape=r.frames.shape)
    tr.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])  # initialises; compiled
    walls = []
    for t in range(1, T):
        t0 = time.perf_counter()
        tr.update(seq.depth[t], seq.keypoints2d[t], seq.confidence[t])
        walls.append(time.perf_counter() - t0)
    update_over = np.asarray(walls) - np.asarray(tr._step_times[-len(walls) :])
    # run() on frames 1.. of a tracker initialised on frame 0: the one-off initialisation
    # (pose from landmarks, 60-step fit, floor RANSAC) is not a per-frame cost.
    tr2 = Tracker(seq.intrinsics, r.config, shape=r.frames.shape)
    tr2.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])
    n_before = len(tr2._step_times)
    t0 = time.perf_counter()
    tr2.run(seq.depth[1:T], seq.keypoints2d[1:T], seq.confidence[1:T], progress=False)
    run_s = time.perf_counter() - t0
    run_steps = tr2._step_times[n_before:]
    return {
        "update_ms": round(1e3 * float(np.median(walls)), 3),
        "update_overhead_ms": round(1e3 * float(np.median(update_over)), 3),
        "run_ms_per_frame": round(1e3 * run_s / (T - 1), 3),
        "run_overhead_ms_per_frame": round(1e3 * (run_s - sum(run_steps)) / (T - 1), 3),
    }


def measure(frames: Frames, runners: list[Runner], *, warmup: int, n_timed: int,
            log=print) -> None:  # fmt: skip
    """Compile every runner (first call on frame 1), then time frames round robin."""
    for r in runners:
        if not r.compile_call:
            continue
        before_rss = _maxrss_mb()
        before_cache = r.compile_count() if isinstance(r, StepRunner) else 0
        t0 = time.perf_counter()
        r.advance(1)
        r.first_call_s = time.perf_counter() - t0
        if isinstance(r, StepRunner):
            r.extra["compiles"] = r.compile_count() - before_cache
            r.extra.update(r.memory(2))
        r.extra["maxrss_MB"] = round(_maxrss_mb(), 1)
        r.extra["maxrss_delta_MB"] = round(_maxrss_mb() - before_rss, 1)
        log(
            f"  compiled {r.method:5s} N={r.n:<3d} {r.resolution}: first call "
            f"{r.first_call_s:5.1f} s",
            flush=True,
        )
    cache = _jit_step._cache_size()
    for k, t in enumerate(range(2, 2 + warmup + n_timed)):
        for r in runners:
            timed = k - (warmup if r.warmup is None else r.warmup)
            if timed < 0:
                r.advance(t)
            elif r.wants(timed):
                r.times.append(r.timed(t, record=True))
    retraced = _jit_step._cache_size() - cache
    for r in runners:
        if isinstance(r, StepRunner):
            r.extra["recompiles_while_timed"] = retraced


def record_of(r: Runner, machine: dict) -> dict:
    ms = 1e3 * float(np.median(r.times))
    rec = {
        "method": r.method,
        "N": r.n,
        "resolution": r.resolution,
        "ms_median": round(ms, 3),
        "ms_min": round(1e3 * float(np.min(r.times)), 3),
        "frames_timed": len(r.times),
        "compile_s": (round(max(r.first_call_s - ms / 1e3, 0.0), 3) if r.compile_call else None),
        "lost_frames": r.lost,
        **r.extra,
        "machine": machine,
    }
    if isinstance(r, ScipyRunner):
        rec["scipy_evals_per_fit"] = round(float(np.mean(r.nfev)), 1)
        rec["scipy_evals_per_fit_median"] = float(np.median(r.nfev))
        rec["scipy_evals_per_fit_max"] = int(np.max(r.nfev))
        fit_s = r.model.fit_seconds
        rec["scipy_ms_per_fit_median"] = round(1e3 * float(np.median(fit_s)), 2)
        rec["scipy_us_per_evaluation"] = round(1e6 * float(np.sum(fit_s)) / sum(r.nfev), 1)
        rec["loss"] = "l2"
    return rec


# =============================================================================================
# Report.
# =============================================================================================


def _find(records, method, n, res):
    for rec in records:
        if (rec["method"], rec["N"], rec["resolution"]) == (method, n, res):
            return rec
    return None


def table(records) -> str:
    lines = []
    for res in dict.fromkeys(r["resolution"] for r in records):
        lvm = _find(records, "lvm", 1, res)
        ns = sorted({r["N"] for r in records if r["resolution"] == res and r["method"] != "lvm"})
        lines += [
            f"\n{res} scoring (ms per frame, median; ratio = other / MHT_h at the same N)",
            "| N | LVM | MHT_h | MHT_h/LVM | loop (a) | loop/MHT_h | scipy (b) | scipy/MHT_h "
            "| compile s | lift+sel | fits | LM steps | obs | render | refit | rest | XLA temp MB "
            "| maxrss MB |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        if lvm:
            lines.append(_row("LVM", lvm, None, None, None))
        for n in ns:
            h = _find(records, "mht_h", n, res)
            if h is None:
                continue
            lines.append(_row(str(n), h, lvm, _find(records, "loop", n, res),
                              _find(records, "scipy", n, res)))  # fmt: skip
    return "\n".join(lines)


def _f(x, fmt="{:.1f}"):
    return "-" if x is None else fmt.format(x)


def _row(label, h, lvm, loop, scipy) -> str:
    ms = h["ms_median"]
    cells = [
        label,
        _f(lvm["ms_median"] if lvm else (ms if label == "LVM" else None)),
        _f(ms) if label != "LVM" else "-",
        _f(ms / lvm["ms_median"] if lvm else None, "{:.2f}x"),
        _f(loop["ms_median"] if loop else None),
        _f(loop["ms_median"] / ms if loop else None, "{:.1f}x"),
        _f(scipy["ms_median"] if scipy else None, "{:.0f}"),
        _f(scipy["ms_median"] / ms if scipy else None, "{:.0f}x"),
        _f(h.get("compile_s")),
        _f(h.get("lift_select_ms"), "{:.2f}"),
        _f(h.get("fits_ms")),
        _f(h.get("lm_steps_mean")),
        _f(h.get("obs_ms")),
        _f(h.get("render_ms")),
        _f(h.get("refit_ms")),
        _f(h.get("rest_ms")),
        _f(h.get("xla_temp_MB")),
        _f(h.get("maxrss_MB"), "{:.0f}"),
    ]
    return "| " + " | ".join(cells) + " |"


def targets(records) -> list[tuple[str, str, bool | None]]:
    """(target, measured, met) for the issue's targets (None: not measured in this run)."""
    res = "160x120"
    lvm = _find(records, "lvm", 1, res)
    h5, h20 = _find(records, "mht_h", 5, res), _find(records, "mht_h", 20, res)
    loop20, scipy20 = _find(records, "loop", 20, res), _find(records, "scipy", 20, res)
    out = []

    def add(name, value, fmt, ok):
        out.append((name, "-" if value is None else fmt.format(value),
                    None if value is None else bool(ok)))  # fmt: skip

    r = h20["ms_median"] / lvm["ms_median"] if (h20 and lvm) else None
    add("MHT_h N=20 <= 4x LVM", r, "{:.2f}x", r is not None and r <= 4)
    r = h5["ms_median"] / lvm["ms_median"] if (h5 and lvm) else None
    add("MHT_h N=5 <= 2x LVM", r, "{:.2f}x", r is not None and r <= 2)
    r = scipy20["ms_median"] / h20["ms_median"] if (scipy20 and h20) else None
    add("MHT_h N=20 >= 100x faster than scipy (b)", r, "{:.0f}x", r is not None and r >= 100)
    r = loop20["ms_median"] / h20["ms_median"] if (loop20 and h20) else None
    add("MHT_h N=20 faster than loop (a)", r, "{:.1f}x", r is not None and r > 1)
    v = h5["ms_median"] if h5 else None
    add("MHT_h N=5 <= 8 ms (160x120)", v, "{:.1f} ms", v is not None and v <= 8)
    v = h20["ms_median"] if h20 else None
    add("MHT_h N=20 <= 25 ms (160x120)", v, "{:.1f} ms", v is not None and v <= 25)
    steps = [x for x in records if x["method"] in ("lvm", "mht_h")]
    v = max((x["compile_s"] for x in steps), default=None)
    add("compile <= 20 s (max over configurations)", v, "{:.1f} s", v is not None and v <= 20)
    v = max(
        (x.get("compiles", 1) + x.get("recompiles_while_timed", 0) for x in steps), default=None
    )
    add("one compile per configuration", v, "{} (max)", v == 1)
    big = [x for x in steps if x["N"] == 100]
    v = max((x["xla_temp_MB"] for x in big), default=None)
    add("memory bounded at N=100 (XLA temp)", v, "{:.1f} MB", v is not None and v < 512)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", help="write the records (a JSON list) to this path")
    parser.add_argument("--quick", action="store_true", help="N in {1, 5, 20}, 160x120 only")
    parser.add_argument(
        "--ns", type=int, nargs="+", help="hypothesis counts (default 1 5 10 20 50 100)"
    )
    parser.add_argument("--resolutions", nargs="+", help="scoring sizes, e.g. 160x120 320x240")
    parser.add_argument("--frames", type=int, default=20, help="timed frames per configuration")
    parser.add_argument("--warmup", type=int, default=2, help="untimed frames after compiling")
    parser.add_argument("--scipy-frames", type=int, default=3, help="timed frames of scipy")
    parser.add_argument(
        "--scipy-ns",
        type=int,
        nargs="+",
        default=None,
        help="N of the scipy baseline (default 1 5 20; --quick: 5)",
    )
    parser.add_argument(
        "--loop-max-n",
        type=int,
        default=100,
        help="largest N of the loop baseline (160x120 only; a loop's cost per "
        "hypothesis is the batched one's plus dispatch, at any resolution)",
    )
    parser.add_argument("--no-baselines", action="store_true")
    parser.add_argument("--no-breakdown", action="store_true")
    parser.add_argument(
        "--breakdown-ns",
        type=int,
        nargs="+",
        default=None,
        help="MHT_h N with a breakdown (LVM always has one; each costs "
        "compiles); default 5 20 (--quick: none)",
    )
    parser.add_argument("--no-host", action="store_true", help="skip Tracker.update/run timing")
    args = parser.parse_args(argv)

    ns = tuple(args.ns or ((1, 5, 20) if args.quick else NS))
    if args.resolutions:
        resolutions = [tuple(int(v) for v in s.split("x")) for s in args.resolutions]
    else:
        resolutions = [RESOLUTIONS[0]] if args.quick else list(RESOLUTIONS)
    scipy_ns = tuple(args.scipy_ns or ((5,) if args.quick else (1, 5, 20)))
    if args.quick:
        # What keeps --quick near 90 s on 2 cores: scipy at N=20 alone took ~25 s per frame and
        # the breakdown ~12 s (plus compiles); the full run measures both.
        args.scipy_frames = min(args.scipy_frames, 1)
        args.no_host = True
        if args.breakdown_ns is None:
            args.no_breakdown = True
    if args.breakdown_ns is None:
        args.breakdown_ns = [5, 20]

    machine = machine_info()
    machine["loadavg_start"] = [round(v, 2) for v in os.getloadavg()]
    print("machine: " + " | ".join(f"{k}: {v}" for k, v in machine.items()), flush=True)
    t_start = time.perf_counter()
    frames = Frames.make(2 + args.warmup + args.frames)
    print(f"sequence: {len(frames)} frames 640x480 (synth walk, seed 0) "
          f"[{time.perf_counter() - t_start:.1f} s]", flush=True)  # fmt: skip

    records = []
    for w, h in resolutions:
        res = f"{w}x{h}"
        base = dict(score_width=w, score_height=h)
        runners: list[Runner] = [StepRunner(frames, TrackerConfig.paper("lvm", **base))]
        runners += [StepRunner(frames, TrackerConfig.recommended("mht_h", num_hypotheses=n, **base))
                    for n in ns]  # fmt: skip
        if not args.no_baselines:
            if (w, h) == RESOLUTIONS[0]:
                runners += [
                    LoopRunner(frames, TrackerConfig.recommended("mht_h", num_hypotheses=n, **base))
                    for n in ns if n <= args.loop_max_n
                ]  # fmt: skip
                runners += [
                    ScipyRunner(
                        frames, TrackerConfig.recommended("mht_h", num_hypotheses=n, **base),
                        max_frames=args.scipy_frames,
                    )
                    for n in ns if n in scipy_ns
                ]  # fmt: skip
        print(f"\n{res}: compiling {len(runners)} configurations", flush=True)
        measure(frames, runners, warmup=args.warmup, n_timed=args.frames)
        print(f"  timed [{time.perf_counter() - t_start:.0f} s]", flush=True)
        for r in runners:
            if isinstance(r, StepRunner):
                bd_ns = args.breakdown_ns if (w, h) == RESOLUTIONS[0] else args.breakdown_ns[-1:]
                if not args.no_breakdown and (r.method == "lvm" or r.n in bd_ns):
                    r.extra.update(breakdown(r))
                if (
                    not args.no_host
                    and (w, h) == RESOLUTIONS[0]
                    and (r.method == "lvm" or r.n in (5, 20))
                ):
                    r.extra.update(host_overhead(r, len(frames)))
            records.append(record_of(r, machine))
        print(f"  breakdown done [{time.perf_counter() - t_start:.0f} s]", flush=True)
        del runners

    machine["loadavg_end"] = [round(v, 2) for v in os.getloadavg()]
    total = time.perf_counter() - t_start
    print(table(records))
    print(
        "\nhost overhead at 160x120 (ms per frame; 'added' = the public call's wall time minus"
        " its own step call, paired per frame): step | Tracker.update (added) | Tracker.run"
        " (added)"
    )
    for rec in records:
        if "update_ms" in rec:
            print(
                f"  {rec['method']:5s} N={rec['N']:<3d} {rec['ms_median']:7.2f} | "
                f"{rec['update_ms']:7.2f} ({rec['update_overhead_ms']:.2f}) | "
                f"{rec['run_ms_per_frame']:7.2f} ({rec['run_overhead_ms_per_frame']:.2f})"
            )
    sc = [r for r in records if r["method"] == "scipy"]
    if sc:
        print(
            f"\nscipy baseline: {sc[0]['frames_timed']} timed frames per N, loss 'l2', "
            f"residual evaluations per fit (finite differences included): mean "
            f"{np.mean([r['scipy_evals_per_fit'] for r in sc]):.0f}, median "
            f"{np.median([r['scipy_evals_per_fit_median'] for r in sc]):.0f}; render + Delta "
            "by posetrack's jitted single-hypothesis scorer"
        )
    print("\ntargets (160x120):")
    for name, value, ok in targets(records):
        status = "not measured" if ok is None else ("met" if ok else "MISSED")
        print(f"  {name:45s} {value:>12s}  {status}")
    print(
        f"\nload average start {machine['loadavg_start']} end {machine['loadavg_end']}; "
        f"total {total:.0f} s"
    )
    if args.json:
        atomic_write_text(args.json, json.dumps(records, indent=1))
        print(f"wrote {args.json}")
    return records


if __name__ == "__main__":
    sys.exit(0 if main() is not None else 1)
