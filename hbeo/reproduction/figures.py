"""Pictures of grids for notebooks: a fast shaded voxel renderer and galleries.

:func:`render_voxels` draws an occupancy grid as an orthographic, Lambert-shaded
image in pure numpy (milliseconds per grid, unlike matplotlib's ``voxels``), seen
from azimuth ``azim`` (degrees about +z, from +x toward +y) and elevation ``elev``
(degrees above the xy plane). The canonical frame's +z is up in the picture. Panels for axes
(depth images, confusion matrices, error violins) and :func:`save`, which writes a figure into the
run folder (:meth:`hbeo.rundir.RunDir.figure`).

May import: foundation (matplotlib lazily).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from hbeo import conventions as C
from hbeo.rotations import view_deg_to_matrix
from hbeo.rundir import RunDir
from hbeo.storage import atomic_file


def save(fig, run, name: str, dpi: int = 90, **savefig_kw) -> Path:
    """Write matplotlib figure ``fig`` as the run's PNG ``name`` (``NN_name.png``) atomically;
    returns the path. ``savefig_kw`` go to ``Figure.savefig`` (e.g. ``bbox_inches="tight"``)."""
    path = RunDir.of(run).figure(name)
    with atomic_file(path) as f:
        fig.savefig(f, format="png", dpi=dpi, **savefig_kw)
    return path


def render_voxels(grid: np.ndarray, azim: float = -60.0, elev: float = 25.0, size: int = 160,
                  color=(0.30, 0.55, 0.85), background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Occupancy grid (R, R, R) -> RGB image (size, size, 3), floats in [0, 1]."""
    grid = np.asarray(grid, dtype=bool)
    r = grid.shape[0]
    img = np.empty((size, size, 3))
    img[:] = background
    shell = grid & ~ndimage.binary_erosion(grid)
    if not shell.any():
        return img
    smooth = ndimage.gaussian_filter(grid.astype(np.float32), 1.0)
    normals = -np.stack(np.gradient(smooth), axis=-1)[shell]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-9
    rot = view_deg_to_matrix(azim, elev)                      # rows: right, up, toward the viewer
    pts = (np.argwhere(shell) + 0.5 - r / 2.0) @ rot.T          # (N, 3): right, up, toward viewer
    light = rot.T @ np.array([0.4, 0.6, 0.7])
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.clip(normals @ light, 0, 1)
    px = size / (r * 0.95 * np.sqrt(2))                       # pixels per voxel, room for any view
    half = max(1, int(np.ceil(px * 0.75)))
    off = np.arange(-half, half + 1)
    ox, oy = [o.ravel() for o in np.meshgrid(off, off)]
    cx = np.round(size / 2 + pts[:, 0] * px).astype(int)[:, None] + ox
    cy = np.round(size / 2 - pts[:, 1] * px).astype(int)[:, None] + oy
    depth = np.repeat(pts[:, 2:3], len(ox), axis=1)
    val = np.repeat(shade[:, None], len(ox), axis=1)
    ok = (cx >= 0) & (cx < size) & (cy >= 0) & (cy < size)
    cx, cy, depth, val = cx[ok], cy[ok], depth[ok], val[ok]
    order = np.argsort(depth, kind="stable")                  # far first, near last: near wins
    flat = cy[order] * size + cx[order]
    out = np.full(size * size, np.nan)
    out[flat] = val[order]
    hit = ~np.isnan(out)
    rgb = img.reshape(-1, 3)
    rgb[hit] = np.clip(out[hit, None] * np.asarray(color)[None], 0, 1)
    return rgb.reshape(size, size, 3)


