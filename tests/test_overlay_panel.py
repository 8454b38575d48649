"""The overlay's 3D panel (``posetrack.app._panel``) and the video it widens.

Synthetic keypoints of the body model, no tracker: nothing here compiles a JAX program beyond
one forward-kinematics call.
"""

from __future__ import annotations

import warnings

import imageio.v3 as iio
import numpy as np
import pytest

import posetrack
from posetrack import _body as body
from posetrack._depthobs import NO_FLOOR
from posetrack.app import PANELS, SkeletonPanel, render_panel
from posetrack.app._cli import _video_panel, build_parser
from posetrack.app._overlay import write_overlay
from posetrack.app._panel import BACKGROUND, FLOOR, GRID, pelvis
from posetrack.app._viz import GREEN, RED

T, W, H = 12, 160, 120
WALK = np.linspace(0.0, 1.0, T)  # metres the person moves away from the camera, per frame


@pytest.fixture(scope="module")
def standing():
    """(18, 3) COCO-18 keypoints, camera frame: a person facing the camera 3 m away."""
    return np.asarray(body.keypoints(body.BodyShape.default(), body.facing_camera_params(3.0)))


@pytest.fixture(scope="module")
def walk(standing):
    """(T, 18, 3): the person walking 1 m straight away from a level camera."""
    return standing[None] + WALK[:, None, None] * np.array([0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def floor(standing):
    """The floor 8 cm below the ankles of a level camera (y down): ``n @ p + d`` = height."""
    return np.array([0.0, -1.0, 0.0, standing[:, 1].max() + 0.08])


def close_to(image, colour, tol=40):
    """``(H, W)`` bool: pixels within ``tol`` (sum of absolute RGB differences) of ``colour``."""
    return np.abs(image.astype(int) - np.asarray(colour)).sum(-1) < tol


def around(image, u, v, r=1):
    """The ``(2r+1, 2r+1, 3)`` pixels centred on ``(u, v)``, which must lie inside ``image``
    (a slice past an edge would be empty, and an empty check passes)."""
    u, v = round(u), round(v)
    assert r <= u < image.shape[1] - r and r <= v < image.shape[0] - r, (u, v, image.shape)
    return image[v - r : v + r + 1, u - r : u + r + 1]


def pixel(image, u, v):
    return around(image, u, v, r=0)[0, 0]


def read_video(path):
    with warnings.catch_warnings():  # imageio starts FFmpeg; JAX warns at any fork
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        return iio.imread(path, index=None)


def overlay(tmp_path, walk, **kwargs):
    intr = posetrack.Intrinsics.create(fx=150, fy=150, cx=W / 2, cy=H / 2, width=W, height=H)
    rgb = [np.full((H, W, 3), 90, np.uint8) for _ in range(T)]
    path = write_overlay(
        tmp_path / "overlay", keypoints3d=walk, status=np.zeros(T, int), delta=np.full(T, 0.3),
        frame_ids=np.arange(T), intrinsics=intr, fps=10.0, rgb=rgb, **kwargs,
    )  # fmt: skip
    assert path.suffix == ".mp4"
    return read_video(path)


# -- the panel --------------------------------------------------------------------------------


@pytest.mark.parametrize("with_floor", [True, False])
def test_side_view_draws_the_pelvis_and_neck_at_their_depth_and_height(walk, floor, with_floor):
    panel = SkeletonPanel(walk, kind="side", height=H, floor=floor if with_floor else None)
    image = panel.render(5)
    for x, y, z in (pelvis(walk[5]), walk[5, 1]):
        # Side view by hand: across = depth (the camera's z, level camera), up = -y, measured
        # from the floor (n @ p + d) where there is one, else from the camera.
        up = floor[:3] @ [x, y, z] + floor[3] if with_floor else -y
        u, v = panel.pixel_of(z, up)
        assert close_to(around(image, u, v), GREEN).all()
        # ... and nowhere near the same height a metre closer (the walk stays behind it).
        u_near = panel.pixel_of(z - 1.0, up)[0]
        assert not close_to(around(image, u_near, v, r=2), GREEN).any()


def test_top_view_draws_the_pelvis_at_its_x_and_depth(walk, floor):
    panel = SkeletonPanel(walk + [0.4, 0.0, 0.0], kind="top", height=H, floor=floor)
    x, _, z = pelvis(walk[7] + [0.4, 0.0, 0.0])
    u, v = panel.pixel_of(x, z)
    assert close_to(around(panel.render(7), u, v), GREEN).all()
    # x to the right, depth upwards: further away is higher up in the panel.
    assert panel.pixel_of(x + 1, z)[0] > u and panel.pixel_of(x, z + 1)[1] < v


def test_skeleton_takes_the_status_colour(walk):
    status = np.zeros(T, int)
    status[3] = 1
    panel = SkeletonPanel(walk, status, kind="side", height=H)
    (u, v), _ = panel.project(pelvis(walk[3]))
    u, v = round(u), round(v)
    assert close_to(around(panel.render(3), u, v), RED).all()


def test_floor_line_only_with_a_floor(walk, floor):
    with_floor = SkeletonPanel(walk, kind="side", height=H, floor=floor)
    row = round(with_floor.pixel_of(0.0, 0.0)[1])
    left, _, right, _ = with_floor.box
    line = close_to(with_floor.render(0)[row, left:right], FLOOR)
    assert line.mean() > 0.8, line.mean()
    for unknown in (None, np.asarray(NO_FLOOR), np.full(4, np.nan)):
        panel = SkeletonPanel(walk, kind="side", height=H, floor=unknown)
        assert not panel.has_floor
        assert not close_to(panel.render(0), FLOOR, tol=30).any()


def test_scale_is_fixed_by_the_clip_and_robust_to_a_stray_keypoint(walk):
    panel = SkeletonPanel(walk, kind="side", height=H)
    stray = walk.copy()
    stray[4, 9] = [0.0, 0.0, 40.0]  # one keypoint 40 m away in one frame
    assert SkeletonPanel(stray, kind="side", height=H).scale == pytest.approx(panel.scale)
    # Every frame is drawn at that one scale: the walk's first and last pelvis are 1 m apart.
    (u0, _), _ = panel.project(pelvis(walk[0]))
    (u1, _), _ = panel.project(pelvis(walk[-1]))
    assert u1 - u0 == pytest.approx(panel.scale * 1.0)
    # ... and the panel leaves room for the whole walk.
    left, top, right, bottom = panel.box
    assert (panel.uv[panel.valid] >= [left, top]).all()
    assert (panel.uv[panel.valid] <= [right, bottom]).all()


def test_trail_shows_where_the_pelvis_was(walk):
    def empty(pixel):  # nothing drawn there: the background or a grid line
        return close_to(pixel, BACKGROUND, tol=10) or close_to(pixel, GRID, tol=10)

    panel = SkeletonPanel(walk, kind="top", height=H, fps=10.0, trail_s=1.5)
    (u6, v6), (u11, v11) = (np.round(panel.project(pelvis(walk[t]))[0]).astype(int)
                            for t in (6, 11))  # fmt: skip
    assert not empty(pixel(panel.render(11), u6, v6))  # where the pelvis was half a second ago
    assert empty(pixel(panel.render(6), u11, v11))  # not where it will be
    no_trail = SkeletonPanel(walk, kind="top", height=H, fps=10.0, trail_s=0.0)
    assert empty(pixel(no_trail.render(11), u6, v6))


def test_render_panel_is_one_frame_of_the_panel(walk, floor):
    image = render_panel(walk, 4, kind="top", height=96, floor=floor, fps=10.0)
    assert image.shape == (96, 96, 3) and image.dtype == np.uint8
    same = SkeletonPanel(walk, kind="top", height=96, floor=floor, fps=10.0).render(4)
    np.testing.assert_array_equal(image, same)
    with pytest.raises(ValueError, match="outside"):
        render_panel(walk, T, height=96)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"kind": "front"}, "kind must be one of"),
        ({"height": 40}, "too small"),
        ({"fps": 0.0}, "fps"),
        ({"status": np.zeros(3)}, "status must be"),
    ],
)
def test_bad_panel_arguments(walk, kwargs, match):
    with pytest.raises(ValueError, match=match):
        SkeletonPanel(walk, **kwargs)


