"""The motion model: poses of many frames fitted jointly under a smooth-motion prior.

The per-frame tracker (``_step.py``) estimates each frame from the previous pose and this
frame's landmarks; its output shakes (independent errors frame to frame) and cannot use what
the following frames say. The smoother takes a window of W frames and minimises, over the W
poses at once (not in the paper),

    E(p_1..p_W) = sum_t S_t(p_t) + lambda * sum_t ||X_{t+1} - 2 X_t + X_{t-1}||^2

where ``S_t`` is Eq. (1) of the paper on frame t's landmarks that agree with the tracker's pose
(the consensus set, as the per-frame refit uses, so the outliers the hypotheses rejected stay
out), with the fit's regularisers, plus a pull toward the tracker's own keypoints weighted by
their confidence (they carry what the depth rendering and the hypotheses' vote found; without
it the smoothed poses were measured worse than the per-frame ones), and ``X_t`` are the 18
model keypoints of pose ``p_t``: a prior on joint accelerations, in metres, the quantity the
acceleration error measures. Where a frame has few landmarks (occlusion) the prior carries
its pose from the frames around it.

**Solver.** Levenberg-Marquardt on the W x 43 parameters. Frame t's residuals depend on
``p_t`` only and an acceleration term on three consecutive poses, so the normal equations are
block-banded (43 x 43 blocks, two blocks either side of the diagonal). Pairing frames makes
them block-tridiagonal (86 x 86 blocks), which a block Thomas elimination (``lax.scan``) solves
in O(W) time: a window of 128 frames costs about as much as 128 single-frame LM steps, where
optimistix' dense LM would form a 5,504-column Jacobian. The per-frame Jacobians are vmapped
``jax.jacfwd`` of the same residual function the tracker's fits use.

One jitted call per window (:func:`smooth_window`); ``posetrack.track`` runs it over the
recording in overlapping windows (offline), each window's solution faded into the next over
the frames they share (:func:`crossfade_weights`, :func:`blend_params`).

**Online** (``Tracker(mode="online", lag=L)``, causal) uses a cheaper model: after each frame
the tracker's keypoints over the last ``online_window`` frames are smoothed by the same
acceleration prior, but in keypoint space, where the problem is linear
(:func:`smooth_keypoints`: one small solve per keypoint), and the pose of frame t - L is
fitted to its smoothed keypoints by a few Gauss-Newton steps (:func:`pose_from_keypoints`).
One jitted call per frame (:func:`online_update`), the window kept on the device. The
window-LM of the offline smoother was measured at 2.5x the per-frame step when run every
frame (12 frames, 4 iterations); this one adds about 15 % (``benchmarks/motion.py``).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from . import _body as body
from ._associate import quiet_nanmedian
from ._camera import Intrinsics
from ._fit import fit_problem, fit_residuals
from ._limbs import LIMBS
from ._observe import Landmarks
from ._programs import program
from ._residuals import ResidualSettings, _sqrt_reweight
from ._rotation import quat_normalize
from ._select import consensus_set

#: Coefficients of the second difference X_{s+1} - 2 X_s + X_{s-1}, for frames s-1, s, s+1.
_C = (1.0, -2.0, 1.0)


@dataclasses.dataclass(frozen=True)
class SmoothSettings:
    """Settings of the motion model (hashable: static under jit).

    The prior's weight is given as physical spreads so it does not depend on the frame rate:
    ``lambda = (landmark_std / (accel_std / fps^2))^2`` per keypoint coordinate.
    """

    accel_std: float = 1.0
    """Spread of a joint's acceleration the prior expects, m/s^2 (the smaller, the smoother).
    """
    landmark_std: float = 0.03
    """Spread of a landmark's error in metres that ``accel_std`` is weighed against."""
    iterations: int = 10
    """Levenberg-Marquardt iterations per window."""
    consensus_distance: float = 0.12
    """A landmark enters frame t's data term if it lies within this of the tracker's pose at
    t, metres (2D landmarks: in metres at the keypoint's depth)."""
    residuals: ResidualSettings = ResidualSettings(loss="l1")
    """The data term: Eq. (1)'s sum of norms by default (robust to what the consensus let
    through)."""
    landmark_weight: float = 1.0
    """Weight of the landmarks (Eq. (1)) in each frame's data term."""
    pose_weight: float = 0.5
    """Weight of the tracker's own keypoints in each frame's data term (they carry what the
    depth rendering and the hypotheses' vote found, which the landmarks alone do not). 0.5
    since 2026-11-29 (1.0 before): on fresh wide real tuning clips 61.59 -> 60.87 mm, none
    worse by more than 1 mm (benchmarks/README.md, "The smoother's consensus distance")."""
    online_window: int = 12
    """Frames the online mode smooths over at every frame (static): the newest frame and the
    ones before it."""
    online_accel_std: float = 6.0
    """Online: spread of a keypoint's acceleration the prior expects, m/s^2, weighed against
    ``landmark_std`` (see :meth:`online_weight`). Chosen on tuning seeds 100-105: 3-9 m/s^2
    traded D against acceleration error by a few per cent either way."""
    online_iterations: int = 3
    """Gauss-Newton steps fitting the pose to the smoothed keypoints (online)."""
    online_robust: float = 0.05
    """Online: after the smoothing, each keypoint-frame's data weight is divided by
    ``1 + (r / online_robust)^2`` (r its distance from the smoothed track, metres) and the
    window smoothed again, so a frame far off its neighbours (an outlier the tracker followed)
    pulls less; 0: one plain smoothing (the default before 2026-12-08). The default since its
    online screen on 76 fresh tuning runs (D -0.55 mm, t -7.3, every group better, fewer
    swapped-limb frames) and its report stage (benchmarks/README.md, "The robust online
    smoothing again"); it costs a second smoothing of the window (~0.06 ms a frame)."""
    window: int = 96
    """Frames per window (offline); static: one compiled program per window size."""
    overlap: int = 16
    """Frames each window shares with the next (offline). See ``crossfade``."""
    crossfade: bool = True
    """Offline: how two windows' solutions meet in the frames they share. ``True`` (the
    default since 2026-12-02): a linear cross-fade over the whole overlap (the poses blended,
    quaternions by normalised linear interpolation, and their keypoints the model's), each
    window weighed least next to its own edge. ``False`` (before): a cut at the middle of the
    overlap (the first and last ``overlap // 2`` frames of a window are taken from its
    neighbours); where the two solutions disagree the track jumps there. Decided by a rule
    written before its runs (benchmarks/README.md, "Offline window seams")."""
    outlier_distance: float = 0.15
    """Offline start: a limb's per-frame pose is an outlier at frame t when its elbow or wrist
    (knee or ankle) lies farther than this, metres, from the median of its positions over
    the ``outlier_frames`` frames either side while the tracker's confidence in it is below
    ``outlier_confidence``; the smoother then starts that limb, and anchors its
    regulariser, at the pose interpolated between the limb's nearest frames that are not
    (:func:`interpolated_start`). ``inf`` turns this off."""
    outlier_confidence: float = 0.3
    """See ``outlier_distance`` (the tracker's per-keypoint confidence, in [0, 1])."""
    outlier_frames: int = 3
    """See ``outlier_distance``."""
    both_ways: bool = False
    """Offline: track the recording a second time, from the last frame to the first, smooth
    each pass and fuse the two smoothed tracks (their keypoints averaged, the pose fitted to
    the average; :mod:`posetrack._bothways`); costs a second per-frame pass and a second
    smoother pass (``posetrack track --both-ways``). See benchmarks/README.md, "Offline both
    ways, second fusion", for what it was measured to do."""

    def __post_init__(self):
        if not (self.accel_std > 0 and self.landmark_std > 0):
            raise ValueError(
                f"SmoothSettings: accel_std and landmark_std must be positive, got "
                f"{self.accel_std} and {self.landmark_std}"
            )
        if self.iterations < 1:
            raise ValueError(f"SmoothSettings.iterations must be >= 1, got {self.iterations}")
        if self.online_window < 4:
            raise ValueError(f"SmoothSettings.online_window must be >= 4, got {self.online_window}")
        if not self.online_accel_std > 0:
            raise ValueError(
                f"SmoothSettings.online_accel_std must be positive, got {self.online_accel_std}"
            )
        if self.online_iterations < 1:
            raise ValueError(
                f"SmoothSettings.online_iterations must be >= 1, got {self.online_iterations}"
            )
        if not (np.isfinite(self.online_robust) and self.online_robust >= 0):
            raise ValueError(
                f"SmoothSettings.online_robust must be >= 0 (metres; 0: off), got "
                f"{self.online_robust}"
            )
        if self.window < 4 or self.window % 2:
            raise ValueError(f"SmoothSettings.window must be even and >= 4, got {self.window}")
        if not 0 <= self.overlap <= self.window // 2:
            raise ValueError(
                f"SmoothSettings.overlap must be in [0, window / 2], got {self.overlap}"
            )
        if not self.outlier_distance > 0:
            raise ValueError(
                f"SmoothSettings.outlier_distance must be positive (inf: off), got "
                f"{self.outlier_distance}"
            )
        if not isinstance(self.both_ways, bool):
            raise ValueError(
                f"SmoothSettings.both_ways must be True or False, got {self.both_ways!r}"
            )
        if self.outlier_frames < 1:
            raise ValueError(
                f"SmoothSettings.outlier_frames must be >= 1, got {self.outlier_frames}"
            )

    def online_weight(self, fps: float | Array) -> Array:
        """The online smoother's prior weight for a frame rate (Hz):
        ``(landmark_std / (online_accel_std / fps^2))^2`` against data weights in [0, 1]."""
        per_frame = self.online_accel_std / (jnp.asarray(fps, jnp.float32) ** 2)
        return (self.landmark_std / per_frame) ** 2

    def weight(self, fps: float | Array) -> Array:
        """lambda for a frame rate (Hz)."""
        per_frame = self.accel_std / (jnp.asarray(fps, jnp.float32) ** 2)
        return (self.landmark_std / per_frame) ** 2


