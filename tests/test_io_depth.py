"""Depth PNG reading: values, lazy sequences, and every kind of bad file."""

import struct
import zlib

import cv2
import numpy as np
import pytest

from posetrack.io import DepthSequence, InputError, probe_depth_png, read_depth, write_depth_png


def _png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image)
    assert ok
    return data.tobytes()


@pytest.fixture
def depth_mm():
    rng = np.random.default_rng(0)
    d = rng.integers(400, 6000, size=(24, 32), dtype=np.uint16)
    d[:3] = 0
    return d


def test_read_depth_converts_units_and_keeps_zero_as_invalid(tmp_path, depth_mm):
    p = tmp_path / "000001.png"
    p.write_bytes(_png(depth_mm))
    d = read_depth(p)
    assert d.dtype == np.float32 and d.shape == (24, 32)
    np.testing.assert_allclose(d, depth_mm / 1000.0, rtol=1e-6)
    assert np.all(d[:3] == 0) and not np.isnan(d).any()
    np.testing.assert_allclose(read_depth(p, scale=5000.0), depth_mm / 5000.0, rtol=1e-6)
    assert probe_depth_png(p) == (24, 32)


def test_write_depth_png_round_trip(tmp_path):
    d = np.array([[0.0, 1.2345, np.nan], [-1.0, 2.0, 65.535]])
    p = tmp_path / "d.png"
    write_depth_png(p, d)
    np.testing.assert_allclose(read_depth(p), [[0, 1.2345, 0], [0, 2.0, 65.535]], atol=6e-4)
    with pytest.raises(ValueError, match="16-bit range"):
        write_depth_png(p, np.full((2, 2), 70.0))


def test_bad_scale_is_rejected(tmp_path, depth_mm):
    p = tmp_path / "1.png"
    p.write_bytes(_png(depth_mm))
    with pytest.raises(ValueError, match="scale"):
        read_depth(p, scale=0.0)


@pytest.mark.parametrize("keep", [0.5, 0.99])
def test_truncated_png(tmp_path, depth_mm, keep):
    data = _png(depth_mm)
    p = tmp_path / "000007.png"
    p.write_bytes(data[: int(len(data) * keep)])
    for reader in (read_depth, probe_depth_png):
        with pytest.raises(InputError, match="truncated") as info:
            reader(p)
        assert info.value.path == str(p) and str(p) in str(info.value)
        assert info.value.field == "PNG chunks"


def test_png_missing_only_iend_is_truncated(tmp_path, depth_mm):
    p = tmp_path / "3.png"
    p.write_bytes(_png(depth_mm)[:-12])
    with pytest.raises(InputError, match="truncated"):
        probe_depth_png(p)


def test_trailing_bytes_after_iend_are_tolerated(tmp_path, depth_mm):
    p = tmp_path / "3.png"
    p.write_bytes(_png(depth_mm) + b"\x00" * 40)
    assert probe_depth_png(p) == (24, 32)
    assert read_depth(p).shape == (24, 32)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"\xff\xd8\xff\xe0" + b"\x00" * 100, "JPEG"),
        (b"depth would be here\n", "text file"),
        (bytes(range(200)), "not a PNG"),
    ],
)
def test_non_png_named_png(tmp_path, content, match):
    p = tmp_path / "000002.png"
    p.write_bytes(content)
    with pytest.raises(InputError, match=match) as info:
        read_depth(p)
    assert info.value.field == "signature" and info.value.value == content[:8]


def test_real_jpeg_named_png(tmp_path):
    ok, jpg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    p = tmp_path / "000002.png"
    p.write_bytes(jpg.tobytes())
    with pytest.raises(InputError, match="JPEG"):
        probe_depth_png(p)


def test_8bit_png(tmp_path):
    p = tmp_path / "000003.png"
    p.write_bytes(_png(np.full((4, 5), 200, np.uint8)))
    with pytest.raises(InputError, match="an 8-bit grayscale PNG") as info:
        read_depth(p)
    assert info.value.field == "IHDR.bit_depth" and info.value.value == 8
    assert "16-bit" in str(info.value)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_rgb_png(tmp_path, dtype):
    p = tmp_path / "000004.png"
    p.write_bytes(_png(np.ones((4, 5, 3), dtype)))
    for reader in (read_depth, probe_depth_png):
        with pytest.raises(InputError, match="RGB PNG") as info:
            reader(p)
        assert info.value.field == "IHDR.color_type" and info.value.value == "RGB"
        assert "single-channel" in str(info.value)


def test_empty_file(tmp_path):
    p = tmp_path / "000005.png"
    p.write_bytes(b"")
    with pytest.raises(InputError, match="empty") as info:
        read_depth(p)
    assert info.value.value == 0


def test_zero_size_image(tmp_path, depth_mm):
    data = bytearray(_png(depth_mm))
    data[16:20] = struct.pack(">I", 0)  # IHDR width = 0, with a valid CRC
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    p = tmp_path / "000006.png"
    p.write_bytes(bytes(data))
    with pytest.raises(InputError, match="zero size") as info:
        read_depth(p)
    assert info.value.value == (0, 24) and "IHDR.width" in info.value.field


def test_corrupt_pixel_data(tmp_path, depth_mm):
    data = bytearray(_png(depth_mm))
    idat = data.index(b"IDAT")
    data[idat + 10 : idat + 40] = b"\x00" * 30
    p = tmp_path / "000008.png"
    p.write_bytes(bytes(data))
    with pytest.raises(InputError, match="decoded") as info:
        read_depth(p)
    assert info.value.field == "image data"


def test_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="cannot be read") as info:
        read_depth(tmp_path / "absent.png")
    assert info.value.field == "file"
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(InputError, match="folder"):
        read_depth(tmp_path / "dir.png")
    with pytest.raises(InputError, match="folder"):
        probe_depth_png(tmp_path / "dir.png")


def test_depth_sequence_is_lazy_and_checks_size(tmp_path, depth_mm, monkeypatch):
    paths = []
    for i in range(3):
        paths.append(tmp_path / f"{i}.png")
        paths[-1].write_bytes(_png(depth_mm + i))
    reads = []
    import posetrack.io._depth as depth_module

    real = depth_module.read_depth
    def counting_read(p, **kw):
        reads.append(p)
        return real(p, **kw)

    monkeypatch.setattr(depth_module, "read_depth", counting_read)
    seq = DepthSequence([paths[0], None, paths[2]], frame_ids=np.arange(3), shape=(24, 32))
    assert reads == [] and len(seq) == 3
    np.testing.assert_allclose(seq[-1], (depth_mm + 2) / 1000.0, rtol=1e-6)
    assert reads == [paths[2]]
    assert np.all(seq[1] == 0) and seq[1].dtype == np.float32
    sub = seq[1:]
    assert isinstance(sub, DepthSequence) and sub.frame_ids.tolist() == [1, 2]
    assert len(list(seq)) == 3
    with pytest.raises(IndexError):
        seq[3]
    wrong = DepthSequence([paths[0]], frame_ids=np.arange(1), shape=(48, 64), size_source="K.json")
    with pytest.raises(InputError, match="32x24 but K.json is 64x48"):
        wrong[0]
