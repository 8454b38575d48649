"""Real motion from the data folder (CMU BVH, MSR Action3D, UTKinect) retargeted to a subject.

The data are read in place from :func:`data_root` and never copied (their licences forbid
redistribution). Retargeting keeps the data's bone DIRECTIONS and the generated subject's own
bone LENGTHS: per frame, every segment gets a global rotation that points its bone along the
data's bone (torso frames from the hip and shoulder lines, limb twist from the elbow/knee
bend plane, feet from the ankle->toe direction, the head from the BVH head rotation when
there is one), then forward kinematics with the subject's offsets rebuilds the body. The
pelvis path is the data's, scaled by the ratio of leg lengths, and re-grounded so the feet
touch the floor (flight phases such as hops are kept).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import numpy as np

from posetrack._so3 import (
    align_two,
    axis_angle,
    frame_from_axes,
    hemisphere_align,
    matrix_to_quat,
    min_rotation,
    normalize,
    quat_to_matrix,
    ry,
    rz,
    slerp,
)
from posetrack.io import bvh_world_transforms, read_bvh

from ._motion import MotionClip, ground
from ._skeleton import SEG, SEGMENTS, Subject

CMU_UNIT_M = 0.056444
"""One CMU BVH length unit in metres (README of cmu-mocap-bvh-subject131)."""

_CMU_DIR = "cmu-mocap-bvh-subject131"
_MSR_DIR = "msr-action3d-skeleton3d"
_UTK_DIR = "utkinect-action3d-joints"

# 0-based joint indices of the Kinect skeleton files, by canonical marker.
_MSR = {"shoulder_l": 0, "shoulder_r": 1, "neck": 2, "spine": 3, "hip_l": 4, "hip_r": 5,
        "pelvis": 6, "elbow_l": 7, "elbow_r": 8, "wrist_l": 9, "wrist_r": 10, "hand_l": 11,
        "hand_r": 12, "knee_l": 13, "knee_r": 14, "ankle_l": 15, "ankle_r": 16, "toe_l": 17,
        "toe_r": 18, "head": 19}
_UTK = {"pelvis": 0, "spine": 1, "neck": 2, "head": 3, "shoulder_l": 4, "elbow_l": 5,
        "wrist_l": 6, "hand_l": 7, "shoulder_r": 8, "elbow_r": 9, "wrist_r": 10, "hand_r": 11,
        "hip_l": 12, "knee_l": 13, "ankle_l": 14, "toe_l": 15, "hip_r": 16, "knee_r": 17,
        "ankle_r": 18, "toe_r": 19}
_CMU = {"hip_l": "LeftHip", "hip_r": "RightHip", "knee_l": "LeftKnee", "knee_r": "RightKnee",
        "ankle_l": "LeftAnkle", "ankle_r": "RightAnkle", "toe_l": "LeftToe",
        "toe_r": "RightToe", "spine": "Chest", "neck": "Neck", "head_base": "Head",
        "shoulder_l": "LeftShoulder", "shoulder_r": "RightShoulder",
        "elbow_l": "LeftElbow", "elbow_r": "RightElbow", "wrist_l": "LeftWrist",
        "wrist_r": "RightWrist", "hand_l": "LFingers", "hand_r": "RFingers"}


def data_root() -> Path | None:
    """The real-data folder, or None when absent.

    ``$POSETRACK_DATA`` if set, else ``<repo>/../shared/data`` (the repo being the checkout
    that contains this package).
    """
    env = os.environ.get("POSETRACK_DATA")
    p = Path(env) if env else Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
    p = p.resolve()
    return p if p.is_dir() else None


@functools.lru_cache(maxsize=8)
def _utk_labels(root: Path) -> dict[str, dict[str, tuple[int, int]]]:
    out: dict[str, dict[str, tuple[int, int]]] = {}
    path = root / _UTK_DIR / "actionLabel_modified.txt"
    if not path.is_file():
        path = root / _UTK_DIR / "actionLabel.txt"
    if not path.is_file():
        return out
    seq = None
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line:
            continue
        if ":" not in line:
            seq = line
            out[seq] = {}
            continue
        name, rng_ = line.split(":", 1)
        vals = rng_.split()
        if seq is None or len(vals) != 2 or "nan" in rng_.lower():
            continue
        out[seq][name.strip()] = (int(vals[0]), int(vals[1]))
    return out


def list_real_motions(*, include_corrupt: bool = False) -> list[str]:
    """Names of the real motions available in :func:`data_root` (empty if it is absent).

    ``cmu:131_01``; ``msr:a01_s01_e01`` (only the 557 sequences of Wang et al. CVPR 2012
    unless ``include_corrupt``); ``utk:s01_e01`` (a whole recording, 10 actions in a row) and
    ``utk:s01_e01:waveHands`` (one labelled action of it).
    """
    root = data_root()
    if root is None:
        return []
    names: list[str] = []
    cmu = root / _CMU_DIR
    if cmu.is_dir():
        names += [f"cmu:{p.stem}" for p in sorted(cmu.glob("[0-9]*_[0-9]*.bvh"))]
    msr = root / _MSR_DIR
    if msr.is_dir():
        seqs = [p.name.removesuffix("_skeleton3D.txt") for p in sorted(
            msr.glob("a*_s*_e*_skeleton3D.txt"))]
        good = msr / "files_used_in_cvpr12_paper.txt"
        if not include_corrupt and good.is_file():
            keep = set(good.read_text().split())
            seqs = [s for s in seqs if s in keep]
        names += [f"msr:{s}" for s in seqs]
    utk = root / _UTK_DIR
    if utk.is_dir():
        labels = _utk_labels(root)
        for p in sorted(utk.glob("joints_s*_e*.txt")):
            seq = p.stem.removeprefix("joints_")
            names.append(f"utk:{seq}")
            names += [f"utk:{seq}:{a}" for a in labels.get(seq, {})]
    return names


def _gauss_smooth(x: np.ndarray, sigma: float, axis: int = 0) -> np.ndarray:
    """Gaussian smoothing along ``axis`` with edge-reflect padding (NumPy only)."""
    if sigma <= 0:
        return x
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    x = np.moveaxis(x, axis, 0)
    pad = np.concatenate([x[r:0:-1], x, x[-2 : -r - 2 : -1]], axis=0) if x.shape[0] > r + 1 \
        else np.concatenate([np.repeat(x[:1], r, 0), x, np.repeat(x[-1:], r, 0)], axis=0)
    out = np.zeros_like(x, dtype=np.float64)
    for i, w in enumerate(k):
        out += w * pad[i : i + x.shape[0]]
    return np.moveaxis(out, 0, axis)


def _resample_uniform(times: np.ndarray, x: np.ndarray, fps: float) -> np.ndarray:
    """Linear resampling of (N, ...) samples at irregular ``times`` to a uniform grid."""
    grid = np.arange(times[0], times[-1] + 1e-9, 1.0 / fps)
    flat = x.reshape(x.shape[0], -1)
    out = np.stack([np.interp(grid, times, flat[:, k]) for k in range(flat.shape[1])], axis=1)
    return out.reshape((grid.size,) + x.shape[1:])


def _fix_chirality(m: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], bool]:
    """Reflect x if the labelled left/right disagree with the direction the feet point.

    A mirrored skeleton (left-handed axes or swapped labels) has its hip line crossed with
    "up" pointing backward while the feet still point forward.
    """
    up = np.array([0.0, 1.0, 0.0])
    fwd_lr = np.cross(m["hip_l"] - m["hip_r"] + m["shoulder_l"] - m["shoulder_r"], up)
    feet = m["toe_l"] - m["ankle_l"] + m["toe_r"] - m["ankle_r"]
    feet[:, 1] = 0
    s = np.median(np.sum(normalize(fwd_lr) * normalize(feet), axis=-1))
    if s >= 0:
        return m, False
    return {k: v * np.array([-1.0, 1.0, 1.0]) for k, v in m.items()}, True


#: Metres: a Kinect skeleton's knee (ankle) pair is relabelled where the two joints lie nearer
#: the other side's hip (knee) by more than this, summed over both legs
#: (:func:`_consistent_legs`).
LEG_LABEL_MARGIN = 0.05


def _consistent_legs(m: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], list[int]]:
    """Exchange a Kinect skeleton's left/right leg labels on the frames where they cross its
    hips: where the knees sit nearer the other side's hip (the two hip-to-knee distances,
    summed, shorter crossed than straight by :data:`LEG_LABEL_MARGIN`), the knee, ankle and
    toe labels are exchanged; then likewise the ankle and toe labels against the knees.

    The Kinect tracker behind MSR Action3D and UTKinect labels the leg joints on their own: in
    MSR Action3D 34 of subject 2's 59 sequences have the knees crossed against the hips on
    every frame (the thighs through each other, 15-20 cm), a11_s03_e01 the ankles against the
    knees, and a few other sequences some frames. Retargeted as they are, the generated body
    crosses its legs, a pose no person in those actions takes and no tracker should be scored
    against. Returns the markers and the frames relabelled at the knees and at the ankles.
    """
    m = dict(m)
    fixed = []
    for parent, chain in (("hip", ("knee", "ankle", "toe")), ("knee", ("ankle", "toe"))):
        pl, pr = m[f"{parent}_l"], m[f"{parent}_r"]
        cl, cr = m[f"{chain[0]}_l"], m[f"{chain[0]}_r"]
        straight = np.linalg.norm(pl - cl, axis=-1) + np.linalg.norm(pr - cr, axis=-1)
        crossed = np.linalg.norm(pl - cr, axis=-1) + np.linalg.norm(pr - cl, axis=-1)
        swap = (crossed + LEG_LABEL_MARGIN < straight)[:, None]
        for joint in chain:
            left, right = m[f"{joint}_l"], m[f"{joint}_r"]
            m[f"{joint}_l"] = np.where(swap, right, left)
            m[f"{joint}_r"] = np.where(swap, left, right)
        fixed.append(int(swap.sum()))
    return m, fixed


def load_markers(name: str) -> tuple[dict[str, np.ndarray], float, dict[str, Any]]:
    """Canonical marker trajectories of a real motion.

    Args:
        name: as listed by :func:`list_real_motions`.

    Returns:
        markers: name -> (N, 3) positions, m, y up (``head_fwd`` is a direction);
        fps: uniform sample rate of the markers, Hz;
        info: provenance (file, source rate, chirality fix, ...).

    Raises:
        FileNotFoundError: naming the missing folder/file when the data are absent.
        ValueError: for an unknown name.
    """
    root = data_root()
    if root is None:
        raise FileNotFoundError(
            "real motion data folder not found: set POSETRACK_DATA or provide "
            f"{Path(__file__).resolve().parents[2] / '..' / 'shared' / 'data'}"
        )
    kind, _, rest = name.partition(":")
    info: dict[str, Any] = {"name": name}
    if kind == "cmu":
        path = root / _CMU_DIR / f"{rest}.bvh"
        if not path.is_file():
            raise FileNotFoundError(f"CMU BVH file not found: {path}")
        bvh = read_bvh(path)
        pos, rot = bvh_world_transforms(
            bvh.parents, bvh.offsets, bvh.channels, bvh.motion, scale=CMU_UNIT_M
        )
        m = {k: pos[:, bvh.names.index(v)] for k, v in _CMU.items()}
        head = bvh.names.index("Head")
        # Top of the head: the Head joint's End Site, a fixed offset in the Head's frame.
        top = np.broadcast_to(bvh.end_sites[head] * CMU_UNIT_M, (len(pos), 3))
        m["head"] = pos[:, head] + np.einsum("fij,fj->fi", rot[:, head], top)
        m["pelvis"] = 0.5 * (m["hip_l"] + m["hip_r"])
        # The head's own frame gives its facing (BVH rest pose faces +z).
        m["head_fwd"] = rot[:, head] @ np.array([0.0, 0.0, 1.0])
        fps = 1.0 / bvh.frame_time
        info.update(file=str(path), source_fps=fps, kinect=False)
        return m, fps, info
    if kind == "msr":
        path = root / _MSR_DIR / f"{rest}_skeleton3D.txt"
        if not path.is_file():
            raise FileNotFoundError(f"MSR Action3D skeleton file not found: {path}")
        a = np.loadtxt(path).reshape(-1, 20, 4)[..., :3].astype(np.float64)
        # Some (corrupt) sequences contain all-zero frames: trim them at the ends and
        # interpolate inside.
        ok = np.abs(a).sum(axis=(1, 2)) > 0
        if ok.sum() < 2:
            raise ValueError(f"MSR Action3D sequence {rest}: fewer than 2 valid frames")
        idx = np.arange(a.shape[0])
        lo, hi = idx[ok][0], idx[ok][-1]
        flat = a.reshape(a.shape[0], -1)
        a = np.stack([np.interp(idx, idx[ok], flat[ok, k]) for k in range(flat.shape[1])],
                     axis=1).reshape(a.shape)[lo : hi + 1]
        info["dropped_frames"] = int((~ok).sum())
        m = {k: a[:, i] for k, i in _MSR.items()}
        fps = 15.0
        info.update(file=str(path), source_fps=fps, kinect=True)
    elif kind == "utk":
        seq, _, action = rest.partition(":")
        path = root / _UTK_DIR / f"joints_{seq}.txt"
        if not path.is_file():
            raise FileNotFoundError(f"UTKinect joints file not found: {path}")
        raw = np.loadtxt(path)
        idx = raw[:, 0]
        if action:
            lab = _utk_labels(root).get(seq, {})
            if action not in lab:
                raise ValueError(f"UTKinect {seq}: no action {action!r}; have {sorted(lab)}")
            lo, hi = lab[action]
            keep = (idx >= lo) & (idx <= hi)
            raw, idx = raw[keep], idx[keep]
        # Frame indices repeat and skip: average duplicates, then resample to 30 fps.
        uniq, inv = np.unique(idx, return_inverse=True)
        j = np.zeros((uniq.size, 60))
        np.add.at(j, inv, raw[:, 1:])
        j /= np.bincount(inv)[:, None]
        fps = 30.0
        j = _resample_uniform(uniq / 30.0, j, fps).reshape(-1, 20, 3)
        m = {k: j[:, i] for k, i in _UTK.items()}
        info.update(file=str(path), source_fps=fps, kinect=True, action=action or None)
    else:
        raise ValueError(f"unknown real motion {name!r}: expected cmu:/msr:/utk: prefix")
    if info["kinect"]:  # labelled joint by joint: legs may cross their own hips
        m, (info["knees_relabelled"], info["ankles_relabelled"]) = _consistent_legs(m)
    # Kinect-tracker skeletons jitter by centimetres: smooth lightly (sigma = 1 sample).
    m = {k: _gauss_smooth(v, 1.0) for k, v in m.items()}
    m, flipped = _fix_chirality(m)
    info["mirrored"] = flipped
    return m, fps, info


def _twist_toward(R: np.ndarray, target_z: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Rotate frames R (N, 3, 3) about their own y axis so z turns toward ``target_z``."""
    y = R[:, :, 1]
    z = R[:, :, 2]
    t = target_z - np.sum(target_z * y, axis=-1, keepdims=True) * y
    ang = np.arctan2(np.sum(np.cross(z, t) * y, axis=-1), np.sum(z * t, axis=-1))
    return axis_angle(y, weight * ang) @ R


