"""The body model as a BVH skeleton: a T-pose rest with the tracked person's bone lengths.

Hierarchy (19 joints, CMU / Mixamo names)::

    Hips (root: the pelvis centre)
      Spine, Chest            the torso in thirds, pelvis to the base of the neck
        Neck                  the COCO "neck" keypoint; carries the model's neck/head rotation
          Head                fixed on the neck (the top of the neck capsule); End Site = top of
                              the head
        RightShoulder         the clavicle, from the base of the neck
          RightArm            the shoulder keypoint; carries the shoulder rotation
            RightForeArm      the elbow keypoint; carries the elbow rotation
              RightHand       the wrist keypoint; End Site = end of the hand
        LeftShoulder ... LeftHand (the same)
      RightUpLeg              the hip keypoint; carries the hip rotation
        RightLeg              the knee keypoint; carries the knee rotation
          RightFoot           the ankle keypoint; End Site = the toes
      LeftUpLeg ... LeftFoot (the same)

The body model (:mod:`posetrack._body`) has a rigid torso, a head rigid on the neck, and no
wrist or ankle joints. So Spine, Chest, Head, the two clavicles (RightShoulder,
LeftShoulder), the hands and the feet are in the hierarchy for the tools that expect them,
but their rotation channels hold the rest rotation (zero for all of them) in every frame.
The 9 model joints and the root carry the model's rotations: forward kinematics of the file
reproduces the model's 13 body keypoints (neck, shoulders, elbows, wrists, hips, knees,
ankles) exactly, and the Head's frame is the model's head frame, so the nose, eyes and ears
ride on it at fixed offsets.

Rest pose (all rotation channels zero) = a T-pose: y up, facing +z, the subject's left at
+x, arms straight out sideways (horizontal), legs straight down, feet pointing forward. The
OFFSETs are the tracked person's :class:`~posetrack.BodyShape` (torso, shoulder width and
drop, upper arm, forearm, hip width, thigh, shin, head size). The model's own rest pose has
the arms hanging; each arm joint's frame is therefore the model's frame turned by 90 deg
about z (``B`` below), which the motion channels undo, so a person standing with hanging arms
has 90 deg in the shoulders' ``Zrotation`` channels and the T-pose is all zeros.

Construction. Each BVH joint j rides on one model frame ``f(j)`` and has a constant rest
alignment ``B_j`` (``Rz(+90)`` on the right arm, ``Rz(-90)`` on the left, identity elsewhere).
Its world rotation is ``Rw_model[f(j)] @ B_j``; its OFFSET is ``B_parent^T (X_j - X_parent)``
with ``X`` the joint positions in the model's rest pose; its local rotation is
``B_parent^T Q_j B_j`` with ``Q_j`` the model's local rotation of ``f(j)`` when j starts a new
model frame and the identity otherwise. Forward kinematics then gives every joint at the
model's position by construction (tested against the model and an independent parser).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _body as body
from .._so3 import quat_multiply, quat_normalize, quat_to_matrix

# (name, parent, model frame f(j), rest alignment about z in quarter turns)
_SKELETON = (
    ("Hips", None, 0, 0),
    ("Spine", "Hips", 0, 0),
    ("Chest", "Spine", 0, 0),
    ("Neck", "Chest", 1, 0),
    ("Head", "Neck", 1, 0),
    ("RightShoulder", "Chest", 0, 0),
    ("RightArm", "RightShoulder", 2, 1),
    ("RightForeArm", "RightArm", 3, 1),
    ("RightHand", "RightForeArm", 3, 1),
    ("LeftShoulder", "Chest", 0, 0),
    ("LeftArm", "LeftShoulder", 4, -1),
    ("LeftForeArm", "LeftArm", 5, -1),
    ("LeftHand", "LeftForeArm", 5, -1),
    ("RightUpLeg", "Hips", 6, 0),
    ("RightLeg", "RightUpLeg", 7, 0),
    ("RightFoot", "RightLeg", 7, 0),
    ("LeftUpLeg", "Hips", 8, 0),
    ("LeftLeg", "LeftUpLeg", 9, 0),
    ("LeftFoot", "LeftLeg", 9, 0),
)

BVH_JOINT_NAMES = tuple(row[0] for row in _SKELETON)
"""The 19 BVH joints, root first (module docstring)."""

BVH_PARENTS = tuple(-1 if p is None else BVH_JOINT_NAMES.index(p) for _, p, _, _ in _SKELETON)
"""Parent index per BVH joint (-1 for Hips)."""

_FRAME = np.array([row[2] for row in _SKELETON])
_PARENTS = np.array(BVH_PARENTS)
# Starts a new model frame (carries that frame's local rotation), or keeps its parent's.
_ROTATES = np.array([p < 0 or _FRAME[p] != _FRAME[j] for j, p in enumerate(BVH_PARENTS)])

BVH_MODEL_JOINTS = {
    name: body.JOINT_NAMES[f]
    for name, f, rotates in zip(BVH_JOINT_NAMES, _FRAME, _ROTATES, strict=True)
    if rotates
}
"""BVH joints that carry a rotation of the body model -> the model joint
(:data:`posetrack._body.JOINT_NAMES`). The other BVH joints keep their rest rotation."""

BVH_KEYPOINTS = {
    "Neck": 1, "RightArm": 2, "RightForeArm": 3, "RightHand": 4, "LeftArm": 5,
    "LeftForeArm": 6, "LeftHand": 7, "RightUpLeg": 8, "RightLeg": 9, "RightFoot": 10,
    "LeftUpLeg": 11, "LeftLeg": 12, "LeftFoot": 13,
}  # fmt: skip
"""BVH joints at a COCO-18 keypoint (name -> keypoint index): all 13 body joints
(:data:`posetrack._body.BODY_JOINTS`). The nose, eyes and ears ride on the Head's frame."""

