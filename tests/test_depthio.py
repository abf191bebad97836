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


def _disc(h=24, w=32) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w]
    return ((u - 16) ** 2 + (v - 12) ** 2 < 49).astype(np.uint8) * 255


def test_a_mask_is_two_valued_and_says_what_marks_the_object(tmp_path):
    m = _disc()
    Image.fromarray(m).save(tmp_path / "m.png")
    want = read_mask(tmp_path / "m.png", m.shape)
    assert want.sum() == (m > 0).sum()
    la = np.stack([m, np.full_like(m, 255)], -1)                # grey + opaque alpha: the grey marks it
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    assert (read_mask(tmp_path / "la.png", m.shape) == want).all()
    rgba = np.dstack([np.full((*m.shape, 3), 255, np.uint8), m])  # white, the alpha marks it
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    assert (read_mask(tmp_path / "rgba.png", m.shape) == want).all()
    rgb = np.dstack([m, m // 2, np.zeros_like(m)])              # one colour on black
    Image.fromarray(rgb, "RGB").save(tmp_path / "rgb.png")
    assert (read_mask(tmp_path / "rgb.png", m.shape) == want).all()
    both = np.dstack([rgb, m[::-1]])
    Image.fromarray(both, "RGBA").save(tmp_path / "both.png")
    with pytest.raises(DataError, match="both.png.*ambiguous"):
        read_mask(tmp_path / "both.png", m.shape)


def test_a_blurred_or_lossy_mask_is_refused_not_thresholded(tmp_path):
    m = _disc()
    Image.fromarray(m).save(tmp_path / "m.jpg", quality=90)
    with pytest.raises(DataError, match="m.jpg.*lossy format"):
        read_mask(tmp_path / "m.jpg", m.shape)
    soft = m.copy()
    soft[12, 9] = 128                                            # one anti-aliased edge pixel
    Image.fromarray(soft).save(tmp_path / "soft.png")
    with pytest.raises(DataError, match="soft.png: mask holds 3 values"):
        read_mask(tmp_path / "soft.png", m.shape)
    np.save(tmp_path / "labels.npy", (m > 0) * 1 + np.eye(24, 32, dtype=int) * 2)   # an instance-label image
    with pytest.raises(DataError, match="labels.npy.*mask == k"):
        read_mask(tmp_path / "labels.npy", m.shape)
    Image.fromarray(np.where(m > 0, 255, 128).astype(np.uint8)).save(tmp_path / "grey.png")
    with pytest.raises(DataError, match="2 values"):                # no zero background
        read_mask(tmp_path / "grey.png", m.shape)


def test_a_file_of_several_images_is_refused(tmp_path):
    pages = [Image.fromarray(np.full((6, 8), 1.5, np.float32)) for _ in range(3)]
    pages[0].save(tmp_path / "d.tif", save_all=True, append_images=pages[1:])
    with pytest.raises(DataError, match="d.tif: the file holds 3 images"):
        read_depth(tmp_path / "d.tif")
