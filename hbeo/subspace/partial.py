"""From a segmented depth image and a pose hypothesis to a partially observed 30^3 grid.

Frames are those of :mod:`hbeo.conventions`: under the hypothesis (R, t), a point x of the
object (metres, origin at its bounding-box centre, longest side ``object_size`` metres) is seen
at ``R @ x + t`` in the camera frame (OpenCV axes), and its continuous grid coordinate is
``u = x / object_size * 24 + 15`` (voxel (i, j, k) covers [i, i+1) x [j, j+1) x [k, k+1)).

Three voxel states (returned as two bool grids, ``filled`` and ``known``). For each voxel, its
centre's camera depth z_c and the depth d of the pixel nearest to the centre's projection:

known-filled (``filled``)
    * every depth pixel's back-projected surface point marks the voxel that contains it;
    * a voxel whose centre projects onto an object pixel is filled when that pixel's surface
      point lies inside the voxel along the ray through the voxel centre, ``|z_c - d| <= e``, with
      ``e`` the exact half-length of the voxel along that ray, in depth: ``e = (s/2) z_c / max_j
      |q_j|``, s the voxel edge and q the camera->centre vector in the object frame (0.5 to 0.87
      voxel edges for a ray along the optical axis). This catches surface voxels that few pixel
      rays sample.
known-empty (``known & ~filled``)
    the centre projects into the image and either the whole ray segment through the voxel lies
    in front of the surface, ``z_c < d - e``, or the pixel is background (d = 0: its ray met no
    object) *and* the voxel's whole image footprint misses the object: the pixel's distance to
    the nearest object pixel exceeds the projected radius of the voxel's bounding sphere
    (sqrt(3)/2 s f / z_c) plus 0.71 px of rounding. (A voxel just outside the silhouette can hold
    object matter behind the limb that its centre ray misses; on a rendered sphere this margin
    cuts wrongly carved voxels from 1.6 % to 0.1 %.) Surface marking wins over carving.
unknown (``~known``)
    behind the observed surface (``z_c > d + e``: occluded), near the silhouette within the
    footprint margin, projecting outside the image, or behind the camera.

Voxel centres form a lattice, so camera coordinates are separable sums over the three axes.
Everything is vectorized over voxels, pixels and rotation hypotheses, in float32 elementwise
arithmetic (no BLAS, so results do not depend on batch size or thread count):
:func:`depth_to_partial` equals one slice of :func:`depth_to_partial_many`. About 0.7 ms per
hypothesis on one core (160x120 image).
"""
from __future__ import annotations

import numpy as np

from hbeo import conventions as C
from hbeo.rotations import check_rotation_matrices

_SPHERE = float(np.sqrt(3.0) / 2.0)    #: bounding-sphere radius of a voxel, in edges
_ROUNDING = float(np.sqrt(0.5))       #: distance from a projected point to its nearest pixel centre, at most
_PAD = 8     #: voxels around the grid in which surface points outside it are counted (half-diagonal 20.8 < 15 + 8)

#: default number of rotation hypotheses processed together (bounds memory to ~30 MB per 16)
DEFAULT_CHUNK = 16


# ----------------------------------------------------------------------------- validation

def _check_depth(depth, intrinsics: C.Intrinsics) -> np.ndarray:
    if not isinstance(intrinsics, C.Intrinsics):
        raise TypeError(f"intrinsics must be hbeo.conventions.Intrinsics, got {type(intrinsics).__name__}")
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must be one image (H, W), got shape {d.shape}")
    if d.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f"depth image is {d.shape[1]}x{d.shape[0]} (W x H) but the intrinsics are for "
                         f"{intrinsics.width}x{intrinsics.height}")
    d = d.astype(np.float32)
    if not np.isfinite(d).all():
        raise ValueError("depth contains NaN or infinity (use 0 for pixels without an object)")
    if (d < 0).any():
        raise ValueError("depth contains negative values (metres; 0 = no object)")
    if not (d > 0).any():
        raise ValueError("depth image is all zero: no object pixel to build a partial grid from")
    return d


