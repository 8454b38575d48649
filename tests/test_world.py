"""Output frames (posetrack._world) and the TRC marker file (posetrack.io._trc)."""

from __future__ import annotations

import numpy as np
import pytest

import posetrack
from posetrack import _body as body
from posetrack import io
from posetrack._so3 import quat_multiply, quat_to_matrix
from posetrack._world import transform_params


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_floor_frame_axes_and_origin():
    # A camera 1.2 m above the floor, pitched down by 20 degrees.
    a = np.deg2rad(20.0)
    up = np.array([0.0, -np.cos(a), np.sin(a)])  # the floor's normal seen by that camera
    pelvis = np.array([0.1, 0.3, 3.0])
    d = 0.95 - up @ pelvis  # the pelvis stands 0.95 m above the floor
    f = posetrack.floor_frame(np.r_[3.0 * up, 3.0 * d], pelvis)  # any scale of the plane
    R = f.rotation
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[1], up, atol=1e-12)  # y is the floor's normal
    assert R[0] @ np.array([1.0, 0, 0]) > 0.99  # x stays the camera's right
    np.testing.assert_allclose(f.points(pelvis), [0.0, 0.95, 0.0], atol=1e-12)
    # The camera sits in front of the person (+z) and above the floor.
    cam = f.points(np.zeros(3))
    assert cam[2] > 2.5 and cam[1] > 0
    # NaN (joints not estimated) stays NaN; the 4x4 matrix says the same as points().
    p = np.array([[np.nan, np.nan, np.nan], [0.3, -0.2, 2.0]])
    w = f.points(p)
    assert np.isnan(w[0]).all()
    np.testing.assert_allclose((f.matrix @ np.r_[p[1], 1.0])[:3], w[1], atol=1e-12)


def test_floor_frame_refuses_no_floor():
    with pytest.raises(ValueError, match="no floor plane"):
        posetrack.floor_frame(posetrack._depthobs.NO_FLOOR, np.zeros(3))
    with pytest.raises(ValueError, match="pelvis"):
        posetrack.floor_frame([0.0, -1.0, 0.0, 1.0], [np.nan, 0, 0])


def test_transformed_params_pose_the_transformed_body():
    rng = np.random.default_rng(0)
    shape = body.BodyShape.default()
    params = np.stack([body.facing_camera_params_np(2.5 + 0.1 * t) for t in range(3)])
    params[:, 7:] += 0.2 * rng.normal(size=params[:, 7:].shape)
    params[:, 3:7] *= 1.7  # quaternions of any norm
    R, s = random_rotation(rng), rng.normal(size=3)
    moved = transform_params(params, R, s)
    kp = np.stack([np.asarray(body.keypoints(shape, p)) for p in params])
    kp_moved = np.stack([np.asarray(body.keypoints(shape, p)) for p in moved])
    np.testing.assert_allclose(kp_moved, kp @ R.T + s, atol=2e-5)
    np.testing.assert_allclose(np.linalg.norm(moved[:, 3:7], axis=1), 1.7, rtol=1e-6)
    # The Hamilton product composes rotations: b first, then a.
    a, b = rng.normal(size=4), rng.normal(size=4)
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-12
    )


def test_trc_round_trip_and_layout(tmp_path):
    rng = np.random.default_rng(1)
    markers = rng.normal(size=(4, 18, 3))
    markers[2, 5] = np.nan  # a marker not seen in frame 2
    path = tmp_path / "m.trc"
    io.write_trc(path, markers, io.COCO18_NAMES, fps=25.0, units="mm", frame_ids=[10, 11, 13, 14])
    lines = path.read_text().splitlines()
    assert lines[0].split("\t")[:3] == ["PathFileType", "4", "(X/Y/Z)"]
    assert lines[2].split("\t")[:5] == ["25.000000", "25.000000", "4", "18", "mm"]
    assert lines[3].split("\t")[2] == "Nose" and lines[4].split("\t")[2:5] == ["X1", "Y1", "Z1"]
    assert lines[5] == "" and len(lines) == 10
    row2 = lines[8].split("\t")
    assert row2[0] == "3" and row2[2 + 15 : 2 + 18] == ["", "", ""]  # a gap, not a zero
    back = io.read_trc(path)
    assert back["names"] == list(io.COCO18_NAMES) and back["units"] == "mm"
    np.testing.assert_allclose(back["times"], [0.0, 0.04, 0.12, 0.16])
    np.testing.assert_allclose(back["markers"], markers * 1000.0, atol=1e-6)  # NaN == NaN


def test_trc_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="names"):
        io.write_trc(tmp_path / "a.trc", np.zeros((2, 3, 3)), ["a", "b"], fps=30.0)
    with pytest.raises(ValueError, match="units"):
        io.write_trc(tmp_path / "a.trc", np.zeros((2, 1, 3)), ["a"], fps=30.0, units="cm")
    (tmp_path / "b.trc").write_text("hello\n")
    with pytest.raises(io.InputError, match="b.trc"):
        io.read_trc(tmp_path / "b.trc")
    assert not (tmp_path / "a.trc").exists()
