"""Observation preprocessing: sensor depth -> the maps ``z = {z_d, z_fg}`` that Delta scores.

The paper: "A pre-processing step uses the estimated model position in the previous frame as
reference and keeps only the observations that are within a predefined range around it. The
observation consists of the resulting 2D depth and foreground maps z = {z_d, z_fg}."

Three steps:

1. :func:`downsample_depth` (per frame, jittable): sensor resolution -> scoring resolution by
   the lower median of the valid depths of each block.
2. :func:`fit_floor_plane` (once, host side, NumPy RANSAC): the supporting plane, so the
   floor under the feet never counts as body.
3. :func:`observation_maps` (per frame, jittable, static shapes): keep the valid pixels whose 3D
   point lies in a body-sized region around the previous root position and above the floor.

Depth maps are in metres; 0 or NaN marks an invalid pixel on input, 0 on output.

:func:`tracker_observation` chains 1 and 3 at the tracker's scoring size
(:func:`scoring_size`, :func:`score_depth`), and :func:`tracker_landmarks` lifts the keypoints
with the tracker's settings: together, what one tracker step observes.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import BodyShape
from ._camera import Intrinsics, pixel_rays_np
from ._config import TrackerConfig
from ._geometry import surface_offsets
from ._observe import Landmarks, body_depth_limit, lift_keypoints

DEFAULT_RADIUS = 1.1
"""Metres: horizontal distance from the vertical axis through the root that can hold body:
half an arm span (~0.9 m for a 1.8 m adult, hands to the side) plus margin for leaning and for
the root estimate being one frame old."""

DEFAULT_HEIGHT_RANGE = (-1.3, 1.4)
"""Metres above the root (pelvis) that can hold body: the feet are ~1 m below it (the floor test
removes the floor, not this bound), raised hands up to ~1.3 m above it."""

DEFAULT_DEPTH_RANGE = (-1.0, 0.7)
"""Metres along the optical axis relative to the root: a hand reaches ~1 m toward the camera
(arm plus a forward lean), backward far less. A wall more than 0.7 m behind the root is
excluded; one closer than that remains (no range test can separate it from a hand swung back)."""

DEFAULT_FLOOR_MARGIN = 0.05
"""Metres: points less than this above the floor plane are dropped: ~2 sigma of Kinect depth
noise at 4 m (sigma ~ 1.4e-3 z^2 m, Khoshelham & Elberink 2012) plus the plane's own error. The
soles of the feet (~5 cm) are lost with it; the ankles are not."""


def _oddeven_merge_pairs(n: int) -> list[tuple[int, int]]:
    """Comparators of Batcher's odd-even merge sort for ``n`` (a power of two) keys."""
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


def sort_last_axis(values: Array) -> Array:
    """Sort along the last axis. Small blocks (<= 32 keys, e.g. 4x4 for 640x480 -> 160x120) go
    through a sorting network of elementwise min/max on whole images: ~10x faster than
    ``jnp.sort`` on CPU (2 ms instead of 18 ms for 19200 blocks of 16), which sorts block by
    block. Larger blocks use ``jnp.sort`` (a network would take minutes to compile)."""
    n = values.shape[-1]
    if n > 32:
        return jnp.sort(values, axis=-1)
    m = 1 << max(n - 1, 0).bit_length()
    keys = [values[..., i] for i in range(n)]
    keys += [jnp.full(values.shape[:-1], jnp.inf, values.dtype)] * (m - n)
    for i, j in _oddeven_merge_pairs(m):
        keys[i], keys[j] = jnp.minimum(keys[i], keys[j]), jnp.maximum(keys[i], keys[j])
    return jnp.stack(keys[:n], axis=-1)