def _check_rotations(Rs) -> np.ndarray:
    Rs = np.asarray(Rs, dtype=np.float64)
    if Rs.ndim != 3 or Rs.shape[1:] != (3, 3):
        raise ValueError(f"rotations must have shape (M, 3, 3), got {Rs.shape}")
    if not np.isfinite(Rs).all():
        raise ValueError("rotation contains NaN or infinity")
    return check_rotation_matrices(Rs)


def _check_common(t, object_size, resolution):
    t = np.asarray(t, dtype=np.float64)
    if t.shape != (3,):
        raise ValueError(f"t must have shape (3,), got {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError(f"t must be finite, got {t}")
    try:
        size = float(object_size)
    except (TypeError, ValueError):
        raise ValueError(f"object_size must be a positive number of metres, got {object_size!r}") from None
    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"object_size must be a positive number of metres, got {object_size!r}")
    if int(resolution) != resolution or resolution < 2:
        raise ValueError(f"resolution must be an integer >= 2, got {resolution!r}")
    return t, size, int(resolution)


# ----------------------------------------------------------------------------- geometry

def voxel_size(object_size: float = 1.0, resolution: int = C.RESOLUTION) -> float:
    """Edge length of one voxel in metres: the longest side ``object_size`` spans 24 of 30 voxels."""
    return float(object_size) / (resolution * C.OBJECT_VOXELS / C.RESOLUTION)


def _axis(resolution: int, s: float) -> np.ndarray:
    """Object-frame coordinate (metres) of the voxel centres along one axis, (R,) float32."""
    return ((np.arange(resolution) + 0.5 - resolution / 2.0) * s).astype(np.float32)


def _lattice(coef: np.ndarray, off: np.ndarray, c: np.ndarray) -> np.ndarray:
    """coef (m, 3), off (m,) -> (m, R, R, R) values ``coef . (c_i, c_j, c_k) + off`` at all voxel
    centres: the lattice is separable, so one full-size addition (in float32)."""
    a = coef[:, 0, None, None] * c[None, :, None]
    a = a + coef[:, 1, None, None] * c[None, None, :]                            # (m, R, R)
    b = coef[:, 2, None] * c[None, :] + off[:, None]                             # (m, R)
    return a[..., None] + b[:, None, None, :]


class _Image:
    """Per-image lookups for the voxel tests, on a one-pixel padded image so that every
    projection clipped to [-1, W] x [-1, H] lands on a pixel (the pad means "outside the image").

    depth: object depth (metres), 0 on background and outside.
    free: for background pixels, (distance in pixels to the nearest object pixel) - rounding
    slack, so that a voxel of footprint radius f/z pixels is carved iff free * z > f; -1 on
    object pixels and outside (never carved as background)."""

    def __init__(self, d: np.ndarray, K: C.Intrinsics):
        from scipy import ndimage
        H, W = d.shape
        self.W2 = W + 2
        self.depth = np.zeros((H + 2, W + 2), np.float32)
        self.depth[1:-1, 1:-1] = d
        gap = ndimage.distance_transform_edt(d == 0).astype(np.float32) - _ROUNDING
        gap[d > 0] = -1.0
        self.free = np.full((H + 2, W + 2), -1.0, np.float32)
        self.free[1:-1, 1:-1] = gap
        self.depth, self.free = self.depth.ravel(), self.free.ravel()
        self.K = K


