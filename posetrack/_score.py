"""The depth discrepancy Delta of Eq. (3) of the paper, for soft or binary maps.

This module is Eq. (3) only: it compares maps. Rendering the hypotheses and scoring them
without storing their depth maps (``render_and_score``) is in ``_render.py``.

Eq. (3):  Delta = lambda * sum_{P_i} min(|z_d - r_d|, d_M) / (d_M |P_i|) + (1 - lambda),
with P_i = z_fg AND r_fg, P_u = z_fg OR r_fg and lambda = |P_i| / |P_u|.

Since lambda / |P_i| = 1 / |P_u|, this is the same as

    Delta = 1 - sum_p i_p * (1 - min(|z_d - r_d|, d_M) / d_M) / |P_u|,

which is what we compute: it needs no division by |P_i| (an empty intersection with a non-empty
union gives exactly 1, not 0/0), and the only guard left is |P_u| = 0 (no foreground in the
observation nor in the rendering), defined as Delta = 1 (nothing explained).

Soft foregrounds: with values in [0, 1] the pixel memberships are the product
``i_p = z_fg * r_fg`` (AND) and the probabilistic OR ``u_p = z_fg + r_fg - z_fg * r_fg``; both
reduce to the set operations of the paper on binary maps, and both are smooth, so Delta is
differentiable with respect to a soft rendering.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

DEFAULT_D_M = 0.15
"""Default depth-difference clamp ``d_M`` of Eq. (3), metres. It must exceed the sensor noise
(Kinect: sigma ~1.3 cm at 3 m, ~2.3 cm at 4 m) plus the misfit of a right pose with an
approximate body shape (a few cm), so a good hypothesis is not penalised for them; and it must be
below the thickness of a limb or torso (10-30 cm), so a limb rendered in front of (or behind) the
surface actually observed there costs the full penalty. The hand tracker the paper builds on
uses 4 cm for hands; a body is roughly 4x larger."""


def delta_sums(z_d, z_fg, r_d, r_fg, d_M) -> tuple[Array, Array]:
    """(sum of i_p * match_p, |P_u|) over the pixels of (partial) maps; see the module
    docstring. Sums over disjoint pixel sets add up, so a tiled renderer can accumulate them
    and finish with :func:`delta_from_sums`."""
    inter = z_fg * r_fg
    union = z_fg + r_fg - inter
    match = 1.0 - jnp.minimum(jnp.abs(z_d - r_d), d_M) / d_M
    return jnp.sum(inter * match), jnp.sum(union)


def delta_from_sums(matched: Array, union: Array) -> Array:
    """Delta from the two sums of :func:`delta_sums`: ``1 - matched / |P_u|``, and 1 where
    ``|P_u| = 0``."""
    # Safe where: |P_u| = 0 means no foreground anywhere; Delta = 1 there, and the division
    # must not run (0/0 would be NaN in the value and in the gradient of the other branch).
    ok = union > 0.0
    return jnp.where(ok, 1.0 - matched / jnp.where(ok, union, 1.0), 1.0)


def sanitize_observation(z_d: Array, z_fg: Array) -> tuple[Array, Array]:
    """Observation with non-finite values zeroed: off the foreground they cannot count; on it
    (never produced by :func:`observation_maps`) they count as a full ``d_M`` mismatch."""
    z_fg = jnp.where(jnp.isfinite(z_fg), z_fg, 0.0)
    z_d = jnp.where(jnp.isfinite(z_d) & (z_fg > 0.0), z_d, 0.0)
    return z_d, z_fg


def delta(
    z_d: Float[Array, "H W"],
    z_fg: Float[Array, "H W"],
    r_d: Float[Array, "H W"],
    r_fg: Float[Array, "H W"],
    *,
    d_M: float | Array = DEFAULT_D_M,
) -> Float[Array, ""]:
    """Delta of Eq. (3) of the paper between an observation and one rendered hypothesis.

    Args:
        z_d: observed depth, metres (any value, also NaN, where ``z_fg`` is 0).
        z_fg: observed foreground in [0, 1] (binary from :func:`observation_maps`).
        r_d: rendered depth, metres (finite everywhere, as :func:`render_depth` gives it).
        r_fg: rendered foreground in [0, 1].
        d_M: depth-difference clamp, metres (see ``DEFAULT_D_M``).

    Returns:
        Delta in [0, 1]: 0 for a perfect match, 1 for disjoint foregrounds or no foreground.
    """
    z_d, z_fg = sanitize_observation(z_d, z_fg)
    matched, union = delta_sums(z_d, z_fg, r_d, r_fg, d_M)
    return delta_from_sums(matched, union)


def delta_batch(
    z_d: Float[Array, "H W"],
    z_fg: Float[Array, "H W"],
    r_d: Float[Array, "hyp H W"],
    r_fg: Float[Array, "hyp H W"],
    *,
    d_M: float | Array = DEFAULT_D_M,
) -> Float[Array, " hyp"]:
    """:func:`delta` over the leading ``hyp`` axis of the rendered maps (one observation)."""
    z_d, z_fg = sanitize_observation(z_d, z_fg)
    return jax.vmap(lambda d, f: delta_from_sums(*delta_sums(z_d, z_fg, d, f, d_M)))(r_d, r_fg)