BVH_END_SITES = {
    "Head": "head_top", "RightHand": "right_hand_end", "LeftHand": "left_hand_end",
    "RightFoot": "right_toes", "LeftFoot": "left_toes",
}  # fmt: skip
"""Leaf joint -> what its End Site marks: the top of the head capsule, the far end of the hand
and foot capsules' axes (:func:`posetrack._body.capsule_offsets`)."""

_H = np.sqrt(0.5)
# B_j as quaternions, wxyz: Rz(90 * k deg) for k = 0, 1, -1.
_ALIGN = np.array([[1.0, 0, 0, 0] if k == 0 else [_H, 0, 0, k * _H] for *_, k in _SKELETON])
_Q_C = np.array([0.0, 1.0, 0.0, 0.0])  # C = diag(1, -1, -1), 180 deg about x
_C = np.diag([1.0, -1.0, -1.0])


def _check_tree() -> None:
    # A BVH joint that starts a new model frame must hang on that frame's model parent, or
    # the local rotation B_p^T Q_j B_j would be relative to the wrong frame.
    for j, p in enumerate(BVH_PARENTS):
        if p >= 0 and _ROTATES[j] and body.JOINT_PARENTS[_FRAME[j]] != _FRAME[p]:
            raise AssertionError(f"BVH joint {BVH_JOINT_NAMES[j]} hangs on the wrong frame")


_check_tree()


def _conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _unalign(j, v: np.ndarray) -> np.ndarray:
    """``B_j^T v``: ``v`` (..., 3) in the rest frame of BVH joint(s) ``j``."""
    return np.einsum("...ji,...j->...i", quat_to_matrix(_ALIGN[j]), v)


class BvhMotion(NamedTuple):
    """A skeleton animation, exactly the keyword arguments of :func:`posetrack.io.write_bvh`.

    ``write_bvh(path, **motion._asdict(), fps=30, camera_to_y_up=True)`` writes it. Lengths in
    metres; quaternions wxyz. Everything is given pre-turned by ``C = diag(1, -1, -1)``, which
    ``camera_to_y_up=True`` undoes, so the file holds the T-pose rest (module docstring).
    """

    joint_names: tuple[str, ...]
    """The 19 joints (:data:`BVH_JOINT_NAMES`)."""
    parents: tuple[int, ...]
    """Parent index per joint (:data:`BVH_PARENTS`, -1 for Hips)."""
    offsets: np.ndarray
    """``float64 (19, 3)`` joint position in its parent's rest frame, metres, times ``C``."""
    root_positions: np.ndarray
    """``float64 (T, 3)`` pelvis centre in the params' frame, metres."""
    local_rotations_wxyz: np.ndarray
    """``float64 (T, 19, 4)`` unit quaternions, wxyz, each joint relative to its parent (Hips
    relative to the params' frame), conjugated by ``C``."""
    end_sites: dict[str, np.ndarray]
    """Leaf joint -> End Site offset (metres, times ``C``): :data:`BVH_END_SITES`."""


