"""Built-in procedural motions (the offline default) and the shared ground-contact solver.

Every motion is written as smooth joint-angle curves (degrees) on the generator's own
skeleton, chained to global segment rotations, then placed on the floor: the pelvis height
makes the lowest foot point touch y = 0 and the horizontal pelvis path is integrated so the
supporting foot does not slide. Walking speed, squat sinking and turning pivots therefore
come out of the leg kinematics instead of being scripted.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from posetrack._so3 import min_rotation, normalize, rx, ry, rz

from ._skeleton import SEG, SEGMENTS, Subject, forward_kinematics, local_to_global

MOTIONS: tuple[str, ...] = (
    "walk", "walk_across", "wave", "squat", "box", "reach", "turn", "idle",
)  # fmt: skip
"""Names of the built-in procedural motions, accepted by ``generate(motion=...)``:

* ``walk``: marching / walking in place, arm swing.
* ``walk_across``: a gait cycle walking sideways across the view (side view), turning around
  at the ends of a ~2.5 m path.
* ``wave``: one or both arms raised and waving, then lowered, repeated.
* ``squat``: repeated squats (pelvis back, trunk lean, arms forward).
* ``box``: boxing guard with straight punches toward the camera (arms in front of the torso).
* ``reach``: random reaching key poses (arms, trunk bend/twist, knee bend), minimum-jerk.
* ``turn``: turning in place between frontal and side views with small steps.
* ``idle``: standing with sway, weight shifts, breathing and head motion.
"""


@dataclasses.dataclass(frozen=True)
class MotionClip:
    """A motion on a given subject: global segment rotations and the pelvis path (world)."""

    root: np.ndarray
    """(T, 3) pelvis origin, world frame (y up, floor y = 0), m."""
    rotations: np.ndarray
    """(T, S, 3, 3) global rotation of every segment (R_world_seg)."""
    name: str
    info: dict[str, Any] = dataclasses.field(default_factory=dict)


def _mj(x: np.ndarray) -> np.ndarray:
    """Minimum-jerk ramp 0 -> 1 on x in [0, 1] (clipped)."""
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x**2)


def _smooth_noise(rng: np.random.Generator, t: np.ndarray, amp: float,
                  fmin: float = 0.08, fmax: float = 0.5, n: int = 3) -> np.ndarray:
    """Band-limited random signal (sum of sinusoids), std ~ amp / sqrt(2)."""
    out = np.zeros_like(t)
    for _ in range(n):
        f = rng.uniform(fmin, fmax)
        out += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return amp * out / np.sqrt(n)


def _bump(p: np.ndarray, c: float, s: float) -> np.ndarray:
    """Periodic Gaussian bump on phase p in [0, 1)."""
    d = (p - c + 0.5) % 1.0 - 0.5
    return np.exp(-0.5 * (d / s) ** 2)


def _keyframes(rng: np.random.Generator, t: np.ndarray, sample, hold=(0.2, 0.6),
               move=(0.8, 1.6)) -> dict[str, np.ndarray]:
    """Minimum-jerk interpolation between random key poses ``sample(rng) -> dict``."""
    T = t.shape[0]
    cur = sample(rng)
    out = {k: np.full(T, v, dtype=np.float64) for k, v in cur.items()}
    time = -rng.uniform(0, hold[1])
    while time < t[-1] + 1e-9:
        time += rng.uniform(*hold)
        nxt = sample(rng)
        dur = rng.uniform(*move)
        w = _mj((t - time) / dur)
        for k in out:
            seg = t >= time
            out[k][seg] = cur[k] + (nxt[k] - cur[k]) * w[seg]
        cur = nxt
        time += dur
    return out


class _Angles:
    """Joint-angle curves (degrees, arrays over time) with anatomical conventions.

    Flexion moves a limb forward (knee flexion backward), abduction away from the midline,
    external rotation turns the front of the limb outward; ``ankle`` > 0 is dorsiflexion
    (toes up). ``pelvis_yaw`` turns the whole body toward its left.
    """

    NAMES = (
        "pelvis_yaw", "pelvis_pitch", "pelvis_roll",
        "abd_flex", "abd_lat", "abd_twist", "chest_flex", "chest_lat", "chest_twist",
        "neck_flex", "neck_yaw", "head_flex", "head_yaw", "head_roll",
    )  # fmt: skip
    SIDED = ("clav_elev", "sh_flex", "sh_abd", "sh_ext", "elbow", "wrist_flex",
             "hip_flex", "hip_abd", "hip_ext", "knee", "ankle")

    def __init__(self, T: int):
        self.T = T
        self.toe_out = {"r": 0.0, "l": 0.0}  # standing foot angle, degrees
        self.toe_down: dict[str, np.ndarray] | None = None
        self.planted = True
        self.a: dict[str, np.ndarray] = {k: np.zeros(T) for k in self.NAMES}
        for s in "rl":
            for k in self.SIDED:
                self.a[f"{s}_{k}"] = np.zeros(T)

    def __getitem__(self, k: str) -> np.ndarray:
        return self.a[k]

    def __setitem__(self, k: str, v) -> None:
        self.a[k] = np.broadcast_to(np.asarray(v, dtype=np.float64), (self.T,)).copy()

    def level_feet(self, toe_down: dict[str, np.ndarray] | None = None, *,
                   planted: bool = True) -> None:
        """Keep each foot level on the floor (pitched toes-down by ``toe_down`` degrees).

        Applied exactly after chaining (see :meth:`apply_feet`), so the ankle angle follows.
        ``planted``: the feet keep the pelvis heading plus the standing toe-out angle (they
        do not twist on the floor when the knees move); otherwise each foot follows the
        heading of its shank (stepping).
        """
        self.planted = planted
        self.toe_down = {s: np.broadcast_to(np.asarray(
            0.0 if toe_down is None else toe_down.get(s, 0.0), dtype=np.float64),
            (self.T,)) for s in "rl"}

    def apply_feet(self, rot: np.ndarray) -> np.ndarray:
        """Replace foot rotations in global ``rot`` (T, S, 3, 3) by level ones, if requested."""
        if self.toe_down is None:
            return rot
        rot = rot.copy()
        for s, sx in (("r", -1.0), ("l", 1.0)):
            if self.planted:
                z = rot[:, SEG["pelvis"], :, 2]
                toe_out = sx * np.deg2rad(self.toe_out[s])
            else:
                z = rot[:, SEG[f"{s}_shank"], :, 2]
                toe_out = 0.0
            heading = np.arctan2(z[:, 0], z[:, 2]) + toe_out
            rot[:, SEG[f"{s}_foot"]] = ry(heading) @ rx(np.deg2rad(self.toe_down[s]))
        return rot

    def local_rotations(self) -> np.ndarray:
        """(T, S, 3, 3) local rotations R_parent_seg (root: R_world_pelvis)."""
        d = {k: np.deg2rad(v) for k, v in self.a.items()}
        L = np.broadcast_to(np.eye(3), (self.T, len(SEGMENTS), 3, 3)).copy()
        L[:, SEG["pelvis"]] = ry(d["pelvis_yaw"]) @ rx(d["pelvis_pitch"]) @ rz(d["pelvis_roll"])
        L[:, SEG["abdomen"]] = ry(d["abd_twist"]) @ rx(d["abd_flex"]) @ rz(d["abd_lat"])
        L[:, SEG["chest"]] = ry(d["chest_twist"]) @ rx(d["chest_flex"]) @ rz(d["chest_lat"])
        L[:, SEG["neck"]] = ry(d["neck_yaw"]) @ rx(d["neck_flex"])
        L[:, SEG["head"]] = ry(d["head_yaw"]) @ rx(d["head_flex"]) @ rz(d["head_roll"])
        for s, sx in (("r", -1.0), ("l", 1.0)):
            g = {k: d[f"{s}_{k}"] for k in self.SIDED}
            L[:, SEG[f"{s}_clavicle"]] = rz(sx * g["clav_elev"])
            # Arm angles are relative to the chest: undo the clavicle's elevation first.
            L[:, SEG[f"{s}_upper_arm"]] = (
                rz(-sx * g["clav_elev"]) @ rz(sx * g["sh_abd"]) @ ry(sx * g["sh_ext"])
                @ rx(-g["sh_flex"])
            )
            L[:, SEG[f"{s}_forearm"]] = rx(-g["elbow"])
            L[:, SEG[f"{s}_hand"]] = rx(-g["wrist_flex"])
            L[:, SEG[f"{s}_thigh"]] = (
                rz(sx * g["hip_abd"]) @ ry(sx * g["hip_ext"]) @ rx(-g["hip_flex"])
            )
            L[:, SEG[f"{s}_shank"]] = rx(g["knee"])
            L[:, SEG[f"{s}_foot"]] = rx(-g["ankle"])
        return L


def _rest(A: _Angles, rng: np.random.Generator, t: np.ndarray, subject: Subject) -> None:
    """Relaxed standing pose with slow sway, breathing and head motion."""
    abd = 9.0 + 25.0 * max(subject.build - 1.0, 0.0)
    for s in "rl":
        A[f"{s}_sh_abd"] = abd + _smooth_noise(rng, t, 2.0)
        A[f"{s}_sh_flex"] = 3.0 + _smooth_noise(rng, t, 3.0)
        A[f"{s}_elbow"] = 12.0 + _smooth_noise(rng, t, 4.0)
        A[f"{s}_sh_ext"] = 5.0
        A[f"{s}_hip_abd"] = 3.0
        A[f"{s}_hip_ext"] = A.toe_out[s] = rng.uniform(3.0, 12.0)
        A[f"{s}_knee"] = 3.0
        A[f"{s}_wrist_flex"] = 5.0 + _smooth_noise(rng, t, 3.0)
    A["pelvis_roll"] = _smooth_noise(rng, t, 1.5)
    A["pelvis_pitch"] = 3.0 + _smooth_noise(rng, t, 1.0)
    A["chest_flex"] = -2.0 + 1.0 * np.sin(2 * np.pi * rng.uniform(0.2, 0.3) * t)  # breathing
    A["chest_twist"] = _smooth_noise(rng, t, 2.0)
    A["head_yaw"] = _smooth_noise(rng, t, 10.0, 0.05, 0.3)
    A["head_flex"] = _smooth_noise(rng, t, 5.0, 0.05, 0.3)
    A["head_roll"] = _smooth_noise(rng, t, 2.0)


def _walk_in_place(A, rng, t, subject):
    f = rng.uniform(0.75, 1.0)
    phi = 2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)
    ah = rng.uniform(28, 48)
    lift = {"l": np.maximum(0, np.sin(phi)) ** 1.5, "r": np.maximum(0, -np.sin(phi)) ** 1.5}
    for s in "rl":
        A[f"{s}_hip_flex"] = ah * lift[s]
        A[f"{s}_knee"] = 3 + 1.7 * ah * lift[s]
    A["pelvis_roll"] = A["pelvis_roll"] + 3.0 * np.sin(phi)
    A["pelvis_yaw"] = A["pelvis_yaw"] + 3.0 * np.cos(phi)
    A["chest_twist"] = A["chest_twist"] - 4.0 * np.cos(phi)
    aa = rng.uniform(15, 35)
    A["l_sh_flex"] = A["l_sh_flex"] - aa * np.sin(phi)
    A["r_sh_flex"] = A["r_sh_flex"] + aa * np.sin(phi)
    for s in "rl":
        A[f"{s}_elbow"] = 20 + 0.6 * np.maximum(A[f"{s}_sh_flex"], 0)
    A.level_feet({s: 12 * lift[s] for s in "rl"}, planted=False)


def _walk_across(A, rng, t, subject):
    Tc = rng.uniform(1.0, 1.2)
    amp = rng.uniform(0.85, 1.1)
    # Heading: walk legs along the path separated by 180-degree turns in place.
    d_walk, d_turn = rng.uniform(1.8, 2.2), rng.uniform(1.1, 1.4)
    heading = np.zeros_like(t)
    s_amp = np.ones_like(t)
    time, h = -rng.uniform(0, d_walk * 0.5), 0.0
    while time < t[-1]:
        time += d_walk
        w = _mj((t - time) / d_turn)
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        heading = np.where(t >= time, h + sign * 180.0 * w, heading)
        bump = np.sin(np.pi * np.clip((t - time) / d_turn, 0, 1))
        s_amp = s_amp - 0.65 * bump
        h += sign * 180.0
        time += d_turn
    pr = (t / Tc + rng.uniform()) % 1.0
    ph = {"r": pr, "l": (pr + 0.5) % 1.0}
    toe_down: dict[str, np.ndarray] = {}
    for s in "rl":
        p = ph[s]
        hip = 12 + 22 * np.cos(2 * np.pi * (p - 0.98))
        # Knee: loading-response bump, then swing flexion rising slower than it falls so
        # the knee is straight again at heel strike.
        dp = (p - 0.72 + 0.5) % 1.0 - 0.5
        knee = (3 + 14 * _bump(p, 0.15, 0.07)
                + 57 * np.exp(-0.5 * (dp / np.where(dp < 0, 0.11, 0.085)) ** 2))
        k = amp * s_amp
        A[f"{s}_hip_flex"] = 6 + k * (hip - 6)
        A[f"{s}_knee"] = 3 + np.maximum(k, 0.5) * (knee - 3)
        # Foot pitch (toes down > 0): heel strike toes-up, flat in stance, heel rise to
        # toe-off; the ankle follows from it (level_feet below).
        toe_down[s] = k * (30 * _bump(p, 0.60, 0.07) - 15 * _bump(p, 0.99, 0.05))
        A[f"{s}_sh_flex"] = 4 - 0.75 * k * (hip - 12)
        A[f"{s}_elbow"] = 18 + 0.5 * np.maximum(A[f"{s}_sh_flex"], 0)
    A["pelvis_yaw"] = heading + 5 * amp * np.sin(2 * np.pi * pr)
    A["chest_twist"] = -7 * amp * np.sin(2 * np.pi * pr)
    A["pelvis_roll"] = 3 * np.sin(2 * np.pi * 2 * pr)
    A["pelvis_pitch"] = 5.0
    A["head_yaw"] = A["head_yaw"] * 0.5
    A.level_feet(toe_down, planted=False)


def _wave(A, rng, t, subject):
    u = rng.uniform()
    arms = ["r"] if u < 0.45 else (["l"] if u < 0.8 else ["r", "l"])
    env = np.zeros_like(t)
    time = rng.uniform(-1.5, 0.4)
    while time < t[-1]:
        up, hold = rng.uniform(0.5, 0.8), rng.uniform(1.8, 3.0)
        env = np.maximum(env, _mj((t - time) / up) * (1 - _mj((t - time - up - hold) / up)))
        time += 2 * up + hold + rng.uniform(0.3, 1.0)
    fw = rng.uniform(1.5, 2.4)
    w = np.sin(2 * np.pi * fw * t + rng.uniform(0, 2 * np.pi))
    for s in arms:
        top = rng.uniform(95, 130)
        A[f"{s}_sh_abd"] = A[f"{s}_sh_abd"] + env * (top - A[f"{s}_sh_abd"] + 10 * w)
        A[f"{s}_sh_ext"] = A[f"{s}_sh_ext"] + env * 80
        A[f"{s}_sh_flex"] = A[f"{s}_sh_flex"] + env * rng.uniform(0, 25)
        A[f"{s}_elbow"] = A[f"{s}_elbow"] + env * (65 + 25 * np.sin(2 * np.pi * fw * t + 0.6))
        A[f"{s}_clav_elev"] = 15 * env
        A[f"{s}_wrist_flex"] = A[f"{s}_wrist_flex"] - 20 * env
    A["chest_lat"] = A["chest_lat"] + (4 * env if arms == ["r"] else -4 * env if
                                       arms == ["l"] else 0)
    A.level_feet()


def _squat(A, rng, t, subject):
    Tsq = rng.uniform(2.4, 3.4)
    depth = rng.uniform(0.75, 1.0)
    d = (0.5 - 0.5 * np.cos(2 * np.pi * t / Tsq + rng.uniform(0, 2 * np.pi))) ** 1.2 * depth
    p = 45 * d
    A["pelvis_pitch"] = A["pelvis_pitch"] + p
    A["abd_flex"] = -0.2 * p
    A["chest_flex"] = A["chest_flex"] - 0.1 * p
    A["neck_flex"] = -0.4 * p
    A["head_flex"] = A["head_flex"] - 0.2 * p
    arms_fwd = rng.uniform() < 0.7
    for s in "rl":
        A[f"{s}_hip_flex"] = 95 * d + A["pelvis_pitch"] - 3.0
        A[f"{s}_knee"] = 3 + 125 * d
        A[f"{s}_hip_abd"] = 3 + 12 * d
        A[f"{s}_hip_ext"] = A[f"{s}_hip_ext"] + 8 * d
        if arms_fwd:
            A[f"{s}_sh_flex"] = A[f"{s}_sh_flex"] + 85 * d / depth * np.minimum(depth, 0.9)
            A[f"{s}_sh_abd"] = A[f"{s}_sh_abd"] * (1 - 0.5 * d)
            A[f"{s}_elbow"] = A[f"{s}_elbow"] * (1 - 0.5 * d)
        else:  # hands to the hips
            A[f"{s}_sh_abd"] = A[f"{s}_sh_abd"] + 25
            A[f"{s}_sh_ext"] = -40
            A[f"{s}_elbow"] = 95
    A.level_feet()


def _box(A, rng, t, subject):
    stance = rng.uniform(6, 14)
    lead = "l" if rng.uniform() < 0.75 else "r"  # orthodox: left foot forward
    back = "r" if lead == "l" else "l"
    bob = 4 * np.sin(2 * np.pi * rng.uniform(1.2, 1.8) * t)
    for s in "rl":
        A[f"{s}_hip_abd"] = 7
        A[f"{s}_knee"] = 18 + bob
    A[f"{lead}_hip_flex"] = stance + 9 + bob / 2
    A[f"{back}_hip_flex"] = -stance + 9 + bob / 2
    A["pelvis_yaw"] = A["pelvis_yaw"] + (-12 if lead == "l" else 12)
    guard = {"sh_flex": 40.0, "sh_abd": 25.0, "elbow": 125.0, "sh_ext": -5.0}
    punch = {"sh_flex": 88.0, "sh_abd": 6.0, "elbow": 5.0, "sh_ext": 0.0}
    q = {"r": np.zeros_like(t), "l": np.zeros_like(t)}
    time, last = rng.uniform(-0.3, 0.3), "r"
    while time < t[-1]:
        arm = ("l" if last == "r" else "r") if rng.uniform() < 0.7 else last
        dur = rng.uniform(0.3, 0.45)
        x = np.clip((t - time) / dur, 0, 1)
        # Fast extension (40 % of the time), slower retraction.
        prof = np.where(x < 0.4, _mj(x / 0.4), 1 - _mj((x - 0.4) / 0.6))
        q[arm] = np.maximum(q[arm], prof * rng.uniform(0.8, 1.0))
        last = arm
        time += dur + rng.uniform(0.15, 0.7)
    for s in "rl":
        for k in guard:
            A[f"{s}_{k}"] = guard[k] + q[s] * (punch[k] - guard[k]) + _smooth_noise(rng, t, 3.0)
        A[f"{s}_clav_elev"] = 8 * q[s]
    A["chest_twist"] = 18 * (q["r"] - q["l"])
    A["abd_twist"] = 6 * (q["r"] - q["l"])
    A["neck_flex"] = 10.0
    A["head_flex"] = A["head_flex"] * 0.3 + 5
    A.level_feet()


def _reach(A, rng, t, subject):
    def sample(r):
        out = {}
        for s in "rl":
            active = r.uniform() < 0.6
            out[f"{s}_sh_flex"] = r.uniform(-15, 150) if active else r.uniform(-5, 25)
            out[f"{s}_sh_abd"] = r.uniform(8, 110) if active else r.uniform(8, 25)
            out[f"{s}_sh_ext"] = r.uniform(-20, 70) if active else r.uniform(-5, 15)
            out[f"{s}_elbow"] = r.uniform(5, 110) if active else r.uniform(10, 40)
        out["abd_flex"] = r.uniform(-3, 25)
        out["chest_flex"] = r.uniform(-5, 20)
        out["chest_twist"] = r.uniform(-25, 25)
        out["chest_lat"] = r.uniform(-10, 10)
        out["knee"] = r.uniform(0, 35) if r.uniform() < 0.5 else r.uniform(0, 8)
        out["head_yaw"] = r.uniform(-30, 30)
        out["head_flex"] = r.uniform(-10, 25)
        return out

    k = _keyframes(rng, t, sample)
    for name in ("abd_flex", "chest_flex", "chest_twist", "chest_lat", "head_yaw", "head_flex"):
        A[name] = A[name] + k[name]
    for s in "rl":
        for name in ("sh_flex", "sh_abd", "sh_ext", "elbow"):
            A[f"{s}_{name}"] = k[f"{s}_{name}"]
        A[f"{s}_clav_elev"] = 0.2 * np.maximum(k[f"{s}_sh_abd"] - 60, 0)
        A[f"{s}_knee"] = 3 + k["knee"]
        A[f"{s}_hip_flex"] = 0.55 * k["knee"]
    A["pelvis_pitch"] = A["pelvis_pitch"] + 0.3 * k["knee"]
    A.level_feet()


def _turn(A, rng, t, subject):
    yaw = np.zeros_like(t)
    speed = np.zeros_like(t)
    time, cur = rng.uniform(0.2, 0.8), 0.0
    while time < t[-1]:
        nxt = 0.0 if cur != 0.0 else float(rng.choice([-1.0, 1.0]) * rng.uniform(70, 100))
        dur = rng.uniform(1.0, 1.5)
        x = (t - time) / dur
        yaw = np.where(t >= time, cur + (nxt - cur) * _mj(x), yaw)
        speed = np.maximum(speed, np.sin(np.pi * np.clip(x, 0, 1)))
        cur = nxt
        time += dur + rng.uniform(0.6, 1.2)
    phi = 2 * np.pi * rng.uniform(0.9, 1.1) * t
    lift = {"l": np.maximum(0, np.sin(phi)) ** 1.5 * speed,
            "r": np.maximum(0, -np.sin(phi)) ** 1.5 * speed}
    for s in "rl":
        A[f"{s}_hip_flex"] = 22 * lift[s]
        A[f"{s}_knee"] = 3 + 40 * lift[s]
    A["pelvis_yaw"] = yaw
    A["head_yaw"] = A["head_yaw"] * 0.5 + 0.15 * np.gradient(yaw, t)
    A.level_feet({s: 8 * lift[s] for s in "rl"}, planted=False)


def _idle(A, rng, t, subject):
    shift = _smooth_noise(rng, t, 4.0, 0.05, 0.2)
    A["l_hip_abd"] = A["l_hip_abd"] + shift
    A["r_hip_abd"] = A["r_hip_abd"] - shift
    A["pelvis_roll"] = A["pelvis_roll"] + 0.6 * shift
    A["abd_lat"] = -0.5 * shift
    for s in "rl":
        A[f"{s}_knee"] = A[f"{s}_knee"] + np.maximum(0, _smooth_noise(rng, t, 6.0, 0.05, 0.2))
        A[f"{s}_hip_flex"] = 0.5 * (A[f"{s}_knee"] - 3)
    A.level_feet()


_BUILDERS = {
    "walk": _walk_in_place, "walk_across": _walk_across, "wave": _wave, "squat": _squat,
    "box": _box, "reach": _reach, "turn": _turn, "idle": _idle,
}


def foot_contacts(subject: Subject, origins: np.ndarray, rotations: np.ndarray,
                  *, local: bool = False):
    """Lowest point of each foot ellipsoid, (T, 2 (R, L), 3) world, m (exact for ellipsoids).

    With ``local=True`` also return that point in each foot's own frame, (T, 2, 3).
    """
    out, loc = [], []
    prims = {p.name: p for p in subject.primitives}
    for side in ("r", "l"):
        prim = prims[f"{side}_foot"]
        seg = SEG[f"{side}_foot"]
        R = rotations[:, seg]
        radii = np.asarray(prim.radii)
        M = R * radii[None, None, :]  # R diag(r)
        # argmin_y over {c + M u, |u| = 1} is u = -M^T e_y / |M^T e_y|.
        g = M[:, 1, :]
        u = -g / np.linalg.norm(g, axis=-1, keepdims=True)
        q = np.asarray(prim.centre) + u * radii
        loc.append(q)
        out.append(origins[:, seg] + np.einsum("tij,tj->ti", R, q))
    if local:
        return np.stack(out, axis=1), np.stack(loc, axis=1)
    return np.stack(out, axis=1)


def ground(subject: Subject, rotations: np.ndarray, *, slide: bool = True,
           root_xz: np.ndarray | None = None, root_y: np.ndarray | None = None) -> np.ndarray:
    """Pelvis path that keeps the feet on the floor.

    Args:
        subject: the body.
        rotations: (T, S, 3, 3) global segment rotations.
        slide: if True integrate the horizontal pelvis motion so the supporting (lower) foot
            does not slide; if False use ``root_xz``.
        root_xz: (T, 2) horizontal pelvis path (x, z) when ``slide`` is False.
        root_y: (T,) desired pelvis height (e.g. from mocap, to keep flight phases); it is
            raised where a foot would go below the floor. None: lowest foot exactly on it.

    Returns:
        (T, 3) pelvis origin, world, m.
    """
    T = rotations.shape[0]
    rel = forward_kinematics(subject, np.zeros((T, 3)), rotations)
    c, q = foot_contacts(subject, rel, rotations, local=True)  # relative to the pelvis
    low = np.min(c[:, :, 1], axis=1)
    y = -low if root_y is None else np.maximum(root_y, -low)
    if slide:
        # Support weights: the lower foot carries the body; a foot swinging forward relative
        # to the pelvis does not (swing clearance in a gait is only a few centimetres).
        # Displacement of the MATERIAL point in contact at frame t between t-1 and t: zero
        # for a foot that rolls (heel strike -> flat -> toe off) without slipping.
        feet = [SEG["r_foot"], SEG["l_foot"]]
        prev = rel[:-1][:, feet] + np.einsum("tfij,tfj->tfi", rotations[:-1][:, feet], q[1:])
        dc = (c[1:] - prev)[:, :, [0, 2]]  # (T-1, 2, 2)
        fwd = rotations[1:, 0][:, [0, 2], 2]  # pelvis forward (x, z)
        fwd = fwd / np.maximum(np.linalg.norm(fwd, axis=-1, keepdims=True), 1e-9)
        v_fwd = np.einsum("tfk,tk->tf", dc, fwd)  # m per frame, > 0 = swinging forward
        h = c[:, :, 1] - low[:, None]
        hm = 0.5 * (h[1:] + h[:-1])
        logw = -hm / 0.004 - np.maximum(v_fwd, 0.0) / 0.004
        logw -= logw.max(axis=1, keepdims=True)
        wm = np.exp(logw)
        wm = wm / wm.sum(axis=1, keepdims=True)
        step = -np.sum(wm[:, :, None] * dc, axis=1)
        xz = np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)], axis=0)
    else:
        assert root_xz is not None
        xz = root_xz
    return np.stack([xz[:, 0], y, xz[:, 1]], axis=1)


def _two_bone_ik(rot: np.ndarray, hips: np.ndarray, knees: np.ndarray, ankles: np.ndarray,
                 targets: np.ndarray, l1: float, l2: float, thigh: int, shank: int) -> None:
    """Re-aim a leg (in place in ``rot``) so the ankle reaches ``targets`` (T, 3).

    The knee stays in the plane the un-corrected leg had (pole = its knee), and each bone is
    turned by the smallest rotation, which keeps its twist.
    """
    v = targets - hips
    d = np.linalg.norm(v, axis=-1)
    u = v / np.maximum(d, 1e-9)[:, None]
    d = np.clip(d, abs(l1 - l2) + 1e-4, l1 + l2 - 1e-4)
    cos_b = np.clip((l1 * l1 + d * d - l2 * l2) / (2 * l1 * d), -1.0, 1.0)
    pole = knees - hips
    n = normalize(pole - np.sum(pole * u, axis=-1, keepdims=True) * u)
    k_new = hips + l1 * (cos_b[:, None] * u + np.sqrt(1 - cos_b**2)[:, None] * n)
    a_new = hips + d[:, None] * u
    R1 = min_rotation(knees - hips, k_new - hips)
    rot[:, thigh] = R1 @ rot[:, thigh]
    shank_old = R1 @ (ankles - knees)[..., None]
    R2 = min_rotation(shank_old[..., 0], a_new - k_new)
    rot[:, shank] = R2 @ R1 @ rot[:, shank]


def _plant(subject: Subject, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pelvis path and leg IK that keep both ankles fixed on the floor (planted motions).

    The ankles stay where they are on average in the designed motion; the pelvis goes where
    the designed leg angles put it relative to them (mean of the two legs), and each leg is
    then re-aimed exactly at its ankle target, so squats sink, weight shifts sway the pelvis
    and the feet never slide.
    """
    T = rot.shape[0]
    rel = forward_kinematics(subject, np.zeros((T, 3)), rot)
    L = subject.dims["ankle_height"]
    feet = [SEG["r_foot"], SEG["l_foot"]]
    e = rel[:, feet]  # (T, 2, 3) ankles relative to the pelvis origin
    A = np.median(e, axis=0)
    A[:, 1] = L
    root = np.mean(A[None] - e, axis=1)
    rot = rot.copy()
    for i, s in enumerate("rl"):
        th, sh, ft = SEG[f"{s}_thigh"], SEG[f"{s}_shank"], SEG[f"{s}_foot"]
        _two_bone_ik(rot, root + rel[:, th], root + rel[:, sh], root + rel[:, ft],
                     np.broadcast_to(A[i], (T, 3)), subject.dims["thigh"],
                     subject.dims["shank"], th, sh)
    return root, rot


def procedural_motion(name: str, subject: Subject, *, n_frames: int, fps: float,
                      rng: np.random.Generator) -> MotionClip:
    """Synthesize a built-in motion (see :data:`MOTIONS`) for ``subject``, facing +z.

    Args:
        name: one of :data:`MOTIONS`.
        subject: the body (limb lengths shape the ground contact and walking speed).
        n_frames: number of frames T.
        fps: frame rate, Hz.
        rng: randomness for amplitudes, rhythms and phases.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown procedural motion {name!r}; choose one of {MOTIONS}")
    t = np.arange(n_frames) / float(fps)
    A = _Angles(n_frames)
    _rest(A, rng, t, subject)
    _BUILDERS[name](A, rng, t, subject)
    rot = local_to_global(A.local_rotations())
    if A.planted:
        root, rot = _plant(subject, rot)
        rot = A.apply_feet(rot)
        root = ground(subject, rot, slide=False, root_xz=root[:, [0, 2]], root_y=root[:, 1])
    else:
        rot = A.apply_feet(rot)
        root = ground(subject, rot)
    return MotionClip(root=root, rotations=rot, name=name,
                      info={"source": "procedural", "travel": name == "walk_across"})