def _bend_weight(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit bend direction of bone b relative to bone a, and a 0..1 confidence weight."""
    a = normalize(a)
    b = normalize(b)
    perp = b - np.sum(b * a, axis=-1, keepdims=True) * a
    s = np.linalg.norm(perp, axis=-1)
    return normalize(perp), np.clip((s - 0.1) / 0.3, 0.0, 1.0)


SPINE_MAX_DEG = 25.0
"""A spine marker whose direction from the mid-hip lies further than this (median over the
sequence) from the mid-hip -> neck direction is not used as it is (:func:`torso_spine`)."""


def torso_spine(markers: dict[str, np.ndarray]) -> np.ndarray:
    """The spine point the pelvis and chest frames are built from, (N, 3).

    The data's spine marker, unless it lies off the line from the mid-hip to the neck by more
    than :data:`SPINE_MAX_DEG` (median angle over the sequence, seen from the mid-hip); then its
    projection onto that line. MSR Action3D's spine joint sits 32-49 degrees off that line
    (median 40 on 25 sequences, ~15 cm behind it), where UTKinect's and CMU's sit 0-13 degrees
    off: built from it, the pelvis tipped back ~35 degrees and the chest forward ~50, a
    contorted torso whose joints lay at the wrong depth inside its surfaces.
    """
    mid_hip = 0.5 * (markers["hip_l"] + markers["hip_r"])
    spine = markers["spine"] - mid_hip
    axis = normalize(markers["neck"] - mid_hip)
    cos = np.sum(normalize(spine) * axis, axis=-1)
    if np.degrees(np.arccos(np.clip(np.median(cos), -1.0, 1.0))) <= SPINE_MAX_DEG:
        return markers["spine"]
    return mid_hip + np.sum(spine * axis, axis=-1, keepdims=True) * axis


def retarget(markers: dict[str, np.ndarray], subject: Subject, *, level_feet: bool = False
             ) -> tuple[np.ndarray, np.ndarray]:
    """Global segment rotations of ``subject`` reproducing the markers' bone directions.

    Args:
        markers: canonical trajectories (N, 3), see :func:`load_markers`.
        subject: the target body.
        level_feet: ignore the ankle->toe direction and keep the foot level, heading where
            the shank's knee plane points (for Kinect-tracker skeletons, whose foot joints
            are the least reliable).

    Returns:
        rotations (N, S, 3, 3) and the pelvis-origin path (N, 3) scaled to the subject's leg
        length (its height is re-grounded later).
    """
    m = markers
    N = m["pelvis"].shape[0]
    S = len(SEGMENTS)
    R = np.zeros((N, S, 3, 3))
    ex = np.array([1.0, 0.0, 0.0])
    mid_hip = 0.5 * (m["hip_l"] + m["hip_r"])
    spine = torso_spine(m)
    R[:, SEG["pelvis"]] = frame_from_axes(spine - mid_hip, m["hip_l"] - m["hip_r"],
                                          primary_axis=1, hint_axis=0)
    R[:, SEG["chest"]] = frame_from_axes(m["neck"] - spine,
                                         m["shoulder_l"] - m["shoulder_r"],
                                         primary_axis=1, hint_axis=0)
    qp, qc = matrix_to_quat(R[:, SEG["pelvis"]]), matrix_to_quat(R[:, SEG["chest"]])
    R[:, SEG["abdomen"]] = quat_to_matrix(slerp(qp, qc, np.full(N, 0.5)))
    Rc = R[:, SEG["chest"]]
    head_base = m.get("head_base", m["head"])
    neck_dir = head_base - m["neck"]
    R[:, SEG["neck"]] = min_rotation(Rc[:, :, 1], neck_dir) @ Rc
    head_dir = m["head"] - head_base if "head_base" in m else neck_dir
    Rn = R[:, SEG["neck"]]
    Rh = min_rotation(Rn[:, :, 1], head_dir) @ Rn
    if "head_fwd" in m:
        Rh = frame_from_axes(head_dir, m["head_fwd"], primary_axis=1, hint_axis=2)
    R[:, SEG["head"]] = Rh
    for s, sx in (("r", -1.0), ("l", 1.0)):
        # Clavicle: neck -> shoulder direction in the chest frame, with the data set's
        # constant marker bias (Kinect "ShoulderCenter" sits above the shoulder line)
        # removed by subtracting its median elevation/protraction, and clamped.
        d = np.einsum("nji,nj->ni", Rc, m[f"shoulder_{s}"] - m["neck"])
        elev = np.arctan2(d[:, 1], np.abs(d[:, 0]))
        prot = np.arctan2(d[:, 2], np.abs(d[:, 0]))
        elev = np.clip(elev - np.median(elev), np.deg2rad(-10), np.deg2rad(30))
        prot = np.clip(prot - np.median(prot), np.deg2rad(-20), np.deg2rad(20))
        loc = np.stack([sx * np.ones(N), np.tan(elev), np.tan(prot)], axis=1)
        Rcl = min_rotation(np.broadcast_to(sx * ex, (N, 3)), loc)
        R[:, SEG[f"{s}_clavicle"]] = Rc @ Rcl
        Rcl_w = R[:, SEG[f"{s}_clavicle"]]
        # Upper arm: swing from the T-pose (arm along the clavicle; singular only for an arm
        # pointing straight across the chest), then twist into the elbow's bend plane.
        upper = m[f"elbow_{s}"] - m[f"shoulder_{s}"]
        fore = m[f"wrist_{s}"] - m[f"elbow_{s}"]
        Rt = Rcl_w @ rz(sx * np.pi / 2)
        Ru = min_rotation(Rt @ np.array([0.0, -1.0, 0.0]), upper) @ Rt
        bend, w = _bend_weight(upper, fore)
        Ru = _twist_toward(Ru, bend, w)
        R[:, SEG[f"{s}_upper_arm"]] = Ru
        Rf = frame_from_axes(-fore, Ru[:, :, 0], primary_axis=1, hint_axis=0)
        R[:, SEG[f"{s}_forearm"]] = Rf
        hand = m[f"hand_{s}"] - m[f"wrist_{s}"]
        ok = (np.linalg.norm(hand, axis=-1) > 1e-3)[:, None]
        hand = np.where(ok, hand, fore)
        R[:, SEG[f"{s}_hand"]] = frame_from_axes(-hand, Rf[:, :, 0], primary_axis=1,
                                                 hint_axis=0)
        # Legs: swing from hanging straight down, twist so the knee bends backward.
        thigh = m[f"knee_{s}"] - m[f"hip_{s}"]
        shank = m[f"ankle_{s}"] - m[f"knee_{s}"]
        Rp = R[:, SEG["pelvis"]]
        Rth = min_rotation(-Rp[:, :, 1], thigh) @ Rp
        bend, w = _bend_weight(thigh, shank)
        Rth = _twist_toward(Rth, -bend, w)
        R[:, SEG[f"{s}_thigh"]] = Rth
        Rsh = frame_from_axes(-shank, Rth[:, :, 0], primary_axis=1, hint_axis=0)
        R[:, SEG[f"{s}_shank"]] = Rsh
        toe = m[f"toe_{s}"] - m[f"ankle_{s}"]
        if level_feet:
            # Kinect foot joints sit mostly below the ankle with a few cm of horizontal
            # offset in arbitrary directions: use the leg's own forward (knee plane) instead.
            fwd = Rsh[:, :, 2]
            R[:, SEG[f"{s}_foot"]] = ry(np.arctan2(fwd[:, 0], fwd[:, 2]))
        else:
            v0 = np.array([0.0, -subject.dims["ankle_height"], 0.55 * subject.dims["foot"]])
            R[:, SEG[f"{s}_foot"]] = align_two(np.broadcast_to(v0, (N, 3)),
                                               np.broadcast_to(ex, (N, 3)), toe, Rsh[:, :, 0])
    # Pelvis path: data mid-hip scaled by the leg-length ratio, lifted to the pelvis origin.
    leg_data = np.median(
        0.5 * (np.linalg.norm(m["knee_l"] - m["hip_l"], axis=-1)
               + np.linalg.norm(m["ankle_l"] - m["knee_l"], axis=-1)
               + np.linalg.norm(m["knee_r"] - m["hip_r"], axis=-1)
               + np.linalg.norm(m["ankle_r"] - m["knee_r"], axis=-1)))
    leg_subj = subject.dims["thigh"] + subject.dims["shank"]
    root = mid_hip * (leg_subj / leg_data)
    root = root + R[:, SEG["pelvis"]] @ np.array([0.0, subject.dims["pelvis_up"], 0.0])
    return R, root


def _resample_rotations(R: np.ndarray, src_fps: float, times: np.ndarray) -> np.ndarray:
    """Slerp (N, S, 3, 3) rotations sampled at ``src_fps`` to arbitrary ``times`` (s)."""
    q = hemisphere_align(matrix_to_quat(R), axis=0)
    x = times * src_fps
    i0 = np.clip(np.floor(x).astype(int), 0, R.shape[0] - 1)
    i1 = np.clip(i0 + 1, 0, R.shape[0] - 1)
    f = np.clip(x - i0, 0.0, 1.0)
    qi = slerp(q[i0], q[i1], np.broadcast_to(f[:, None], q[i0].shape[:-1]))
    return quat_to_matrix(qi)


def _smooth_rotations(R: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing of rotations over time (on sign-aligned quaternions)."""
    if sigma <= 0:
        return R
    q = hemisphere_align(matrix_to_quat(R), axis=0)
    return quat_to_matrix(_gauss_smooth(q, sigma))


