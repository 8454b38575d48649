"""The BVH skeleton of the body model (``posetrack.app._bvh_skeleton``): T-pose rest, offsets
from the body shape, and motion that reproduces the model's joints. Checked with our reader
and forward kinematics and with an independent parser (bvhio), without running the tracker."""

from __future__ import annotations

import warnings

import jax
import numpy as np
import pytest

import posetrack
from posetrack import _body as body
from posetrack import io
from posetrack.app._bvh_skeleton import (
    BVH_END_SITES,
    BVH_JOINT_NAMES,
    BVH_KEYPOINTS,
    BVH_MODEL_JOINTS,
    BVH_PARENTS,
    bvh_from_params,
    bvh_rest_pose,
)

with warnings.catch_warnings():  # bvhio imports PyGLM by its older name
    warnings.simplefilter("ignore", PendingDeprecationWarning)
    import bvhio

C = np.array([1.0, -1.0, -1.0])  # camera frame <-> the file's y-up world (a diagonal matrix)
# Rounding in the file: 6 decimals of a centimetre = 0.01 um per value; a few values add up.
TOL_M = 1e-6
HEAD_KEYPOINTS = (0, 14, 15, 16, 17)  # nose, eyes, ears: on the Head's frame
STILL = ("Spine", "Chest", "Head", "RightShoulder", "LeftShoulder", "RightHand", "LeftHand",
         "RightFoot", "LeftFoot")  # fmt: skip


def random_params(rng, n):
    """Random poses: any rotation per joint, quaternions of random norm and sign (wxyz)."""
    q = rng.normal(size=(n, body.NUM_JOINTS, 4)) * rng.uniform(0.3, 3.0, size=(n, 1, 1))
    q[0, 3] = [1.0, 1e-7, 0.0, -1e-7]  # near identity
    q[1] = -q[0]  # the sign ambiguity: q and -q are the same pose
    t = rng.uniform([-1, -1, 1.5], [1, 1, 5], size=(n, 3))
    t[1] = t[0]
    return np.concatenate([t, q.reshape(n, -1)], axis=1)


def write(path, shape, params, fps=25.0):
    io.write_bvh(path, **bvh_from_params(shape, params)._asdict(), fps=fps, camera_to_y_up=True)
    return io.read_bvh(path)


def world(bvh):
    """Joint positions (T, J, 3) and rotations (T, J, 3, 3) in the camera frame, metres."""
    pos, rot = io.bvh_world_transforms(bvh.parents, bvh.offsets, bvh.channels, bvh.motion)
    return pos / 100.0 * C, C[:, None] * rot  # p_cam = C p_file, R_cam = C R_file


@pytest.fixture(scope="module")
def shape():
    """A person unlike the default one, in float64 (the references need the precision)."""
    prev = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield posetrack.BodyShape.create(thigh=0.47, forearm=0.23, upper_arm=0.31, head_scale=1.1,
                                     torso=0.55, shoulder_drop=0.03)  # fmt: skip
    jax.config.update("jax_enable_x64", prev)


@pytest.fixture(scope="module")
def poses(shape, tmp_path_factory):
    """12 random poses written and read back, with the model's keypoints and frames."""
    params = random_params(np.random.default_rng(3), 12)
    path = tmp_path_factory.mktemp("bvh") / "random.bvh"
    bvh = write(path, shape, params)
    kpts = np.asarray(jax.vmap(body.keypoints, in_axes=(None, 0))(shape, params))
    rot_model = np.asarray(jax.vmap(body.joint_frames, in_axes=(None, 0))(shape, params)[0])
    return path, params, bvh, kpts, rot_model