def consensus_masks(
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    params: Float[Array, "frame 43"],
    landmarks: Landmarks,
    distance: float,
    keypoints: Float[Array, "frame kpt 3"] | None = None,
) -> tuple[Bool[Array, "frame kpt"], Bool[Array, "frame kpt"]]:
    """Per frame, the landmarks within ``distance`` of the pose's keypoints (3D, and 2D where
    the keypoint has no depth), as in the tracker's consensus refit. ``keypoints``: the
    poses' keypoints when known (default: computed from ``params`` with ``shape``)."""
    if keypoints is None:
        keypoints = jax.vmap(lambda p: body.keypoints(shape, p))(params)

    def one(k, lm):
        use3d, use2d = consensus_set(lm, k, intrinsics, distance)
        return use3d, use2d & ~lm.has_depth

    return jax.vmap(one)(keypoints, landmarks)


def _acceleration_weights(valid: Bool[Array, " frame"]):
    """Which acceleration terms exist (all three frames valid) and the banded weights."""
    v = valid.astype(jnp.float32)
    W = v.shape[0]
    term = jnp.zeros(W).at[1:-1].set(v[:-2] * v[1:-1] * v[2:])  # term s couples s-1, s, s+1
    prev = jnp.concatenate([jnp.zeros(1), term[:-1]])  # term s = t - 1 (t is its s+1)
    nxt = jnp.concatenate([term[1:], jnp.zeros(1)])  # term s = t + 1 (t is its s-1)
    w0 = prev + 4.0 * term + nxt  # sum of c^2 over the terms that contain frame t
    w1 = -2.0 * term - 2.0 * nxt  # (t, t+1): terms s = t and s = t + 1
    w2 = nxt  # (t, t+2): term s = t + 1
    return term, w0, w1, w2


