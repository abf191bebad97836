"""Augmentation that stays exact: rolling the camera about its optical axis; mirroring the image.

Turning the camera by an angle a about its z axis (OpenCV frame: x right, y down, z forward)
moves every pixel on a circle about the principal point and leaves every depth value as it
is, so a rendered view can be rolled without rendering again: the new image is the old one
resampled (nearest pixel) under the 2-D rotation about (cx, cy), and the object's rotation
becomes Rz(a) R (R: object -> camera). Exact for square pixels (fx == fy) up to the nearest-
pixel rounding and the image corners (pixels that come from outside the frame are empty).
Under uniform SO(3) views this gives every training view all of its rolls.

Mirroring the image left-right about the principal point (u -> 2 cx - u) maps every camera point p to
F p, F = diag(-1, 1, 1): the mirrored image is exactly the view of the mirrored object (its points
F_obj x) at the proper rotation F R F_obj, for any reflection F_obj of the object frame. The class of a
ModelNet object is mirror-invariant (a mirrored chair is a chair); its pose and shape are mirrored by
the class's own mirror plane, which the image does not tell (:func:`mirror_depth`, used by
:meth:`hbeo.model.inference.HBEO.predict` for the class answer only; in training, where the class is known,
:mod:`hbeo.model.mirror` mirrors the labels too).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch
from torch.utils.data import Dataset

from hbeo.conventions import Intrinsics
from hbeo.rotations import matrix_to_axis_angle, z_angle_to_matrix


def roll_depth(depth: np.ndarray, K: Intrinsics, angle: float) -> np.ndarray:
    """Depth (H, W) seen by a camera rolled by ``angle`` (radians) about its optical axis: the view
    of the object turned by :func:`hbeo.rotations.z_angle_to_matrix` (angle). Nearest-pixel
    resampling; 0 where the source pixel lies outside the frame."""
    if not math.isclose(K.fx, K.fy, rel_tol=1e-6):
        raise ValueError(f"rolling a view needs square pixels (fx == fy), got fx={K.fx}, fy={K.fy}")
    H, W = depth.shape
    du, dv = _offsets(H, W, K.cx, K.cy)
    c, s = math.cos(angle), math.sin(angle)
    # inverse map: the pixel of the old image that lands on (u, v)
    su = np.rint(c * du + s * dv + K.cx).astype(np.int64)
    sv = np.rint(-s * du + c * dv + K.cy).astype(np.int64)
    ok = (su >= 0) & (su < W) & (sv >= 0) & (sv < H)
    out = np.zeros_like(depth)
    out[ok] = depth[sv[ok], su[ok]]
    return out


def mirror_depth(depth: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Depth (..., H, W) mirrored left-right about the principal point: pixel (u, v) takes the value at
    (2 cx - u, v), nearest pixel; 0 where that lies outside the frame (none when cx = (W - 1) / 2).
    Mirroring twice gives the image back wherever the mirrored column stays inside the frame."""
    W = depth.shape[-1]
    su = np.rint(2 * K.cx - np.arange(W)).astype(np.int64)
    ok = (su >= 0) & (su < W)
    out = np.zeros_like(depth)
    out[..., ok] = depth[..., su[ok]]
    return out


@lru_cache(maxsize=8)
def _offsets(H: int, W: int, cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets (H, W) from the principal point, u - cx and v - cy (read-only, cached)."""
    v, u = np.mgrid[0:H, 0:W]
    du, dv = u - cx, v - cy
    du.flags.writeable = dv.flags.writeable = False
    return du, dv


class RollAugment(Dataset):
    """Items of a view dataset (``depth`` (1, H, W), ``rotation`` (3, 3), ``axis_angle`` (3,), ...)
    rolled by a uniform random angle each time they are read. The angle comes from torch's global
    generator, so a seeded run (and its exact resume, which restores that generator) repeats."""

    def __init__(self, base: Dataset, K: Intrinsics):
        if not math.isclose(K.fx, K.fy, rel_tol=1e-6):
            raise ValueError(f"roll augmentation needs square pixels (fx == fy), got fx={K.fx}, fy={K.fy}")
        self.base, self.K = base, K

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        return roll_item(self.base[i], self.K)


def roll_item(item: dict, K: Intrinsics) -> dict:
    """A copy of view item ``item`` rolled by a uniform random angle (torch's global generator)."""
    item = dict(item)
    a = float(torch.rand(()).item()) * 2 * math.pi
    d = roll_depth(item["depth"][0].numpy(), K, a)
    R = z_angle_to_matrix(a) @ item["rotation"].double().numpy()
    item["depth"] = torch.from_numpy(d)[None]
    item["rotation"] = torch.from_numpy(R.astype(np.float32))
    item["axis_angle"] = torch.from_numpy(matrix_to_axis_angle(R).astype(np.float32))
    return item
