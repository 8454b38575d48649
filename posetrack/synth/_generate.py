"""``generate``: the synthetic RGB-D + keypoint "camera" and its output type."""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from posetrack._camera import Intrinsics, pixel_rays_np

from ._bystander import bystander_motion
from ._detector import DetectorConfig, perfect_detector, simulate_detector
from ._mocap import real_motion
from ._motion import MOTIONS, procedural_motion
from ._occlusion import MAX_LEVEL, occluder_rects, person_boxes, rect_mask
from ._scene import BODY_LABEL0, make_scene, place_motion
from ._sensor import SensorConfig, ideal_sensor, simulate_sensor
from ._skeleton import (
    KEYPOINT_NAMES,
    N_KPT,
    SEG,
    Subject,
    forward_kinematics,
    keypoints_world,
    sample_subject,
)
from ._surface import Background, hair_mask, primitives_camera, render_frame, shade
from ._variety import VARIETIES, draw_wide

# Independent random streams per concern, keyed by (seed, stream): changing one option (say
# the occlusion level) leaves the subject, motion, scene and sensor noise unchanged. The
# two-person streams come after the original ones, so single-person output is as it was.
_SUBJECT, _MOTION, _SCENE, _SENSOR, _DETECTOR, _OCCLUDER, _RGB = range(1, 8)
_BYSTANDER, _BYSTANDER_DET, _PEOPLE_ORDER = 8, 9, 10
_WIDE = 11  # variety="wide": its own stream, so the standard streams draw what they drew


