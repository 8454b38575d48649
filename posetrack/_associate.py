"""Which detected person is the tracked one (host side, NumPy).

A 2D detector lists every person it sees, in no particular order (OpenPose writes
``person_id`` -1 unless its tracker is on). A single-person tracker must pick one person once
and then follow it; taking the best-scoring detection anew every frame makes the track hop
between people whenever a second person is in view.

* **Initial choice** (:func:`choose_person`): by default the most complete detection (most
  keypoints with valid depth), the closest among those nearly as complete; or the largest,
  the closest, or a given index.
* **Association** (:func:`match_costs`): each detection's keypoints are lifted with the depth
  map (the median of valid depths in a small window, as the tracker's own lifting) and
  compared with the followed detection's lifted keypoints when it was last seen (where the
  person was *seen*, not where the fit put them: a poor fit must not move the gate off the
  person): the cost is the median over keypoints of the 3D distance where both have depth,
  and of the 2D distance converted to metres at the reference depth where only the reference
  has. A detection is the tracked person only if its cost is under
  a gate, which widens while the person is unseen (:meth:`FollowSettings.gate_after`).
  Other detections are ignored (and their pixels removed from the depth the tracker fits,
  :func:`other_people_mask`: their depth is not the tracked body's).
* **Re-acquisition** after a loss: a detection must also be consistent with the person's body
  proportions measured while tracking (:func:`segment_lengths`, :func:`shape_mismatch`) and lie
  within the widened gate of the last tracked position; when none is, the frame stays lost
  rather than jumping to whoever else is in view.

:class:`PersonFollower` holds the followed person's identity (reference, body proportions)
and applies these rules; the tracker and its body-shape pre-pass each run one.

No JAX here: a handful of people per frame, a few hundred numbers; the per-frame tracker step
stays one jitted call.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from ._camera import Intrinsics

#: Rules for the initial choice of person (besides an integer index).
PERSON_RULES = ("auto", "largest", "closest")
PersonRule = Literal["auto", "largest", "closest"] | int

#: Metres from a person's median lifted depth beyond which a lifted keypoint is taken to have
#: missed the body (a keypoint a few pixels off a far, thin limb reads the wall behind it):
#: :func:`segment_lengths` skips it, and the tracker's agreement test does not count it
#: (``posetrack._step.landmark_agreement``).
PLAUSIBLE_DEPTH_BAND = 0.4

#: Keypoint pairs whose 3D distance describes a body's proportions (COCO-18 indices):
#: shoulder width, hip width, upper arms, forearms, thighs, shins, neck to each hip.
SEGMENTS = (
    (2, 5), (8, 11), (2, 3), (5, 6), (3, 4), (6, 7), (8, 9), (11, 12), (9, 10), (12, 13),
    (1, 8), (1, 11),
)  # fmt: skip

#: COCO-18 bones drawn when masking another person's pixels (:func:`other_people_mask`).
_BONES = (
    (1, 2), (2, 3), (3, 4), (1, 5), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11),
    (11, 12), (12, 13), (2, 8), (5, 11), (8, 11), (1, 0), (0, 14), (0, 15), (14, 16), (15, 17),
)  # fmt: skip


def quiet_nanmedian(a: np.ndarray, axis: int) -> np.ndarray:
    """``np.nanmedian`` without the all-NaN warning (an all-NaN slice gives NaN: nothing
    measured, which callers handle), the same values bit for bit.

    A sort instead of ``np.nanmedian``'s masked-array path, which costs about half a
    millisecond per call on the small arrays of a frame (three calls a frame, per person).
    """
    a = np.asarray(a)
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float64)
    s = np.moveaxis(np.sort(a, axis=axis), axis, -1)  # NaNs sort last
    if s.shape[-1] == 0:
        return np.full(s.shape[:-1], np.nan, s.dtype)
    n = np.count_nonzero(~np.isnan(s), axis=-1)
    # All-NaN slices (n = 0) read index 0, a NaN: the NaN result without a special case.
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(s, np.minimum(n // 2, s.shape[-1] - 1)[..., None], axis=-1)[..., 0]
    # NumPy's median of an even count: the two middle values summed, halved, in their dtype.
    return np.true_divide(lo + hi, 2, dtype=s.dtype)


@dataclasses.dataclass(frozen=True)
class FollowSettings:
    """How the tracker follows one person among several detections.

    Distances are medians over a detection's keypoints, metres (see :func:`match_costs`).
    """

    gate: float = 0.35
    """A detection is the tracked person when its cost is below this (m). The cost of the
    right person is a frame of motion plus keypoint and depth noise (surface against surface):
    typically 0.03-0.12 m. A second person is a body width or more away."""
    gate_growth: float = 0.02
    """Metres the gate widens per frame the person is not found (0.6 m/s at 30 fps)."""
    gate_max: float = 1.5
    """The widest gate, m."""
    shape_tolerance: float = 0.15
    """Re-acquisition: the median over body segments of |log(length / tracked length)| must be
    below this (0.15 = about 16 %). Single-frame lengths are noisy, so this rejects clearly
    different bodies (a child, a much taller person) rather than telling twins apart: measured
    frame by frame (2026-12-05, benchmarks/README "The re-acquisition's shape check"), it
    refuses the tracked person in 20 % of frames on wide real motion and 6 % on standard
    bodies, a bystander in 25 %. Skipped where ``alone_frames`` says nobody else was seen."""
    min_keypoints: int = 3
    """A detection needs this many keypoints (confidence above ``confidence_threshold``) to be
    considered at all."""
    confidence_threshold: float = 0.1
    """Keypoints at or below this confidence are ignored (as the tracker's lifting does)."""
    mask_others: bool = True
    """Remove the other detected people's pixels from the depth the tracker fits and scores."""
    depth_band: float = 0.0
    """> 0 (metres): the reference follows the whole body. A detection's keypoint lifted further
    than this from its median lifted depth is read as having missed the body (a keypoint a few
    pixels off a thin limb reads the wall behind it; :func:`plausible_depth`): it is compared in
    2D only (:func:`match_costs`) and never enters the reference; and once a detection is
    accepted, every keypoint it lifts within the band replaces its reference
    (:meth:`PersonFollower.observe`), not only those within the gate of their old place. 0 (the
    class default; what online and per-frame tracking use): the reference takes any lifted
    keypoint, and afterwards only those within the gate. There, a keypoint lifted onto the wall
    once stays in the reference (later, correct liftings lie far from it, so they never replace
    it), as does a limb that swung further than the gate; with a few such keypoints the median
    cost of the only person in view outgrows the widening gate and the track is never
    re-acquired (a diagnosis of 2026-12-04 on a tuning clip: 45 of 120 frames lost;
    benchmarks/README.md, "The follower's reference"). :data:`PLAUSIBLE_DEPTH_BAND` (0.4) is the
    value measured; the tracker's default offline (:meth:`for_mode`, ``follow="auto"``) since
    2026-12-04: on the frames both versions answer it met its rule on fresh tuning runs and in
    the offline report stage (answered frames 22,375 -> 22,754 of 23,040, D -0.25 mm), and
    failed the online report stage by one cell (real motion, wide, clean: +3.0 mm at equal
    coverage), so online and per-frame it stays 0 (benchmarks/README.md, "The follower's
    reference"). Not in the paper."""
    alone_frames: int = 0
    """> 0: once the track has been dropped (a re-acquisition) and no frame has shown two or
    more people for this many frames (or none ever has), the only person in view is the
    followed one: wherever the gate would put them (their lifted keypoints then replace the
    reference), and whatever one frame's body proportions say (the re-acquisition's check,
    ``shape_tolerance``, refuses the tracked person in ~20 % of frames on wide real motion and
    then protects nothing; it did in the first two versions). While the track is alive
    the gate decides as before: a first version that also took a lone detection the gate
    refused there failed its screen (2026-12-05: answered frames +3.1 %, but swapped-limb
    frames +6.3 % and one cell +3.6 mm, from detections that had jumped). 0 (the default): the
    gate alone decides. Without it, a person who moves faster than the gate widens (0.6 m/s)
    while the track is lost is refused for as long as they keep moving, alone in the view: on
    72 wide tuning runs (2026-12-05, benchmarks/README "The only person in view, refused") 307
    of the 615 frames answered by nobody showed one person, detected, refused by the gate (a
    walk across the view with 4 % of its frames answered; a hop across, 35 %). The second
    version (the gate only) answers 95 % of the hop's frames; a screen of 186 fresh runs
    failed it on one occluded walk across (+32.5 mm on the frames both answer under tracker
    seed 0, -0.9 over seeds 1-3: a re-acquisition a frame earlier sends the track elsewhere),
    while 6 runs answered more frames. The third version's screen pooled three tracker
    seeds (260 fresh runs) and failed too: 48 runs changed, answered frames +2.3 %, D -0.41
    mm on the frames both answer, but one occluded walk across answered 30 % fewer frames
    and another was 26.7 mm worse (benchmarks/README "The pooled screen"). Opt-in. Not in
    the paper."""

    @classmethod
    def for_mode(cls, mode: str, **changes) -> FollowSettings:
        """The :class:`Tracker`'s default for a mode (``follow="auto"``): :attr:`depth_band`
        :data:`PLAUSIBLE_DEPTH_BAND` offline, 0 online and per-frame (decided on tuning runs
        and the report stages, see :attr:`depth_band`). ``changes`` override fields, e.g.
        ``gate=0.5``."""
        if mode not in ("offline", "online", "per-frame"):
            raise ValueError(
                f"FollowSettings.for_mode: mode must be 'offline', 'online' or 'per-frame', "
                f"got {mode!r}"
            )
        if mode == "offline":
            changes = {"depth_band": PLAUSIBLE_DEPTH_BAND, **changes}
        return cls(**changes)

    def __post_init__(self):
        v = self.depth_band
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
            raise ValueError(f"FollowSettings.depth_band must be >= 0 metres, got {v!r}")
        n = self.alone_frames
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"FollowSettings.alone_frames must be an integer >= 0, got {n!r}")

    def gate_after(self, unseen: int) -> float:
        """The gate (m) after ``unseen`` consecutive frames without the tracked person."""
        return min(self.gate + self.gate_growth * max(int(unseen), 0), self.gate_max)