def _second_difference(X: Float[Array, "frame n"], term: Float[Array, " frame"]):
    """a_s = X_{s+1} - 2 X_s + X_{s-1} where term s exists, else 0; (frame, n)."""
    a = jnp.zeros_like(X).at[1:-1].set(X[2:] - 2.0 * X[1:-1] + X[:-2])
    return a * term[:, None]


def _block_tridiagonal_solve(D, U, b):
    """Solve a symmetric block-tridiagonal system (block Thomas elimination).

    Args:
        D: (K, n, n) diagonal blocks; U: (K, n, n) super-diagonal blocks (U[k] couples block k
            with k + 1; U[K-1] unused); b: (K, n) right-hand side.

    Returns:
        (K, n) solution. The system must be positive definite (the LM damping makes it so).
    """

    def forward(carry, xs):
        Dp_prev, bp_prev, U_prev = carry
        Dk, bk, Uk = xs
        X = jnp.linalg.solve(Dp_prev, U_prev)  # Dp_{k-1}^{-1} U_{k-1}
        Dp = Dk - U_prev.T @ X
        bp = bk - X.T @ bp_prev
        return (Dp, bp, Uk), (Dp, bp)

    n = D.shape[-1]
    zero = jnp.zeros((n, n), D.dtype)
    init = (jnp.eye(n, dtype=D.dtype), jnp.zeros(n, D.dtype), zero)
    _, (Dp, bp) = jax.lax.scan(forward, init, (D, b, U))

    def backward(x_next, xs):
        Dk, bk, Uk = xs
        x = jnp.linalg.solve(Dk, bk - Uk @ x_next)
        return x, x

    U_shift = U.at[-1].set(zero)
    _, x = jax.lax.scan(backward, jnp.zeros(n, D.dtype), (Dp, bp, U_shift), reverse=True)
    return x


