"""OpenPose 2D keypoint JSON files, COCO-18 and BODY_25 layouts, one file per frame.

A file looks like ``{"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d":
[x0, y0, c0, x1, y1, c1, ...], ...}, ...]}``. The layout is detected from the length of
``pose_keypoints_2d``: 54 numbers = COCO-18, 75 = BODY_25 (mapped to COCO-18 by dropping
MidHip and the six foot points; both share the COCO hips). Coordinates are pixels of the
image the detector ran on, which must be the colour image registered to depth.

Conventions of the returned arrays:

* a keypoint with confidence 0 is missing (OpenPose writes 0, 0, 0); its coordinates are set
  to 0, never NaN, so a confidence-weighted sum in jitted code stays finite;
* a file with nobody in it is a frame without observation, not an error.

Person choice when a file lists several people: the one whose ``person_id`` contains the
requested id if an id is given; otherwise the one with the largest score
``sum(confidence) * diagonal of the bounding box of its confident keypoints`` (pixels):
confident and large, i.e. near the camera. The choice is reported in ``notes``.

Keypoints outside the image (image size known): a detector often puts a joint a few pixels
past the border, so points within ``margin`` pixels (default 16) of the image are kept as
they are. Farther out, the default ``out_of_image="error"`` raises: OpenPose never puts a
joint far outside the image it saw, so this almost always means keypoints from a different
resolution (e.g. a 1920x1080 colour stream against 640x480 depth). ``out_of_image="drop"``
marks such points missing (confidence 0) and notes it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .._associate import detection_score
from ._atomic import atomic_write_text
from ._errors import InputError, format_value
from ._json import load_json, number

COCO18_NAMES = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
    "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
)  # fmt: skip
"""OpenPose COCO-18 keypoint names, in order: the library's keypoint layout."""

BODY25_NAMES = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
    "MidHip", "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar",
    "LEar", "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
)  # fmt: skip
"""OpenPose BODY_25 keypoint names, in order."""

BODY25_TO_COCO18 = np.array([BODY25_NAMES.index(name) for name in COCO18_NAMES], dtype=np.int64)
"""``coco18[i] = body25[BODY25_TO_COCO18[i]]``: [0..7, 9..18] (skips MidHip=8 and the feet)."""

_LAYOUTS = {54: "COCO-18", 75: "BODY_25"}
_INDEX = {"COCO-18": np.arange(18), "BODY_25": BODY25_TO_COCO18}
_NAMES = {"COCO-18": COCO18_NAMES, "BODY_25": BODY25_NAMES}
AMBIGUOUS_RATIO = 0.8
"""A multi-person choice is flagged ambiguous when the runner-up scores >= this x the best."""


@dataclass(frozen=True, eq=False)
class KeypointFrame:
    """2D keypoints of the chosen person in one OpenPose file, in COCO-18 order."""

    keypoints2d: np.ndarray
    """``float32 (18, 2)`` pixels (u, v); 0 where missing."""
    confidence: np.ndarray
    """``float32 (18,)``; 0 = missing."""
    layout: str | None
    """``"COCO-18"`` or ``"BODY_25"``; None when the file lists nobody."""
    num_people: int
    """Number of people the file lists."""
    person_index: int
    """Index into ``people`` of the chosen person; -1 when nobody was chosen."""
    scores: tuple[float, ...]
    """Selection score of every person (sum of confidences x bounding-box diagonal, px)."""
    ambiguous: bool = False
    """Several people and the runner-up scored >= ``AMBIGUOUS_RATIO`` x the chosen one."""
    dropped: tuple[int, ...] = ()
    """COCO-18 indices marked missing because they lay outside the image (``"drop"``)."""
    notes: tuple[str, ...] = field(default=())
    """Human-readable remarks: the person choice, dropped keypoints, person id not found."""
    people: np.ndarray = field(default_factory=lambda: np.zeros((0, 18, 3), np.float32))
    """``float32 (P, 18, 3)`` every listed person in file order, COCO-18 ``(u, v, confidence)``
    with the same out-of-image rule as the chosen one; 0 = missing. A tracker that follows
    one person through a recording chooses among these (``posetrack.Tracker``)."""

    @property
    def observed(self) -> bool:
        """A person was chosen and has at least one keypoint with confidence > 0."""
        return self.person_index >= 0 and bool(np.any(self.confidence > 0))


