"""The room and the camera: floor, back wall (and sometimes a side wall), camera placement.

World frame: y up, floor y = 0. The camera stands at (0, h, 0) looking along -z, tilted down
by a few degrees, with a small random roll and yaw; the person is placed 2-3.5 m in front of
it and the back wall ~4.5-5 m away. Camera frame as in ``posetrack._camera`` (x right,
y down, z forward).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from posetrack._camera import Intrinsics
from posetrack._so3 import rx, ry, rz

from ._motion import MotionClip
from ._skeleton import SEG, Subject, forward_kinematics, keypoints_world

LABEL_NONE, LABEL_FLOOR, LABEL_WALL, LABEL_SIDE_WALL = 0, 1, 2, 3
BODY_LABEL0 = 8
"""Label of body primitive k is ``BODY_LABEL0 + k``; below that: background."""


@dataclasses.dataclass(frozen=True)
class Plane:
    """Plane n . p = c in the world frame (n unit, pointing into the room)."""

    normal: tuple[float, float, float]
    offset: float
    label: int


@dataclasses.dataclass(frozen=True)
class Scene:
    """Static room and camera for one sequence."""

    intrinsics: Intrinsics
    R_cam_world: np.ndarray
    """(3, 3) rotation, world -> camera."""
    t_cam_world: np.ndarray
    """(3,) translation, p_cam = R_cam_world @ p_world + t_cam_world, m."""
    planes: tuple[Plane, ...]
    camera_height: float
    """Camera centre above the floor, m."""
    tilt_deg: float
    """Downward pitch of the optical axis, degrees."""
    person_distance: float
    """Distance of the person's path centre along the optical direction, m."""
    wall_distance: float
    """Distance of the back wall from the camera (world -z), m."""

    @property
    def T_cam_world(self) -> np.ndarray:
        """(4, 4) homogeneous transform mapping world points into the camera frame."""
        T = np.eye(4)
        T[:3, :3] = self.R_cam_world
        T[:3, 3] = self.t_cam_world
        return T

    def to_camera(self, p_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> camera frame, m."""
        return p_world @ self.R_cam_world.T + self.t_cam_world

    def floor_plane_camera(self) -> np.ndarray:
        """Floor as (n_x, n_y, n_z, d) in the camera frame: n . p + d = 0, n pointing up."""
        n = self.R_cam_world @ np.array([0.0, 1.0, 0.0])
        d = -float(n @ self.t_cam_world)  # the floor passes through the world origin
        return np.array([*n, d])

    def inside(self, p_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (...) bool: on the room side of the floor and every wall
        (a point behind a wall cannot be seen, whatever its projection)."""
        ok = np.ones(p_world.shape[:-1], dtype=bool)
        for pl in self.planes:
            ok &= p_world @ np.asarray(pl.normal) >= pl.offset
        return ok


@dataclasses.dataclass(frozen=True)
class CameraVariation:
    """Camera placement that replaces :func:`make_scene`'s own draw (the "wide" variety of
    ``generate``); everything else about the scene is drawn as usual."""

    height: float
    """Camera centre above the floor, m."""
    extra_tilt_deg: float
    """Added to the pitch that aims the optical axis at the body's middle, degrees (the total
    is clipped to [0, ``max_tilt_deg``]: the camera never looks up)."""
    roll_deg: float
    """Roll about the optical axis, degrees."""
    max_tilt_deg: float = 35.0
    """Largest downward pitch, degrees."""


def _intr_np(intr: Intrinsics) -> tuple[float, float, float, float, int, int]:
    return (float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), intr.width,
            intr.height)


def project(intr: Intrinsics, p: np.ndarray) -> np.ndarray:
    """Pinhole projection of camera-frame points (..., 3), m -> pixels (..., 2) (z >= 1 mm)."""
    fx, fy, cx, cy, _, _ = _intr_np(intr)
    z = np.maximum(p[..., 2], 1e-3)
    return np.stack([fx * p[..., 0] / z + cx, fy * p[..., 1] / z + cy], axis=-1)


def _yaw_of(v: np.ndarray) -> float:
    """Angle (rad) about +y taking +z to the horizontal direction v."""
    return float(np.arctan2(v[0], v[2]))