def smooth_window(
    settings: SmoothSettings,
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    params: Float[Array, "frame 43"],
    landmarks: Landmarks,
    use3d: Bool[Array, "frame kpt"],
    use2d: Bool[Array, "frame kpt"],
    valid: Bool[Array, " frame"],
    fps: Float[Array, ""],
    pose_confidence: Float[Array, "frame kpt"],
    iterations: int | None = None,
    targets: Float[Array, "frame kpt 3"] | None = None,
) -> Float[Array, "frame 43"]:
    """Fit the poses of a window of frames jointly (see the module docstring). Jittable.

    Args:
        settings: the prior and the solver (static).
        shape, intrinsics: as for :func:`~posetrack.fit_pose`.
        params: (frame, 43) the per-frame estimates, the start and the regularisers' anchor;
            quaternions wxyz.
        landmarks: the frames' lifted observations (a leading ``frame`` axis).
        use3d, use2d: (frame, kpt) the landmarks each frame's data term uses.
        valid: (frame,) frames that have a pose; an invalid frame (before the first
            estimate, padding) takes part in no acceleration term and is returned unchanged.
        fps: frame rate, Hz (scales the prior, see :class:`SmoothSettings`).
        pose_confidence: (frame, kpt) weight in [0, 1] of each of the tracker's own keypoints
            in the data term (the tracker's per-keypoint confidence: a keypoint inferred
            rather than observed pulls less, and the prior carries it).
        iterations: LM iterations (static; default ``settings.iterations``).
        targets: (frame, kpt, 3) the tracker's own keypoints, metres (default: those of
            ``params`` with ``shape``). Given apart when ``shape`` is not the shape the
            per-frame poses were fitted with (``Tracker(refine=...)``): the same pose angles
            with other bone lengths would put the limbs' ends elsewhere.

    Returns:
        (frame, 43) smoothed poses, unit quaternions with w >= 0.
    """
    W = params.shape[0]
    if W % 2:
        raise ValueError(f"smooth_window: the window must have an even number of frames, got {W}")
    lam = settings.weight(fps)
    term, w0, w1, w2 = _acceleration_weights(valid)

    def problem(p, lm, u3, u2):
        start, args = fit_problem(
            p, shape, lm, intrinsics, use3d=u3, use2d=u2, residuals=settings.residuals
        )
        _, _, _, u3, u2, mpp, _, _ = args
        return start, u3, u2, mpp

    start, u3, u2, mpp = jax.vmap(problem)(params, landmarks, use3d, use2d)
    # An invalid frame has no data; its regularisers alone keep it where it is.
    frame_args = (landmarks, u3 & valid[:, None], u2 & valid[:, None], mpp, start)

    if targets is None:
        targets = jax.vmap(lambda p: body.keypoints(shape, p))(start)
    frame_args = (*frame_args, targets, jnp.asarray(pose_confidence) * valid[:, None])

    def data_res(p, a):
        lm, u3, u2, mpp, anchor, target, conf = a
        r = fit_residuals(p, (shape, lm, intrinsics, u3, u2, mpp, anchor, settings.residuals))
        e = body.keypoints(shape, p) - target
        if settings.residuals.loss == "l1":
            e = _sqrt_reweight(e, settings.residuals.eps)
        e = e * jnp.sqrt(settings.pose_weight * conf)[:, None]
        n_lm = 18 * 5
        return jnp.concatenate(
            [r[:n_lm] * jnp.sqrt(settings.landmark_weight), r[n_lm:], e.reshape(-1)]
        )

    def kps(p):
        return body.keypoints(shape, p).reshape(-1)

    def cost(P):
        r = jax.vmap(data_res)(P, frame_args)
        a = _second_difference(jax.vmap(kps)(P), term)
        return jnp.sum(r * r) + lam * jnp.sum(a * a)

    def iterate(_, carry):
        P, mu, c = carry
        r = jax.vmap(data_res)(P, frame_args)  # (frame, res)
        A = jax.vmap(jax.jacfwd(data_res))(P, frame_args)  # (frame, res, 43)
        X = jax.vmap(kps)(P)  # (frame, 54)
        B = jax.vmap(jax.jacfwd(kps))(P)  # (frame, 54, 43)
        a = _second_difference(X, term)
        # Gradient: frame t sits in term t-1 (coefficient 1), t (-2) and t+1 (1).
        a_prev = jnp.concatenate([jnp.zeros_like(a[:1]), a[:-1]])
        a_next = jnp.concatenate([a[1:], jnp.zeros_like(a[:1])])
        Ba = jnp.einsum("tki,tk->ti", B, a_prev - 2.0 * a + a_next)
        g = jnp.einsum("tri,tr->ti", A, r) + lam * Ba
        BtB = jnp.einsum("tki,tkj->tij", B, B)
        B_next = jnp.concatenate([B[1:], jnp.zeros_like(B[:1])])
        B_next2 = jnp.concatenate([B[2:], jnp.zeros_like(B[:2])])
        AtA = jnp.einsum("tri,trj->tij", A, A)
        D = AtA + lam * w0[:, None, None] * BtB
        eye = jnp.eye(43, dtype=P.dtype)
        D = D + mu * (
            eye[None] * jnp.diagonal(D, axis1=-2, axis2=-1)[:, None, :] + 1e-6 * eye[None]
        )
        U1 = lam * w1[:, None, None] * jnp.einsum("tki,tkj->tij", B, B_next)
        U2 = lam * w2[:, None, None] * jnp.einsum("tki,tkj->tij", B, B_next2)
        # Pair frames (2k, 2k+1): bandwidth two in frames is one in pairs.
        K = W // 2
        SD = jnp.concatenate(
            [
                jnp.concatenate([D[0::2], U1[0::2]], axis=2),
                jnp.concatenate([jnp.swapaxes(U1[0::2], 1, 2), D[1::2]], axis=2),
            ],
            axis=1,
        )
        zero = jnp.zeros((K, 43, 43), P.dtype)
        SU = jnp.concatenate(
            [
                jnp.concatenate([U2[0::2], zero], axis=2),
                jnp.concatenate([U1[1::2], U2[1::2]], axis=2),
            ],
            axis=1,
        )
        b = -g.reshape(K, 86)
        step = _block_tridiagonal_solve(SD, SU, b).reshape(W, 43)
        P_new = P + step
        c_new = cost(P_new)
        better = jnp.isfinite(c_new) & (c_new < c)
        return (
            jnp.where(better, P_new, P),
            jnp.where(better, mu * 0.3, mu * 4.0),
            jnp.where(better, c_new, c),
        )

    P0 = start
    carry = (P0, jnp.asarray(1e-3, P0.dtype), cost(P0))
    P, _, _ = jax.lax.fori_loop(0, iterations or settings.iterations, iterate, carry)
    P = body.normalize_params(P)
    return jnp.where(valid[:, None], P, params)