# -- the video --------------------------------------------------------------------------------


def test_video_is_the_image_plus_the_panel(tmp_path, walk, floor):
    frames = overlay(tmp_path, walk, panel="side", floor=floor)
    panel = SkeletonPanel(walk, kind="side", height=H, floor=floor, fps=10.0)
    assert frames.shape == (T, H, W + panel.width, 3) and panel.width == H
    for t in (0, T - 1):  # the skeleton where the panel's projection puts it
        (u, v), _ = panel.project(pelvis(walk[t]))
        u, v = W + round(u), round(v)
        # H.264 halves the colour resolution: most of the 3x3 pixels, at a looser tolerance.
        assert close_to(around(frames[t], u, v), GREEN, tol=90).sum() >= 6, t
    # One scale for the clip: the grid and tick labels (below the plot) never change.
    bottom = panel.box[3]
    labels = frames[:, bottom + 2 :, W:].astype(int)
    assert np.abs(labels - labels[0]).max() < 24
    assert np.abs(frames[T - 1, bottom + 2 :, W:].astype(int) - panel.background[bottom + 2 :]
                  ).mean() < 3  # fmt: skip


def test_video_frame_width_stays_even(tmp_path, walk):
    intr = posetrack.Intrinsics.create(fx=150, fy=150, cx=80, cy=60, width=161, height=120)
    path = write_overlay(
        tmp_path / "odd", keypoints3d=walk, status=np.zeros(T, int), delta=np.full(T, 0.3),
        frame_ids=np.arange(T), intrinsics=intr, fps=10.0,
        rgb=[np.zeros((120, 161, 3), np.uint8)] * T, panel="top",
    )  # fmt: skip
    assert read_video(path).shape == (T, 120, 161 + 121, 3)


