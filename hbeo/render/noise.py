"""Kinect-like sensor noise for clean depth images (:class:`SensorNoise`).

Depth images are float32 (H, W) or (N, H, W), metres, 0 = no data, as :class:`hbeo.render.renderer.Renderer`
makes them; pixel (u, v) sees along the camera-frame ray ((u - cx) / fx, (v - cy) / fy, 1) of
:class:`hbeo.conventions.Intrinsics`. Deterministic given the numpy Generator passed in.
Imports :mod:`hbeo.conventions`, numpy and scipy only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hbeo import conventions as C


@dataclass
class SensorNoise:
    """Kinect-like corruption of a clean depth image (all parts optional; zero disables one).

    sigma_a, sigma_b: depth-dependent Gaussian noise, sigma = a + b z^2 (metres; defaults fit
    Nguyen et al. 2012's Kinect axial noise over 0.5-3 m: 1.9 mm at 1 m, 6.4 mm at 2 m).
    disparity_step: z is quantized in disparity (1/z, 1/m) with this step, so depth steps are
    ``disparity_step * z^2`` (1.5 mm at 1 m, 6 mm at 2 m). grazing_deg: pixels whose surface
    normal (from the depth image's gradients) is more than this angle from the viewing ray are
    dropped. edge_p: probability of dropping each pixel within 1 pixel of the silhouette.
    seg_px: the object mask is eroded or dilated (sign random) by 0..seg_px pixels; dilated
    pixels take the depth of the nearest object pixel (mixed pixels at the boundary).
    """

    sigma_a: float = 0.0004
    sigma_b: float = 0.0015
    disparity_step: float = 0.0015
    grazing_deg: float = 78.0
    edge_p: float = 0.3
    seg_px: int = 2

    def apply(self, depth: np.ndarray, K: C.Intrinsics, rng: np.random.Generator) -> np.ndarray:
        """Noisy copy of depth (H, W) or (N, H, W), float32, metres, 0 = no data. Deterministic given rng."""
        d = np.asarray(depth, dtype=np.float32)
        if d.ndim == 3:
            return np.stack([self.apply(x, K, rng) for x in d]) if len(d) else d.copy()
        if d.shape != (K.height, K.width):
            raise ValueError(f"depth image is {d.shape}, intrinsics are for {K.height}x{K.width} (rows x cols)")
        if not np.isfinite(d).all() or (d < 0).any():
            raise ValueError("depth must be finite and >= 0 (0 = no object)")
        from scipy import ndimage
        d = d.copy()
        mask = d > 0
        if not mask.any():
            return d
        keep = mask.copy()
        if self.grazing_deg is not None and self.grazing_deg < 90:
            keep &= _grazing_cos(d, K) >= np.cos(np.radians(self.grazing_deg))
        if self.edge_p > 0:
            border = mask & ~ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool), border_value=0)
            keep &= ~(border & (rng.random(d.shape) < self.edge_p))
        if self.seg_px > 0:
            k = int(rng.integers(0, self.seg_px + 1))
            if k > 0 and rng.random() < 0.5:           # erode the segmentation
                keep &= ndimage.binary_erosion(mask, iterations=k, border_value=0)
            elif k > 0:                                  # dilate: bleed nearest object depths outward
                grown = ndimage.binary_dilation(mask, iterations=k)
                _, (ri, ci) = ndimage.distance_transform_edt(~mask, return_indices=True)
                new = grown & ~mask
                d[new] = d[ri[new], ci[new]]
                keep |= new
        z = d[keep].astype(np.float64)
        if self.sigma_a > 0 or self.sigma_b > 0:
            z = z + rng.normal(size=z.shape) * (self.sigma_a + self.sigma_b * z * z)
        if self.disparity_step and self.disparity_step > 0:
            with np.errstate(divide="ignore"):
                q = np.round(1.0 / (np.maximum(z, 1e-6) * self.disparity_step))
                z = np.where(q > 0, 1.0 / (np.maximum(q, 1) * self.disparity_step), 0.0)
        z[~np.isfinite(z) | (z <= 0)] = 0.0
        out = np.zeros_like(d)
        out[keep] = z.astype(np.float32)
        return out


def _grazing_cos(depth: np.ndarray, K: C.Intrinsics) -> np.ndarray:
    """|cos| of the angle between the surface normal (from depth gradients) and the viewing ray,
    per pixel (H, W); 1 where the normal cannot be estimated (isolated pixels)."""
    H, W = depth.shape
    z = depth.astype(np.float64)
    valid = z > 0
    u = (np.arange(W) - K.cx) / K.fx
    v = (np.arange(H) - K.cy) / K.fy
    P = np.empty((H, W, 3))
    P[..., 0], P[..., 1], P[..., 2] = z * u[None, :], z * v[:, None], z

    def tangent(axis):
        fwd = np.zeros_like(P)
        ok_f = np.zeros((H, W), bool)
        sl_a = [slice(None)] * 2
        sl_b = [slice(None)] * 2
        sl_a[axis], sl_b[axis] = slice(0, -1), slice(1, None)
        sa, sb = tuple(sl_a), tuple(sl_b)
        fwd[sa] = P[sb] - P[sa]
        ok_f[sa] = valid[sb] & valid[sa]
        bwd = np.zeros_like(P)
        ok_b = np.zeros((H, W), bool)
        bwd[sb] = fwd[sa]
        ok_b[sb] = ok_f[sa]
        both = ok_f & ok_b
        tan = np.where(both[..., None], (fwd + bwd) / 2, np.where(ok_f[..., None], fwd, bwd))
        return tan, ok_f | ok_b

    tu, ok_u = tangent(1)
    tv, ok_v = tangent(0)
    n = np.cross(tu, tv)
    nn = np.linalg.norm(n, axis=-1)
    pn = np.linalg.norm(P, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.abs((n * P).sum(-1)) / (nn * pn)
    ok = valid & ok_u & ok_v & (nn > 0)
    return np.where(ok, c, 1.0)
