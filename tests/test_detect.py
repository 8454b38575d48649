"""posetrack.detect: BlazePose 33 -> COCO-18 mapping, pixel and crop conventions, the optional
dependency (clear ImportError, never imported by ``import posetrack``), and offline model runs.

The mapping tests need no MediaPipe. The model-running tests skip when the extra is absent; they
run on blank and noise images (BlazePose does not fire reliably on flat synthetic renders) and
check that nothing is downloaded. Detection on a real person is in ``test_real_data.py``.
"""

import os
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import posetrack
from posetrack import detect
from posetrack.detect import BLAZEPOSE_TO_COCO18, NECK, blazepose_to_coco18
from posetrack.detect._mapping import check_crop

#: BlazePose's 33 landmark names in index order, as MediaPipe documents them (PoseLandmark).
BLAZEPOSE_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip

#: The mapping as the issue specifies it (COCO-18 index -> BlazePose index; neck separately).
SPEC = {
    0: 0, 2: 12, 3: 14, 4: 16, 5: 11, 6: 13, 7: 15, 8: 24, 9: 26, 10: 28, 11: 23, 12: 25,
    13: 27, 14: 5, 15: 2, 16: 8, 17: 7,
}  # fmt: skip

MISSING = f"MediaPipe not installed ({detect.INSTALL_HINT}): model-running test skipped"


def _landmarks(visibility=0.9):
    """(33, 3) hand-made landmarks: distinct, well inside the image, given visibility."""
    j = np.arange(33)
    x = 0.1 + 0.8 * j / 32
    y = 0.9 - 0.7 * ((j * 7) % 33) / 32
    return np.stack([x, y, np.full(33, visibility)], axis=1)


# --- the 33 -> 18 mapping (no MediaPipe needed) ---------------------------------------------


def test_mapping_table_matches_the_spec_and_the_names():
    assert len(BLAZEPOSE_TO_COCO18) == 18
    for coco, blaze in SPEC.items():
        assert BLAZEPOSE_TO_COCO18[coco] == blaze, posetrack.KEYPOINT_NAMES[coco]
    assert BLAZEPOSE_TO_COCO18[1] == NECK
    # Names agree (posetrack's COCO-18 names use MediaPipe's spelling): catches left/right swaps.
    for coco, blaze in enumerate(BLAZEPOSE_TO_COCO18):
        if blaze != NECK:
            assert BLAZEPOSE_NAMES[blaze] == posetrack.KEYPOINT_NAMES[coco]


def test_blazepose_names_match_mediapipe():
    if not detect.available():
        pytest.skip(MISSING)
    from mediapipe.python.solutions.pose import PoseLandmark

    assert tuple(p.name.lower() for p in PoseLandmark) == BLAZEPOSE_NAMES


def test_mapping_on_hand_made_landmarks():
    lm = _landmarks()
    lm[11, 2], lm[12, 2] = 0.8, 0.7  # shoulders' visibility: the neck takes the smaller
    W, H = 200, 100
    kp, conf = blazepose_to_coco18(lm, (0, H, 0, W), min_confidence=0.5)
    assert kp.dtype == np.float32 and conf.dtype == np.float32
    assert kp.shape == (18, 2) and conf.shape == (18,)
    # Pixel centres: (0, 0) is the centre of the top-left pixel, normalised 0 is its left edge.
    uv = np.stack([lm[:, 0] * W - 0.5, lm[:, 1] * H - 0.5], axis=1)
    for coco, blaze in SPEC.items():
        np.testing.assert_allclose(kp[coco], uv[blaze], atol=1e-4)
        assert conf[coco] == pytest.approx(lm[blaze, 2])
    np.testing.assert_allclose(kp[1], 0.5 * (uv[11] + uv[12]), atol=1e-4)
    assert conf[1] == pytest.approx(0.7)


def test_low_confidence_landmarks_are_missing():
    lm = _landmarks()
    lm[14, 2] = 0.3  # right elbow (COCO 3)
    lm[11, 2] = 0.2  # left shoulder (COCO 5): the neck goes with it
    lm[0, 2] = np.nan  # nose (COCO 0)
    kp, conf = blazepose_to_coco18(lm, (0, 100, 0, 200), min_confidence=0.5)
    for i in (0, 1, 3, 5):
        assert conf[i] == 0.0 and np.all(kp[i] == 0.0), posetrack.KEYPOINT_NAMES[i]
    assert np.all(conf[[2, 4, 6, 7, 8]] > 0)
    # With no threshold the elbow and shoulder come back, with their own confidence.
    _, conf0 = blazepose_to_coco18(lm, (0, 100, 0, 200), min_confidence=0.0)
    assert conf0[3] == pytest.approx(0.3) and conf0[1] == pytest.approx(0.2)


