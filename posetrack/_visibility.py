"""Self-occlusion: 3D landmarks the body model says cannot be what the depth camera saw.

A keypoint is lifted to 3D at the depth measured around its detected pixel (``_observe.py``).
Where another part of the body lies in front of the joint on that pixel's ray (the far arm
behind the torso in a side view, the far ear behind the head), the depth is the occluder's
front surface, 20-30 cm too close to the camera, and the 3D residual of Eq. (1) pulls the
joint onto it. The paper's flag F_i only asks whether depth is valid there.

:func:`self_occluded` casts rays against the capsules of a reference pose (the previous
output) in closed form (``_render.capsule_fields``) and flags a landmark when all three hold:

(a) on the ray through the model's joint, a part that does not hold the joint lies more than
    ``margin`` in front of it (the model says the joint is hidden);
(b) the surface the sensor saw (the landmark less its surface offset) lies more than
    ``margin`` in front of the model's joint;
(c) on the ray through the detected keypoint, that surface lies within ``tolerance`` of the
    model's hiding part (the observation is explained by the occluder).

(c) is the way back from a wrong model: an arm the model holds behind the torso while the
real one is in front of it is seen well in front of the torso's surface, so its landmark stays
and pulls the arm out. (b) alone (tried: ``benchmarks/README.md``) dropped the landmarks of
every fast motion toward the camera and locked poses in; (a) with (b), without (c), locked in
after a detector's outliers had put the model's arm behind the torso.

How the tracker uses it (``TrackerConfig.occlusion_gate``, off by default): every other
hypothesis leaves the flagged 3D landmarks out and fits their 2D detections instead (the
detection is still evidence across the image plane); the other hypotheses keep them, and
Delta decides. Taking them from every hypothesis locked wrong poses in even with (c). Not in
the paper.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from . import _body as body
from ._body import NUM_KEYPOINTS
from ._camera import Intrinsics, backproject
from ._metrics import LEG_PAIRS, LIMB_PAIRS
from ._observe import Landmarks
from ._render import Capsules, capsule_fields, capsule_params
from ._rotation import quat_normalize, quat_to_matrix


def self_occluded(
    shape: body.BodyShape,
    params: Float[Array, 43],
    landmarks: Landmarks,
    intrinsics: Intrinsics,
    offsets: Float[Array, " kpt"] | float,
    margin: float | Array,
    tolerance: float | Array,
) -> Bool[Array, " kpt"]:
    """Which 3D landmarks the pose ``params`` says are the surface of a body part hiding the
    joint.

    Args:
        shape: body dimensions.
        params: (43,) the reference pose (the previous frame's output).
        landmarks: this frame's lifted landmarks.
        intrinsics: the camera the keypoints were detected in.
        offsets: the depth each landmark was pushed back from the surface at lifting (metres,
            ``_geometry.surface_offsets`` or 0).
        margin: metres; the hiding surface and the landmark must lie this far in front of the
            model's joint.
        tolerance: metres; the seen surface must lie within this of the hiding part's surface
            on the detection's ray (else something else, the limb itself, was seen).

    Returns:
        (18,) True where the landmark has depth and all three tests hold (module docstring).
    """
    a, b, radius = body.capsules(shape, params)
    caps = capsule_params(Capsules(a=a, b=b, radius=radius))
    joints = body.keypoints(shape, params)
    # Rays through the model's joints and through the detected keypoints (z = 1).
    ray_det = backproject(intrinsics, landmarks.keypoints2d, jnp.ones_like(landmarks.confidence))
    rays = jnp.stack([joints / jnp.maximum(joints[:, 2:], 1e-3), ray_det])  # (2, kpt, 3)
    p = {k: v[None, None, :] for k, v in caps.items()}
    delta, z = capsule_fields(rays[..., 0:1], rays[..., 1:2], p)  # (2, kpt, capsule)
    # A capsule that holds the joint (its own limb, the torso around a hip) is not in front
    # of it: only the other parts can hide it.
    seg = b - a
    s = jnp.clip(
        jnp.einsum("kpc,pc->kp", joints[:, None, :] - a[None], seg) * caps["inv_dd"][None, :],
        0.0, 1.0,
    )  # fmt: skip
    gap = jnp.linalg.norm(joints[:, None, :] - (a[None] + s[..., None] * seg[None]), axis=-1)
    other = gap > radius[None, :]
    front = jnp.min(jnp.where((delta < 0.0) & other[None], z, jnp.inf), axis=-1)  # (2, kpt)
    joint_z = joints[:, 2]
    seen = landmarks.points3d[:, 2] - offsets  # the surface the sensor saw
    hidden = front[0] < joint_z - margin
    in_front = seen < joint_z - margin
    explained = jnp.abs(seen - front[1]) < tolerance
    return landmarks.has_depth & hidden & in_front & explained


#: A pose is a side view when its right-to-left direction (shoulders and hips) points this
#: far along the viewing axis: sin 30 degrees of turn away from facing the camera.
SIDE_VIEW_SIN = 0.5


#: Shoulders and hips, (right, left) COCO-18 indices: the torso's far-side keypoints
#: (:func:`far_side` with ``torso=True``).
TORSO_PAIRS: tuple[tuple[int, int], ...] = ((2, 5), (8, 11))


def turn_sine(params: Float[Array, 43]) -> Float[Array, ""]:
    """The sine of the pose's turn away from facing the camera: the camera-z part of the
    pelvis' right-to-left axis (the root frame's x), positive when the right side lies behind
    the left. Jittable."""
    return -quat_to_matrix(quat_normalize(params[3:7]))[2, 0]


def far_side(
    params: Float[Array, 43], torso: bool = False, sin: Float[Array, ""] | float = SIDE_VIEW_SIN
) -> Bool[Array, " kpt"]:
    """The elbow, wrist, knee and ankle (``LIMB_PAIRS``) of the side a pose turns away from
    the camera; with ``torso`` (static) its shoulder and hip too (:data:`TORSO_PAIRS`).

    In a side view the far limbs hang behind the torso, and the depth on their keypoints'
    pixels is the near side's surface. The model's torso is rigid, so the shoulders' and
    hips' right-to-left direction is the root's x axis: its camera-z component is the depth
    the right side lies behind the left per metre of width (the sine of the turn). Above
    ``sin`` (default :data:`SIDE_VIEW_SIN`; may be traced) the right limbs are flagged,
    below its negative the left ones; nothing in between (a person facing the camera, or
    away). Jittable.
    """
    turned = turn_sine(params)
    pairs = LIMB_PAIRS + (TORSO_PAIRS if torso else ())
    right, left = (jnp.asarray(side) for side in zip(*pairs, strict=True))
    flags = jnp.zeros(NUM_KEYPOINTS, bool).at[right].set(turned > sin)
    return flags.at[left].set(turned < -sin)


#: The eyes and ears, (right, left) keypoint indices.
FACE_PAIRS: tuple[tuple[int, int], ...] = ((14, 15), (16, 17))
#: The neck's keypoint index.
NECK = 1


def side_view_bounds(
    params: Float[Array, 43], sin: Float[Array, ""] | float = SIDE_VIEW_SIN, legs: bool = False
) -> Bool[Array, " kpt"]:
    """The keypoints whose pixels show a surface in front of the joint in a side view (as
    :func:`far_side` decides one): the far side's shoulder, elbow, wrist, hip, eye and ear,
    and the neck, which then lines up behind the near shoulder; with ``legs`` (static) the
    far knee and ankle too. Their lifted depth is a bound (:func:`posetrack._observe.
    as_bounds`, ``TrackerConfig.far_side_bound``). ``sin``: as :func:`far_side`'s. Jittable.

    The legs are left out by default: in side views of walking and turning the far knee and
    ankle are seen between the legs and lifted within 13 mm of the joint (median), while the
    far shoulder, elbow and hip are lifted 17-35 cm too close (benchmarks/README.md, "Which
    far-side landmarks are wrong in a side view")."""
    flags = far_side(params, torso=True, sin=sin)
    right_far, left_far = flags[TORSO_PAIRS[0][0]], flags[TORSO_PAIRS[0][1]]
    right, left = (jnp.asarray(side) for side in zip(*FACE_PAIRS, strict=True))
    flags = flags.at[right].set(right_far).at[left].set(left_far)
    if not legs:
        flags = flags.at[jnp.asarray([k for pair in LEG_PAIRS for k in pair])].set(False)
    return flags.at[NECK].set(right_far | left_far)
