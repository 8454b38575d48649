"""BVH (Biovision hierarchy) motion files: writer, reader and forward kinematics.

What :func:`write_bvh` writes:

* one ROOT with 6 channels ``Xposition Yposition Zposition Zrotation Yrotation Xrotation``,
  every other joint 3 channels ``Zrotation Yrotation Xrotation`` (the CMU-mocap convention,
  read by Blender, MotionBuilder, Maya, ...). The local rotation of a joint is
  ``R = Rz(z) @ Ry(y) @ Rx(x)`` with the angles in degrees (the channel order is the matrix
  product order).
* lengths in **centimetres** by default (``units="cm"``; ``"m"`` is available). In Blender:
  File > Import > Motion Capture (.bvh) with Scale 0.01 for centimetre files gives metres.
* the ROOT OFFSET is 0 0 0 and the root position channels hold the full root position, so
  readers that add the root OFFSET to the position channels and readers that ignore it agree.
* Axes: a BVH is conventionally y-up. Our camera frame is y-down, z-forward (OpenCV); with
  ``camera_to_y_up=True`` everything (root position and rotation, joint offsets and local
  rotations, end sites) is conjugated by a 180 deg rotation about x, ``C = diag(1, -1, -1)``:
  points map as ``p' = C p`` and rotations as ``R' = C R C``. A person standing upright in
  front of the camera then stands upright (+y up) and faces +z, the BVH convention, and the
  rest pose (all rotations identity) is upright too.

Euler angles come from the rotation matrix in a way that stays exact at gimbal lock (y = +-90
deg): z is taken from the first column, then y and x from the matrix with Rz removed, so any
error in z is compensated by x. Angles are unwrapped over time (adding 360 deg to one angle
does not change the rotation), so animation curves have no 360 deg jumps.
"""

from __future__ import annotations

import io
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from posetrack._so3 import matrix_to_euler_zyx, quat_to_matrix, rx, ry, rz

from ._atomic import atomic_write_text
from ._errors import InputError

_C_Y_UP = np.diag([1.0, -1.0, -1.0])
_CHANNEL_NAMES = {f"{a}{k}" for a in "XYZ" for k in ("position", "rotation")}
_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
_JOINT_CHANNELS = ("Zrotation", "Yrotation", "Xrotation")
_NAME_OK = re.compile(r"^[^\s{}]+$")
_AXIS_ROTATIONS = (rx, ry, rz)


class Bvh(NamedTuple):
    """A parsed BVH file; lengths in the file's units, angles in degrees."""

    names: tuple[str, ...]
    """Joint names in file (depth-first) order."""
    parents: np.ndarray
    """``int64 (J,)`` parent index, -1 for the root; ``parents[j] < j``."""
    offsets: np.ndarray
    """``float64 (J, 3)`` OFFSET of each joint in its parent's frame."""
    channels: tuple[tuple[str, ...], ...]
    """Channel names per joint, e.g. ``("Zrotation", "Yrotation", "Xrotation")``."""
    motion: np.ndarray
    """``float64 (T, C)`` channel values, columns in joint order then channel order."""
    frame_time: float
    """Seconds per frame."""
    end_sites: dict[int, np.ndarray]
    """Joint index -> End Site OFFSET ``(3,)``."""


def _depth_first(parents: np.ndarray) -> list[int]:
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(int(p), []).append(j)
    order, stack = [], [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j, [])))
    return order