def test_landmarks_outside_the_image_are_missing():
    W, H = 200, 100
    lm = _landmarks()
    lm[28, 0] = 1.05  # right ankle (COCO 10) past the right edge
    lm[27, 1] = 1.2  # left ankle (COCO 13) below the bottom
    lm[16, 0] = -0.01  # right wrist (COCO 4) left of the image
    lm[12, 1] = -0.3  # right shoulder (COCO 2) above: takes the neck with it
    lm[13, 0] = (W - 1e-3) / W  # left elbow (COCO 6): inside the last pixel, u = W - 0.5 - eps
    lm[15, 0] = 1.0  # left wrist (COCO 7): u = W - 0.5 rounds out of the image
    kp, conf = blazepose_to_coco18(lm, (0, H, 0, W), min_confidence=0.0)
    for i in (10, 13, 4, 2, 1, 7):
        assert conf[i] == 0.0 and np.all(kp[i] == 0.0), posetrack.KEYPOINT_NAMES[i]
    assert conf[6] > 0 and kp[6, 0] < W - 0.5
    # The same convention as posetrack.lift_keypoints: what the mapping keeps, lifting accepts.
    intr = posetrack.Intrinsics.create(fx=100.0, fy=100.0, cx=100.0, cy=50.0, width=W, height=H)
    depth = np.full((H, W), 2.0, np.float32)
    lifted = posetrack.lift_keypoints(depth, kp, conf, intr, confidence_threshold=0.0)
    np.testing.assert_array_equal(np.asarray(lifted.detected), conf > 0)


def test_landmarks_outside_the_crop_are_missing_even_inside_the_image():
    lm = _landmarks()
    lm[28, 1] = 1.1  # right ankle below the crop (the person is cut by the crop)
    kp, conf = blazepose_to_coco18(lm, (100, 300, 400, 500), min_confidence=0.0)
    assert conf[10] == 0.0 and np.all(kp[10] == 0.0)
    assert np.all(conf[[0, 2, 3, 4, 8, 9, 11, 12, 13]] > 0)


def test_crop_mapping_to_full_image_pixels():
    top, bottom, left, right = 10, 110, 50, 250
    lm = _landmarks()
    lm[0, :2] = 0.5, 0.25  # nose: the middle of the crop's width, a quarter down
    kp, _ = blazepose_to_coco18(lm, (top, bottom, left, right))
    np.testing.assert_allclose(kp[0], [50 + 100 - 0.5, 10 + 25 - 0.5], atol=1e-4)


@settings(max_examples=60, deadline=None)
@given(
    H=st.integers(20, 1080),
    W=st.integers(20, 1920),
    data=st.data(),
)
def test_crop_and_full_image_agree(H, W, data):
    """A point seen through a crop maps to the same full-image pixel as seen on the whole image,
    and the centre of crop pixel (r, c) maps to full-image pixel (top + r, left + c)."""
    top = data.draw(st.integers(0, H - 2))
    bottom = data.draw(st.integers(top + 1, H))
    left = data.draw(st.integers(0, W - 2))
    right = data.draw(st.integers(left + 1, W))
    h, w = bottom - top, right - left
    r = data.draw(st.integers(0, h - 1))
    c = data.draw(st.integers(0, w - 1))
    crop_lm = _landmarks(visibility=1.0)
    crop_lm[0, :2] = (c + 0.5) / w, (r + 0.5) / h
    kp_crop, conf_crop = blazepose_to_coco18(crop_lm, (top, bottom, left, right))
    assert conf_crop[0] == 1.0
    np.testing.assert_allclose(kp_crop[0], [left + c, top + r], atol=1e-3)
    full_lm = crop_lm.copy()
    full_lm[0, 0] = (left + crop_lm[0, 0] * w) / W
    full_lm[0, 1] = (top + crop_lm[0, 1] * h) / H
    kp_full, _ = blazepose_to_coco18(full_lm, (0, H, 0, W))
    np.testing.assert_allclose(kp_full[0], kp_crop[0], atol=1e-3)


def test_mapping_rejects_wrong_shape():
    with pytest.raises(ValueError, match=r"\(33, 3\)"):
        blazepose_to_coco18(np.zeros((17, 3)), (0, 10, 0, 10))


