"""Rotation helpers for the generator (NumPy, host side).

Rotation matrices act on column vectors; stacks carry leading axes (``(..., 3, 3)``).
Quaternions are ``wxyz`` (scalar first), as everywhere in posetrack.
"""

from __future__ import annotations

import numpy as np


def _axis_rot(angle: np.ndarray | float, axis: int) -> np.ndarray:
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
    """Rotation about +x by ``angle`` radians (any shape -> shape + (3, 3))."""
    return _axis_rot(angle, 0)


def ry(angle: np.ndarray | float) -> np.ndarray:
    """Rotation about +y by ``angle`` radians."""
    return _axis_rot(angle, 1)


def rz(angle: np.ndarray | float) -> np.ndarray:
    """Rotation about +z by ``angle`` radians."""
    return _axis_rot(angle, 2)


def normalize(v: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors along the last axis (zero vectors stay zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, eps)


def axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation about unit ``axis`` (..., 3) by ``angle`` (...) radians."""
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
    """Smallest rotation taking direction ``a`` onto direction ``b`` (both (..., 3)).

    Antiparallel inputs (undefined axis) rotate by pi about an axis perpendicular to ``a``;
    callers choose reference directions that keep real data away from that case.
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


def frame_from_axes(primary: np.ndarray, hint: np.ndarray, *, primary_axis: int,
                    hint_axis: int) -> np.ndarray:
    """Rotation whose column ``primary_axis`` is ``primary`` and column ``hint_axis`` lies in
    the plane of (primary, hint), on hint's side. Shapes (..., 3) -> (..., 3, 3).

    The hint is only used for its component orthogonal to ``primary``; if that component
    vanishes the result is arbitrary but finite, so callers blend in a fallback first.
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
    """Rotation R with R @ v0 = v (directions) and R @ h0 as close to h as possible.

    ``v0, h0`` are rest-frame vectors, ``v, h`` targets; all (..., 3).
    """
    B0 = frame_from_axes(v0, h0, primary_axis=0, hint_axis=1)
    B = frame_from_axes(v, h, primary_axis=0, hint_axis=1)
    return B @ np.swapaxes(B0, -1, -2)


def to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to unit quaternions (..., 4), ``wxyz``, w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    q = np.empty((m.shape[0], 4))
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    # Shepperd's method: pick the largest of (w, x, y, z) to divide by, for stability.
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


def from_quat(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4), ``wxyz`` (normalised here), to rotation matrices (..., 3, 3)."""
    q = normalize(np.asarray(q, dtype=np.float64))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation of ``wxyz`` quaternions (..., 4) at fractions t (...)."""
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
    """Flip signs along a time axis so consecutive quaternions have non-negative dot product."""
    q = np.moveaxis(np.array(q, dtype=np.float64), axis, 0)
    for i in range(1, q.shape[0]):
        flip = np.sum(q[i] * q[i - 1], axis=-1) < 0
        q[i][flip] *= -1
    return np.moveaxis(q, 0, axis)
