"""Depth images of occupancy grids by ray marching, batched in torch: :class:`GridCaster`.

Owns the ``torch`` render backend: B depth images of B (object, pose) pairs at once, on the device
the caller chooses (CPU or CUDA), with no host copy inside the march. It renders the surface that
:func:`hbeo.render.renderer.grid_mesh` triangulates, without the triangles: the 0.5 level set of the
same field (:func:`hbeo.render.renderer.grid_field`: the grid padded by one voxel and
constrained-smoothed), interpolated trilinearly. Marching cubes on that field is not exactly its
trilinear level set; measured agreement with the embree renderer on ``grid_mesh`` of real ModelNet10
grids is in ``benchmarks/README.md`` ("Grid ray marching") and ``tests/test_gridcast.py``.

Units and frames (:mod:`hbeo.conventions`, as :mod:`hbeo.render.renderer`)
    Grid coordinate u (voxel centre i + 0.5) maps to ``x = (u - R/2) / (0.8 R) * object_size`` metres;
    padded field index ``p = u + 0.5``. A pose (R, t) puts object point x at ``R @ x + t`` in the
    camera frame (OpenCV axes). Depth (B, H, W) float32: the camera-frame z of the first surface point
    on the ray through each pixel *centre*, metres; 0 where the ray misses.

Method, per ray ``p(z) = a + z b`` (padded index coordinates, linear in the camera depth z)
    1. clip to the object's box (the cells that can hold field >= 0.5: the lattice points where the
       field is >= 0.5, grown by one voxel) and to :attr:`GridCaster.znear`;
    2. march: at each sample take the trilinear field; stop at the first sample >= 0.5; otherwise step
       by the largest of ``step`` voxels, a safe distance (a lower bound on the distance to the nearest
       point where the field can reach 0.5: the distance between the centres of the sample's cell and
       the nearest cell with a corner >= 0.5, less sqrt(3) voxels) and (0.5 - field) / slope (slope:
       a bound on the field's gradient), so empty space costs few samples;
    3. refine the bracketing pair of samples by ``refine`` bisections, then one secant step.

    Rays are compacted as they finish, so the cost follows the samples actually taken. Like any fixed
    step march it can miss a feature thinner than ``step`` along the ray that ``grid_mesh`` shows.

Memory: per object the field (float32) and the safe distance (uint8) over its box only, about
50 kB for a ModelNet10 object at R = 30 (a few hundred MB for all of ModelNet10's training grids). A march's
own memory per ray (:data:`MARCH_BYTES_PER_RAY`) sizes how many images a streamed training renders at once
(:func:`auto_render_ahead`).

Backends of the march (``backend``): ``torch`` (:meth:`GridCaster._march`, any device, the reference) or
``triton`` (:func:`hbeo.render.fused.march`: one fused kernel, CUDA, or a CPU under Triton's interpreter);
``auto`` (the default, or the environment's :data:`BACKEND_ENV`) takes ``triton`` on a CUDA device where
triton imports, and falls back to ``torch`` with a warning if the kernel fails to build there. Both share
the per-image set-up (:meth:`GridCaster._rays`).

Imports torch, numpy, scipy, :mod:`hbeo.conventions`, :mod:`hbeo.rotations` (the poses are checked on the host,
B x 9 numbers, before the march), :mod:`hbeo.limits` (the CPUs for smoothing in worker processes),
:mod:`hbeo.render.renderer` and (the triton backend) :mod:`hbeo.render.fused`.
"""
from __future__ import annotations

import math
import os
import warnings

import numpy as np
import torch

from hbeo import conventions as C
from hbeo.render.renderer import _check_size, grid_field
from hbeo.rotations import check_rotation_matrices

#: the field's level that is the surface (as grid_mesh's marching cubes)
LEVEL = 0.5
_SAFE_MARGIN = math.sqrt(3.0)           # voxels: see the module docstring, step 2
SAFE_UNITS = 4                          #: safe distances are stored in quarter voxels (uint8)
#: the march backends (:class:`GridCaster`'s ``backend``)
BACKENDS = ("auto", "torch", "triton")
#: environment variable giving the default backend (``auto`` when unset), e.g. ``HBEO_GRIDCAST=torch``
BACKEND_ENV = "HBEO_GRIDCAST"


