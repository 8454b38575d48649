"""Output frames: the depth camera's, or a world frame standing on the floor.

Poses are estimated in the depth camera's frame (OpenCV: x right, y down, z forward, metres).
That frame tilts with the camera, and its "height" axis points down, which is awkward for
biomechanics and animation. The tracker already fits the floor plane (it scores hypotheses
against it), so a world frame costs nothing more:

* ``floor``: y up (the floor's normal), metres, right-handed; x is the camera's x laid onto the
  floor, z = x cross y points from the scene towards the camera; the origin is on the floor
  under the pelvis of the first tracked frame. A level camera gives ``diag(1, -1, -1)`` plus a
  shift, the convention of BVH, OpenSim and most animation tools.

A :class:`WorldFrame` maps camera points (``points``) and body-model parameters (``params``:
the root's translation and rotation; joint rotations are relative and do not change).
NumPy, host side: it runs once per recording, on the tracker's result.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._depthobs import NO_FLOOR
from ._so3 import matrix_to_quat, quat_multiply

#: The output frames ``posetrack track --frame`` accepts.
FRAMES = ("camera", "floor")


@dataclasses.dataclass(frozen=True)
class WorldFrame:
    """A rigid frame the outputs are written in: ``p_world = rotation @ (p_camera - origin)``."""

    name: str
    """"camera" or "floor" (:data:`FRAMES`)."""
    rotation: np.ndarray
    """``(3, 3)`` rows are the frame's x, y, z axes in camera coordinates."""
    origin: np.ndarray
    """``(3,)`` the frame's origin in camera coordinates, metres."""

    @property
    def matrix(self) -> np.ndarray:
        """``(4, 4)`` homogeneous ``world_from_camera``."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = -self.rotation @ self.origin
        return m

    def points(self, p: np.ndarray) -> np.ndarray:
        """``(..., 3)`` camera-frame points in this frame (NaN stays NaN)."""
        p = np.asarray(p, np.float64)
        return (p - self.origin) @ self.rotation.T

    def params(self, params: np.ndarray) -> np.ndarray:
        """``(T, 43)`` body-model parameters posing the same body in this frame."""
        return transform_params(params, self.rotation, -self.rotation @ self.origin)


def camera_frame() -> WorldFrame:
    """The depth camera's own frame (the identity)."""
    return WorldFrame("camera", np.eye(3), np.zeros(3))


def floor_frame(floor: np.ndarray, pelvis: np.ndarray) -> WorldFrame:
    """The floor frame (module docstring) of a floor plane and a pelvis position.

    Args:
        floor: ``(4,)`` plane ``(nx, ny, nz, d)``, camera frame: ``n @ p + d`` is a point's
            height above the floor (the tracker's ``TrackResult.floor``).
        pelvis: ``(3,)`` camera-frame point whose foot on the floor is the origin.

    Raises:
        ValueError: no floor (``NO_FLOOR`` or not finite), a normal along the camera's x axis,
            or a pelvis that is not finite.
    """
    floor = np.asarray(floor, np.float64).reshape(-1)
    pelvis = np.asarray(pelvis, np.float64).reshape(-1)
    if floor.shape != (4,) or not np.isfinite(floor).all() or np.allclose(floor, NO_FLOOR):
        raise ValueError(
            "floor frame: no floor plane was found in this recording (the tracker needs a "
            "visible, near-horizontal floor under the person); use the camera frame instead"
        )
    if pelvis.shape != (3,) or not np.isfinite(pelvis).all():
        raise ValueError(f"floor frame: the pelvis must be a finite 3D point, got {pelvis!r}")
    norm = np.linalg.norm(floor[:3])
    y, d = floor[:3] / norm, floor[3] / norm
    x = np.array([1.0, 0.0, 0.0]) - y[0] * y
    if np.linalg.norm(x) < 1e-6:
        raise ValueError(f"floor frame: the floor normal {y.tolist()} is the camera's x axis")
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    origin = pelvis - (y @ pelvis + d) * y
    return WorldFrame("floor", np.stack([x, y, z]), origin)


def transform_params(params: np.ndarray, rotation: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Parameters of the body moved rigidly by ``p -> rotation @ p + shift``.

    The root translation (the pelvis) moves as a point and the root quaternion turns by
    ``rotation`` (its norm is kept); the joint quaternions are relative to their parents.
    """
    params = np.array(params, np.float64)
    params[:, :3] = params[:, :3] @ np.asarray(rotation).T + np.asarray(shift)
    turn = matrix_to_quat(np.asarray(rotation, np.float64))
    params[:, 3:7] = quat_multiply(turn, params[:, 3:7])
    return params