smooth_window_jit = eqx.filter_jit(smooth_window)


#: The limbs the smoother's start repairs (right arm, left arm, right leg, left leg, as
#: ``_limbs.LIMBS``): the two keypoints at each limb's end (COCO-18: elbow and wrist, knee
#: and ankle) and the two joints that pose it (``body.JOINT_NAMES``).
LIMB_KEYPOINTS = tuple((mid, end) for _, _, _, mid, end in LIMBS)
LIMB_JOINTS = tuple((upper, lower) for upper, lower, *_ in LIMBS)


def interpolated_start(
    settings: SmoothSettings,
    params: np.ndarray,
    keypoints: np.ndarray,
    confidence: np.ndarray,
    valid: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The offline smoother's start with each limb's per-frame outliers interpolated.

    The per-frame tracker sometimes follows a detector outlier for a frame (a wrist or an
    ankle pulled half a metre away, the hypotheses in disagreement, so with a low confidence).
    The smoother's data term then hardly weighs that frame, but its Levenberg-Marquardt
    starts there and its regulariser anchors there: from such a start the acceleration prior
    drags the limb's neighbouring frames toward the outlier and the fit settles in a wrong
    local minimum (a generated clip: an ankle 20-30 cm off over 12 frames the per-frame
    poses had right but one). So where a limb is an outlier (see
    ``SmoothSettings.outlier_distance``) its two joint quaternions are replaced by the
    normalised linear interpolation between the limb's nearest frames before and after that
    are not; a limb with no such frame on one side is left as it is. Host-side NumPy, once
    per recording.

    Args:
        settings: ``outlier_distance``, ``outlier_confidence``, ``outlier_frames``.
        params: (T, 43) per-frame poses (quaternions wxyz).
        keypoints: (T, 18, 3) their keypoints, metres.
        confidence: (T, 18) the tracker's per-keypoint confidence.
        valid: (T,) frames with a pose; the others are neither read nor changed.

    Returns:
        ``(params, replaced)``: (T, 43) float32, and (T, 4) bool, which limb (in
        :data:`LIMB_KEYPOINTS` order) was replaced at which frame.
    """
    params = np.array(params, np.float32)
    valid = np.asarray(valid, bool)
    T, h = len(params), settings.outlier_frames
    replaced = np.zeros((T, len(LIMB_KEYPOINTS)), bool)
    if not np.isfinite(settings.outlier_distance):
        return params, replaced
    x = np.where(valid[:, None, None], np.asarray(keypoints, np.float64), np.nan)
    pad = np.full((h, *x.shape[1:]), np.nan)
    xp = np.concatenate([pad, x, pad])
    near = np.stack([xp[h + o : h + o + T] for o in range(-h, h + 1) if o != 0])
    # A frame without a valid neighbour gets a NaN median: never an outlier.
    dev = np.linalg.norm(x - quiet_nanmedian(near, axis=0), axis=-1)
    outlier = (dev > settings.outlier_distance) & (
        np.asarray(confidence) < settings.outlier_confidence
    )
    for limb, (kps, joints) in enumerate(zip(LIMB_KEYPOINTS, LIMB_JOINTS)):
        bad = valid & outlier[:, list(kps)].any(axis=1)
        good = np.flatnonzero(valid & ~bad)
        t = np.flatnonzero(bad)
        i = np.searchsorted(good, t)
        inside = (i > 0) & (i < len(good))
        t, i = t[inside], i[inside]
        before, after = good[i - 1], good[i]
        w = ((t - before) / (after - before))[:, None]
        for j in joints:
            cols = slice(3 + 4 * j, 7 + 4 * j)
            q0, q1 = params[before, cols], params[after, cols]
            q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -q1, q1)
            q = (1 - w) * q0 + w * q1
            params[t, cols] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        replaced[t, limb] = True
    return params, replaced


def smooth_sequence(
    settings: SmoothSettings,
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    params: np.ndarray,
    landmarks: Landmarks,
    valid: np.ndarray,
    *,
    fps: float,
    keypoints: np.ndarray,
    pose_confidence: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The offline smoother over a whole recording: :func:`smooth_window` on overlapping
    windows of ``settings.window`` frames (one jitted call each; one compiled program for
    any length).

    Args:
        params: (T, 43) the tracker's per-frame poses (any values where ``valid`` is False).
        landmarks: the T frames' landmarks, NumPy or JAX arrays with a leading frame axis.
        valid: (T,) frames with an estimate.
        fps: frame rate, Hz.
        keypoints: (T, 18, 3) the tracker's per-frame keypoints, metres (any values where
            ``valid`` is False): the consensus reference and the anchor of the data term
            (``targets`` of :func:`smooth_window`).
        pose_confidence: (T, 18) the tracker's per-keypoint confidence, the keypoints'
            weights in the data term (default 1); where it is low and a limb's keypoints
            jump, the limb starts from its neighbours' pose (:func:`interpolated_start`).

    Returns:
        ``(params, keypoints, interpolated)``: (T, 43) NumPy float32, frames that are not
        ``valid`` unchanged; (T, 18, 3) the keypoints of those poses, metres; (T, 4) bool,
        which limb (``_limbs.LIMB_NAMES``) started from its neighbours' pose at which frame.
    """
    params = np.asarray(params, np.float32)
    valid = np.asarray(valid, bool)
    T = len(params)
    conf = np.ones((T, 18), np.float32) if pose_confidence is None else pose_confidence
    params, interpolated = interpolated_start(settings, params, keypoints, conf, valid)
    W, overlap = settings.window, settings.overlap
    step = W - overlap
    half = overlap // 2
    fade = crossfade_weights(overlap) if settings.crossfade else None
    safe = np.where(valid[:, None], params, body.facing_camera_params_np(2.5))
    kps_in = np.where(valid[:, None, None], np.nan_to_num(np.asarray(keypoints, np.float32)), 0.0)
    lm = jax.tree.map(lambda x: np.asarray(x), landmarks)
    out = params.copy()
    out_kps = np.zeros((T, 18, 3), np.float32)
    fps_arr = jnp.asarray(fps, jnp.float32)
    previous = np.zeros((W, 43), np.float32)  # the last window's poses of the shared frames
    previous_weight = np.zeros(W, np.float32)
    start = 0
    while True:
        stop = min(start + W, T)
        n = stop - start

        def pad(x, fill=0):
            x = x[start:stop]
            widths = [(0, W - n)] + [(0, 0)] * (x.ndim - 1)
            return np.pad(x, widths, constant_values=fill)

        smoothed, kps = smooth_window_program(
            settings, shape, intrinsics, jnp.asarray(pad(safe)),
            jax.tree.map(lambda x: jnp.asarray(pad(x)), lm), jnp.asarray(pad(valid)), fps_arr,
            jnp.asarray(pad(conf)), jnp.asarray(pad(kps_in)),
            jnp.asarray(previous), jnp.asarray(previous_weight),
        )  # fmt: skip
        smoothed, kps = np.asarray(smoothed)[:n], np.asarray(kps)[:n]
        if settings.crossfade:  # this window's frames, the shared ones blended in the program
            first, last = 0, n
            if stop < T:
                previous[:overlap] = smoothed[step:]
                previous_weight[:overlap] = fade
        else:
            first = 0 if start == 0 else half
            last = n if stop == T else n - half
        keep = np.arange(first, last)
        out[start + keep] = np.where(
            valid[start + keep, None], smoothed[keep], params[start + keep]
        )
        out_kps[start + keep] = kps[keep]
        if stop == T:
            return out, out_kps, interpolated
        start += step


@program("smooth_window", static_argnums=(0,))
def smooth_window_program(
    settings: SmoothSettings,
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    params: Float[Array, "frame 43"],
    landmarks: Landmarks,
    valid: Bool[Array, " frame"],
    fps: Float[Array, ""],
    pose_confidence: Float[Array, "frame kpt"],
    keypoints: Float[Array, "frame kpt 3"],
    previous: Float[Array, "frame 43"],
    previous_weight: Float[Array, " frame"],
) -> tuple[Float[Array, "frame 43"], Float[Array, "frame kpt 3"]]:
    """One window of :func:`smooth_sequence` as one compiled program: each frame's consensus
    landmarks, :func:`smooth_window`, the smoothed poses blended with ``previous`` (the last
    window's, where ``previous_weight`` > 0: :func:`blend_params`; valid frames only), and
    the keypoints of those poses (of the valid frames; the others' are those of ``params``).
    Any recording length reuses it."""
    use3d, use2d = consensus_masks(
        shape, intrinsics, params, landmarks, settings.consensus_distance, keypoints=keypoints
    )
    P = smooth_window(
        settings, shape, intrinsics, params, landmarks, use3d, use2d, valid, fps,
        pose_confidence, targets=keypoints,
    )  # fmt: skip
    return blend_window(shape, P, valid, previous, previous_weight)


def blend_window(
    shape: body.BodyShape,
    params: Float[Array, "frame 43"],
    valid: Bool[Array, " frame"],
    previous: Float[Array, "frame 43"],
    previous_weight: Float[Array, " frame"],
) -> tuple[Float[Array, "frame 43"], Float[Array, "frame kpt 3"]]:
    """A window's poses with ``previous`` blended in where ``previous_weight`` > 0 and the
    frame is ``valid`` (:func:`blend_params`; elsewhere ``params`` as they are), and the
    keypoints of the result."""
    w = jnp.where(valid, previous_weight, 0.0)[:, None]
    P = jnp.where(w > 0, blend_params(previous, params, w), params)
    return P, jax.vmap(lambda p: body.keypoints(shape, p))(P)


def crossfade_weights(overlap: int) -> np.ndarray:
    """The earlier window's weight over the ``overlap`` frames two offline windows share:
    ``1 - (i + 1) / (overlap + 1)``, from near 1 down to near 0 (each window weighed least
    next to its own edge, where its solution knows the least)."""
    return (1.0 - np.arange(1, overlap + 1) / (overlap + 1)).astype(np.float32)


def blend_params(
    a: Float[Array, "*batch 43"], b: Float[Array, "*batch 43"], weight_a: Float[Array, "*batch 1"]
) -> Float[Array, "*batch 43"]:
    """``weight_a`` of pose ``a`` and the rest of ``b``: the root positions interpolated
    linearly, each quaternion by normalised linear interpolation along the shorter arc."""
    q_a = a[..., 3:].reshape(*a.shape[:-1], 10, 4)
    q_b = b[..., 3:].reshape(*b.shape[:-1], 10, 4)
    w = weight_a[..., None]
    q_a = jnp.where(jnp.sum(q_a * q_b, axis=-1, keepdims=True) < 0, -q_a, q_a)
    q = quat_normalize(w * q_a + (1 - w) * q_b)
    xyz = weight_a * a[..., :3] + (1 - weight_a) * b[..., :3]
    return jnp.concatenate([xyz, q.reshape(*q.shape[:-2], 40)], axis=-1)


class OnlineWindow(eqx.Module):
    """The online motion model's memory: the newest ``online_window`` frames (oldest first),
    kept on the device between frames."""

    keypoints: Float[Array, "frame kpt 3"]
    """The tracker's per-frame keypoints, metres."""
    confidence: Float[Array, "frame kpt"]
    """Their weights in the data term (the tracker's per-keypoint confidence)."""
    params: Float[Array, "frame 43"]
    """The per-frame poses (the start of the pose fit; quaternions wxyz)."""
    valid: Bool[Array, " frame"]
    """Frames that belong to the current track segment."""

    @staticmethod
    def empty(size: int) -> OnlineWindow:
        # Made on the host and copied: jnp.zeros / jnp.tile here compiled (or loaded) four
        # small programs for every new tracker, ~0.15 s of a warm start.
        return OnlineWindow(
            keypoints=jax.device_put(np.zeros((size, 18, 3), np.float32)),
            confidence=jax.device_put(np.zeros((size, 18), np.float32)),
            params=jax.device_put(np.tile(body.facing_camera_params_np(2.5), (size, 1))),
            valid=jax.device_put(np.zeros(size, bool)),
        )

    def push(self, keypoints, confidence, params, valid) -> OnlineWindow:
        """The window with a new newest frame (the oldest dropped)."""

        def roll(buf, x):
            return jnp.concatenate([buf[1:], jnp.asarray(x, buf.dtype)[None]])

        return OnlineWindow(
            keypoints=roll(self.keypoints, keypoints),
            confidence=roll(self.confidence, confidence),
            params=roll(self.params, params),
            valid=roll(self.valid, valid),
        )


#: Smallest data weight of a frame of the track (a frame with nothing observed is carried by
#: the prior, but the system must stay solvable when a whole window is unobserved).
_MIN_WEIGHT = 0.02


def smooth_keypoints(
    keypoints: Float[Array, "frame kpt 3"],
    confidence: Float[Array, "frame kpt"],
    valid: Bool[Array, " frame"],
    weight: Float[Array, ""],
) -> Float[Array, "frame kpt 3"]:
    """Keypoint trajectories smoothed over a window: per keypoint, the minimiser of

        sum_t c_t |x_t - y_t|^2 + weight * sum_t |x_{t+1} - 2 x_t + x_{t-1}|^2

    (acceleration terms only where all three frames are ``valid``; c = ``confidence``, at
    least 0.02 on valid frames). A linear problem: one (frame x frame) solve per keypoint,
    the same matrix for x, y and z. Frames that are not valid come back unchanged.
    """
    W = keypoints.shape[0]
    term, _, _, _ = _acceleration_weights(valid)
    D = jnp.zeros((W, W), keypoints.dtype)
    rows = jnp.arange(1, W - 1)
    D = D.at[rows, rows - 1].set(1.0).at[rows, rows].set(-2.0).at[rows, rows + 1].set(1.0)
    D = D * term[:, None]
    prior = weight * (D.T @ D)
    c = jnp.where(valid[:, None], jnp.maximum(confidence, _MIN_WEIGHT), 1.0)  # (frame, kpt)
    A = jax.vmap(lambda ck: jnp.diag(ck) + prior, in_axes=1)(c)  # (kpt, frame, frame)
    b = jnp.swapaxes(c[:, :, None] * keypoints, 0, 1)  # (kpt, frame, 3)
    x = jnp.swapaxes(jnp.linalg.solve(A, b), 0, 1)
    return jnp.where(valid[:, None, None], x, keypoints)


def pose_from_keypoints(
    shape: body.BodyShape,
    start: Float[Array, 43],
    targets: Float[Array, "kpt 3"],
    iterations: int,
) -> Float[Array, 43]:
    """The pose near ``start`` whose 18 keypoints best match ``targets`` (metres): a few damped
    Gauss-Newton steps on ``keypoints(p) - targets`` with the fits' unit-quaternion residuals
    and a weak pull toward ``start`` (it fixes the twist no keypoint sees). Quaternions wxyz."""
    settings = ResidualSettings()

    def res(p):
        e = (body.keypoints(shape, p) - targets).reshape(-1)
        q = p[3:].reshape(-1, 4)
        unit = settings.unit_weight * (jnp.sum(q * q, axis=-1) - 1.0)
        return jnp.concatenate([e, unit, 0.01 * (p - start)])

    def step(_, p):
        r = res(p)
        J = jax.jacfwd(res)(p)
        H = J.T @ J
        H = H + 1e-3 * jnp.diag(jnp.diagonal(H)) + 1e-6 * jnp.eye(43, dtype=p.dtype)
        return p - jnp.linalg.solve(H, J.T @ r)

    p = jax.lax.fori_loop(0, iterations, step, body.normalize_params(start))
    p = body.normalize_params(p)
    return jnp.where(jnp.all(jnp.isfinite(p)), p, start)


def _online_smooth(settings: SmoothSettings, window: OnlineWindow, fps) -> Array:
    """The window's keypoint tracks smoothed (:func:`smooth_keypoints`), with
    ``settings.online_robust`` a second time under reweighted data."""
    weight = settings.online_weight(fps)
    smoothed = smooth_keypoints(window.keypoints, window.confidence, window.valid, weight)
    if settings.online_robust > 0:
        r = jnp.linalg.norm(window.keypoints - smoothed, axis=-1)
        conf = window.confidence / (1.0 + (r / settings.online_robust) ** 2)
        smoothed = smooth_keypoints(window.keypoints, conf, window.valid, weight)
    return smoothed


def online_update(
    settings: SmoothSettings,
    shape: body.BodyShape,
    fps: Float[Array, ""],
    window: OnlineWindow,
    keypoints: Float[Array, "kpt 3"],
    confidence: Float[Array, " kpt"],
    params: Float[Array, 43],
    valid: Bool[Array, ""],
    lag: int,
) -> tuple[OnlineWindow, Float[Array, 43], Float[Array, "kpt 3"]]:
    """The online motion model after one frame (one jitted call): push the frame, smooth the
    window's keypoint trajectories (:func:`smooth_keypoints`, weight
    :meth:`SmoothSettings.online_weight`), and fit the pose of the frame ``lag`` frames back to
    its smoothed keypoints (:func:`pose_from_keypoints`).

    Returns:
        ``(window, params, keypoints)``: the new window and the smoothed pose of frame
        ``t - lag`` with its model keypoints (meaningful where that frame is valid).
    """
    window = window.push(keypoints, confidence, params, valid)
    smoothed = _online_smooth(settings, window, fps)
    i = window.keypoints.shape[0] - 1 - lag
    pose = pose_from_keypoints(shape, window.params[i], smoothed[i], settings.online_iterations)
    return window, pose, body.keypoints(shape, pose)


#: Compiled for compile time (``rare``): it runs every online frame, but in 0.4 ms either way,
#: and on a cold start it compiles beside the step, the first pose's critical path.
online_update_program = program("online_update", static_argnums=(0, 8), rare=True)(
    online_update
)


@program("online_flush", static_argnums=(0,))
def online_flush(
    settings: SmoothSettings, shape: body.BodyShape, fps: Float[Array, ""], window: OnlineWindow
) -> tuple[Float[Array, "frame 43"], Float[Array, "frame kpt 3"]]:
    """At the end of a recording: the smoothed poses of every frame in the window (the newest
    ``lag`` frames were never published)."""
    smoothed = _online_smooth(settings, window, fps)
    poses = jax.vmap(
        lambda p, x: pose_from_keypoints(shape, p, x, settings.online_iterations)
    )(window.params, smoothed)
    return poses, jax.vmap(lambda p: body.keypoints(shape, p))(poses)
