"""BVH: write -> read -> forward kinematics equals FK computed directly from the quaternions."""

import numpy as np
import pytest
from conftest import require_data
from test_so3 import qmul, qrotate, quat_axis_angle

from posetrack._so3 import rx, rz
from posetrack.io import (
    InputError,
    bvh_forward_kinematics,
    bvh_world_transforms,
    read_bvh,
    write_bvh,
)


def fk_from_quaternions(parents, offsets, root, quats):
    """Reference FK written with quaternion algebra (independent of the matrix code)."""
    quats = quats / np.linalg.norm(quats, axis=-1, keepdims=True)
    n_frames, n_joints = quats.shape[:2]
    q_world = np.zeros((n_frames, n_joints, 4))
    p_world = np.zeros((n_frames, n_joints, 3))
    for j in range(n_joints):
        p = parents[j]
        if p < 0:
            q_world[:, j], p_world[:, j] = quats[:, j], root
        else:
            q_world[:, j] = qmul(q_world[:, p], quats[:, j])
            offset = np.broadcast_to(offsets[j], root.shape)
            p_world[:, j] = p_world[:, p] + qrotate(q_world[:, p], offset)
    return p_world


def random_motion(seed, n_frames=40, n_joints=12):
    rng = np.random.default_rng(seed)
    # parents[j] < j, deliberately not in depth-first order (the file order differs).
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, n_joints)])
    offsets = rng.uniform(-0.4, 0.4, (n_joints, 3))
    root = rng.uniform(-2, 2, (n_frames, 3))
    quats = rng.normal(size=(n_frames, n_joints, 4))
    # Gimbal lock of the ZYX decomposition (y = +-90 deg), near-identity, and q vs -q.
    lock = qmul(quat_axis_angle([0, 0, 1], 0.7), quat_axis_angle([0, 1, 0], np.pi / 2))
    quats[0, :] = qmul(lock, quat_axis_angle([1, 0, 0], -0.3))
    quats[1, :] = qmul(quat_axis_angle([0, 1, 0], -np.pi / 2), quat_axis_angle([1, 0, 0], 2.0))
    quats[2, :] = [1.0, 1e-9, -2e-9, 1e-9]
    quats[3, :] = quat_axis_angle([0, 1, 0], np.pi / 2 - 1e-7)
    quats[5] = -quats[4]
    names = [f"joint{j}" for j in range(n_joints)]
    return names, parents, offsets, root, quats


def _fk_file(path):
    bvh = read_bvh(path)
    return bvh, bvh_forward_kinematics(bvh.parents, bvh.offsets, bvh.channels, bvh.motion)


@pytest.mark.parametrize(
    ("seed", "units", "scale"), [(0, "cm", 0.01), (1, "m", 1.0), (2, "cm", 0.01)]
)
def test_round_trip_positions(tmp_path, seed, units, scale):
    names, parents, offsets, root, quats = random_motion(seed)
    path = tmp_path / "motion.bvh"
    write_bvh(
        path, joint_names=names, parents=parents, offsets=offsets, root_positions=root,
        local_rotations_wxyz=quats, fps=30.0, units=units,
    )  # fmt: skip
    bvh, positions = _fk_file(path)
    order = [bvh.names.index(n) for n in names]
    expected = fk_from_quaternions(parents, offsets, root, quats)
    np.testing.assert_allclose(positions[:, order] * scale, expected, atol=1e-6, rtol=0)
    assert bvh.frame_time == pytest.approx(1 / 30.0, abs=1e-10) and bvh.motion.shape[0] == 40
    assert bvh.channels[0] == (
        "Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"
    )  # fmt: skip
    assert all(c == ("Zrotation", "Yrotation", "Xrotation") for c in bvh.channels[1:])
    assert np.all(bvh.offsets[0] == 0)
    leaves = set(range(len(names))) - set(parents[1:].tolist())
    assert {bvh.names[j] for j in bvh.end_sites} == {names[j] for j in leaves}


