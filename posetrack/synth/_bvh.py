"""Minimal BVH (Biovision hierarchy) reader and forward kinematics.

Conventions (the common ones, as in the CMU/cgspeed files): rotation channels compose in the
order they are listed, ``R_local = R_c1(a1) @ R_c2(a2) @ R_c3(a3)`` (e.g. ``Zrotation
Yrotation Xrotation`` -> ``Rz @ Ry @ Rx``), angles in degrees; a joint's position is
``p_parent + R_parent @ (OFFSET + translation channels)``. Each joint may list its own
channel order (the CMU arms use ``Z X Y``). ``End Site`` blocks become joints named
``<parent>_end`` without channels. Lengths are returned in file units times ``scale``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from posetrack._so3 import rx, ry, rz

_ROT = {"Xrotation": rx, "Yrotation": ry, "Zrotation": rz}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


@dataclasses.dataclass(frozen=True)
class BvhClip:
    """A parsed BVH file."""

    names: tuple[str, ...]
    """Joint names in file order (parents before children); end sites are ``<parent>_end``."""
    parents: np.ndarray
    """(J,) parent index, -1 for the root."""
    offsets: np.ndarray
    """(J, 3) OFFSET of each joint in its parent's frame, file units."""
    channels: tuple[tuple[str, ...], ...]
    """Channel names per joint (empty for end sites)."""
    channel_start: np.ndarray
    """(J,) first column of each joint's channels in ``motion``."""
    frame_time: float
    """Seconds per frame."""
    motion: np.ndarray
    """(F, C) channel values per frame (degrees / file units)."""

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        return self.names.index(name)


def parse_bvh(text: str) -> BvhClip:
    """Parse BVH text.

    Raises:
        ValueError: with the offending token when the file is malformed or the frame data do
            not match the declared channels and frame count.
    """
    tok = text.split()
    i = 0
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    stack: list[int] = []
    pending: int | None = None

    def expect(word: str) -> None:
        nonlocal i
        if i >= len(tok) or tok[i] != word:
            got = tok[i] if i < len(tok) else "<end of file>"
            raise ValueError(f"BVH: expected {word!r} at token {i}, got {got!r}")
        i += 1

    expect("HIERARCHY")
    while i < len(tok):
        t = tok[i]
        if t in ("ROOT", "JOINT"):
            names.append(tok[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            pending = len(names) - 1
            i += 2
        elif t == "End":
            expect("End")
            expect("Site")
            if not stack:
                raise ValueError("BVH: End Site outside any joint")
            names.append(f"{names[stack[-1]]}_end")
            parents.append(stack[-1])
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            pending = len(names) - 1
        elif t == "{":
            if pending is None:
                raise ValueError(f"BVH: unexpected '{{' at token {i}")
            stack.append(pending)
            pending = None
            i += 1
        elif t == "}":
            if not stack:
                raise ValueError(f"BVH: unbalanced '}}' at token {i}")
            stack.pop()
            i += 1
        elif t == "OFFSET":
            try:
                offsets[stack[-1]] = [float(v) for v in tok[i + 1 : i + 4]]
            except (ValueError, IndexError) as e:
                raise ValueError(f"BVH: bad OFFSET at token {i}: {tok[i + 1 : i + 4]}") from e
            i += 4
        elif t == "CHANNELS":
            n = int(tok[i + 1])
            ch = tuple(tok[i + 2 : i + 2 + n])
            for c in ch:
                if c not in _ROT and c not in _POS:
                    raise ValueError(f"BVH: unknown channel {c!r} in joint {names[stack[-1]]}")
            channels[stack[-1]] = ch
            i += 2 + n
        elif t == "MOTION":
            i += 1
            break
        else:
            raise ValueError(f"BVH: unexpected token {t!r} at {i}")
    if stack:
        raise ValueError("BVH: unbalanced braces in HIERARCHY")
    if not names:
        raise ValueError("BVH: no joints")
    expect("Frames:")
    n_frames = int(tok[i])
    i += 1
    expect("Frame")
    expect("Time:")
    frame_time = float(tok[i])
    i += 1
    n_ch = sum(len(c) for c in channels)
    values = np.asarray(tok[i:], dtype=np.float64)
    if values.size < n_frames * n_ch:
        raise ValueError(
            f"BVH: {values.size} motion values for {n_frames} frames x {n_ch} channels"
        )
    motion = values[: n_frames * n_ch].reshape(n_frames, n_ch)
    start = np.cumsum([0] + [len(c) for c in channels])[:-1]
    if frame_time <= 0:
        raise ValueError(f"BVH: Frame Time must be positive, got {frame_time}")
    return BvhClip(
        names=tuple(names), parents=np.asarray(parents), offsets=np.asarray(offsets),
        channels=tuple(channels), channel_start=np.asarray(start), frame_time=frame_time,
        motion=motion,
    )


def read_bvh(path: str | Path) -> BvhClip:
    """Read and parse a BVH file."""
    return parse_bvh(Path(path).read_text())


def bvh_forward_kinematics(clip: BvhClip, *, scale: float = 1.0,
                           frames: np.ndarray | slice | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Global joint positions and rotations of a BVH clip.

    Args:
        clip: parsed file.
        scale: multiplies offsets and translations (e.g. 0.056444 for CMU units -> m).
        frames: optional subset of frames.

    Returns:
        positions (F, J, 3) in file units x scale, rotations (F, J, 3, 3) global (the
        rotation of each joint's own frame; end sites inherit their parent's).
    """
    m = clip.motion if frames is None else clip.motion[frames]
    F, J = m.shape[0], len(clip.names)
    pos = np.zeros((F, J, 3))
    rot = np.zeros((F, J, 3, 3))
    for j in range(J):
        R = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
        trans = np.zeros((F, 3))
        c0 = clip.channel_start[j]
        for k, ch in enumerate(clip.channels[j]):
            v = m[:, c0 + k]
            if ch in _ROT:
                R = R @ _ROT[ch](np.deg2rad(v))
            else:
                trans[:, _POS[ch]] = v
        local_t = (clip.offsets[j] + trans) * scale
        p = clip.parents[j]
        if p < 0:
            pos[:, j] = local_t
            rot[:, j] = R
        else:
            pos[:, j] = pos[:, p] + np.einsum("fij,fj->fi", rot[:, p], local_t)
            rot[:, j] = rot[:, p] @ R
    return pos, rot
