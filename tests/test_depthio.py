import numpy as np
import pytest
from PIL import Image

from hbeo.model.depthfile import parse_intrinsics, read_depth, read_mask
from hbeo.errors import DataError


def test_16bit_png_in_millimetres(tmp_path):
    mm = np.zeros((24, 32), np.uint16)
    mm[5:10, 5:10] = 1500
    Image.fromarray(mm).save(tmp_path / "d.png")
    d = read_depth(tmp_path / "d.png")
    assert d.dtype == np.float32 and d.max() == pytest.approx(1.5) and (d == 0).sum() == 24 * 32 - 25
    assert read_depth(tmp_path / "d.png", depth_scale=0.0001).max() == pytest.approx(0.15)


def test_float_npy_and_tiff_in_metres(tmp_path):
    d = np.zeros((24, 32), np.float32)
    d[3, 4] = 2.25
    d[0, 0] = np.nan
    np.save(tmp_path / "d.npy", d)
    Image.fromarray(d).save(tmp_path / "d.tiff")
    for name in ("d.npy", "d.tiff"):
        out = read_depth(tmp_path / name)
        assert out[3, 4] == pytest.approx(2.25) and out[0, 0] == 0 and np.isfinite(out).all()


@pytest.mark.parametrize("make, msg", [
    (lambda p: p.write_bytes(b"not an image"), "unreadable image"),
    (lambda p: Image.fromarray(np.zeros((4, 4), np.uint16)).save(p), "all zero"),
    (lambda p: Image.fromarray(np.full((4, 4), 9, np.uint8)).save(p), "dtype uint8"),
    (lambda p: Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(p), "single-channel"),
])
def test_bad_depth_files(tmp_path, make, msg):
    p = tmp_path / "bad.png"
    make(p)
    with pytest.raises(DataError, match=msg) as err:
        read_depth(p)
    assert "bad.png" in str(err.value)


def test_missing_and_nan_files(tmp_path):
    with pytest.raises(DataError, match="no such depth file"):
        read_depth(tmp_path / "x.png")
    np.save(tmp_path / "nan.npy", np.full((3, 3), np.nan))
    with pytest.raises(DataError, match="all NaN"):
        read_depth(tmp_path / "nan.npy")
    (tmp_path / "x.jpg").write_bytes(b"")
    with pytest.raises(DataError, match="unsupported depth format"):
        read_depth(tmp_path / "x.jpg")


def test_masks_and_intrinsics(tmp_path):
    Image.fromarray(np.eye(4, dtype=np.uint8) * 255).save(tmp_path / "m.png")
    assert read_mask(tmp_path / "m.png", (4, 4)).sum() == 4
    with pytest.raises(DataError, match="mask is 4x4 but the depth image is 8x6"):
        read_mask(tmp_path / "m.png", (6, 8))
    K = parse_intrinsics("525,525,319.5,239.5", 640, 480)
    assert K.fx == 525 and K.width == 640
    for bad in ("525,525,319.5", "a,b,c,d", "-5,525,319,239", "525,525,5000,239"):
        with pytest.raises(ValueError):
            parse_intrinsics(bad, 640, 480)
