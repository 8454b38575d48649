"""The generator's own body: skeleton, random subject dimensions and surface primitives.

This is deliberately NOT the tracker's body model (``posetrack._body``): the surface is made of
ellipsoids (pelvis, abdomen, chest, head, nose, hands, feet) and tapered capsules ("round
cones": the convex hull of two spheres of different radii) for the neck and limbs, and every
dimension is drawn per subject. The tracker's capsules can therefore never fit it exactly, as
with a real person.

Body frame of every segment at rest: x = subject's left, y = up, z = subject's forward
(right-handed). Limbs hang along -y at rest. World frame: the same axes with the floor at
y = 0. Metres throughout.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

SEGMENTS: tuple[str, ...] = (
    "pelvis", "abdomen", "chest", "neck", "head",
    "r_clavicle", "r_upper_arm", "r_forearm", "r_hand",
    "l_clavicle", "l_upper_arm", "l_forearm", "l_hand",
    "r_thigh", "r_shank", "r_foot",
    "l_thigh", "l_shank", "l_foot",
)  # fmt: skip
"""Segment names; index = position. The root is the pelvis."""

PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 2, 5, 6, 7, 2, 9, 10, 11, 0, 13, 14, 0, 16, 17)
SEG = {name: i for i, name in enumerate(SEGMENTS)}

KEYPOINT_NAMES: tuple[str, ...] = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
    "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
)  # fmt: skip
"""OpenPose COCO-18 keypoint order (R = the subject's right)."""

N_KPT = 18
# Parent keypoint of each COCO-18 keypoint (for bone lengths and plausible hallucinations).
KPT_PARENT: tuple[int, ...] = (1, -1, 1, 2, 3, 1, 5, 6, 1, 8, 9, 1, 11, 12, 0, 0, 14, 15)
# Left/right pairs (right index, left index).
LR_PAIRS: tuple[tuple[int, int], ...] = ((2, 5), (3, 6), (4, 7), (8, 11), (9, 12), (10, 13),
                                         (14, 15), (16, 17))


@dataclasses.dataclass(frozen=True)
class Ellipsoid:
    """Ellipsoid attached to segment ``seg``: centre and semi-axes (m) in the segment frame."""

    name: str
    seg: int
    centre: tuple[float, float, float]
    radii: tuple[float, float, float]
    group: str


@dataclasses.dataclass(frozen=True)
class RoundCone:
    """Tapered capsule: convex hull of spheres (a, ra) and (b, rb), points in segment frame."""

    name: str
    seg: int
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    ra: float
    rb: float
    group: str


Primitive = Ellipsoid | RoundCone


@dataclasses.dataclass(frozen=True)
class BodyVariation:
    """Extra per-subject changes on top of :func:`sample_subject`'s own draw (the "wide"
    variety of ``generate``). The defaults change nothing."""

    girth: float = 1.0
    """Multiplier on the girth scale: every part radius and the torso's width and depth."""
    upper_arm: float = 1.0
    """Multiplier on the upper-arm length (both sides)."""
    forearm: float = 1.0
    """Multiplier on the forearm length."""
    thigh: float = 1.0
    """Multiplier on the thigh length."""
    shank: float = 1.0
    """Multiplier on the shank length."""
    shoulder_width: float = 1.0
    """Multiplier on the distance between the shoulder joints."""
    hip_width: float = 1.0
    """Multiplier on the distance between the hip joints."""
    shoulder_drop: float = 0.0
    """Shoulder joints this far below the neck keypoint (0: level with it), m."""
    torso_shift: float = 0.0
    """Pelvis, abdomen and chest surfaces moved this far forward (+z; negative: backward)
    relative to the skeleton, so the hip and shoulder joints sit deeper or shallower inside
    the body, m."""


@dataclasses.dataclass(frozen=True)
class Subject:
    """One synthetic person: bone offsets, surface primitives and keypoint definitions.

    Build with :func:`sample_subject`. All lengths in metres.
    """

    height: float
    """Standing height (floor to top of head), m."""
    build: float
    """Girth multiplier (1 = average; ~0.85 slim ... 1.25 heavy)."""
    offsets: np.ndarray
    """(S, 3) origin of each segment in its parent's frame (root row unused), m."""
    primitives: tuple[Primitive, ...]
    """Surface pieces, ray-cast exactly by :mod:`._surface`."""
    kpt_seg: np.ndarray
    """(18,) segment index of each COCO-18 keypoint."""
    kpt_local: np.ndarray
    """(18, 3) keypoint position in its segment frame, m."""
    kpt_radius: np.ndarray
    """(18,) body radius around each keypoint (visibility tolerance), m."""
    kpt_own: tuple[frozenset[int], ...]
    """Per keypoint: primitive indices that count as "the joint itself" for visibility."""
    foot_sole: np.ndarray
    """(2, 2, 3) heel and toe sole points of (right, left) foot in the foot frame, m."""
    colors: dict[str, tuple[int, int, int]]
    """RGB albedo per primitive group."""
    dims: dict[str, float]
    """Named dimensions (for reports and ``SyntheticSequence.subject``)."""

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the dimensions (m) and colours."""
        out: dict[str, Any] = {"height": self.height, "build": self.build}
        out.update(self.dims)
        out["colors"] = {k: list(v) for k, v in self.colors.items()}
        return out


def _surface_y(r: tuple[float, float, float], x: float, y: float) -> float:
    """z on the front of an ellipsoid with semi-axes r at (x, y) relative to its centre."""
    v = 1.0 - (x / r[0]) ** 2 - (y / r[1]) ** 2
    return r[2] * float(np.sqrt(max(v, 0.0)))


def sample_subject(rng: np.random.Generator, *,
                   variation: BodyVariation | None = None) -> Subject:
    """Draw a random adult: height U(1.55, 1.95) m, proportions and girth varied.

    Proportions follow Drillis & Contini segment ratios with per-bone jitter (~3.5 %), a
    shoulder/hip "shape" factor and a girth multiplier; head size scales weakly with height.

    Args:
        rng: randomness (the draws are the same with or without ``variation``).
        variation: further changes applied to the drawn dimensions (None: none). Recorded in
            ``dims`` (``variation_*`` entries) when given.
    """
    H = float(rng.uniform(1.55, 1.95))
    build = float(np.clip(rng.normal(1.03, 0.11), 0.85, 1.3))
    shape = float(rng.uniform(-1.0, 1.0))  # +1 broad shoulders/narrow hips, -1 the reverse

    def j(sd: float = 0.035) -> float:
        return float(np.clip(rng.normal(1.0, sd), 1 - 2.5 * sd, 1 + 2.5 * sd))

    g = build * (H / 1.75) ** 0.5  # girth scale
    gh = (H / 1.75) ** 0.3  # head scale
    d = {
        "ankle_height": 0.039 * H * j(0.05),
        "shank": 0.246 * H * j(),
        "thigh": 0.245 * H * j(),
        "hip_half_width": 0.052 * H * j(0.05) * (1 - 0.07 * shape) * build**0.3,
        "pelvis_up": 0.035 * H,
        "lumbar": 0.065 * H * j(0.05),
        "thorax": 0.100 * H * j(0.05),
        "neck_base": 0.080 * H * j(0.05),
        "neck": 0.055 * H * j(0.08),
        "shoulder_half_width": 0.098 * H * j(0.04) * (1 + 0.07 * shape) * build**0.2,
        "upper_arm": 0.172 * H * j(),
        "forearm": 0.146 * H * j(),
        "hand": 0.108 * H * j(0.05),
        "foot": 0.152 * H * j(0.04),
    }
    v = variation
    if v is not None:
        g *= v.girth
        for name in ("upper_arm", "forearm", "thigh", "shank"):
            d[name] *= getattr(v, name)
        d["shoulder_half_width"] *= v.shoulder_width
        d["hip_half_width"] *= v.hip_width
    S = len(SEGMENTS)
    off = np.zeros((S, 3))
    off[SEG["abdomen"]] = (0, d["lumbar"], 0)
    off[SEG["chest"]] = (0, d["thorax"], 0)
    off[SEG["neck"]] = (0, d["neck_base"], -0.015)
    off[SEG["head"]] = (0, d["neck"], 0.012)
    for side, sx in (("r", -1.0), ("l", 1.0)):
        off[SEG[f"{side}_clavicle"]] = (0, d["neck_base"], -0.015)
        off[SEG[f"{side}_upper_arm"]] = (sx * d["shoulder_half_width"],
                                         -v.shoulder_drop if v is not None else 0, 0)
        off[SEG[f"{side}_forearm"]] = (0, -d["upper_arm"], 0)
        off[SEG[f"{side}_hand"]] = (0, -d["forearm"], 0)
        off[SEG[f"{side}_thigh"]] = (sx * d["hip_half_width"], -d["pelvis_up"], 0)
        off[SEG[f"{side}_shank"]] = (0, -d["thigh"], 0)
        off[SEG[f"{side}_foot"]] = (0, -d["shank"], 0)

    belly = g * build**0.7  # heavier people grow more in depth at the belly
    hr = (0.077 * gh * j(0.04), 0.113 * gh * j(0.04), 0.097 * gh * j(0.04))
    hc = (0.0, 0.095 * gh, 0.012)
    dz = v.torso_shift if v is not None else 0.0
    prims: list[Primitive] = [
        Ellipsoid("pelvis", SEG["pelvis"], (0, -0.02, -0.01 + dz),
                  (0.160 * g * (1 - 0.05 * shape), 0.11 * g**0.5, 0.105 * g), "trousers"),
        Ellipsoid("abdomen", SEG["abdomen"], (0, 0.065, 0.004 * belly + dz),
                  (0.140 * g, 0.155, 0.098 * belly), "shirt"),
        Ellipsoid("chest", SEG["chest"], (0, 0.035, -0.005 + dz),
                  (0.156 * g * (1 + 0.05 * shape), 0.155, 0.106 * g), "shirt"),
        RoundCone("neck", SEG["neck"], (0, 0, 0), (0, d["neck"], 0.012),
                  0.058 * g**0.6, 0.050 * g**0.5, "skin"),
        Ellipsoid("head", SEG["head"], hc, hr, "skin"),
        Ellipsoid("nose", SEG["head"], (0, hc[1] - 0.018, hc[2] + hr[2] * 0.90),
                  (0.013, 0.022, 0.022), "skin"),
    ]
    L = d["ankle_height"]
    foot_r = (0.043 * g**0.3, 0.55 * L + 0.004, 0.5 * d["foot"])
    foot_c_z = -0.2 * d["foot"] + foot_r[2]
    for side, sx in (("r", -1.0), ("l", 1.0)):
        prims += [
            RoundCone(f"{side}_upper_arm", SEG[f"{side}_upper_arm"], (0, 0, 0),
                      (0, -d["upper_arm"], 0), 0.050 * g, 0.037 * g, "shirt"),
            RoundCone(f"{side}_forearm", SEG[f"{side}_forearm"], (0, 0, 0),
                      (0, -d["forearm"], 0), 0.037 * g, 0.026 * g**0.7, "skin"),
            Ellipsoid(f"{side}_hand", SEG[f"{side}_hand"], (0, -0.45 * d["hand"], 0.005),
                      (0.020 * g**0.5, 0.48 * d["hand"], 0.045 * g**0.3), "skin"),
            RoundCone(f"{side}_thigh", SEG[f"{side}_thigh"], (0, 0, 0), (0, -d["thigh"], 0),
                      0.082 * g, 0.050 * g, "trousers"),
            RoundCone(f"{side}_shank", SEG[f"{side}_shank"], (0, 0, 0), (0, -d["shank"], 0),
                      0.049 * g, 0.031 * g**0.7, "trousers"),
            Ellipsoid(f"{side}_foot", SEG[f"{side}_foot"],
                      (0, -L + foot_r[1], foot_c_z), foot_r, "shoes"),
        ]
    names = [p.name for p in prims]
    P = {n: i for i, n in enumerate(names)}

    # COCO-18 keypoints: joint centres inside the body; face points on the head surface.
    kseg = np.zeros(N_KPT, dtype=np.int64)
    kloc = np.zeros((N_KPT, 3))
    krad = np.zeros(N_KPT)
    kown: list[frozenset[int]] = [frozenset()] * N_KPT
    eye_x, eye_y = 0.032 * gh, 0.022 * gh
    ear_z = -0.012
    face = {
        0: (0, hc[1] - 0.028, hc[2] + hr[2] * 0.90 + 0.018),  # nose tip
        14: (-eye_x, hc[1] + eye_y, hc[2] + _surface_y(hr, eye_x, eye_y) - 0.008),
        15: (eye_x, hc[1] + eye_y, hc[2] + _surface_y(hr, eye_x, eye_y) - 0.008),
        16: (-hr[0] * float(np.sqrt(1 - (ear_z / hr[2]) ** 2)), hc[1], hc[2] + ear_z),
        17: (hr[0] * float(np.sqrt(1 - (ear_z / hr[2]) ** 2)), hc[1], hc[2] + ear_z),
    }
    for k, p in face.items():
        kseg[k], kloc[k], krad[k] = SEG["head"], p, 0.012
        kown[k] = frozenset({P["head"], P["nose"]})
    kseg[1], krad[1] = SEG["neck"], 0.07 * g
    kown[1] = frozenset({P["neck"], P["chest"], P["head"]})
    for side, (sh, el, wr, hp, kn, an) in (("r", (2, 3, 4, 8, 9, 10)),
                                           ("l", (5, 6, 7, 11, 12, 13))):
        kseg[sh], krad[sh] = SEG[f"{side}_upper_arm"], 0.055 * g
        kseg[el], krad[el] = SEG[f"{side}_forearm"], 0.040 * g
        kseg[wr], krad[wr] = SEG[f"{side}_hand"], 0.030 * g
        kseg[hp], krad[hp] = SEG[f"{side}_thigh"], 0.085 * g
        kseg[kn], krad[kn] = SEG[f"{side}_shank"], 0.052 * g
        kseg[an], krad[an] = SEG[f"{side}_foot"], 0.035 * g
        kown[sh] = frozenset({P[f"{side}_upper_arm"], P["chest"]})
        kown[el] = frozenset({P[f"{side}_upper_arm"], P[f"{side}_forearm"]})
        kown[wr] = frozenset({P[f"{side}_forearm"], P[f"{side}_hand"]})
        kown[hp] = frozenset({P[f"{side}_thigh"], P["pelvis"]})
        kown[kn] = frozenset({P[f"{side}_thigh"], P[f"{side}_shank"]})
        kown[an] = frozenset({P[f"{side}_shank"], P[f"{side}_foot"]})
    sole = np.zeros((2, 2, 3))
    for i in range(2):
        sole[i, 0] = (0, -L, -0.2 * d["foot"] + 0.03)
        sole[i, 1] = (0, -L, 0.8 * d["foot"] - 0.03)

    skin = [(224, 172, 140), (198, 134, 96), (141, 85, 54), (236, 195, 165), (170, 110, 75)]
    palette = [(40, 70, 160), (170, 40, 40), (60, 130, 70), (200, 180, 60), (120, 120, 130),
               (230, 230, 225), (30, 30, 35), (150, 80, 150)]
    trousers = [(40, 45, 70), (25, 25, 30), (90, 85, 75), (60, 80, 120), (110, 70, 40)]
    colors = {
        "skin": skin[int(rng.integers(len(skin)))],
        "shirt": palette[int(rng.integers(len(palette)))],
        "trousers": trousers[int(rng.integers(len(trousers)))],
        "shoes": (int(rng.integers(20, 200)),) * 3,
        "hair": [(25, 20, 15), (70, 45, 25), (150, 110, 60), (110, 110, 105)][
            int(rng.integers(4))],
    }
    dims = dict(d)
    dims["girth_scale"] = g
    dims["shape"] = shape
    if v is not None:
        dims.update({f"variation_{k}": float(x) for k, x in dataclasses.asdict(v).items()})
    return Subject(
        height=H, build=build, offsets=off, primitives=tuple(prims), kpt_seg=kseg,
        kpt_local=kloc, kpt_radius=krad, kpt_own=tuple(kown), foot_sole=sole,
        colors=colors, dims=dims,
    )


def forward_kinematics(subject: Subject, root: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Segment origins from global segment rotations.

    Args:
        subject: whose bone offsets to use.
        root: (T, 3) world position of the pelvis origin, m.
        rotations: (T, S, 3, 3) world rotation of every segment (R_world_seg).

    Returns:
        (T, S, 3) world position of every segment origin, m. Bone lengths are the subject's
        by construction, whatever the rotations.
    """
    T = root.shape[0]
    pos = np.zeros((T, len(SEGMENTS), 3))
    pos[:, 0] = root
    for s in range(1, len(SEGMENTS)):
        p = PARENTS[s]
        pos[:, s] = pos[:, p] + rotations[:, p] @ subject.offsets[s]
    return pos


def local_to_global(local: np.ndarray) -> np.ndarray:
    """Chain local rotations (T, S, 3, 3) (R_parent_seg; root = R_world_pelvis) to global."""
    out = np.empty_like(local)
    out[:, 0] = local[:, 0]
    for s in range(1, len(SEGMENTS)):
        out[:, s] = out[:, PARENTS[s]] @ local[:, s]
    return out


def keypoints_world(subject: Subject, origins: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """COCO-18 ground-truth keypoints (T, 18, 3), world frame, m."""
    R = rotations[:, subject.kpt_seg]  # (T, 18, 3, 3)
    return origins[:, subject.kpt_seg] + np.einsum("tkij,kj->tki", R, subject.kpt_local)


def sole_points(subject: Subject, origins: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(T, 2 feet (R, L), 2 (heel, toe), 3) world sole points, m."""
    out = []
    for i, seg in enumerate((SEG["r_foot"], SEG["l_foot"])):
        out.append(origins[:, seg, None] + np.einsum("tij,pj->tpi", rotations[:, seg],
                                                      subject.foot_sole[i]))
    return np.stack(out, axis=1)
