"""Realistic synthetic RGB-D sequences of a person, with OpenPose-like 2D keypoints.

A host-side (NumPy/OpenCV) stand-in for a Kinect-v1 recording plus an OpenPose detector, used
by tests, benchmarks, notebooks and the demo until real data are available. It differs from
the tracker's own capsule model the way a real camera does: its own body shape (ellipsoids and
tapered capsules, a random subject per seed), a room, a Kinect-like depth sensor, detector
errors, occluders, and built-in or real (CMU/MSR/UTKinect) motion. ``bystander=True`` makes
two-person scenes: a second person crosses the view, leaves and comes back (``people2d``).

Quick use::

    seq = posetrack.synth.generate(0, motion="box", n_frames=60, occlusion_level=2)
    posetrack.synth.save(seq, "recordings/box0")
"""

from ._detector import DetectorConfig as DetectorConfig
from ._detector import simulate_detector as simulate_detector
from ._generate import SyntheticSequence as SyntheticSequence
from ._generate import generate as generate
from ._mocap import data_root as data_root
from ._mocap import list_real_motions as list_real_motions
from ._mocap import load_markers as load_markers
from ._motion import MOTIONS as MOTIONS
from ._sensor import SensorConfig as SensorConfig
from ._sensor import ideal_sensor as ideal_sensor
from ._sensor import projector_shadow as projector_shadow
from ._sensor import simulate_sensor as simulate_sensor
from ._skeleton import KEYPOINT_NAMES as KEYPOINT_NAMES
from ._write import save as save

__all__ = [
    "MOTIONS",
    "KEYPOINT_NAMES",
    "DetectorConfig",
    "SensorConfig",
    "SyntheticSequence",
    "data_root",
    "generate",
    "ideal_sensor",
    "list_real_motions",
    "load_markers",
    "projector_shadow",
    "save",
    "simulate_detector",
    "simulate_sensor",
]