def test_no_panel_keeps_the_image_size(tmp_path, walk):
    assert overlay(tmp_path, walk, panel=None).shape == (T, H, W, 3)


def test_write_overlay_refuses_an_unknown_panel(tmp_path, walk):
    with pytest.raises(ValueError, match="panel must be one of"):
        overlay(tmp_path, walk, panel="front")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("command", ["track", "track-many"])
def test_video_panel_flag(command, capsys):
    def parse(*flags):
        required = ["--manifest", "m.csv"] if command == "track-many" else ["--depth", "d"]
        return build_parser().parse_args([command, "--out", "o", *required, *flags])

    assert PANELS == ("side", "top")
    assert _video_panel(parse()) == "side"
    assert _video_panel(parse("--video-panel", "top")) == "top"
    assert _video_panel(parse("--video-panel", "none")) is None
    with pytest.raises(SystemExit) as exit_:
        parse("--video-panel", "front")
    assert exit_.value.code == 2 and "--video-panel" in capsys.readouterr().err


def test_line_plot_draws_series_past_the_palette_dashed():
    """Eleven series: the eleventh repeats the first one's colour, so it is drawn dashed (gaps
    of background along its line), the first solid."""
    from posetrack.app import line_plot
    from posetrack.app._viz import PALETTE

    x = [0.0, 10.0]
    series = {f"s{k}": (x, [float(k), float(k)]) for k in range(11)}
    img = line_plot(series, size=(400, 300), ylim=(-1.0, 11.0))

    # Inside the plot, clear of the end markers and the legend: the rows where the first
    # colour appears are the two series' lines, y = 10 (top) and y = 0 (bottom).
    colour = np.array(PALETTE[0], np.uint8)
    hit = np.abs(img[:, 90:300].astype(int) - colour).sum(-1) < 60
    rows = np.flatnonzero(hit.any(1))
    solid, dashed = hit[rows.max()].mean(), hit[rows.min()].mean()
    assert solid > 0.95, solid
    assert 0.3 < dashed < 0.8, dashed
