"""Landmark selection weights and weighted subset sampling of the MHT (paper section 2.2).

For each hypothesis h, each landmark i gets a 3D selection weight W_i and a 2D weight w_i:

* random exclusion: ``W^r = 1 - R``, ``w^r = 1 - r``;
* model geometry: ``W^g = exp(-d_g / (2 sigma_g^2))``, d_g in [0, 1]
  (see :func:`geometry_distance`);
* temporal continuity: ``W^h = exp(-d_h / (2 sigma_h^2))`` with
  ``d_h = min(|O_i,t - M^h_i,t-1|, d_hmax) / d_hmax``;
* 2D weights from 3D ones: ``w = l W + (1 - l)``, l = 0.33;
* combination by min: ``W = min(W^r, W^g, W^h)``, ``w = min(w^r, w^g, w^h)`` (MHT_r uses only the
  random term, MHT_g adds geometry, MHT_h adds temporal continuity).

Then ``S = floor(sum_i W_i)`` 3D and ``s = floor(sum_i w_i)`` 2D landmarks are drawn by weighted
random sampling without replacement (Gumbel top-k: add Gumbel noise to ``log W`` and keep the
S largest; exactly sequential weighted sampling without replacement, with static shapes).

Weights are zero where there is nothing to select (no depth for W, no detection for w).

:func:`landmark_weights` combines the criteria of a method for every hypothesis and
:func:`landmark_subsets` draws the subsets; the tracker step calls the latter.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ._body import BodyShape
from ._camera import Intrinsics, project
from ._config import TrackerConfig
from ._geometry import GEOMETRY_PARTNER, part_radii, partner_rest_lengths
from ._observe import Landmarks

L_2D = 0.33
"""The paper's l: ``w = l W + (1 - l)``, so about 1 in 3 excluded 3D landmarks also loses its
2D one."""

_LINE_SAMPLES = np.linspace(0.2, 0.8, 4)


def geometry_distance(
    landmarks: Landmarks,
    partner_points: Float[Array, "kpt 3"],
    partner_valid: Bool[Array, " kpt"],
    rest_lengths: Float[Array, " kpt"],
    part_radius: Float[Array, " kpt"],
    depth: Float[Array, "H W"],
    intrinsics: Intrinsics,
    *,
    length_tolerance: float = 0.35,
    line_tolerance: float = 0.10,
) -> Float[Array, " kpt"]:
    """The normalised geometric discrepancy d_g in [0, 1] of each 3D landmark.

    For landmark O_i and its partner point P (the observed partner landmark where it has depth,
    else the hypothesis' previous model keypoint), two terms, each in [0, 1]:

    * length: ``min(| |O_i - P| - L_i | / (length_tolerance * L_i), 1)``, where L_i is the
      model's distance between the two keypoints (a bone length);
    * line: the segment from P to O_i should lie on the body, so the depth observed where its
      interior points (20-80 % along it) project should be that of the segment less the part's
      radius (the sensor sees the surface in front of the axis). Per sample
      ``min(|z_obs - (z_seg - r)|, line_tolerance) / line_tolerance``, averaged; samples
      without valid depth count as the full 1 (a limb cannot lie where the sensor sees nothing).

    ``d_g = (length + line) / 2``: 0 when both agree with the model, 1 when both are off by
    more than their tolerance. Keypoints without depth get d_g = 1 (their W is zero anyway).

    Args:
        landmarks: this frame's lifted landmarks.
        partner_points: (kpt, 3) partner point for each keypoint, metres.
        partner_valid: (kpt,) whether the partner point exists at all.
        rest_lengths: (kpt,) the model's distance to the partner, metres.
        part_radius: (kpt,) radius of the body part between them, metres.
        depth: (H, W) observed depth, metres (0 / NaN invalid), at ``intrinsics``' size.
        intrinsics: the camera of ``depth``.
        length_tolerance: relative length error that counts as a full mismatch.
        line_tolerance: depth error (metres) that counts as a full mismatch along the line.
    """
    obs = landmarks.points3d
    length = jnp.linalg.norm(obs - partner_points, axis=-1)
    d_len = jnp.minimum(jnp.abs(length - rest_lengths) / (length_tolerance * rest_lengths), 1.0)
    t = jnp.asarray(_LINE_SAMPLES, obs.dtype)
    seg = partner_points[:, None, :] + t[None, :, None] * (obs - partner_points)[:, None, :]
    uv = project(intrinsics, seg)  # (kpt, samples, 2)
    H, W = depth.shape
    col = jnp.clip(jnp.round(uv[..., 0]).astype(jnp.int32), 0, W - 1)
    row = jnp.clip(jnp.round(uv[..., 1]).astype(jnp.int32), 0, H - 1)
    inside = (
        (uv[..., 0] > -0.5) & (uv[..., 0] < W - 0.5) & (uv[..., 1] > -0.5) & (uv[..., 1] < H - 0.5)
    )
    z_obs = depth[row, col]
    valid = inside & jnp.isfinite(z_obs) & (z_obs > 0)
    expected = seg[..., 2] - part_radius[:, None]
    err = jnp.minimum(jnp.abs(jnp.where(valid, z_obs, 0.0) - expected), line_tolerance)
    d_line = jnp.mean(jnp.where(valid, err / line_tolerance, 1.0), axis=-1)
    d_g = 0.5 * (d_len + d_line)
    return jnp.where(
        landmarks.has_depth & partner_valid, d_g, jnp.where(landmarks.has_depth, d_len, 1.0)
    )


def temporal_distance(
    landmarks: Landmarks,
    previous: Float[Array, "kpt 3"],
    intrinsics: Intrinsics,
    *,
    d_hmax: float,
) -> tuple[Float[Array, " kpt"], Float[Array, " kpt"]]:
    """d_h of the paper for the 3D landmarks, and its 2D counterpart.

    3D: ``min(|O_i,t - M^h_i,t-1|, d_hmax) / d_hmax``. 2D (for keypoints detected without depth,
    an extension of the paper, which defines d_h on 3D landmarks only): the pixel distance
    between o_i and the projection of M^h_i,t-1, converted to metres at that keypoint's depth,
    truncated and normalised the same way.
    """
    d3, d2 = landmark_distances(landmarks, previous, intrinsics)
    return jnp.minimum(d3, d_hmax) / d_hmax, jnp.minimum(d2, d_hmax) / d_hmax


def consensus_set(
    landmarks: Landmarks, points: Float[Array, "kpt 3"], intrinsics: Intrinsics, distance
) -> tuple[Bool[Array, " kpt"], Bool[Array, " kpt"]]:
    """The landmarks a pose agrees with (the RANSAC consensus set): ``(use3d, use2d)``, the 3D
    landmarks within ``distance`` of the keypoints ``points`` and the detected 2D ones within
    it in the image (metres at the keypoint's depth, :func:`landmark_distances`)."""
    d3, d2 = landmark_distances(landmarks, points, intrinsics)
    return landmarks.has_depth & (d3 < distance), landmarks.detected & (d2 < distance)


def landmark_distances(
    landmarks: Landmarks, points: Float[Array, "kpt 3"], intrinsics: Intrinsics
) -> tuple[Float[Array, " kpt"], Float[Array, " kpt"]]:
    """Distance of each landmark from a model keypoint, metres: in 3D (``|O_i - M_i|``) and in
    the image (pixel distance between o_i and the projection of M_i, converted to metres at
    M_i's depth, at least 0.2 m)."""
    d3 = jnp.linalg.norm(landmarks.points3d - points, axis=-1)
    m = project(intrinsics, points)
    f = jnp.sqrt(intrinsics.fx * intrinsics.fy)
    d2 = jnp.linalg.norm(m - landmarks.keypoints2d, axis=-1) * jnp.maximum(points[:, 2], 0.2) / f
    return d3, d2


def gaussian_weight(d: Array, sigma: float) -> Array:
    """``exp(-d / (2 sigma^2))`` as in the paper."""
    return jnp.exp(-d / (2.0 * sigma * sigma))


def sample_subset(
    key: PRNGKeyArray, weights: Float[Array, " kpt"], available: Bool[Array, " kpt"]
) -> Bool[Array, " kpt"]:
    """Draw ``floor(sum(weights))`` of the available items without replacement, with
    probabilities proportional to ``weights`` (Gumbel top-k). Weights outside ``available`` are
    ignored (treated as 0).

    Returns:
        (kpt,) boolean selection mask.
    """
    w = jnp.where(available, weights, 0.0)
    count = jnp.floor(jnp.sum(w) + 1e-6).astype(jnp.int32)
    # Gumbel top-k: the k largest of log w + Gumbel are a weighted sample without replacement.
    # Zero weights get -inf keys (safe log), so they are never drawn while weight remains.
    safe = jnp.where(w > 0, w, 1.0)
    keys = jnp.where(w > 0, jnp.log(safe) + jax.random.gumbel(key, w.shape, w.dtype), -jnp.inf)
    rank = jnp.argsort(jnp.argsort(-keys))
    return (rank < count) & (w > 0)


def landmark_weights(
    config: TrackerConfig,
    shape: BodyShape,
    intrinsics: Intrinsics,
    depth: Float[Array, "H W"],
    landmarks: Landmarks,
    previous: Float[Array, "hyp kpt 3"],
) -> tuple[Float[Array, "hyp kpt"], Float[Array, "hyp kpt"]]:
    """The selection weights (W, w) of every hypothesis for ``config.method`` (section 2.2).

    MHT_r: ``W = W^r``; MHT_g adds W^g; MHT_h adds W^h; combined by min. With
    ``config.temporal_2d`` (not in the paper), a 2D-only landmark (detected, no depth) also
    gets a temporal 2D weight from its reprojection distance (:func:`temporal_distance`); the
    paper leaves it at 1. LVM is not weighted (all ones).

    Args:
        config: the method and its sigmas (traced).
        shape: body dimensions (rest lengths, part radii).
        intrinsics: the camera of ``depth`` and the keypoints.
        depth: (H, W) observed depth, metres.
        landmarks: this frame's lifted landmarks.
        previous: (hyp, kpt, 3) each hypothesis' model keypoints at the previous frame, metres.

    Returns:
        (W, w), each (hyp, kpt) in [0, 1], before zeroing what is unavailable.
    """
    N = previous.shape[0]
    F = landmarks.has_depth
    dtype = landmarks.points3d.dtype
    if config.method == "lvm":
        return jnp.ones((N, 18), dtype), jnp.ones((N, 18), dtype)
    W = jnp.full((N, 18), 1.0 - config.R, dtype)
    w = jnp.full((N, 18), 1.0 - config.r, dtype)
    if config.method in ("mht_g", "mht_h"):
        partner = np.asarray(GEOMETRY_PARTNER, np.int32)
        rest = partner_rest_lengths(shape)
        radii = part_radii(shape)

        def geom(prev):
            # The partner is the observed landmark where it has depth, else this hypothesis'
            # previous model keypoint.
            pts = jnp.where(F[partner][:, None], landmarks.points3d[partner], prev[partner])
            valid = jnp.ones((18,), bool)
            return geometry_distance(landmarks, pts, valid, rest, radii, depth, intrinsics)

        Wg = gaussian_weight(jax.vmap(geom)(previous), config.sigma_g)
        W = jnp.minimum(W, Wg)
        w = jnp.minimum(w, jnp.where(F, L_2D * Wg + (1 - L_2D), 1.0))
    if config.method == "mht_h":
        d3, d2 = jax.vmap(
            lambda prev: temporal_distance(landmarks, prev, intrinsics, d_hmax=config.d_hmax)
        )(previous)
        Wh = gaussian_weight(d3, config.sigma_h)
        W = jnp.minimum(W, Wh)
        if config.temporal_2d:
            w2_only = L_2D * gaussian_weight(d2, config.sigma_h) + (1 - L_2D)
        else:
            w2_only = jnp.ones_like(Wh)
        w = jnp.minimum(w, jnp.where(F, L_2D * Wh + (1 - L_2D), w2_only))
    return W, w


def landmark_subsets(
    config: TrackerConfig,
    key: PRNGKeyArray,
    shape: BodyShape,
    intrinsics: Intrinsics,
    depth: Float[Array, "H W"],
    landmarks: Landmarks,
    previous: Float[Array, "hyp kpt 3"],
) -> tuple[Bool[Array, "hyp kpt"], Bool[Array, "hyp kpt"]]:
    """(use3d, use2d) of every hypothesis: the MHT's landmark subsets, drawn by
    :func:`sample_subset` from :func:`landmark_weights`; all landmarks for LVM (and for
    hypothesis 0 with ``config.all_landmarks_hypothesis``).

    Returns:
        (use3d, use2d), each (hyp, kpt) boolean; ``use3d`` implies F_i, ``use2d`` implies f_i.
    """
    N = previous.shape[0]
    F, f = landmarks.has_depth, landmarks.detected
    if config.method == "lvm":
        return jnp.broadcast_to(F, (N, 18)), jnp.broadcast_to(f, (N, 18))
    W, w = landmark_weights(config, shape, intrinsics, depth, landmarks, previous)
    keys = jax.random.split(key, (N, 2))
    use3d = jax.vmap(sample_subset, in_axes=(0, 0, None))(keys[:, 0], W, F)
    use2d = jax.vmap(sample_subset, in_axes=(0, 0, None))(keys[:, 1], w, f)
    if config.all_landmarks_hypothesis and N > 1:
        # Hypothesis 0 fits every landmark, as LVM does (opt-in; not in the paper).
        use3d, use2d = use3d.at[0].set(F), use2d.at[0].set(f)
    return use3d, use2d
