"""From a user's depth image to the model's input view, and back to the user's frame.

A model is trained on images from one virtual camera (its intrinsics and size; objects
near the optical axis at the training distances). A real image has other intrinsics and
the object anywhere in it. :func:`to_model_view` resamples the masked depth into the
model's camera after turning it to look straight at the object (rotation ``Q``, virtual
camera frame -> user camera frame), so a pose predicted in the virtual frame becomes
``Q @ R`` in the user's. With ``ref_distance`` it also zooms the virtual camera and shifts
depth so the object appears as if its centre were at ``ref_distance`` metres, which makes
the input insensitive to the object's distance (up to perspective). The centre's distance
is estimated as that of the observed points' median plus their lateral radius
(sqrt(2) x RMS distance from the view ray: the radius of a disc).

Resampling is backward (each virtual pixel looks up the nearest user pixel along its ray),
so there are no holes; depth is re-expressed as z in the virtual camera.

How much of the object the model sees is measured, not assumed: ``View.coverage`` is the
fraction of the object's observed points that project inside the model's image (a wrong
``K_user``, or a user camera wider than the model's with the object off-centre, lower it), ``View.filled`` the number of non-zero input pixels (0: the network would see an
empty image). :class:`hbeo.model.inference.HBEO` turns these into an error or a warning.

Imports hbeo.conventions and hbeo.rotations only.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hbeo.conventions import Intrinsics, backproject
from hbeo.rotations import direction_to_matrix


@dataclass
class View:
    """Result of :func:`to_model_view`."""

    depth: np.ndarray       #: (H, W) float32, metres in the virtual camera, 0 = none
    Q: np.ndarray           #: (3, 3) virtual camera frame -> user camera frame
    center: np.ndarray      #: (3,) robust centre of the observed points, user camera frame, metres
    distance: float         #: estimated distance of the object's centre: |center| + its lateral radius
    zoom: float             #: virtual focal length / model focal length (1 without ref_distance)
    coverage: float = 1.0   #: fraction of the object's points (valid masked pixels) inside the model's image
    filled: int = 0         #: non-zero pixels of ``depth`` (the network's input)
    points: int = 0         #: the object's valid pixels in the user's image (what ``depth`` is made from)


@lru_cache(maxsize=8)
def _pixel_rays_cached(K: Intrinsics, zoom: float) -> np.ndarray:
    v, u = np.mgrid[0:K.height, 0:K.width]
    rays = np.stack([(u - K.cx) / (K.fx * zoom), (v - K.cy) / (K.fy * zoom), np.ones_like(u, float)], -1)
    rays.setflags(write=False)
    return rays


def _pixel_rays(K: Intrinsics, zoom: float) -> np.ndarray:
    """Rays (H, W, 3) through the pixel centres of camera ``K`` with its focal length times ``zoom``
    (cached for the unzoomed camera, which every call without distance normalization uses)."""
    if zoom == 1.0:
        return _pixel_rays_cached(K, 1.0)
    return _pixel_rays_cached.__wrapped__(K, zoom)


def check_depth(depth, mask=None, name: str = "depth") -> np.ndarray:
    """Validated float64 depth with the mask applied; ValueError naming the problem."""
    d = np.asarray(depth)
    if d.ndim != 2 or min(d.shape) < 1:
        raise ValueError(f"{name} must be a 2-D image, got shape {d.shape}")
    if d.dtype.kind not in "uif":
        raise ValueError(f"{name} has dtype {d.dtype}; expected numbers")
    valid = d > 0                                   # False for NaN
    if d.dtype.kind == "f":
        valid &= np.isfinite(d)
    if mask is not None:
        m = np.asarray(mask)
        if m.shape != d.shape:
            raise ValueError(f"mask is {m.shape[1] if m.ndim > 1 else '?'}x{m.shape[0]} but {name} is "
                             f"{d.shape[1]}x{d.shape[0]}")
        valid &= m.astype(bool)
    if not valid.any():
        if d.dtype.kind == "f" and np.isnan(d).all():
            raise ValueError(f"{name} is all NaN")
        raise ValueError(f"{name} has no valid pixels (all zero, NaN or masked out)")
    out = np.zeros(d.shape)
    np.copyto(out, d, where=valid)
    return out


def to_model_view(depth, K_user: Intrinsics, K_model: Intrinsics, mask=None, recenter: bool = True,
                  ref_distance: float | None = None, toward=None) -> View:
    """Resample a (masked) depth image (H, W), metres, into the model's camera; see the module doc. ``toward``
    (3,), user camera frame, with ``recenter``: the point the virtual camera turns to instead of the observed
    points' median (e.g. an estimate of the object's centre, which the visible surface's median is not)."""
    d = check_depth(depth, mask)
    if d.shape != (K_user.height, K_user.width):
        raise ValueError(f"depth image is {d.shape[1]}x{d.shape[0]} but the intrinsics are for "
                         f"{K_user.width}x{K_user.height}")
    pts, _ = backproject(d, K_user)
    center = np.median(pts, axis=0)
    if recenter:
        aim = center if toward is None else np.asarray(toward, np.float64)
        Q = direction_to_matrix(aim)           # virtual camera -> user camera: +z onto the centre
        local = pts[:, :2] @ Q[:2, :2] + pts[:, 2:] * Q[2, :2]    # virtual frame, x and y only
        mid = np.median(local, axis=0)
    else:                                          # the virtual frame is the camera's
        Q, local, mid = np.eye(3), pts[:, :2], center[:2]
    lateral = np.sqrt(2 * np.mean(np.sum((local - mid) ** 2, axis=1)))
    dist = float(np.linalg.norm(center) + lateral)   # the centre lies about one radius behind the surface
    zoom = dist / ref_distance if ref_distance else 1.0
    if not recenter and zoom == 1.0 and K_user == K_model:       # the model's own camera: nothing to resample
        return View(d.astype(np.float32), Q, center, dist, zoom, 1.0, int(np.count_nonzero(d)), len(pts))
    rays = _pixel_rays(K_model, zoom) @ Q.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uu = np.rint(K_user.fx * rays[..., 0] / rays[..., 2] + K_user.cx)
        vv = np.rint(K_user.fy * rays[..., 1] / rays[..., 2] + K_user.cy)
    ok = (rays[..., 2] > 0) & (uu >= 0) & (uu < K_user.width) & (vv >= 0) & (vv < K_user.height)
    out = np.zeros((K_model.height, K_model.width))
    ui, vi = uu[ok].astype(int), vv[ok].astype(int)
    z = d[vi, ui]
    hit = z > 0
    # the user point on that pixel, expressed in the virtual frame: z' = (Q^T p)_z
    p = np.stack([(ui[hit] - K_user.cx) * z[hit] / K_user.fx, (vi[hit] - K_user.cy) * z[hit] / K_user.fy, z[hit]], -1)
    zv = p @ Q[:, 2]
    if ref_distance:
        zv = zv - dist + ref_distance
    vals = np.zeros(ok.sum())
    vals[hit] = zv
    out[ok] = vals
    out = out.astype(np.float32)
    return View(out, Q, center, dist, zoom, _coverage(pts, Q, K_model, zoom), int(np.count_nonzero(out)), len(pts))


def _coverage(pts: np.ndarray, Q: np.ndarray, K: Intrinsics, zoom: float) -> float:
    """Fraction of the points (N, 3), user camera frame, that the virtual camera (``K`` with its
    focal length times ``zoom``, frame ``Q``) sees inside its image (nearest-pixel bounds, as the
    resampling rounds)."""
    p = pts @ Q                                    # virtual frame: Q^T p for each point
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K.fx * zoom * p[:, 0] / z + K.cx
        v = K.fy * zoom * p[:, 1] / z + K.cy
    inside = (z > 0) & (u >= -0.5) & (u < K.width - 0.5) & (v >= -0.5) & (v < K.height - 0.5)
    return float(inside.mean())