@pytest.mark.parametrize(
    "crop, match",
    [
        ((0, 10, 0), "top, bottom, left, right"),
        ("abcd", "integer"),
        ((0, 10.5, 0, 10), "bottom must be an integer"),
        ((5, 5, 0, 10), "top < bottom"),
        ((0, 10, 0, 161), "right=161"),
        ((-1, 10, 0, 10), "top=-1"),
        ((0, 121, 0, 10), "bottom=121"),
    ],
)
def test_bad_crop_is_a_clear_error(crop, match):
    with pytest.raises(ValueError, match=match):
        check_crop(crop, (120, 160, 3), "test")
    # Raised at the public boundary before MediaPipe is needed.
    with pytest.raises(ValueError, match=match):
        detect.detect_image(np.zeros((120, 160, 3), np.uint8), crop=crop)


def test_crop_none_is_the_whole_image():
    assert check_crop(None, (120, 160, 3), "test") == (0, 120, 0, 160)
    assert check_crop(np.array([1, 2, 3, 4]), (120, 160, 3), "test") == (1, 2, 3, 4)


@pytest.mark.parametrize(
    "image, match",
    [
        (np.zeros((10, 10), np.uint8), r"\(H, W, 3\)"),
        (np.zeros((10, 10, 4), np.uint8), r"\(H, W, 3\)"),
        (np.zeros((10, 10, 3), np.float32), "uint8"),
        (np.zeros((0, 10, 3), np.uint8), "empty"),
    ],
)
def test_bad_image_is_a_clear_error(image, match):
    with pytest.raises(ValueError, match=match):
        detect.detect_image(image)
    with pytest.raises(ValueError, match=match):
        detect.detect_keypoints([image], progress=False)
    if detect.available():  # a later frame: the detector is already running
        frames = [np.zeros((10, 10, 3), np.uint8), image]
        with pytest.raises(ValueError, match="frame 1"):
            detect.detect_keypoints(frames, progress=False)


def test_no_frames_give_empty_arrays():
    kp, conf = detect.detect_keypoints([], progress=False)
    assert kp.shape == (0, 18, 2) and conf.shape == (0, 18)
    assert kp.dtype == np.float32 and conf.dtype == np.float32


def test_bad_thresholds_are_clear_errors():
    with pytest.raises(ValueError, match="min_confidence"):
        detect.PoseDetector(min_confidence=1.5)
    with pytest.raises(ValueError, match="min_detection_confidence"):
        detect.PoseDetector(min_detection_confidence=-0.1)
    with pytest.raises(ValueError, match="min_confidence"):
        detect.detect_keypoints([], min_confidence=float("nan"), progress=False)


# --- the optional dependency -----------------------------------------------------------------


def test_import_posetrack_does_not_import_mediapipe():
    code = (
        "import sys, posetrack, posetrack.detect\n"
        "loaded = [m for m in sys.modules if m == 'mediapipe' or m.startswith('mediapipe.')]\n"
        "assert not loaded, loaded\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_missing_mediapipe_is_a_clear_import_error(monkeypatch):
    # Hide MediaPipe, including any submodule an earlier test imported (the import system
    # looks the full dotted name up in sys.modules first).
    for name in [m for m in sys.modules if m == "mediapipe" or m.startswith("mediapipe.")]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "mediapipe", None)
    assert detect.available() is False
    image = np.zeros((64, 64, 3), np.uint8)
    for call in (
        lambda: detect.PoseDetector(),
        lambda: detect.detect_image(image),
        lambda: detect.detect_keypoints([image], progress=False),
    ):
        with pytest.raises(ImportError, match=r'pip install "\.\[detect\]"'):
            call()


# --- the model, offline (skipped without the extra) ------------------------------------------


@pytest.fixture
def no_network(monkeypatch):
    """Any attempt to reach the network, or MediaPipe's model download helper, fails loudly."""

    def refuse(*args, **kwargs):
        raise AssertionError(f"network access attempted: {args[:2]!r}")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket.socket, "connect_ex", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    monkeypatch.setattr(urllib.request, "urlopen", refuse)
    from mediapipe.python.solutions import download_utils

    monkeypatch.setattr(download_utils, "download_oss_model", refuse)


def _model_files() -> set[Path]:
    import mediapipe

    return set(Path(mediapipe.__file__).parent.glob("modules/pose_*/*"))


