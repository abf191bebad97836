"""Near-duplicate objects and the validation split that keeps them together.

Owns: grid IoU between objects of the same class (:func:`pairwise_iou`, :func:`nearest_iou`), the
groups of near-duplicates (:func:`twin_groups`: connected components of same-class objects whose grid
IoU reaches a threshold) and the grouped validation split (:func:`split_groups`: whole groups go to
validation, class by class). Why: ModelNet's training split holds many near-duplicate models, so an
object held out at random often keeps a twin in training, and validation then scores higher than the
test split (measured in ``benchmarks/bench_duplicates.py``).

Grids are as stored (ModelNet objects are aligned per class; no alignment search here): bool or 0/1
(n, 30, 30, 30) or (n, 27000). IoU is |a & b| / |a | b| over occupied voxels, computed per class with
float32 matrix products (intersections ``A @ B.T``). Imports numpy and :mod:`hbeo.config` only.
"""
from __future__ import annotations

import numpy as np

from hbeo import config

#: The grouped split's default IoU threshold: same-class training objects whose grids overlap at least
#: this much are one group (the profiles' :attr:`hbeo.config.DataConfig.twin_iou`, where its reason is).
TWIN_IOU = config.DataConfig.twin_iou
#: The validation splits :func:`hbeo.data.datasets.split_validation` knows: ``object`` (objects drawn
#: at random per class, the split every committed result used) and ``grouped`` (whole groups of
#: near-duplicates, :func:`split_groups`).
VAL_SPLITS = ("object", "grouped")


def _flat(grids, name: str = "grids") -> np.ndarray:
    G = np.asarray(grids)
    if G.ndim == 4:
        G = G.reshape(len(G), -1)
    if G.ndim != 2:
        raise ValueError(f"{name} must be (n, 30, 30, 30) or (n, d) occupancy, got shape {G.shape}")
    if G.dtype.kind not in "biuf":
        raise ValueError(f"{name} must hold occupancy (bool or 0/1), got dtype {G.dtype}")
    return G.astype(np.float32)


def pairwise_iou(A, B=None) -> np.ndarray:
    """Grid IoU of every row of ``A`` with every row of ``B`` (``A`` itself when None), float64 (n_a, n_b).
    Two empty grids have IoU 0."""
    a = _flat(A, "A")
    b = a if B is None else _flat(B, "B")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"A and B must have the same grid size, got {a.shape[1]} and {b.shape[1]} voxels")
    inter = (a @ b.T).astype(np.float64)
    union = a.sum(1, dtype=np.float64)[:, None] + b.sum(1, dtype=np.float64)[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def nearest_iou(grids, labels, ref_grids=None, ref_labels=None, chunk: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Each object's largest grid IoU to a reference object of its own class, and that object's index:
    (iou (n,), index (n,) into the reference, -1 where the class has no other object). Without
    ``ref_grids`` the reference is ``grids`` itself, less the object. ``chunk``: rows per product."""
    labels = np.asarray(labels)
    same = ref_grids is None
    ref_labels = labels if same else np.asarray(ref_labels)
    if len(labels) != len(grids) or (not same and len(ref_labels) != len(ref_grids)):
        raise ValueError(f"nearest_iou: {len(grids)} grids but {len(labels)} labels (or the reference's differ)")
    best, where = np.zeros(len(labels)), np.full(len(labels), -1, np.int64)
    for c in np.unique(labels):
        rows, refs = np.flatnonzero(labels == c), np.flatnonzero(ref_labels == c)
        if not len(refs):
            continue
        R = np.asarray(grids if same else ref_grids)[refs]
        for s in range(0, len(rows), chunk):
            part = rows[s:s + chunk]
            iou = pairwise_iou(np.asarray(grids)[part], R)
            if same:                                   # not the object itself
                iou[np.arange(len(part)), np.searchsorted(refs, part)] = -1
                if len(refs) < 2:
                    continue
            j = iou.argmax(1)
            best[part], where[part] = iou[np.arange(len(part)), j], refs[j]
    return best, where


def twin_groups(grids, labels, threshold: float = TWIN_IOU) -> np.ndarray:
    """Group index per object (n,) int64: connected components (union-find) of same-class objects whose
    grid IoU is at least ``threshold``; numbered by first member, in object order."""
    if not 0 < threshold <= 1:
        raise ValueError(f"threshold must be in (0, 1], got {threshold}")
    labels = np.asarray(labels)
    if len(labels) != len(grids):
        raise ValueError(f"twin_groups: {len(grids)} grids but {len(labels)} labels")
    parent = np.arange(len(labels))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for c in np.unique(labels):
        idx = np.flatnonzero(labels == c)
        iou = pairwise_iou(np.asarray(grids)[idx])
        a, b = np.nonzero(np.triu(iou >= threshold, k=1))
        for i, j in zip(idx[a], idx[b]):
            ri, rj = find(i), find(j)
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
    roots = np.array([find(i) for i in range(len(labels))], np.int64)
    _, first, inv = np.unique(roots, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))           # groups numbered by their first member
    return order[inv].astype(np.int64)


def split_groups(labels, groups, val_fraction: float = 0.1, seed: int = 0) -> np.ndarray:
    """Which objects go to validation, a bool mask (n,), taking whole ``groups`` (:func:`twin_groups`):
    per class, the class's groups in a random order (from ``seed``) join validation while they fit in
    ``round(val_fraction * n)`` objects (a group that would overshoot is passed over); a class of two or
    more objects gives at least one object (its smallest group, unless that is the whole class). A group
    never spans classes' sides; deterministic given ``seed``."""
    if not 0 <= val_fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    labels, groups = np.asarray(labels), np.asarray(groups)
    if labels.shape != groups.shape:
        raise ValueError(f"split_groups: labels {labels.shape} and groups {groups.shape} differ")
    rng = np.random.default_rng([int(seed), 0x5EED, 0x6209])
    val = np.zeros(len(labels), bool)
    for c in np.unique(labels):
        objs = np.flatnonzero(labels == c)
        gs, sizes = np.unique(groups[objs], return_counts=True)
        k = int(round(val_fraction * len(objs)))
        taken = 0
        for g in rng.permutation(len(gs)):
            if taken + sizes[g] <= k:
                val[objs[groups[objs] == gs[g]]] = True
                taken += sizes[g]
            if taken == k:
                break
        if val_fraction > 0 and len(objs) >= 2 and taken == 0 and len(gs) > 1:
            g = int(np.argmin(sizes))
            val[objs[groups[objs] == gs[g]]] = True
    return val
