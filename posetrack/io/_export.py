"""Tracker outputs: a NumPy ``.npz`` of poses and EasyMocap-style per-frame JSON.

Both are written atomically (see :mod:`posetrack.io._atomic`). Poses are in the depth
camera frame (OpenCV: x right, y down, z forward) or, when asked, the floor frame (y up; the
``.npz`` records which), metres, COCO-18 keypoint order. No NaN is
ever written as a pose value: ``params`` must be finite, and NaN in ``keypoints3d`` only
means "not estimated" (the whole joint, with confidence 0).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from ._atomic import atomic_dir, atomic_open
from ._errors import InputError
from ._openpose import BODY25_NAMES, BODY25_TO_COCO18, COCO18_NAMES

STATUSES = ("tracked", "lost", "no_observation")
"""Per-frame status values; stored in ``.npz`` as strings, and accepted as 0, 1, 2."""

POSES_FORMAT = "posetrack-poses"
POSES_VERSION = 1
#: Values of ``joint_state`` in ``poses.npz`` (``TrackResult.joint_state``), by code 0, 1, 2.
JOINT_STATE_NAMES = ("not_estimated", "predicted", "observed")


def _first_bad(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _check_keypoints(keypoints3d, confidence, what: str) -> tuple[np.ndarray, np.ndarray]:
    kp = np.asarray(keypoints3d, dtype=np.float64)
    conf = np.asarray(confidence, dtype=np.float64)
    if kp.ndim != 3 or kp.shape[1:] != (18, 3):
        raise ValueError(f"{what}: keypoints3d must be (T, 18, 3), got {kp.shape}")
    if conf.shape != kp.shape[:2]:
        raise ValueError(f"{what}: confidence must be {kp.shape[:2]}, got {conf.shape}")
    nan = np.isnan(kp)
    partial = nan.any(-1) & ~nan.all(-1)
    if partial.any():
        t, j = _first_bad(partial)
        raise ValueError(
            f"{what}: keypoints3d[{t}, {j}] = {kp[t, j].tolist()} is partly NaN; a joint is "
            "either estimated (3 finite numbers) or not (all NaN)"
        )
    if np.isinf(kp).any():
        idx = _first_bad(np.isinf(kp))
        raise ValueError(f"{what}: keypoints3d{list(idx)} is infinite")
    if not np.isfinite(conf).all() or (conf < 0).any():
        idx = _first_bad(~np.isfinite(conf) | (conf < 0))
        raise ValueError(f"{what}: confidence{list(idx)} = {conf[idx]}; expected finite >= 0")
    unestimated = nan.all(-1)
    if (unestimated & (conf > 0)).any():
        t, j = _first_bad(unestimated & (conf > 0))
        raise ValueError(
            f"{what}: keypoints3d[{t}, {j}] is NaN (not estimated) but confidence is {conf[t, j]}"
        )
    return kp, conf


def _check_frame_ids(frame_ids, n: int, what: str) -> np.ndarray:
    ids = np.asarray(frame_ids)
    if ids.shape != (n,) or (n and not np.issubdtype(ids.dtype, np.integer)):
        raise ValueError(f"{what}: frame_ids must be ({n},) integers, got {ids.dtype} {ids.shape}")
    if n > 1 and not np.all(np.diff(ids) > 0):
        t = int(np.flatnonzero(np.diff(ids) <= 0)[0])
        raise ValueError(
            f"{what}: frame_ids must increase strictly; frame_ids[{t}:{t + 2}] = "
            f"{ids[t : t + 2].tolist()}"
        )
    if n and ids.min() < 0:
        raise ValueError(f"{what}: frame_ids must be >= 0, got {int(ids.min())}")
    return ids.astype(np.int64)


def _status_strings(status, n: int) -> np.ndarray:
    raw = np.asarray(status)
    if raw.shape != (n,):
        raise ValueError(f"write_poses_npz: status must be ({n},), got {raw.shape}")
    if np.issubdtype(raw.dtype, np.integer):
        bad = (raw < 0) | (raw >= len(STATUSES))
        if bad.any():
            t = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"write_poses_npz: status[{t}] = {raw[t]}; expected 0, 1 or 2 {STATUSES}"
            )
        return np.asarray(STATUSES, dtype="<U14")[raw]
    out = raw.astype(str)
    bad = ~np.isin(out, STATUSES)
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise ValueError(f"write_poses_npz: status[{t}] = {out[t]!r}; expected one of {STATUSES}")
    return out.astype("<U14")


def write_poses_npz(
    path: str | os.PathLike[str],
    *,
    keypoints3d: np.ndarray,
    confidence: np.ndarray,
    params: np.ndarray,
    delta: np.ndarray,
    status: Sequence[str] | np.ndarray,
    fps: float | None,
    frame_ids: np.ndarray,
    frame: str = "camera",
    world_from_camera: np.ndarray | None = None,
    joint_state: np.ndarray | None = None,
) -> None:
    """Write the tracked sequence to an uncompressed ``.npz``, atomically.

    The file holds exactly ``path`` (no ``.npz`` is appended). Arrays, T = frames:

    ======================  ==============  ==================================================
    key                     dtype, shape    meaning
    ======================  ==============  ==================================================
    ``format``              str             ``"posetrack-poses"``
    ``version``             int64           1
    ``frame_ids``           int64 (T,)      frame number of each row (file-name numbers)
    ``keypoints3d``         float32 (T,18,3) COCO-18 joints, metres, in ``frame``; NaN = not
                                            estimated
    ``frame``               str             ``"camera"`` (the depth camera: x right, y down,
                                            z forward) or ``"floor"`` (y up, origin on the
                                            floor: ``posetrack.floor_frame``)
    ``world_from_camera``   float64 (4,4)   camera -> ``frame`` (identity for "camera")
    ``confidence``          float32 (T,18)  0 where not estimated
    ``params``              float64 (T,P)   body-model parameters (P = 43), always finite,
                                            posing the body in ``frame``
    ``delta``               float32 (T,)    objective (discrepancy) of the chosen hypothesis;
                                            NaN where not computed
    ``status``              <U14 (T,)       ``"tracked"``, ``"lost"`` or ``"no_observation"``
    ``joint_names``         <U9 (18,)       COCO-18 names
    ``joint_state``         int8 (T,18)     0 not estimated, 1 predicted (not detected this
                                            frame), 2 observed; ABSENT when not given
    ``joint_state_names``   <U13 (3,)       the names of those values; with ``joint_state``
    ``fps``                 float64 ()      frames per second; ABSENT when unknown
    ======================  ==============  ==================================================

    Load with ``np.load(path)`` (no pickle needed) or :func:`read_poses_npz`.

    Raises:
        ValueError: inconsistent shapes; NaN or inf in ``params``; inf in ``delta``; a
            partly-NaN joint or NaN joint with confidence > 0; an unknown status; frame ids
            not strictly increasing; a non-positive fps.
    """
    what = "write_poses_npz"
    kp, conf = _check_keypoints(keypoints3d, confidence, what)
    n = kp.shape[0]
    params = np.asarray(params, dtype=np.float64)
    if params.ndim != 2 or params.shape[0] != n:
        raise ValueError(f"{what}: params must be ({n}, P), got {params.shape}")
    if not np.isfinite(params).all():
        t, k = _first_bad(~np.isfinite(params))
        raise ValueError(
            f"{what}: params[{t}, {k}] = {params[t, k]} (frame {int(np.asarray(frame_ids)[t])}); "
            "a pose value must never be NaN or inf"
        )
    delta = np.asarray(delta, dtype=np.float64)
    if delta.shape != (n,):
        raise ValueError(f"{what}: delta must be ({n},), got {delta.shape}")
    if np.isinf(delta).any():
        raise ValueError(f"{what}: delta[{_first_bad(np.isinf(delta))[0]}] is infinite")
    arrays = {
        "format": np.asarray(POSES_FORMAT),
        "version": np.asarray(POSES_VERSION, dtype=np.int64),
        "frame_ids": _check_frame_ids(frame_ids, n, what),
        "keypoints3d": kp.astype(np.float32),
        "confidence": conf.astype(np.float32),
        "params": params,
        "delta": delta.astype(np.float32),
        "status": _status_strings(status, n),
        "joint_names": np.asarray(COCO18_NAMES),
        "frame": np.asarray(str(frame)),
        "world_from_camera": _check_transform(world_from_camera, what),
    }
    if fps is not None:
        fps = float(fps)
        if not np.isfinite(fps) or fps <= 0:
            raise ValueError(f"{what}: fps must be positive, got {fps}")
        arrays["fps"] = np.asarray(fps, dtype=np.float64)
    if joint_state is not None:
        state = np.asarray(joint_state)
        if state.shape != kp.shape[:2] or not np.isin(state, (0, 1, 2)).all():
            raise ValueError(
                f"{what}: joint_state must be ({n}, 18) of 0, 1, 2, got {state.shape} with "
                f"values {np.unique(state).tolist()[:5]}"
            )
        estimated = np.isfinite(kp).all(axis=-1)
        if np.any((state == 0) != ~estimated):
            t, j = _first_bad((state == 0) != ~estimated)
            raise ValueError(
                f"{what}: joint_state[{t}, {j}] = {int(state[t, j])} but the joint is "
                f"{'' if estimated[t, j] else 'not '}estimated; 0 means exactly not estimated"
            )
        arrays["joint_state"] = state.astype(np.int8)
        arrays["joint_state_names"] = np.asarray(JOINT_STATE_NAMES)
    with atomic_open(path, "wb") as f:
        np.savez(f, **arrays)


def _check_transform(m, what: str) -> np.ndarray:
    """A rigid ``(4, 4)`` transform (None: the identity)."""
    if m is None:
        return np.eye(4)
    m = np.asarray(m, np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ValueError(f"{what}: world_from_camera must be a finite (4, 4), got {m.shape}")
    R = m[:3, :3]
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.allclose(m[3], [0, 0, 0, 1])):
        raise ValueError(f"{what}: world_from_camera is not a rigid transform: {m.tolist()}")
    return m


def read_poses_npz(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Read a file written by :func:`write_poses_npz` (arrays as documented there).

    Raises:
        InputError: not a readable ``.npz``, or not a posetrack poses file.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as e:  # OSError, ValueError (not a zip: pickle refused), BadZipFile, EOFError
        raise InputError(path, "file", str(path), f"is not a readable .npz file ({e})") from e
    if str(arrays.get("format", "")) != POSES_FORMAT:
        raise InputError(path, "format", arrays.get("format"), "is not a posetrack poses file")
    return arrays


def _to_body25(kp: np.ndarray, conf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COCO-18 (18, 3)/(18,) -> BODY_25: MidHip = mean of the hips, feet not estimated."""
    out = np.zeros((25, 3))
    c = np.zeros(25)
    out[BODY25_TO_COCO18] = kp
    c[BODY25_TO_COCO18] = conf
    rhip, lhip = COCO18_NAMES.index("RHip"), COCO18_NAMES.index("LHip")
    if conf[rhip] > 0 and conf[lhip] > 0:
        mid = BODY25_NAMES.index("MidHip")
        out[mid] = 0.5 * (kp[rhip] + kp[lhip])
        c[mid] = min(conf[rhip], conf[lhip])
    return out, c


