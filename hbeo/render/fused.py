"""The grid ray march of :class:`hbeo.render.gridcast.GridCaster` as one fused Triton kernel: :func:`march`.

Owns the ``triton`` march backend: one program marches, refines and writes the depth of a tile of
``TW x TH`` pixels of ``G`` images (:data:`GPU_TILE`: 16 x 8 pixels of one image on a GPU), every ray's
state in registers and the object's field read through the cache, with no host synchronisation and no
tensor per iteration (the torch march launches ~40 kernels, makes ~30 tensors and reads the device three
times an iteration). The torch march (:meth:`GridCaster._march`) stays the CPU path and the reference;
this module reproduces it operation by operation.

Inputs (what :meth:`GridCaster._rays` computes, on the caster's device): per image ``M`` (B, 3, 3) float32
(voxels per metre times R^T), ``a`` (B, 3) float32 (the camera centre in the object's box coordinates,
voxels) and ``ext`` (B, 3) float32 (the box size, voxels); the caster's flat field (float32), safe
distances (uint8, quarter voxels), per-object flat offsets and 1 / slope, and pixel-ray slopes
``xs`` (W,), ``ys`` (H,). Output: depth (B, H, W) float32, camera-frame z of the first surface point on
the ray through each pixel centre, metres, 0 on a miss: the units and frames of :mod:`hbeo.render.gridcast`.
Sensor noise and the float16 rounding of a rendered set stay with the caller
(:meth:`hbeo.render.torch_datasets.FreshPoses.render_batch`), which applies them to either backend's depth.

Method, per ray (as :mod:`hbeo.render.gridcast`): ``b = xs M[:, 0] + ys M[:, 1] + M[:, 2]``; clip to the
box (slab test, ``1 / b`` by IEEE division, NaN propagated as torch does) and to ``znear``; march: trilinear
field (torch's ``lerp``: ``fma(w, e - s, s)`` for ``|w| < 0.5``, else ``fma(w - 1, e - s, e)``), stop at the
first sample >= 0.5, step ``max(safe, (0.5 - f) / slope, step) / |b|`` metres (``|b|`` as torch's
``norm``: ``sqrt(fma(b2, b2, fma(b1, b1, b0 b0)))``); then ``refine`` bisections and one secant step.
Every other product and sum is rounded separately, as torch's separate operations round them: the
kernel is launched with ``enable_fp_fusion=False``, so the compiler contracts none into an FMA.

Agreement with the torch march (``tests/test_fused.py``)
    On a CPU, under Triton's interpreter (numpy arithmetic; ``TRITON_INTERPRET=1``), against the torch
    march on the CPU: bit-equal depth on every pixel of the tested grids (random blobs, thin rods and
    plates, a one-voxel grid, a hollow shell, procedural furniture; 55 images of 24x18 to 40x30, 43,482
    pixels, none differing). ``TRITON_INTERPRET=1`` must be set before triton is first imported (triton
    builds its standard library, ``tl.max``, for the interpreter then; :func:`kernel` refuses otherwise).
    There the kernel's helpers stay plain Python (a jitted helper re-patches triton.language at every
    call) and a program takes whole images (:func:`tiling`): the interpreter pays per operation. It evaluates
    ``tl.fma`` as two float32 roundings, so there the kernel takes each FMA in float64 (``F64``: the
    product of two float32 is exact in float64, then one rounding to float64 and one to float32); the
    two differ from a true FMA only when the float64 sum lands exactly halfway between two float32
    numbers (no tested pixel differed). With the GPU's ``tl.fma`` instead (``f64=False``), which the
    interpreter rounds twice, 8 of 771 hit pixels of the 25x19 test differ, by at most 2.4e-7 m, and none
    flips: the branch a GPU runs is exercised too. On a GPU the kernel uses the hardware FMA; the reference is
    the torch march on the same GPU, whose kernels (CUDA's ``lerp`` and ``norm``) may round differently from
    torch's CPU ones: bit-equality is not claimed there; ``benchmarks/bench_gpu_first_minute.py`` measures
    the share of pixels that differ, the largest depth difference and the hit/miss flips.
    A guard ends a ray's march after ``max_steps`` samples (never reached in exact arithmetic: a ray
    crosses the box in fewer than its diagonal / step samples); such a ray would be a miss.

Imports torch; triton only inside :func:`kernel` (the ``gpu`` extra of pyproject.toml), so the package
imports without it.
"""
from __future__ import annotations

