"""Reading depth images and masks from disk, with clear errors.

Formats: 16-bit PNG in millimetres (the Kinect / RealSense convention; scale 0.001 to
metres), float ``.npy`` and float ``.tif``/``.tiff`` in metres. ``depth_scale`` overrides
the factor that turns stored values into metres. 0, NaN and negative values mean "no
measurement". Every problem raises :class:`hbeo.errors.DataError` naming the file.

Plausibility: the median valid depth (after the scale) must lie in :data:`DEPTH_RANGE_M`, which
catches metres stored in a 16-bit PNG (read as millimetres), a wrong ``depth_scale`` and similar
unit mistakes; :func:`parse_intrinsics` rejects a field of view outside :data:`FOV_RANGE_DEG`
(e.g. a focal length of 1e-9 px), pixels far from square and a principal point far outside
the image.

Imports hbeo.errors and hbeo.conventions only.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hbeo.errors import DataError, require_file

SUFFIXES = (".png", ".npy", ".tif", ".tiff")
#: metres: a depth camera's object distances; a median valid depth outside is a unit mistake
DEPTH_RANGE_M = (0.1, 20.0)
#: degrees: plausible horizontal and vertical fields of view of a depth camera's pinhole model
FOV_RANGE_DEG = (1.0, 170.0)
#: largest plausible ratio fx / fy (or fy / fx)
MAX_ASPECT = 4.0


def _read_raw(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except Exception as err:
            raise DataError(path, f"unreadable .npy file ({type(err).__name__}: {err})") from None
    from PIL import Image
    try:
        with Image.open(path) as im:
            pages = getattr(im, "n_frames", 1)
            arr = np.array(im)
    except Exception as err:
        raise DataError(path, f"unreadable image ({type(err).__name__}: {err})") from None
    if pages > 1:
        raise DataError(path, f"the file holds {pages} images (pages or frames); expected one")
    return arr


def read_depth(path, depth_scale: float | None = None) -> np.ndarray:
    """Depth image (H, W) float32 in metres, 0 where there is no measurement."""
    path = Path(path)
    require_file(path, "depth")
    if path.suffix.lower() not in SUFFIXES:
        raise DataError(path, f"unsupported depth format {path.suffix!r}; expected {', '.join(SUFFIXES)}")
    raw = _read_raw(path)
    if raw.ndim != 2:
        raise DataError(path, f"depth must be a single-channel image, got shape {raw.shape}")
    if raw.dtype.kind not in "uif" or raw.dtype == np.uint8:
        raise DataError(path, f"depth has dtype {raw.dtype}; expected 16-bit integers (mm) or floats (m)")
    if depth_scale is None:
        depth_scale = 0.001 if raw.dtype.kind in "ui" else 1.0
    if not np.isfinite(depth_scale) or depth_scale <= 0:
        raise DataError(path, f"depth scale must be positive, got {depth_scale}")
    if raw.size == 0:
        raise DataError(path, f"depth image is empty ({raw.shape[1]}x{raw.shape[0]} pixels)")
    with np.errstate(over="ignore", invalid="ignore"):
        d = raw.astype(np.float64) * depth_scale
    finite = np.isfinite(d)
    if not finite.any():
        nan = np.isnan(d)
        raise DataError(path, "depth is all NaN" if nan.all() else "depth is all infinite" if not nan.any()
                        else "depth has no finite value (only NaN and infinity)")
    d = np.where(finite & (d > 0), d, 0.0)
    if not (d > 0).any():
        raise DataError(path, "depth is all zero (no measurement in the image)" if not np.any(raw)
                        else "depth has no positive finite value (no measurement in the image)")
    med, (lo, hi) = float(np.median(d[d > 0])), DEPTH_RANGE_M
    if not lo <= med <= hi:
        stored = "integers read as millimetres" if raw.dtype.kind in "ui" else "floats read as metres"
        raise DataError(path, f"median depth {med:.3g} m is implausible (expected {lo:g}..{hi:g} m; {stored} "
                              f"times scale {depth_scale:g}); check --depth-scale")
    return d.astype(np.float32)


def _mask_values(path: Path, m: np.ndarray) -> np.ndarray:
    """The 2-D array that marks the object in mask image ``m``: the image itself, or of a colour image (H, W, C)
    its colour channels when its alpha (the last of 2 or 4 channels) is constant, else its alpha when the colours
    are; DataError when both vary (which marks the object is ambiguous)."""
    if m.ndim == 2:
        return m
    alpha = m[..., -1] if m.shape[-1] in (2, 4) else None
    colour = m[..., :-1] if alpha is not None else m
    def still(a):
        return bool((a == a.reshape(-1, *a.shape[2:])[0]).all())
    if alpha is None or still(alpha):
        return colour
    if still(colour):
        return alpha
    raise DataError(path, "mask varies in both colour and alpha, so which marks the object is ambiguous; save "
                          "it as one channel: 0 background, one non-zero value for the object")


def read_mask(path, shape: tuple[int, int]) -> np.ndarray:
    """Bool mask (H, W) from a PNG/.npy/.tif: 0 = background, one non-zero value (or colour) = object; must
    match ``shape``. A colour image marks the object by its colours, or by its alpha where the colours are
    constant. More than two values (a JPEG's or an anti-aliased edge's blur, an instance-label image) are
    refused: thresholding them here would silently take in background pixels."""
    path = Path(path)
    require_file(path, "mask")
    if path.suffix.lower() not in SUFFIXES:
        lossy = " (a lossy format blurs the mask's edges into background pixels)" if path.suffix.lower() in (
            ".jpg", ".jpeg", ".webp") else ""
        raise DataError(path, f"unsupported mask format {path.suffix!r}{lossy}; expected {', '.join(SUFFIXES)}")
    m = _read_raw(path)
    if m.ndim not in (2, 3) or m.size == 0:
        raise DataError(path, f"mask must be a 2-D image (or RGB(A)), got shape {m.shape}")
    if m.dtype.kind not in "buif":
        raise DataError(path, f"mask has dtype {m.dtype}; expected booleans or numbers (non-zero = object)")
    if m.dtype.kind == "f" and not np.isfinite(m).all():
        raise DataError(path, "mask has NaN or infinite values; expected 0 (background) and non-zero (object)")
    m = _mask_values(path, m)
    values = np.unique(m.reshape(-1, *m.shape[2:]), axis=0)
    if len(values) > 2 or (len(values) == 2 and values[0].any()):
        what = "colours" if m.ndim == 3 else "values"
        raise DataError(path, f"mask holds {len(values)} {what} where a mask holds two (0 background, one "
                              "non-zero value for the object): a JPEG's or an anti-aliased edge's blur, or an "
                              "instance-label image; threshold it or pick the object's label (mask == k) yourself")
    if m.ndim == 3:
        m = m.any(axis=-1)
    if m.shape != tuple(shape):
        raise DataError(path, f"mask is {m.shape[1] if m.ndim > 1 else '?'}x{m.shape[0]} but the depth image "
                              f"is {shape[1]}x{shape[0]}")
    if not m.any():
        raise DataError(path, "mask is all zero (no object pixel)")
    return m.astype(bool)


def parse_intrinsics(text: str, width: int, height: int):
    """``"fx,fy,cx,cy"`` (pixels) for an image of ``width`` x ``height`` -> Intrinsics."""
    from hbeo.conventions import Intrinsics
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"intrinsics {text!r}: expected four numbers fx,fy,cx,cy") from None
    if len(vals) != 4:
        raise ValueError(f"intrinsics {text!r}: expected four numbers fx,fy,cx,cy, got {len(vals)}")
    fx, fy, cx, cy = vals
    if not all(np.isfinite(vals)) or fx <= 0 or fy <= 0:
        raise ValueError(f"intrinsics {text!r}: need finite numbers and focal lengths fx, fy > 0")
    if not (-width <= cx <= 2 * width and -height <= cy <= 2 * height):
        raise ValueError(f"intrinsics {text!r}: principal point far outside the {width}x{height} image")
    if max(fx / fy, fy / fx) > MAX_ASPECT:
        raise ValueError(f"intrinsics {text!r}: fx/fy = {fx / fy:.3g}, implausibly non-square pixels")
    lo, hi = FOV_RANGE_DEG
    for axis, f, n in (("horizontal", fx, width), ("vertical", fy, height)):
        fov = float(np.degrees(2 * np.arctan(n / (2 * f))))
        if not lo <= fov <= hi:
            raise ValueError(f"intrinsics {text!r}: {axis} field of view {fov:.3g} degrees for a {width}x{height} "
                             f"image is implausible (expected {lo:g}..{hi:g}); fx, fy are in pixels of this image")
    return Intrinsics(fx, fy, cx, cy, width, height)
