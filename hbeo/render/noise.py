"""Kinect-like sensor noise for clean depth images (:class:`SensorNoise`).

Depth images are float32 (H, W) or (N, H, W), metres, 0 = no data, as :class:`hbeo.render.renderer.Renderer`
makes them; pixel (u, v) sees along the camera-frame ray ((u - cx) / fx, (v - cy) / fy, 1) of
:class:`hbeo.conventions.Intrinsics`. Deterministic given the numpy Generator passed in.
Also the bounds of where and on which views the noise is applied (:data:`MAX_NOISE_SCALE`,
:func:`whole_noisy_views`) and the checks of the commands' ``--noise-scale`` and ``--noise-fraction``, shared by
:class:`hbeo.render.views.RenderSettings`, ``train`` and ``evaluate``.
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
        mask = d > 0
        if not mask.any():
            return d.copy()
        rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
        pad = max(int(self.seg_px), 0) + 2      # the silhouette's ring, erosion and dilation stay inside
        box = (max(rows[0] - pad, 0), min(rows[-1] + pad + 1, d.shape[0]),
               max(cols[0] - pad, 0), min(cols[-1] + pad + 1, d.shape[1]))
        return self._apply_box(d, K, rng, box)

    def _apply_box(self, d: np.ndarray, K: C.Intrinsics, rng: np.random.Generator, box) -> np.ndarray:
        """:meth:`apply` computed inside ``box`` (row start, row stop, column start, column stop), which holds
        every object pixel with a margin of ``seg_px + 2``: every pixel outside it stays 0, and the random draws
        (the edge draw over the whole frame, the depth noise over the kept pixels in row-major order) are those
        of the whole frame, so the answer is the whole frame's, bit for bit, at the cost of the box (a 640x480
        frame's object covers a fraction of it)."""
        from scipy import ndimage
        r0, r1, c0, c1 = (int(b) for b in box)
        full = d
        d = full[r0:r1, c0:c1].copy()
        mask = d > 0
        keep = mask.copy()
        if self.grazing_deg is not None and self.grazing_deg < 90:
            keep &= _grazing_cos(d, K, (r0, c0)) >= np.cos(np.radians(self.grazing_deg))
        if self.edge_p > 0:
            border = mask & ~ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool), border_value=0)
            keep &= ~(border & (rng.random(full.shape)[r0:r1, c0:c1] < self.edge_p))
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
        out = np.zeros_like(full)
        out[r0:r1, c0:c1][keep] = z.astype(np.float32)
        return out


def _grazing_cos(depth: np.ndarray, K: C.Intrinsics, origin=(0, 0)) -> np.ndarray:
    """|cos| of the angle between the surface normal (from depth gradients) and the viewing ray,
    per pixel (H, W); 1 where the normal cannot be estimated (isolated pixels). ``depth`` is the window of the
    frame whose first pixel is (row, column) ``origin``; pixels beyond it must be 0 (no data). Each pixel's
    tangents are central differences (one-sided at an edge of the data); x, y and z are kept as separate
    (H, W) arrays, which is what makes it fast (a reduction over a last axis of 3 is slow in numpy), with the
    arithmetic of the cross product, norms and dot product written in numpy's own order."""
    H, W = depth.shape
    z = depth.astype(np.float64)
    valid = z > 0
    u = (np.arange(origin[1], origin[1] + W) - K.cx) / K.fx
    v = (np.arange(origin[0], origin[0] + H) - K.cy) / K.fy
    P = (z * u[None, :], z * v[:, None], z)

    def tangent(axis):
        sa = (slice(None), slice(0, -1)) if axis == 1 else (slice(0, -1), slice(None))
        sb = (slice(None), slice(1, None)) if axis == 1 else (slice(1, None), slice(None))
        ok_f = np.zeros((H, W), bool)
        ok_f[sa] = valid[sb] & valid[sa]
        ok_b = np.zeros((H, W), bool)
        ok_b[sb] = ok_f[sa]
        both = ok_f & ok_b
        tan = []
        for p in P:
            fwd = np.zeros((H, W))
            fwd[sa] = p[sb] - p[sa]
            bwd = np.zeros((H, W))
            bwd[sb] = fwd[sa]
            tan.append(np.where(both, (fwd + bwd) / 2, np.where(ok_f, fwd, bwd)))
        return tan, ok_f | ok_b

    (a0, a1, a2), ok_u = tangent(1)
    (b0, b1, b2), ok_v = tangent(0)
    n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    pn = np.sqrt(P[0] * P[0] + P[1] * P[1] + P[2] * P[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.abs(n0 * P[0] + n1 * P[1] + n2 * P[2]) / (nn * pn)
    ok = valid & ok_u & ok_v & (nn > 0)
    return np.where(ok, c, 1.0)


# --------------------------------------------------------------------------- where the noise is applied

#: The largest :attr:`hbeo.render.views.RenderSettings.noise_scale` (a view costs its square in rendering time and
#: memory).
MAX_NOISE_SCALE = 16


def check_noise_scale(noise: bool, noise_scale: int, what: str = "a view") -> None:
    """Refuse a ``--noise-scale`` that :class:`hbeo.render.views.RenderSettings` would refuse, naming the command's
    options (for ``train`` and ``evaluate``, before any data or model is read)."""
    if noise_scale != 1 and not noise:
        raise ValueError(f"--noise-scale {noise_scale} says where the sensor noise is applied: it needs --noise")
    if not 1 <= noise_scale <= MAX_NOISE_SCALE:
        raise ValueError(f"--noise-scale {noise_scale}: at most {MAX_NOISE_SCALE} ({what} costs its square in "
                         f"rendering time and memory)")


def check_noise_fraction(noise: bool, noise_fraction: float, views: int) -> None:
    """Refuse a ``--noise-fraction`` that :class:`hbeo.render.views.RenderSettings` would refuse for ``views``
    views per object, naming the command's options (for ``train``, before any data is read)."""
    if noise_fraction != 1 and not noise:
        raise ValueError(f"--noise-fraction {noise_fraction:g} says which training views carry the sensor noise: it "
                         f"needs --noise")
    if not 0 < noise_fraction <= 1:
        raise ValueError(f"--noise-fraction {noise_fraction:g}: a share of the views, in (0, 1]")
    if not whole_noisy_views(noise_fraction, views):
        raise ValueError(f"--noise-fraction {noise_fraction:g} of {views} views per object is "
                         f"{noise_fraction * views:g} views: it must be a whole number of at least 1 (change "
                         f"--noise-fraction or --views)")


def whole_noisy_views(noise_fraction: float, views: int) -> bool:
    """Whether ``noise_fraction`` of ``views`` views is a whole number of views, at least one."""
    k = noise_fraction * views
    return abs(k - round(k)) <= 1e-9 and round(k) >= 1