def real_motion(name: str, subject: Subject, *, n_frames: int, fps: float,
                start: float = 0.0) -> MotionClip:
    """A real motion retargeted to ``subject`` and resampled to ``fps``.

    Args:
        name: e.g. ``"cmu:131_01"``, ``"msr:a01_s01_e01"``, ``"utk:s01_e01:waveHands"``.
        subject: the target body.
        n_frames: output length T.
        fps: output frame rate, Hz.
        start: start time in the clip, s. If the clip is shorter than needed it is played
            back and forth (ping-pong), which keeps the motion continuous and plausible.
    """
    markers, src_fps, info = load_markers(name)
    R, root = retarget(markers, subject, level_feet=bool(info.get("kinect")))
    N = R.shape[0]
    dur = (N - 1) / src_fps
    t = start + np.arange(n_frames) / fps
    looped = bool(t[-1] > dur + 1e-9) or start > dur
    if dur > 0:
        t = np.abs(((t / dur + 1.0) % 2.0) - 1.0) * dur  # ping-pong into [0, dur]
    else:
        t = np.zeros_like(t)
    Rt = _resample_rotations(R, src_fps, t)
    x = t * src_fps
    rt = np.stack([np.interp(x, np.arange(N), root[:, k]) for k in range(3)], axis=1)
    if src_fps < fps:  # upsampled: remove the slerp kinks at source samples
        Rt = _smooth_rotations(Rt, 0.5 * fps / src_fps)
        rt = _gauss_smooth(rt, 0.5 * fps / src_fps)
    # Height: keep the data's vertical motion (hops), offset so the feet are on the floor in
    # most frames, and never below it.
    g = ground(subject, Rt, slide=False, root_xz=rt[:, [0, 2]])
    off = np.median(g[:, 1] - rt[:, 1])
    root_final = ground(subject, Rt, slide=False, root_xz=rt[:, [0, 2]],
                        root_y=rt[:, 1] + off)
    info.update(source="real", travel=True, looped=looped, start=start)
    return MotionClip(root=root_final, rotations=Rt, name=name, info=info)