def kth_smallest_nonnegative(values: Array, k: Array) -> Array:
    """The ``k``-th smallest (0-based, per row) along the last axis of non-negative floats
    (``+inf`` allowed): exactly the value a full sort would put at index ``k``.

    For large blocks (12x12 = 144 pixels for 1920x1080 -> 160x90) sorting every block cost
    ~200-300 ms a frame on CPU. Non-negative floats order like their bit patterns read as
    integers, so a bisection on the bits finds the smallest value with at least ``k + 1``
    values at or below it in 31 (float32) counting passes: ~15 ms for the same blocks.
    """
    dtype = values.dtype
    ibits = jnp.int32 if dtype.itemsize == 4 else jnp.int64
    bits = jax.lax.bitcast_convert_type(values, ibits)
    lo = jnp.zeros(k.shape, ibits)
    hi = jnp.broadcast_to(jax.lax.bitcast_convert_type(jnp.asarray(jnp.inf, dtype), ibits), k.shape)

    def halve(_, bounds):
        lo, hi = bounds
        mid = lo + (hi - lo) // 2
        enough = jnp.sum(bits <= mid[..., None], axis=-1) >= k + 1
        return jnp.where(enough, lo, mid + 1), jnp.where(enough, mid, hi)

    lo, _ = jax.lax.fori_loop(0, 8 * dtype.itemsize - 1, halve, (lo, hi))
    return jax.lax.bitcast_convert_type(lo, dtype)


def downsample_depth(
    depth_m: Float[Array, "H W"],
    factor: int | tuple[int, int],
    *,
    min_valid: float = 0.5,
) -> Float[Array, "h w"]:
    """Downsample a depth map by an integer factor, robust to invalid pixels.

    Each ``fy`` x ``fx`` block becomes the lower median of its valid depths (valid: finite and
    > 0), or 0 (invalid) when fewer than ``min_valid`` of its pixels are valid.

    Why the median: the block minimum would grow every foreground object by up to a block at
    its silhouette and pick up sensor outliers; the mean would invent depths between the body
    and the background at silhouettes ("flying pixels") that match no surface. The median of a
    silhouette block snaps to the majority surface, and the lower median (not the average of
    the two middle values) is always a measured depth.

    Pair the result with ``intrinsics.scaled(w, h)``: block centres then map to pixel centres.

    Args:
        depth_m: depth in metres; 0 or NaN = invalid.
        factor: block size, ``f`` or ``(fy, fx)``; must divide the image size.
        min_valid: smallest fraction of valid pixels a block needs to be valid.

    Returns:
        The ``(H / fy, W / fx)`` depth map, metres, 0 where invalid.

    Raises:
        ValueError: if the factor does not divide the image size (raised at trace time).
    """
    fy, fx = (factor, factor) if isinstance(factor, int) else factor
    height, width = depth_m.shape
    if fy <= 0 or fx <= 0 or height % fy or width % fx:
        raise ValueError(
            f"downsample_depth: factor {factor!r} must divide the depth map size {width}x{height}"
        )
    h, w = height // fy, width // fx
    blocks = depth_m.reshape(h, fy, w, fx).transpose(0, 2, 1, 3).reshape(h, w, fy * fx)
    valid = jnp.isfinite(blocks) & (blocks > 0)
    n_valid = jnp.sum(valid, axis=-1)
    # Invalid pixels sort last (+inf), so the k-th smallest valid depth sits at index k.
    keyed = jnp.where(valid, blocks, jnp.inf)
    mid = jnp.maximum(n_valid - 1, 0) // 2
    if fy * fx <= 32:
        median = jnp.take_along_axis(sort_last_axis(keyed), mid[..., None], axis=-1)[..., 0]
    else:
        median = kth_smallest_nonnegative(keyed, mid)
    enough = n_valid >= max(1, math.ceil(min_valid * fy * fx))
    return jnp.where(enough, median, 0.0).astype(depth_m.dtype)


