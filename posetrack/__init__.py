"""posetrack: differentiable multiple-hypothesis 3D human pose tracking from RGB-D video.

A JAX implementation of Makris & Argyros, "Robust 3D Human Pose Estimation Guided by Filtered
Subsets of Body Keypoints". The core, one module per stage:

    _body (model, FK) -> _geometry (body-derived constants) -> _camera -> _observe (lifting)
    -> _residuals (Eq. 1) -> _fit (LM) -> _score (Eq. 3) -> _render (rasteriser, render+score)
    -> _depthobs (observation preprocessing) -> _select (landmark subsets) -> _config
    -> _step (one batched frame) -> _tracker (sequences; inputs checked by _inputs, results
    in _result) -> _world (output frames); _metrics,
    _init, _refine beside them;
    _associate (which person) and _sides (which side) relabel detections before the tracker.

Around the core: ``posetrack.io`` (file formats), ``posetrack.synth`` (a synthetic RGB-D
generator that is not the tracker's model), ``posetrack.detect`` (optional 2D detector) and
``posetrack.app`` (command line, demo, result files, pictures).
"""

from . import app as app
from . import io as io
from . import synth as synth
from ._associate import FollowSettings as FollowSettings
from ._associate import choose_person as choose_person
from ._associate import detection_score as detection_score
from ._associate import lift_candidates as lift_candidates
from ._associate import match_costs as match_costs
from ._batcher import ChunkBatcher as ChunkBatcher
from ._batcher import StepBatcher as StepBatcher
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
from ._config import BEYOND_THE_PAPER as BEYOND_THE_PAPER
from ._config import METHODS as METHODS
from ._config import TrackerConfig as TrackerConfig
from ._depthobs import downsample_depth as downsample_depth
from ._depthobs import fit_floor_plane as fit_floor_plane
from ._depthobs import observation_maps as observation_maps
from ._duplicates import DuplicateFilter as DuplicateFilter
from ._duplicates import DuplicateSettings as DuplicateSettings
from ._fit import FitResult as FitResult
from ._fit import FitSettings as FitSettings
from ._fit import fit_hypotheses as fit_hypotheses
from ._fit import fit_pose as fit_pose
from ._init import estimate_shape as estimate_shape
from ._init import initial_pose as initial_pose
from ._limbs import LIMB_NAMES as LIMB_NAMES
from ._many import track_many as track_many
from ._metrics import LIMB_PAIRS as LIMB_PAIRS
from ._metrics import Accuracy as Accuracy
from ._metrics import acceleration_error as acceleration_error
from ._metrics import accuracy as accuracy
from ._metrics import followed_identity as followed_identity
from ._metrics import gaussian_smoothed as gaussian_smoothed
from ._metrics import identity_jumps as identity_jumps
from ._metrics import jitter as jitter
from ._metrics import joint_errors as joint_errors
from ._metrics import motion_metrics as motion_metrics
from ._metrics import naive_lifting as naive_lifting
from ._metrics import success_curve as success_curve
from ._metrics import swapped_limb_frames as swapped_limb_frames
from ._metrics import swapped_limbs as swapped_limbs
from ._observe import Landmarks as Landmarks
from ._observe import body_depth_limit as body_depth_limit
from ._observe import confident_depth as confident_depth
from ._observe import lift_keypoints as lift_keypoints
from ._observe import observed_share as observed_share
from ._programs import enable_cache as enable_cache
from ._refine import refine_pose as refine_pose
from ._render import Capsules as Capsules
from ._render import render_and_score as render_and_score
from ._render import render_depth as render_depth
from ._render import render_depth_batch as render_depth_batch
from ._residuals import ResidualSettings as ResidualSettings
from ._result import JOINT_STATES as JOINT_STATES
from ._result import STATUS_NAMES as STATUS_NAMES
from ._result import TrackResult as TrackResult
from ._score import delta as delta
from ._score import delta_batch as delta_batch
from ._shapefit import ShapeFitSettings as ShapeFitSettings
from ._shapefit import refine_shape as refine_shape
from ._sides import SIDE_GROUPS as SIDE_GROUPS
from ._sides import SideLabeller as SideLabeller
from ._sides import SideSettings as SideSettings
from ._sides import arbitration_spans as arbitration_spans
from ._sides import frontal_turns as frontal_turns
from ._sides import prefer_exchanged as prefer_exchanged
from ._sides import two_sided_exchanged as two_sided_exchanged
from ._smooth import SmoothSettings as SmoothSettings
from ._smooth import smooth_window as smooth_window
from ._step import FrameEstimate as FrameEstimate
from ._step import TrackState as TrackState
from ._step import tracker_step as tracker_step
from ._tracker import LOST as LOST
from ._tracker import MODES as MODES
from ._tracker import NO_OBSERVATION as NO_OBSERVATION
from ._tracker import ONLINE_LAG as ONLINE_LAG
from ._tracker import RUN_CHUNK as RUN_CHUNK
from ._tracker import TRACKED as TRACKED
from ._tracker import Tracker as Tracker
from ._tracker import lift_sequence as lift_sequence
from ._tracker import track as track
from ._world import FRAMES as FRAMES
from ._world import WorldFrame as WorldFrame
from ._world import camera_frame as camera_frame
from ._world import floor_frame as floor_frame
from .app import SavedResults as SavedResults
from .app import bvh_from_result as bvh_from_result
from .app import output_frame as output_frame
from .app import save_results as save_results