import importlib.util
import math
import os

import torch

#: triton.language, bound by :func:`kernel` on first use (triton is optional); the kernel functions below
#: are plain Python until then, and their ``tl.constexpr`` annotations stay strings (``from __future__``)
tl = None
#: parameters per image in the kernel's table: M (9, row-major), a (3), ext (3), 1 / slope
PARAMS = 16
#: the largest grid dimension 1 of a launch (groups of G images per launch)
MAX_GROUPS = 65535
#: a program's tile on a GPU: (TW, TH, G), TW x TH pixels of G images, 128 rays, 4 warps
GPU_TILE = (16, 8, 1)
#: under the interpreter, which pays per operation rather than per ray: a program takes the whole image (sides
#: rounded up to powers of two, at most 64) of as many images as fit in this many lanes
INTERPRETER_LANES = 1 << 15


def available() -> bool:
    """Whether triton can be imported (without importing it)."""
    return importlib.util.find_spec("triton") is not None


def interpreting() -> bool:
    """Whether Triton's interpreter is on (``TRITON_INTERPRET=1``): kernels then run on CPU tensors in numpy."""
    return os.environ.get("TRITON_INTERPRET", "0").strip().lower() in ("1", "true", "on", "yes", "y")


# -- the kernel (plain functions; :func:`kernel` wraps each in triton.jit)
def _fma(a, b, c, F64: tl.constexpr):
    """a * b + c rounded once (float32); F64: through float64 (for the interpreter, whose fma rounds twice)."""
    if F64:
        return (a.to(tl.float64) * b.to(tl.float64) + c.to(tl.float64)).to(tl.float32)
    else:
        return tl.fma(a, b, c)


def _lerp(s, e, w, F64: tl.constexpr):
    """torch.lerp(s, e, w) as ATen computes it for float32 (both its vectorized and its scalar paths)."""
    small = tl.abs(w) < 0.5
    return _fma(tl.where(small, w, w - 1.0), e - s, tl.where(small, s, e), F64)


def _nanmin(x, y):
    """torch.minimum: NaN if either is."""
    return tl.minimum(x, y, propagate_nan=tl.PropagateNan.ALL)


def _nanmax(x, y):
    """torch.maximum: NaN if either is."""
    return tl.maximum(x, y, propagate_nan=tl.PropagateNan.ALL)


def _sample(fp, a0, a1, a2, b0, b1, b2, z, sx, sy, m, F64: tl.constexpr):
    """(trilinear field, flat cell index) at ``a + z b`` (box coordinates) for the lanes ``m``: GridCaster's
    ``_cells`` then ``_trilinear``. ``fp``: the object's field; corner (i, j, k) at offset i sx + j sy + k."""
    x0 = tl.maximum(a0 + z * b0, 0.0)
    x1 = tl.maximum(a1 + z * b1, 0.0)
    x2 = tl.maximum(a2 + z * b2, 0.0)
    i0 = tl.floor(x0)
    i1 = tl.floor(x1)
    i2 = tl.floor(x2)
    f0 = x0 - i0
    f1 = x1 - i1
    f2 = x2 - i2
    base = i0.to(tl.int32) * sx + i1.to(tl.int32) * sy + i2.to(tl.int32)
    base = tl.where(m, base, 0)
    p = fp + base
    c000 = tl.load(p, mask=m, other=0.0)
    c001 = tl.load(p + 1, mask=m, other=0.0)
    c010 = tl.load(p + sy, mask=m, other=0.0)
    c011 = tl.load(p + sy + 1, mask=m, other=0.0)
    c100 = tl.load(p + sx, mask=m, other=0.0)
    c101 = tl.load(p + sx + 1, mask=m, other=0.0)
    c110 = tl.load(p + sx + sy, mask=m, other=0.0)
    c111 = tl.load(p + sx + sy + 1, mask=m, other=0.0)
    y00 = _lerp(c000, c001, f2, F64)
    y01 = _lerp(c010, c011, f2, F64)
    y10 = _lerp(c100, c101, f2, F64)
    y11 = _lerp(c110, c111, f2, F64)
    v0 = _lerp(y00, y01, f1, F64)
    v1 = _lerp(y10, y11, f1, F64)
    return _lerp(v0, v1, f0, F64), base