def write_bvh(
    path: str | os.PathLike[str],
    *,
    joint_names: Sequence[str],
    parents: Sequence[int] | np.ndarray,
    offsets: np.ndarray,
    root_positions: np.ndarray,
    local_rotations_wxyz: np.ndarray,
    fps: float,
    end_sites: Mapping[str, Sequence[float]] | None = None,
    units: Literal["cm", "m"] = "cm",
    camera_to_y_up: bool = False,
) -> None:
    """Write a skeleton animation as BVH, atomically (conventions in the module docstring).

    Forward kinematics of the exported motion (metres, before unit scaling)::

        Rw[root] = R[root];            pw[root] = root_positions
        Rw[j] = Rw[parent] @ R[j];     pw[j] = pw[parent] + Rw[parent] @ offsets[j]

    Args:
        path: destination ``.bvh``.
        joint_names: J unique names without whitespace or braces.
        parents: ``(J,)`` parent indices, ``parents[0] == -1`` (single root), ``parents[j] < j``.
        offsets: ``(J, 3)`` metres, joint j's position in its parent's frame in the rest pose.
            ``offsets[0]`` is not used (the root is placed by ``root_positions``).
        root_positions: ``(T, 3)`` metres.
        local_rotations_wxyz: ``(T, J, 4)`` quaternions, wxyz, joint frame relative to its
            parent's (the root's relative to the world); normalised here.
        fps: frames per second.
        end_sites: leaf joint name -> End Site offset (metres). A leaf without an entry gets
            an End Site continuing its bone at half its length.
        units: ``"cm"`` (default) or ``"m"`` for lengths in the file. Centimetres are written
            with 6 decimals, metres with 8 (0.01 µm either way).
        camera_to_y_up: convert from the y-down camera frame to a y-up world (rotate 180 deg
            about x), see the module docstring.

    Raises:
        ValueError: bad names or topology, shapes that disagree, non-finite values, a zero
            quaternion, a non-positive fps, an end site on a joint that has children.
    """
    names = [str(n) for n in joint_names]
    n_joints = len(names)
    parents = np.asarray(parents, dtype=np.int64)
    if n_joints == 0 or parents.shape != (n_joints,):
        raise ValueError(f"write_bvh: parents must be ({n_joints},), got {parents.shape}")
    for j, name in enumerate(names):
        if not _NAME_OK.match(name):
            raise ValueError(
                f"write_bvh: joint_names[{j}] = {name!r} is empty or has spaces/braces"
            )
    if len(set(names)) != n_joints:
        dup = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"write_bvh: joint name {dup!r} appears twice")
    if parents[0] != -1 or any(not 0 <= parents[j] < j for j in range(1, n_joints)):
        raise ValueError(
            f"write_bvh: parents must start with -1 and have parents[j] < j, got {parents.tolist()}"
        )
    offsets = np.asarray(offsets, dtype=np.float64)
    root = np.asarray(root_positions, dtype=np.float64)
    quats = np.asarray(local_rotations_wxyz, dtype=np.float64)
    n_frames = root.shape[0] if root.ndim == 2 else -1
    if offsets.shape != (n_joints, 3):
        raise ValueError(f"write_bvh: offsets must be ({n_joints}, 3), got {offsets.shape}")
    if root.ndim != 2 or root.shape[1] != 3 or n_frames < 1:
        raise ValueError(f"write_bvh: root_positions must be (T, 3) with T >= 1, got {root.shape}")
    if quats.shape != (n_frames, n_joints, 4):
        raise ValueError(
            f"write_bvh: local_rotations_wxyz must be ({n_frames}, {n_joints}, 4), "
            f"got {quats.shape}"
        )
    checked = (("offsets", offsets), ("root_positions", root), ("local_rotations_wxyz", quats))
    for arg, value in checked:
        if not np.isfinite(value).all():
            idx = tuple(int(i) for i in np.argwhere(~np.isfinite(value))[0])
            raise ValueError(f"write_bvh: {arg}{list(idx)} is not finite")
    norms = np.linalg.norm(quats, axis=-1)
    if (norms < 1e-6).any():
        t, j = (int(i) for i in np.argwhere(norms < 1e-6)[0])
        raise ValueError(f"write_bvh: local_rotations_wxyz[{t}, {j}] is a zero quaternion")
    fps = float(fps)
    if not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"write_bvh: fps must be positive, got {fps}")
    if units not in ("cm", "m"):
        raise ValueError(f"write_bvh: units must be 'cm' or 'm', got {units!r}")
    has_child = np.zeros(n_joints, bool)
    has_child[parents[1:]] = True
    ends: dict[int, np.ndarray] = {}
    for key, value in (end_sites or {}).items():
        if key not in names:
            raise ValueError(f"write_bvh: end_sites names unknown joint {key!r}")
        j = names.index(key)
        if has_child[j]:
            raise ValueError(f"write_bvh: end site on {key!r}, which has children")
        ends[j] = np.asarray(value, dtype=np.float64).reshape(3)
    for j in np.flatnonzero(~has_child):
        ends.setdefault(int(j), 0.5 * offsets[j])

    rotations = quat_to_matrix(quats)  # (T, J, 3, 3)
    offsets = offsets.copy()
    if camera_to_y_up:
        rotations = _C_Y_UP @ rotations @ _C_Y_UP
        root = root @ _C_Y_UP  # C is symmetric: (C p)^T = p^T C
        offsets = offsets @ _C_Y_UP
        ends = {j: _C_Y_UP @ e for j, e in ends.items()}
    angles = np.degrees(np.unwrap(matrix_to_euler_zyx(rotations), axis=0))  # (T, J, 3) z y x
    scale, digits = (100.0, 6) if units == "cm" else (1.0, 8)

    def fmt(v) -> str:
        return " ".join(f"{round(float(x) * scale, digits) + 0.0:.{digits}f}" for x in v)

    order = _depth_first(parents)
    depth = {0: 0}
    lines = ["HIERARCHY"]
    closing: list[int] = []  # joints whose brace is still open, innermost last
    for j in order:
        if j:
            depth[j] = depth[int(parents[j])] + 1
        while closing and depth[closing[-1]] >= depth[j]:
            lines.append("\t" * depth[closing.pop()] + "}")
        tab = "\t" * depth[j]
        if j == 0:
            lines += [f"ROOT {names[0]}", "{", "\tOFFSET " + fmt(np.zeros(3))]
            lines.append("\tCHANNELS 6 " + " ".join(_ROOT_CHANNELS))
        else:
            lines += [f"{tab}JOINT {names[j]}", f"{tab}{{", f"{tab}\tOFFSET {fmt(offsets[j])}"]
            lines.append(f"{tab}\tCHANNELS 3 " + " ".join(_JOINT_CHANNELS))
        if j in ends:
            lines += [f"{tab}\tEnd Site", f"{tab}\t{{", f"{tab}\t\tOFFSET {fmt(ends[j])}"]
            lines.append(f"{tab}\t}}")
        closing.append(j)
    while closing:
        lines.append("\t" * depth[closing.pop()] + "}")
    lines += ["MOTION", f"Frames: {n_frames}", f"Frame Time: {1.0 / fps:.10f}"]

    columns = [root * scale, angles[:, 0]] + [angles[:, j] for j in order[1:]]
    # Rounding first, then + 0.0, turns -0.0 (and -1e-12) into a clean 0.000000.
    table = np.round(np.concatenate(columns, axis=1), digits) + 0.0
    buffer = io.StringIO()
    np.savetxt(buffer, table, fmt=f"%.{digits}f", delimiter=" ")
    atomic_write_text(path, "\n".join(lines) + "\n" + buffer.getvalue())