@dataclasses.dataclass(frozen=True)
class Candidates:
    """The detections of one frame, lifted (NumPy arrays over P people)."""

    keypoints2d: np.ndarray
    """``float32 (P, 18, 2)`` pixels."""
    confidence: np.ndarray
    """``float32 (P, 18)``; 0 = missing."""
    points3d: np.ndarray
    """``float64 (P, 18, 3)`` lifted keypoints, camera frame, m (0 where ``has_depth`` is
    false)."""
    detected: np.ndarray
    """``bool (P, 18)`` confidence above the threshold."""
    has_depth: np.ndarray
    """``bool (P, 18)`` detected and valid depth found around the keypoint."""

    def __len__(self) -> int:
        return int(self.keypoints2d.shape[0])

    def usable(self, min_keypoints: int = 3) -> np.ndarray:
        """``bool (P,)`` people with at least ``min_keypoints`` detected keypoints."""
        return self.detected.sum(axis=1) >= min_keypoints

    def person(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """``(keypoints2d (18, 2), confidence (18,))`` of person ``p``."""
        return self.keypoints2d[p], self.confidence[p]


def lift_candidates(
    depth_m: np.ndarray,
    keypoints2d: np.ndarray,
    confidence: np.ndarray,
    intrinsics: Intrinsics,
    *,
    window: int = 5,
    confidence_threshold: float = 0.1,
    min_depth: float = 0.2,
    max_depth: float = 10.0,
    min_valid: int = 3,
) -> Candidates:
    """Lift every detected person's keypoints with the depth map (plain lifting).

    The same rule as the tracker's lifting (``lift_keypoints``, whose options these mirror):
    the median of the valid depths in a ``window`` x ``window`` square around the keypoint,
    back-projected; no surface offset (association compares bodies, it does not fit joints).
    A NumPy twin rather than a vmap of the JAX function: the number of people changes from
    frame to frame, and each new count would compile a new program on the host's critical
    path; ``tests/test_associate.py`` checks that both agree.

    Args:
        depth_m: ``(H, W)`` metres; 0, NaN and depths outside [min_depth, max_depth] invalid.
        keypoints2d: ``(P, 18, 2)`` pixels. confidence: ``(P, 18)``.
        intrinsics: the depth camera.

    Returns:
        :class:`Candidates`.
    """
    kp = np.asarray(keypoints2d, np.float64).reshape(-1, 18, 2)
    conf = np.asarray(confidence, np.float64).reshape(-1, 18)
    H, W = depth_m.shape
    detected = (conf > confidence_threshold) & np.isfinite(kp).all(axis=-1)
    detected &= (kp[..., 0] > -0.5) & (kp[..., 0] < W - 0.5)
    detected &= (kp[..., 1] > -0.5) & (kp[..., 1] < H - 0.5)
    r = window // 2
    off = np.arange(-r, r + 1)
    ui = np.rint(np.where(detected, kp[..., 0], 0)).astype(int)[..., None, None] + off[None, :]
    vi = np.rint(np.where(detected, kp[..., 1], 0)).astype(int)[..., None, None] + off[:, None]
    inside = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    z = np.asarray(depth_m, np.float64)[np.clip(vi, 0, H - 1), np.clip(ui, 0, W - 1)]
    valid = inside & np.isfinite(z) & (z >= min_depth) & (z <= max_depth)
    z = np.where(valid, z, np.nan).reshape(*kp.shape[:2], -1)
    count = valid.reshape(*kp.shape[:2], -1).sum(axis=-1)
    has_depth = detected & (count >= min_valid)
    zm = np.where(has_depth, quiet_nanmedian(np.where(has_depth[..., None], z, 1.0), axis=-1), 0)
    fx, fy, cx, cy = (float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                         intrinsics.cy))  # fmt: skip
    pts = np.stack([(kp[..., 0] - cx) / fx * zm, (kp[..., 1] - cy) / fy * zm, zm], axis=-1)
    pts = np.where(has_depth[..., None], pts, 0.0)
    return Candidates(
        keypoints2d=kp.astype(np.float32), confidence=conf.astype(np.float32),
        points3d=pts, detected=detected, has_depth=has_depth,
    )  # fmt: skip


