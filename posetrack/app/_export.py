"""From a :class:`~posetrack.TrackResult` to files: the glue behind ``posetrack track``.

:func:`save_results` writes one output folder, atomically (built in a hidden temporary folder
next to it and renamed into place at the end, :func:`posetrack.io.atomic_dir`)::

    out/poses.npz            keypoints3d, confidence, params, delta, status, frame_ids[, fps]
    out/keypoints3d/*.json   EasyMocap layout, one file per frame
    out/motion.bvh           19-joint skeleton, T-pose rest, and its motion (y-up, centimetres)
    out/markers.trc          the 18 keypoints as OpenSim markers (metres)
    out/overlay.mp4          (or overlay.gif) the skeleton drawn on colour or depth, and a side view
    out/summary.json         frames, status counts, method, config, body shape, timing

:func:`bvh_from_result` gives the BVH skeleton and motion as arrays, for other writers.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import math
import os
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._camera import Intrinsics
from .._depthobs import NO_FLOOR
from .._result import JOINT_STATES, STATUS_NAMES, TrackResult
from .._world import FRAMES, WorldFrame, camera_frame, floor_frame, transform_params
from ..io import (
    COCO18_NAMES,
    MARKER_NAME,
    atomic_dir,
    write_bvh,
    write_easymocap,
    write_openpose_json,
    write_poses_npz,
    write_trc,
)
from ._bvh_skeleton import BVH_END_SITES as BVH_END_SITES
from ._bvh_skeleton import BVH_JOINT_NAMES as BVH_JOINT_NAMES
from ._bvh_skeleton import BVH_KEYPOINTS as BVH_KEYPOINTS
from ._bvh_skeleton import BVH_PARENTS as BVH_PARENTS
from ._bvh_skeleton import BvhMotion as BvhMotion
from ._bvh_skeleton import bvh_from_params as bvh_from_params
from ._overlay import write_overlay
from ._panel import PANELS

DEFAULT_FPS = 30.0
"""Frame rate assumed for the BVH and the video when the recording does not say (a folder
of images has no frame rate)."""

# 180 deg about x: the camera frame (y down) -> a y-up world, as write_bvh(camera_to_y_up=True).
_C = np.diag([1.0, -1.0, -1.0])


def bvh_from_result(result: TrackResult, frame: WorldFrame | None = None) -> BvhMotion:
    """The tracked skeleton and motion as BVH arrays (:func:`bvh_from_params` of the result).

    Every frame has a pose: frames without an estimate repeat the nearest estimated one
    (``TrackResult.params`` is never NaN); ``result.status`` says which frames those are.
    With a ``frame`` (:func:`output_frame`), the motion is in that frame, written as y-up by
    ``write_bvh(camera_to_y_up=True)`` (a floor frame, already y-up, is turned by ``C`` first so
    that the writer's ``C`` undoes it: the file then holds floor coordinates).
    """
    params = result.params
    if frame is not None and frame.name != "camera":
        params = transform_params(frame.params(params), _C, np.zeros(3))
    return bvh_from_params(result.shape, params)


def output_frame(result: TrackResult, name: str = "camera") -> WorldFrame:
    """The frame outputs are written in: ``"camera"`` (as tracked) or ``"floor"`` (y up, the
    origin on the floor under the first tracked frame's pelvis; :func:`posetrack.floor_frame`).

    Raises:
        ValueError: an unknown name; ``"floor"`` without a floor found or a tracked frame.
    """
    if name not in FRAMES:
        raise ValueError(f"output frame must be one of {FRAMES}, got {name!r}")
    if name == "camera":
        return camera_frame()
    tracked = np.flatnonzero(np.asarray(result.status) == 0)
    if not len(tracked):
        raise ValueError("floor frame: no frame was tracked, so there is no pelvis to stand on")
    floor = NO_FLOOR if result.floor is None else result.floor  # floor_frame refuses it
    return floor_frame(floor, result.params[tracked[0], :3])


@dataclasses.dataclass(frozen=True)
class SavedResults:
    """What :func:`save_results` wrote."""

    folder: Path
    """The output folder."""
    poses: Path
    """``poses.npz``."""
    keypoints3d: Path
    """The EasyMocap ``keypoints3d`` folder."""
    bvh: Path
    """``motion.bvh``."""
    trc: Path
    """``markers.trc``."""
    overlay: Path | None
    """``overlay.mp4`` or ``overlay.gif``; None without video."""
    keypoints2d: Path | None
    """The OpenPose ``keypoints2d`` folder of the detector's keypoints; None when not given."""
    summary: dict[str, Any]
    """The contents of ``summary.json``."""


def check_output_dir(path: str | os.PathLike[str]) -> Path:
    """Fail early (before tracking) if ``path`` could not be replaced by :func:`save_results`.

    A folder is replaced only if it does not exist, is empty, or was written by posetrack
    (carries :data:`posetrack.io.MARKER_NAME`); the same rule :func:`posetrack.io.atomic_dir`
    enforces at the end, checked here so a mistyped ``--out`` does not cost a tracking run.
    The folder that will hold ``path`` (or the nearest existing folder above it) must also
    accept new files: a read-only disk or folder fails here, not after tracking. A full disk
    cannot be told in advance; :func:`save_results` reports it when it happens.

    Raises:
        FileExistsError: ``path`` is a file, or a folder with other data in it, or a file
            stands where a folder above it should be.
        OSError: no file can be created there (read-only, permissions); the message names
            ``path`` and the system's reason.
    """
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise FileExistsError(f"{path}: exists and is not a folder; refusing to replace it")
    if path.is_dir() and not (path / MARKER_NAME).is_file() and any(path.iterdir()):
        raise FileExistsError(
            f"{path}: folder exists and was not written by posetrack (no {MARKER_NAME} file "
            "inside); refusing to replace it. Delete it or choose another output folder."
        )
    folder = path.absolute().parent
    while not os.path.lexists(folder) and folder != folder.parent:
        folder = folder.parent  # atomic_dir creates the missing ones
    if not folder.is_dir():
        raise FileExistsError(f"{path}: cannot create it, {folder} is a file, not a folder")
    try:
        # An unnamed file (O_TMPFILE on Linux): nothing is left behind, even if killed here.
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        raise _write_error(path, e) from e
    return path


# The errors of a disk or folder that refuses a write (as opposed to an unreadable input).
_WRITE_ERRNOS = frozenset(
    getattr(errno, name)
    for name in ("ENOSPC", "EDQUOT", "EROFS", "EFBIG", "EACCES", "EPERM", "EIO")
    if hasattr(errno, name)
)


def _write_error(out: Path, e: OSError) -> OSError:
    """``e`` (raised while writing ``out``) as one sentence that names ``out``: the raw one
    names a hidden temporary file, or no file at all (``write`` on a full disk)."""
    reason = e.strerror or str(e)
    return OSError(
        e.errno,
        f"cannot write {out}: {reason} (nothing was written there; an earlier output in that "
        "folder is unchanged)",
    )


@contextlib.contextmanager
def _write_errors_name(out: Path) -> Iterator[None]:
    """Re-raise a refused write of ``out`` (full disk, read-only...) as :func:`_write_error`;
    other errors (an unreadable colour frame for the overlay, say) pass unchanged."""
    try:
        yield
    except OSError as e:
        if _is_write_error(e, out):
            raise _write_error(out, e) from e
        raise


def _is_write_error(e: OSError, out: Path) -> bool:
    """Whether ``e`` is a refused write of ``out`` (or of the hidden folder it is built in)."""
    if isinstance(e, FileExistsError) or e.errno not in _WRITE_ERRNOS:
        return False
    if e.filename is None:  # write(), fsync(): always one of the output's files
        return True
    name = os.path.abspath(os.fsdecode(e.filename))
    target = os.path.abspath(out)
    building = os.path.join(os.path.dirname(target), f".{os.path.basename(target)}.")
    return name == target or name.startswith(building)


def without_timings(summary: Any) -> Any:
    """``summary.json`` (parsed) without what differs between two runs of the same inputs:
    the ``timing`` section and every ``*_s`` entry (seconds), at any depth. What is left is
    byte-for-byte reproducible (README, Reliability)."""
    if isinstance(summary, dict):
        return {
            k: without_timings(v)
            for k, v in summary.items()
            if k != "timing" and not k.endswith("_s")
        }
    if isinstance(summary, list):
        return [without_timings(v) for v in summary]
    return summary


def _jsonable(value: Any) -> Any:
    """Plain JSON values (NaN and inf become null: JSON has neither)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.integer, bool, np.bool_)):
        return value.item() if isinstance(value, np.generic) else value
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def status_counts(status: np.ndarray) -> dict[str, int]:
    """Frames per status name (``tracked``, ``lost``, ``no_observation``)."""
    status = np.asarray(status)
    return {name: int(np.sum(status == code)) for code, name in enumerate(STATUS_NAMES)}


def save_results(
    out_dir: str | os.PathLike[str],
    result: TrackResult,
    *,
    intrinsics: Intrinsics,
    frame_ids: Sequence[int] | np.ndarray | None = None,
    fps: float | None = None,
    rgb: Sequence[np.ndarray] | None = None,
    depth: Sequence[np.ndarray] | None = None,
    depth_scale: float = 1000.0,
    video: bool = True,
    video_panel: str | None = "side",
    detections: tuple[np.ndarray, np.ndarray] | None = None,
    keypoints2d: tuple[np.ndarray, np.ndarray, Sequence[str]] | None = None,
    info: dict[str, Any] | None = None,
    progress: bool = False,
    frame: str = "camera",
) -> SavedResults:
    """Write every output of a tracked sequence into ``out_dir``, atomically.

    The folder is built in a hidden temporary folder next to ``out_dir`` and renamed into place
    when everything is written: after a crash or Ctrl-C, ``out_dir`` is either absent or the
    previous complete output. A previous output folder is replaced as a whole; a folder not
    written by posetrack is never replaced (:class:`FileExistsError`, raised before writing).

    Files (T = frames):

    * ``poses.npz`` (:func:`posetrack.io.write_poses_npz`): ``keypoints3d`` float32
      (T, 18, 3) metres, camera frame (x right, y down, z forward), COCO-18, NaN where not
      estimated (before the first initialisation, and after a track loss until the tracker
      re-initialises; frames without observation while tracking repeat the last pose with
      confidence 0); ``confidence`` (T, 18); ``params`` (T, 43), never NaN;
      ``delta`` (T,); ``status`` strings; ``frame_ids``; ``fps`` when known.
    * ``keypoints3d/<frame:06d>.json`` (:func:`posetrack.io.write_easymocap`): EasyMocap
      ``[{"id": 0, "keypoints3d": [[x, y, z, c], ...]}]``, BODY_25 order, camera frame, metres.
    * ``motion.bvh``: :func:`bvh_from_result` written with ``camera_to_y_up=True`` in
      centimetres (Blender: File > Import > Motion Capture, scale 0.01).
    * ``markers.trc`` (:func:`posetrack.io.write_trc`): the 18 COCO-18 keypoints as OpenSim
      markers, metres, in ``frame``; empty where not estimated.
    * ``overlay.mp4`` or ``overlay.gif`` (``video=True``): :func:`posetrack.app.write_overlay`,
      with the ``video_panel`` view beside the image (the floor drawn where the tracker found
      one).
    * ``keypoints2d/<stem>_keypoints.json`` (with ``keypoints2d``): the 2D keypoints the
      tracker was given, as OpenPose JSON (:func:`posetrack.io.write_openpose_json`; nobody
      where every confidence is 0), so a run can be repeated from them without the detector.
    * ``summary.json``: frames, status counts, mean Delta, method and configuration, body shape,
      fps, timing, the files, plus ``info``.

    Args:
        out_dir: output folder.
        result: the tracker's output.
        intrinsics: the depth camera (projects the skeleton for the overlay).
        frame_ids: ``(T,)`` increasing frame numbers (file names of the JSON); default 0..T-1.
        fps: frames per second, or None if unknown (then ``poses.npz`` has no ``fps``, and the
            BVH and video use :data:`DEFAULT_FPS`).
        rgb: ``T`` colour images ``uint8 (H, W, 3)`` registered to depth, for the overlay.
        depth: ``T`` depth images (float metres, or ``uint16`` at ``depth_scale`` units per
            metre), drawn colourised when ``rgb`` is None.
        depth_scale: units per metre of ``uint16`` depth.
        video: write the overlay (needs ``rgb`` or ``depth``).
        video_panel: ``"side"`` (default) or ``"top"``: the 3D view beside the image in the
            overlay (:class:`posetrack.app.SkeletonPanel`); None: the image alone.
        detections: optional ``((T, 18, 2), (T, 18))`` 2D keypoints and confidences given to
            the tracker, drawn as dots on the overlay.
        keypoints2d: optional ``((T, 18, 2), (T, 18), T stems)``: 2D keypoints to save as
            OpenPose JSON, one ``<stem>_keypoints.json`` per frame (the command line: the colour
            images' stems, or the frame ids as ``%06d`` for a video).
        info: extra JSON-able entries for ``summary.json`` (inputs, notes, timing, ...).
        progress: progress bar for the overlay on stderr.
        frame: ``"camera"`` or ``"floor"`` (:func:`output_frame`): the frame of the poses in
            ``poses.npz``, the JSON, the BVH and the TRC (the overlay is drawn in the image).

    Returns:
        A :class:`SavedResults`.

    Raises:
        ValueError: inconsistent lengths, a non-positive fps, ``video`` without frames, an
            unknown ``video_panel``, a floor frame without a floor.
        FileExistsError: ``out_dir`` exists and was not written by posetrack.
        OSError: the disk or folder refused a write (full, read-only, permissions): one
            sentence naming ``out_dir`` and the system's reason; nothing is left at
            ``out_dir`` (an earlier output there is unchanged).
    """
    t0 = time.perf_counter()
    T = len(result.params)
    ids = np.arange(T) if frame_ids is None else np.asarray(frame_ids)
    if ids.shape != (T,):
        raise ValueError(f"save_results: frame_ids must be ({T},), got {ids.shape}")
    if T > 1 and not np.all(np.diff(ids) > 0):
        raise ValueError(f"save_results: frame_ids must increase strictly, got {ids.tolist()}")
    if fps is not None and not (math.isfinite(float(fps)) and float(fps) > 0):
        raise ValueError(f"save_results: fps must be positive, got {fps!r}")
    if video and rgb is None and depth is None:
        raise ValueError("save_results: video=True needs rgb or depth frames to draw on")
    if video_panel is not None and video_panel not in PANELS:
        raise ValueError(
            f"save_results: video_panel must be one of {PANELS} or None, got {video_panel!r}"
        )
    if keypoints2d is not None:
        kp2, conf2, stems = keypoints2d
        if np.shape(kp2) != (T, 18, 2) or np.shape(conf2) != (T, 18) or len(stems) != T:
            raise ValueError(
                f"save_results: keypoints2d must be (({T}, 18, 2), ({T}, 18), {T} stems), got "
                f"({np.shape(kp2)}, {np.shape(conf2)}, {len(stems)} stems)"
            )
        if len(set(stems)) != T or any(not s or "/" in s or os.sep in s for s in stems):
            raise ValueError("save_results: keypoints2d stems must be unique file-name stems")
    for name, frames in (("rgb", rgb), ("depth", depth)):
        if frames is not None and len(frames) != T:
            raise ValueError(f"save_results: {name} has {len(frames)} frames, result has {T}")
    out = check_output_dir(out_dir)
    rate = float(fps) if fps is not None else DEFAULT_FPS
    world = output_frame(result, frame)
    motion = bvh_from_result(result, world)  # validates params before anything is written
    kp3d = world.points(result.keypoints3d)
    params = world.params(result.params)

    tracked = result.status == 0
    summary: dict[str, Any] = {
        "frames": T,
        "frame_ids": {"first": int(ids[0]), "last": int(ids[-1])} if T else None,
        "status_counts": status_counts(result.status),
        "joint_state_counts": {
            name: int(np.sum(result.joint_state == k)) for k, name in enumerate(JOINT_STATES)
        },
        "mean_delta_tracked": float(np.mean(result.delta[tracked])) if tracked.any() else None,
        "method": result.config.method,
        "hypotheses": result.config.n,
        "config": dataclasses.asdict(result.config),
        "shape": result.shape.to_dict(),
        "fps": float(fps) if fps is not None else None,
        "fps_used_for_bvh_and_video": rate,
        "intrinsics": intrinsics.to_dict(),
        "frame": {
            "name": world.name,
            "world_from_camera": world.matrix,
            "floor_plane_camera": result.floor,
        },
        "timing": {
            "compile_s": result.compile_s,
            "ms_per_frame_steady": result.ms_per_frame,
        },
    }
    with _write_errors_name(out), atomic_dir(out) as tmp:
        write_poses_npz(
            tmp / "poses.npz", keypoints3d=kp3d, confidence=result.confidence, params=params,
            delta=result.delta, status=result.status, fps=fps, frame_ids=ids, frame=world.name,
            world_from_camera=world.matrix, joint_state=result.joint_state,
        )  # fmt: skip
        write_easymocap(tmp, kp3d, result.confidence, ids)
        write_bvh(tmp / "motion.bvh", **motion._asdict(), fps=rate, camera_to_y_up=True)
        write_trc(tmp / "markers.trc", kp3d, COCO18_NAMES, fps=rate, frame_ids=ids)
        overlay = None
        if video:
            overlay = write_overlay(
                tmp / "overlay", keypoints3d=result.keypoints3d, status=result.status,
                delta=result.delta, frame_ids=ids, intrinsics=intrinsics, fps=rate, rgb=rgb,
                depth=depth, depth_scale=depth_scale, detections=detections, panel=video_panel,
                floor=result.floor, progress=progress,
            )  # fmt: skip
        if keypoints2d is not None:
            (tmp / "keypoints2d").mkdir()
            for k, c, stem in zip(*keypoints2d):
                seen = np.asarray(c) > 0
                write_openpose_json(
                    tmp / "keypoints2d" / f"{stem}_keypoints.json",
                    *((k, c) if seen.any() else (np.zeros((0, 18, 2)), np.zeros((0, 18)))),
                )  # fmt: skip
        files = {
            "poses": "poses.npz",
            "keypoints3d": "keypoints3d/ (EasyMocap, BODY_25 order)",
            "bvh": "motion.bvh (y-up, centimetres)",
            "trc": f"markers.trc (OpenSim markers, metres, {world.name} frame)",
            "overlay": overlay.name if overlay is not None else None,
            "keypoints2d": None if keypoints2d is None else "keypoints2d/ (OpenPose JSON, 2D)",
            "summary": "summary.json",
        }
        summary["files"] = files
        summary["timing"]["write_s"] = time.perf_counter() - t0
        if info:
            for key, value in info.items():
                if key == "timing":
                    summary["timing"].update(value)
                else:
                    summary[key] = value
        summary = _jsonable(summary)
        (tmp / "summary.json").write_text(
            json.dumps(summary, indent=1, allow_nan=False) + "\n", encoding="utf-8"
        )
    return SavedResults(
        folder=out,
        poses=out / "poses.npz",
        keypoints3d=out / "keypoints3d",
        bvh=out / "motion.bvh",
        trc=out / "markers.trc",
        overlay=None if overlay is None else out / overlay.name,
        keypoints2d=None if keypoints2d is None else out / "keypoints2d",
        summary=summary,
    )
