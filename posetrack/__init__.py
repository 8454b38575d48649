"""posetrack: differentiable multiple-hypothesis 3D human pose tracking from RGB-D video.

A JAX implementation of Makris & Argyros, "Robust 3D Human Pose Estimation Guided by Filtered
Subsets of Body Keypoints". The pipeline, one module per stage:

    _body (model, FK) -> _camera -> _observe (lifting) -> _residuals (Eq. 1) -> _fit (LM)
    -> _render (soft depth rasteriser) -> _depthobs + _score (Eq. 3) -> _select (subsets)
    -> _step (one batched frame) -> _tracker (sequences); io, synth, metrics, viz, cli around it.
"""

from . import io as io
from . import synth as synth
from ._body import BODY_JOINTS as BODY_JOINTS
from ._body import KEYPOINT_NAMES as KEYPOINT_NAMES
from ._body import NUM_PARAMS as NUM_PARAMS
from ._body import BodyShape as BodyShape
from ._body import capsules as capsules
from ._body import facing_camera_params as facing_camera_params
from ._body import keypoints as keypoints
from ._body import make_params as make_params
from ._camera import Intrinsics as Intrinsics
from ._camera import backproject as backproject
from ._camera import project as project
from ._depthobs import downsample_depth as downsample_depth
from ._depthobs import fit_floor_plane as fit_floor_plane
from ._depthobs import observation_maps as observation_maps
from ._export import SavedResults as SavedResults
from ._export import bvh_from_result as bvh_from_result
from ._export import save_results as save_results
from ._fit import FitResult as FitResult
from ._fit import FitSettings as FitSettings
from ._fit import fit_hypotheses as fit_hypotheses
from ._fit import fit_pose as fit_pose
from ._init import estimate_shape as estimate_shape
from ._init import initial_pose as initial_pose
from ._metrics import Accuracy as Accuracy
from ._metrics import accuracy as accuracy
from ._metrics import naive_lifting as naive_lifting
from ._metrics import success_curve as success_curve
from ._observe import Landmarks as Landmarks
from ._observe import lift_keypoints as lift_keypoints
from ._render import Capsules as Capsules
from ._render import render_depth as render_depth
from ._render import render_depth_batch as render_depth_batch
from ._residuals import ResidualSettings as ResidualSettings
from ._score import delta as delta
from ._score import render_and_score as render_and_score
from ._step import METHODS as METHODS
from ._step import FrameEstimate as FrameEstimate
from ._step import TrackerConfig as TrackerConfig
from ._step import TrackState as TrackState
from ._step import tracker_step as tracker_step
from ._tracker import Tracker as Tracker
from ._tracker import TrackResult as TrackResult
from ._tracker import lift_sequence as lift_sequence
from ._tracker import track as track

__version__ = "0.1.0"

__all__ = [
    "BODY_JOINTS", "KEYPOINT_NAMES", "METHODS", "NUM_PARAMS", "Accuracy", "BodyShape", "Capsules",
    "FitResult", "FitSettings", "FrameEstimate", "Intrinsics", "Landmarks", "ResidualSettings",
    "TrackResult", "TrackState", "Tracker", "TrackerConfig", "accuracy", "backproject",
    "capsules", "delta", "downsample_depth", "estimate_shape", "facing_camera_params",
    "fit_floor_plane", "fit_hypotheses", "fit_pose", "initial_pose", "io", "keypoints",
    "lift_keypoints", "make_params", "naive_lifting", "observation_maps", "project",
    "render_and_score", "render_depth", "render_depth_batch", "success_curve", "synth", "track",
    "SavedResults", "bvh_from_result", "save_results", "lift_sequence",
    "tracker_step",
]  # fmt: skip