def _person_ids(path: Path, where: str, value: Any) -> tuple[int, ...]:
    if value is None:
        return ()
    items = value if isinstance(value, list) else [value]
    ids = []
    for k, item in enumerate(items):
        v = number(path, f"{where}[{k}]" if isinstance(value, list) else where, item)
        if v != int(v):
            raise InputError(path, where, item, "is not an integer person id")
        ids.append(int(v))
    return tuple(ids)


def _parse_person(path: Path, i: int, person: Any) -> tuple[str, np.ndarray, tuple[int, ...]]:
    """Validate one entry of ``people``; return (layout, (K, 3) array, person ids)."""
    where = f"people[{i}]"
    if not isinstance(person, dict):
        raise InputError(path, where, person, f"is {format_value(person)}; expected an object")
    if "pose_keypoints_2d" not in person:
        raise InputError(
            path,
            f"{where}.pose_keypoints_2d",
            None,
            f"is missing (keys: {', '.join(sorted(map(str, person)))})",
        )
    flat = person["pose_keypoints_2d"]
    field_name = f"{where}.pose_keypoints_2d"
    if not isinstance(flat, list):
        raise InputError(path, field_name, flat, f"is {format_value(flat)}; expected a list")
    if len(flat) not in _LAYOUTS:
        raise InputError(
            path,
            field_name,
            len(flat),
            f"has {len(flat)} numbers; expected 54 (COCO-18) or 75 (BODY_25)",
        )
    values = np.array(
        [number(path, f"{field_name}[{k}]", v) for k, v in enumerate(flat)], dtype=np.float64
    ).reshape(-1, 3)
    negative = np.flatnonzero(values[:, 2] < 0)
    if negative.size:
        k = int(negative[0])
        raise InputError(
            path, f"{field_name}[{3 * k + 2}]", values[k, 2],
            f"confidence of keypoint {k} is negative ({values[k, 2]})",
        )  # fmt: skip
    ids = _person_ids(path, f"{where}.person_id", person.get("person_id"))
    return _LAYOUTS[len(flat)], values, ids


def _check_inside(
    path: Path,
    i: int,
    xyc: np.ndarray,
    layout: str,
    image_size: tuple[int, int] | None,
    margin: float,
    out_of_image: str,
) -> tuple[np.ndarray, list[int]]:
    """Person ``i``'s (18, 3) keypoints with the out-of-image rule applied (raise or mark
    missing); missing keypoints zeroed. Returns (keypoints, dropped COCO-18 indices)."""
    xyc = xyc.copy()
    dropped: list[int] = []
    if image_size is not None:
        width, height = image_size
        lo, hi_u, hi_v = -0.5 - margin, width - 0.5 + margin, height - 0.5 + margin
        outside = (xyc[:, 2] > 0) & (
            (xyc[:, 0] < lo) | (xyc[:, 0] > hi_u) | (xyc[:, 1] < lo) | (xyc[:, 1] > hi_v)
        )
        for k in np.flatnonzero(outside):
            k = int(k)
            raw = int(_INDEX[layout][k])
            u, v = float(xyc[k, 0]), float(xyc[k, 1])
            if out_of_image == "error":
                raise InputError(
                    path,
                    f"people[{i}].pose_keypoints_2d[{3 * raw}:{3 * raw + 2}]",
                    (u, v),
                    f"keypoint {_NAMES[layout][raw]} at (u={u:g}, v={v:g}) lies outside the "
                    f"{width}x{height} image by more than {margin:g} px; keypoints from a "
                    "different image resolution? (out_of_image='drop', or --drop-outside on "
                    "the command line, marks such points missing instead)",
                )
            dropped.append(k)
            xyc[k] = 0.0
    xyc[xyc[:, 2] <= 0] = 0.0
    return xyc, dropped