def test_hierarchy_has_spine_head_wrists_and_ankles(poses):
    bvh = poses[2]
    parent = {bvh.names[j]: bvh.names[p] for j, p in enumerate(bvh.parents) if p >= 0}
    assert bvh.names[0] == "Hips" and set(bvh.names) == set(BVH_JOINT_NAMES)
    chains = [("Hips", "Spine", "Chest", "Neck", "Head")]
    for side in ("Right", "Left"):
        chains += [("Chest", f"{side}Shoulder", f"{side}Arm", f"{side}ForeArm", f"{side}Hand"),
                   ("Hips", f"{side}UpLeg", f"{side}Leg", f"{side}Foot")]  # fmt: skip
    for chain in chains:
        assert all(parent[child] == up for up, child in zip(chain, chain[1:])), chain
    assert {bvh.names[j] for j in bvh.end_sites} == set(BVH_END_SITES)
    assert len(BVH_KEYPOINTS) == 13 and sorted(BVH_KEYPOINTS.values()) == list(body.BODY_JOINTS)
    assert len(BVH_MODEL_JOINTS) == body.NUM_JOINTS
    assert set(BVH_MODEL_JOINTS.values()) == set(body.JOINT_NAMES)


def test_motion_reproduces_the_model_for_random_poses(shape, poses):
    _, params, bvh, kpts, rot_model = poses
    pos, rot = world(bvh)
    for name, k in BVH_KEYPOINTS.items():
        err = np.linalg.norm(pos[:, bvh.names.index(name)] - kpts[:, k], axis=-1).max()
        assert err < TOL_M, (name, err)
    # Joints carrying a model rotation have that model frame's world rotation (the model's
    # rest pose differs from the T-pose only in the arms, turned 90 deg about z).
    for name, model in BVH_MODEL_JOINTS.items():
        if "Arm" in name:
            continue
        got, want = rot[:, bvh.names.index(name)], rot_model[:, body.JOINT_NAMES.index(model)]
        np.testing.assert_allclose(got, want, atol=1e-7, err_msg=name)
    # The nose, eyes and ears ride on the Head: keypoint offset minus the Head's place on the
    # neck frame (Neck and Head have the model's neck axes).
    head = bvh.names.index("Head")
    head_on_neck = bvh.offsets[head] / 100.0
    local = np.asarray(body.keypoint_offsets(shape))
    for k in HEAD_KEYPOINTS:
        got = pos[:, head] + rot[:, head] @ (local[k] - head_on_neck)
        assert np.linalg.norm(got - kpts[:, k], axis=-1).max() < TOL_M, k
    # Joints the model does not rotate keep the rest rotation (zero channels) in every frame.
    cols = np.cumsum([0] + [len(c) for c in bvh.channels])
    for name in STILL:
        j = bvh.names.index(name)
        np.testing.assert_array_equal(bvh.motion[:, cols[j] : cols[j + 1]], 0.0, err_msg=name)
    np.testing.assert_allclose(pos[1], pos[0], atol=TOL_M)  # -q posed like q


def test_rest_pose_is_a_t_pose_with_the_persons_bone_lengths(shape, tmp_path):
    """All channels zero: arms straight out sideways, legs straight down, y up, facing +z;
    the OFFSETs (centimetres) are the body shape's lengths."""
    bvh = write(tmp_path / "rest.bvh", shape, np.asarray(body.facing_camera_params(2.5))[None])
    f = shape.to_dict()
    rest = io.bvh_forward_kinematics(bvh.parents, bvh.offsets, bvh.channels,
                                     np.zeros_like(bvh.motion)) / 100.0  # fmt: skip
    p = {name: rest[0, j] for j, name in enumerate(bvh.names)}
    for side, sign in (("Right", -1.0), ("Left", 1.0)):
        arm = [p[f"{side}{n}"] for n in ("Arm", "ForeArm", "Hand")]
        np.testing.assert_allclose(arm[1] - arm[0], [sign * f["upper_arm"], 0, 0], atol=1e-8)
        np.testing.assert_allclose(arm[2] - arm[1], [sign * f["forearm"], 0, 0], atol=1e-8)
        leg = [p[f"{side}{n}"] for n in ("UpLeg", "Leg", "Foot")]
        np.testing.assert_allclose(leg[0], [sign * f["hip_width"], 0, 0], atol=1e-8)
        np.testing.assert_allclose(leg[1] - leg[0], [0, -f["thigh"], 0], atol=1e-8)
        np.testing.assert_allclose(leg[2] - leg[1], [0, -f["shin"], 0], atol=1e-8)
        np.testing.assert_allclose(
            arm[0], [sign * f["shoulder_width"], f["torso"] - f["shoulder_drop"], 0], atol=1e-8
        )
        toes = bvh.end_sites[bvh.names.index(f"{side}Foot")]
        hand = bvh.end_sites[bvh.names.index(f"{side}Hand")]
        assert toes[2] > 5 and toes[1] < 0 and hand[0] * sign > 5  # cm: forward; outward
    for name in ("Spine", "Chest", "Neck"):
        assert p[name][0] == 0 and p[name][2] == 0 and p[name][1] > 0
    np.testing.assert_allclose(p["Neck"], [0, f["torso"], 0], atol=1e-8)
    assert p["Head"][1] > p["Neck"][1] and bvh.end_sites[bvh.names.index("Head")][1] > 15
    # A person standing in front of the camera with hanging arms (the model's rest pose): the
    # root is at the camera's (0, 0, 2.5 m) turned to y-up, and only the shoulders' Zrotation
    # channels move (+-90 deg: the arms down from the T-pose).
    np.testing.assert_allclose(bvh.motion[0, :3], [0.0, 0.0, -250.0], atol=1e-6)
    cols = np.cumsum([0] + [len(c) for c in bvh.channels])
    expected = np.zeros(cols[-1])
    expected[cols[bvh.names.index("RightArm")]] = 90.0  # Zrotation comes first
    expected[cols[bvh.names.index("LeftArm")]] = -90.0
    np.testing.assert_allclose(bvh.motion[0, 3:], expected[3:], atol=1e-6)


