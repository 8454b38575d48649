#!/usr/bin/env python
"""Speed of one tracker step: batched LVM and MHT_h against a Python loop and scipy (issue 4).

Every measured configuration runs on the same generated sequence (``posetrack.synth``, motion
"walk", seed 0, 640x480 uint16 depth) from the same initial pose; one frame is:

* ``lvm`` / ``mht_h``: ``posetrack._tracker.step`` exactly as ``Tracker.update`` calls it
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
* ``scipy_equal`` (baseline b, the same work as the tracker's fits, done the way a scipy user
  with a JAX model would): per hypothesis, serially,
  ``scipy.optimize.least_squares(method="lm", jac=..., max_nfev=config.fit.max_steps)`` on
  posetrack's own residual function (``posetrack._fit.fit_residuals``, jitted) with its
  analytic forward-mode Jacobian (``jax.jacfwd`` of it, jitted; the forward kinematics carry
  an analytic ``custom_jvp``), from the same start with the same masks. The cap: optimistix'
  ``max_steps = k`` evaluates residuals and Jacobian at the start and at k - 1 trial points
  and returns the last accepted one (``max_steps = 1`` returns the start); MINPACK's
  ``lmder`` evaluates the residuals at the start, the Jacobian at every accepted point, and
  stops once it has made ``max_nfev`` residual evaluations, i.e. after ``max_nfev - 1`` trial
  points; scipy then evaluates the Jacobian once more at the solution (for ``grad``). So
  ``max_nfev = k`` is exactly the same budget: k residual evaluations, at most k Jacobian
  evaluations (``njev`` <= k - 1 inside MINPACK, plus scipy's final one), k - 1 LM trial
  steps. The counts actually made are recorded (``scipy_nfev_*``, ``scipy_njev_*``, and
  ``scipy_calls_*``: calls of our residual / Jacobian functions, which is what costs) and
  checked by ``tests/test_speed_baselines.py``. scipy's default tolerances stay (the cap
  binds first). The consensus refit is another such fit.
* ``scipy_converged`` (baseline c, what a Python user would write without JAX): per
  hypothesis ``scipy.optimize.least_squares(method="lm")`` with a NumPy forward model
  (:func:`np_keypoints`, this file) and scipy's default finite-difference Jacobian and
  tolerances, run to convergence (no cap: a different amount of work from the tracker's
  capped fits; its residual evaluations per fit are recorded), on the residuals of
  Eq. (1) in their plain least-squares form (``ResidualSettings(loss="l2")``, as the MHT's
  fits use: same masks, same 2D scaling and the same two regularisers). Measured on a few
  frames only (``--scipy-frames``, default 3) at N in {1, 5, 20}: it is slow.

In both scipy baselines lifting, subset sampling and each hypothesis' render + Delta reuse
posetrack's jitted functions (the point of them is the fitting cost). After the timed frames,
each scipy fit's landmark cost is compared with posetrack's ``fit_pose`` (the tracker's
settings) from the same start with the same masks (``fit_cost_ratio_*``: scipy / posetrack;
below 1: scipy's fit is closer to the landmarks).

Timing: the configurations of one resolution are interleaved frame by frame (round robin), so
a neighbour's load hits them alike and the ratios printed are measured under the same
conditions. ``ms_median`` is the median over ``--frames`` frames after ``--warmup`` frames;
``compile_s`` is the first call's wall time (trace + compile + one run) minus ``ms_median``.
The machine's load average (``os.getloadavg()``) is printed at the start and at the end and
stored in every record's ``machine`` (``loadavg_start``, ``loadavg_end``).

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
    python benchmarks/speed.py --quick       # N in {1, 5, 20}, 160x120, scipy_converged N=5 on
                                             # 1 frame, no breakdown: ~90 s on a quiet machine
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
from posetrack import SmoothSettings, TrackerConfig
from posetrack._body import JOINT_PARENTS, KEYPOINT_FRAMES, normalize_params
from posetrack._depthobs import tracker_landmarks, tracker_observation
from posetrack._fit import FitSettings, fit_hypotheses, fit_pose, fit_problem, fit_residuals
from posetrack._inputs import check_frame
from posetrack._residuals import ResidualSettings, landmark_residuals
from posetrack._select import landmark_subsets
from posetrack._so3 import quat_to_matrix
from posetrack._step import (
    TrackState,
    consensus_refit,
    reseed_hypotheses,
    score_hypotheses,
)
from posetrack._tracker import Tracker, step
from posetrack.app import machine_info
from posetrack.io import atomic_write_text

DTYPE = jnp.float32
RESOLUTIONS = ((160, 120), (320, 240))
NS = (1, 5, 10, 20, 50, 100)  # 10: the shipped default
# =============================================================================================
# NumPy forward model and Eq. (1) residuals (baseline c, scipy_converged).
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


#: The head keypoints in the neck frame of a default-size head (left eye and ear; the right
#: ones mirror x), metres: posetrack's ``BodyShape`` values, written out again here so the
#: NumPy model is an independent reference (``tests/test_speed_baselines.py`` checks that
#: :func:`np_keypoints` equals ``posetrack.keypoints``).
HEAD_NOSE = (0.0, 0.17, 0.11)
HEAD_EYE = (0.033, 0.205, 0.085)
HEAD_EAR = (0.075, 0.185, 0.0)


def np_keypoint_offsets(shape: dict[str, float]) -> np.ndarray:
    """(18, 3) each COCO-18 keypoint in the frame it rides on (``KEYPOINT_FRAMES``), metres."""
    k = shape["head_scale"]
    nose, eye, ear = (np.asarray(v) for v in (HEAD_NOSE, HEAD_EYE, HEAD_EAR))
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


_PARENTS = np.asarray(JOINT_PARENTS)
_KP_FRAMES = np.asarray(KEYPOINT_FRAMES)
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
    R = quat_to_matrix(params[3:].reshape(10, 4))  # NumPy, any norm (0 -> identity)
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

    The same vector as ``posetrack._fit.fit_residuals`` with ``ResidualSettings(loss="l2")``:
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


def landmarks_to_numpy(lm: pt.Landmarks) -> dict[str, np.ndarray]:
    return {
        "points3d": np.asarray(lm.points3d, np.float64),
        "keypoints2d": np.asarray(lm.keypoints2d, np.float64),
        "has_depth": np.asarray(lm.has_depth, bool),
        "detected": np.asarray(lm.detected, bool),
    }


# =============================================================================================
# Baseline b (scipy_equal): scipy's MINPACK LM on posetrack's residuals and JAX Jacobian.
# =============================================================================================


@partial(jax.jit, static_argnums=0)
def problem_one(residuals: ResidualSettings, start, shape, intrinsics, lm, use3d, use2d):
    """``fit_problem`` of one hypothesis: (normalised start, args without the settings)."""
    start, args = fit_problem(
        start, shape, lm, intrinsics, use3d=use3d, use2d=use2d, residuals=residuals
    )
    return start, args[:-1]  # the settings are static: jit returns arrays only


@partial(jax.jit, static_argnums=0)
def residuals_one(residuals: ResidualSettings, params, args):
    """``fit_residuals`` (Eq. (1) + regularisers), jitted."""
    return fit_residuals(params, (*args, residuals))


@partial(jax.jit, static_argnums=0)
def jacobian_one(residuals: ResidualSettings, params, args):
    """The (residual, 43) Jacobian of ``fit_residuals``, forward mode (``jax.jacfwd``; the
    forward kinematics' analytic ``custom_jvp`` does the work), jitted."""
    return jax.jacfwd(fit_residuals)(params, (*args, residuals))


@partial(jax.jit, static_argnums=0)
def fit_cost(residuals: ResidualSettings, params, start, shape, intrinsics, lm, use3d, use2d):
    """``FitResult.cost`` of ``params`` (normalised) for the problem ``fit_pose`` builds from
    ``start``: the landmark term without regularisers, 2D scale fixed at the start."""
    _, args = fit_problem(
        start, shape, lm, intrinsics, use3d=use3d, use2d=use2d, residuals=residuals
    )
    _, _, _, u3, u2, mpp, _, _ = args
    r = landmark_residuals(
        normalize_params(params), shape, lm, intrinsics,
        use3d=u3, use2d=u2, metres_per_pixel=mpp, settings=residuals,
    )  # fmt: skip
    return jnp.sum(r * r)


class ScipyEqualFit:
    """``scipy.optimize.least_squares(method="lm")`` with the same budget as ``fit_pose``.

    Residuals and Jacobian are posetrack's (:func:`residuals_one`, :func:`jacobian_one`), in
    the process' JAX dtype; MINPACK iterates in float64. ``max_nfev = settings.max_steps``: the
    same number of residual evaluations (``max_steps``), Jacobian evaluations (at most
    ``max_steps``: MINPACK's ``njev <= max_steps - 1`` plus scipy's final one) and LM trial
    steps (``max_steps - 1``) as optimistix' ``max_steps`` (see the module docstring).
    """

    def __init__(self, shape: pt.BodyShape, intrinsics: pt.Intrinsics, settings: FitSettings):
        self.shape, self.intrinsics = shape, intrinsics
        self.settings = settings
        self.max_nfev = settings.max_steps
        self.nfev: list[int] = []  # MINPACK's counts, per fit
        self.njev: list[int] = []
        self.fun_calls: list[int] = []  # calls of our functions, per fit (what costs)
        self.jac_calls: list[int] = []
        self.fit_seconds: list[float] = []

    def fit(self, start, lm: pt.Landmarks, use3d, use2d) -> np.ndarray:
        """One fit from ``start`` (43,) with masks (18,); returns the normalised pose (float64;
        the start where scipy returned a non-finite pose)."""
        from scipy.optimize import least_squares

        t0 = time.perf_counter()
        res = self.settings.residuals
        start, args = problem_one(res, start, self.shape, self.intrinsics, lm, use3d, use2d)
        calls = [0, 0]

        def fun(x):
            calls[0] += 1
            return np.asarray(residuals_one(res, x, args), np.float64)

        def jac(x):
            calls[1] += 1
            return np.asarray(jacobian_one(res, x, args), np.float64)

        x0 = np.asarray(start, np.float64)
        sol = least_squares(fun, x0, jac=jac, method="lm", max_nfev=self.max_nfev)
        params = np_normalize_params(sol.x)
        if not np.all(np.isfinite(params)):
            params = x0
        self.nfev.append(int(sol.nfev))
        self.njev.append(int(sol.njev))
        self.fun_calls.append(calls[0])
        self.jac_calls.append(calls[1])
        self.fit_seconds.append(time.perf_counter() - t0)
        return params


# =============================================================================================
# Jitted pieces of tracker_step: the baselines' shared parts and the breakdown.
# =============================================================================================


def _one(config: TrackerConfig) -> TrackerConfig:
    """The config of the parts that do not depend on N or the method (one compile per
    resolution for them, shared by every N)."""
    return config.replace(method="mht_h", num_hypotheses=1)


@jax.jit
def lift_select(config, shape, intrinsics, state, depth, kp2d, conf):
    """Lifting + landmark weights + subset sampling (the start of ``tracker_step``)."""
    key, key_next = jax.random.split(state.key)
    lm = tracker_landmarks(config, shape, intrinsics, depth, kp2d, conf)
    use3d, use2d = landmark_subsets(config, key, shape, intrinsics, depth, lm, state.previous)
    return lm, use3d, use2d, key_next


@jax.jit
def observe(config, intrinsics, floor, best, depth):
    """The 640x480 -> scoring-size downsample and the observation maps of Eq. (3):
    ``(z_d, z_fg, known, small_intrinsics)``."""
    return tracker_observation(config, depth, intrinsics, floor, best[:3])


@jax.jit
def fits_batched(config, shape, intrinsics, lm, hypotheses, use3d, use2d):
    """The N vmapped LM fits of the step."""
    return fit_hypotheses(
        hypotheses, shape, lm, intrinsics, use3d=use3d, use2d=use2d, settings=config.fit
    )


@jax.jit
def render_batched(config, shape, small_intr, params, z_d, z_fg, known):
    """The N renders + Delta of the step."""
    return score_hypotheses(config, shape, params, z_d, z_fg, small_intr, known)


@partial(jax.jit, static_argnums=0)
def fit_one(settings, start, shape, intrinsics, lm, use3d, use2d):
    """One hypothesis' fit (baseline a)."""
    return fit_pose(start, shape, lm, intrinsics, use3d=use3d, use2d=use2d, settings=settings)


@jax.jit
def score_one(config, shape, small_intr, params, z_d, z_fg, known):
    """One hypothesis' render + Delta (all baselines)."""
    return score_hypotheses(config, shape, params[None], z_d, z_fg, small_intr, known)[0]


@jax.jit
def refit_one(config, shape, intrinsics, lm, chosen, chosen_delta, z_d, z_fg, small_intr, known):
    """The consensus refit of the winner: one fit + one render + Delta."""

    def score(p):
        return score_hypotheses(config, shape, p, z_d, z_fg, small_intr, known)

    return consensus_refit(config, shape, intrinsics, lm, chosen, chosen_delta, score)


@jax.jit
def finish(config, shape, params, deltas, best, chosen, chosen_delta, key_next):
    """The end of ``tracker_step``: reseed and the next state (all baselines)."""
    params = params.at[best].set(chosen)
    hyps = reseed_hypotheses(config, params, deltas, best, chosen)
    kps = jax.vmap(lambda p: pt.keypoints(shape, p))(hyps)
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
            check_frame(intr, seq.depth[t], seq.keypoints2d[t], seq.confidence[t], 1000.0, "b")
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
        self.config1 = _one(config)
        self.tracker = Tracker(frames.seq.intrinsics, config, shape=frames.shape)
        # Tracker internals (no public accessor): the initialisation alone, without a first
        # step (which would compile before ``measure`` times it), and the state and floor it
        # leaves for the jitted step.
        ok = self.tracker.initialize(frames.depth[0], frames.kp[0], frames.conf[0])
        if not ok:
            raise RuntimeError("benchmark sequence: initialisation failed on frame 0")
        self.state: TrackState = self.tracker.state
        self.floor = self.tracker.floor
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
        return (self.tracker.shape, f.intrinsics, self.floor, self.state,
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
    """``posetrack._tracker.step`` as ``Tracker.update`` calls it."""

    def __init__(self, frames, config, **kw):
        super().__init__(frames, config, **kw)
        self.method = config.method
        self.record_inputs = True

    def advance(self, t):
        state, est = step(self.config, *self.args(t))
        jax.block_until_ready(est)
        self.last = est
        self._accept(state, est.num_3d, est.delta)

    def compile_count(self):
        return step._cache_size()

    def memory(self, t):
        compiled = step.lower(self.config, *self.args(t)).compile()
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
            self.config, shape, f.intrinsics, self.state, f.depth[t], f.kp[t], f.conf[t]
        )
        obs = observe(self.config1, f.intrinsics, self.floor, self.state.best, f.depth[t])
        return lm, use3d, use2d, key_next, obs

    def finish(self, params, deltas, lm, obs, key_next):
        """Selection, consensus refit, reseed; ``deltas`` on the host."""
        shape = self.tracker.shape
        best = int(np.argmin(deltas))
        chosen, chosen_delta = params[best], jnp.asarray(deltas[best], DTYPE)
        if self.config.consensus_refit and self.config.method != "lvm":
            z_d, z_fg, known, small_intr = obs
            chosen, chosen_delta = refit_one(
                self.config1, shape, self.frames.intrinsics, lm, chosen, chosen_delta,
                z_d, z_fg, small_intr, known,
            )  # fmt: skip
        state, kp = finish(self.config, shape, params, jnp.asarray(deltas, DTYPE), best, chosen,
                           chosen_delta, key_next)  # fmt: skip
        jax.block_until_ready(state)
        self.last = (chosen, chosen_delta, best, kp)
        self._accept(state, jnp.sum(lm.has_depth), chosen_delta)

    def advance(self, t):
        shape, intr = self.tracker.shape, self.frames.intrinsics
        lm, use3d, use2d, key_next, obs = self.prepare(t)
        z_d, z_fg, known, small_intr = obs
        params, deltas = [], []
        for h in range(self.n):
            res = fit_one(self.config.fit, self.state.hypotheses[h], shape, intr, lm,
                          use3d[h], use2d[h])  # fmt: skip
            params.append(res.params)
            deltas.append(score_one(self.config1, shape, small_intr, res.params, z_d, z_fg,
                                    known))  # fmt: skip
        self.finish(jnp.stack(params), np.asarray(jnp.stack(deltas)), lm, obs, key_next)


class ScipyRunner(LoopRunner):
    """The scipy baselines: a scipy fit per hypothesis; posetrack's render + Delta.

    Subclasses say how one hypothesis is fitted (:meth:`fit`)."""

    def __init__(self, frames, config, **kw):
        import scipy.optimize  # noqa: F401  (imported here, not inside the first timed frame)

        super().__init__(frames, config, **kw)
        # NumPy keypoints and projection for the consensus refit's inlier masks.
        self.model = NumpyResiduals(frames.shape, frames.intrinsics)
        self.fits: list = []  # (start, lm, use3d, use2d, params) of each hypothesis' fit

    def fit(self, start, lm, lm_np, use3d, use2d) -> np.ndarray:
        raise NotImplementedError

    def advance(self, t):
        shape = self.tracker.shape
        lm, use3d, use2d, key_next, obs = self.prepare(t)
        z_d, z_fg, known, small_intr = obs
        lm_np = landmarks_to_numpy(lm)
        use3d, use2d = np.asarray(use3d), np.asarray(use2d)
        starts = np.asarray(self.state.hypotheses)
        params, deltas = [], []
        for h in range(self.n):
            p = self.fit(starts[h], lm, lm_np, use3d[h], use2d[h])
            self.fits.append((starts[h], lm, use3d[h], use2d[h], p))
            params.append(p)
            deltas.append(float(score_one(self.config1, shape, small_intr,
                                          jnp.asarray(p, DTYPE), z_d, z_fg, known)))  # fmt: skip
        deltas = np.asarray(deltas)
        best = int(np.argmin(deltas))
        chosen, chosen_delta = params[best], deltas[best]
        if self.config.consensus_refit and self.config.method != "lvm":
            chosen, chosen_delta = self.consensus_refit(chosen, chosen_delta, lm, lm_np, obs)
        state, kp = finish(self.config, shape, jnp.asarray(np.stack(params), DTYPE),
                           jnp.asarray(deltas, DTYPE), best, jnp.asarray(chosen, DTYPE),
                           jnp.asarray(chosen_delta, DTYPE), key_next)  # fmt: skip
        jax.block_until_ready(state)
        self.last = (chosen, chosen_delta, best, kp)
        self._accept(state, lm_np["has_depth"].sum(), chosen_delta)

    def consensus_refit(self, chosen, chosen_delta, lm, lm_np, obs):
        """``consensus_refit`` with this baseline's fit (inlier masks as there)."""
        z_d, z_fg, known, small_intr = obs
        m = self.model
        M = m.keypoints(chosen)
        tau = self.config.consensus_distance
        d3 = np.linalg.norm(M - lm_np["points3d"], axis=-1)
        d2 = (np.linalg.norm(m.project(M) - lm_np["keypoints2d"], axis=-1)
              * np.maximum(M[:, 2], 0.2) / np.sqrt(m.fx * m.fy))  # fmt: skip
        use3d, use2d = lm_np["has_depth"] & (d3 < tau), lm_np["detected"] & (d2 < tau)
        p = self.fit(chosen, lm, lm_np, use3d, use2d)
        d = float(score_one(self.config1, self.tracker.shape, small_intr,
                            jnp.asarray(p, DTYPE), z_d, z_fg, known))  # fmt: skip
        return (p, d) if d <= chosen_delta else (chosen, chosen_delta)

    def fit_quality(self) -> dict:
        """Landmark cost of each recorded hypothesis fit over posetrack's ``fit_pose`` (the
        tracker's settings) from the same start with the same masks (untimed)."""
        shape, intr, fs = self.tracker.shape, self.frames.intrinsics, self.config.fit
        ratios = []
        for start, lm, u3, u2, p in self.fits:
            start = jnp.asarray(start, DTYPE)
            ours = float(fit_one(fs, start, shape, intr, lm, u3, u2).cost)
            theirs = float(fit_cost(fs.residuals, jnp.asarray(p, DTYPE), start, shape, intr, lm,
                                    u3, u2))  # fmt: skip
            ratios.append(theirs / max(ours, 1e-12))
        r = np.asarray(ratios)
        return {
            "fit_cost_ratio_median": round(float(np.median(r)), 3),
            "fit_cost_ratio_p10": round(float(np.percentile(r, 10)), 3),
            "fit_cost_ratio_p90": round(float(np.percentile(r, 90)), 3),
            "fits_compared": len(r),
        }


class ScipyEqualRunner(ScipyRunner):
    """Baseline (b): scipy LM on posetrack's residuals and JAX Jacobian, the tracker's cap."""

    method = "scipy_equal"

    def __init__(self, frames, config, **kw):
        super().__init__(frames, config, **kw)
        self.fitter = ScipyEqualFit(frames.shape, frames.intrinsics, config.fit)

    def fit(self, start, lm, lm_np, use3d, use2d):
        return self.fitter.fit(jnp.asarray(start, DTYPE), lm, use3d, use2d)


class ScipyConvergedRunner(ScipyRunner):
    """Baseline (c): scipy LM, NumPy model, finite differences, default tolerances."""

    method = "scipy_converged"
    warmup = 0
    #: No compiling call: its jitted parts (lifting, scorer, refit masks) are the loop
    #: baseline's, compiled before it; scipy itself has nothing to compile.
    compile_call = False

    def __init__(self, frames, config, **kw):
        super().__init__(frames, config, **kw)
        if config.fit.residuals != self.model.settings:
            raise ValueError("scipy_converged implements the MHT's l2 residuals only")
        self.nfev: list[int] = []

    def fit(self, start, lm, lm_np, use3d, use2d):
        p, nfev = self.model.fit(np.asarray(start, np.float64), lm_np, use3d, use2d)
        self.nfev.append(nfev)
        return p


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
    sh, intr, floor = r.tracker.shape, f.intrinsics, r.floor
    cfg, cfg1 = r.config, r.config1
    ins = r.inputs
    out = {}
    _, out["lift_select_ms"], ls = _time_replay(
        lambda i: lift_select(cfg, sh, intr, ins[i][0], f.depth[ins[i][1]], f.kp[ins[i][1]],
                              f.conf[ins[i][1]]), ins)  # fmt: skip
    _, out["fits_ms"], fits = _time_replay(
        lambda i: fits_batched(cfg, sh, intr, ls[i][0], ins[i][0].hypotheses, ls[i][1],
                               ls[i][2]), ins)  # fmt: skip
    steps = np.stack([np.asarray(x.num_steps) for x in fits])
    out["lm_steps_mean"] = round(float(steps.mean()), 2)
    out["lm_steps_max"] = int(steps.max())
    _, out["obs_ms"], obs = _time_replay(
        lambda i: observe(cfg1, intr, floor, ins[i][0].best, f.depth[ins[i][1]]), ins
    )
    _, out["render_ms"], deltas = _time_replay(
        lambda i: render_batched(cfg, sh, obs[i][3], fits[i].params, *obs[i][:3]), ins
    )
    parts = ["lift_select_ms", "fits_ms", "obs_ms", "render_ms"]
    if r.config.consensus_refit and r.config.method != "lvm":

        def refit(i):
            b = int(np.argmin(np.asarray(deltas[i])))
            return refit_one(cfg1, sh, intr, ls[i][0], fits[i].params[b], deltas[i][b],
                             obs[i][0], obs[i][1], obs[i][3], obs[i][2])  # fmt: skip

        _, out["refit_ms"], _ = _time_replay(refit, ins)
        parts.append("refit_ms")
    out = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in out.items()}
    out["rest_ms"] = round(float(np.median(r.times)) * 1e3 - sum(out[p] for p in parts), 3)
    return out