def object_volume(field: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """One object's march data from its field (P, P, P) (:func:`hbeo.render.renderer.grid_field`):
    ``(lo (3,) int64, field float32, safe uint8, slope)``. ``field`` is the crop over the padded lattice
    points ``lo .. hi`` that bound every cell where the field can reach 0.5, plus one layer of zeros
    past ``hi`` on each axis (so a cell's far corners always exist); ``safe[i, j, k]``, of the cell with
    corner (i, j, k), is a lower bound on the distance from any point of the cell to the nearest point
    where the field can reach 0.5, in 1 / :data:`SAFE_UNITS` voxels, rounded down; ``slope`` bounds
    the field's gradient (per voxel)."""
    from scipy import ndimage
    f = np.asarray(field, np.float32)
    active = f >= LEVEL
    if not active.any():
        raise ValueError("the field never reaches 0.5: an empty grid has no surface to render")
    idx = np.nonzero(active)
    lo = np.maximum(np.array([i.min() for i in idx]) - 1, 0)
    hi = np.minimum(np.array([i.max() for i in idx]) + 1, np.array(f.shape) - 1)
    crop = f[tuple(slice(a, b + 1) for a, b in zip(lo, hi))]
    # cells with a corner >= 0.5 hold every point where the field reaches 0.5; the distance between
    # two cells' centres, less sqrt(3), bounds the distance between their points
    act = crop >= LEVEL
    cells = ndimage.maximum_filter(act, size=2, origin=-1, mode="constant")[:-1, :-1, :-1]
    dist = ndimage.distance_transform_edt(~cells)
    safe = np.zeros(np.array(crop.shape) + 1, np.uint8)
    safe[:-2, :-2, :-2] = np.floor(np.clip(dist - _SAFE_MARGIN, 0, 63) * SAFE_UNITS)
    out = np.zeros(np.array(crop.shape) + 1, np.float32)
    out[:-1, :-1, :-1] = crop
    slope = math.sqrt(sum(float(np.abs(np.diff(crop, axis=ax)).max(initial=0.0)) ** 2 for ax in range(3)))
    return lo.astype(np.int64), out, safe, max(slope, 1e-3)


#: :class:`GridCaster` smooths grids in worker processes (``workers`` None) from this many grids on, on a machine
#: with at least :data:`PARALLEL_MIN_CPUS` CPUs: ~20-50 ms a grid on one core (12 passes of a 3-D Gaussian),
#: so ModelNet10's 3,991 training grids took about a minute in one process (the second GPU lease's warm-up)
PARALLEL_MIN_GRIDS = 256
PARALLEL_MIN_CPUS = 4


def _volume(grid, smooth: float):
    """One grid's ``(R, lo, field, safe, slope)`` (:func:`object_volume` of its :func:`grid_field`), or the
    message of the ValueError it raised (a string: it crosses a process boundary as one)."""
    try:
        f = grid_field(grid, smooth)
        return (f.shape[0] - 2, *object_volume(f))
    except ValueError as err:
        return str(err)


def _volume_chunk(args):
    grids, smooth = args
    return [_volume(g, smooth) for g in grids]


def _volumes(grids: list, smooth: float, workers: int | None) -> list:
    """:func:`_volume` of every grid, in order: in this process, or split between ``workers`` processes
    (None: every CPU, up to 16, where there are :data:`PARALLEL_MIN_CPUS` and :data:`PARALLEL_MIN_GRIDS`
    grids; 0 or 1: this process). Each grid's figures are the same either way (the same function)."""
    from hbeo.limits import usable_cores
    cpus = usable_cores()
    if workers is None:
        workers = min(cpus, 16) if cpus >= PARALLEL_MIN_CPUS and len(grids) >= PARALLEL_MIN_GRIDS else 1
    workers = min(int(workers), len(grids))
    if workers <= 1:
        return [_volume(g, smooth) for g in grids]
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing as mp
    size = -(-len(grids) // (4 * workers))                 # 4 chunks a worker: an even load
    chunks = [(grids[i:i + size], smooth) for i in range(0, len(grids), size)]
    # spawn, not fork: the caller may hold a CUDA context, which a forked child must not inherit
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
        return [v for part in pool.map(_volume_chunk, chunks) for v in part]


class GridCaster:
    """Batched depth renderer of a fixed list of occupancy grids for one camera, in torch.

    ``GridCaster(grids, intrinsics, object_size=1.0, smooth=1.0, device="cpu", step=0.25, refine=8, workers=None,
    backend=None)``:
    ``grids`` (N, R, R, R) occupancy (or a list of such grids), smoothed once here
    (:func:`hbeo.render.renderer.grid_field`; a non-cubic grid raises ValueError, an empty one
    DataError, a ValueError) and kept on ``device``; ``step``: the march's smallest step, voxels;
    ``refine``: bisections of the bracketing samples; ``workers``: processes that smooth the grids
    (:func:`_volumes`; None: all CPUs for a large set on a machine with several); ``backend``: the march,
    ``auto``, ``torch`` or ``triton`` (module docstring; None: :data:`BACKEND_ENV`, else ``auto``), resolved
    into :attr:`backend`. :meth:`render` takes object indices and poses.
    Deterministic: the same inputs give the same image on the same device.
    """

    #: objects must lie entirely beyond this depth (metres), as for :class:`hbeo.render.renderer.Renderer`
    znear = 0.01

    def __init__(self, grids, intrinsics: C.Intrinsics, object_size: float = 1.0, smooth: float = 1.0,
                 device="cpu", step: float = 0.25, refine: int = 8, workers: int | None = None,
                 backend: str | None = None):
        if not isinstance(intrinsics, C.Intrinsics):
            raise TypeError(f"intrinsics must be hbeo.conventions.Intrinsics, got {type(intrinsics).__name__}")
        self.intrinsics, self.object_size = intrinsics, _check_size(object_size)
        self.step, self.refine, self.level = float(step), int(refine), LEVEL
        if not (math.isfinite(self.step) and 0 < self.step <= 2):
            raise ValueError(f"step must be in (0, 2] voxels, got {step!r}")
        if self.refine < 0:
            raise ValueError(f"refine must be >= 0, got {refine!r}")
        self.device = torch.device(device)
        self.backend, self._auto = _resolve_backend(backend, self.device)
        grids = list(grids) if not isinstance(grids, np.ndarray) or grids.ndim != 3 else [grids]
        if not grids:
            raise ValueError("GridCaster needs at least one grid")
        res = None
        los, dims, fields, safes, slopes = [], [], [], [], []
        for i, vol in enumerate(_volumes(grids, float(smooth), workers)):
            if isinstance(vol, str):
                raise ValueError(f"grid {i}: {vol}")
            r, lo, crop, safe, slope = vol
            if res is None:
                res = r
            elif r != res:
                raise ValueError(f"grid {i} is {r}^3, grid 0 is {res}^3: all grids must share one size")
            los.append(lo)
            dims.append(crop.shape)
            fields.append(crop)
            safes.append(safe)
            slopes.append(slope)
        self.resolution = int(res)
        self.n_objects = len(grids)
        dev = self.device
        # one layout for all: each object a block (its x size, DY, DZ), so a cell's corners lie at the
        # same flat offsets for every object
        shp = np.array(dims, np.int64)
        DY, DZ = int(shp[:, 1].max()), int(shp[:, 2].max())
        offs = np.concatenate([[0], np.cumsum(shp[:, 0] * DY * DZ)])
        field = np.zeros(int(offs[-1]), np.float32)
        safe = np.zeros(int(offs[-1]), np.uint8)
        for i, (fi, si) in enumerate(zip(fields, safes)):
            nx, ny, nz = fi.shape
            field[offs[i]:offs[i + 1]].reshape(nx, DY, DZ)[:, :ny, :nz] = fi
            safe[offs[i]:offs[i + 1]].reshape(nx, DY, DZ)[:, :ny, :nz] = si
        self._field, self._safe = torch.from_numpy(field).to(dev), torch.from_numpy(safe).to(dev)
        self._strides = (DY * DZ, DZ)
        corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.int64)
        self._corners = torch.from_numpy(corners @ np.array([DY * DZ, DZ, 1])).to(dev)   # x-major (8,)
        # per object: flat offset; box lower and upper corner and 1 / slope
        self._offset = torch.from_numpy(offs[:-1].astype(np.int64)).to(dev)
        lo = np.array(los, np.float32)
        self._lo = torch.from_numpy(lo).to(dev)
        self._hi = torch.from_numpy((lo + shp - 2).astype(np.float32)).to(dev)
        self._inv_slope = torch.from_numpy(1.0 / np.array(slopes, np.float32)).to(dev)
        # voxels per metre, and the padded index of the object origin (the grid's centre)
        self._k = self.resolution * C.OBJECT_VOXELS / C.RESOLUTION / self.object_size
        self._c0 = self.resolution / 2.0 + 0.5
        self._radius = math.sqrt(3.0) * (self.resolution / 2.0 + 1.0) / self._k      # metres, padded box
        K = intrinsics
        self._xs = ((torch.arange(K.width, dtype=torch.float64) - K.cx) / K.fx).float().to(dev)
        self._ys = ((torch.arange(K.height, dtype=torch.float64) - K.cy) / K.fy).float().to(dev)

    @property
    def nbytes(self) -> int:
        """Bytes held on the device for the objects."""
        return sum(t.numel() * t.element_size() for t in (self._field, self._safe))

    def __repr__(self):
        K = self.intrinsics
        return (f"<GridCaster {self.n_objects} grids of {self.resolution}^3, {K.width}x{K.height}, {self.device}, "
                f"{self.backend}>")

    # -- public
    def render(self, objects, Rs, ts) -> torch.Tensor:
        """Depth (B, H, W) float32 on the caster's device, metres, 0 = miss, of objects ``objects``
        (B,) (indices into the grids) at poses ``Rs`` (B, 3, 3), ``ts`` (B, 3) metres (tensors on any
        device, or arrays). ValueError for a bad shape, an index out of range, a matrix that is not a
        rotation, a non-finite pose or an object not entirely beyond :attr:`znear`."""
        dev = self.device
        obj = torch.as_tensor(objects, device=dev).long().reshape(-1)
        Rs = torch.as_tensor(Rs, device=dev, dtype=torch.float64)
        ts = torch.as_tensor(ts, device=dev, dtype=torch.float64)
        B = obj.shape[0]
        if Rs.shape != (B, 3, 3) or ts.shape != (B, 3):
            raise ValueError(f"need rotations (B, 3, 3) and translations (B, 3) for B = {B} objects, got "
                             f"{tuple(Rs.shape)} and {tuple(ts.shape)}")
        K = self.intrinsics
        if B == 0:
            return torch.zeros((0, K.height, K.width), dtype=torch.float32, device=dev)
        if bool(((obj < 0) | (obj >= self.n_objects)).any()):
            raise ValueError(f"object indices must lie in 0..{self.n_objects - 1}, got {obj.min()}..{obj.max()}")
        if not bool(torch.isfinite(Rs).all() & torch.isfinite(ts).all()):
            raise ValueError("pose contains NaN or infinity")
        check_rotation_matrices(Rs.cpu().numpy())      # the one check (hbeo.rotations); B x 9 numbers
        near = ts[:, 2] - self._radius <= self.znear
        if bool(near.any()):
            i = int(torch.nonzero(near)[0, 0])
            raise ValueError(f"pose {i}: object not entirely beyond z = {self.znear} m (centre at z = "
                             f"{float(ts[i, 2]):.3g} m, bounding radius {self._radius:.3g} m)")
        if self.backend == "triton":
            from hbeo.render import fused
            try:
                return fused.march(self, obj, *self._rays(obj, Rs, ts))
            except Exception as err:            # auto only: a kernel that does not build here falls back
                if not self._auto:
                    raise
                warnings.warn(f"GridCaster: the triton march failed ({type(err).__name__}: {err}); "
                              f"using the torch march", RuntimeWarning, stacklevel=2)
                self.backend = "torch"
        return self._march(obj, Rs, ts)

    # -- the march
    def _cells(self, off, x):
        """Flat index of the cell holding each point x (n, 3) (box coordinates, voxels) of objects at flat
        offsets ``off`` (n,), and the point's offsets in it (n, 3)."""
        q = x.clamp_min(0)
        i0 = q.floor()
        fr = q - i0
        i0 = i0.long()
        sx, sy = self._strides
        return off + i0[:, 0] * sx + i0[:, 1] * sy + i0[:, 2], fr

    def _trilinear(self, base, fr):
        """Trilinear field at the points of cells ``base`` (n,) with offsets ``fr`` (n, 3)."""
        c = self._field.take(base[:, None] + self._corners)                         # (n, 8)
        c = torch.lerp(c[:, 0::2], c[:, 1::2], fr[:, 2:3])                           # along z: (n, 4)
        c = torch.lerp(c[:, 0::2], c[:, 1::2], fr[:, 1:2])                           # along y: (n, 2)
        return torch.lerp(c[:, 0], c[:, 1], fr[:, 0])

    def _rays(self, obj, Rs, ts):
        """Per image (float32, on the device): ``M`` (B, 3, 3) = k R^T, ``a`` (B, 3) = k R^T (-t) + c0 - lo and
        ``ext`` (B, 3) = hi - lo, so the ray of pixel (u, v) is p(z) = a + z b in box coordinates (padded index
        - lo, voxels), b = M (x_u, y_v, 1), z the camera depth; the box is [0, ext]."""
        M = (self._k * Rs.transpose(1, 2)).float()                          # (B, 3, 3)
        lo_b = self._lo[obj]
        a = (self._k * (Rs.transpose(1, 2) @ -ts[:, :, None])[:, :, 0] + self._c0).float() - lo_b   # (B, 3)
        return M, a, self._hi[obj] - lo_b

    def _march(self, obj, Rs, ts):
        K, dev = self.intrinsics, self.device
        B, H, W = obj.shape[0], K.height, K.width
        M, a, ext = self._rays(obj, Rs, ts)
        b = (self._xs[None, None, :, None] * M[:, None, None, :, 0] + self._ys[None, :, None, None]
             * M[:, None, None, :, 1] + M[:, None, None, :, 2])             # (B, H, W, 3)
        inv = 1.0 / b
        z1 = -a[:, None, None] * inv
        z2 = (ext[:, None, None] - a[:, None, None]) * inv
        z_in = torch.minimum(z1, z2).amax(-1).clamp_min(self.znear)
        z_out = torch.maximum(z1, z2).amin(-1)
        ray = torch.nonzero((z_in < z_out).reshape(-1)).squeeze(1)        # flat (B*H*W) ray ids
        depth = torch.zeros(B * H * W, dtype=torch.float32, device=dev)
        if ray.numel() == 0:
            return depth.reshape(B, H, W)
        img = torch.div(ray, H * W, rounding_mode="floor")
        o = obj[img]
        b_r = b.reshape(-1, 3)[ray]
        z = z_in.reshape(-1)[ray]
        # state per live ray: floats a (3), b (3), z, z_end, metres of z per voxel, 1 / slope, previous z;
        # integers: ray id, flat offset of the object
        fs = torch.cat([a[img], b_r, z[:, None], z_out.reshape(-1)[ray][:, None],
                        (1.0 / b_r.norm(dim=1))[:, None], self._inv_slope[o][:, None], z[:, None]], 1)
        ls = torch.stack([ray, self._offset[o]], 1)
        hits_f, hits_l = [], []
        while fs.shape[0]:
            z = fs[:, 6]
            base, fr = self._cells(ls[:, 1], fs[:, 0:3] + z[:, None] * fs[:, 3:6])
            f = self._trilinear(base, fr)
            hit = f >= self.level
            # step: the safe distance, or what the slope allows, but at least `step` voxels
            safe = torch.maximum(self._safe.take(base).float() * (1.0 / SAFE_UNITS), (self.level - f) * fs[:, 9])
            z_next = z + safe.clamp_min(self.step) * fs[:, 8]
            if bool(hit.any()):
                h = torch.nonzero(hit).squeeze(1)
                hits_f.append(fs[h])
                hits_l.append(ls[h])
            keep = torch.nonzero(~hit & (z_next < fs[:, 7])).squeeze(1)
            fs[:, 10] = z
            fs[:, 6] = z_next
            fs, ls = fs.index_select(0, keep), ls.index_select(0, keep)
        if not hits_f:
            return depth.reshape(B, H, W)
        fs, ls = torch.cat(hits_f), torch.cat(hits_l)
        off, a_r, b_r = ls[:, 1], fs[:, 0:3], fs[:, 3:6]

        def field(zz):
            return self._trilinear(*self._cells(off, a_r + zz[:, None] * b_r))
        zl, zh = fs[:, 10], fs[:, 6]
        fl, fh = field(zl), field(zh)
        for _ in range(self.refine):
            zm = 0.5 * (zl + zh)
            fm = field(zm)
            up = fm >= self.level
            zh, fh = torch.where(up, zm, zh), torch.where(up, fm, fh)
            zl, fl = torch.where(up, zl, zm), torch.where(up, fl, fm)
        # secant between the bracketing samples; a ray that starts inside (znear) keeps its first sample
        w = ((self.level - fl) / (fh - fl).clamp_min(1e-12)).clamp(0, 1)
        depth[ls[:, 0]] = torch.where(fl >= self.level, zl, zl + w * (zh - zl))
        return depth.reshape(B, H, W)


def _resolve_backend(backend: str | None, device: torch.device) -> tuple[str, bool]:
    """(``torch`` or ``triton``, whether chosen by ``auto``) for ``backend`` (None: :data:`BACKEND_ENV`, else
    ``auto``) on ``device``. ``triton`` needs triton and a CUDA device, or a CPU under Triton's interpreter."""
    from hbeo.render import fused
    name = backend if backend is not None else (os.environ.get(BACKEND_ENV, "").strip().lower() or "auto")
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
    if name == "auto":
        return ("triton" if device.type == "cuda" and fused.available() else "torch"), True
    if name == "triton":
        if not fused.available():
            raise ValueError("backend 'triton' needs triton (pip install triton, or the gpu extra)")
        if device.type != "cuda" and not fused.interpreting():
            raise ValueError(f"backend 'triton' needs a CUDA device (or TRITON_INTERPRET=1 on a CPU), got {device}")
    return name, False


def embree_agreement(grids, intrinsics: C.Intrinsics, n_poses: int, seed: int = 0) -> dict:
    """How the caster's images agree with embree's on ``grid_mesh`` of the same grids, at the same poses.

    ``n_poses`` views of every grid from the default sampler of ``intrinsics``' image size (seeded); returns
    ``iou`` (silhouette IoU per image, object order), ``iou_pooled`` (intersection over union summed over the
    images) and ``depth_diff`` (|depth difference|, metres, over every pixel both renderers hit)."""
    from hbeo.render.renderer import Renderer, grid_mesh
    from hbeo.render.views import RenderSettings
    caster = GridCaster(grids, intrinsics)
    sampler = RenderSettings(image_size=(intrinsics.width, intrinsics.height)).view_sampler
    rng = np.random.default_rng(seed)
    ious, inter, union, diffs = [], 0, 0, []
    with Renderer(intrinsics, "embree") as ren:
        for i, g in enumerate(grids):
            R, t = sampler.sample(n_poses, rng)
            ref = ren.render_many(grid_mesh(g), R, t)
            out = caster.render(np.full(n_poses, i), R, t).numpy()
            for a, b in zip(ref, out):
                ma, mb = a > 0, b > 0
                i_, u_ = int((ma & mb).sum()), int((ma | mb).sum())
                ious.append(i_ / u_)
                inter, union = inter + i_, union + u_
                diffs.append(np.abs(a - b)[ma & mb])
    return {"iou": np.array(ious), "iou_pooled": inter / union, "depth_diff": np.concatenate(diffs)}


#: :meth:`hbeo.model.trainingdata.ModelView.plan_reads`: at most this many images rendered in one march on a CUDA
#: device (the ray-marcher reached 2,722 images/s at 320x240 in batches of 2,048 on an H200, 1,028 in batches of 128:
#: lease-2026-11-26b)
RENDER_AHEAD = 2048
#: peak bytes a ray of a march holds (its state and temporaries; measured on the CPU: 101 at
#: 1,024 images of 80x60, 128 at 4,096)
MARCH_BYTES_PER_RAY = 128


def auto_render_ahead(free_bytes: int, pixels: int) -> int:
    """Images to render in one march on a device with ``free_bytes`` free, of ``pixels`` rays each: at most
    :data:`RENDER_AHEAD`, and a march within a quarter of the free memory (0: a batch at a time)."""
    return int(min(RENDER_AHEAD, max(0, int(free_bytes)) // (4 * MARCH_BYTES_PER_RAY * max(1, int(pixels)))))