def observation_maps(
    depth_m: Float[Array, "H W"],
    intrinsics: Intrinsics,
    *,
    center: Float[Array, 3],
    floor: tuple[Float[Array, 3], Float[Array, ""]] | None = None,
    radius: float = DEFAULT_RADIUS,
    height_range: tuple[float, float] = DEFAULT_HEIGHT_RANGE,
    depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE,
    floor_margin: float = DEFAULT_FLOOR_MARGIN,
) -> tuple[Float[Array, "H W"], Float[Array, "H W"]]:
    """The observation ``z = {z_d, z_fg}`` of the paper around the previous body position.

    A valid pixel is foreground when its 3D point ``p`` (camera frame) satisfies, with
    ``q = p - center`` and ``up`` the floor normal (camera ``-y`` without a floor):

    * ``height_range[0] <= q . up <= height_range[1]`` (above/below the root),
    * ``|q - (q . up) up| <= radius`` (horizontal distance from the root's vertical axis),
    * ``depth_range[0] <= p_z - center_z <= depth_range[1]`` (removes the back wall),
    * ``normal . p + offset > floor_margin`` when ``floor = (normal, offset)`` is given.

    Jittable; shapes are static. See the ``DEFAULT_*`` constants for why these bounds.

    Args:
        depth_m: depth in metres at the scoring resolution (0 or NaN = invalid).
        intrinsics: camera of ``depth_m``.
        center: previous root position, camera frame, metres.
        floor: ``(normal, offset)`` from :func:`fit_floor_plane`, or ``None``.
        radius, height_range, depth_range, floor_margin: metres, as above.

    Returns:
        ``(z_d, z_fg)``: depth in metres (0 off the foreground) and the binary foreground
        (0./1.), both in the dtype of ``depth_m``.
    """
    dtype = depth_m.dtype
    fx, fy, cx, cy = (
        jnp.asarray(v, dtype) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)
    )
    center = jnp.asarray(center, dtype)
    valid = jnp.isfinite(depth_m) & (depth_m > 0)
    z = jnp.where(valid, depth_m, 0.0)
    x = (jnp.arange(intrinsics.width, dtype=dtype)[None, :] - cx) / fx * z
    y = (jnp.arange(intrinsics.height, dtype=dtype)[:, None] - cy) / fy * z
    qx, qy, qz = x - center[0], y - center[1], z - center[2]
    if floor is None:
        ux, uy, uz = 0.0, -1.0, 0.0
    else:
        normal = jnp.asarray(floor[0], dtype)
        ux, uy, uz = normal[0], normal[1], normal[2]
    height = qx * ux + qy * uy + qz * uz
    hx, hy, hz = qx - height * ux, qy - height * uy, qz - height * uz
    keep = (
        valid
        & (height >= height_range[0])
        & (height <= height_range[1])
        & (hx * hx + hy * hy + hz * hz <= radius * radius)
        & (qz >= depth_range[0])
        & (qz <= depth_range[1])
    )
    if floor is not None:
        above = x * ux + y * uy + z * uz + jnp.asarray(floor[1], dtype)
        keep = keep & (above > floor_margin)
    return jnp.where(keep, z, 0.0), keep.astype(dtype)


_FLOOR_MAX_WIDTH = 640
"""``fit_floor_plane`` works on every k-th pixel of wider depth maps: its least-squares
refinement over all 2 million pixels of a 1920x1080 map took 1.4 s at the first frame."""