@pytest.mark.parametrize("tracking", [True, False])
def test_detector_runs_offline_and_downloads_nothing(tracking, request):
    if not detect.available():
        pytest.skip(MISSING)
    request.getfixturevalue("no_network")
    before = _model_files()
    rng = np.random.default_rng(0)
    images = [
        np.zeros((240, 320, 3), np.uint8),
        np.full((240, 320, 3), 200, np.uint8),
        rng.integers(0, 256, (240, 320, 3), dtype=np.uint8),
    ]
    with detect.PoseDetector(tracking=tracking) as detector:
        for image in images:
            for crop in (None, (20, 220, 40, 200)):
                kp, conf = detector(image, crop=crop)
                assert kp.shape == (18, 2) and conf.shape == (18,)
                assert kp.dtype == np.float32 and conf.dtype == np.float32
                # Nobody in these images: every keypoint missing, in OpenPose's convention.
                assert np.all(conf == 0.0) and np.all(kp == 0.0)
    assert _model_files() == before  # no model file fetched into the package


def test_detect_keypoints_shapes(request):
    if not detect.available():
        pytest.skip(MISSING)
    request.getfixturevalue("no_network")
    frames = [np.zeros((120, 160, 3), np.uint8)] * 3
    kp, conf = detect.detect_keypoints(iter(frames), progress=False, crop=(10, 110, 20, 140))
    assert kp.shape == (3, 18, 2) and conf.shape == (3, 18)
    assert kp.dtype == np.float32 and np.all(conf == 0)


def test_closed_detector_is_a_clear_error():
    if not detect.available():
        pytest.skip(MISSING)
    detector = detect.PoseDetector()
    detector.close()
    detector.close()  # idempotent
    with pytest.raises(ValueError, match="closed"):
        detector(np.zeros((32, 32, 3), np.uint8))


# --- MediaPipe's native log lines --------------------------------------------------------------

#: What MediaPipe 0.10.21 prints from C++ the first time a graph runs (seen before the filter).
NATIVE_NOISE = ("XNNPACK delegate", "absl::InitializeLog", "inference_feedback_manager")

DETECT_SCRIPT = """
import numpy as np
from posetrack import detect
frames = [np.zeros((120, 160, 3), np.uint8)] * 3
kp, conf = detect.detect_keypoints(frames, progress=True)
print("shape", kp.shape)
with detect.PoseDetector() as detector:  # an error inside the filtered call still surfaces
    detector._pose.process = lambda image: 1 / 0
    detector(frames[0])
"""


def _run_detection(**env):
    run = subprocess.run(
        [sys.executable, "-c", DETECT_SCRIPT], capture_output=True, timeout=300,
        env={**os.environ, **env},
    )  # fmt: skip
    # Decoded by hand: text=True would translate "\r" into "\n" and hide a redraw.
    run.stdout, run.stderr = run.stdout.decode(), run.stderr.decode()
    return run


def test_mediapipe_log_lines_are_silenced_and_progress_and_errors_are_not():
    if not detect.available():
        pytest.skip(MISSING)
    run = _run_detection(POSETRACK_MEDIAPIPE_LOGS="")
    assert "shape (3, 18, 2)" in run.stdout
    for noise in NATIVE_NOISE:
        assert noise not in run.stderr, run.stderr
    # Progress (stderr is a pipe: whole lines) and the Python exception both come through,
    # so descriptor 2 was restored after every call, including the one that raised.
    assert "\r" not in run.stderr
    assert "detecting: 100% 3/3" in run.stderr
    assert run.returncode == 1 and "ZeroDivisionError" in run.stderr
    # The control: with the filter off, the same run prints those lines (so the test can fail).
    loud = _run_detection(POSETRACK_MEDIAPIPE_LOGS="1")
    assert all(noise in loud.stderr for noise in NATIVE_NOISE), loud.stderr


def test_native_log_filter_drops_info_keeps_errors_and_restores_stderr(capfd):
    from posetrack.detect._quiet import native_logs_filtered

    lines = (
        b"INFO: Created TensorFlow Lite XNNPACK delegate for CPU.\n"
        b"WARNING: All log messages before absl::InitializeLog() is called are written to STDERR\n"
        b"W0000 00:00:1795580150.167385    9046 inference_feedback_manager.cc:114] Feedback\n"
        b"I0000 00:00:1795580150.167385    9046 gl_context.cc:357] GL version\n"
        b"E0000 00:00:1795580150.167385    9046 calculator_graph.cc:887] a real error\n"
        b"something else\n"
    )
    with pytest.raises(RuntimeError, match="inside"):
        with native_logs_filtered():
            os.write(2, lines)
            with native_logs_filtered():  # nested: one redirection, restored once
                os.write(2, b"nested\n")
            raise RuntimeError("inside")
    os.write(2, b"after\n")
    err = capfd.readouterr().err
    assert err == (
        "E0000 00:00:1795580150.167385    9046 calculator_graph.cc:887] a real error\n"
        "something else\nnested\nafter\n"
    )
