"""Quaternion helpers (wxyz everywhere), written to be NaN-free under autodiff.

All functions take the last axis as the quaternion (w, x, y, z) and broadcast over the rest.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

_IDENTITY = (1.0, 0.0, 0.0, 0.0)


def quat_normalize(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Unit quaternion (wxyz) ``q / |q|``; the zero quaternion maps to the identity.

    The "safe where" pattern: ``jnp.where(ok, q / norm, identity)`` alone would still
    propagate NaN gradients from the untaken branch (0/0), so the norm fed to the division is
    replaced by 1 where it is (near) zero. Both branches then have finite derivatives.
    """
    sq = jnp.sum(q * q, axis=-1, keepdims=True)
    ok = sq > 1e-12
    safe_sq = jnp.where(ok, sq, 1.0)
    identity = jnp.asarray(_IDENTITY, dtype=q.dtype)
    return jnp.where(ok, q / jnp.sqrt(safe_sq), identity)


def quat_to_matrix(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix of a UNIT quaternion (wxyz). Normalise first if unsure."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        jnp.stack([1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)], axis=-1),
        jnp.stack([2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)], axis=-1),
        jnp.stack([2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)], axis=-1),
    ]
    return jnp.stack(rows, axis=-2)


def quat_multiply(
    p: Float[Array, "*batch 4"], q: Float[Array, "*batch 4"]
) -> Float[Array, "*batch 4"]:
    """Hamilton product ``p * q`` (wxyz): rotating by ``q`` first, then ``p``."""
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conjugate(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Conjugate (the inverse of a unit quaternion), wxyz."""
    return q * jnp.asarray([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def quat_angle(
    q1: Float[Array, "*batch 4"], q2: Float[Array, "*batch 4"]
) -> Float[Array, "*batch"]:
    """Rotation angle (radians) between two unit quaternions (wxyz); ``q`` and ``-q`` are equal."""
    d = jnp.abs(jnp.sum(q1 * q2, axis=-1))
    return 2.0 * jnp.arccos(jnp.clip(d, 0.0, 1.0))


# ---------------------------------------------------------------------------------------------
# NumPy versions for host-side code (initialisation, file export): no tracing, float64.
# ---------------------------------------------------------------------------------------------


def np_quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """NumPy rotation matrix of a quaternion (wxyz), normalised here."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(n > 1e-12, q / np.where(n > 1e-12, n, 1.0), np.array(_IDENTITY))
    return _np_q2m(q)


def _np_q2m(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def np_matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """NumPy unit quaternion (wxyz, w >= 0) of a rotation matrix (Shepperd's method)."""
    m = np.asarray(m, dtype=np.float64)
    batch = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    out = np.empty((m.shape[0], 4))
    for i, r in enumerate(m):
        tr = np.trace(r)
        if tr > 0:
            s = np.sqrt(tr + 1.0) * 2
            q = [
                0.25 * s,
                (r[2, 1] - r[1, 2]) / s,
                (r[0, 2] - r[2, 0]) / s,
                (r[1, 0] - r[0, 1]) / s,
            ]
        elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
            q = [
                (r[2, 1] - r[1, 2]) / s,
                0.25 * s,
                (r[0, 1] + r[1, 0]) / s,
                (r[0, 2] + r[2, 0]) / s,
            ]
        elif r[1, 1] > r[2, 2]:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
            q = [
                (r[0, 2] - r[2, 0]) / s,
                (r[0, 1] + r[1, 0]) / s,
                0.25 * s,
                (r[1, 2] + r[2, 1]) / s,
            ]
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
            q = [
                (r[1, 0] - r[0, 1]) / s,
                (r[0, 2] + r[2, 0]) / s,
                (r[1, 2] + r[2, 1]) / s,
                0.25 * s,
            ]
        q = np.asarray(q)
        out[i] = q if q[0] >= 0 else -q
    return out.reshape(*batch, 4)


def np_quat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """NumPy unit quaternion (wxyz) of the smallest rotation taking direction ``a`` to ``b``."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / max(np.linalg.norm(a), 1e-12)
    b = b / max(np.linalg.norm(b), 1e-12)
    d = float(np.dot(a, b))
    if d < -1 + 1e-9:
        # Opposite directions: rotate by pi about any axis orthogonal to a.
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return np.array([0.0, *axis])
    q = np.array([1.0 + d, *np.cross(a, b)])
    return q / np.linalg.norm(q)
