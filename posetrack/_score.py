"""The depth discrepancy Delta of Eq. (3) of the paper, soft and batched over hypotheses.

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

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._camera import Intrinsics
from ._render import (
    DEFAULT_SHARPNESS,
    Capsules,
    _acc_add_group,
    _acc_final,
    _acc_init,
    _as_sharpness,
    _capsule_fields,
    _check_capsules,
    _prim_params,
    _ray_grid,
    _render_one,
)

DEFAULT_D_M = 0.15
"""Default depth-difference clamp ``d_M`` of Eq. (3), metres. It must exceed the sensor noise
(Kinect: sigma ~1.3 cm at 3 m, ~2.3 cm at 4 m) plus the misfit of a right pose with an
approximate body shape (a few cm), so a good hypothesis is not penalised for them; and it must be
below the thickness of a limb or torso (10-30 cm), so a limb rendered in front of (or behind) the
surface actually observed there costs the full penalty. The hand tracker the paper builds on
uses 4 cm for hands; a body is roughly 4x larger."""


def _sums(z_d, z_fg, r_d, r_fg, d_M):
    """(sum of i_p * match_p, |P_u|) over the pixels; see the module docstring."""
    inter = z_fg * r_fg
    union = z_fg + r_fg - inter
    match = 1.0 - jnp.minimum(jnp.abs(z_d - r_d), d_M) / d_M
    return jnp.sum(inter * match), jnp.sum(union)


def _delta_from_sums(matched, union):
    # Safe where: |P_u| = 0 means no foreground anywhere; Delta = 1 there, and the division
    # must not run (0/0 would be NaN in the value and in the gradient of the other branch).
    ok = union > 0.0
    return jnp.where(ok, 1.0 - matched / jnp.where(ok, union, 1.0), 1.0)


def _sanitize_observation(z_d, z_fg):
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
    z_d, z_fg = _sanitize_observation(z_d, z_fg)
    matched, union = _sums(z_d, z_fg, r_d, r_fg, d_M)
    return _delta_from_sums(matched, union)


def delta_batch(
    z_d: Float[Array, "H W"],
    z_fg: Float[Array, "H W"],
    r_d: Float[Array, "hyp H W"],
    r_fg: Float[Array, "hyp H W"],
    *,
    d_M: float | Array = DEFAULT_D_M,
) -> Float[Array, " hyp"]:
    """:func:`delta` over the leading ``hyp`` axis of the rendered maps (one observation)."""
    z_d, z_fg = _sanitize_observation(z_d, z_fg)
    return jax.vmap(lambda d, f: _delta_from_sums(*_sums(z_d, z_fg, d, f, d_M)))(r_d, r_fg)


# ----------------------------------------------------------------------------------------------
# Fused render + Delta over hypotheses.


def _score_full(x, y, caps, z_d, z_fg, sharpness, d_M, known=None):
    """Delta of one hypothesis rendered over the whole image."""
    r_d, r_fg = _render_one(x, y, caps, sharpness)
    if known is not None:
        r_fg = r_fg * known
    return _delta_from_sums(*_sums(z_d, z_fg, r_d, r_fg, d_M))


class _Tiles(eqx.Module):
    """The observation cut into ``tile`` x ``tile`` pixel tiles (padded), plus the tiles' rays.

    Tile ``T`` (one past the last) is an all-zero dummy that pads the last chunk.
    """

    z_d: Array  # (T + 1, tile, tile) observed depth, metres (0 off the foreground)
    z_fg: Array  # (T + 1, tile, tile) observed foreground
    inside: Array  # (T + 1, tile, tile) 1 for pixels inside the image, 0 for padding
    fg_total: Array  # () sum of z_fg: |z_fg| enters |P_u| in full, rendered or not
    x: Array  # (Tx, tile) ray x of each tile column's pixels
    y: Array  # (Ty, tile) ray y of each tile row's pixels
    x_centre: Array  # (Tx,) ray x through each tile's centre
    y_centre: Array  # (Ty,) ray y through each tile's centre
    half_diag: Array  # () max |r - r_centre| over a tile's pixel rays (z = 1)
    tile: int = eqx.field(static=True)
    nx: int = eqx.field(static=True)
    ny: int = eqx.field(static=True)


def _tile_observation(z_d, z_fg, intrinsics: Intrinsics, tile: int, dtype, known=None) -> _Tiles:
    height, width = intrinsics.height, intrinsics.width
    ny, nx = -(-height // tile), -(-width // tile)
    pad = ((0, ny * tile - height), (0, nx * tile - width))

    def tiles(img):
        img = jnp.pad(img.astype(dtype), pad).reshape(ny, tile, nx, tile).transpose(0, 2, 1, 3)
        dummy = jnp.zeros((1, tile, tile), dtype)
        return jnp.concatenate([img.reshape(ny * nx, tile, tile), dummy])

    fx, fy, cx, cy = (
        jnp.asarray(v, dtype) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)
    )
    u = jnp.arange(nx * tile, dtype=dtype).reshape(nx, tile)
    v = jnp.arange(ny * tile, dtype=dtype).reshape(ny, tile)
    return _Tiles(
        z_d=tiles(z_d),
        z_fg=tiles(z_fg),
        inside=tiles(jnp.ones((height, width), dtype) if known is None else known),
        fg_total=jnp.sum(z_fg.astype(dtype)),
        x=(u - cx) / fx,
        y=(v - cy) / fy,
        x_centre=(u.mean(axis=1) - cx) / fx,
        y_centre=(v.mean(axis=1) - cy) / fy,
        half_diag=0.5 * tile * jnp.sqrt(1.0 / (fx * fx) + 1.0 / (fy * fy)),
        tile=tile,
        nx=nx,
        ny=ny,
    )


def _score_culled(caps, obs: _Tiles, sharpness, d_M, margin, chunk: int, group: int):
    """Delta of one hypothesis, rendering only the tiles near the body and, per chunk of
    tiles, only the capsules near one of them. Exact for the hard renderer (``margin`` 0); the
    soft one loses only coverage below ``sigmoid(-sharpness * margin)`` per pixel and capsule.

    A capsule can come within ``e`` of a pixel ray only if it comes within
    ``e + reach * half_diag`` of the tile's centre ray, where ``reach`` bounds the distance of
    the capsule's points from the camera (the closest-approach point on a ray is never farther
    from the camera than the point it approaches).
    """
    p = _prim_params(caps)
    n_prim = caps.radius.shape[0]
    n_tiles = obs.nx * obs.ny
    dtype = obs.z_d.dtype
    pc = {k: v[:, None, None] for k, v in p.items()}
    delta_c, _ = _capsule_fields(obs.x_centre[None, None, :], obs.y_centre[None, :, None], pc)
    reach = jnp.sqrt(jnp.maximum(jnp.sum(caps.a * caps.a, -1), jnp.sum(caps.b * caps.b, -1)))
    near = delta_c <= margin + reach[:, None, None] * obs.half_diag  # (P, Ty, Tx)
    near = jnp.concatenate([near.reshape(n_prim, n_tiles), jnp.zeros((n_prim, 1), bool)], 1)
    tile_on = jnp.any(near[:, :n_tiles], axis=0)
    n_active = jnp.sum(tile_on)
    # Active tiles first, in raster order: a chunk is a horizontal strip of the body, which
    # few capsules touch.
    tile_ids = jnp.argsort(~tile_on, stable=True).astype(jnp.int32)
    n_pad = -(-n_tiles // chunk) * chunk - n_tiles
    tile_ids = jnp.concatenate([tile_ids, jnp.full((n_pad,), n_tiles, jnp.int32)])

    def do_chunk(j, sums):
        matched, union_r = sums
        ids = jax.lax.dynamic_slice_in_dim(tile_ids, j * chunk, chunk)
        ids = jnp.where(j * chunk + jnp.arange(chunk) < n_active, ids, n_tiles)
        row = jnp.minimum(ids // obs.nx, obs.ny - 1)
        col = ids % obs.nx
        x = obs.x[col][None, :, None, :]  # (1, C, 1, tile): capsule group, tile, row, column
        y = obs.y[row][None, :, :, None]  # (1, C, tile, 1)
        # Capsules near any tile of the chunk come first; each is rendered exactly on the whole
        # chunk, ``group`` capsules per loop step (fewer, larger steps: on CPU the cost of this
        # loop is dominated by per-step overhead, not arithmetic).
        used = jnp.any(near[:, ids], axis=1)
        n_used = jnp.sum(used)
        order = jnp.concatenate([jnp.argsort(~used, stable=True), jnp.zeros((group,), jnp.int32)])

        def do_group(g, acc):
            sel = jax.lax.dynamic_slice_in_dim(order, g * group, group)
            pk = {name: v[sel][:, None, None, None] for name, v in p.items()}
            d_g, z_g = _capsule_fields(x, y, pk)
            # Padding slots: a far miss, no coverage and no depth weight.
            real = g * group + jnp.arange(group) < n_used
            d_g = jnp.where(real[:, None, None, None], d_g, 1e3)
            return _acc_add_group(acc, d_g, z_g, sharpness)

        acc = _acc_init((chunk, obs.tile, obs.tile), dtype, sharpness)
        acc = jax.lax.fori_loop(0, (n_used + group - 1) // group, do_group, acc)
        r_d, r_fg = _acc_final(acc, sharpness)
        r_fg = r_fg * obs.inside[ids]
        z_fg = obs.z_fg[ids]
        inter = z_fg * r_fg
        match = 1.0 - jnp.minimum(jnp.abs(obs.z_d[ids] - r_d), d_M) / d_M
        return matched + jnp.sum(inter * match), union_r + jnp.sum(r_fg - inter)

    n_chunks = (n_active + chunk - 1) // chunk
    zero = jnp.zeros((), dtype)
    matched, union_r = jax.lax.fori_loop(0, n_chunks, do_chunk, (zero, zero))
    return _delta_from_sums(matched, obs.fg_total + union_r)


_CULL_MARGIN = 10.0
"""Soft culling margin in units of 1/sharpness: neglected coverage < sigmoid(-10) = 4.5e-5."""


def render_and_score(
    capsules: Capsules,
    z_d: Float[Array, "H W"],
    z_fg: Float[Array, "H W"],
    intrinsics: Intrinsics,
    *,
    sharpness: float | Array | None = DEFAULT_SHARPNESS,
    d_M: float | Array = DEFAULT_D_M,
    cull: bool = True,
    tile: int = 8,
    chunk: int = 16,
    batch_size: int | None = None,
    dtype=jnp.float32,
    group: int = 4,
    known: Float[Array, "H W"] | None = None,
    vectorize: bool = True,
) -> Float[Array, " hyp"]:
    """Delta (Eq. (3) of the paper) of every hypothesis against one observation, fused with
    the rendering so the hypotheses' depth maps are never stored together.

    Args:
        capsules: capsules with a leading ``hyp`` axis, camera frame, metres.
        z_d, z_fg: observation maps from :func:`observation_maps`, at ``intrinsics``' size.
        intrinsics: camera of the observation maps.
        sharpness: renderer sharpness, 1/metre (:func:`render_depth`); ``None``: hard.
        d_M: depth-difference clamp of Eq. (3), metres.
        cull: render only the ``tile`` x ``tile`` pixel tiles that some capsule of the
            hypothesis comes near, ``chunk`` tiles at a time, and per chunk only the capsules
            near one of its tiles, ``group`` capsules per loop step. Exact for the hard
            renderer; the soft one drops coverage below sigmoid(-10) = 5e-5 per pixel and
            capsule. The cost then follows the body's image area instead of the image's. Its
            loops have data-dependent trip counts, so this path is forward-mode
            differentiable only (``jax.jvp``); ``cull=False`` renders every pixel and supports
            reverse mode.
        tile, chunk, group: culling granularity (static; the defaults were the fastest
            measured at 160x120 and 320x240).
        batch_size: hypotheses vmapped per step of the ``lax.map`` (``cull=False`` only:
            culling branches per hypothesis, which ``vmap`` would turn into doing both sides).
        dtype: compute dtype; the capsules and maps are cast to it (float32: float64
            rendering is several times slower).
        known: optional (H, W) map, 1 where the sensor measured something (valid depth), 0
            where it did not (holes, removed areas). Rendered foreground over unknown pixels
            is left out of |P_u|: the sensor cannot say the body is not there. ``None``: every
            pixel is known (Eq. (3) as the paper writes it).
        vectorize: (``cull=True``) evaluate all hypotheses together (``vmap``: the culling
            loops run to the longest hypothesis' trip count, which differs little between
            hypotheses of one frame) instead of one after another (``lax.map``: one set of
            loops per hypothesis). Memory stays bounded either way (chunk x tile x tile per
            hypothesis); vectorised was faster on CPU, mostly for the hard renderer
            (``benchmarks/README.md``).

    Returns:
        Delta per hypothesis, in [0, 1].
    """
    _check_capsules("render_and_score", capsules, 1)
    for name, img in (("z_d", z_d), ("z_fg", z_fg), ("known", z_fg if known is None else known)):
        if jnp.shape(img) != intrinsics.shape:
            raise ValueError(
                f"render_and_score: {name} has shape {jnp.shape(img)}, the "
                f"intrinsics say {intrinsics.shape}"
            )
    capsules = capsules.astype(dtype)
    sharpness = _as_sharpness(sharpness, dtype)
    z_d, z_fg = _sanitize_observation(jnp.asarray(z_d, dtype), jnp.asarray(z_fg, dtype))
    if cull:
        if batch_size not in (None, 1):
            raise ValueError(
                f"render_and_score: batch_size must be None with cull=True, got {batch_size!r}"
            )
        known = None if known is None else jnp.asarray(known, dtype)
        obs = _tile_observation(z_d, z_fg, intrinsics, tile, dtype, known)
        margin = 0.0 if sharpness is None else _CULL_MARGIN / sharpness
        score = partial(
            _score_culled, obs=obs, sharpness=sharpness, d_M=d_M, margin=margin, chunk=chunk,
            group=group,
        )  # fmt: skip
        return jax.vmap(score)(capsules) if vectorize else jax.lax.map(score, capsules)
    x, y = _ray_grid(intrinsics, dtype)
    return jax.lax.map(
        lambda c: _score_full(
            x, y, c, z_d, z_fg, sharpness, d_M, None if known is None else jnp.asarray(known, dtype)
        ),
        capsules,
        batch_size=batch_size,
    )