def bvh_rest_pose(shape: body.BodyShape) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The T-pose skeleton of a body shape, as the BVH file holds it (y up, facing +z).

    Args:
        shape: body dimensions (metres).

    Returns:
        ``offsets (19, 3)``, metres, each joint in its parent's rest frame
        (:data:`BVH_JOINT_NAMES` order; the root's is zero), and the End Site offsets (leaf
        joint name -> ``(3,)`` metres, in that joint's rest frame).
    """
    joint_offs = np.asarray(body.joint_offsets(shape), np.float64)
    kpt_offs = np.asarray(body.keypoint_offsets(shape), np.float64)
    _, cap_b, cap_r = (np.asarray(x, np.float64) for x in body.capsule_offsets(shape))
    cap_b = dict(zip(body.CAPSULE_NAMES, cap_b, strict=True))
    cap_r = dict(zip(body.CAPSULE_NAMES, cap_r, strict=True))
    # The model's rest pose (every rotation identity): frame origins and keypoints, body frame.
    origin = np.zeros((body.NUM_JOINTS, 3))
    for f in range(1, body.NUM_JOINTS):
        origin[f] = origin[body.JOINT_PARENTS[f]] + joint_offs[f]
    kpt = origin[list(body.KEYPOINT_FRAMES)] + kpt_offs
    neck, head = kpt[1], origin[1] + cap_b["neck"]
    X = {"Hips": origin[0], "Spine": neck / 3, "Chest": 2 * neck / 3, "Head": head}
    X |= {"RightShoulder": neck, "LeftShoulder": neck}
    X |= {name: kpt[k] for name, k in BVH_KEYPOINTS.items()}
    X = np.stack([X[name] for name in BVH_JOINT_NAMES])
    # End Sites in the frame of the model frame they ride on (rest: body-frame directions).
    ends = {
        "Head": cap_b["head"] + np.array([0.0, cap_r["head"], 0.0]) - cap_b["neck"],
        "RightHand": cap_b["right_hand"] - kpt_offs[4],
        "LeftHand": cap_b["left_hand"] - kpt_offs[7],
        "RightFoot": cap_b["right_foot"] - kpt_offs[10],
        "LeftFoot": cap_b["left_foot"] - kpt_offs[13],
    }
    offsets = np.zeros_like(X)
    offsets[1:] = _unalign(_PARENTS[1:], X[1:] - X[_PARENTS[1:]])
    j_of = {name: BVH_JOINT_NAMES.index(name) for name in ends}
    return offsets, {k: _unalign(j_of[k], v) for k, v in ends.items()}


def bvh_from_params(shape: body.BodyShape, params: np.ndarray) -> BvhMotion:
    """The body model as a T-pose BVH skeleton (module docstring), posed by ``params``.

    ``write_bvh(camera_to_y_up=True)`` maps the params' frame to the file's y-up world with
    ``C = diag(1, -1, -1)`` (points ``C p``, rotations ``C R C``); the offsets, end sites and
    local rotations are handed over pre-turned by ``C`` (the root rotation as ``R_root C``) so
    that the file holds the T-pose rest of :func:`bvh_rest_pose` and, in every frame, the
    model's pose turned by ``C``: for camera-frame params a person upright in front of the
    camera stands upright (+y) in the file.

    Args:
        shape: body dimensions (metres).
        params: ``(T, 43)`` pose parameters (quaternions wxyz, any non-zero norm).

    Returns:
        A :class:`BvhMotion`.

    Raises:
        ValueError: ``params`` of the wrong shape or not finite.
    """
    params = np.asarray(params, dtype=np.float64)
    if params.ndim != 2 or params.shape[1] != body.NUM_PARAMS:
        raise ValueError(f"bvh_from_params: params must be (T, 43), got {params.shape}")
    if not np.isfinite(params).all():
        t, k = (int(i) for i in np.argwhere(~np.isfinite(params))[0])
        raise ValueError(f"bvh_from_params: params[{t}, {k}] = {params[t, k]} is not finite")
    n_frames = len(params)
    q_model = quat_normalize(params[:, 3:].reshape(n_frames, body.NUM_JOINTS, 4))
    # Q_j: the model frame's local rotation where j starts one, else the identity.
    q = np.where(_ROTATES[None, :, None], q_model[:, _FRAME], np.array([1.0, 0, 0, 0]))
    align_parent = np.where((_PARENTS < 0)[:, None], _ALIGN[0], _ALIGN[_PARENTS])
    local = quat_multiply(quat_multiply(_conj(align_parent), q), _ALIGN)  # B_p^T Q_j B_j
    # Pre-turn by C for the writer: C L C for the joints; the root's file rotation is C R_root,
    # so it is handed over as C (C R_root) C = R_root C.
    local[:, 1:] = quat_multiply(quat_multiply(_Q_C, local[:, 1:]), _Q_C)  # q_C^-1 = -q_C
    local[:, 0] = quat_multiply(local[:, 0], _Q_C)
    offsets, ends = bvh_rest_pose(shape)
    return BvhMotion(
        joint_names=BVH_JOINT_NAMES,
        parents=BVH_PARENTS,
        offsets=offsets @ _C,
        root_positions=params[:, :3].copy(),
        local_rotations_wxyz=local,
        end_sites={k: _C @ v for k, v in ends.items()},
    )
