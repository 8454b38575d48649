"""The 25-DOF / 43-parameter human body model of the paper (section 2.1).

Parameters (K = 43, one flat vector, float):

    [0:3]    root translation t_cam_root, metres, camera frame (the pelvis centre)
    [3:7]    root quaternion q_cam_root, wxyz
    [7:43]   9 joint quaternions, wxyz, each relative to its parent frame, in the order of
             ``JOINT_NAMES[1:]``: neck/head, right shoulder, right elbow, left shoulder,
             left elbow, right hip, right knee, left hip, left knee.

The paper's 25 degrees of freedom (6 root + 3 neck + 2x3 shoulders + 2x1 elbows + 2x3 hips +
2x1 knees) are parameterised with a full quaternion per joint as in the paper (K = 43), so the
elbow and knee twist and the limbs' rotation about their own axis are free; they move no
keypoint and no capsule surface, and the fitter's weak prior toward the previous pose holds them.

Body frame (the root's, and every joint's in the rest pose): x = the subject's left, y = up,
z = forward (the way the chest faces). In the rest pose (all joint quaternions identity) the
subject stands upright with arms hanging down and legs straight. Quaternions are normalised
inside the kinematics, so any non-zero 4-vector is a valid rotation (NaN-safe gradients).

Keypoints follow OpenPose COCO-18 (``KEYPOINT_NAMES``); R = the subject's right.

Body dimensions (:class:`BodyShape`) are a separate pytree so one model fits people of
different size. The model also carries a volumetric surface: capsules (segments with a radius)
attached to the kinematic frames, rendered by ``posetrack._render``.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float

from ._rotation import quat_normalize, quat_to_matrix

NUM_PARAMS = 43
NUM_KEYPOINTS = 18

KEYPOINT_NAMES = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder",
    "left_elbow", "left_wrist", "right_hip", "right_knee", "right_ankle", "left_hip",
    "left_knee", "left_ankle", "right_eye", "left_eye", "right_ear", "left_ear",
)  # fmt: skip

#: Indices of the 13 body joints the paper's metrics use (neck, shoulders, elbows, wrists, hips,
#: knees, ankles): COCO-18 keypoints 1..13.
BODY_JOINTS = tuple(range(1, 14))

#: Kinematic frames: the root and the 9 rotating joints, in parameter order.
JOINT_NAMES = (
    "root", "neck", "right_shoulder", "right_elbow", "left_shoulder", "left_elbow",
    "right_hip", "right_knee", "left_hip", "left_knee",
)  # fmt: skip
JOINT_PARENTS = (-1, 0, 0, 2, 0, 4, 0, 6, 0, 8)
NUM_JOINTS = len(JOINT_NAMES)

#: Left/right keypoint pairs (COCO-18 indices), e.g. for swap handling.
KEYPOINT_FLIP = (0, 1, 5, 6, 7, 2, 3, 4, 11, 12, 13, 8, 9, 10, 15, 14, 17, 16)


def flip_labels(keypoints) -> np.ndarray:
    """``int (18,)`` the identity labelling with ``keypoints`` exchanged left/right
    (:data:`KEYPOINT_FLIP`): ``x[flip_labels(k)]`` reads the other side for those keypoints."""
    idx = np.arange(len(KEYPOINT_FLIP))
    return np.where(np.isin(idx, list(keypoints)), np.asarray(KEYPOINT_FLIP), idx)

#: Parent keypoint of each keypoint on the skeleton (the neck's parent is the hips' midpoint,
#: marked -1; the nose's parent is the neck). Used by the geometric landmark weights.
KEYPOINT_PARENTS = (1, -1, 1, 2, 3, 1, 5, 6, 1, 8, 9, 1, 11, 12, 0, 0, 14, 15)

#: Kinematic frame each keypoint rides on.
KEYPOINT_FRAMES = (1, 1, 2, 3, 3, 4, 5, 5, 6, 7, 7, 8, 9, 9, 1, 1, 1, 1)

# Head keypoints in the neck frame for head_scale = 1 (metres): nose, right/left eye,
# right/left ear. The neck frame's origin is the base of the neck (the COCO "neck" keypoint).
_NOSE = (0.0, 0.17, 0.11)
_EYE = (0.033, 0.205, 0.085)
_EAR = (0.075, 0.185, 0.0)


class BodyShape(eqx.Module):
    """Body dimensions in metres. Every field is a scalar array, so shapes can be estimated
    (and differentiated) like any other parameter.

    Use :meth:`BodyShape.default` for an average adult, :meth:`BodyShape.create` to override
    fields, and :meth:`scaled` for a uniformly larger or smaller person.
    """

    torso: Float[Array, ""]
    """Pelvis centre to the base of the neck (COCO neck keypoint), metres."""
    shoulder_width: Float[Array, ""]
    """Half the distance between the shoulder keypoints, metres."""
    shoulder_drop: Float[Array, ""]
    """How far the shoulder keypoints sit below the neck keypoint, metres."""
    hip_width: Float[Array, ""]
    """Half the distance between the hip keypoints, metres."""
    upper_arm: Float[Array, ""]
    """Shoulder to elbow, metres."""
    forearm: Float[Array, ""]
    """Elbow to wrist, metres."""
    thigh: Float[Array, ""]
    """Hip to knee, metres."""
    shin: Float[Array, ""]
    """Knee to ankle, metres."""
    head_scale: Float[Array, ""]
    """Scale of the head keypoints and head surface (1 = average adult)."""
    torso_radius: Float[Array, ""]
    """Radius of the central torso capsule, metres (the side capsules are 0.8x)."""
    upper_arm_radius: Float[Array, ""]
    """Metres."""
    forearm_radius: Float[Array, ""]
    """Metres."""
    thigh_radius: Float[Array, ""]
    """Metres."""
    shin_radius: Float[Array, ""]
    """Metres."""
    head_radius: Float[Array, ""]
    """Metres, at head_scale = 1."""

    @staticmethod
    def default(dtype=None) -> BodyShape:
        """An average adult (about 1.75 m tall). The same (immutable) object for every call
        with one dtype: a tracker asks for it every frame until its shape is estimated."""
        return _default_shape(jax.dtypes.canonicalize_dtype(dtype or float))

    @staticmethod
    def create(dtype=None, **overrides: float) -> BodyShape:
        """The default adult with some fields overridden, e.g. ``create(thigh=0.45)``.

        Raises:
            ValueError: for an unknown field or a non-finite or non-positive value
                (``shoulder_drop`` may be zero or negative).
        """
        values = dict(_DEFAULTS)
        for name, value in overrides.items():
            if name not in values:
                raise ValueError(f"BodyShape: unknown field {name!r}; fields are {list(values)}")
            v = float(value)
            if not np.isfinite(v) or (v <= 0 and name != "shoulder_drop"):
                raise ValueError(f"BodyShape: {name} must be finite and positive, got {value!r}")
            values[name] = v
        # Converted on the host (jnp.asarray would compile a conversion program: start-up).
        dtype = jax.dtypes.canonicalize_dtype(dtype or float)
        return BodyShape(**{k: jax.device_put(np.asarray(v, dtype)) for k, v in values.items()})

    def scaled(self, factor: float | Array) -> BodyShape:
        """Every length and radius multiplied by ``factor`` (a taller or smaller person)."""
        return jax.tree.map(lambda x: x * factor, self)

    def to_dict(self) -> dict[str, float]:
        """Plain dict of Python floats (metres)."""
        return {k: float(getattr(self, k)) for k in _DEFAULTS}

    @staticmethod
    def from_dict(values: dict[str, float], dtype=None) -> BodyShape:
        """Inverse of :meth:`to_dict` (unknown keys raise, missing keys take the default)."""
        return BodyShape.create(dtype=dtype, **values)

    @property
    def height(self) -> Array:
        """Approximate standing height (ankle to top of head plus a foot), metres."""
        return self.shin + self.thigh + self.torso + self.head_scale * 0.25 + 0.07


_DEFAULTS = {
    "torso": 0.52,
    "shoulder_width": 0.185,
    "shoulder_drop": 0.02,
    "hip_width": 0.11,
    "upper_arm": 0.29,
    "forearm": 0.26,
    "thigh": 0.43,
    "shin": 0.42,
    "head_scale": 1.0,
    "torso_radius": 0.11,
    "upper_arm_radius": 0.045,
    "forearm_radius": 0.036,
    "thigh_radius": 0.07,
    "shin_radius": 0.05,
    "head_radius": 0.095,
}


@functools.cache
def _default_shape(dtype) -> BodyShape:
    """``BodyShape.default`` per dtype, made at its first call (no JAX work at import)."""
    return BodyShape.create(dtype=dtype)


# ---------------------------------------------------------------------------------------------
# Geometry of the model in its own frames (functions of the shape only).
# ---------------------------------------------------------------------------------------------


def _vec(*xs) -> Array:
    return jnp.stack([jnp.asarray(x) for x in xs])


def joint_offsets(shape: BodyShape) -> Float[Array, "joint 3"]:
    """Position of each kinematic frame's origin in its parent's frame (rest pose), metres."""
    z = jnp.zeros_like(shape.torso)
    sh_y = shape.torso - shape.shoulder_drop
    return jnp.stack(
        [
            _vec(z, z, z),  # root (its translation comes from the parameters)
            _vec(z, shape.torso, z),  # neck
            _vec(-shape.shoulder_width, sh_y, z),  # right shoulder (subject's right = -x)
            _vec(z, -shape.upper_arm, z),  # right elbow
            _vec(shape.shoulder_width, sh_y, z),  # left shoulder
            _vec(z, -shape.upper_arm, z),  # left elbow
            _vec(-shape.hip_width, z, z),  # right hip
            _vec(z, -shape.thigh, z),  # right knee
            _vec(shape.hip_width, z, z),  # left hip
            _vec(z, -shape.thigh, z),  # left knee
        ]
    )


def keypoint_offsets(shape: BodyShape) -> Float[Array, "kpt 3"]:
    """Each COCO-18 keypoint in the frame it rides on (``KEYPOINT_FRAMES``), metres."""
    z = jnp.zeros_like(shape.torso)
    s = shape.head_scale
    zero = _vec(z, z, z)
    wrist = _vec(z, -shape.forearm, z)
    ankle = _vec(z, -shape.shin, z)

    def head(x, y, zz):
        return _vec(s * x, s * y, s * zz)

    return jnp.stack(
        [
            head(*_NOSE),
            zero,  # neck
            zero, zero, wrist,  # right shoulder, elbow, wrist
            zero, zero, wrist,  # left
            zero, zero, ankle,  # right hip, knee, ankle
            zero, zero, ankle,  # left
            head(-_EYE[0], _EYE[1], _EYE[2]),
            head(_EYE[0], _EYE[1], _EYE[2]),
            head(-_EAR[0], _EAR[1], _EAR[2]),
            head(_EAR[0], _EAR[1], _EAR[2]),
        ]
    )  # fmt: skip


#: Names of the surface capsules, in order.
CAPSULE_NAMES = (
    "torso", "torso_right", "torso_left", "pelvis", "shoulders", "neck", "head",
    "right_upper_arm", "right_forearm", "right_hand", "left_upper_arm", "left_forearm",
    "left_hand", "right_thigh", "right_shin", "right_foot", "left_thigh", "left_shin",
    "left_foot",
)  # fmt: skip
#: Frame each capsule rides on (both endpoints).
CAPSULE_FRAMES = (0, 0, 0, 0, 0, 1, 1, 2, 3, 3, 4, 5, 5, 6, 7, 7, 8, 9, 9)
NUM_CAPSULES = len(CAPSULE_NAMES)


def capsule_offsets(
    shape: BodyShape,
) -> tuple[Float[Array, "prim 3"], Float[Array, "prim 3"], Float[Array, " prim"]]:
    """Capsule endpoints ``a``, ``b`` in their frames (``CAPSULE_FRAMES``) and radii, metres."""
    z = jnp.zeros_like(shape.torso)
    t, sw, hw, s = shape.torso, shape.shoulder_width, shape.hip_width, shape.head_scale
    sh_y = t - shape.shoulder_drop
    side_top = jnp.maximum(sw - 0.07, 0.02)
    ua, fa, th, sn = shape.upper_arm, shape.forearm, shape.thigh, shape.shin
    rows = [
        # (a, b, radius)
        (_vec(z, z + 0.02, z), _vec(z, t - 0.12, z), shape.torso_radius),
        (_vec(-0.7 * hw, z + 0.06, z), _vec(-side_top, t - 0.11, z), 0.8 * shape.torso_radius),
        (_vec(0.7 * hw, z + 0.06, z), _vec(side_top, t - 0.11, z), 0.8 * shape.torso_radius),
        (_vec(-hw, z, z), _vec(hw, z, z), 1.35 * shape.thigh_radius),
        (_vec(-sw, sh_y, z), _vec(sw, sh_y, z), 1.1 * shape.upper_arm_radius),
        (_vec(z, z - 0.02, z), _vec(z, 0.08 * s, 0.01 * s), 0.055 * s),
        (_vec(z, 0.15 * s, 0.025 * s), _vec(z, 0.21 * s, 0.025 * s), shape.head_radius * s),
    ]
    for _ in range(2):  # right arm, then left arm (frames differ, geometry is the same)
        rows += [
            (_vec(z, z, z), _vec(z, -ua, z), shape.upper_arm_radius),
            (_vec(z, z, z), _vec(z, -fa, z), shape.forearm_radius),
            (_vec(z, -fa - 0.03, z), _vec(z, -fa - 0.10, z), 1.1 * shape.forearm_radius),
        ]
    for _ in range(2):  # right leg, then left leg
        rows += [
            (_vec(z, z, z), _vec(z, -th, z), shape.thigh_radius),
            (_vec(z, z, z), _vec(z, -sn, z), shape.shin_radius),
            (_vec(z, -sn - 0.03, z - 0.02), _vec(z, -sn - 0.05, z + 0.12), 0.8 * shape.shin_radius),
        ]
    a = jnp.stack([r[0] for r in rows])
    b = jnp.stack([r[1] for r in rows])
    radius = jnp.stack([jnp.asarray(r[2]) * jnp.ones_like(z) for r in rows])
    return a, b, radius


# ---------------------------------------------------------------------------------------------
# Forward kinematics with an analytic forward-mode derivative.
# ---------------------------------------------------------------------------------------------

# Frames grouped by depth in the tree, so the chain is two batched matmuls, not nine.
_LEVEL1 = np.array([1, 2, 4, 6, 8], np.int32)
_LEVEL2 = np.array([3, 5, 7, 9], np.int32)
_LEVEL2_PARENT = np.array([2, 4, 6, 8], np.int32)
_ORDER = np.argsort(np.concatenate([[0], _LEVEL1, _LEVEL2])).astype(np.int32)


def _ancestors() -> np.ndarray:
    """anc[f, j] = 1 if frame j is frame f or one of its ancestors."""
    anc = np.zeros((NUM_JOINTS, NUM_JOINTS))
    for f in range(NUM_JOINTS):
        j = f
        while j >= 0:
            anc[f, j] = 1.0
            j = JOINT_PARENTS[j]
    return anc


_ANCESTORS = _ancestors()
_PARENT_OR_SELF = np.array([max(p, 0) for p in JOINT_PARENTS], np.int32)


def _frames(joint_offs: Array, params: Array):
    """World rotations Rw (joint,3,3), origins c (joint,3), unit quats and quat norms."""
    t = params[:3]
    q = params[3:].reshape(NUM_JOINTS, 4)
    qn = quat_normalize(q)
    R = quat_to_matrix(qn)
    R0 = R[0]
    Rw1 = jnp.einsum("ab,jbc->jac", R0, R[_LEVEL1])
    c1 = t[None, :] + jnp.einsum("ab,jb->ja", R0, joint_offs[_LEVEL1])
    # Level-1 frames are stored in _LEVEL1 order; their parents for level 2 are at known spots.
    pos = {int(j): i for i, j in enumerate(_LEVEL1)}
    par = np.array([pos[int(p)] for p in _LEVEL2_PARENT], np.int32)
    # A broadcast product, not einsum's batched dot: XLA's HLO verifier rejects the batched
    # dot once the tracker step is vmapped over sequences as well as hypotheses (track_many).
    Rw2 = jnp.sum(Rw1[par][:, :, :, None] * R[_LEVEL2][:, None, :, :], axis=2)
    c2 = c1[par] + jnp.einsum("jab,jb->ja", Rw1[par], joint_offs[_LEVEL2])
    Rw = jnp.concatenate([R0[None], Rw1, Rw2])[_ORDER]
    c = jnp.concatenate([t[None], c1, c2])[_ORDER]
    sq = jnp.sum(q * q, axis=-1)
    # Safe norm: the zero quaternion maps to identity in quat_normalize; keep 1/|q| finite.
    qnorm = jnp.sqrt(jnp.where(sq > 1e-12, sq, 1.0))
    return Rw, c, qn, qnorm


def _omega_matrix(qn: Array) -> Array:
    """G(q) with body angular velocity = 2 G(q) dq for unit q (wxyz): G = [-v, w I - [v]x]."""
    w, x, y, z = qn[..., 0], qn[..., 1], qn[..., 2], qn[..., 3]
    return jnp.stack(
        [
            jnp.stack([-x, w, z, -y], axis=-1),
            jnp.stack([-y, -z, w, x], axis=-1),
            jnp.stack([-z, y, -x, w], axis=-1),
        ],
        axis=-2,
    )


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _posed_points(frames: tuple[int, ...], joint_offs: Array, local: Array, params: Array) -> Array:
    Rw, c, _, _ = _frames(joint_offs, params)
    f = np.asarray(frames, np.int32)
    return c[f] + jnp.einsum("mab,mb->ma", Rw[f], local)


def _posed_points_jvp(frames, primals, tangents):
    # Analytic forward-mode derivative. jacfwd through the scalar-style FK emits hundreds of
    # tiny XLA ops and was measured 5x slower on CPU (PERF-NOTES.md); this rule is a handful
    # of batched ops, and its primal-only parts (rotations, lever arms) are computed once
    # when optimistix vmaps it over the 43 basis tangents.
    joint_offs, local, params = primals
    d_offs, d_local, d_params = tangents
    f = np.asarray(frames, np.int32)
    Rw, c, qn, qnorm = _frames(joint_offs, params)
    p = c[f] + jnp.einsum("mab,mb->ma", Rw[f], local)
    anc = jnp.asarray(_ANCESTORS[f], dtype=p.dtype)  # (M, joint)
    dp = jnp.zeros_like(p)
    if not isinstance(d_params, SymbolicZero):
        dt = d_params[:3]
        dq = d_params[3:].reshape(NUM_JOINTS, 4)
        # Body-frame angular velocity 2 G(q^) dq / |q| (the normalisation's projection is
        # absorbed because G(q^) q^ = 0), then to the world frame.
        omega_body = 2.0 * jnp.einsum("jab,jb->ja", _omega_matrix(qn), dq) / qnorm[:, None]
        omega = jnp.einsum("jab,jb->ja", Rw, omega_body)
        # dp_m = dt + sum_j anc[m, j] omega_j x (p_m - c_j)
        #      = dt + (anc @ omega)_m x p_m - (anc @ (omega x c))_m
        big_omega = anc @ omega
        kappa = anc @ jnp.cross(omega, c)
        dp = dp + dt[None, :] + jnp.cross(big_omega, p) - kappa
    if not isinstance(d_offs, SymbolicZero):
        # Moving frame j's origin (in its parent's frame) moves it and its descendants.
        Rparent = Rw[_PARENT_OR_SELF].at[0].set(jnp.eye(3, dtype=p.dtype))
        v = jnp.einsum("jab,jb->ja", Rparent, d_offs)
        dp = dp + anc @ v
    if not isinstance(d_local, SymbolicZero):
        dp = dp + jnp.einsum("mab,mb->ma", Rw[f], d_local)
    return p, dp


_posed_points.defjvp(_posed_points_jvp, symbolic_zeros=True)


def keypoints(shape: BodyShape, params: Float[Array, 43]) -> Float[Array, "kpt 3"]:
    """Forward kinematics: the 18 COCO-18 keypoints M_i in the camera frame, metres.

    Args:
        shape: body dimensions.
        params: the 43 pose parameters (see the module docstring; quaternions wxyz, any norm).

    Returns:
        (18, 3) keypoints in OpenPose COCO-18 order, metres.
    """
    return _posed_points(KEYPOINT_FRAMES, joint_offsets(shape), keypoint_offsets(shape), params)


def capsules(
    shape: BodyShape, params: Float[Array, 43]
) -> tuple[Float[Array, "prim 3"], Float[Array, "prim 3"], Float[Array, " prim"]]:
    """The posed surface: capsule endpoints ``a``, ``b`` (camera frame, metres) and radii."""
    a, b, radius = capsule_offsets(shape)
    frames = CAPSULE_FRAMES + CAPSULE_FRAMES
    pts = _posed_points(frames, joint_offsets(shape), jnp.concatenate([a, b]), params)
    return pts[:NUM_CAPSULES], pts[NUM_CAPSULES:], radius


def joint_frames(
    shape: BodyShape, params: Float[Array, 43]
) -> tuple[Float[Array, "joint 3 3"], Float[Array, "joint 3"]]:
    """World (camera-frame) rotation and origin of each of the 10 kinematic frames."""
    Rw, c, _, _ = _frames(joint_offsets(shape), params)
    return Rw, c


# ---------------------------------------------------------------------------------------------
# Parameter vectors.
# ---------------------------------------------------------------------------------------------


def make_params(
    translation: Float[Array, 3],
    root_quat: Float[Array, 4],
    joint_quats: Float[Array, "9 4"] | None = None,
) -> Float[Array, 43]:
    """Assemble the 43-vector from root translation (metres), root quaternion and the 9 joint
    quaternions (wxyz; identity = rest pose when omitted)."""
    translation = jnp.asarray(translation)
    dtype = translation.dtype
    if joint_quats is None:
        joint_quats = jnp.tile(jnp.asarray([1.0, 0.0, 0.0, 0.0], dtype=dtype), (9, 1))
    return jnp.concatenate(
        [
            translation,
            jnp.asarray(root_quat, dtype=dtype),
            jnp.asarray(joint_quats, dtype=dtype).reshape(-1),
        ]
    )


def facing_camera_params(distance: float = 2.5, dtype=None) -> Float[Array, 43]:
    """Rest pose standing upright ``distance`` metres in front of the camera, facing it.

    The body frame's up (+y) maps to the camera's -y and its forward (+z) to the camera's -z,
    a rotation of pi about x: q = (0, 1, 0, 0).
    """
    dtype = dtype or float
    return make_params(
        jnp.asarray([0.0, 0.0, distance], dtype=dtype),
        jnp.asarray([0.0, 1.0, 0.0, 0.0], dtype=dtype),
    )


def facing_camera_params_np(distance: float = 2.5) -> np.ndarray:
    """:func:`facing_camera_params` as a float32 NumPy array, for host code (no JAX dispatch:
    computing it at import time with JAX cost a third of a second of start-up)."""
    quats = [0.0, 1.0, 0.0, 0.0] + [1.0, 0.0, 0.0, 0.0] * (NUM_JOINTS - 1)
    return np.asarray([0.0, 0.0, distance, *quats], np.float32)


def normalize_params(params: Float[Array, "*batch 43"]) -> Float[Array, "*batch 43"]:
    """Same pose with unit quaternions, each with w >= 0 (a canonical sign)."""
    t = params[..., :3]
    q = quat_normalize(params[..., 3:].reshape(*params.shape[:-1], NUM_JOINTS, 4))
    q = jnp.where(q[..., :1] < 0, -q, q)
    return jnp.concatenate([t, q.reshape(*params.shape[:-1], NUM_JOINTS * 4)], axis=-1)
