"""Completion metrics between target and predicted 30^3 grids (batched).

All functions take bool grids ``(R, R, R)`` or batches ``(N, R, R, R)`` (anything
``> 0.5`` counts as filled) and return a float or an ``(N,)`` array.

Empty grids, explicitly:
    * EDT error e': the distance field of an empty grid is taken to be the grid
      diagonal ``R * sqrt(3)`` everywhere (no object is farther than anything in
      the grid); two empty grids give 0. (scipy's EDT of an all-background grid is
      meaningless, so it is never computed.)
    * naive error e: undefined for an empty target -> ValueError; any prediction
      against a non-empty target is fine.
    * IoU: two empty grids give 1.0; one empty gives 0.0.
    * Chamfer distance: like e', an empty surface is ``R * sqrt(3)`` from everything;
      two empty grids give 0.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext

import numpy as np
from scipy import ndimage

from hbeo.limits import usable_cores


def _batch(x, name: str) -> tuple[np.ndarray, bool]:
    x = np.asarray(x)
    single = x.ndim == 3
    if single:
        x = x[None]
    if x.ndim != 4 or len(set(x.shape[1:])) != 1:
        raise ValueError(f"{name}: expected a grid (R, R, R) or a batch (N, R, R, R), got shape {x.shape}")
    return (x > 0.5) if x.dtype != bool else x, single


def _pair(target, pred):
    t, single = _batch(target, "target")
    p, _ = _batch(pred, "prediction")
    if t.shape != p.shape:
        raise ValueError(f"target {t.shape} and prediction {p.shape} differ in shape")
    return t, p, single


def _out(v: np.ndarray, single: bool):
    return float(v[0]) if single else v


def distance_field(grid: np.ndarray) -> np.ndarray:
    """Unsigned EDT of one grid (R, R, R): 0 on/inside the object, else distance (voxels)
    to the nearest occupied voxel; an empty grid gives ``R * sqrt(3)`` everywhere."""
    g = np.asarray(grid) > 0.5
    if not g.any():
        return np.full(g.shape, g.shape[0] * np.sqrt(3.0))
    return ndimage.distance_transform_edt(~g)


def edt_error(target, pred, threads: int | None = None):
    """e' = ||D - D_hat||_2 between the targets' and predictions' distance fields.

    A grid that occurs more than once in the call (an object's several views, a class's mean shape) has its
    distance field computed once and kept until its last use; the fields of a block of :data:`EDT_BLOCK` pairs
    are computed on ``threads`` threads (None: the usable cores; scipy's EDT runs without the GIL). The same
    numbers as one field a pair, computed in turn: the EDT is most of an evaluation's scoring time."""
    t, p, single = _pair(target, pred)
    n = len(t)
    keys = _grid_keys(np.concatenate([t, p]))
    last = {}
    for i in range(n):
        last[keys[i]] = last[keys[n + i]] = i
    threads = usable_cores() if threads is None else max(1, int(threads))
    out, kept = np.empty(n), {}
    with ThreadPoolExecutor(threads) if threads > 1 and n > 1 else nullcontext() as pool:
        for a in range(0, n, EDT_BLOCK):
            b = min(n, a + EDT_BLOCK)
            need = {}
            for i in range(a, b):
                for k, g in ((keys[i], t[i]), (keys[n + i], p[i])):
                    if k not in kept and k not in need:
                        need[k] = g
            kept.update(zip(need, (pool.map if pool else map)(distance_field, need.values())))
            for i in range(a, b):
                out[i] = np.linalg.norm(kept[keys[i]] - kept[keys[n + i]])
            kept = {k: f for k, f in kept.items() if last[k] >= b}     # those used again after this block
    return _out(out, single)


#: pairs whose distance fields :func:`edt_error` computes together (~0.2 MB a field at 30^3)
EDT_BLOCK = 128


def _grid_keys(grids: np.ndarray) -> list[bytes]:
    """One key a grid (N, R, R, R) bool: its packed bits, equal exactly when the grids are."""
    return [row.tobytes() for row in np.packbits(grids.reshape(len(grids), -1), axis=1)]


def naive_error(target, pred):
    """The paper's naive score e = 1 - ||o - o_hat||_2 / ||o||_2 (1 is a perfect completion;
    ``|o|`` read as the Euclidean norm of the target vector)."""
    t, p, single = _pair(target, pred)
    n_t = t.reshape(len(t), -1).sum(axis=1)
    if (n_t == 0).any():
        raise ValueError(f"naive error is undefined for an empty target (batch index {int(np.argmax(n_t == 0))})")
    diff = (t != p).reshape(len(t), -1).sum(axis=1)
    return _out(1.0 - np.sqrt(diff) / np.sqrt(n_t), single)


def iou(target, pred):
    """Intersection over union of occupied voxels."""
    t, p, single = _pair(target, pred)
    inter = (t & p).reshape(len(t), -1).sum(axis=1)
    union = (t | p).reshape(len(t), -1).sum(axis=1)
    return _out(np.where(union == 0, 1.0, inter / np.maximum(union, 1)), single)


def surface(grid: np.ndarray) -> np.ndarray:
    """Occupied voxels with at least one empty 6-neighbour (the grid's outside is empty)."""
    g = np.asarray(grid) > 0.5
    return g & ~ndimage.binary_erosion(g, border_value=0)


def chamfer(target, pred):
    """Symmetric Chamfer distance (voxels) between grid surfaces: mean distance from each
    surface voxel of one to the nearest of the other, averaged over both directions."""
    t, p, single = _pair(target, pred)
    out = []
    for a, b in zip(t, p):
        sa, sb = surface(a), surface(b)
        if not sa.any() and not sb.any():
            out.append(0.0)
        elif not sa.any() or not sb.any():
            out.append(a.shape[0] * np.sqrt(3.0))
        else:
            d_ab = ndimage.distance_transform_edt(~sb)[sa].mean()
            d_ba = ndimage.distance_transform_edt(~sa)[sb].mean()
            out.append((d_ab + d_ba) / 2.0)
    return _out(np.array(out), single)


def completion_errors(target, pred) -> dict[str, np.ndarray]:
    """All four metrics for a batch: ``{"edt": ..., "naive": ..., "iou": ..., "chamfer": ...}``."""
    return {"edt": np.atleast_1d(edt_error(target, pred)), "naive": np.atleast_1d(naive_error(target, pred)),
            "iou": np.atleast_1d(iou(target, pred)), "chamfer": np.atleast_1d(chamfer(target, pred))}