def place_motion(clip: MotionClip, rng: np.random.Generator, *,
                 yaw_deg: float | None = None) -> MotionClip:
    """Rotate a motion about the vertical and centre it at the world origin.

    Travelling motions (pelvis path longer than 0.8 m) are turned so they travel across the
    view (along world x, a side view of the person), others so the first frame faces the
    camera (+z); both with a random yaw jitter. ``yaw_deg`` overrides the final facing/travel
    angle (0 = facing the camera / travelling to the camera's right).
    """
    xz = clip.root[:, [0, 2]]
    span = np.ptp(xz, axis=0)
    travel = bool(np.hypot(*span) > 0.8)
    if travel:
        c = xz - xz.mean(axis=0)
        _, _, vt = np.linalg.svd(c, full_matrices=False)
        u = vt[0]
        if np.dot(xz[-1] - xz[0], u) < 0:
            u = -u
        cur = _yaw_of(np.array([u[0], 0.0, u[1]]))
        target = np.pi / 2 if rng.uniform() < 0.5 else -np.pi / 2  # along +x or -x
        jitter = np.deg2rad(rng.uniform(-20, 20))
        if yaw_deg is not None:
            target, jitter = np.pi / 2 + np.deg2rad(yaw_deg), 0.0
    else:
        f = clip.rotations[0, SEG["pelvis"]] @ np.array([0.0, 0.0, 1.0])
        cur = _yaw_of(f)
        target = 0.0
        jitter = np.deg2rad(rng.uniform(-25, 25))
        if yaw_deg is not None:
            target, jitter = np.deg2rad(yaw_deg), 0.0
    Ry = ry(target + jitter - cur)
    root = clip.root @ Ry.T
    lo, hi = root[:, [0, 2]].min(axis=0), root[:, [0, 2]].max(axis=0)
    centre = 0.5 * (lo + hi)
    root = root - np.array([centre[0], 0.0, centre[1]])
    rot = np.einsum("ij,tsjk->tsik", Ry, clip.rotations)
    info = dict(clip.info, travel_across=travel, yaw_deg=float(np.rad2deg(target + jitter)))
    return MotionClip(root=root, rotations=rot, name=clip.name, info=info)


def make_scene(rng: np.random.Generator, intrinsics: Intrinsics, subject: Subject,
               clip: MotionClip, *, camera: CameraVariation | None = None
               ) -> tuple[Scene, MotionClip]:
    """Camera and room for a placed motion; moves the motion to stand in front of the camera.

    The person's distance is drawn in [2, 3.5] m and increased (up to 4.2 m) until the whole
    body (head top to soles) stays inside the image in >= 95 % of the frames.

    Args:
        rng: randomness (the same draws are made whatever ``camera`` is).
        intrinsics: the camera's intrinsics. subject: the person. clip: the placed motion.
        camera: camera height, tilt and roll to use instead of the drawn 0.8-1.2 m, aim + 1-4
            deg and +-1.5 deg.
    """
    h_cam = float(rng.uniform(0.8, 1.2))
    roll = np.deg2rad(rng.uniform(-1.5, 1.5))
    yaw = np.deg2rad(rng.uniform(-3, 3))
    x_off = float(rng.uniform(-0.2, 0.2))
    d = float(rng.uniform(2.0, 3.5))
    extra_tilt = float(rng.uniform(1.0, 4.0))
    if camera is not None:
        h_cam, extra_tilt = float(camera.height), float(camera.extra_tilt_deg)
        roll = np.deg2rad(camera.roll_deg)
    aim = 0.5 * subject.height - 0.05
    org = forward_kinematics(subject, clip.root, clip.rotations)
    kp = keypoints_world(subject, org, clip.rotations)
    head = org[:, SEG["head"]] + clip.rotations[:, SEG["head"]] @ np.array([0, 0.22, 0.0])
    pts = np.concatenate([kp, head[:, None], kp[:, [10, 13]] - [0, 0.08, 0]], axis=1)
    fx, fy, cx, cy, W, H = _intr_np(intrinsics)
    while True:
        tilt = max(np.arctan2(h_cam - aim, d), 0.0) + np.deg2rad(extra_tilt)
        if camera is not None:
            tilt = float(np.clip(tilt, 0.0, np.deg2rad(camera.max_tilt_deg)))
        R_world_cam = ry(yaw) @ rx(-tilt) @ np.diag([1.0, -1.0, -1.0]) @ rz(roll)
        C = np.array([0.0, h_cam, 0.0])
        Rcw = R_world_cam.T
        tcw = -Rcw @ C
        shift = np.array([x_off, 0.0, -d])
        p = (pts + shift) @ Rcw.T + tcw
        uv = project(intrinsics, p)
        m = 0.02 * W
        inside = ((uv[..., 0] > m) & (uv[..., 0] < W - 1 - m) & (uv[..., 1] > m)
                  & (uv[..., 1] < H - 1 - m) & (p[..., 2] > 0.5)).all(axis=1)
        if inside.mean() >= 0.95 or d >= 4.2:
            break
        d += 0.15
    root = clip.root + shift
    far = float(np.max(-(root[:, 2]))) + 0.7
    wall = max(float(rng.uniform(4.5, 5.0)), far)
    planes = [Plane((0.0, 1.0, 0.0), 0.0, LABEL_FLOOR), Plane((0.0, 0.0, 1.0), -wall, LABEL_WALL)]
    if rng.uniform() < 0.5:
        s = float(rng.uniform(2.2, 3.0))
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        planes.append(Plane((-side, 0.0, 0.0), -s, LABEL_SIDE_WALL))
    scene = Scene(intrinsics=intrinsics, R_cam_world=Rcw, t_cam_world=tcw, planes=tuple(planes),
                  camera_height=h_cam, tilt_deg=float(np.rad2deg(tilt)), person_distance=d,
                  wall_distance=wall)
    placed = MotionClip(root=root, rotations=clip.rotations, name=clip.name,
                        info=dict(clip.info, fit_fraction=float(inside.mean())))
    return scene, placed