def _partial_chunk(img: _Image, pts_s, c, Rs, t, s, res, out_f, out_k):
    """Fill out_f, out_k (m, R^3) bool for rotations Rs (m, 3, 3); pts_s (n, 3) float32 are the
    image's surface points relative to t, in voxel units. Elementwise float32 (no BLAS), so a
    hypothesis gives the same grid in any chunk."""
    K = img.K
    m = len(Rs)
    Rf = Rs.astype(np.float32)
    tf = t.astype(np.float32)
    # camera frame P = R x + t; projection numerators U = fx X + cx Z, V = fy Y + cy Z; depth Z
    cu = K.fx * Rf[:, 0] + K.cx * Rf[:, 2]
    cv = K.fy * Rf[:, 1] + K.cy * Rf[:, 2]
    ou = np.full(m, K.fx * tf[0] + K.cx * tf[2], np.float32)
    ov = np.full(m, K.fy * tf[1] + K.cy * tf[2], np.float32)
    Z = _lattice(Rf[:, 2], np.full(m, tf[2], np.float32), c)
    invz = np.float32(1.0) / Z
    col = _lattice(cu, ou, c)
    col *= invz
    np.rint(col, out=col)
    np.clip(col, -1, K.width, out=col)
    row = _lattice(cv, ov, c)
    row *= invz
    np.rint(row, out=row)
    np.clip(row, -1, K.height, out=row)
    row *= img.W2
    row += col
    row += img.W2 + 1
    idx = row.astype(np.int32)
    behind = Z <= 1e-6
    if behind.any():                       # voxels behind the camera: unknown (index 0 is padding)
        idx[behind] = 0
    d = img.depth[idx]
    free = img.free[idx]
    # half-length e of the voxel along the ray through its centre, in depth: the ray
    # x_c + lam q / |q| (q = x_c + R^T t, camera centre -> voxel centre, object frame) stays in
    # the voxel for |lam| <= (s/2) / max_j |q_j / |q||, a change in depth of e = (s/2) Z / max_j |q_j|
    # (0.5 to 0.87 voxel edges for a z-aligned ray). Tests below are multiplied through by max_j |q_j|.
    Rt_t = np.einsum("mji,j->mi", Rs, t).astype(np.float32)                    # (m, 3)
    q = np.abs(c[None, None, :] + Rt_t[:, :, None])                              # (m, 3, R) per axis
    qmax = np.maximum(np.maximum(q[:, 0, :, None], q[:, 1, None, :])[..., None], q[:, 2, None, None, :])
    thr = Z * np.float32(0.5 * s)
    diff = d - Z
    diff *= qmax                           # (d - Z) max|q|: background pixels (d = 0) give < -thr
    filled = np.abs(diff) <= thr           # the pixel's surface point lies inside the voxel
    empty = diff > thr                     # the whole ray segment through the voxel is in front
    # background carving only where the voxel's image footprint (its bounding sphere of radius
    # sqrt(3)/2 s, projected: r = fpx / Z pixels) misses the object: a voxel just behind the
    # silhouette can hold object matter its centre ray misses
    free *= Z
    empty |= free > np.float32(_SPHERE * s * max(K.fx, K.fy))
    filled = filled.reshape(m, -1)
    empty = empty.reshape(m, -1)
    # every pixel's surface point marks its voxel: u = R^T (p - t) / s + R/2
    n_out = np.zeros(m, np.int64)
    if len(pts_s):
        half = np.float32(res / 2.0)
        lin = np.zeros((m, len(pts_s)), np.int32)
        ext = np.zeros((m, len(pts_s)), np.int32)       # index in a grid padded by _PAD voxels
        inside = np.ones((m, len(pts_s)), bool)
        E = res + 2 * _PAD
        for j, (mult, emult) in enumerate(((res * res, E * E), (res, E), (1, 1))):
            u = (pts_s[:, 0][None] * Rf[:, 0, j, None] + pts_s[:, 1][None] * Rf[:, 1, j, None]
                 + pts_s[:, 2][None] * Rf[:, 2, j, None]) + half
            f = np.floor(u).astype(np.int32)
            inside &= f.view(np.uint32) < res                                   # 0 <= f < res
            ext += np.clip(f + _PAD, 0, E - 1) * emult
            f *= mult
            lin += f
        mi = np.broadcast_to(np.arange(m, dtype=np.int32)[:, None], lin.shape)
        filled[mi[inside], lin[inside]] = True
        out = ~inside
        if out.any():                      # surface voxels the grid cannot hold, counted once each
            hits = np.zeros((m, E ** 3), bool)
            hits[mi[out], ext[out]] = True
            n_out = hits.sum(axis=1)
    out_f[:] = filled
    np.logical_or(filled, empty, out=out_k)
    return n_out


