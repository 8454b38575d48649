"""File formats: validated inputs (depth PNGs, OpenPose JSON, intrinsics JSON or OpenCV
YAML/XML, colour, TUM RGB-D sequences) and atomically written outputs (poses ``.npz``,
EasyMocap JSON, BVH, and the input formats themselves, which ``posetrack.synth.save`` writes).

NumPy/OpenCV only. Every bad input file raises :class:`InputError` (a ``ValueError``) naming
the file, the field and the offending value.
"""

from ._atomic import MARKER_NAME as MARKER_NAME
from ._atomic import atomic_dir as atomic_dir
from ._atomic import atomic_open as atomic_open
from ._atomic import atomic_write_bytes as atomic_write_bytes
from ._atomic import atomic_write_text as atomic_write_text
from ._bvh import Bvh as Bvh
from ._bvh import bvh_forward_kinematics as bvh_forward_kinematics
from ._bvh import bvh_world_transforms as bvh_world_transforms
from ._bvh import read_bvh as read_bvh
from ._bvh import write_bvh as write_bvh
from ._depth import DepthSequence as DepthSequence
from ._depth import probe_depth_png as probe_depth_png
from ._depth import read_depth as read_depth
from ._depth import write_depth_png as write_depth_png
from ._errors import InputError as InputError
from ._export import STATUSES as STATUSES
from ._export import read_poses_npz as read_poses_npz
from ._export import write_easymocap as write_easymocap
from ._export import write_poses_npz as write_poses_npz
from ._frames import format_ranges as format_ranges
from ._frames import frame_number as frame_number
from ._frames import list_frames as list_frames
from ._intrinsics import read_intrinsics as read_intrinsics
from ._intrinsics import read_intrinsics_json as read_intrinsics_json
from ._intrinsics import write_intrinsics_json as write_intrinsics_json
from ._manifest import ManifestRow as ManifestRow
from ._manifest import read_manifest as read_manifest
from ._openpose import BODY25_NAMES as BODY25_NAMES
from ._openpose import BODY25_TO_COCO18 as BODY25_TO_COCO18
from ._openpose import COCO18_NAMES as COCO18_NAMES
from ._openpose import KeypointFrame as KeypointFrame
from ._openpose import read_openpose_json as read_openpose_json
from ._openpose import write_openpose_json as write_openpose_json
from ._recording import Recording as Recording
from ._recording import load_recording as load_recording
from ._recording import load_tum as load_tum
from ._rgb import RgbFrames as RgbFrames
from ._rgb import RgbVideo as RgbVideo
from ._rgb import read_rgb as read_rgb
from ._rgb import write_rgb as write_rgb
from ._trc import read_trc as read_trc
from ._trc import write_trc as write_trc
from ._tum import TUM_CAMERAS as TUM_CAMERAS
from ._tum import TUM_DEPTH_SCALE as TUM_DEPTH_SCALE
from ._tum import TUM_MAX_DIFFERENCE as TUM_MAX_DIFFERENCE
from ._tum import TUM_REGISTERED_DEPTH as TUM_REGISTERED_DEPTH
from ._tum import associate_timestamps as associate_timestamps
from ._tum import read_tum_list as read_tum_list

__all__ = [
    "MARKER_NAME",
    "STATUSES",
    "BODY25_NAMES",
    "BODY25_TO_COCO18",
    "COCO18_NAMES",
    "TUM_CAMERAS",
    "TUM_REGISTERED_DEPTH",
    "TUM_DEPTH_SCALE",
    "TUM_MAX_DIFFERENCE",
    "Bvh",
    "DepthSequence",
    "InputError",
    "KeypointFrame",
    "ManifestRow",
    "Recording",
    "RgbFrames",
    "RgbVideo",
    "associate_timestamps",
    "atomic_dir",
    "atomic_open",
    "atomic_write_bytes",
    "atomic_write_text",
    "bvh_forward_kinematics",
    "bvh_world_transforms",
    "format_ranges",
    "frame_number",
    "list_frames",
    "load_recording",
    "load_tum",
    "probe_depth_png",
    "read_bvh",
    "read_depth",
    "read_intrinsics",
    "read_intrinsics_json",
    "read_manifest",
    "read_openpose_json",
    "read_poses_npz",
    "read_rgb",
    "read_trc",
    "read_tum_list",
    "write_bvh",
    "write_depth_png",
    "write_easymocap",
    "write_intrinsics_json",
    "write_openpose_json",
    "write_poses_npz",
    "write_rgb",
    "write_trc",
]