def test_camera_to_y_up(tmp_path):
    names, parents, offsets, root, quats = random_motion(3, n_frames=10)
    leaf = next(j for j in range(len(names)) if j not in parents)
    path = tmp_path / "y_up.bvh"
    write_bvh(
        path, joint_names=names, parents=parents, offsets=offsets, root_positions=root,
        local_rotations_wxyz=quats, fps=25.0, camera_to_y_up=True,
        end_sites={names[leaf]: [0.0, 0.1, 0.0]},
    )  # fmt: skip
    bvh, positions = _fk_file(path)
    order = [bvh.names.index(n) for n in names]
    expected = fk_from_quaternions(parents, offsets, root, quats) * np.array([1, -1, -1])
    np.testing.assert_allclose(positions[:, order] / 100, expected, atol=1e-6, rtol=0)
    # An upright skeleton in the camera frame (head at -y) is upright in the file (+y).
    np.testing.assert_allclose(bvh.end_sites[bvh.names.index(names[leaf])], [0, -10.0, 0])


def test_euler_angles_are_unwrapped_over_time(tmp_path):
    angles = np.linspace(0, 4 * np.pi, 50)
    quats = np.stack([quat_axis_angle([0, 0, 1], a) for a in angles])[:, None]
    path = tmp_path / "spin.bvh"
    write_bvh(
        path, joint_names=["root"], parents=[-1], offsets=np.zeros((1, 3)),
        root_positions=np.zeros((50, 3)), local_rotations_wxyz=quats, fps=10,
    )  # fmt: skip
    z = read_bvh(path).motion[:, 3]
    assert np.max(np.abs(np.diff(z))) < 20 and z[-1] == pytest.approx(720.0, abs=1e-4)


def test_write_bvh_rejects_bad_arguments(tmp_path):
    names, parents, offsets, root, quats = random_motion(4, n_frames=8, n_joints=3)
    good = dict(
        joint_names=names, parents=parents, offsets=offsets, root_positions=root,
        local_rotations_wxyz=quats, fps=30,
    )  # fmt: skip
    path = tmp_path / "x.bvh"
    for change, match in [
        ({"joint_names": ["a", "b c", "d"]}, "spaces"),
        ({"joint_names": ["a", "a", "b"]}, "twice"),
        ({"parents": [-1, 2, 0]}, "parents"),
        ({"fps": 0}, "fps"),
        ({"local_rotations_wxyz": np.zeros_like(quats)}, "zero quaternion"),
        ({"root_positions": np.full_like(root, np.nan)}, "not finite"),
        ({"end_sites": {"nobody": [0, 0, 0]}}, "unknown joint"),
    ]:
        with pytest.raises(ValueError, match=match):
            write_bvh(path, **{**good, **change})
    assert not path.exists()


def test_read_bvh_errors(tmp_path):
    names, parents, offsets, root, quats = random_motion(5, n_frames=6, n_joints=4)
    path = tmp_path / "m.bvh"
    write_bvh(
        path, joint_names=names, parents=parents, offsets=offsets, root_positions=root,
        local_rotations_wxyz=quats, fps=30,
    )  # fmt: skip
    lines = path.read_text().splitlines()
    bad = tmp_path / "bad.bvh"
    bad.write_text("\n".join(lines[:-2]) + "\n")
    with pytest.raises(InputError, match="declares 6 frames but the file holds 4") as info:
        read_bvh(bad)
    assert info.value.field == "Frames" and info.value.value == 6
    bad.write_text("\n".join(lines[:-1] + [lines[-1].replace(" ", " abc ", 1)]) + "\n")
    with pytest.raises(InputError, match="values|number"):
        read_bvh(bad)
    bad.write_text("\n".join(lines[:-1] + [lines[-1].rsplit(" ", 1)[0] + " nan"]) + "\n")
    with pytest.raises(InputError, match="finite") as info:
        read_bvh(bad)
    assert info.value.field == f"line {len(lines)}"
    motion_at = lines.index("MOTION")
    bad.write_text("\n".join(lines[:motion_at]))
    with pytest.raises(InputError, match="no MOTION"):
        read_bvh(bad)