def read_openpose_json(
    path: str | os.PathLike[str],
    *,
    person_id: int | None = None,
    image_size: tuple[int, int] | None = None,
    margin: float = 16.0,
    out_of_image: Literal["error", "drop"] = "error",
    scale: float = 1.0,
) -> KeypointFrame:
    """Read one OpenPose JSON file and return the chosen person in COCO-18 order.

    Args:
        path: ``<stem>_keypoints.json``.
        person_id: pick the person whose ``person_id`` contains this id; None = best score
            (see the module docstring).
        image_size: ``(width, height)`` in pixels, to check keypoints lie in the image.
        margin: pixels outside the image that are still accepted as they are.
        out_of_image: ``"error"`` (default) or ``"drop"`` (mark missing, with a note) for a
            confident keypoint farther than ``margin`` outside the image.
        scale: pixel coordinates are scaled by it before anything else, pixel centre to pixel
            centre (``(x + 0.5) * scale - 0.5``): keypoints detected on an image of another
            size than depth (2 for half-size colour).

    Returns:
        A :class:`KeypointFrame`; ``person_index == -1`` when nobody is listed or the
        requested id is absent (a frame without observation).

    Raises:
        InputError: unreadable/empty file, not JSON, not OpenPose (no ``people`` list), a
            ``pose_keypoints_2d`` that is not 54 or 75 numbers, a non-numeric, NaN or infinite
            value, a negative confidence, people of different layouts, a keypoint outside
            the image (``out_of_image="error"``).
    """
    if out_of_image not in ("error", "drop"):
        raise ValueError(f"out_of_image must be 'error' or 'drop', got {out_of_image!r}")
    path = Path(path)
    doc = load_json(path, "OpenPose")
    if not isinstance(doc, dict) or not isinstance(doc.get("people"), list):
        got = (
            f"a top-level {type(doc).__name__}"
            if not isinstance(doc, dict)
            else "no 'people' key"
            if "people" not in doc
            else f"'people' = {format_value(doc['people'])}"
        )
        raise InputError(
            path,
            "people",
            doc.get("people") if isinstance(doc, dict) else type(doc).__name__,
            f"not an OpenPose keypoint file: expected an object with a 'people' list, got {got}",
        )
    people = [_parse_person(path, i, p) for i, p in enumerate(doc["people"])]
    empty = np.zeros((18, 2), np.float32), np.zeros(18, np.float32)
    if not people:
        return KeypointFrame(*empty, layout=None, num_people=0, person_index=-1, scores=())
    layouts = {layout for layout, _v, _ids in people}
    if len(layouts) > 1:
        raise InputError(
            path, "people[*].pose_keypoints_2d", sorted(layouts),
            f"people use different layouts ({', '.join(sorted(layouts))}) in one file",
        )  # fmt: skip
    layout = people[0][0]
    coco = [values[_INDEX[layout]] for _l, values, _ids in people]
    if scale != 1.0:  # pixel centres stay centres: (x + 0.5) * scale - 0.5
        coco = [np.concatenate([(c[:, :2] + 0.5) * scale - 0.5, c[:, 2:]], axis=1) for c in coco]
    xyc_all = np.stack(coco)
    scores = tuple(float(v) for v in detection_score(xyc_all[..., :2], xyc_all[..., 2]))
    notes: list[str] = []
    ambiguous = False
    if person_id is not None:
        matches = [i for i, (_l, _v, ids) in enumerate(people) if person_id in ids]
        if not matches:
            seen = sorted({i for _l, _v, ids in people for i in ids})
            notes.append(f"{path.name}: person_id {person_id} not listed (ids: {seen})")
            return KeypointFrame(
                *empty, layout=layout, num_people=len(people), person_index=-1,
                scores=scores, notes=tuple(notes),
            )  # fmt: skip
        if len(matches) > 1:
            raise InputError(
                path, "people[*].person_id", person_id,
                f"person_id {person_id} is listed by people{matches}; ids must be unique",
            )  # fmt: skip
        chosen = matches[0]
    else:
        chosen = int(np.argmax(scores))  # first of equals: deterministic
        if len(people) > 1:
            runner_up = max(s for i, s in enumerate(scores) if i != chosen)
            ambiguous = runner_up >= AMBIGUOUS_RATIO * scores[chosen]
            notes.append(
                f"{path.name}: {len(people)} people, chose people[{chosen}] (score "
                f"{scores[chosen]:.0f} vs runner-up {runner_up:.0f}"
                + (", AMBIGUOUS)" if ambiguous else ")")
            )
    cleaned, dropped = [], []
    for i, raw_xyc in enumerate(coco):
        xyc_i, dropped_i = _check_inside(path, i, raw_xyc, layout, image_size, margin, out_of_image)
        cleaned.append(xyc_i)
        if dropped_i:
            names = ", ".join(COCO18_NAMES[k] for k in dropped_i)
            who = "" if len(coco) == 1 else f"people[{i}]: "
            notes.append(f"{path.name}: {who}dropped keypoints outside the image: {names}")
        if i == chosen:
            dropped = dropped_i
    everyone = np.stack(cleaned).astype(np.float32)
    xyc = everyone[chosen].copy()
    missing = xyc[:, 2] <= 0
    xyc[missing] = 0.0
    return KeypointFrame(
        keypoints2d=xyc[:, :2].astype(np.float32),
        confidence=xyc[:, 2].astype(np.float32),
        layout=layout,
        num_people=len(people),
        person_index=chosen,
        scores=scores,
        ambiguous=ambiguous,
        dropped=tuple(dropped),
        notes=tuple(notes),
        people=everyone,
    )


