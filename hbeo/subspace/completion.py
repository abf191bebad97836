"""Completion with the object subspace: masks, projection, errors per object and per class."""
from __future__ import annotations

import numpy as np
import pandas as pd
from hbeo.progress import tqdm

from hbeo.subspace import metrics
from hbeo.data.gridset import GridSet
from hbeo.subspace.basis import ObjectSubspace


def random_mask(shape, known_fraction: float = 0.5, seed: int = 0) -> np.ndarray:
    """Bool mask of ``shape``: each voxel known independently with probability ``known_fraction``."""
    if not 0 <= known_fraction <= 1:
        raise ValueError(f"known_fraction must be in [0, 1], got {known_fraction}")
    return np.random.default_rng(seed).random(shape) < known_fraction


def complete(subspace: ObjectSubspace, grids: np.ndarray, known: np.ndarray | None = None,
             method: str = "lstsq", batch: int = 64, progress: bool = True, **kw) -> np.ndarray:
    """Completed bool grids (N, 30, 30, 30): full projection if ``known`` is None, else partial
    projection from the voxels ``known`` marks; back-projected and thresholded at 0.5."""
    out = np.empty(grids.shape, bool)
    for i in tqdm(range(0, len(grids), batch), desc="complete", unit="batch", disable=not progress):
        g = grids[i:i + batch]
        c = subspace.project(g) if known is None else subspace.partial_project(g, known[i:i + batch],
                                                                                method=method, **kw)
        out[i:i + batch] = subspace.reconstruct(c, threshold=0.5)
    return out


def evaluate(subspace: ObjectSubspace, gs: GridSet, known: np.ndarray | None = None,
             method: str = "lstsq", progress: bool = True, **kw) -> pd.DataFrame:
    """One row per object of ``gs``: id, class, and the completion errors edt, naive, iou, chamfer."""
    pred = complete(subspace, gs.grids, known, method=method, progress=progress, **kw)
    errs = metrics.completion_errors(gs.grids, pred)
    return pd.DataFrame({"id": gs.ids, "class": [gs.classes[i] for i in gs.labels], **errs})


def by_class(df: pd.DataFrame) -> pd.DataFrame:
    """Mean of each error per class, plus an ``all`` row (mean over objects)."""
    cols = [c for c in ("edt", "naive", "iou", "chamfer") if c in df]
    out = df.groupby("class")[cols].mean()
    out.loc["all"] = df[cols].mean()
    return out
