"""Intrinsics JSON: the three layouts agree, non-physical values are named errors."""

import json

import pytest

from posetrack import Intrinsics
from posetrack.io import InputError, read_intrinsics_json, write_intrinsics_json

FX, FY, CX, CY, W, H = 525.0, 523.5, 319.5, 239.25, 640, 480

LAYOUTS = {
    "open3d": {"width": W, "height": H, "intrinsic_matrix": [FX, 0, 0, 0, FY, 0, CX, CY, 1]},
    "plain": {"fx": FX, "fy": FY, "cx": CX, "cy": CY, "width": W, "height": H},
    "ros1": {
        "width": W,
        "height": H,
        "distortion_model": "plumb_bob",
        "D": [0, 0, 0, 0, 0],
        "K": [FX, 0, CX, 0, FY, CY, 0, 0, 1],
    },
    "ros2": {"width": W, "height": H, "k": [FX, 0, CX, 0, FY, CY, 0, 0, 1]},
    "rows": {"width": W, "height": H, "K": [[FX, 0, CX], [0, FY, CY], [0, 0, 1]]},
    "ros_calibration": {
        "image_width": W,
        "image_height": H,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [FX, 0, CX, 0, FY, CY, 0, 0, 1]},
    },
    "plain_and_ros": {
        "fx": FX, "fy": FY, "cx": CX, "cy": CY, "width": W, "height": H,
        "K": [FX, 0, CX, 0, FY, CY, 0, 0, 1],
    },
}  # fmt: skip


def _write(tmp_path, doc, name="intrinsics.json"):
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_gives_the_same_numbers(tmp_path, layout):
    k = read_intrinsics_json(_write(tmp_path, LAYOUTS[layout]))
    assert k.to_dict() == {"fx": FX, "fy": FY, "cx": CX, "cy": CY, "width": W, "height": H}


@pytest.mark.parametrize("layout", ["plain", "open3d", "ros"])
def test_write_read_round_trip(tmp_path, layout):
    k = Intrinsics.create(fx=FX, fy=FY, cx=CX, cy=CY, width=W, height=H)
    path = tmp_path / f"{layout}.json"
    write_intrinsics_json(path, k, layout=layout)
    assert read_intrinsics_json(path).to_dict() == k.to_dict()


def _bad(**changes):
    doc = dict(LAYOUTS["plain"])
    for key, value in changes.items():
        if value is None:
            doc.pop(key)
        else:
            doc[key] = value
    return doc


@pytest.mark.parametrize(
    ("doc", "field", "value", "match"),
    [
        (_bad(fx=0), "fx", 0.0, "must be positive"),
        (_bad(fy=-500.0), "fy", -500.0, "must be positive"),
        (_bad(cx=700.0), "cx", 700.0, "outside the image"),
        (_bad(cy=-3.0), "cy", -3.0, "outside the image"),
        (_bad(width=0), "width", 0, "positive integer"),
        (_bad(height=479.5), "height", 479.5, "positive integer"),
        (_bad(width=None), "width", None, "missing"),
        (_bad(fx="525"), "fx", "525", "expected a number"),
        (_bad(fx=True), "fx", True, "expected a number"),
        (_bad(cy=None), "cy", None, "missing"),
        (
            {"width": W, "height": H, "intrinsic_matrix": [FX, 0, 0, 0, -FY, 0, CX, CY, 1]},
            "intrinsic_matrix[4]", -FY, "must be positive",
        ),
        (
            {"width": W, "height": H, "K": [FX, 0, 9000, 0, FY, CY, 0, 0, 1]},
            "K[2]", 9000.0, "outside the image",
        ),
        (
            {"width": W, "height": H, "K": [FX, 0.5, CX, 0, FY, CY, 0, 0, 1]},
            "K[1]", 0.5, "skew",
        ),
        (
            {"width": W, "height": H, "K": [FX, 0, CX, 0, FY, CY, 0, 0, 2]},
            "K[8]", 2.0, "must be 1",
        ),
        ({"width": W, "height": H, "K": [FX, 0, CX]}, "K", [FX, 0, CX], "expected 9"),
        (
            {"width": W, "height": H, "intrinsic_matrix": [FX, 0, CX, 0, FY, CY, 0, 0, 1]},
            "intrinsic_matrix", [FX, 0, CX, 0, FY, CY, 0, 0, 1], "looks row-major",
        ),
        (
            {"width": W, "height": H, "K": [FX, 0, 0, 0, FY, 0, CX, CY, 1]},
            "K", [FX, 0, 0, 0, FY, 0, CX, CY, 1], "looks column-major",
        ),
        ({"focal": 500, "size": [W, H]}, "(top level)", ["focal", "size"], "no known"),
        ([FX, FY, CX, CY], "(top level)", "list", "expected an object"),
        (
            {**LAYOUTS["plain"], "K": [FX + 1, 0, CX, 0, FY, CY, 0, 0, 1]},
            "K[0] / fx", (FX + 1, FX), "disagree",
        ),
    ],
)  # fmt: skip
def test_non_physical_or_malformed_intrinsics(tmp_path, doc, field, value, match):
    path = _write(tmp_path, doc)
    with pytest.raises(InputError, match=match) as info:
        read_intrinsics_json(path)
    err = info.value
    assert (err.field, err.value) == (field, value)
    assert str(err).startswith(f"{path}: {field}: ")


def test_nan_and_empty_files(tmp_path):
    path = _write(tmp_path, '{"fx": NaN, "fy": 1, "cx": 1, "cy": 1, "width": 2, "height": 2}')
    with pytest.raises(InputError, match="finite") as info:
        read_intrinsics_json(path)
    assert info.value.field == "fx"
    with pytest.raises(InputError, match="empty"):
        read_intrinsics_json(_write(tmp_path, ""))
    with pytest.raises(InputError, match="cannot be read"):
        read_intrinsics_json(tmp_path / "absent.json")