def _canonical_channel(token: str) -> str | None:
    name = token[:1].upper() + token[1:].lower()
    return name if name in _CHANNEL_NAMES else None


def read_bvh(path: str | os.PathLike[str]) -> Bvh:
    """Parse a BVH file (any channel order and position channels on any joint).

    Returns:
        A :class:`Bvh`; ``names, parents, offsets, channels, motion = read_bvh(p)[:5]``.

    Raises:
        InputError: naming the line and token: unreadable file, missing HIERARCHY / ROOT /
            MOTION, bad OFFSET or CHANNELS, duplicate joint names, more than one ROOT,
            a "Frames:" count different from the number of motion rows, a row with the wrong
            number of values, a non-numeric or non-finite value, a non-positive frame time.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig", errors="strict")
    except UnicodeDecodeError as e:
        raise InputError(path, "file", str(path), "is not a text file, so not BVH") from e
    except OSError as e:
        raise InputError(path, "file", str(path), f"cannot be read ({e.strerror})") from e
    lines = text.splitlines()
    motion_line = next(
        (i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None
    )
    if motion_line is None:
        raise InputError(path, "MOTION", None, "has no MOTION section (not a BVH file?)")
    tokens = [(tok, i + 1) for i, line in enumerate(lines[:motion_line]) for tok in line.split()]
    pos = 0

    def take(expect: str | None = None) -> tuple[str, int]:
        nonlocal pos
        if pos >= len(tokens):
            raise InputError(path, f"line {motion_line + 1}", "MOTION", "hierarchy ends early")
        tok, line_no = tokens[pos]
        if expect is not None and tok.upper() != expect.upper():
            raise InputError(path, f"line {line_no}", tok, f"expected {expect!r}")
        pos += 1
        return tok, line_no

    def take_float() -> float:
        tok, line_no = take()
        try:
            value = float(tok)
        except ValueError:
            raise InputError(path, f"line {line_no}", tok, "expected a number") from None
        if not math.isfinite(value):
            raise InputError(path, f"line {line_no}", tok, "expected a finite number")
        return value

    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: dict[int, np.ndarray] = {}

    def joint(parent: int, name: str, line_no: int) -> None:
        if name in names:
            raise InputError(path, f"line {line_no}", name, "joint name appears twice")
        j = len(names)
        names.append(name)
        parents.append(parent)
        take("{")
        take("OFFSET")
        offsets.append([take_float(), take_float(), take_float()])
        chans: tuple[str, ...] = ()
        if pos < len(tokens) and tokens[pos][0].upper() == "CHANNELS":
            take()
            tok, ln = take()
            if not tok.isdigit():
                raise InputError(path, f"line {ln}", tok, "expected the number of channels")
            chan_list = []
            for _ in range(int(tok)):
                ctok, cln = take()
                canonical = _canonical_channel(ctok)
                if canonical is None:
                    raise InputError(path, f"line {cln}", ctok, "unknown channel name")
                chan_list.append(canonical)
            chans = tuple(chan_list)
        channels.append(chans)
        while True:
            tok, ln = take()
            key = tok.upper()
            if key == "}":
                return
            if key == "JOINT":
                child, cln = take()
                joint(j, child, cln)
            elif key == "END":
                take("Site")
                take("{")
                take("OFFSET")
                end_sites[j] = np.array([take_float(), take_float(), take_float()])
                take("}")
            else:
                raise InputError(path, f"line {ln}", tok, "expected JOINT, End Site or '}'")

    take("HIERARCHY")
    take("ROOT")
    root_name, root_line = take()
    joint(-1, root_name, root_line)
    if pos != len(tokens):
        tok, ln = tokens[pos]
        what = "a second ROOT (not supported)" if tok.upper() == "ROOT" else "text after it"
        raise InputError(path, f"line {ln}", tok, f"unexpected {what}")

    rest = [(i + 1, line.split()) for i, line in enumerate(lines) if i > motion_line]
    rest = [(n, toks) for n, toks in rest if toks]

    def header(k: int, label: str) -> float:
        if k >= len(rest):
            raise InputError(path, label, None, "is missing after MOTION")
        line_no, toks = rest[k]
        joined = " ".join(toks)
        if not joined.upper().startswith(label.upper()):
            raise InputError(path, f"line {line_no}", joined, f"expected {label!r}")
        try:
            return float(joined[len(label) :].strip())
        except ValueError:
            raise InputError(path, f"line {line_no}", joined, f"{label!r} needs a number") from None

    n_frames = header(0, "Frames:")
    frame_time = header(1, "Frame Time:")
    if n_frames != int(n_frames) or n_frames < 0:
        raise InputError(path, "Frames", n_frames, "expected a whole number of frames")
    if not math.isfinite(frame_time) or frame_time <= 0:
        raise InputError(path, "Frame Time", frame_time, "expected a positive number of seconds")
    rows = rest[2:]
    n_channels = sum(len(c) for c in channels)
    if len(rows) != int(n_frames):
        raise InputError(
            path, "Frames", int(n_frames),
            f"declares {int(n_frames)} frames but the file holds {len(rows)} motion rows"
            + (" (truncated file?)" if len(rows) < n_frames else ""),
        )  # fmt: skip
    for line_no, toks in rows:
        if len(toks) != n_channels:
            raise InputError(
                path, f"line {line_no}", len(toks),
                f"motion row has {len(toks)} values; the hierarchy declares {n_channels} channels",
            )  # fmt: skip
    try:
        motion = np.array([toks for _n, toks in rows], dtype=np.float64).reshape(-1, n_channels)
    except ValueError:
        for line_no, toks in rows:
            for tok in toks:
                try:
                    float(tok)
                except ValueError:
                    raise InputError(path, f"line {line_no}", tok, "expected a number") from None
        raise
    if not np.isfinite(motion).all():
        r, c = (int(i) for i in np.argwhere(~np.isfinite(motion))[0])
        raise InputError(path, f"line {rows[r][0]}", rows[r][1][c], "expected a finite number")
    return Bvh(
        names=tuple(names),
        parents=np.asarray(parents, dtype=np.int64),
        offsets=np.asarray(offsets, dtype=np.float64).reshape(-1, 3),
        channels=tuple(channels),
        motion=motion,
        frame_time=frame_time,
        end_sites=end_sites,
    )


def bvh_world_transforms(
    parents: np.ndarray,
    offsets: np.ndarray,
    channels: Sequence[Sequence[str]],
    motion: np.ndarray,
    *,
    scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """World positions and rotations of every joint (forward kinematics of a BVH file).

    Standard BVH semantics: a joint's local translation is its OFFSET plus its position
    channels (if any), times ``scale``; its local rotation is the product of its rotation
    channels in the order listed (degrees), e.g. ``Zrotation Xrotation Yrotation`` gives
    ``rz @ rx @ ry``; ``Rw[j] = Rw[parent] @ R[j]``, ``pw[j] = pw[parent] + Rw[parent] @ t[j]``.
    Motion columns follow joint order, then channel order. An End Site (``Bvh.end_sites``)
    sits at ``pw[j] + Rw[j] @ (scale * offset)`` of its joint j. Use with :func:`read_bvh`::

        bvh = read_bvh(p)
        positions, rotations = bvh_world_transforms(
            bvh.parents, bvh.offsets, bvh.channels, bvh.motion, scale=0.01  # cm -> m
        )

    Args:
        parents: ``(J,)`` parent indices, -1 for the root, ``parents[j] < j``.
        offsets: ``(J, 3)`` OFFSETs, file length units.
        channels: J tuples of channel names (``"Xposition"`` ... ``"Zrotation"``).
        motion: ``(T, C)`` channel values (file length units, degrees).
        scale: metres (or any unit) per file length unit; multiplies every translation.

    Returns:
        ``positions (T, J, 3)`` in file units times ``scale`` and ``rotations (T, J, 3, 3)``,
        each joint's frame in the world (``R_world_joint``).

    Raises:
        ValueError: the motion columns do not match the channels, or ``parents[j] >= j``.
    """
    parents = np.asarray(parents, dtype=np.int64)
    offsets = np.asarray(offsets, dtype=np.float64)
    motion = np.asarray(motion, dtype=np.float64)
    n_joints = len(parents)
    n_frames = motion.shape[0]
    if motion.shape[1] != sum(len(c) for c in channels):
        raise ValueError("bvh_forward_kinematics: motion columns do not match the channels")
    rot_w = np.empty((n_joints, n_frames, 3, 3))
    pos_w = np.empty((n_joints, n_frames, 3))
    col = 0
    for j in range(n_joints):
        rot = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
        trans = np.broadcast_to(offsets[j], (n_frames, 3)).copy()
        for name in channels[j]:
            axis = "XYZ".index(name[0])
            if name.endswith("position"):
                trans[:, axis] += motion[:, col]
            else:
                rot = rot @ _AXIS_ROTATIONS[axis](np.radians(motion[:, col]))
            col += 1
        trans *= scale
        p = int(parents[j])
        if p < 0:
            rot_w[j], pos_w[j] = rot, trans
        else:
            if p >= j:
                raise ValueError("bvh_forward_kinematics: parents[j] must be < j")
            rot_w[j] = rot_w[p] @ rot
            pos_w[j] = pos_w[p] + np.einsum("tab,tb->ta", rot_w[p], trans)
    return pos_w.transpose(1, 0, 2), rot_w.transpose(1, 0, 2, 3)


def bvh_forward_kinematics(
    parents: np.ndarray,
    offsets: np.ndarray,
    channels: Sequence[Sequence[str]],
    motion: np.ndarray,
    *,
    scale: float = 1.0,
) -> np.ndarray:
    """World positions ``(T, J, 3)`` of every joint, in the file's length units times ``scale``.

    The positions of :func:`bvh_world_transforms` (see there for the conventions)::

        bvh = read_bvh(p)
        positions = bvh_forward_kinematics(bvh.parents, bvh.offsets, bvh.channels, bvh.motion)
    """
    return bvh_world_transforms(parents, offsets, channels, motion, scale=scale)[0]