def fit_floor_plane(
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    *,
    seed: int = 0,
    iterations: int = 300,
    max_tilt_deg: float = 45.0,
    inlier_base: float = 0.01,
    inlier_quadratic: float = 0.004,
    min_inlier_fraction: float = 0.05,
    max_points: int = 20000,
) -> tuple[np.ndarray, float]:
    """Fit the floor plane with RANSAC (NumPy, host side; run once at initialisation).

    Candidate planes through three random valid points are kept only if their normal is within
    ``max_tilt_deg`` of the camera's up direction (``-y``) and the camera is above them, so a
    wall or the person never qualifies however many points it has; the candidate with most
    inliers wins. The inlier band grows with depth like the sensor noise:
    ``inlier_base + inlier_quadratic * z**2`` metres (~3 sigma of Kinect noise).

    The winner is then refined by least squares (SVD), twice, on its inliers that are also
    locally flat: the height above the plane changes little between a pixel and the one a few
    rows away relative to their distance (slope < 0.5). Without that test the strip of wall
    just above a wall-floor junction (within the band at 4 m: ~9 cm) tilts and lifts the
    fitted floor by a couple of centimetres.

    Args:
        depth_m: depth in metres (any resolution matching ``intrinsics``; maps wider than 640
            pixels are read at every k-th pixel, k = ceil(width / 640)); 0 or NaN = invalid.
        intrinsics: camera of ``depth_m``.
        seed: RANSAC random seed (the fit is deterministic given it).
        iterations: RANSAC samples.
        max_tilt_deg: largest angle between the floor normal and the camera's up direction.
        inlier_base, inlier_quadratic: inlier band, metres and 1/metre.
        min_inlier_fraction: fewest inliers, as a fraction of the valid points, to accept.
        max_points: RANSAC scores candidates on at most this many random valid points.

    Returns:
        ``(normal, offset)``: unit normal (3,) pointing up (toward the camera side) and offset
        in metres, such that ``normal @ p + offset`` is the height of a camera-frame point
        ``p`` above the floor (``offset`` is the camera's height).

    Raises:
        ValueError: no plane within the tilt limit has ``min_inlier_fraction`` of the points.
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    if depth.shape != intrinsics.shape:
        raise ValueError(
            f"fit_floor_plane: depth_m has shape {depth.shape}, intrinsics say {intrinsics.shape}"
        )
    stride = -(-intrinsics.width // _FLOOR_MAX_WIDTH)
    if stride > 1:  # every stride-th pixel: the same camera at a lower resolution
        depth = depth[::stride, ::stride]
        intrinsics = Intrinsics(
            fx=float(intrinsics.fx) / stride, fy=float(intrinsics.fy) / stride,
            cx=float(intrinsics.cx) / stride, cy=float(intrinsics.cy) / stride,
            width=depth.shape[1], height=depth.shape[0],
        )  # fmt: skip
    valid = np.isfinite(depth) & (depth > 0)
    grid = pixel_rays_np(**intrinsics.to_dict()) * np.where(valid, depth, np.nan)[..., None]
    all_points = grid[valid]
    if len(all_points) < 3:
        raise ValueError(f"fit_floor_plane: only {len(all_points)} valid depth pixels")
    rng = np.random.default_rng(seed)
    points = all_points
    if len(points) > max_points:
        points = points[rng.choice(len(points), max_points, replace=False)]

    def band(p):
        return inlier_base + inlier_quadratic * p[..., 2] ** 2

    def oriented(normal, offset):
        # Camera (origin) above the floor: offset = height of the camera > 0.
        return (-normal, -offset) if offset < 0 else (normal, offset)

    cos_tilt = math.cos(math.radians(max_tilt_deg))
    points_band = band(points)
    best, best_count = None, 0
    for i, j, k in rng.integers(0, len(points), size=(iterations, 3)):
        normal = np.cross(points[j] - points[i], points[k] - points[i])
        norm = np.linalg.norm(normal)
        if norm < 1e-9:
            continue
        normal, offset = oriented(normal / norm, -float(normal @ points[i]) / norm)
        if -normal[1] < cos_tilt:  # up is -y in the camera frame
            continue
        count = int(np.sum(np.abs(points @ normal + offset) < points_band))
        if count > best_count:
            best, best_count = (normal, offset), count
    if best is None or best_count < min_inlier_fraction * len(points):
        raise ValueError(
            f"fit_floor_plane: no floor-like plane (within {max_tilt_deg} deg of level) found: "
            f"best has {best_count} inliers of {len(points)} valid points"
        )

    normal, offset = best
    step = max(2, intrinsics.height // 40)
    for _ in range(2):
        height = grid @ normal + offset  # NaN where invalid
        # Steepest slope toward the pixels `step` rows above and below (NaN: no valid
        # neighbour): a junction pixel is flat toward one side only, so take the max.
        slope = np.full(height.shape, np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            for lo, hi in (
                (slice(None, -step), slice(step, None)),
                (slice(step, None), slice(None, -step)),
            ):
                rise = np.abs(height[hi] - height[lo])
                run = np.linalg.norm(grid[hi] - grid[lo], axis=-1)
                slope[lo] = np.fmax(slope[lo], rise / run)
            keep = valid & (np.abs(height) < band(grid)) & (slope < 0.5)
        inliers = grid[keep]
        if len(inliers) < 3:
            break
        centroid = inliers.mean(axis=0)
        normal = np.linalg.svd(inliers - centroid, full_matrices=False)[2][-1]
        normal, offset = oriented(normal, -float(normal @ centroid))
    return normal, float(offset)


#: Floor plane (nx, ny, nz, d) used when none was found: 100 m below, so nothing is dropped.
NO_FLOOR = (0.0, -1.0, 0.0, 100.0)


def scoring_size(
    config: TrackerConfig, height: int, width: int, *, refine: bool = False
) -> tuple[int, int]:
    """(h, w) of the scoring maps: ``score_width`` wide, and ``score_height`` high when it has the
    sensor's aspect ratio (within 2 %); otherwise the height follows the sensor's aspect ratio
    (e.g. 160x90 for a 16:9 sensor), so the maps never drop part of the image. With ``refine``,
    the same for ``refine_width`` x ``refine_height``."""
    if refine:
        w, h = config.refine_width, config.refine_height
    else:
        w, h = config.score_width, config.score_height
    if abs(h / w - height / width) > 0.02 * height / width:
        h = max(8, round(w * height / width))
    return h, w


def score_depth(
    depth: Float[Array, "H W"],
    intrinsics: Intrinsics,
    config: TrackerConfig,
    *,
    refine: bool = False,
) -> tuple[Float[Array, "h w"], Intrinsics]:
    """The sensor depth at the scoring resolution, and the matching intrinsics.

    Blocks of ``(H // h) x (W // w)`` pixels are reduced by :func:`downsample_depth`; a
    remainder of rows/columns that does not fill a block (e.g. 1080 = 9 x 120 fits, 1000 would
    not) is cropped from the bottom/right first, which leaves fx, fy, cx, cy unchanged.
    """
    H, W = depth.shape
    h, w = scoring_size(config, H, W, refine=refine)
    if H < h or W < w:
        raise ValueError(f"depth {W}x{H} is smaller than the scoring size {w}x{h}")
    fy, fx = H // h, W // w
    cropped = depth[: h * fy, : w * fx]
    crop_intr = Intrinsics(
        fx=intrinsics.fx, fy=intrinsics.fy, cx=intrinsics.cx, cy=intrinsics.cy,
        width=w * fx, height=h * fy,
    )  # fmt: skip
    return downsample_depth(cropped, (fy, fx)), crop_intr.scaled(w, h)


def tracker_observation(
    config: TrackerConfig,
    depth: Float[Array, "H W"],
    intrinsics: Intrinsics,
    floor: Float[Array, 4],
    center: Float[Array, 3],
    *,
    refine: bool = False,
) -> tuple[Float[Array, "h w"], Float[Array, "h w"], Float[Array, "h w"] | None, Intrinsics]:
    """The paper's observation preprocessing at the scoring (or refinement) resolution.

    Args:
        config: scoring size, ``body_range``, ``invalid_is_unknown``.
        depth: (H, W) sensor depth, metres (0 / NaN invalid).
        intrinsics: the sensor's camera.
        floor: (nx, ny, nz, d) floor plane, ``NO_FLOOR`` when unknown.
        center: the previous root position, camera frame, metres.
        refine: use the refinement resolution instead of the scoring one.

    Returns:
        ``(z_d, z_fg, known, intrinsics)``: the observation maps, the valid-depth mask (``None``
        unless ``config.invalid_is_unknown``) and the camera at that resolution.
    """
    small, small_intr = score_depth(depth, intrinsics, config, refine=refine)
    known = (small > 0).astype(small.dtype) if config.invalid_is_unknown else None
    z_d, z_fg = observation_maps(
        small, small_intr, center=center, radius=config.body_range, floor=(floor[:3], floor[3])
    )
    return z_d, z_fg, known, small_intr


def landmark_offsets(config: TrackerConfig, shape: BodyShape) -> Float[Array, " kpt"] | float:
    """How far the tracker's lifting pushes each landmark back from the seen surface (metres):
    :func:`~posetrack._geometry.surface_offsets` with ``config.surface_offset``, else 0."""
    return surface_offsets(shape) if config.surface_offset else 0.0


def tracker_landmarks(
    config: TrackerConfig,
    shape: BodyShape,
    intrinsics: Intrinsics,
    depth: Float[Array, "H W"],
    keypoints2d: Float[Array, "kpt 2"],
    confidence: Float[Array, " kpt"],
) -> Landmarks:
    """:func:`~posetrack.lift_keypoints` with the tracker's settings: its lifting window and
    confidence threshold, and with ``config.surface_offset`` each landmark pushed back by
    :func:`~posetrack._geometry.surface_offsets` (surface -> joint centre), each window
    reading only depths within ``config.lift_band`` behind the torso
    (:func:`~posetrack.body_depth_limit`)."""

    def lift(**max_depth):  # lift_keypoints' own max_depth unless given
        return lift_keypoints(
            depth, keypoints2d, confidence, intrinsics,
            window=config.lift_window, confidence_threshold=config.confidence_threshold,
            depth_offset=landmark_offsets(config, shape), rule=config.lift_rule, **max_depth,
        )  # fmt: skip

    # Lifted twice: the torso's landmarks place the body, and windows then ignore the depths
    # more than ``config.lift_band`` behind it (the background; off at 0: the same landmarks).
    return lift(max_depth=body_depth_limit(lift(), config.lift_band))
