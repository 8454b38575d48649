"""Observation preprocessing: robust downsampling, floor RANSAC, the body-range maps."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import require_data

from posetrack._camera import Intrinsics
from posetrack._depthobs import downsample_depth, fit_floor_plane, observation_maps
from posetrack._render import Capsules, render_depth

jax.config.update("jax_numpy_rank_promotion", "raise")



# ---------------------------------------------------------------------------------------------
# Downsampling.


def test_downsample_block_lower_median_and_invalid_blocks():
    nan = np.nan
    depth = np.array(
        [
            [1.0, 2.0, 5.0, nan, 2.0, 2.01],
            [3.0, 4.0, 0.0, 0.0, 9.0, 2.02],
        ],
        np.float32,
    )
    out = np.asarray(jax.jit(downsample_depth, static_argnums=1)(depth, (2, 2)))
    # Block 0: lower median of {1, 2, 3, 4} is 2 (a measured value, not 2.5).
    # Block 1: one valid pixel of four < 50 %: invalid (0).
    # Block 2: one outlier (9 m) among {2, 2.01, 2.02}: the median ignores it.
    np.testing.assert_array_equal(out, np.array([[2.0, 0.0, 2.01]], np.float32))
    assert out.dtype == np.float32
    loose = downsample_depth(jnp.asarray(depth), 2, min_valid=0.25)
    np.testing.assert_array_equal(np.asarray(loose), np.array([[2.0, 5.0, 2.01]], np.float32))


def test_downsample_non_square_factor_and_shapes():
    depth = np.arange(1, 6 * 12 + 1, dtype=np.float32).reshape(6, 12)
    out = downsample_depth(jnp.asarray(depth), (3, 4))
    assert out.shape == (2, 3)
    # Block (0, 0) holds rows 0-2, columns 0-3: values 1-4, 13-16, 25-28; lower median 14.
    assert float(out[0, 0]) == 14.0
    with pytest.raises(ValueError, match="divide"):
        downsample_depth(jnp.asarray(depth), 5)


def test_downsample_all_invalid_gives_zero_not_nan():
    depth = jnp.full((8, 8), jnp.nan)
    out = downsample_depth(depth, 4)
    assert bool(jnp.all(out == 0.0))


def test_sorting_network_sorts():
    from posetrack._depthobs import sort_last_axis

    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 5, 9, 16, 25, 32, 33):  # 33: falls back to jnp.sort
        x = rng.normal(size=(20, n)).astype(np.float32)
        x[rng.random(x.shape) < 0.2] = np.inf  # invalid pixels
        x[:, 0] = x[:, -1]  # ties
        np.testing.assert_array_equal(np.asarray(sort_last_axis(jnp.asarray(x))), np.sort(x, -1))


def test_downsample_real_kinect_frame():
    import imageio.v3 as iio

    # Read in place from the shared data folder (no licence: never copied); skips if absent.
    path = require_data("rgbd-pose3d-freiburg-sample") / "depth.png"
    depth = iio.imread(path).astype(np.float32) / 1000.0  # mm -> m, 1920x1080
    out = np.asarray(downsample_depth(jnp.asarray(depth), (9, 12)))
    assert out.shape == (120, 160)
    assert np.all(np.isfinite(out))
    valid_in = depth[depth > 0]
    got = out[out > 0]
    assert 0.02 < got.size / out.size < 0.5  # sparse outdoor depth, people only
    assert got.min() >= valid_in.min() and got.max() <= valid_in.max()


# ---------------------------------------------------------------------------------------------
# A synthetic room: floor, back wall and a person, camera 1.3 m high tilted 15 deg down.

CAM_HEIGHT, TILT = 1.3, np.radians(15.0)
UP = np.array([0.0, -np.cos(TILT), -np.sin(TILT)])  # world up in the camera frame
FWD = np.array([0.0, -np.sin(TILT), np.cos(TILT)])  # horizontal forward in the camera frame
K_HI = Intrinsics.create(fx=262.0, fy=262.0, cx=159.5, cy=119.5, width=320, height=240)
K_LO = K_HI.scaled(160, 120)


def person(distance=3.0):
    """A standing person (10 capsules) whose feet touch the floor, camera frame."""
    pelvis_h = 0.95
    root = distance * FWD + (pelvis_h - CAM_HEIGHT) * UP
    right, down = np.array([1.0, 0.0, 0.0]), -UP

    def p(x, y, z):  # body offsets: x right, y down, z away from the camera
        return root + x * right + y * down + z * FWD

    segs = [
        (p(0, 0, 0), p(0, -0.5, 0), 0.14), (p(0, -0.7, 0), p(0, -0.7, 0), 0.11),
        (p(0.2, -0.45, 0), p(0.3, -0.1, -0.1), 0.05),
        (p(0.3, -0.1, -0.1), p(0.35, 0.1, -0.4), 0.04),
        (p(-0.2, -0.45, 0), p(-0.3, -0.15, 0.05), 0.05),
        (p(-0.3, -0.15, 0.05), p(-0.32, 0.1, 0.1), 0.04),
        (p(0.1, 0.0, 0), p(0.12, 0.5, 0), 0.075), (p(0.12, 0.5, 0), p(0.12, 0.89, 0), 0.06),
        (p(-0.1, 0.0, 0), p(-0.12, 0.5, 0), 0.075), (p(-0.12, 0.5, 0), p(-0.12, 0.89, 0), 0.06),
    ]
    a, b, r = (np.array(v) for v in zip(*segs))
    return root, Capsules(jnp.asarray(a), jnp.asarray(b), jnp.asarray(r))


def room_depth(k: Intrinsics, caps, *, wall_distance=4.5, rng=None):
    """Depth (metres) of floor + back wall + person, optional Kinect-like noise and holes;
    and the true label of every pixel (0 floor, 1 wall, 2 person, -1 nothing)."""
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    rays = np.stack([(u - float(k.cx)) / float(k.fx), (v - float(k.cy)) / float(k.fy),
                     np.ones(u.shape)], -1)
    with np.errstate(divide="ignore"):
        t_floor = np.where(rays @ UP < 0, -CAM_HEIGHT / (rays @ UP), np.inf)
        t_wall = np.where(rays @ FWD > 0, wall_distance / (rays @ FWD), np.inf)
    body_d, body_fg = (np.asarray(x) for x in render_depth(caps, k, sharpness=None))
    t_body = np.where(body_fg > 0, body_d, np.inf)
    stacked = np.stack([t_floor, t_wall, t_body])
    label = np.where(np.isfinite(stacked.min(0)), np.argmin(stacked, 0), -1)
    depth = np.where(label >= 0, stacked.min(0), 0.0)
    if rng is not None:
        depth = depth + rng.normal(0, 1.425e-3 * depth**2)
        depth[rng.random(depth.shape) < 0.05] = 0.0
    return depth, label


@pytest.fixture(scope="module")
def room():
    root, caps = person()
    depth_hi, _ = room_depth(K_HI, caps, rng=np.random.default_rng(0))
    depth_lo = np.asarray(downsample_depth(jnp.asarray(depth_hi, jnp.float32), 2))
    _, label_lo = room_depth(K_LO, caps)
    return root, depth_hi, depth_lo, label_lo


def test_fit_floor_plane_recovers_tilted_floor(room):
    _, depth_hi, _, _ = room
    normal, offset = fit_floor_plane(depth_hi, K_HI)
    angle = np.degrees(np.arccos(np.clip(normal @ UP, -1, 1)))
    assert angle < 0.2
    assert abs(offset - CAM_HEIGHT) < 0.005


def test_fit_floor_plane_refuses_a_wall():
    k = Intrinsics.create(fx=60.0, fy=60.0, cx=39.5, cy=29.5, width=80, height=60)
    depth = np.full((60, 80), 3.0)  # a fronto-parallel wall: many points, wrong orientation
    with pytest.raises(ValueError, match="floor"):
        fit_floor_plane(depth, k)


@pytest.fixture(scope="module")
def obs_maps():
    return jax.jit(observation_maps, static_argnames=(
        "radius", "height_range", "depth_range", "floor_margin"))


def test_observation_keeps_the_person_and_drops_floor_and_wall(room, obs_maps):
    root, depth_hi, depth_lo, label = room
    floor = fit_floor_plane(depth_hi, K_HI)
    z_d, z_fg = obs_maps(jnp.asarray(depth_lo), K_LO, center=jnp.asarray(root, jnp.float32),
                         floor=(jnp.asarray(floor[0]), jnp.asarray(floor[1])))
    z_d, z_fg = np.asarray(z_d), np.asarray(z_fg) > 0
    body = label == 2
    # Labels come from centre rays, depths from 2x2 block medians: they may disagree on the
    # silhouette, so score the pixels at least one pixel away from it.
    padded = np.pad(body, 1, mode="edge")
    edge = np.any([padded[1 + i: 121 + i, 1 + j: 161 + j] != body
                   for i in (-1, 0, 1) for j in (-1, 0, 1)], axis=0)
    valid = (depth_lo > 0) & ~edge
    # Everything kept is the person; nearly all of the person is kept.
    assert np.sum(z_fg & ~body & valid) == 0
    assert np.sum(z_fg & body & valid) >= 0.95 * np.sum(body & valid)
    assert np.all(z_d[~z_fg] == 0) and np.all(z_d[z_fg] > 2.0)
    # Without the floor plane the floor around the feet is taken for body.
    _, z_fg_nofloor = obs_maps(jnp.asarray(depth_lo), K_LO,
                               center=jnp.asarray(root, jnp.float32))
    floor_px = np.asarray(z_fg_nofloor > 0) & (label == 0)
    assert floor_px.sum() > 50
    # Far from the person (2 m to the side) nothing qualifies.
    _, z_fg_far = obs_maps(jnp.asarray(depth_lo), K_LO,
                           center=jnp.asarray(root + [2.0, 0, 0], jnp.float32),
                           floor=(jnp.asarray(floor[0]), jnp.asarray(floor[1])))
    assert float(jnp.sum(z_fg_far)) == 0.0


def test_observation_range_is_metric(obs_maps):
    # Hand-placed points around a centre at (0, 0, 3): the cylinder radius, the depth window
    # and the height range, with the camera's -y as up.
    k = Intrinsics.create(fx=100.0, fy=100.0, cx=0.0, cy=0.0, width=5, height=1)
    # Pixels u = 0..4 at these depths are the points (u / 100 * z, 0, z).
    depth = np.array([[3.0, 3.5, 2.1, 3.69, 3.72]], np.float32)
    _, z_fg = obs_maps(jnp.asarray(depth), k, center=jnp.zeros(3, jnp.float32) + jnp.array(
        [0.0, 0.0, 3.0], jnp.float32))
    # u=0: at the centre. u=1: (0.035, 0, 3.5) 0.5 m behind. u=2: (0.042, 0, 2.1) 0.9 m in
    # front. u=3: (0.11, 0, 3.69) 0.69 m behind (inside 0.7). u=4: 0.72 m behind (outside).
    np.testing.assert_array_equal(np.asarray(z_fg), [[1, 1, 1, 1, 0]])
