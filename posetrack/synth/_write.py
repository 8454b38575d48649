"""Write a synthetic sequence to disk in the layout of a user's recording, with the writers
of :mod:`posetrack.io` (so the folder reads back through ``posetrack.io.load_recording``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posetrack.io import (
    atomic_dir,
    write_depth_png,
    write_intrinsics_json,
    write_openpose_json,
    write_rgb,
)

from ._generate import SyntheticSequence


def _frame_people(seq: SyntheticSequence, t: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The people a detector lists in frame ``t``, in their order, as :func:`save` writes them.

    The listed people of ``seq.people2d[t]``, with the main person's slot
    (``seq.people_index[t]``) taken from ``seq.keypoints2d[t]`` / ``seq.confidence[t]`` so a
    copy edited with ``dataclasses.replace(seq, keypoints2d=..., confidence=...)`` is written
    as edited (a main person given detections where it had none comes last); a person left
    without any confidence > 0 is dropped.

    Returns:
        keypoints (P', 18, 2) px, confidence (P', 18) (P' may be 0: nobody) and the main
        person's index among them (-1 when not listed).
    """
    kp = np.array(seq.people2d[t], dtype=np.float32)
    conf = np.array(seq.people_confidence[t], dtype=np.float32)
    i = int(seq.people_index[t])
    is_main = np.arange(len(kp)) == i
    if i >= 0:
        kp[i], conf[i] = seq.keypoints2d[t], seq.confidence[t]
    elif np.any(seq.confidence[t] > 0):
        kp = np.concatenate([kp, np.asarray(seq.keypoints2d[t], np.float32)[None]])
        conf = np.concatenate([conf, np.asarray(seq.confidence[t], np.float32)[None]])
        is_main = np.append(is_main, True)
    keep = np.any(conf > 0, axis=-1)
    is_main = is_main[keep]
    return kp[keep], conf[keep], int(np.argmax(is_main)) if is_main.any() else -1


def save(seq: SyntheticSequence, folder: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``seq`` as a recording folder, atomically.

    Layout::

        folder/depth/000000.png                16-bit PNG, millimetres, 0 = invalid
        folder/rgb/000000.png                  8-bit RGB PNG (if the sequence has colour)
        folder/keypoints/000000_keypoints.json OpenPose 1.3 JSON, COCO-18: every listed
                                               person of people2d, in its order, person_id
                                               -1; no person where nothing was detected
        folder/intrinsics.json                 {"fx", "fy", "cx", "cy", "width", "height"}
        folder/ground_truth.npz                joints3d (T,18,3) m camera frame, visible
                                               (T,18), fps, plus joints2d, confidence-free
                                               extras (T_cam_world, floor_plane), and
                                               people_index (T,) (the main person's place
                                               in each JSON, -1 = absent), others_joints3d
                                               (T,P-1,18,3) m (the other people)

    The folder is built next to ``folder`` and renamed into place at the end
    (:func:`posetrack.io.atomic_dir`), so an interrupted save never leaves a complete-looking
    folder; it carries :data:`posetrack.io.MARKER_NAME`.

    Args:
        seq: the sequence.
        folder: destination (must not exist unless ``overwrite``).
        overwrite: replace an existing folder; only one written by posetrack (it carries
            :data:`posetrack.io.MARKER_NAME`) or an empty one, so a mistyped path cannot wipe
            out unrelated data.

    Returns:
        The destination path.

    Raises:
        FileExistsError: the folder exists and ``overwrite`` is False, or it was not written
            by posetrack.
    """
    dest = Path(folder)
    if dest.exists() and not overwrite:
        raise FileExistsError(f"save: {dest} already exists (pass overwrite=True)")
    people_index = np.full(seq.n_frames, -1, np.int64)  # as written (edited copies too)
    with atomic_dir(dest) as tmp:
        for sub in ("depth", "keypoints") + (() if seq.rgb is None else ("rgb",)):
            (tmp / sub).mkdir()
        for t in range(seq.n_frames):
            name = f"{t:06d}"
            # Millimetres -> metres -> millimetres is exact: k / 1000 * 1000 rounds back to k.
            write_depth_png(tmp / "depth" / f"{name}.png", seq.depth[t] / 1000.0, scale=1000.0)
            if seq.rgb is not None:
                write_rgb(tmp / "rgb" / f"{name}.png", seq.rgb[t])
            kp, conf, people_index[t] = _frame_people(seq, t)
            write_openpose_json(tmp / "keypoints" / f"{name}_keypoints.json", kp, conf)
        write_intrinsics_json(tmp / "intrinsics.json", seq.intrinsics)
        np.savez_compressed(
            tmp / "ground_truth.npz", joints3d=seq.joints3d, visible=seq.visible,
            fps=np.float64(seq.fps), joints2d=seq.joints2d, T_cam_world=seq.T_cam_world,
            floor_plane=seq.floor_plane, people_index=people_index,
            others_joints3d=seq.others_joints3d,
        )  # fmt: skip
    return dest
