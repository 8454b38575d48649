"""Rotation algebra in NumPy for host-side code: file formats (io), the synthetic generator
(synth) and initialisation. The one place for it; jitted code uses the JAX twins in
:mod:`posetrack._rotation`.

Conventions:

* rotation matrices act on column vectors (``p_a = R_a_b @ p_b``); stacks carry leading axes,
  ``(*batch, 3, 3)``;
* quaternions are **wxyz** (scalar first) in every function here, ``(*batch, 4)``; ``q`` and
  ``-q`` are the same rotation, and functions returning one pick ``w >= 0``;
* angles in radians; everything float64 and broadcast over leading axes.

NumPy only (no JAX), so io and synth stay importable and fast without tracing.
"""

from __future__ import annotations

import numpy as np

_IDENTITY_WXYZ = np.array([1.0, 0.0, 0.0, 0.0])


def normalize(v: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors along the last axis; zero vectors stay zero.

    Args:
        v: ``(*batch, n)`` vectors.
        eps: norms below this divide by ``eps`` instead (so 0 maps to 0, never NaN).

    Returns:
        ``(*batch, n)`` unit vectors (or zero).
    """
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, eps)


def _axis_rotation(angle: np.ndarray | float, axis: int) -> np.ndarray:
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def rx(angle: np.ndarray | float) -> np.ndarray:
    """Rotation about +x.

    Args:
        angle: ``(*batch)`` radians.

    Returns:
        ``(*batch, 3, 3)`` rotation matrices.
    """
    return _axis_rotation(angle, 0)


def ry(angle: np.ndarray | float) -> np.ndarray:
    """Rotation about +y: ``(*batch)`` radians -> ``(*batch, 3, 3)``."""
    return _axis_rotation(angle, 1)


def rz(angle: np.ndarray | float) -> np.ndarray:
    """Rotation about +z: ``(*batch)`` radians -> ``(*batch, 3, 3)``."""
    return _axis_rotation(angle, 2)


def axis_angle(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rotation about an axis by an angle (Rodrigues' formula).

    Args:
        axis: ``(*batch, 3)`` direction (normalised here; need not be unit).
        angle: ``(*batch)`` radians.

    Returns:
        ``(*batch, 3, 3)`` rotation matrices.
    """
    axis = normalize(axis)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    c, s = np.cos(angle), np.sin(angle)
    C = 1.0 - c
    R = np.empty(np.shape(angle) + (3, 3))
    R[..., 0, 0] = c + x * x * C
    R[..., 0, 1] = x * y * C - z * s
    R[..., 0, 2] = x * z * C + y * s
    R[..., 1, 0] = y * x * C + z * s
    R[..., 1, 1] = c + y * y * C
    R[..., 1, 2] = y * z * C - x * s
    R[..., 2, 0] = z * x * C - y * s
    R[..., 2, 1] = z * y * C + x * s
    R[..., 2, 2] = c + z * z * C
    return R


def min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking direction ``a`` onto direction ``b``.

    Antiparallel inputs (undefined axis) rotate by pi about an axis perpendicular to ``a``.

    Args:
        a: ``(*batch, 3)`` from-direction (any non-zero length).
        b: ``(*batch, 3)`` to-direction.

    Returns:
        ``(*batch, 3, 3)`` rotation matrices ``R`` with ``R @ a / |a| = b / |b|``.
    """
    a = normalize(a)
    b = normalize(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1)
    c = np.sum(a * b, axis=-1)
    angle = np.arctan2(s, c)
    # Fallback axis for (anti)parallel vectors: anything perpendicular to a.
    perp = np.cross(a, np.array([1.0, 0.0, 0.0]))
    perp2 = np.cross(a, np.array([0.0, 1.0, 0.0]))
    perp = np.where(np.linalg.norm(perp, axis=-1, keepdims=True) > 0.1, perp, perp2)
    axis = np.where((s > 1e-9)[..., None], axis, perp)
    return axis_angle(axis, angle)


def frame_from_axes(
    primary: np.ndarray, hint: np.ndarray, *, primary_axis: int, hint_axis: int
) -> np.ndarray:
    """Rotation whose column ``primary_axis`` is along ``primary`` and whose column
    ``hint_axis`` lies in the plane of (primary, hint), on hint's side.

    The hint is only used for its component orthogonal to ``primary``; if that component
    vanishes the result is arbitrary but finite, so callers blend in a fallback first.

    Args:
        primary: ``(*batch, 3)`` direction of axis ``primary_axis``.
        hint: ``(*batch, 3)`` approximate direction of axis ``hint_axis``.
        primary_axis: 0, 1 or 2 (x, y, z).
        hint_axis: 0, 1 or 2, different from ``primary_axis``.

    Returns:
        ``(*batch, 3, 3)`` right-handed rotation matrices (the axes are the columns).
    """
    p = normalize(primary)
    h = hint - np.sum(hint * p, axis=-1, keepdims=True) * p
    h = normalize(h)
    third = 3 - primary_axis - hint_axis
    # Right-handed: e_third = e_i x e_j for the cyclic order (i, j, third).
    if (primary_axis, hint_axis) in ((0, 1), (1, 2), (2, 0)):
        t = np.cross(p, h)
    else:
        t = np.cross(h, p)
    R = np.empty(p.shape[:-1] + (3, 3))
    R[..., :, primary_axis] = p
    R[..., :, hint_axis] = h
    R[..., :, third] = t
    return R


def align_two(v0: np.ndarray, h0: np.ndarray, v: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Rotation ``R`` with ``R @ v0`` along ``v`` and ``R @ h0`` as close to ``h`` as possible.

    Args:
        v0: ``(*batch, 3)`` rest-frame direction that must map exactly onto ``v``.
        h0: ``(*batch, 3)`` rest-frame direction that should map near ``h``.
        v: ``(*batch, 3)`` target of ``v0``.
        h: ``(*batch, 3)`` target of ``h0``.

    Returns:
        ``(*batch, 3, 3)`` rotation matrices.
    """
    B0 = frame_from_axes(v0, h0, primary_axis=0, hint_axis=1)
    B = frame_from_axes(v, h, primary_axis=0, hint_axis=1)
    return B @ np.swapaxes(B0, -1, -2)


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (wxyz) ``q / |q|``; a (near-)zero quaternion maps to the identity.

    The zero-to-identity rule is the body model's (:func:`posetrack._rotation.quat_normalize`).

    Args:
        q: ``(*batch, 4)`` quaternions, wxyz, any norm.

    Returns:
        ``(*batch, 4)`` unit quaternions, wxyz (the sign of ``q`` is kept).
    """
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    ok = n > 1e-12
    if ok.all():  # the common case: skip both np.where (a third of the time on tiny arrays)
        return q / n
    return np.where(ok, q / np.where(ok, n, 1.0), _IDENTITY_WXYZ)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions (wxyz), normalised here; ``q`` and ``-q`` agree.

    Args:
        q: ``(*batch, 4)`` quaternions, wxyz, any non-zero norm (zero means identity).

    Returns:
        ``(*batch, 3, 3)`` rotation matrices.
    """
    q = quat_normalize(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (yy + zz)
    R[..., 0, 1] = 2 * (xy - wz)
    R[..., 0, 2] = 2 * (xz + wy)
    R[..., 1, 0] = 2 * (xy + wz)
    R[..., 1, 1] = 1 - 2 * (xx + zz)
    R[..., 1, 2] = 2 * (yz - wx)
    R[..., 2, 0] = 2 * (xz - wy)
    R[..., 2, 1] = 2 * (yz + wx)
    R[..., 2, 2] = 1 - 2 * (xx + yy)
    return R


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (wxyz, ``w >= 0``) of rotation matrices (Shepperd's method).

    Args:
        R: ``(*batch, 3, 3)`` rotation matrices.

    Returns:
        ``(*batch, 4)`` unit quaternions, wxyz, ``w >= 0``.
    """
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    q = np.empty((m.shape[0], 4))
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    # Divide by the largest of (w, x, y, z): the others then come with full precision, also
    # near 180 deg where w -> 0.
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    for idx in range(4):
        sel = k == idx
        if not np.any(sel):
            continue
        a = m[sel]
        if idx == 0:
            s = np.sqrt(1.0 + a[:, 0, 0] + a[:, 1, 1] + a[:, 2, 2]) * 2
            q[sel] = np.stack([0.25 * s, (a[:, 2, 1] - a[:, 1, 2]) / s,
                               (a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 1, 0] - a[:, 0, 1]) / s], 1)
        elif idx == 1:
            s = np.sqrt(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2]) * 2
            q[sel] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, 0.25 * s,
                               (a[:, 0, 1] + a[:, 1, 0]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s], 1)
        elif idx == 2:
            s = np.sqrt(1.0 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2]) * 2
            q[sel] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 0, 1] + a[:, 1, 0]) / s,
                               0.25 * s, (a[:, 1, 2] + a[:, 2, 1]) / s], 1)
        else:
            s = np.sqrt(1.0 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1]) * 2
            q[sel] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s], 1)
    q = normalize(q)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of wxyz quaternions (broadcasting): ``b`` first, then ``a``."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unit quaternion (wxyz, ``w >= 0``) of the smallest rotation taking ``a`` onto ``b``.

    Args:
        a: ``(*batch, 3)`` from-direction.
        b: ``(*batch, 3)`` to-direction.

    Returns:
        ``(*batch, 4)`` quaternions, wxyz; see :func:`min_rotation` for antiparallel inputs.
    """
    return matrix_to_quat(min_rotation(a, b))


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (wxyz), along the shorter arc.

    Args:
        q0: ``(*batch, 4)`` start (t = 0), wxyz.
        q1: ``(*batch, 4)`` end (t = 1), wxyz; ``-q1`` is used where that is nearer ``q0``.
        t: ``(*batch)`` fractions.

    Returns:
        ``(*batch, 4)`` unit quaternions, wxyz.
    """
    d = np.sum(q0 * q1, axis=-1)
    q1 = np.where((d < 0)[..., None], -q1, q1)  # shortest arc (q and -q are the same rotation)
    d = np.abs(d)
    t = np.asarray(t)[..., None]
    theta = np.arccos(np.clip(d, -1.0, 1.0))[..., None]
    s = np.sin(theta)
    # Near-identical rotations: sin(theta) -> 0, fall back to normalised lerp.
    small = s < 1e-6
    safe_s = np.where(small, 1.0, s)
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe_s)
    w1 = np.where(small, t, np.sin(t * theta) / safe_s)
    return normalize(w0 * q0 + w1 * q1)


def hemisphere_align(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip quaternion signs along a time axis so consecutive ones have ``dot >= 0``.

    Makes a sequence continuous for interpolation or smoothing (``q`` and ``-q`` are the
    same rotation, their average is not).

    Args:
        q: ``(..., 4)`` quaternions, wxyz, with time along ``axis``.
        axis: the time axis.

    Returns:
        A copy of ``q`` with signs flipped.
    """
    q = np.moveaxis(np.array(q, dtype=np.float64), axis, 0)
    for i in range(1, q.shape[0]):
        flip = np.sum(q[i] * q[i - 1], axis=-1) < 0
        q[i][flip] *= -1
    return np.moveaxis(q, 0, axis)


def matrix_to_euler_zyx(R: np.ndarray) -> np.ndarray:
    """Euler angles (z, y, x) with ``R = rz(z) @ ry(y) @ rx(x)``.

    Exact to rounding everywhere, including gimbal lock (y = +-pi/2): z comes from the first
    column (arbitrary but harmless when that column is along +-z), then y and x are read off
    ``rz(z)^T R = ry(y) rx(x)``, whose second row is ``[0, cos x, -sin x]`` whatever y is.

    Args:
        R: ``(*batch, 3, 3)`` rotation matrices.

    Returns:
        ``(*batch, 3)`` angles (z, y, x), radians; z, x in (-pi, pi], y in [-pi/2, pi/2].
    """
    R = np.asarray(R, dtype=np.float64)
    z = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    cz, sz = np.cos(z), np.sin(z)
    # M = Rz(z)^T R: rows 0 and 1 are mixes of R's rows 0 and 1.
    m00 = cz * R[..., 0, 0] + sz * R[..., 1, 0]
    m11 = -sz * R[..., 0, 1] + cz * R[..., 1, 1]
    m12 = -sz * R[..., 0, 2] + cz * R[..., 1, 2]
    y = np.arctan2(-R[..., 2, 0], m00)
    x = np.arctan2(-m12, m11)
    return np.stack([z, y, x], axis=-1)
