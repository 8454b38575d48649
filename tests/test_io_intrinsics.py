"""Intrinsics files: the JSON layouts and OpenCV YAML/XML agree, non-physical values are named
errors."""

import json

import cv2
import numpy as np
import pytest

from posetrack import Intrinsics
from posetrack.io import InputError, read_intrinsics, read_intrinsics_json, write_intrinsics_json
from posetrack.io._intrinsics import read_intrinsics_file

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


# -- OpenCV YAML/XML (cv::FileStorage) ---------------------------------------------------------

K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])


def _filestorage(path, entries):
    """Write ``entries`` with cv2.FileStorage (the format follows the extension)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        fs.write(key, value)
    fs.release()
    return path


@pytest.mark.parametrize("ext", ["yml", "yaml", "xml"])
@pytest.mark.parametrize("key", ["camera_matrix", "cameraMatrix"])
def test_opencv_calibration_file_round_trip(tmp_path, ext, key):
    path = _filestorage(
        tmp_path / f"calib.{ext}",
        {"image_width": W, "image_height": H, key: K, "distortion_coefficients": np.zeros((5, 1))},
    )
    read = read_intrinsics_file(path)
    assert read.intrinsics.to_dict() == {
        "fx": FX, "fy": FY, "cx": CX, "cy": CY, "width": W, "height": H,
    }  # fmt: skip
    assert read.size_in_file and read.notes == []  # zero distortion: nothing to say
    assert read.layout.endswith("(OpenCV XML)" if ext == "xml" else "(OpenCV YAML)")
    assert read_intrinsics(path).to_dict() == read_intrinsics_json(path).to_dict()


def test_ros_calibration_yaml_and_a_yaml_header_without_the_extension(tmp_path):
    # camera_calibration's ost.yaml: no %YAML header, no !!opencv-matrix tag.
    ros = (
        f"image_width: {W}\nimage_height: {H}\ncamera_name: narrow_stereo\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: [{FX}, 0, {CX}, 0, {FY}, {CY}, 0, 0, 1]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n"
    )
    assert read_intrinsics(_write(tmp_path, ros, "ost.yaml")).cx == CX
    # Any extension: a text starting with %YAML is OpenCV YAML, not JSON.
    assert read_intrinsics(_write(tmp_path, "%YAML:1.0\n---\n" + ros, "camera.txt")).fy == FY


def _easymocap(tmp_path, dist=(0.0, 0.0, 0.0, 0.0, 0.0)):
    """intri.yml as EasyMocap's FileStorage writes it (by hand: CRLF, quoted names, no size).
    Camera "02" is camera "01" with twice the focal length."""
    lines = ["%YAML:1.0", "---", "names:", '  - "01"', '  - "02"']
    for name, f in (("01", 1.0), ("02", 2.0)):
        k = K * [[f], [f], [1]]
        lines += [f"K_{name}: !!opencv-matrix", "  rows: 3", "  cols: 3", "  dt: d",
                  f"  data: [{', '.join(f'{v:.6f}' for v in k.ravel())}]"]  # fmt: skip
        lines += [f"dist_{name}: !!opencv-matrix", "  rows: 1", "  cols: 5", "  dt: d",
                  f"  data: [{', '.join(f'{v:.6f}' for v in dist)}]"]  # fmt: skip
    path = tmp_path / "intri.yml"
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode())
    return path


def test_easymocap_intri_yml_choose_a_camera_by_name(tmp_path):
    path = _easymocap(tmp_path)
    with pytest.raises(InputError, match="holds 2 cameras") as info:
        read_intrinsics(path, image_size=(W, H))
    assert (info.value.field, info.value.value) == ("names", ["01", "02"])
    assert f"{path}#01" in str(info.value)  # says how to choose
    k = read_intrinsics(f"{path}#02", image_size=(W, H))
    assert (k.fx, k.fy, k.width, k.height) == (2 * FX, 2 * FY, W, H)
    read = read_intrinsics_file(f"{path}#01", image_size=(W, H))
    assert read.intrinsics.fx == FX and read.layout.startswith("EasyMocap") and "01" in read.layout
    assert not read.size_in_file
    with pytest.raises(InputError, match="no camera '03'") as info:
        read_intrinsics(f"{path}#03", image_size=(W, H))
    assert info.value.field == "names" and "01, 02" in str(info.value)


def test_one_camera_needs_no_name_and_takes_its_size(tmp_path):
    # EasyVolcap's variant writes W_<name> / H_<name>; written here by cv2.FileStorage (XML).
    path = _filestorage(
        tmp_path / "intri.xml",
        {"names": ["cam0"], "K_cam0": K, "dist_cam0": np.zeros((1, 5)), "W_cam0": W, "H_cam0": H},
    )
    read = read_intrinsics_file(path)
    assert read.intrinsics.to_dict()["cx"] == CX and read.size_in_file
    with pytest.raises(InputError, match="holds one camera") as info:
        read_intrinsics(_filestorage(tmp_path / "c.yml", {"camera_matrix": K}).with_name("c.yml#x"))
    assert info.value.field == "#x"


def test_file_without_a_size_says_so_and_how_to_give_it(tmp_path):
    with pytest.raises(InputError, match="gives no image size") as info:
        read_intrinsics(f"{_easymocap(tmp_path)}#01")
    err = info.value
    assert err.field == "W_01 / H_01" and err.value is None
    assert "image_size=" in str(err) and "depth images" in str(err) and "--size" in str(err)
    # A size in the file wins over image_size.
    path = _filestorage(tmp_path / "calib.yml", {"image_width": W, "image_height": H, "K": K})
    assert read_intrinsics(path, image_size=(10, 10)).width == W
    path = _filestorage(tmp_path / "half.yml", {"image_width": W, "camera_matrix": K})
    with pytest.raises(InputError, match="needs both image_height and image_width") as info:
        read_intrinsics(path, image_size=(W, H))
    assert info.value.field == "image_height"


def test_distortion_is_ignored_with_a_note(tmp_path):
    read = read_intrinsics_file(f"{_easymocap(tmp_path, dist=(0.1, -0.2, 0, 0, 0))}#02",
                                image_size=(W, H))  # fmt: skip
    assert len(read.notes) == 1 and "dist_02" in read.notes[0]
    assert "ignored" in read.notes[0] and "undistorted" in read.notes[0]
    path = _filestorage(
        tmp_path / "calib.xml",
        {"image_width": W, "image_height": H, "camera_matrix": K,
         "distortion_coefficients": np.array([[0.0, 0.01, 0.0, 0.0, 0.0]])},
    )  # fmt: skip
    (note,) = read_intrinsics_file(path).notes
    assert "distortion_coefficients" in note


@pytest.mark.parametrize(
    ("text", "field", "match"),
    [
        ("%YAML:1.0\n---\nimage_width: 640\nimage_height 480\n", "line 4", "Missing ':'"),
        ("<?xml version=\"1.0\"?>\n<opencv_storage>\n<a>1</a>\n", "line 3", "not valid"),
        ("%YAML:1.0\n---\n- 1\n- 2\n", "(top level)", "expected a map"),
        ("%YAML:1.0\n---\nimage_width: 640\n", "(top level)", "no known intrinsics layout"),
        (
            "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix"
            "\n  rows: 3\n  cols: 4\n  dt: d\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0]\n",
            "camera_matrix.cols", "is 4; the camera matrix is 3x3",
        ),
        (
            "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix"
            "\n  rows: 3\n  cols: 3\n  dt: d\n  data: [500, 0, 320, 0, .nan, 240, 0, 0, 1]\n",
            "camera_matrix.data[4]", "finite",
        ),
        (
            "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncameraMatrix: !!opencv-matrix"
            "\n  rows: 3\n  cols: 3\n  dt: d\n  data: [500, 0, 320, 0, 500, 900, 0, 0, 1]\n",
            "cameraMatrix.data[5]", "outside the image",
        ),
        ("\n\n", "file", "empty"),
    ],
)  # fmt: skip
def test_malformed_opencv_files_name_the_field(tmp_path, text, field, match):
    path = _write(tmp_path, text, "calib.yml")
    with pytest.raises(InputError, match=match) as info:
        read_intrinsics(path)
    assert info.value.field == field
    assert str(info.value).startswith(f"{path}: {field}: ")


def test_a_file_named_with_a_hash_is_read_as_it_is(tmp_path):
    path = _write(tmp_path, LAYOUTS["plain"], "take#2.json")
    assert read_intrinsics(path).fx == FX
    with pytest.raises(InputError, match="cannot be read"):
        read_intrinsics(tmp_path / "absent.yml#01")
