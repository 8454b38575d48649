"""posetrack._so3 (NumPy rotation algebra, quaternions wxyz) against independent formulas:
the Hamilton product ``q v q*`` for quaternions, textbook axis matrices for Euler angles and
the power ``q0 (q0^-1 q1)^t`` for slerp. Pure NumPy, fast. The quaternion references here
(``qmul``, ``qrotate``, ``quat_axis_angle``) also serve tests/test_io_bvh.py."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posetrack import _so3


def qmul(a, b):
    """Hamilton product of wxyz quaternions (..., 4)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def qconj(q):
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def qrotate(q, v):
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4), wxyz: q v q*."""
    qv = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], -1)
    return qmul(qmul(q, qv), qconj(q))[..., 1:]


def ref_matrix(q):
    """Rotation matrix of unit quaternions via q e_k q*: column k is the image of e_k."""
    q = np.asarray(q, dtype=np.float64)
    cols = [qrotate(q, np.broadcast_to(e, q.shape[:-1] + (3,))) for e in np.eye(3)]
    return np.stack(cols, axis=-1)


def quat_axis_angle(axis, angle):
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], -1)


def assert_same_rotation_quat(q, q_ref, atol):
    """q equals q_ref or -q_ref (the same rotation)."""
    sign = np.where(np.sum(q * q_ref, -1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, sign * q_ref, atol=atol)


def random_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


axes = st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(
    lambda a: np.linalg.norm(a) > 1e-3
)
quaternions = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 1e-3
)
# Near identity, ordinary, and near 180 deg (where w -> 0 and Shepperd's branch matters).
angles = st.one_of(
    st.floats(0.0, 1e-6), st.floats(0.0, np.pi), st.floats(np.pi - 1e-6, np.pi)
)


@settings(max_examples=150, deadline=None)
@given(axis=axes, angle=angles, sign=st.sampled_from([1.0, -1.0]))
def test_quat_matrix_round_trip_and_sign(axis, angle, sign):
    q = sign * quat_axis_angle(axis, angle)
    R = _so3.quat_to_matrix(q)
    np.testing.assert_allclose(R, ref_matrix(q), atol=1e-14)
    # q and -q: the same matrix, to the bit (each entry is a product of two components).
    np.testing.assert_array_equal(_so3.quat_to_matrix(-q), R)
    back = _so3.matrix_to_quat(ref_matrix(q))
    assert back[0] >= 0.0
    assert_same_rotation_quat(back, q, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(back), 1.0, atol=1e-15)


def test_matrix_to_quat_near_and_at_180_degrees():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(6, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[0] = [1.0, 0.0, 0.0]  # exactly about an axis: trace = -1, two diagonal entries -1
    n[1] = [0.0, 0.0, -1.0]
    for w in (0.0, 1e-12, 1e-8, 1e-4):
        q = np.concatenate([np.full((6, 1), w), np.sqrt(1 - w * w) * n], -1)
        back = _so3.matrix_to_quat(ref_matrix(q))
        assert np.all(back[:, 0] >= 0)
        assert_same_rotation_quat(back, q, atol=1e-12)


def test_quat_normalize_and_zero_quaternion_is_identity():
    np.testing.assert_array_equal(_so3.quat_normalize(np.zeros(4)), [1.0, 0.0, 0.0, 0.0])
    identities = np.tile(np.eye(3), (2, 1, 1))
    np.testing.assert_array_equal(_so3.quat_to_matrix(np.zeros((2, 4))), identities)
    q = np.array([0.0, 3.0, 0.0, 4.0])
    np.testing.assert_allclose(_so3.quat_normalize(q), [0.0, 0.6, 0.0, 0.8], atol=1e-16)
    # Non-unit input: normalised before building the matrix.
    np.testing.assert_allclose(_so3.quat_to_matrix(q), ref_matrix(q / 5.0), atol=1e-15)


def test_axis_rotations_and_axis_angle_match_textbook_matrices():
    a = np.array([0.3, -1.2, 2.9])
    c, s = np.cos(a), np.sin(a)
    for k, (f, e) in enumerate(((_so3.rx, [1, 0, 0]), (_so3.ry, [0, 1, 0]), (_so3.rz, [0, 0, 1]))):
        ref = [
            np.array([[1, 0, 0], [0, c[i], -s[i]], [0, s[i], c[i]]]) if k == 0
            else np.array([[c[i], 0, s[i]], [0, 1, 0], [-s[i], 0, c[i]]]) if k == 1
            else np.array([[c[i], -s[i], 0], [s[i], c[i], 0], [0, 0, 1]])
            for i in range(3)
        ]  # fmt: skip
        np.testing.assert_allclose(f(a), np.stack(ref), atol=1e-15)
        np.testing.assert_allclose(_so3.axis_angle(np.tile(e, (3, 1)), a), np.stack(ref),
                                   atol=1e-15)
    rng = np.random.default_rng(1)
    axis, angle = rng.normal(size=(5, 3)), rng.uniform(-np.pi, np.pi, 5)
    np.testing.assert_allclose(
        _so3.axis_angle(axis, angle), ref_matrix(quat_axis_angle(axis, angle)), atol=1e-14
    )


@settings(max_examples=200, deadline=None)
@given(q=quaternions, near_lock=st.booleans(), sign=st.sampled_from([1.0, -1.0]))
def test_matrix_to_euler_zyx_reconstructs_the_rotation(q, near_lock, sign):
    q = np.asarray(q) * sign
    q /= np.linalg.norm(q)
    if near_lock:  # push the rotation onto (or next to) y = +-90 deg
        q = qmul(quat_axis_angle([0, 1, 0], np.pi / 2), q * np.array([1, 1, 1e-9, 1]))
        q /= np.linalg.norm(q)
    R = ref_matrix(q)
    z, y, x = _so3.matrix_to_euler_zyx(R)
    cz, sz, cy, sy, cx, sx = np.cos(z), np.sin(z), np.cos(y), np.sin(y), np.cos(x), np.sin(x)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    np.testing.assert_allclose(Rz @ Ry @ Rx, R, atol=1e-12)
    assert -np.pi / 2 <= y <= np.pi / 2


def test_euler_zyx_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(2)
    zyx = rng.uniform([-np.pi, -np.pi / 2, -np.pi], [np.pi, np.pi / 2, np.pi], size=(50, 3))
    zyx[:5, 1] = np.pi / 2  # gimbal lock: only z + x (or z - x) is defined
    zyx[5:10, 1] = -np.pi / 2
    R = _so3.rz(zyx[:, 0]) @ _so3.ry(zyx[:, 1]) @ _so3.rx(zyx[:, 2])
    back = _so3.matrix_to_euler_zyx(R)
    R_back = _so3.rz(back[:, 0]) @ _so3.ry(back[:, 1]) @ _so3.rx(back[:, 2])
    np.testing.assert_allclose(R_back, R, atol=1e-12)
    np.testing.assert_allclose(back[10:], zyx[10:], atol=1e-9)  # unique away from the lock


def _ref_slerp(q0, q1, t):
    """q0 (q0^-1 q1)^t along the shorter arc, via the axis-angle of the relative rotation."""
    rel = qmul(qconj(q0), q1)
    rel = rel * np.where(rel[..., :1] < 0, -1.0, 1.0)
    angle = 2 * np.arctan2(np.linalg.norm(rel[..., 1:], axis=-1), rel[..., 0])
    axis = rel[..., 1:] / np.maximum(np.linalg.norm(rel[..., 1:], axis=-1, keepdims=True), 1e-300)
    return qmul(q0, quat_axis_angle(axis, t * angle))


def test_slerp_endpoints_midpoint_and_shorter_arc():
    rng = np.random.default_rng(3)
    q0, q1 = random_quats(rng, 20), random_quats(rng, 20)
    q1[:10] *= -1  # about half have a negative dot: slerp must take the shorter arc anyway
    np.testing.assert_allclose(_so3.slerp(q0, q1, np.zeros(20)), q0, atol=1e-14)
    assert_same_rotation_quat(_so3.slerp(q0, q1, np.ones(20)), q1, atol=1e-14)
    for t in (0.25, 0.5, 0.9):
        out = _so3.slerp(q0, q1, np.full(20, t))
        assert_same_rotation_quat(out, _ref_slerp(q0, q1, t), atol=1e-12)
    # Shorter arc: the midpoint is no farther than half the (<= 180 deg) angle from both ends.
    mid = _so3.slerp(q0, q1, np.full(20, 0.5))
    d0 = np.abs(np.sum(mid * q0, -1))
    d01 = np.abs(np.sum(q0 * q1, -1))
    np.testing.assert_allclose(2 * np.arccos(np.minimum(d0, 1)), np.arccos(np.minimum(d01, 1)),
                               atol=1e-7)
    # Nearly identical ends (the normalised-lerp branch) stay unit and in between.
    q2 = q0 + 1e-9 * rng.normal(size=q0.shape)
    out = _so3.slerp(q0, q2 / np.linalg.norm(q2, axis=-1, keepdims=True), np.full(20, 0.5))
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(out, q0, atol=1e-8)


@settings(max_examples=100, deadline=None)
@given(a=axes, b=axes, flip=st.booleans())
def test_min_rotation_and_quat_between_take_a_onto_b_by_the_smallest_angle(a, b, flip):
    a, b = np.asarray(a), np.asarray(b)
    if flip:  # exactly antiparallel: the axis is undefined, any pi rotation will do
        b = -2.0 * a
    ah, bh = a / np.linalg.norm(a), b / np.linalg.norm(b)
    R = _so3.min_rotation(a, b)
    # Within 1e-9 rad of parallel the axis falls back to one perpendicular to a: error <= 2e-9.
    np.testing.assert_allclose(R @ ah, bh, atol=3e-9)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
    assert angle == pytest.approx(np.arccos(np.clip(ah @ bh, -1, 1)), abs=1e-6)
    q = _so3.quat_between(a, b)
    assert q.shape == (4,) and q[0] >= 0
    np.testing.assert_allclose(qrotate(q, ah), bh, atol=3e-9)


@pytest.mark.parametrize(
    "primary_axis,hint_axis", [(0, 1), (1, 0), (1, 2), (2, 1), (2, 0), (0, 2)]
)
def test_frame_from_axes_is_a_right_handed_frame(primary_axis, hint_axis):
    rng = np.random.default_rng(4)
    p, h = rng.normal(size=(8, 3)), rng.normal(size=(8, 3))
    R = _so3.frame_from_axes(p, h, primary_axis=primary_axis, hint_axis=hint_axis)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.tile(np.eye(3), (8, 1, 1)),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R[:, :, primary_axis], p / np.linalg.norm(p, axis=-1)[:, None],
                               atol=1e-12)
    assert np.all(np.sum(R[:, :, hint_axis] * h, -1) > 0)  # on the hint's side


def test_align_two_maps_v0_exactly_and_h0_into_the_plane_of_v_and_h():
    rng = np.random.default_rng(5)
    v0, h0, v, h = (rng.normal(size=(6, 3)) for _ in range(4))
    R = _so3.align_two(v0, h0, v, h)
    unit = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R, unit(v0)), unit(v), atol=1e-12)
    n = unit(np.cross(v, h))
    h0_perp = h0 - np.sum(h0 * unit(v0), -1, keepdims=True) * unit(v0)
    hr = np.einsum("nij,nj->ni", R, unit(h0_perp))
    np.testing.assert_allclose(np.sum(hr * n, -1), 0.0, atol=1e-12)
    assert np.all(np.sum(hr * h, -1) > 0)


def test_hemisphere_align_makes_sequences_continuous_without_changing_rotations():
    rng = np.random.default_rng(6)
    q0, q1 = (np.tile(random_quats(rng, 1), (30, 1)) for _ in range(2))
    q = _so3.slerp(q0, q1, np.linspace(0, 1, 30))
    signs = rng.choice([-1.0, 1.0], size=(30, 1))
    flipped = q * signs
    out = _so3.hemisphere_align(np.stack([flipped, flipped], axis=1), axis=0)
    assert np.all(np.sum(out[1:] * out[:-1], -1) >= 0)
    np.testing.assert_array_equal(np.abs(out[:, 0]), np.abs(flipped))