@dataclasses.dataclass(frozen=True, eq=False)
class SyntheticSequence:
    """A rendered synthetic RGB-D sequence with detector output and ground truth.

    Camera frame: x right, y down, z forward, metres. Pixel (0, 0) is the centre of the
    top-left pixel. Keypoints in OpenPose COCO-18 order (:data:`KEYPOINT_NAMES`).
    """

    depth: np.ndarray
    """(T, H, W) uint16 measured depth, millimetres; 0 = invalid."""
    rgb: np.ndarray | None
    """(T, H, W, 3) uint8 shaded colour image registered to the depth (occluders black);
    None when generated with ``with_rgb=False``."""
    keypoints2d: np.ndarray
    """(T, 18, 2) float32 detected keypoints, px; (0, 0) when not detected."""
    confidence: np.ndarray
    """(T, 18) float32 detection confidence in [0, 1]; 0 = not detected."""
    joints3d: np.ndarray
    """(T, 18, 3) float64 ground-truth keypoints, camera frame, m (joint centres inside the
    body; eyes, ears and nose on the head surface)."""
    joints2d: np.ndarray
    """(T, 18, 2) float64 exact projections of ``joints3d``, px."""
    visible: np.ndarray
    """(T, 18) bool: the keypoint is inside the image, not under an occluder and not hidden
    by the body itself or by another person (``bystander=True``)."""
    occluder_masks: np.ndarray
    """(T, H, W) bool pixels removed by occluding rectangles."""
    person_mask: np.ndarray
    """(T, H, W) bool pixels showing the (main) person (noise-free, before occluders); not
    the bystander's."""
    intrinsics: Intrinsics
    """Camera intrinsics."""
    fps: float
    """Frame rate, Hz."""
    T_cam_world: np.ndarray
    """(4, 4) world (y up, floor y = 0) -> camera transform."""
    floor_plane: np.ndarray
    """(4,) floor in the camera frame, (n, d) with n . p + d = 0, n unit and pointing up."""
    subject: dict[str, Any]
    """The generated person's dimensions (m) and colours."""
    meta: dict[str, Any]
    """Motion, seed, levels, scene, sensor and detector settings (those used, after any
    ``variety="wide"`` changes), ``variety`` and ``wide`` (None, or every wide draw as a
    nested dict plus ``sensor_applied`` / ``detector_applied``: False where an explicit
    ``sensor=`` / ``detector=`` won), per-keypoint
    ``self_visibility``, ``occluded_fraction`` (rectangles) and ``hidden_fraction``
    (rectangles or another person in front), (T, 18) each. ``meta["bystander"]`` is None
    without a second person, else a dict: ``height`` (m) and ``subject`` (as ``subject``),
    ``speed`` (m/s), ``passes`` (two dicts: ``side`` "front"/"behind", ``depth`` m from the
    camera, ``direction`` +1 = toward the image's right, ``frames`` [start, stop) of the
    walk, ``x_start``/``x_stop`` world x, m) and its own three (T, 18) fractions."""
    # Every-person fields. Optional at construction (None): then derived from keypoints2d /
    # confidence as a one-person scene (see __post_init__), so older call sites still work.
    people2d: np.ndarray = None  # type: ignore[assignment]
    """(T, P, 18, 2) float32 every person the detector lists in each frame, px, in its order
    (random per frame), zero-padded after the listed ones. A person is listed when at least
    one of its keypoints is detected. P = 1 without bystander, and then
    ``people2d[:, 0] == keypoints2d``."""
    people_confidence: np.ndarray = None  # type: ignore[assignment]
    """(T, P, 18) float32 confidences of ``people2d``; 0 = missed keypoint or padding."""
    people_index: np.ndarray = None  # type: ignore[assignment]
    """(T,) int64 slot of the main person (``joints3d``, ``keypoints2d``) in ``people2d[t]``;
    -1 when none of its keypoints is detected that frame."""
    others_joints3d: np.ndarray = None  # type: ignore[assignment]
    """(T, P - 1, 18, 3) float64 ground-truth keypoints of the other people, camera frame, m
    (also while they are out of view); (T, 0, 18, 3) without bystander."""

    def __post_init__(self) -> None:
        if self.people2d is not None:
            return
        listed = np.any(self.confidence > 0, axis=-1)
        derived = {
            "people2d": np.asarray(self.keypoints2d, np.float32)[:, None].copy(),
            "people_confidence": np.asarray(self.confidence, np.float32)[:, None].copy(),
            "people_index": np.where(listed, 0, -1).astype(np.int64),
            "others_joints3d": np.zeros((len(listed), 0, 18, 3)),
        }
        for name, value in derived.items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)

    @property
    def n_frames(self) -> int:
        return int(self.depth.shape[0])

    def __len__(self) -> int:
        return self.n_frames

    def __repr__(self) -> str:
        return (f"SyntheticSequence(motion={self.meta['motion']!r}, seed={self.meta['seed']}, "
                f"frames={self.n_frames}, size={self.intrinsics.width}x"
                f"{self.intrinsics.height}, fps={self.fps}, "
                f"occlusion_level={self.meta['occlusion_level']}"
                f"{', bystander=True' if self.meta.get('bystander') else ''})")


