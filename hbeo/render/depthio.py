"""Reading depth images and masks from disk, with clear errors.

Formats: 16-bit PNG in millimetres (the Kinect / RealSense convention; scale 0.001 to
metres), float ``.npy`` and float ``.tif``/``.tiff`` in metres. ``depth_scale`` overrides
the factor that turns stored values into metres. 0, NaN and negative values mean "no
measurement". Every problem raises :class:`hbeo.errors.DataError` naming the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hbeo.errors import DataError

SUFFIXES = (".png", ".npy", ".tif", ".tiff")


def _read_raw(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except Exception as err:
            raise DataError(path, f"unreadable .npy file ({type(err).__name__}: {err})") from None
    from PIL import Image
    try:
        with Image.open(path) as im:
            return np.array(im)
    except Exception as err:
        raise DataError(path, f"unreadable image ({type(err).__name__}: {err})") from None


def read_depth(path, depth_scale: float | None = None) -> np.ndarray:
    """Depth image (H, W) float32 in metres, 0 where there is no measurement."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "no such depth file")
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
    d = raw.astype(np.float64) * depth_scale
    if np.isnan(d).all():
        raise DataError(path, "depth is all NaN")
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
    if not (d > 0).any():
        raise DataError(path, "depth is all zero (no measurement in the image)")
    return d.astype(np.float32)


def read_mask(path, shape: tuple[int, int]) -> np.ndarray:
    """Bool mask (H, W) from a PNG/.npy/.tif (non-zero = object); must match ``shape``."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "no such mask file")
    m = _read_raw(path)
    if m.ndim == 3:                      # RGB(A) masks: any non-zero channel
        m = m[..., :3].any(axis=-1)
    if m.shape != tuple(shape):
        raise DataError(path, f"mask is {m.shape[1] if m.ndim > 1 else '?'}x{m.shape[0]} but the depth image "
                              f"is {shape[1]}x{shape[0]}")
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
    if not (-width <= cx <= 2 * width and -height <= cy <= 2 * height):
        raise ValueError(f"intrinsics {text!r}: principal point far outside the {width}x{height} image")
    return Intrinsics(fx, fy, cx, cy, width, height)