def detection_score(keypoints2d: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """OpenPose-style prominence of each person: sum of confidences x bounding-box diagonal.

    Args:
        keypoints2d: ``(P, 18, 2)`` (or any ``(P, K, 2)``) pixels. confidence: ``(P, K)``.

    Returns:
        ``(P,)`` scores (0 for a person with fewer than 2 keypoints).
    """
    kp = np.asarray(keypoints2d, np.float64)
    conf = np.asarray(confidence, np.float64)
    valid = conf > 0
    lo = np.where(valid[..., None], kp, np.inf).min(axis=1)
    hi = np.where(valid[..., None], kp, -np.inf).max(axis=1)
    with np.errstate(invalid="ignore"):
        diag = np.hypot(*(hi - lo).T)
    score = np.where(valid, conf, 0).sum(axis=1) * np.nan_to_num(diag, nan=0.0, posinf=0.0)
    return np.where(valid.sum(axis=1) >= 2, score, 0.0)


def choose_person(cands: Candidates, rule: PersonRule = "auto", *, min_keypoints: int = 3) -> int:
    """The person to follow from the first frame's detections; -1 if none qualifies.

    Args:
        cands: the frame's lifted detections.
        rule: ``"auto"`` = the most complete (most keypoints with depth), the closest of those
            within 2 keypoints of it; ``"largest"`` = largest detection score
            (:func:`detection_score`); ``"closest"`` = smallest median depth; an ``int`` = that
            index into the frame's list of people.
        min_keypoints: detections with fewer keypoints are never chosen by a rule.

    Raises:
        ValueError: an unknown rule, or an index outside the frame's list.
    """
    if isinstance(rule, (int, np.integer)) and not isinstance(rule, bool):
        listed = int(cands.detected.any(axis=1).sum())  # padding (no keypoint) comes last
        if not 0 <= int(rule) < listed:
            raise ValueError(
                f"person index {int(rule)} is not among the {listed} people detected in the "
                f"first frame with detections (indices 0..{listed - 1})"
            )
        return int(rule)
    if rule not in PERSON_RULES:
        raise ValueError(f"person must be one of {PERSON_RULES} or an index, got {rule!r}")
    n_det = cands.detected.sum(axis=1)
    n_3d = cands.has_depth.sum(axis=1)
    ok = n_det >= min_keypoints
    if not ok.any():
        return -1
    z = quiet_nanmedian(np.where(cands.has_depth, cands.points3d[..., 2], np.nan), axis=1)
    z = np.where(np.isfinite(z), z, np.inf)
    if rule == "largest":
        score = detection_score(cands.keypoints2d, np.where(cands.detected, cands.confidence, 0))
        return int(np.argmax(np.where(ok, score, -1.0)))
    if rule == "closest":
        return (
            int(np.argmin(np.where(ok & (n_3d > 0), z, np.inf)))
            if (ok & (n_3d > 0)).any()
            else int(np.argmax(np.where(ok, n_det, -1)))
        )
    complete = ok & (n_3d >= n_3d[ok].max() - 2)
    return (
        int(np.argmin(np.where(complete, z, np.inf)))
        if np.isfinite(z[complete]).any()
        else int(np.argmax(np.where(ok, n_det, -1)))
    )


def plausible_depth(points3d: np.ndarray, has_depth: np.ndarray, band: float) -> np.ndarray:
    """``has_depth`` less the keypoints lifted more than ``band`` metres from their person's
    median lifted depth (``band`` 0: ``has_depth`` unchanged).

    Args:
        points3d: ``(..., 18, 3)``. has_depth: ``(..., 18)``. band: metres.

    Returns:
        ``bool (..., 18)``.
    """
    f = np.asarray(has_depth, bool)
    if band <= 0:
        return f
    z = np.where(f, np.asarray(points3d, np.float64)[..., 2], np.nan)
    return f & (np.abs(z - quiet_nanmedian(z, axis=-1)[..., None]) <= band)


def match_costs(
    cands: Candidates,
    reference3d: np.ndarray,
    intrinsics: Intrinsics,
    *,
    min_keypoints: int = 3,
    depth_band: float = 0.0,
) -> np.ndarray:
    """How far each detection is from the tracked person, metres (``inf`` if not comparable).

    The smaller of two readings. Keypoint by keypoint: the median over keypoints of the 3D
    distance between the lifted keypoint and the reference keypoint where the detection has
    depth, and of the 2D distance between the keypoint and the reference's projection, times
    the reference depth over the focal length, where it has not; the median ignores a few
    wrong keypoints (detector outliers, one swapped limb). The body as a whole: the median of
    those 2D distances over all keypoints, combined (root of the sum of squares) with the
    difference between the detection's and the reference's median lifted depth over the
    keypoints both have; it holds where many keypoints are lifted off the body (a far person
    with a jittery detector: a keypoint a few pixels off a thin limb is lifted onto the wall
    behind it, in the detection and in the reference alike). Another person is a body width
    away in the image or in depth, so both readings keep them apart.

    Args:
        cands: the frame's lifted detections.
        reference3d: ``(18, 3)`` where the person was (camera frame, m), e.g. the lifted
            keypoints of its last detection; NaN rows ignored.
        intrinsics: the depth camera.
        min_keypoints: fewer comparable keypoints give ``inf``.
        depth_band: > 0: a detection's keypoints lifted further than this from its median
            lifted depth are compared in 2D (:func:`plausible_depth`).

    Returns:
        ``(P,)`` costs, m.
    """
    ref = np.asarray(reference3d, np.float64)
    fx, fy, cx, cy = (float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                         intrinsics.cy))  # fmt: skip
    ref_ok = np.isfinite(ref).all(axis=-1) & (ref[:, 2] > 0.1)
    z = np.where(ref_ok, ref[:, 2], 1.0)
    uv = np.stack([fx * ref[:, 0] / z + cx, fy * ref[:, 1] / z + cy], axis=-1)
    d3 = np.linalg.norm(cands.points3d - np.where(ref_ok[:, None], ref, 0.0)[None], axis=-1)
    d2 = np.linalg.norm(cands.keypoints2d - uv[None], axis=-1) * z[None] / (0.5 * (fx + fy))
    has_depth = plausible_depth(cands.points3d, cands.has_depth, depth_band)
    d = np.where(has_depth, d3, d2)
    usable = cands.detected & ref_ok[None]
    cost = quiet_nanmedian(np.where(usable, d, np.nan), axis=1)
    # The body as a whole: where its keypoints lie in the image, and its median depth.
    lateral = quiet_nanmedian(np.where(usable, d2, np.nan), axis=1)
    both = usable & has_depth
    z_cand = quiet_nanmedian(np.where(both, cands.points3d[..., 2], np.nan), axis=1)
    z_ref = quiet_nanmedian(np.where(both, ref[None, :, 2], np.nan), axis=1)
    body = np.hypot(lateral, np.where(both.sum(axis=1) >= min_keypoints, z_cand - z_ref, np.nan))
    cost = np.fmin(cost, body)
    return np.where(usable.sum(axis=1) >= min_keypoints, cost, np.inf)


