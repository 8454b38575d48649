"""The bystander: a second person who walks across the view and back (two-person scenes).

The tracker follows one person; a second one walking through the picture tests that the track
does not hop between people. The bystander is a random subject of its own with the procedural
``walk`` gait (walking in place) carried along a straight world path parallel to the image
plane (world x), in two passes:

* pass 1 crosses the whole view IN FRONT of the main person (0.4-1.2 m nearer the camera than
  the main person's path centre, never nearer than :data:`MIN_DEPTH`), entering from outside
  the image on one side and leaving beyond the other;
* after a while out of view, pass 2 walks back the other way, in front again or, half of the
  time and only where the back wall leaves :data:`WALL_CLEARANCE` behind it, 0.8-1.3 m BEHIND
  the main person.

Pass 1 starts near 0.1 T and is meant to end by 0.5 T, pass 2 starts near 0.6 T (T = clip
length); one walking speed, the path length over the 0.4 T available to a pass, clipped to
[0.8, 2.0] m/s, so in a short clip pass 1 may run late and pass 2 may not finish or not start.
When not walking, the bystander stands :data:`PARK` beyond the end of its path, far outside
the view frustum, so it is neither rendered nor detected.

Simplification: the in-place gait is slid along the path (the feet are not planted), so the
stride does not match the speed; a detector sees the same walking silhouette.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from posetrack._so3 import ry

from ._motion import MotionClip, procedural_motion
from ._scene import Scene, project
from ._skeleton import Subject

MIN_DEPTH = 1.2
"""Nearest path of the bystander, m from the camera (world -z)."""
FRONT_GAP = (0.4, 1.2)
"""How much nearer the camera than the main person's path centre a front pass runs, m. At
0.4 m the two bodies nearly brush (each torso is ~0.25 m deep): the hardest case for telling
the people apart by depth. (It was 0.6-1.2 m until the first association benchmark came out
with no identity jump at all; widened before the reported run.)"""
WALL_CLEARANCE = 0.5
"""Least room between a path behind the main person and the back wall, m."""
PARK = 5.0
"""How far beyond the end of its path the bystander waits between passes, m."""
MARGIN = 0.7
"""Pelvis distance beyond the last column where a body point is in view at which a path
starts and ends, m: half a stride of arm swing plus the shoulders, so the whole body is
outside the image there."""
SPEED_RANGE = (0.8, 2.0)
"""Walking speed bounds, m/s."""


def view_span(scene: Scene, depth: float, height: float) -> tuple[float, float]:
    """World-x interval over which a person at ``depth`` (world -z, m) can appear in the image.

    Points at floor level, half height and head height (``height``, m) on the line
    ``z = -depth`` are projected on a 1 cm grid; the interval covers every grid point that
    lands inside the image in front of the camera, widened by :data:`MARGIN` on both sides.

    Returns:
        (x_lo, x_hi), world metres; the pelvis is out of view outside it.
    """
    intr = scene.intrinsics
    xs = np.arange(-2000, 2001) * 0.01
    ys = np.array([0.0, 0.5 * height, height])
    p = np.stack(np.broadcast_arrays(xs[:, None], ys[None, :], -depth), axis=-1)
    cam = scene.to_camera(p)
    uv = project(intr, cam)
    ok = ((uv[..., 0] >= 0) & (uv[..., 0] <= intr.width - 1) & (uv[..., 1] >= 0)
          & (uv[..., 1] <= intr.height - 1) & (cam[..., 2] > 0.1)).any(axis=1)
    if not ok.any():  # cannot happen for a camera looking into the room; stay safe
        return -MARGIN, MARGIN
    return float(xs[ok].min()) - MARGIN, float(xs[ok].max()) + MARGIN


def bystander_motion(rng: np.random.Generator, subject: Subject, scene: Scene, *,
                     n_frames: int, fps: float) -> tuple[MotionClip, dict[str, Any]]:
    """The bystander's motion in the world of ``scene`` (see the module docstring).

    Args:
        rng: the bystander's own stream (gait, depths, directions, timing).
        subject: the bystander's body.
        scene: the room and camera; ``scene.person_distance`` is the main person's path
            centre and ``scene.wall_distance`` the back wall, m from the camera.
        n_frames: number of frames T.
        fps: frame rate, Hz.

    Returns:
        The placed clip ((T, 3) pelvis path and (T, S, 3, 3) world segment rotations) and a
        description: ``speed`` (m/s) and ``passes``, two dicts with ``side`` ("front" or
        "behind"), ``depth`` (m from the camera, world -z), ``direction`` (+1 = toward the
        camera's right, i.e. world +x; -1 the reverse), ``frames`` ([start, stop) walking
        frames within the clip; empty when the clip ends first), ``x_start`` and ``x_stop``
        (world x of the path's ends, m).
    """
    clip = procedural_motion("walk", subject, n_frames=n_frames, fps=fps, rng=rng)
    d = scene.person_distance
    depth1 = max(d - float(rng.uniform(*FRONT_GAP)), MIN_DEPTH)
    dir1 = 1.0 if rng.uniform() < 0.5 else -1.0
    behind_coin = bool(rng.uniform() < 0.5)
    front2 = max(d - float(rng.uniform(*FRONT_GAP)), MIN_DEPTH)
    room = scene.wall_distance - WALL_CLEARANCE - d  # deepest offset behind the main path
    u_back = float(rng.uniform())  # drawn always, so the stream does not depend on the room
    behind = behind_coin and room >= 0.8
    depth2 = d + 0.8 + u_back * (min(1.3, room) - 0.8) if behind else front2
    dir2 = -dir1
    T = int(n_frames)
    starts = [int(round(float(rng.uniform(0.08, 0.12)) * T)),
              int(round(float(rng.uniform(0.58, 0.62)) * T))]
    paths = []
    for depth, direction in ((depth1, dir1), (depth2, dir2)):
        lo, hi = view_span(scene, depth, subject.height)
        x0, x1 = (lo, hi) if direction > 0 else (hi, lo)
        paths.append((depth, direction, x0, x1))
    window = 0.4 * T / fps  # seconds available to each pass
    need = max(abs(p[3] - p[2]) for p in paths) / window
    speed = float(np.clip(need, *SPEED_RANGE))
    gap = max(1, int(round(0.05 * T)))
    x = np.empty(T)
    z = np.empty(T)
    yaw = np.empty(T)
    passes = []
    begin = 0
    for i, (depth, direction, x0, x1) in enumerate(paths):
        s = starts[i] if i == 0 else max(starts[i], passes[-1]["frames"][1] + gap)
        n = int(math.ceil(abs(x1 - x0) / speed * fps)) + 1  # frames from x0 to past x1
        s, e = min(s, T), min(s + n, T)
        # Waiting out of view on the entry side until the pass begins.
        x[begin:s] = x0 - direction * PARK
        z[begin:s] = -depth
        yaw[begin:s] = direction * np.pi / 2
        walk = x0 + direction * speed * (np.arange(s, e) - s) / fps
        x[s:e] = walk
        z[s:e] = -depth
        yaw[s:e] = direction * np.pi / 2  # the gait faces +z; ry(+-90 deg) turns it to +-x
        begin = e
        passes.append({"side": "behind" if depth > d else "front", "depth": float(depth),
                       "direction": int(direction), "frames": (s, e), "x_start": float(x0),
                       "x_stop": float(x1)})
    direction, x1 = paths[-1][1], paths[-1][3]
    x[begin:] = x1 + direction * PARK
    z[begin:] = -paths[-1][0]
    yaw[begin:] = direction * np.pi / 2
    R = ry(yaw)  # (T, 3, 3)
    rot = np.einsum("tij,tsjk->tsik", R, clip.rotations)
    root = np.stack([x, clip.root[:, 1], z], axis=1)
    info = dict(clip.info, bystander=True)
    placed = MotionClip(root=root, rotations=rot, name=clip.name, info=info)
    return placed, {"speed": speed, "passes": passes}