def _march_kernel(field_ptr, safe_ptr, xs_ptr, ys_ptr, par_ptr, off_ptr, out_ptr, B, H, W, sx, sy,
                  znear, step, level, safe_unit, max_steps,
                  TW: tl.constexpr, TH: tl.constexpr, G: tl.constexpr, REFINE: tl.constexpr, F64: tl.constexpr):
    """Depth of the tile ``program_id(0)`` (row-major over tiles of TW x TH pixels) of the G images
    ``program_id(1) * G ...``: lane = (image of the group, row of the tile, column of the tile)."""
    tile = tl.program_id(0)
    ntx = (W + TW - 1) // TW
    lane = tl.arange(0, G * TW * TH)
    r = lane % (TW * TH)
    img = tl.program_id(1) * G + lane // (TW * TH)
    v = (tile // ntx) * TH + r // TW
    u = (tile % ntx) * TW + r % TW
    inside = (u < W) & (v < H) & (img < B)
    xs = tl.load(xs_ptr + u, mask=inside, other=0.0)
    ys = tl.load(ys_ptr + v, mask=inside, other=0.0)
    par = par_ptr + img.to(tl.int64) * 16
    off = tl.load(off_ptr + img, mask=inside, other=0)
    fp = field_ptr + off
    sp = safe_ptr + off
    a0 = tl.load(par + 9, mask=inside, other=0.0)
    a1 = tl.load(par + 10, mask=inside, other=0.0)
    a2 = tl.load(par + 11, mask=inside, other=0.0)
    inv_slope = tl.load(par + 15, mask=inside, other=0.0)
    # the ray p(z) = a + z b, b = xs M[:, 0] + ys M[:, 1] + M[:, 2] (box coordinates, voxels)
    b0 = xs * tl.load(par + 0, mask=inside, other=0.0) + ys * tl.load(par + 1, mask=inside, other=0.0) \
        + tl.load(par + 2, mask=inside, other=1.0)
    b1 = xs * tl.load(par + 3, mask=inside, other=0.0) + ys * tl.load(par + 4, mask=inside, other=0.0) \
        + tl.load(par + 5, mask=inside, other=1.0)
    b2 = xs * tl.load(par + 6, mask=inside, other=0.0) + ys * tl.load(par + 7, mask=inside, other=0.0) \
        + tl.load(par + 8, mask=inside, other=1.0)
    # clip to the box [0, ext] (slab test) and to znear; NaN (0 * inf) propagates and the ray misses
    one = tl.full(b0.shape, 1.0, tl.float32)
    r0 = tl.math.div_rn(one, b0)
    r1 = tl.math.div_rn(one, b1)
    r2 = tl.math.div_rn(one, b2)
    s0 = -a0 * r0
    s1 = -a1 * r1
    s2 = -a2 * r2
    t0 = (tl.load(par + 12, mask=inside, other=0.0) - a0) * r0
    t1 = (tl.load(par + 13, mask=inside, other=0.0) - a1) * r1
    t2 = (tl.load(par + 14, mask=inside, other=0.0) - a2) * r2
    z_in = _nanmax(_nanmax(_nanmin(s0, t0), _nanmin(s1, t1)), _nanmin(s2, t2))
    z_in = tl.where(z_in < znear, znear, z_in)
    z_end = _nanmin(_nanmin(_nanmax(s0, t0), _nanmax(s1, t1)), _nanmax(s2, t2))
    live = inside & (z_in < z_end)
    # metres of z per voxel along the ray: 1 / |b|
    mpv = tl.math.div_rn(one, tl.sqrt_rn(_fma(b2, b2, _fma(b1, b1, b0 * b0, F64), F64)))
    z = tl.where(live, z_in, 0.0)
    zp = z
    f_prev = tl.full(z.shape, 0.0, tl.float32)
    fl = f_prev
    fh = f_prev
    hit = live & (z < 0.0)
    n = 0
    while (tl.max(live.to(tl.int32), axis=0) > 0) & (n < max_steps):
        f, base = _sample(fp, a0, a1, a2, b0, b1, b2, z, sx, sy, live, F64)
        h = f >= level
        safe = tl.load(sp + base, mask=live, other=0).to(tl.float32) * safe_unit
        z_next = z + tl.maximum(tl.maximum(safe, (level - f) * inv_slope), step) * mpv
        new = live & h
        fl = tl.where(new, tl.where(zp == z, f, f_prev), fl)   # a ray inside at its first sample: fl = f
        fh = tl.where(new, f, fh)
        hit = hit | new
        go = live & (f < level) & (z_next < z_end)
        zp = tl.where(go, z, zp)
        f_prev = tl.where(go, f, f_prev)
        z = tl.where(go, z_next, z)
        live = go
        n += 1
    # refine the bracket (zl, zh) of each hit: bisections, then one secant step
    zl = zp
    zh = z
    for _ in tl.static_range(REFINE):
        zm = 0.5 * (zl + zh)
        fm, _unused = _sample(fp, a0, a1, a2, b0, b1, b2, zm, sx, sy, hit, F64)
        up = fm >= level
        zh = tl.where(up, zm, zh)
        fh = tl.where(up, fm, fh)
        zl = tl.where(up, zl, zm)
        fl = tl.where(up, fl, fm)
    w = tl.math.div_rn(level - fl, tl.maximum(fh - fl, 1e-12))
    w = tl.minimum(tl.maximum(w, 0.0), 1.0)
    depth = tl.where(fl >= level, zl, zl + w * (zh - zl))
    depth = tl.where(hit, depth, 0.0)
    tl.store(out_ptr + (img.to(tl.int64) * H + v) * W + u, depth, mask=inside)


_PLAIN = {"_fma": _fma, "_lerp": _lerp, "_nanmin": _nanmin, "_nanmax": _nanmax, "_sample": _sample,
          "_march_kernel": _march_kernel}
_BUILT: dict = {}


def kernel():
    """The march kernel, built once a process: triton.jit of the functions above (Triton's interpreter
    when :func:`interpreting`). ImportError without triton."""
    mode = interpreting()
    if mode not in _BUILT:
        global tl
        import triton
        import triton.language
        from triton.runtime.interpreter import InterpretedFunction
        if mode and not isinstance(triton.language.standard.max, InterpretedFunction):
            raise RuntimeError("TRITON_INTERPRET=1 was set after triton was imported: triton builds its standard "
                               "library (tl.max) for the interpreter only when the variable is set at its import")
        tl = triton.language
        g = globals()
        for name, fn in _PLAIN.items():          # the kernel calls its helpers by these module names
            # the interpreter re-patches triton.language on every call of a jitted helper (~0.2 ms): there
            # the helpers stay plain functions, called inside the kernel's own patched scope
            g[name] = fn if mode and name != "_march_kernel" else triton.jit(fn)
        _BUILT.clear()
        _BUILT[mode] = g["_march_kernel"]
    return _BUILT[mode]


def tiling(width: int, height: int, batch: int, interpret: bool) -> tuple[int, int, int]:
    """A program's tile (TW, TH, G): :data:`GPU_TILE`, or under the interpreter whole images, as many as
    :data:`INTERPRETER_LANES` hold. Each ray's arithmetic is the same whatever the tile."""
    if not interpret:
        return GPU_TILE
    p2 = lambda n: 1 << max(int(n) - 1, 0).bit_length()           # noqa: E731  (the power of two >= n)
    tw, th = min(p2(width), 64), min(p2(height), 64)
    return tw, th, max(1, min(p2(batch), INTERPRETER_LANES // (tw * th)))


def march(caster, obj: torch.Tensor, M: torch.Tensor, a: torch.Tensor, ext: torch.Tensor,
          tile: tuple[int, int, int] | None = None, f64: bool | None = None) -> torch.Tensor:
    """Depth (B, H, W) float32 on the caster's device, metres, 0 = miss, of objects ``obj`` (B,) (int64,
    on the device) with the per-image ray set-up ``M`` (B, 3, 3), ``a`` (B, 3), ``ext`` (B, 3) (float32,
    :meth:`hbeo.render.gridcast.GridCaster._rays`). No host read; one launch per :data:`MAX_GROUPS` tiles
    of images. ``tile``: (TW, TH, G), powers of two (None: :func:`tiling`); ``f64``: FMAs through float64
    (None: under the interpreter only; False there runs the GPU's ``tl.fma``, which the interpreter rounds
    twice). Needs a CUDA device, or CPU tensors under Triton's interpreter."""
    from hbeo.render.gridcast import SAFE_UNITS
    interpret = interpreting()
    dev = caster.device
    if dev.type != "cuda" and not interpret:
        raise ValueError(f"the triton march needs a CUDA device (or TRITON_INTERPRET=1 on a CPU), got {dev}")
    K = caster.intrinsics
    B, H, W = obj.shape[0], K.height, K.width
    TW, TH, G = tile or tiling(W, H, B, interpret)
    if min(TW, TH, G) < 1 or any(n & (n - 1) for n in (TW, TH, G)):
        raise ValueError(f"tile sides and images must be powers of two, got {(TW, TH, G)}")
    out = torch.empty((B, H, W), dtype=torch.float32, device=dev)
    if B == 0:
        return out
    par = torch.cat([M.reshape(B, 9), a, ext, caster._inv_slope[obj][:, None]], 1).float().contiguous()
    assert par.shape[1] == PARAMS
    off = caster._offset[obj].contiguous()
    sx, sy = caster._strides
    diagonal = math.sqrt(3.0) * (caster.resolution + 4)                # voxels: more than the box's diagonal
    max_steps = int(4 * diagonal / caster.step) + 64
    kern = kernel()
    tiles = -(-W // TW) * -(-H // TH)
    per = MAX_GROUPS * G
    with _quiet(interpret):
        for i in range(0, B, per):
            j = min(B, i + per)
            kern[(tiles, -(-(j - i) // G))](
                caster._field, caster._safe, caster._xs, caster._ys, par[i:j], off[i:j], out[i:j], j - i, H, W,
                sx, sy, float(caster.znear), float(caster.step), float(caster.level), 1.0 / SAFE_UNITS, max_steps,
                TW=TW, TH=TH, G=G, REFINE=int(caster.refine), F64=interpret if f64 is None else bool(f64),
                num_warps=max(1, min(8, G * TW * TH // 32)), enable_fp_fusion=False)
    return out


def _quiet(interpret: bool):
    """Under the interpreter, numpy's warnings for 1 / 0 = inf and 0 * inf = NaN, which the slab test means."""
    import contextlib
    if not interpret:
        return contextlib.nullcontext()
    import numpy as np
    return np.errstate(divide="ignore", invalid="ignore")