def segment_lengths(
    points3d: np.ndarray, has_depth: np.ndarray, *, depth_band: float = PLAUSIBLE_DEPTH_BAND
) -> np.ndarray:
    """Lengths of :data:`SEGMENTS` between lifted keypoints, m; NaN where an end lacks depth
    or lies more than ``depth_band`` from the person's median lifted depth (a keypoint a few
    pixels off a far, thin limb is lifted onto the background behind it, which would make
    the segment a metre long).

    Args:
        points3d: ``(..., 18, 3)``. has_depth: ``(..., 18)``.

    Returns:
        ``(..., S)`` with S = ``len(SEGMENTS)``.
    """
    a, b = (np.array(i) for i in zip(*SEGMENTS))
    p = np.asarray(points3d, np.float64)
    f = plausible_depth(p, has_depth, depth_band)
    length = np.linalg.norm(p[..., a, :] - p[..., b, :], axis=-1)
    return np.where(f[..., a] & f[..., b], length, np.nan)


def shape_mismatch(
    lengths: np.ndarray, reference: np.ndarray, *, min_segments: int = 3
) -> np.ndarray:
    """Median over segments of ``|log(length / reference)|``; NaN when fewer than
    ``min_segments`` segments are measured in both (the test is then inconclusive).

    Args:
        lengths: ``(P, S)`` from :func:`segment_lengths`. reference: ``(S,)`` (NaN = unknown).

    Returns:
        ``(P,)``.
    """
    with np.errstate(all="ignore"):
        r = np.abs(np.log(np.asarray(lengths) / np.asarray(reference)[None]))
        r = np.where(np.isfinite(r), r, np.nan)
    out = quiet_nanmedian(r, axis=1)
    return np.where(np.isfinite(r).sum(axis=1) >= min_segments, out, np.nan)