def write_openpose_json(
    path: str | os.PathLike[str],
    keypoints2d: np.ndarray,
    confidence: np.ndarray,
    *,
    person_ids: list[int] | None = None,
) -> None:
    """Write COCO-18 keypoints as an OpenPose JSON file, atomically.

    Args:
        path: destination, conventionally ``<frame:06d>_keypoints.json``.
        keypoints2d: ``(18, 2)`` pixels for one person, or ``(P, 18, 2)`` for P people
            (P may be 0: a frame with nobody).
        confidence: ``(18,)`` or ``(P, 18)``, >= 0; 0 = missing (written as 0, 0, 0 whatever
            the coordinates, which may then be NaN).
        person_ids: one id per person (OpenPose writes -1 when not tracking); default -1.

    Raises:
        ValueError: shapes disagree, a negative or non-finite confidence, or a non-finite
            coordinate where the confidence is > 0.
    """
    kp = np.asarray(keypoints2d, dtype=np.float64)
    conf = np.asarray(confidence, dtype=np.float64)
    if kp.ndim == 2:
        kp, conf = kp[None], conf[None]
    if kp.ndim != 3 or kp.shape[1:] != (18, 2) or conf.shape != kp.shape[:2]:
        raise ValueError(
            "write_openpose_json: expected keypoints2d (18, 2) or (P, 18, 2) and confidence "
            f"(18,) or (P, 18), got {np.shape(keypoints2d)} and {np.shape(confidence)}"
        )
    if not np.all(np.isfinite(conf)) or np.any(conf < 0):
        bad = np.argwhere(~np.isfinite(conf) | (conf < 0))[0]
        raise ValueError(
            f"write_openpose_json: confidence{list(bad)} = {conf[tuple(bad)]}; expected >= 0"
        )
    present = conf > 0
    if not np.all(np.isfinite(kp[present])):
        bad = np.argwhere(present[..., None] & ~np.isfinite(kp))[0]
        raise ValueError(
            f"write_openpose_json: keypoints2d{list(bad)} = {kp[tuple(bad)]} with confidence > 0"
        )
    if person_ids is None:
        person_ids = [-1] * len(kp)
    if len(person_ids) != len(kp):
        raise ValueError(f"write_openpose_json: {len(person_ids)} person_ids for {len(kp)} people")
    people = []
    for p in range(len(kp)):
        xyc = np.concatenate([np.where(present[p, :, None], kp[p], 0.0), conf[p, :, None]], 1)
        people.append(
            {
                "person_id": [int(person_ids[p])],
                "pose_keypoints_2d": [float(v) for v in xyc.reshape(-1)],
                "face_keypoints_2d": [],
                "hand_left_keypoints_2d": [],
                "hand_right_keypoints_2d": [],
                "pose_keypoints_3d": [],
                "face_keypoints_3d": [],
                "hand_left_keypoints_3d": [],
                "hand_right_keypoints_3d": [],
            }
        )
    atomic_write_text(path, json.dumps({"version": 1.3, "people": people}))