def iter_partial(depth, intrinsics: C.Intrinsics, Rs, t, object_size: float = 1.0,
                 chunk: int = DEFAULT_CHUNK, resolution: int = C.RESOLUTION):
    """Generator over :func:`depth_to_partial_many`'s result in chunks: yields ``(start, filled,
    known, outside)`` with flat bool arrays (m, R^3) for hypotheses ``start .. start + m - 1``
    (m <= chunk) and ``outside`` (m,) int: the number of voxels *outside* the grid (in a margin
    of 8 voxels around it) that the surface points fall in under each hypothesis; the true pose
    of an object that fits the grid has none. Validates and prepares the image once."""
    d = _check_depth(depth, intrinsics)
    Rs = _check_rotations(Rs)
    t, size, res = _check_common(t, object_size, resolution)
    if int(chunk) != chunk or int(chunk) < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if t[2] <= 0:
        raise ValueError(f"t = {t} puts the object centre behind the camera (need t_z > 0, metres)")
    return _iter_partial(d, intrinsics, Rs, t, size, int(chunk), res)


def _iter_partial(d, K, Rs, t, size, chunk, res):
    s = voxel_size(size, res)
    c = _axis(res, s)
    pts, _ = C.backproject(d, K)
    pts_s = ((pts - t) / s).astype(np.float32)
    img = _Image(d, K)
    n = res ** 3
    for a in range(0, len(Rs), chunk):
        m = min(len(Rs), a + chunk) - a
        filled = np.empty((m, n), bool)
        known = np.empty((m, n), bool)
        outside = _partial_chunk(img, pts_s, c, Rs[a:a + m], t, s, res, filled, known)
        yield a, filled, known, outside


def depth_to_partial_many(depth, intrinsics: C.Intrinsics, Rs, t, object_size: float = 1.0,
                          chunk: int = DEFAULT_CHUNK, resolution: int = C.RESOLUTION
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Partial grids of one depth image under M rotation hypotheses ``Rs`` (M, 3, 3) sharing the
    translation ``t`` (3,), metres. Returns ``(filled, known)``, each bool (M, R, R, R) (R = 30):
    ``filled`` = known-filled, ``known`` = known-filled or known-empty (see the module docstring).
    Vectorized over voxels, pixels and hypotheses; ``chunk`` hypotheses at a time bound the
    temporaries (about 1.3 MB per hypothesis)."""
    it = iter_partial(depth, intrinsics, Rs, t, object_size, chunk, resolution)
    M, res = len(np.asarray(Rs)), int(resolution)
    filled = np.empty((M, res ** 3), bool)
    known = np.empty((M, res ** 3), bool)
    for a, f, k, _ in it:
        filled[a:a + len(f)], known[a:a + len(f)] = f, k
    shape = (M, res, res, res)
    return filled.reshape(shape), known.reshape(shape)


def depth_to_partial(depth, intrinsics: C.Intrinsics, R, t, object_size: float = 1.0,
                     resolution: int = C.RESOLUTION) -> tuple[np.ndarray, np.ndarray]:
    """Partial grid of one depth image (H, W), metres, 0 = no object, under the pose hypothesis
    R (3, 3) object->camera, t (3,) metres. Returns ``(filled, known)``, both bool (30, 30, 30):
    filled = known-filled (surface hits), known = filled or known-empty; unknown = ``~known``."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"R must have shape (3, 3), got {R.shape}")
    f, k = depth_to_partial_many(depth, intrinsics, R[None], t, object_size, chunk=1, resolution=resolution)
    return f[0], k[0]