def other_people_mask(
    depth_m: np.ndarray,
    cands: Candidates,
    keep: int,
    intrinsics: Intrinsics,
    *,
    half_width: float = 0.12,
    depth_band: float = 0.3,
    reference_depth: float | None = None,
) -> np.ndarray:
    """Pixels that show another detected person: ``bool (H, W)``.

    For every person except ``keep``, each bone between two keypoints with depth is drawn as a
    band ``half_width`` metres wide (at the bone's depth); a pixel in the band belongs to that
    person when its depth is within ``depth_band`` of the bone's. Where ``reference_depth`` (the
    tracked person's depth) is given, bones within ``depth_band`` of it are skipped: with two
    people at one depth the depth cannot tell whose pixel it is, and removing the tracked
    person's own pixels would do more harm than keeping a neighbour's.

    Args:
        depth_m: ``(H, W)`` metres. cands: the frame's detections. keep: the tracked person's
            index (-1: mask everyone). intrinsics: the depth camera.

    Returns:
        ``bool (H, W)``.
    """
    import cv2  # opencv-python-headless is a core dependency; imported here to keep start-up lean

    H, W = depth_m.shape
    f = 0.5 * (float(intrinsics.fx) + float(intrinsics.fy))
    # One label image: every drawn bone gets its own value; a pixel takes the depth band of the
    # bone drawn over it (later bones overwrite earlier ones where bands overlap).
    labels = np.zeros((H, W), np.uint16)
    lo, hi = [np.inf], [-np.inf]
    for p in range(len(cands)):
        if p == keep:
            continue
        kp, pts, ok = cands.keypoints2d[p], cands.points3d[p], cands.has_depth[p]
        for a, b in _BONES:
            if not (ok[a] and ok[b]):
                continue
            z = 0.5 * (pts[a, 2] + pts[b, 2])
            if reference_depth is not None and abs(z - reference_depth) < depth_band:
                continue
            width = max(int(round(2 * half_width * f / max(z, 0.3))), 1)
            ua, va = (int(round(float(v))) for v in kp[a])
            ub, vb = (int(round(float(v))) for v in kp[b])
            cv2.line(labels, (ua, va), (ub, vb), len(lo), thickness=width)
            lo.append(min(pts[a, 2], pts[b, 2]) - depth_band)
            hi.append(max(pts[a, 2], pts[b, 2]) + depth_band)
    if len(lo) == 1:
        return np.zeros((H, W), bool)
    d = np.asarray(depth_m, np.float64)
    return (d >= np.asarray(lo)[labels]) & (d <= np.asarray(hi)[labels]) & (d > 0)


