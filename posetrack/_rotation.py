"""Quaternion helpers in JAX (wxyz everywhere), written to be NaN-free under autodiff.

All functions take the last axis as the quaternion (w, x, y, z) and broadcast over the rest.
Host-side NumPy rotation algebra (io, synth, initialisation) lives in :mod:`posetrack._so3`.
"""

from __future__ import annotations

import jax.numpy as jnp
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