def test_reads_a_real_cmu_file():
    bvh, positions = _fk_file(require_data("cmu-mocap-bvh-subject131") / "131_01.bvh")
    assert bvh.names[0] == "Hips" and len(bvh.names) == 31 and positions.shape == (994, 31, 3)
    assert bvh.channels[0][3:] == ("Zrotation", "Yrotation", "Xrotation")
    assert bvh.frame_time == pytest.approx(1 / 120, rel=1e-3)
    # Rigid bones: joint-to-parent distances are the same in every frame.
    child = np.arange(1, 31)
    lengths = np.linalg.norm(positions[:, child] - positions[:, bvh.parents[child]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(lengths[0], lengths.shape), atol=1e-9)
    np.testing.assert_allclose(lengths[0], np.linalg.norm(bvh.offsets[child], axis=-1), atol=1e-9)


TINY_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Chest
  {
    OFFSET 0 2 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 3
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.5
1 2 3 0 0 0 0 0 0
0 0 0 90 0 0 0 90 0
0 0 0 0 0 0 90 90 0
"""


def test_hand_written_file_per_joint_channel_order_end_site_and_scale(tmp_path):
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY_BVH)
    bvh = read_bvh(path)
    assert bvh.names == ("Hips", "Chest") and list(bvh.parents) == [-1, 0]
    assert bvh.frame_time == 0.5 and bvh.motion.shape == (3, 9)
    assert bvh.channels[1] == ("Zrotation", "Xrotation", "Yrotation")
    np.testing.assert_array_equal(bvh.end_sites[1], [0, 0, 3])
    pos, rot = bvh_world_transforms(bvh.parents, bvh.offsets, bvh.channels, bvh.motion, scale=2.0)
    np.testing.assert_array_equal(
        pos, bvh_forward_kinematics(bvh.parents, bvh.offsets, bvh.channels, bvh.motion, scale=2.0)
    )
    end = pos[:, 1] + np.einsum("tij,j->ti", rot[:, 1], 2.0 * bvh.end_sites[1])
    # Frame 0: pure translation (scaled).
    np.testing.assert_allclose(pos[0], [[2, 4, 6], [2, 8, 6]], atol=1e-12)
    np.testing.assert_allclose(end[0], [2, 8, 12], atol=1e-12)
    # Frame 1: root Zrot 90 turns the chest offset to -x; chest Xrot 90 then root Zrot 90
    # take the end offset (0, 0, 3) to (0, -3, 0) and then (3, 0, 0).
    np.testing.assert_allclose(pos[1], [[0, 0, 0], [-4, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(end[1], [2, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rot[1, 1], rz(np.pi / 2) @ rx(np.pi / 2), atol=1e-12)
    # Frame 2: channel order Z X Y means R = Rz @ Rx (reversed order would give (0, -1, 0)).
    np.testing.assert_allclose(end[2], [6, 4, 0], atol=1e-12)


@pytest.mark.parametrize(
    "edit,match",
    [
        (lambda t: t.replace("HIERARCHY\n", ""), "HIERARCHY"),
        (lambda t: t.replace("Frames: 3", "Frames: 4"), "declares 4 frames"),
        (lambda t: t.replace("Zrotation Xrotation", "Wrotation Xrotation"), "unknown channel"),
        (lambda t: t.replace("  }\n}\nMOTION", "  }\nMOTION"), "hierarchy ends early"),
    ],
)
def test_read_bvh_rejects_malformed_hierarchies(tmp_path, edit, match):
    path = tmp_path / "bad.bvh"
    path.write_text(edit(TINY_BVH))
    with pytest.raises(InputError, match=match):
        read_bvh(path)
