"""What notebook 01 shows about a dataset and its 30^3 grids: class counts, one object voxelized
step by step, the layout check per class, and the comparison with the published grids.

Grids are bool (30, 30, 30) in the 3D ShapeNets layout (:mod:`hbeo.conventions`); occupancy is a
fraction of the 27,000 voxels, spans and indices are in voxels.

May import: foundation, data, and :mod:`hbeo.report.figures` (matplotlib lazily).
"""
from __future__ import annotations


import numpy as np
import pandas as pd

from hbeo import config
from hbeo import conventions
from hbeo.data import datasets
from hbeo.report import figures


def class_counts(ds, profile) -> pd.DataFrame:
    """The dataset's objects per class and split (:meth:`Dataset.summary`), with the run's share:
    ``train (run)``, ``test (run)`` (the first n of each class the profile selects)."""
    counts = ds.summary()
    picked = {s: datasets.select(ds, s, profile) for s in conventions.SPLITS}
    for s, recs in picked.items():
        used = pd.Series([r.cls for r in recs]).value_counts()
        counts[f"{s} (run)"] = used.reindex(counts.index).fillna(0).astype(int)
    counts.loc["total", [f"{s} (run)" for s in conventions.SPLITS]] = [len(picked[s]) for s in conventions.SPLITS]
    return counts


def steps_figure(ds, profile):
    """The run's first training object: its mesh's vertices (y against z, mesh units), the surface
    voxels and the filled grid, the two grids from the renderer's default viewpoint. None (with a
    note) when the source stores grids only."""
    import matplotlib.pyplot as plt
    from hbeo.data.voxel import fill_solid, surface_grid
    rec = datasets.select(ds, "train", profile)[0]
    if not rec.has_mesh:
        print(f"{ds.name} stores grids, not meshes: nothing to voxelize for {rec.id}")
        return None
    mesh = rec.mesh()
    surface = surface_grid(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    solid = fill_solid(surface, close=1)
    r = conventions.RESOLUTION
    fig, ax = plt.subplots(1, 3, figsize=(9, 3.6), layout="constrained")
    v = np.asarray(mesh.vertices)
    mid, half = (v.max(0) + v.min(0)) / 2, 0.55 * (v.max(0) - v.min(0)).max()   # the grid's cube + 10 %
    ax[0].scatter(v[:, 1], v[:, 2], s=1)
    ax[0].set(xlim=(mid[1] - half, mid[1] + half))             # z follows: equal aspect, centred on the mesh
    ax[0].set_aspect("equal", adjustable="datalim")
    ax[0].set(xlabel="y (mesh units)", ylabel="z (mesh units)")
    ax[0].set_title(f"mesh: {len(v)} vertices", fontsize=9)
    for a, g, t in [(ax[1], surface, "surface voxels"), (ax[2], solid, "filled voxels")]:
        a.imshow(figures.render_voxels(g))
        a.set_title(f"{t}: {g.sum()}", fontsize=9)
        a.axis("off")
    fig.suptitle(f"Voxelizing {rec.id} into the {r}³ grid: mesh vertices (side view along x) → surface "
                 f"voxels → filled voxels\n(grids seen from azimuth −60°, elevation 25°, +z up)", fontsize=10)
    return fig


def layout_by_class(gridset) -> pd.DataFrame:
    """Per class of a :class:`~hbeo.data.gridset.GridSet`: objects, mean occupancy, and the
    smallest and largest span of the occupied region along its longest axis (the layout: 24)."""
    rows = []
    for g, lab in zip(gridset.grids, gridset.labels):
        nz = np.argwhere(g)
        rows.append({"class": gridset.classes[lab], "occupancy": g.mean(),
                     "longest span": (nz.max(0) - nz.min(0) + 1).max() if len(nz) else 0})
    df = pd.DataFrame(rows)
    return df.groupby("class").agg(objects=("occupancy", "size"), occupancy=("occupancy", "mean"),
                                   span_min=("longest span", "min"), span_max=("longest span", "max"))


def compare_with_published() -> pd.DataFrame | None:
    """IoU of each ModelNet10 sample bathtub mesh voxelized here against its published 3D ShapeNets
    grid, one row (``IoU``) with a ``mean`` column; None (with a note) when ``shared/modelnet10_sample``
    or the published grids are not found (:func:`hbeo.config.modelnet10_sample_dir`, :func:`hbeo.config.vox30_path`)."""
    from hbeo.data.voxel import voxelize
    sample, vox_file = config.modelnet10_sample_dir(), config.vox30_path()
    if sample is None or vox_file is None:
        print("shared/modelnet10_sample or modelnet10_vox30 not found: comparison skipped")
        return None
    with np.load(vox_file, allow_pickle=False) as z:
        names, X = list(z["names_train"]), z["X_train"]
    ious = {}
    for path in sorted(sample.glob("bathtub/train/*.off")):
        g, r = voxelize(path), X[names.index(path.stem)].astype(bool)
        ious[path.stem] = (g & r).sum() / (g | r).sum()
    ious["mean"] = float(np.mean(list(ious.values()))) if ious else np.nan
    return pd.Series(ious, name="IoU").to_frame().T
