"""Body geometry the tracker derives from a :class:`~posetrack.BodyShape`.

Three per-keypoint quantities used by the lifting and the landmark selection, all in metres:
how far each joint centre lies behind the body surface a depth sensor sees
(:func:`surface_offsets`), and for the geometric test of the MHT's W^g, each keypoint's
partner on one rigid part (:data:`GEOMETRY_PARTNER`), the rest distance to it
(:func:`partner_rest_lengths`) and the radius of the part between them (:func:`part_radii`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import KEYPOINT_PARENTS, BodyShape, facing_camera_params, keypoints

#: Partner keypoint of each keypoint for the geometric test: its skeleton parent; the neck, whose
#: parent is the hips' midpoint, is paired with the right hip (the neck-hip distance is rigid in
#: the model too). Every pair lies on one rigid part of the model, so its length is constant.
GEOMETRY_PARTNER: tuple[int, ...] = tuple(8 if p < 0 else p for p in KEYPOINT_PARENTS)


def surface_offsets(shape: BodyShape) -> Float[Array, " kpt"]:
    """Depth of each keypoint's joint centre behind the body surface the sensor sees, metres.

    Face keypoints (nose, eyes, ears) are on the surface (0); the others lie about one local
    part radius behind it.
    """
    z = jnp.zeros_like(shape.torso)
    sh, el, wr = (
        1.1 * shape.upper_arm_radius,
        1.1 * shape.forearm_radius,
        0.9 * shape.forearm_radius,
    )
    hip, kn, an = 1.35 * shape.thigh_radius, shape.shin_radius, 0.8 * shape.shin_radius
    neck = 0.6 * shape.torso_radius
    return jnp.stack([z, neck, sh, el, wr, sh, el, wr, hip, kn, an, hip, kn, an, z, z, z, z])


def partner_rest_lengths(shape: BodyShape) -> Float[Array, " kpt"]:
    """Distance of each keypoint from its :data:`GEOMETRY_PARTNER` in the model, metres (at
    least 3 cm, so a normalised length error never divides by ~0)."""
    rest = keypoints(shape, facing_camera_params(3.0, dtype=shape.torso.dtype))
    partner = np.asarray(GEOMETRY_PARTNER, np.int32)
    return jnp.maximum(jnp.linalg.norm(rest - rest[partner], axis=-1), 0.03)


def part_radii(shape: BodyShape) -> Float[Array, " kpt"]:
    """Radius of the body part between each keypoint and its geometry partner, metres (5 cm
    for the face keypoints, which have no modelled part)."""
    z = 0.05 * jnp.ones_like(shape.torso)
    ua, fa = shape.upper_arm_radius, shape.forearm_radius
    th, sn, to = shape.thigh_radius, shape.shin_radius, shape.torso_radius
    return jnp.stack([z, to, to, ua, fa, to, ua, fa, to, th, sn, to, th, sn, z, z, z, z])