def test_offsets_follow_the_body_shape(shape):
    full, _ = bvh_rest_pose(shape)
    np.testing.assert_allclose(bvh_rest_pose(shape.scaled(0.5))[0], 0.5 * full, atol=1e-12)
    # One length of the person changes exactly the bones it names.
    longer, _ = bvh_rest_pose(posetrack.BodyShape.create(**{**shape.to_dict(), "shin": 0.5}))
    changed = {BVH_JOINT_NAMES[j] for j in np.flatnonzero(np.any(longer != full, axis=1))}
    assert changed == {"RightFoot", "LeftFoot"}
    np.testing.assert_allclose(longer[BVH_JOINT_NAMES.index("LeftFoot")], [0, -0.5, 0])
    assert BVH_PARENTS[:3] == (-1, 0, 1)


def test_an_independent_parser_reads_the_same_skeleton_and_motion(poses):
    """bvhio (its own parser, Euler conversion and forward kinematics, in float32) agrees
    with our reader on the hierarchy, frames and world positions, and with the model."""
    path, params, bvh, kpts, _ = poses
    container = bvhio.readAsBvh(str(path))
    assert container.FrameCount == len(params) == len(bvh.motion)
    assert container.FrameTime == pytest.approx(1 / 25.0, abs=1e-9)
    layout = container.Root.layout()
    names = [j.Name for j, _, _ in layout]
    assert names == list(bvh.names)  # both in file (depth-first) order
    parents = {child.Name: j.Name for j, _, _ in layout for child in j.Children}
    assert parents == {bvh.names[j]: bvh.names[p] for j, p in enumerate(bvh.parents) if p >= 0}
    assert all(list(j.Channels) == list(c) for (j, _, _), c in zip(layout, bvh.channels))
    ends = {j.Name: np.array(j.EndSite) for j, _, _ in layout if not j.Children}
    for name, end in ends.items():
        np.testing.assert_allclose(end, bvh.end_sites[bvh.names.index(name)], atol=1e-4)

    ours = io.bvh_forward_kinematics(bvh.parents, bvh.offsets, bvh.channels, bvh.motion)
    root = bvhio.readAsHierarchy(str(path))
    theirs = np.empty_like(ours)
    for t in range(len(params)):
        root.loadPose(t)
        theirs[t] = [np.array(j.PositionWorld) for j, _, _ in root.layout()]
    err_cm = np.abs(theirs - ours).max()
    assert err_cm < 1e-3, err_cm  # 10 um: float32 arithmetic on positions of a few metres
    model_err = max(
        np.linalg.norm(theirs[:, bvh.names.index(n)] / 100 * C - kpts[:, k], axis=-1).max()
        for n, k in BVH_KEYPOINTS.items()
    )
    assert model_err < 1e-4, model_err  # 0.1 mm