def host_overhead(r: StepRunner, n_frames: int) -> dict:
    """What ``Tracker.update`` and ``Tracker.run`` add to the step, per frame.

    Paired within each call, so robust to a neighbour's load: the Tracker records the wall time
    of its own ``step`` call + ``block_until_ready`` (``step_times``); the overhead is the
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
    update_over = np.asarray(walls) - np.asarray(tr.step_times[-len(walls) :])
    # run() on frames 1.. of a tracker initialised on frame 0: the one-off initialisation
    # (pose from landmarks, 60-step fit, floor RANSAC) is not a per-frame cost.
    # Per-frame: the loop's own overhead (motion.py times the offline smoother beside it).
    tr2 = Tracker(seq.intrinsics, r.config, shape=r.frames.shape, mode="per-frame")
    tr2.update(seq.depth[0], seq.keypoints2d[0], seq.confidence[0])
    n_before = len(tr2.step_times)
    t0 = time.perf_counter()
    tr2.run(seq.depth[1:T], seq.keypoints2d[1:T], seq.confidence[1:T], progress=None)
    run_s = time.perf_counter() - t0
    run_steps = tr2.step_times[n_before:]
    # The motion models on the same frames: online (one extra jitted call per frame, at the
    # default lag) and offline (the smoother after the forward pass), each against its own
    # steps.
    tr3 = Tracker(seq.intrinsics, r.config, shape=r.frames.shape, mode="online")
    for t in range(T):
        tr3.update(seq.depth[t], seq.keypoints2d[t], seq.confidence[t])
    online_ms = 1e3 * float(np.median(tr3.motion_times[1:]))
    online_step = 1e3 * float(np.median(tr3.step_times))
    # The left/right judgement tracks the first frames of each exchange twice
    # (SideSettings.online_frames).
    twice = sum(stop - start for start, stop, *_ in tr3.side_spans) / T
    # The smoother works in windows of 96 frames (80 new each): a recording of 176 frames
    # (the T frames played forward and back) is two windows, the steady-state cost per frame.
    k = len(seq.depth)
    idx = [min(i % (2 * k - 2), 2 * k - 3 - i % (2 * k - 2)) if k > 1 else 0 for i in range(176)]
    frames = ([seq.depth[i] for i in idx], [seq.keypoints2d[i] for i in idx],
              [seq.confidence[i] for i in idx])  # fmt: skip
    tr4 = Tracker(seq.intrinsics, r.config, shape=r.frames.shape, mode="offline")
    tr4.run(*frames, progress=None)
    tr4 = Tracker(seq.intrinsics, r.config, shape=r.frames.shape, mode="offline")
    tr4.run(*frames, progress=None)  # compiled now: the timed run
    offline_ms = 1e3 * tr4.smooth_s / len(idx)
    offline_step = 1e3 * float(np.median(tr4.step_times))
    # Offline both ways (SmoothSettings.both_ways): a second per-frame pass, backwards; its
    # steps per frame (2, plus any stretch the left/right arbitration tracked twice) at its
    # own median step, and its smoothers and fusion, against its own median step. Run twice:
    # the fusion's pose fit is a program of its own, compiled in the first run.
    for _ in range(2):
        tr5 = Tracker(
            seq.intrinsics, r.config, shape=r.frames.shape, mode="offline",
            motion=SmoothSettings(both_ways=True),
        )  # fmt: skip
        tr5.run(*frames, progress=None)
    both_steps = len(tr5.step_times) / len(idx)
    both_step = 1e3 * float(np.median(tr5.step_times))
    both_ms = 1e3 * tr5.smooth_s / len(idx)
    return {
        "online_ms": round(online_ms, 3),
        "online_retracked_share": round(twice, 3),
        "online_total_over_step": round((online_step + online_ms) * (1 + twice) / online_step, 3),
        "offline_ms_per_frame": round(offline_ms, 3),
        "offline_total_over_step": round((offline_step + offline_ms) / offline_step, 3),
        "offline_both_ways_steps_per_frame": round(both_steps, 3),
        "offline_both_ways_total_over_step": round(
            (both_steps * both_step + both_ms) / both_step, 3
        ),
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
    cache = step._cache_size()
    for k, t in enumerate(range(2, 2 + warmup + n_timed)):
        for r in runners:
            timed = k - (warmup if r.warmup is None else r.warmup)
            if timed < 0:
                r.advance(t)
            elif r.wants(timed):
                r.times.append(r.timed(t, record=True))
    retraced = step._cache_size() - cache
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
    if isinstance(r, ScipyConvergedRunner):
        rec["jacobian"] = "finite differences (scipy default), NumPy model"
        rec["stopping"] = "scipy defaults (ftol = xtol = gtol = 1e-8), no cap"
        rec["scipy_evals_per_fit"] = round(float(np.mean(r.nfev)), 1)
        rec["scipy_evals_per_fit_median"] = float(np.median(r.nfev))
        rec["scipy_evals_per_fit_max"] = int(np.max(r.nfev))
        fit_s = r.model.fit_seconds
        rec["scipy_ms_per_fit_median"] = round(1e3 * float(np.median(fit_s)), 2)
        rec["scipy_us_per_evaluation"] = round(1e6 * float(np.sum(fit_s)) / sum(r.nfev), 1)
        rec["loss"] = "l2"
    if isinstance(r, ScipyEqualRunner):
        fr = r.fitter
        rec["jacobian"] = "jax.jacfwd of posetrack's fit_residuals, jitted"
        rec["stopping"] = f"max_nfev = fit.max_steps = {fr.max_nfev} (scipy default tolerances)"
        rec["fit_max_steps"] = r.config.fit.max_steps
        rec["scipy_max_nfev"] = fr.max_nfev
        for name, v in (("nfev", fr.nfev), ("njev", fr.njev), ("fun_calls", fr.fun_calls),
                        ("jac_calls", fr.jac_calls)):  # fmt: skip
            rec[f"scipy_{name}_mean"] = round(float(np.mean(v)), 2)
            rec[f"scipy_{name}_min"] = int(np.min(v))
            rec[f"scipy_{name}_max"] = int(np.max(v))
        rec["scipy_fits"] = len(fr.nfev)
        rec["scipy_ms_per_fit_median"] = round(1e3 * float(np.median(fr.fit_seconds)), 3)
        rec["loss"] = r.config.fit.residuals.loss
    if isinstance(r, ScipyRunner):
        rec.update(r.fit_quality())
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
            "| N | LVM | MHT_h | MHT_h/LVM | loop (a) | loop/MHT_h | scipy equal (b) "
            "| equal/MHT_h | scipy converged (c) | converged/MHT_h | compile s | lift+sel | fits "
            "| LM steps | obs | render | refit | rest | XLA temp MB | maxrss MB |",
            "|---" * 20 + "|",
        ]
        if lvm:
            lines.append(_row("LVM", lvm, None, None, None, None))
        for n in ns:
            h = _find(records, "mht_h", n, res)
            if h is None:
                continue
            lines.append(_row(str(n), h, lvm, _find(records, "loop", n, res),
                              _find(records, "scipy_equal", n, res),
                              _find(records, "scipy_converged", n, res)))  # fmt: skip
    return "\n".join(lines)


def _f(x, fmt="{:.1f}"):
    return "-" if x is None else fmt.format(x)


def _row(label, h, lvm, loop, equal, converged) -> str:
    ms = h["ms_median"]
    cells = [
        label,
        _f(lvm["ms_median"] if lvm else (ms if label == "LVM" else None)),
        _f(ms) if label != "LVM" else "-",
        _f(ms / lvm["ms_median"] if lvm else None, "{:.2f}x"),
        _f(loop["ms_median"] if loop else None),
        _f(loop["ms_median"] / ms if loop else None, "{:.1f}x"),
        _f(equal["ms_median"] if equal else None),
        _f(equal["ms_median"] / ms if equal else None, "{:.1f}x"),
        _f(converged["ms_median"] if converged else None, "{:.0f}"),
        _f(converged["ms_median"] / ms if converged else None, "{:.0f}x"),
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
    loop20 = _find(records, "loop", 20, res)
    equal20 = _find(records, "scipy_equal", 20, res)
    conv20 = _find(records, "scipy_converged", 20, res)
    out = []

    def add(name, value, fmt, ok):
        out.append((name, "-" if value is None else fmt.format(value),
                    None if value is None else bool(ok)))  # fmt: skip

    r = h20["ms_median"] / lvm["ms_median"] if (h20 and lvm) else None
    add("MHT_h N=20 <= 4x LVM", r, "{:.2f}x", r is not None and r <= 4)
    r = h5["ms_median"] / lvm["ms_median"] if (h5 and lvm) else None
    add("MHT_h N=5 <= 2x LVM", r, "{:.2f}x", r is not None and r <= 2)
    r = equal20["ms_median"] / h20["ms_median"] if (equal20 and h20) else None
    add("MHT_h N=20 >= 100x faster than scipy, equal work (b)", r, "{:.1f}x",
        r is not None and r >= 100)  # fmt: skip
    r = conv20["ms_median"] / h20["ms_median"] if (conv20 and h20) else None
    add("MHT_h N=20 >= 100x faster than scipy, to convergence (c)", r, "{:.0f}x",
        r is not None and r >= 100)  # fmt: skip
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


def _loadavg() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


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
    parser.add_argument(
        "--scipy-frames", type=int, default=3, help="timed frames of scipy_converged"
    )
    parser.add_argument(
        "--scipy-ns",
        type=int,
        nargs="+",
        default=None,
        help="N of the scipy_converged baseline (default 1 5 20; --quick: 5)",
    )
    parser.add_argument(
        "--scipy-equal-ns",
        type=int,
        nargs="+",
        default=[5, 20],
        help="N of the scipy_equal baseline, timed on every frame (default 5 20)",
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
        # What keeps --quick near 90 s on 2 cores: scipy_converged at N=20 alone took ~25 s per
        # frame and the breakdown ~12 s (plus compiles); the full run measures both.
        args.scipy_frames = min(args.scipy_frames, 1)
        args.no_host = True
        if args.breakdown_ns is None:
            args.no_breakdown = True
    if args.breakdown_ns is None:
        args.breakdown_ns = [5, 20]

    machine = machine_info()
    machine["loadavg_start"] = _loadavg()
    print("machine: " + " | ".join(f"{k}: {v}" for k, v in machine.items()), flush=True)
    print(f"load average at the start (1, 5, 15 min): {machine['loadavg_start']}", flush=True)
    t_start = time.perf_counter()
    frames = Frames.make(2 + args.warmup + args.frames)
    print(f"sequence: {len(frames)} frames 640x480 (synth walk, seed 0) "
          f"[{time.perf_counter() - t_start:.1f} s]", flush=True)  # fmt: skip

    records = []
    for w, h in resolutions:
        res = f"{w}x{h}"
        base = dict(score_width=w, score_height=h)

        def mht(n, base=base):
            return TrackerConfig.recommended("mht_h", num_hypotheses=n, **base)

        runners: list[Runner] = [StepRunner(frames, TrackerConfig.paper("lvm", **base))]
        runners += [StepRunner(frames, mht(n)) for n in ns]
        if not args.no_baselines and (w, h) == RESOLUTIONS[0]:
            runners += [LoopRunner(frames, mht(n)) for n in ns if n <= args.loop_max_n]
            runners += [ScipyEqualRunner(frames, mht(n)) for n in ns if n in args.scipy_equal_ns]
            runners += [
                ScipyConvergedRunner(frames, mht(n), max_frames=args.scipy_frames)
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
                    and (r.method == "lvm" or r.n in (5, 10, 20))
                ):
                    r.extra.update(host_overhead(r, len(frames)))
            records.append(record_of(r, machine))
        print(f"  breakdown done [{time.perf_counter() - t_start:.0f} s]", flush=True)
        del runners

    # ``machine`` is shared by every record: the end load lands in all of them.
    machine["loadavg_end"] = _loadavg()
    total = time.perf_counter() - t_start
    print(table(records))
    print(
        "\nhost overhead at 160x120 (ms per frame; 'added' = the public call's wall time minus"
        " its own step call, paired per frame): step | Tracker.update (added) | Tracker.run"
        " (added) | online motion model (total / step) | offline smoother (total / step) | offline"
        " both ways (total / step)"
    )
    for rec in records:
        if "update_ms" in rec:
            print(
                f"  {rec['method']:5s} N={rec['N']:<3d} {rec['ms_median']:7.2f} | "
                f"{rec['update_ms']:7.2f} ({rec['update_overhead_ms']:.2f}) | "
                f"{rec['run_ms_per_frame']:7.2f} ({rec['run_overhead_ms_per_frame']:.2f}) | "
                f"online +{rec['online_ms']:.2f} ({rec['online_total_over_step']:.2f}x) | "
                f"offline +{rec['offline_ms_per_frame']:.2f} "
                f"({rec['offline_total_over_step']:.2f}x) | "
                f"both ways {rec['offline_both_ways_total_over_step']:.2f}x"
            )
    for rec in records:
        if rec["method"] == "scipy_equal":
            print(
                f"\nscipy_equal N={rec['N']}: {rec['frames_timed']} timed frames, "
                f"max_nfev {rec['scipy_max_nfev']} (fit.max_steps {rec['fit_max_steps']}); per "
                f"fit ({rec['scipy_fits']} fits): nfev {rec['scipy_nfev_min']}-"
                f"{rec['scipy_nfev_max']}, njev {rec['scipy_njev_min']}-{rec['scipy_njev_max']}"
                f" (mean {rec['scipy_njev_mean']}), calls of our residual / Jacobian function "
                f"{rec['scipy_fun_calls_max']} / {rec['scipy_jac_calls_max']} (max); "
                f"{rec['scipy_ms_per_fit_median']:.2f} ms per fit; landmark cost / posetrack's "
                f"fit_pose: median {rec['fit_cost_ratio_median']} (10-90 %: "
                f"{rec['fit_cost_ratio_p10']}-{rec['fit_cost_ratio_p90']})"
            )
    for rec in records:
        if rec["method"] == "scipy_converged":
            print(
                f"\nscipy_converged N={rec['N']}: {rec['frames_timed']} timed frames, loss "
                f"'l2', residual evaluations per fit (finite differences included): mean "
                f"{rec['scipy_evals_per_fit']:.0f}, median "
                f"{rec['scipy_evals_per_fit_median']:.0f}; {rec['scipy_ms_per_fit_median']:.0f}"
                f" ms per fit; landmark cost / posetrack's fit_pose: median "
                f"{rec['fit_cost_ratio_median']} (10-90 %: {rec['fit_cost_ratio_p10']}-"
                f"{rec['fit_cost_ratio_p90']})"
            )
    print("\ntargets (160x120):")
    for name, value, ok in targets(records):
        status = "not measured" if ok is None else ("met" if ok else "MISSED")
        print(f"  {name:58s} {value:>12s}  {status}")
    print(
        f"\nload average (1, 5, 15 min) at the start {machine['loadavg_start']}, at the end "
        f"{machine['loadavg_end']}; total {total:.0f} s"
    )
    if args.json:
        atomic_write_text(args.json, json.dumps(records, indent=1))
        print(f"wrote {args.json}")
    return records


if __name__ == "__main__":
    sys.exit(0 if main() is not None else 1)
