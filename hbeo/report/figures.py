"""Pictures of grids for notebooks: a fast shaded voxel renderer and galleries.

:func:`render_voxels` draws an occupancy grid as an orthographic, Lambert-shaded
image in pure numpy (milliseconds per grid, unlike matplotlib's ``voxels``), seen
from azimuth ``azim`` (degrees about +z, from +x toward +y) and elevation ``elev``
(degrees above the xy plane). The canonical frame's +z is up in the picture. Panels for axes
(depth images, confusion matrices, error violins) and :func:`save`, which writes a figure into the
run folder (:meth:`hbeo.rundir.RunDir.figure`).

:data:`METHOD_COLORS` is the one place that gives each method setting its colour: every figure of
notebooks 05-07 (:mod:`hbeo.report.paper_figures`) colours a method with
:func:`method_color`, the paper's reported figures in the light shade of the same colour.

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


#: Key of HBEO with the verify step (metrics with a non-null ``verify``) and of the trivial
#: class-mean completion, in :data:`METHOD_COLORS`; the other keys are (method, pose).
HBEO_VERIFY, CLASS_MEAN = "hbeo + verify", "class mean"
#: One colour per method setting (matplotlib's tab10), the same in every figure. HBEO is blue; the
#: class-mean answer grey. 3DShapeNets appears only as the paper's reported figures.
METHOD_COLORS = {("hbeo", "3dof"): "#1f77b4", HBEO_VERIFY: "#9467bd", ("beo", "known"): "#2ca02c",
                 ("beo", "1dof"): "#ff7f0e", ("beo", "3dof"): "#d62728", ("icp", "3dof"): "#8c564b",
                 ("icp", "1dof"): "#17becf", ("voxcnn", "known"): "#e377c2", ("3dshapenets", "known"): "#bcbd22",
                 CLASS_MEAN: "#7f7f7f"}
#: Colour of a setting missing from :data:`METHOD_COLORS` (near black, unlike all of them).
OTHER_COLOR = "#333333"


def method_key(metrics: dict):
    """Key of a metrics dict (:mod:`hbeo.evaluation.evaluate`) in :data:`METHOD_COLORS`:
    :data:`HBEO_VERIFY` when it ran the verify step (``protocol.VERIFIED``), else (method, pose)."""
    if metrics.get("verify") or str(metrics["method"]).endswith("-verify"):
        return HBEO_VERIFY
    return (metrics["method"], metrics["pose"])


def method_color(key, shade: str = "dark") -> str:
    """Hex colour of a method: ``key`` is a :data:`METHOD_COLORS` key or a metrics dict; ``shade``
    ``dark`` (the colour itself: this run) or ``light`` (mixed halfway with white: the paper's
    reported figures beside it)."""
    if isinstance(key, dict):
        key = method_key(key)
    color = METHOD_COLORS.get(key, OTHER_COLOR)
    if shade == "dark":
        return color
    if shade != "light":
        raise ValueError(f"shade must be 'dark' or 'light', got {shade!r}")
    rgb = np.array([int(color[i:i + 2], 16) for i in (1, 3, 5)], float)
    return "#" + "".join(f"{int(round(v)):02x}" for v in rgb + 0.5 * (255 - rgb))


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


def gallery(grids, titles=None, ncols: int = 5, size: int = 160, panel: float = 1.8, title: str | None = None,
            **view):
    """Matplotlib figure showing grids (sequence of (R, R, R)) in a table of rendered panels, under
    the figure title ``title`` (wrapped to the figure's width) when given."""
    import textwrap
    import matplotlib.pyplot as plt
    n = len(grids)
    ncols = max(1, min(ncols, n))
    nrows = max(1, int(np.ceil(n / ncols)))
    width = panel * ncols
    lines = [w for part in (title or "").split("\n") for w in textwrap.wrap(part, int(width * 72 / 5.8)) or [""]]
    head = 0.19 * len(lines) + 0.15 if title else 0.0                # inches above the panels
    height = panel * nrows + 0.3 + head
    fig, axes = plt.subplots(nrows, ncols, figsize=(width, height), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for i, g in enumerate(grids):
        ax = axes.ravel()[i]
        ax.imshow(render_voxels(g, size=size, **view))
        if titles is not None:
            ax.set_title(titles[i], fontsize=8)
    if title:
        fig.suptitle("\n".join(lines), fontsize=10, y=1 - 0.05 / height, va="top").set_in_layout(False)
    fig.tight_layout(rect=(0, 0, 1, 1 - head / height))
    return fig


def class_gallery(gridset, per_class: int = 3, title: str | None = None, **kw):
    """Gallery with ``per_class`` examples of each class of a :class:`hbeo.data.gridset.GridSet`,
    titled with the split and the viewpoint (``title`` replaces that figure title)."""
    picks, titles = [], []
    for ci, name in enumerate(gridset.classes):
        idx = np.flatnonzero(gridset.labels == ci)[:per_class]
        for i in idx:
            picks.append(gridset.grids[i])
            titles.append(f"{name}\n{gridset.ids[i]}")
    if title is None:
        r, split = gridset.grids.shape[-1], {"train": "training"}.get(gridset.split, gridset.split)
        az, el = (f"{kw.get(k, d):g}°".replace("-", "−") for k, d in (("azim", -60.0), ("elev", 25.0)))
        title = (f"The first {per_class} {split} grids of each class: filled {r}³ occupancy grids, "
                 f"seen from azimuth {az}, elevation {el} (+z up)")
    return gallery(picks, titles, ncols=per_class * 2 if per_class <= 3 else per_class, title=title, **kw)


def eigen_gallery(subspace, classes=None, modes: int = 2, sigmas: float = 2.0, title: str | None = None, **kw):
    """Eigen-objects: per class, the mean and the mean moved -/+ ``sigmas`` standard deviations
    along each of the first ``modes`` components (fields thresholded at 0.5); ``title`` replaces the
    figure title that says so."""
    grids, titles = [], []
    for c in classes or subspace.classes_:
        n = min(modes, subspace.n_components_[c])
        grids.append(subspace.eigen_object(c) >= 0.5)
        titles.append(f"{c}\nmean")
        for j in range(modes):
            for sgn in (-1, 1):
                ok = j < n
                grids.append(subspace.eigen_object(c, j, sgn * sigmas) >= 0.5 if ok else np.zeros((1, 1, 1), bool))
                titles.append(f"mode {j + 1} {'−' if sgn < 0 else '+'}{sigmas:g}σ" if ok else "")
    if title is None:
        title = (f"Eigen-objects: each class's mean grid and the mean moved ± {sigmas:g}σ along its first "
                 f"{modes} principal components (σ: the standard deviation of the class's training grids "
                 f"along that component; fields thresholded at 0.5; blank: the class kept fewer components)")
    return gallery(grids, titles, ncols=1 + 2 * modes, title=title, **kw)


def show_depth(ax, depth, title: str | None = None, vmax: float | None = None, vmin: float | None = None,
               colorbar: bool = False):
    """Draw a depth image (H, W), metres, on a matplotlib axis: near = bright, no object = white.
    The colour scale runs from ``vmin`` to ``vmax`` (default: this image's nearest and farthest
    pixel; give panels one pair to share a scale); ``colorbar`` adds a bar in metres beside ``ax``.
    Returns the image (for a colour bar shared by several panels)."""
    d = np.ma.masked_less_equal(np.asarray(depth, dtype=np.float32), 0)
    lo = vmin if vmin is not None else (d.min() if d.count() else 0)
    im = ax.imshow(d, cmap="viridis_r", vmin=lo, vmax=vmax or (d.max() if d.count() else 1))
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)
    if colorbar:
        ax.figure.colorbar(im, ax=ax, fraction=0.046, pad=0.04).set_label("depth (m)", fontsize=8)
    return im


def depth_and_grid_gallery(items, size: int = 120, panel: float = 1.7, title: str | None = None):
    """Figure with pairs (depth image, its object's grid): ``items`` = [(depth, grid, title), ...];
    the depth images share one colour scale, shown by a colour bar in metres; ``title``: the
    figure title."""
    import matplotlib.pyplot as plt
    n = len(items)
    ncols = 4
    nrows = max(1, int(np.ceil(n / 2)))
    seen = np.concatenate([np.asarray(d, np.float32).ravel() for d, _, _ in items] or [np.zeros(0)])
    seen = seen[seen > 0]
    lo, hi = (float(seen.min()), float(seen.max())) if len(seen) else (0.0, 1.0)
    bar = 0.9                                                   # inches on the right for the colour bar
    head = 0.4 * (title or "").count("\n") + 0.45 if title else 0.0
    fig, axes = plt.subplots(nrows, ncols, figsize=(panel * ncols + bar, panel * nrows + 0.3 + head),
                             squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    im = None
    for i, (depth, grid, title_i) in enumerate(items):
        a, b = axes[i // 2, 2 * (i % 2)], axes[i // 2, 2 * (i % 2) + 1]
        im = show_depth(a, depth, title_i, vmin=lo, vmax=hi)
        b.imshow(render_voxels(grid, size=size))
        b.set_title("its grid (canonical frame)", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    right = panel * ncols / (panel * ncols + bar)
    fig.tight_layout(rect=(0, 0, right, 1))
    if im is not None:
        top, bottom = axes[0, 0].get_position().y1, axes[-1, 0].get_position().y0
        cax = fig.add_axes((right + 0.15 * (1 - right), bottom + 0.15 * (top - bottom), 0.12 * (1 - right),
                            0.7 * (top - bottom)))
        fig.colorbar(im, cax=cax).set_label("depth (m)", fontsize=8)
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


def error_violins(ax, groups: dict, ylabel: str, title: str | None = None, colors: dict | None = None) -> list:
    """Violin per group {label: values} in its colour (``colors`` {label: colour}), a narrow box
    inside (median line, interquartile range, whiskers to 1.5 IQR) and the mean as a black dot (the
    paper's pose-error figure marks the mean with a circle). Draws no legend: returns the handles
    for a figure legend outside the axes."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    labels = list(groups)
    data = [np.asarray(groups[k], dtype=float) for k in labels]
    colors = colors or {}
    pos = np.arange(1, len(data) + 1)
    many = [(p, d) for p, d in zip(pos, data) if len(d) > 1]
    if many:
        parts = ax.violinplot([d for _, d in many], [p for p, _ in many], showextrema=False, widths=0.8)
        for body, k in zip(parts["bodies"], [labels[p - 1] for p, _ in many]):
            body.set_facecolor(colors.get(k, OTHER_COLOR))
            body.set_edgecolor(colors.get(k, OTHER_COLOR))
            body.set_alpha(0.45)
    full = [(p, d) for p, d in zip(pos, data) if len(d)]
    if full:
        ax.boxplot([d for _, d in full], positions=[p for p, _ in full], widths=0.14, showfliers=False,
                   patch_artist=True, boxprops=dict(facecolor="white", edgecolor="k", linewidth=0.9),
                   medianprops=dict(color="k", linewidth=1.6), whiskerprops=dict(color="k", linewidth=0.9),
                   capprops=dict(color="k", linewidth=0.9))
    ax.scatter(pos, [d.mean() if len(d) else np.nan for d in data], s=36, color="k", edgecolor="white",
               zorder=4)
    ax.set_xticks(pos, [f"{k}\n(n={len(d)})" for k, d in zip(labels, data)], fontsize=7)
    ax.set_xlim(0.4, len(data) + 0.6)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=9)
    return [Patch(facecolor="0.6", alpha=0.45, label="distribution of the queries (violin)"),
            Patch(facecolor="white", edgecolor="k", label="box: interquartile range,\nline: median, whiskers 1.5 IQR"),
            Line2D([], [], ls="", marker="o", color="k", markeredgecolor="white", markersize=7,
                   label="mean (the paper's circles)")]


assert C.RESOLUTION == 30  # the renderer's defaults assume the standard grid size