class PersonFollower:
    """Who is followed, frame after frame: the one place that decides it.

    Holds the person's identity: the reference (the followed detection's lifted keypoints
    where it was last seen), the frames since it was updated, and the body proportions
    measured while tracked. :class:`~posetrack.Tracker` keeps one, and its body-shape pre-pass
    runs a fresh one over the first frames, so both follow by the same rules.
    """

    def __init__(self, settings: FollowSettings | None, rule: PersonRule, intrinsics: Intrinsics):
        self.settings = settings
        """None: no following, each frame's most prominent detection (the per-frame choice)."""
        self.rule = rule
        self.intrinsics = intrinsics
        self.reference: np.ndarray | None = None
        """``(18, 3)`` where the person was last seen (lifted keypoints; NaN = never with
        depth); None until a person is chosen."""
        self.since = 0
        """Frames since :attr:`reference` was updated."""
        self.lengths: list[np.ndarray] = []
        """Body segment lengths (:func:`segment_lengths`) from tracked frames."""
        self.crowd_since: int | None = None
        """Frames since one showed two or more usable detections (None: none has yet)."""
        self._new_reference = False

    @property
    def min_keypoints(self) -> int:
        return (self.settings or FollowSettings()).min_keypoints

    def signature(self) -> np.ndarray | None:
        """The person's median segment lengths, once 5 tracked frames measured them."""
        if len(self.lengths) < 5:
            return None
        return quiet_nanmedian(np.stack(self.lengths), axis=0)

    def select(self, cands: Candidates, *, reacquiring: bool = False) -> int:
        """The index of the followed person among this frame's detections, or -1.

        Args:
            cands: the frame's lifted detections.
            reacquiring: the track was dropped; a candidate must also match the body
                proportions (when they are known and measurable).
        """
        if self.settings is None:  # per-frame choice: the most prominent detection
            score = detection_score(cands.keypoints2d, cands.confidence)
            return int(np.argmax(score)) if (score > 0).any() or len(cands) == 1 else -1
        if not self.usable(cands):
            return -1
        fs = self.settings
        if self.reference is None:
            return choose_person(cands, self.rule, min_keypoints=fs.min_keypoints)
        cost = match_costs(
            cands, self.reference, self.intrinsics, min_keypoints=fs.min_keypoints,
            depth_band=fs.depth_band,
        )  # fmt: skip
        ok = cost < fs.gate_after(self.since)
        # Track dropped, nobody else seen for a while: the only person in view is the followed
        # one, and neither the gate nor the proportions refuse them.
        lone = reacquiring and self._alone(cands)
        alone = lone and not ok.any()
        if alone:
            ok = cands.usable(fs.min_keypoints)
        signature = self.signature()
        if reacquiring and not lone and signature is not None and ok.any():
            # Inconclusive (too few segments measured) is not a veto.
            mismatch = shape_mismatch(segment_lengths(cands.points3d, cands.has_depth), signature)
            ok &= ~(mismatch > fs.shape_tolerance)
        if not ok.any():
            return -1
        self._new_reference = alone  # alone: ok marks the one usable detection
        return int(np.argmax(ok)) if alone else int(np.argmin(np.where(ok, cost, np.inf)))

    def _alone(self, cands: Candidates) -> bool:
        """:attr:`FollowSettings.alone_frames`: one usable detection in this frame and none
        of the last ``alone_frames`` frames showed more."""
        n, crowd = self.settings.alone_frames, self.crowd_since
        return (
            n > 0 and cands.usable(self.min_keypoints).sum() == 1 and (crowd is None or crowd >= n)
        )

    def usable(self, cands: Candidates) -> bool:
        """Whether anyone in the frame has enough keypoints to be considered."""
        return bool(cands.usable(self.min_keypoints).any())

    def observe(self, cands: Candidates, p: int) -> None:
        """One more frame, in which detection ``p`` (-1: none) was the followed person.

        The reference moves to where the person is *seen*, not where a fit put them: a poor
        fit (a bad first initialisation, lost frames while the person walks on) must not move
        the gate off the person. But a keypoint of a half-hidden person is often lifted onto
        whoever hides it and must not drag the reference onto that person. So only keypoints
        within the gate of their reference position update it; the others (and those never
        measured) move with the median displacement of the consistent ones. With
        :attr:`FollowSettings.depth_band`, a keypoint lifted off the person's median depth
        is not seen at all (:func:`plausible_depth`), and every keypoint seen replaces its
        reference once enough are consistent.
        """
        self.since += 1
        if int(cands.usable(self.min_keypoints).sum()) >= 2:
            self.crowd_since = 0
        elif self.crowd_since is not None:
            self.crowd_since += 1
        new_reference, self._new_reference = self._new_reference, False
        if p < 0:
            return
        if new_reference:  # taken as the only person in view: start the reference afresh
            self.reference = None
        fs = self.settings or FollowSettings()
        seen_depth = plausible_depth(cands.points3d[p], cands.has_depth[p], fs.depth_band)
        lifted = np.where(seen_depth[:, None], cands.points3d[p], np.nan)
        seen = np.isfinite(lifted).all(axis=1)
        if self.reference is None:
            if seen.sum() >= self.min_keypoints:
                self.reference, self.since = lifted, 0
            return
        ref = self.reference
        known = np.isfinite(ref).all(axis=1)
        both = seen & known
        dist = np.linalg.norm(np.where(both[:, None], lifted - ref, 0.0), axis=1)
        gate = fs.gate_after(self.since)
        consistent = both & (dist < gate)
        if consistent.sum() < self.min_keypoints:
            return  # nothing trustworthy seen: the gate keeps widening
        shift = np.median(lifted[consistent] - ref[consistent], axis=0)
        update = seen if fs.depth_band > 0 else consistent | (seen & ~known)
        self.reference = np.where(update[:, None], lifted, ref + shift)
        self.since = 0

    def tracked(self, cands: Candidates, p: int) -> None:
        """Detection ``p`` was fitted and tracked: record the body's proportions."""
        if len(self.lengths) < 200:
            self.lengths.append(segment_lengths(cands.points3d[p], cands.has_depth[p]))