__version__ = "0.1.0"

__all__ = [
    # subpackages
    "app", "io", "synth",
    # body model and camera
    "BODY_JOINTS", "KEYPOINT_NAMES", "NUM_PARAMS", "BodyShape", "Intrinsics", "backproject",
    "capsules", "facing_camera_params", "keypoints", "make_params", "project",
    # observations
    "Landmarks", "body_depth_limit", "confident_depth", "downsample_depth", "fit_floor_plane",
    "lift_keypoints", "observation_maps", "observed_share",
    # fitting (Eq. (1))
    "FitResult", "FitSettings", "ResidualSettings", "estimate_shape", "fit_hypotheses",
    "fit_pose", "initial_pose", "refine_pose",
    # body shape from depth
    "ShapeFitSettings", "refine_shape",
    # rendering and scoring (Eq. (3))
    "Capsules", "delta", "delta_batch", "render_and_score", "render_depth", "render_depth_batch",
    # the tracker
    "BEYOND_THE_PAPER", "FrameEstimate", "JOINT_STATES", "LOST", "METHODS", "NO_OBSERVATION",
    "STATUS_NAMES",
    "TRACKED", "TrackResult", "TrackState", "Tracker", "TrackerConfig", "lift_sequence",
    "track", "tracker_step",
    # many recordings at once
    "ChunkBatcher", "RUN_CHUNK", "StepBatcher", "track_many",
    # start-up: compiled programs kept on disk
    "enable_cache",
    # the motion model
    "LIMB_NAMES", "MODES", "ONLINE_LAG", "SmoothSettings", "smooth_window",
    # the detector's left/right swaps
    "SIDE_GROUPS", "SideLabeller", "SideSettings", "arbitration_spans", "frontal_turns",
    "prefer_exchanged",
    "two_sided_exchanged",
    # a detection that jumped onto another keypoint
    "DuplicateFilter", "DuplicateSettings",
    # which person is followed
    "FollowSettings", "choose_person", "detection_score", "lift_candidates", "match_costs",
    # metrics
    "LIMB_PAIRS", "Accuracy", "acceleration_error", "accuracy", "followed_identity",
    "gaussian_smoothed", "identity_jumps", "jitter", "joint_errors", "motion_metrics",
    "naive_lifting", "success_curve", "swapped_limb_frames", "swapped_limbs",
    # output frames
    "FRAMES", "WorldFrame", "camera_frame", "floor_frame",
    # result files
    "SavedResults", "bvh_from_result", "output_frame", "save_results",
]  # fmt: skip
