"""Write a synthetic sequence to disk in the layout of a user's recording."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ._generate import SyntheticSequence


def openpose_json(keypoints2d: np.ndarray, confidence: np.ndarray) -> dict:
    """OpenPose 1.3 JSON dict for one frame: (18, 2) px and (18,) confidences (COCO-18).

    A frame where nothing was detected has no person, as OpenPose writes it.
    """
    flat: list[float] = []
    for (x, y), c in zip(keypoints2d.tolist(), confidence.tolist(), strict=True):
        flat += [float(x), float(y), float(c)] if c > 0 else [0.0, 0.0, 0.0]
    people = []
    if np.any(confidence > 0):
        people.append({
            "person_id": [-1],
            "pose_keypoints_2d": flat,
            "face_keypoints_2d": [],
            "hand_left_keypoints_2d": [],
            "hand_right_keypoints_2d": [],
            "pose_keypoints_3d": [],
            "face_keypoints_3d": [],
            "hand_left_keypoints_3d": [],
            "hand_right_keypoints_3d": [],
        })
    return {"version": 1.3, "people": people}


def save(seq: SyntheticSequence, folder: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``seq`` as a recording folder, atomically.

    Layout::

        folder/depth/000000.png                16-bit PNG, millimetres, 0 = invalid
        folder/rgb/000000.png                  8-bit RGB PNG (if the sequence has colour)
        folder/keypoints/000000_keypoints.json OpenPose 1.3 JSON, COCO-18
        folder/intrinsics.json                 {"fx", "fy", "cx", "cy", "width", "height"}
        folder/ground_truth.npz                joints3d (T,18,3) m camera frame, visible
                                               (T,18), fps, plus joints2d, confidence-free
                                               extras (T_cam_world, floor_plane)

    Everything is written into a hidden temporary folder next to ``folder`` and renamed into
    place at the end, so an interrupted save never leaves a complete-looking folder.

    Args:
        seq: the sequence.
        folder: destination (must not exist unless ``overwrite``).
        overwrite: replace an existing folder.

    Returns:
        The destination path.

    Raises:
        FileExistsError: the folder exists and ``overwrite`` is False.
    """
    dest = Path(folder)
    if dest.exists() and not overwrite:
        raise FileExistsError(f"save: {dest} already exists (pass overwrite=True)")
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.tmp-", dir=dest.parent))
    try:
        for sub in ("depth", "rgb", "keypoints"):
            if sub == "rgb" and seq.rgb is None:
                continue
            (tmp / sub).mkdir()
        for t in range(seq.n_frames):
            name = f"{t:06d}"
            if not cv2.imwrite(str(tmp / "depth" / f"{name}.png"), seq.depth[t]):
                raise OSError(f"save: could not write depth frame {t} to {tmp}")
            if seq.rgb is not None:
                bgr = cv2.cvtColor(seq.rgb[t], cv2.COLOR_RGB2BGR)
                if not cv2.imwrite(str(tmp / "rgb" / f"{name}.png"), bgr):
                    raise OSError(f"save: could not write rgb frame {t} to {tmp}")
            with open(tmp / "keypoints" / f"{name}_keypoints.json", "w") as f:
                json.dump(openpose_json(seq.keypoints2d[t], seq.confidence[t]), f)
        with open(tmp / "intrinsics.json", "w") as f:
            json.dump(seq.intrinsics.to_dict(), f, indent=1)
        np.savez_compressed(
            tmp / "ground_truth.npz", joints3d=seq.joints3d, visible=seq.visible,
            fps=np.float64(seq.fps), joints2d=seq.joints2d, T_cam_world=seq.T_cam_world,
            floor_plane=seq.floor_plane,
        )
        if dest.exists():
            old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
            os.replace(dest, old)
            os.replace(tmp, dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