def write_easymocap(
    folder: str | os.PathLike[str],
    keypoints3d: np.ndarray,
    confidence: np.ndarray,
    frame_ids: np.ndarray,
    *,
    layout: Literal["body25", "coco18"] = "body25",
    person_id: int = 0,
) -> Path:
    """Write EasyMocap-style 3D keypoints: ``<folder>/keypoints3d/<frame:06d>.json``.

    Each file is ``[{"id": person_id, "keypoints3d": [[x, y, z, c], ...]}]`` (metres, rounded to
    1 µm), or ``[]`` for a frame where no joint was estimated. Joints not estimated are written
    ``[0, 0, 0, 0]`` (JSON has no NaN). ``layout="body25"`` (default: EasyMocap's ``body25``
    skeleton) adds MidHip = mean of the hips and unestimated feet; ``"coco18"`` writes the 18
    joints as they are. Coordinates are written as given: the depth-camera frame, or the floor
    frame when the caller transformed them (``posetrack track --frame floor``).

    The ``keypoints3d`` folder is built aside and renamed into place: an old one (written by
    posetrack) is replaced as a whole; one not written by posetrack is never replaced
    (:class:`FileExistsError`).

    Returns:
        The ``keypoints3d`` folder.
    """
    what = "write_easymocap"
    if layout not in ("body25", "coco18"):
        raise ValueError(f"{what}: layout must be 'body25' or 'coco18', got {layout!r}")
    kp, conf = _check_keypoints(keypoints3d, confidence, what)
    ids = _check_frame_ids(frame_ids, kp.shape[0], what)
    target = Path(folder) / "keypoints3d"
    with atomic_dir(target) as tmp:
        for t, frame in enumerate(ids):
            est = ~np.isnan(kp[t]).any(-1)
            if not est.any():
                people = []
            else:
                xyz = np.where(est[:, None], kp[t], 0.0)
                c = np.where(est, conf[t], 0.0)
                if layout == "body25":
                    xyz, c = _to_body25(xyz, c)
                rows = np.concatenate([xyz, c[:, None]], axis=1)
                people = [
                    {"id": int(person_id), "keypoints3d": np.round(rows, 6).tolist()}
                ]
            (tmp / f"{int(frame):06d}.json").write_text(json.dumps(people), encoding="utf-8")
    return target