def gallery(grids, titles=None, ncols: int = 5, size: int = 160, panel: float = 1.8, **view):
    """Matplotlib figure showing grids (sequence of (R, R, R)) in a table of rendered panels."""
    import matplotlib.pyplot as plt
    n = len(grids)
    ncols = max(1, min(ncols, n))
    nrows = max(1, int(np.ceil(n / ncols)))
    fig, axes = plt.subplots(nrows, ncols, figsize=(panel * ncols, panel * nrows + 0.3), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for i, g in enumerate(grids):
        ax = axes.ravel()[i]
        ax.imshow(render_voxels(g, size=size, **view))
        if titles is not None:
            ax.set_title(titles[i], fontsize=8)
    fig.tight_layout()
    return fig


def class_gallery(gridset, per_class: int = 3, **kw):
    """Gallery with ``per_class`` examples of each class of a :class:`hbeo.data.gridset.GridSet`."""
    picks, titles = [], []
    for ci, name in enumerate(gridset.classes):
        idx = np.flatnonzero(gridset.labels == ci)[:per_class]
        for i in idx:
            picks.append(gridset.grids[i])
            titles.append(f"{name}\n{gridset.ids[i]}")
    return gallery(picks, titles, ncols=per_class * 2 if per_class <= 3 else per_class, **kw)


def eigen_gallery(subspace, classes=None, modes: int = 2, sigmas: float = 2.0, **kw):
    """Eigen-objects: per class, the mean and the mean moved -/+ ``sigmas`` standard deviations
    along each of the first ``modes`` components (fields thresholded at 0.5)."""
    grids, titles = [], []
    for c in classes or subspace.classes_:
        n = min(modes, subspace.n_components_[c])
        grids.append(subspace.eigen_object(c) >= 0.5)
        titles.append(f"{c}\nmean")
        for j in range(modes):
            for sgn in (-1, 1):
                ok = j < n
                grids.append(subspace.eigen_object(c, j, sgn * sigmas) >= 0.5 if ok else np.zeros((1, 1, 1), bool))
                titles.append(f"mode {j + 1} {'-' if sgn < 0 else '+'}{sigmas:g}σ" if ok else "")
    return gallery(grids, titles, ncols=1 + 2 * modes, **kw)


def show_depth(ax, depth, title: str | None = None, vmax: float | None = None):
    """Draw a depth image (H, W), metres, on a matplotlib axis: near = bright, no object = white."""
    d = np.ma.masked_less_equal(np.asarray(depth, dtype=np.float32), 0)
    ax.imshow(d, cmap="viridis_r", vmin=d.min() if d.count() else 0, vmax=vmax or (d.max() if d.count() else 1))
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)


def depth_and_grid_gallery(items, size: int = 120, panel: float = 1.7):
    """Figure with pairs (depth image, its object's grid): ``items`` = [(depth, grid, title), ...]."""
    import matplotlib.pyplot as plt
    n = len(items)
    ncols = 4
    nrows = max(1, int(np.ceil(n / 2)))
    fig, axes = plt.subplots(nrows, ncols, figsize=(panel * ncols, panel * nrows + 0.3), squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    for i, (depth, grid, title) in enumerate(items):
        a, b = axes[i // 2, 2 * (i % 2)], axes[i // 2, 2 * (i % 2) + 1]
        show_depth(a, depth, title)
        b.imshow(render_voxels(grid, size=size))
        b.set_title("grid (canonical frame)", fontsize=8)
    fig.tight_layout()
    return fig


def confusion(ax, matrix, classes, title: str | None = None):
    """Row-normalized confusion matrix (rows: true class, columns: predicted) with counts."""
    m = np.asarray(matrix, dtype=float)
    norm = m / np.maximum(m.sum(1, keepdims=True), 1)
    ax.imshow(norm, cmap="Blues", vmin=0, vmax=1)
    names = [c.replace("_", " ") for c in classes]
    ax.set_xticks(range(len(classes)), names, rotation=90, fontsize=7)
    ax.set_yticks(range(len(classes)), names, fontsize=7)
    ax.set_xlabel("predicted class", fontsize=8)
    ax.set_ylabel("true class", fontsize=8)
    for i in range(len(classes)):
        for j in range(len(classes)):
            if m[i, j]:
                ax.text(j, i, int(m[i, j]), ha="center", va="center", fontsize=6,
                        color="white" if norm[i, j] > 0.5 else "black")
    if title:
        ax.set_title(title, fontsize=9)


def error_violins(ax, groups: dict, ylabel: str, title: str | None = None):
    """Violin per group {label: values} with the mean marked by a dot and the median by a bar
    (the paper's pose-error figure marks the mean with a circle)."""
    labels = list(groups)
    data = [np.asarray(groups[k], dtype=float) for k in labels]
    pos = np.arange(1, len(data) + 1)
    ok = [d for d in data if len(d) > 1]
    if ok:
        ax.violinplot([d if len(d) > 1 else np.repeat(d, 2) for d in data], pos, showmedians=True,
                      showextrema=False)
    ax.scatter(pos, [d.mean() if len(d) else np.nan for d in data], color="k", zorder=3, label="mean")
    ax.set_xticks(pos, [f"{k}\n(n={len(d)})" for k, d in zip(labels, data)], fontsize=7)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7, loc="upper right")
    if title:
        ax.set_title(title, fontsize=9)


assert C.RESOLUTION == 30  # the renderer's defaults assume the standard grid size