def _visibility(joints_cam: np.ndarray, uv: np.ndarray, radius: np.ndarray, own, label,
                depth, occ_mask, fx: float, W: int, H: int, *, others=()
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-keypoint fraction of a 5x5 neighbourhood that shows its own parts / an occluder.

    A sample "shows the joint" when the surface there belongs to one of the joint's own
    primitives and lies at most 1.3 x the local body radius + 3 cm in front of the joint
    centre (an arm in front of the torso, the far side of the body, the back of the head or
    another person in front fail the test). A sample is "hidden" when it lies under an
    occluding rectangle or shows another person's surface farther than that in front of the
    joint: a person passing in front acts on the detector like an occluder.

    Args:
        joints_cam: (18, 3) keypoints, camera frame, m. uv: (18, 2) their projections, px.
        radius: (18,) body radius at each keypoint, m.
        own: per keypoint, the primitive indices (label - BODY_LABEL0) of its own parts.
        label: (H, W) render labels. depth: (H, W) rendered z, m.
        occ_mask: (H, W) bool occluding rectangles. fx: focal length, px. W, H: image size.
        others: primitive indices of the other people's bodies.

    Returns:
        (18,) each: self-visibility, fraction under a rectangle, fraction hidden (under a
        rectangle or behind another person; equal to the previous one without ``others``).
    """
    z = joints_cam[:, 2]
    rho = np.maximum(1.5, 0.7 * radius * fx / np.maximum(z, 0.1))
    g = np.linspace(-1.0, 1.0, 5)
    off = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)  # (25, 2)
    pts = uv[:, None, :] + rho[:, None, None] * off[None]
    ui = np.round(pts[..., 0]).astype(int)
    vi = np.round(pts[..., 1]).astype(int)
    inside = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    uc, vc = np.clip(ui, 0, W - 1), np.clip(vi, 0, H - 1)
    lab = label[vc, uc].astype(int) - BODY_LABEL0
    zs = depth[vc, uc]
    tol = 1.3 * radius + 0.03
    own_ok = np.zeros(lab.shape, dtype=bool)
    for k in range(N_KPT):
        own_ok[k] = np.isin(lab[k], list(own[k])) & ((z[k] - zs[k]) < tol[k])
    own_ok &= inside
    self_vis = own_ok.mean(axis=1)
    rect = occ_mask[vc, uc]
    occ = (rect & inside).mean(axis=1)
    if len(others) == 0:
        return self_vis, occ, occ
    person = np.isin(lab, list(others)) & ((z[:, None] - zs) >= tol[:, None])
    hidden = ((rect | person) & inside).mean(axis=1)
    return self_vis, occ, hidden


def _project_joints(joints3d: np.ndarray, K: tuple[float, float, float, float], W: int,
                    H: int) -> tuple[np.ndarray, np.ndarray]:
    """(..., 18, 3) camera-frame keypoints, m -> projections (..., 18, 2), px, and (..., 18)
    bool: inside the image and at least 10 cm in front of the camera."""
    fx, fy, cx, cy = K
    z = np.maximum(joints3d[..., 2], 1e-3)
    uv = np.stack([fx * joints3d[..., 0] / z + cx, fy * joints3d[..., 1] / z + cy], -1)
    in_image = ((uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0)
                & (uv[..., 1] <= H - 1) & (joints3d[..., 2] > 0.1))
    return uv, in_image


def _list_people(rng: np.random.Generator, kps: list[np.ndarray], confs: list[np.ndarray]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a detector lists per frame: the detected people in a random order, zero-padded.

    Args:
        rng: the order (one permutation of all people per frame, drawn whoever is listed).
        kps: per person (T, 18, 2) detections, px; the main person first.
        confs: per person (T, 18) confidences; a person with none > 0 is not listed.

    Returns:
        people2d (T, P, 18, 2) float32, people_confidence (T, P, 18) float32 and the main
        person's slot (T,) int64 (-1 when not listed).
    """
    T, P = kps[0].shape[0], len(kps)
    people2d = np.zeros((T, P, N_KPT, 2), np.float32)
    people_conf = np.zeros((T, P, N_KPT), np.float32)
    index = np.full(T, -1, np.int64)
    for t in range(T):
        slot = 0
        for i in rng.permutation(P):
            if np.any(confs[i][t] > 0):
                people2d[t, slot], people_conf[t, slot] = kps[i][t], confs[i][t]
                if i == 0:
                    index[t] = slot
                slot += 1
    return people2d, people_conf, index


def generate(
    seed: int = 0,
    *,
    motion: str = "walk",
    n_frames: int = 60,
    fps: float = 30.0,
    occlusion_level: int = 0,
    width: int = 640,
    height: int = 480,
    sensor_noise: bool = True,
    detector_noise: bool = True,
    progress: bool | Callable[[int, int, str], None] | None = False,
    intrinsics: Intrinsics | None = None,
    sensor: SensorConfig | None = None,
    detector: DetectorConfig | None = None,
    occluder_area: float = 0.12,
    motion_start: float = 0.0,
    yaw_deg: float | None = None,
    with_rgb: bool = True,
    bystander: bool = False,
    variety: str = "standard",
) -> SyntheticSequence:
    """Render a synthetic RGB-D sequence of one random person, optionally with a second one.

    Args:
        seed: everything random derives from it (same arguments => identical arrays).
        motion: a built-in motion (:data:`MOTIONS`) or a real one from
            :func:`list_real_motions` (``"cmu:131_01"``, ``"msr:a01_s01_e01"``,
            ``"utk:s01_e01:waveHands"``).
        n_frames: number of frames T.
        fps: frame rate, Hz.
        occlusion_level: 0 (none) .. 4 rectangles over the person (see ``_occlusion``).
        width, height: image size, px; intrinsics are the Kinect-v1-like 640x480 ones
            (fx = fy = 525, principal point at the centre) rescaled to this size.
        sensor_noise: apply the Kinect model (noise, quantisation, shadows, dropouts);
            False gives the exact rendered depth rounded to mm (still 0 out of range).
        detector_noise: apply OpenPose-like errors; False reports the exact projections of
            the ground-truth keypoints with confidence 1 (0 and (0, 0) outside the image).
        progress: ``progress(frames_done, n_frames, "")`` after each frame (the application
            layer passes ``posetrack.app.ProgressBar("generating")``); True prints a plain
            line to stderr every tenth of the frames.
        intrinsics: explicit intrinsics (overrides width/height).
        sensor: sensor parameters. detector: detector error parameters.
        occluder_area: nominal area of each occluding rectangle, fraction of the person box.
        motion_start: start time within a real motion clip, s.
        yaw_deg: fixed facing (travel) direction instead of a random one; 0 = facing the
            camera (travelling motions: moving to the camera's right).
        with_rgb: also render the colour images.
        bystander: add a second random person (own subject and random streams) who walks
            across the view in front of the main person, stays out of view a while and
            walks back, in front again or behind (see ``posetrack.synth._bystander``). It is
            rendered in the same ray cast, so it hides the main person (whose ``visible``,
            ``keypoints2d`` and ``confidence`` suffer: a person in front acts on the detector
            like an occluder) and is hidden by it; its own detections (same
            ``DetectorConfig``, its own noise; a keypoint behind a wall is never detected)
            go to ``people2d`` with the main person's, in a random order per frame.
            ``keypoints2d``, ``confidence``, ``joints3d`` and ``person_mask`` stay the main
            person's; the bystander's ground truth is ``others_joints3d``, its description
            ``meta["bystander"]``. The main person's subject, motion and scene are those of
            the same call without bystander, and so is every output until the bystander
            first comes into view; after that the depth noise differs everywhere (the sensor
            model draws a content-dependent amount of randomness per frame).
        variety: "standard" (the generator as it always was) or "wide": a per-clip draw from
            a separate stream of the seed widens the body (girth, limb lengths, shoulder
            and hip width, shoulder drop, joint depth inside the torso), the camera (height
            0.6-2.2 m, pitch 0-35 deg, roll +-5 deg), the depth noise and dropouts, and the
            detector errors (jitter scale and family, misses, outliers, longer swaps,
            whole-body swaps, limb snaps); ranges in ``posetrack.synth._variety``. The
            subject's other draws, the motion and the rest of the scene stay those of the
            standard clip. An explicit ``sensor`` or ``detector`` wins over the wide draw
            for that part. ``fps`` is never changed: benchmarks should vary it themselves.
            The draw is in ``meta["wide"]``. A bystander keeps a standard body but shares
            the detector errors.

    Raises:
        ValueError: naming the bad argument. FileNotFoundError: real motion data missing.
    """
    if int(n_frames) != n_frames or n_frames < 1:
        raise ValueError(f"generate: n_frames must be a positive integer, got {n_frames!r}")
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"generate: fps must be positive, got {fps!r}")
    if int(occlusion_level) != occlusion_level or not 0 <= occlusion_level <= MAX_LEVEL:
        raise ValueError(f"generate: occlusion_level must be 0..{MAX_LEVEL}, got "
                         f"{occlusion_level!r}")
    if variety not in VARIETIES:
        raise ValueError(f"generate: variety must be one of {VARIETIES}, got {variety!r}")
    if motion not in MOTIONS and ":" not in motion:
        raise ValueError(f"generate: unknown motion {motion!r}; built-in: {MOTIONS}, real: "
                         "see list_real_motions()")
    if intrinsics is None:
        if int(width) != width or int(height) != height or width < 16 or height < 16:
            raise ValueError(f"generate: bad image size {width!r}x{height!r}")
        intrinsics = Intrinsics.create(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640,
                                       height=480)
        if (width, height) != (640, 480):
            intrinsics = intrinsics.scaled(int(width), int(height))
    n_frames, W, H = int(n_frames), intrinsics.width, intrinsics.height
    fx, fy = float(intrinsics.fx), float(intrinsics.fy)
    cx, cy = float(intrinsics.cx), float(intrinsics.cy)

    def rng(stream: int) -> np.random.Generator:
        return np.random.default_rng([int(seed) & 0xFFFFFFFF, stream])

    wide = draw_wide(rng(_WIDE)) if variety == "wide" else None
    if sensor is not None:
        scfg = sensor
    else:
        scfg = wide.sensor_config() if wide is not None else SensorConfig()
    if detector is not None:
        dcfg = detector
    else:
        dcfg = wide.detector_config() if wide is not None else DetectorConfig()

    t_start = time.perf_counter()
    subject = sample_subject(rng(_SUBJECT), variation=wide.body if wide is not None else None)
    if motion in MOTIONS:
        clip = procedural_motion(motion, subject, n_frames=n_frames, fps=fps, rng=rng(_MOTION))
    else:
        clip = real_motion(motion, subject, n_frames=n_frames, fps=fps, start=motion_start)
    r_scene = rng(_SCENE)
    clip = place_motion(clip, r_scene, yaw_deg=yaw_deg)
    scene, clip = make_scene(r_scene, intrinsics, subject, clip,
                             camera=wide.camera if wide is not None else None)
    floor_rgb = tuple(int(v) for v in r_scene.integers(90, 190, size=3))
    wall_rgb = tuple(int(v) for v in r_scene.integers(160, 235, size=3))

    origins = forward_kinematics(subject, clip.root, clip.rotations)
    kp_world = keypoints_world(subject, origins, clip.rotations)
    joints3d = scene.to_camera(kp_world)
    K = (fx, fy, cx, cy)
    joints2d, in_image = _project_joints(joints3d, K, W, H)
    n_main = len(subject.primitives)
    by = None
    by_prims: range | tuple[()] = ()  # the bystander's primitive indices in the ray cast
    if bystander:
        r_by = rng(_BYSTANDER)
        by_subject = sample_subject(r_by)
        by_clip, by_info = bystander_motion(r_by, by_subject, scene, n_frames=n_frames, fps=fps)
        by_origins = forward_kinematics(by_subject, by_clip.root, by_clip.rotations)
        by_world = keypoints_world(by_subject, by_origins, by_clip.rotations)
        by_j3d = scene.to_camera(by_world)
        by_j2d, by_in = _project_joints(by_j3d, K, W, H)
        by_in &= scene.inside(by_world)  # behind the side wall: gone through a doorway
        by_prims = range(n_main, n_main + len(by_subject.primitives))
        by = {
            "own": tuple(frozenset(n_main + i for i in s) for s in by_subject.kpt_own),
            "head": BODY_LABEL0 + n_main + [p.name for p in by_subject.primitives].index("head"),
            "self_vis": np.zeros((n_frames, N_KPT)),
            "occ": np.zeros((n_frames, N_KPT)),
            "hidden": np.zeros((n_frames, N_KPT)),
        }

    # Occluders follow a smoothed box around the body (keypoints, head top, soles).
    head_top = origins[:, SEG["head"]] + clip.rotations[:, SEG["head"]] @ np.array(
        [0.0, 0.2, 0.0])
    body = np.concatenate([kp_world, head_top[:, None]], axis=1)
    bc = scene.to_camera(body)
    buv = np.stack([fx * bc[..., 0] / np.maximum(bc[..., 2], 1e-3) + cx,
                    fy * bc[..., 1] / np.maximum(bc[..., 2], 1e-3) + cy], -1)
    boxes = person_boxes(buv)
    rects = occluder_rects(rng(_OCCLUDER), boxes, int(occlusion_level), fps,
                           area_fraction=occluder_area, anchors=buv[:, :N_KPT])

    rays = pixel_rays_np(fx=fx, fy=fy, cx=cx, cy=cy, width=W, height=H)
    rr = np.sum(rays * rays, axis=-1)
    background = Background(scene, rays)
    head_label = BODY_LABEL0 + [p.name for p in subject.primitives].index("head")
    r_sensor, r_rgb = rng(_SENSOR), rng(_RGB)
    depth = np.zeros((n_frames, H, W), np.uint16)
    rgb = np.zeros((n_frames, H, W, 3), np.uint8) if with_rgb else None
    occ_masks = np.zeros((n_frames, H, W), bool)
    person = np.zeros((n_frames, H, W), bool)
    self_vis = np.zeros((n_frames, N_KPT))
    occ = np.zeros((n_frames, N_KPT))
    hidden = np.zeros((n_frames, N_KPT))
    for t in range(n_frames):
        # One ray cast for everybody: the main person's primitives first, so its labels are
        # BODY_LABEL0 + k for k < n_main and the bystander's come after.
        prims = primitives_camera(subject, origins[t], clip.rotations[t], scene)
        if by is not None:
            prims += primitives_camera(by_subject, by_origins[t], by_clip.rotations[t], scene)
        ren = render_frame(prims, background, rays, rr, K)
        person[t] = (ren.label >= BODY_LABEL0) & (ren.label < BODY_LABEL0 + n_main)
        R_cam_head = scene.R_cam_world @ clip.rotations[t, SEG["head"]]
        hair = hair_mask(ren, head_label, R_cam_head)
        others: list[tuple[Subject, np.ndarray]] = []
        all_hair = hair
        if by is not None:
            R_cam_by_head = scene.R_cam_world @ by_clip.rotations[t, SEG["head"]]
            others.append((by_subject, hair_mask(ren, by["head"], R_cam_by_head)))
            all_hair = hair | others[0][1]
        if sensor_noise:
            d = simulate_sensor(r_sensor, ren.depth, fx=fx, fy=fy, cx=cx, cy=cy, config=scfg,
                                normal=ren.normal, hair=all_hair)
        else:
            d = ideal_sensor(ren.depth, scfg)
        m = rect_mask(rects[t], (H, W))
        occ_masks[t] = m
        d[m] = 0
        depth[t] = d
        if rgb is not None:
            img = shade(ren, background, subject, hair, r_rgb, floor_rgb, wall_rgb,
                        others=others)
            img[m] = 0
            rgb[t] = img
        self_vis[t], occ[t], hidden[t] = _visibility(
            joints3d[t], joints2d[t], subject.kpt_radius, subject.kpt_own, ren.label,
            ren.depth, m, fx, W, H, others=by_prims)
        if by is not None:
            by["self_vis"][t], by["occ"][t], by["hidden"][t] = _visibility(
                by_j3d[t], by_j2d[t], by_subject.kpt_radius, by["own"], ren.label, ren.depth,
                m, fx, W, H, others=range(n_main))
        if callable(progress):
            progress(t + 1, n_frames, "")
        elif progress and ((t + 1) * 10 // n_frames > t * 10 // n_frames or t == 0):
            # Whole lines, no carriage return: this module draws no bars (the app layer does)
            # and a redirected stderr keeps every redraw.
            el = time.perf_counter() - t_start
            print(f"posetrack.synth: frame {t + 1}/{n_frames} ({el:.1f} s)", file=sys.stderr,
                  flush=True)  # fmt: skip
    centre_occ = np.array([[occ_masks[t, int(round(v)), int(round(u))]
                            if in_image[t, k] else False
                            for k, (u, v) in enumerate(joints2d[t])] for t in range(n_frames)])
    visible = in_image & (self_vis >= 0.3) & ~centre_occ
    # ``hidden`` is ``occ`` without a bystander; with one, a person in front counts as an
    # occluder for the detector (its miss rate and confidence), not only as self-occlusion.
    if detector_noise:
        kp2d, conf = simulate_detector(rng(_DETECTOR), joints2d, self_vis, hidden, in_image,
                                       width=W, height=H, config=dcfg)
    else:
        kp2d, conf = perfect_detector(joints2d, in_image)
    kps, confs = [kp2d], [conf]
    by_meta = None
    if by is not None:
        if detector_noise:
            by_kp, by_conf = simulate_detector(rng(_BYSTANDER_DET), by_j2d, by["self_vis"],
                                               by["hidden"], by_in, width=W, height=H,
                                               config=dcfg)
        else:
            by_kp, by_conf = perfect_detector(by_j2d, by_in)
        kps.append(by_kp)
        confs.append(by_conf)
        by_meta = {
            "height": by_subject.height,
            "subject": by_subject.to_dict(),
            **by_info,
            "self_visibility": by["self_vis"],
            "occluded_fraction": by["occ"],
            "hidden_fraction": by["hidden"],
        }
    people2d, people_conf, people_index = _list_people(rng(_PEOPLE_ORDER), kps, confs)
    others3d = (by_j3d[:, None] if by is not None else np.zeros((n_frames, 0, N_KPT, 3)))
    meta = {
        "motion": motion,
        "motion_info": {k: v for k, v in clip.info.items()},
        "seed": int(seed),
        "n_frames": n_frames,
        "fps": float(fps),
        "occlusion_level": int(occlusion_level),
        "occluder_area": float(occluder_area),
        "occluder_rects": rects,
        "sensor_noise": bool(sensor_noise),
        "detector_noise": bool(detector_noise),
        "sensor": dataclasses.asdict(scfg),
        "detector": dataclasses.asdict(dcfg),
        "scene": {
            "camera_height": scene.camera_height, "tilt_deg": scene.tilt_deg,
            "person_distance": scene.person_distance, "wall_distance": scene.wall_distance,
            "side_wall": len(scene.planes) > 2,
        },
        "keypoint_names": KEYPOINT_NAMES,
        "self_visibility": self_vis,
        "occluded_fraction": occ,
        "hidden_fraction": hidden,
        "bystander": by_meta,
        "variety": variety,
        "wide": None if wide is None else {
            **wide.to_dict(), "sensor_applied": sensor is None,
            "detector_applied": detector is None,
        },
        "generation_seconds": time.perf_counter() - t_start,
    }
    return SyntheticSequence(
        depth=depth, rgb=rgb, keypoints2d=kp2d, confidence=conf, joints3d=joints3d,
        joints2d=joints2d, visible=visible, occluder_masks=occ_masks, person_mask=person,
        intrinsics=intrinsics, fps=float(fps), T_cam_world=scene.T_cam_world,
        floor_plane=scene.floor_plane_camera(), subject=subject.to_dict(), meta=meta,
        people2d=people2d, people_confidence=people_conf, people_index=people_index,
        others_joints3d=others3d,
    )
