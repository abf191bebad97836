"""Which accounting of "60 % of the variance" gives which basis size: per-class component counts and the
shared dimension under named readings of the paper's rule, measured on training grids.

Owns the comparison behind the method page's "Why 143 dimensions and not 344": for each *case* (a fill of
the grids, an accounting of the variance, a sample of the training objects) the components each class keeps
at a variance fraction, the shared dimension that gives, and the one common fraction that would give the
paper's 344 dimensions. The default basis (:class:`~hbeo.subspace.basis.ObjectSubspace`, VBPCA on the solid
grids) is one case among them; nothing here changes it.

Shapes and units: grids bool (N, R, R, R) (R = 30 for ModelNet10), labels int (N,) into ``classes``;
spectra float64 (k,) are variances in occupancy units squared (a voxel is 0 or 1), descending, and
:func:`ratios` divides them by the accounting's total, so ratios are unitless and sum to at most 1.
Shared dimension: components plus one mean per class (the rank of ``[W_1 .. W_m, mu_1 .. mu_m]`` when
they are independent, as in the reference run; the VBPCA cases report the orthonormalized rank itself).

Regenerate the committed table (a few minutes on 2 cores)::

    python -m hbeo.subspace.size --out results/cpu-modelnet10-vox30/02_subspace_size.csv
"""
from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from scipy import ndimage

from hbeo.subspace.basis import ObjectSubspace

#: The paper's figures this comparison is held against: the shared dimension and the per-class range.
PAPER_DIM = 344
PAPER_RANGE = (30, 70)
#: The published 3D ShapeNets grids' margin: an object's longest side spans R - 2 x MARGIN voxels.
MARGIN = 3

#: Accountings of the variance (name -> what "the fraction of the variance" is the fraction of).
ACCOUNTINGS = {
    "vbpca": "VBPCA's fitted component variances over the data's total variance about the fitted mean "
             "(noise included in the total): the default basis's rule",
    "vbpca-signal": "VBPCA's fitted component variances over their own sum (the noise term left out)",
    "pca": "eigenvalues of the centred sample covariance over its trace",
    "uncentred": "eigenvalues of the uncentred second moment (the mean's direction included) over its trace",
    "standardized": "eigenvalues of the correlation matrix (every voxel scaled to unit variance)",
    "singular-values": "singular values of the centred data (standard deviations, not variances) over their sum",
}
#: Fills of the grids (name -> what the grids are).
FILLS = {
    "solid": "the published grids: solid, longest side 24 voxels, 3-voxel margin",
    "surface": "their surface shell (filled voxels with an empty 6-neighbour)",
    "solid, no margin": "the solid grids rescaled (nearest voxel) so the longest side spans the whole grid",
    "surface, no margin": "the surface shell of the rescaled solid grids",
    "solid, 4 quarter turns": "the solid grids and their copies turned 90, 180 and 270 degrees about +z",
}
#: The committed cases: (fill, accounting, training objects per class or None for all).
CASES = (("solid", "vbpca", None), ("solid", "pca", None), ("solid", "vbpca-signal", None), ("solid", "uncentred", None), ("solid", "standardized", None),
         ("solid", "singular-values", None), ("solid", "pca", 100),
         ("solid, 4 quarter turns", "pca", None), ("solid, no margin", "pca", None),
         ("surface", "pca", None), ("surface", "pca", 100), ("surface, no margin", "pca", None),
         ("surface, no margin", "vbpca", None))
_VBPCA = {"vbpca": {}, "vbpca-signal": {}}


def surface_shell(grids) -> np.ndarray:
    """Bool (N, R, R, R): the filled voxels of ``grids`` with at least one empty 6-neighbour (outside the
    grid counts as empty)."""
    g = np.asarray(grids, bool)
    inner = ndimage.binary_erosion(g, structure=ndimage.generate_binary_structure(3, 1)[None], border_value=0)
    return g & ~inner


def without_margin(grids, margin: int = MARGIN) -> np.ndarray:
    """Bool (N, R, R, R): the central (R - 2 margin)^3 block of each grid resampled (nearest voxel) onto
    the whole grid, as if voxelized with the longest side spanning R voxels instead of R - 2 margin."""
    g = np.asarray(grids, bool)
    r = g.shape[1]
    idx = (np.arange(r) * (r - 2 * margin) / r).astype(int) + margin
    return g[:, idx][:, :, idx][:, :, :, idx]


def quarter_turns(grids) -> np.ndarray:
    """Bool (4N, R, R, R): the grids and their copies turned a quarter, half and three quarters about +z
    (axes (x, y, z), the last one up)."""
    g = np.asarray(grids, bool)
    return np.concatenate([np.rot90(g, k, axes=(1, 2)) for k in range(4)])


def fill(grids, name: str) -> np.ndarray:
    """The grids under the fill ``name`` (a key of :data:`FILLS`)."""
    if name == "solid":
        return np.asarray(grids, bool)
    if name == "surface":
        return surface_shell(grids)
    if name == "solid, no margin":
        return without_margin(grids)
    if name == "surface, no margin":
        return surface_shell(without_margin(grids))
    if name == "solid, 4 quarter turns":
        return quarter_turns(grids)
    raise ValueError(f"unknown fill {name!r}; one of {list(FILLS)}")


def spectrum(X, accounting: str = "pca") -> np.ndarray:
    """Descending spectrum (k,) of samples ``X`` (n, d) (or grids) under a non-VBPCA ``accounting``:
    eigenvalues (occupancy units squared) of the centred covariance, the uncentred second moment or the
    correlation matrix, or the centred data's singular values / sqrt(n) (occupancy units). Computed from the
    n x n Gram matrix; a d x d matrix is never formed."""
    X = np.asarray(X).reshape(len(X), -1).astype(np.float64)
    if accounting not in ("pca", "uncentred", "standardized", "singular-values"):
        raise ValueError(f"spectrum: {accounting!r} is not a covariance accounting (VBPCA ones: vbpca_spectrum)")
    if accounting != "uncentred":
        X = X - X.mean(axis=0)
    if accounting == "standardized":
        sd = X.std(axis=0)
        X = X[:, sd > 0] / sd[sd > 0]
    lam = np.clip(np.linalg.eigvalsh(X @ X.T / len(X))[::-1], 0, None)
    return np.sqrt(lam) if accounting == "singular-values" else lam


def ratios(values) -> np.ndarray:
    """A spectrum divided by its sum (unitless, sums to 1; zeros for an all-zero spectrum)."""
    v = np.asarray(values, np.float64)
    return v / v.sum() if v.sum() > 0 else np.zeros_like(v)


def count_at(ratio, fraction: float) -> int:
    """Fewest leading entries of ``ratio`` whose sum reaches ``fraction`` (all of them if it never does)."""
    r = np.asarray(ratio, np.float64)
    reach = np.cumsum(r) >= fraction - 1e-12
    return int(np.argmax(reach)) + 1 if reach.any() else len(r)


def shared_dim(counts: dict) -> int:
    """Components of all classes plus one mean per class."""
    return int(sum(counts.values())) + len(counts)


def fraction_for_dim(spectra: dict, target: int) -> float:
    """Smallest common fraction (to 1e-9) at which ``spectra`` ({class: ratios}) give ``shared_dim`` >=
    ``target``; NaN when even all their directions fall short."""
    def dim(f):
        return shared_dim({c: count_at(r, f) for c, r in spectra.items()})
    if dim(1.0) < target:
        return float("nan")
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if dim(mid) < target else (lo, mid)
    return hi


def _sample(labels, per_class, seed) -> np.ndarray:
    """Indices of at most ``per_class`` objects of each class (drawn with ``seed``), or all."""
    labels = np.asarray(labels)
    if per_class is None:
        return np.arange(len(labels))
    rng = np.random.default_rng(seed)
    return np.sort(np.concatenate([rng.choice(np.flatnonzero(labels == c), min(per_class, (labels == c).sum()),
                                              replace=False) for c in np.unique(labels)]))


def case_spectra(grids, labels, classes, fill_name: str = "solid", accounting: str = "pca",
                 per_class: int | None = None, seed: int = 0, fraction: float = 0.6,
                 max_components: int = 150) -> tuple[dict, int | None, dict]:
    """One case: ({class: ratios}, the VBPCA basis's orthonormalized dimension at ``fraction`` or None for
    a covariance accounting, {class: training objects used}). Quarter turns multiply a class's objects by 4."""
    labels = np.asarray(labels)
    pick = _sample(labels, per_class, seed)
    G, y = np.asarray(grids)[pick], labels[pick]
    if fill_name == "solid, 4 quarter turns":
        y = np.tile(y, 4)
    G = fill(G, fill_name)
    n = {c: int((y == i).sum()) for i, c in enumerate(classes)}
    if accounting in _VBPCA:
        sub = ObjectSubspace(variance=fraction, max_components=max_components, vbpca=_VBPCA[accounting])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sub.fit(G, y, classes, progress=False)
        spectra = dict(sub.class_spectrum_)
        if accounting == "vbpca-signal":
            return {c: ratios(r) for c, r in spectra.items()}, None, n
        return spectra, sub.dim_, n
    return {c: ratios(spectrum(G[y == i], accounting)) for i, c in enumerate(classes)}, None, n


def size_table(grids, labels, classes, cases=CASES, fraction: float = 0.6, target: int = PAPER_DIM,
               seed: int = 0, max_components: int = 150, log=None) -> pd.DataFrame:
    """One row per case: fill, accounting, objects per class, the components each class keeps at
    ``fraction``, their range, the shared dimension (components + one mean per class), the VBPCA basis's
    own rank where fitted, the classes inside :data:`PAPER_RANGE`, the common fraction giving ``target``
    dimensions and the per-class range there. ``log``: called with each finished row's label."""
    lo, hi = PAPER_RANGE
    rows = []
    for fill_name, accounting, per_class in cases:
        spectra, rank, n = case_spectra(grids, labels, classes, fill_name, accounting, per_class, seed,
                                        fraction, max_components)
        k = {c: count_at(r, fraction) for c, r in spectra.items()}
        f = fraction_for_dim(spectra, target)
        kt = {c: count_at(r, f) for c, r in spectra.items()} if np.isfinite(f) else {}
        row = {"fill": fill_name, "accounting": accounting,
               "objects per class": "all" if per_class is None else per_class, **{c: k[c] for c in classes},
               "fewest": min(k.values()), "most": max(k.values()), "shared dimension": shared_dim(k),
               "basis rank": rank if rank is not None else "",
               f"classes keeping {lo}-{hi}": sum(lo <= v <= hi for v in k.values()),
               f"fraction for {target}": round(f, 4) if np.isfinite(f) else "",
               f"fewest at {target}": min(kt.values()) if kt else "",
               f"most at {target}": max(kt.values()) if kt else "",
               "objects (fewest-most)": f"{min(n.values())}-{max(n.values())}"}
        rows.append(row)
        if log:
            log(f"{fill_name} / {accounting} / {row['objects per class']}: {row['fewest']}-{row['most']}, "
                f"shared {row['shared dimension']}")
    return pd.DataFrame(rows)


def markdown_table(table: pd.DataFrame) -> str:
    """The method page's table of a :func:`size_table` (read back from its CSV): one row per case, counts only."""
    lo, hi = PAPER_RANGE
    head = ("| grids | variance counted as | objects per class | components per class | shared dimension "
            f"| classes keeping {lo}–{hi} |\n| --- | --- | --- | ---: | ---: | ---: |")
    cols = list(table.columns)
    m = cols.index("fewest") - cols.index("objects per class") - 1              # the class columns between
    rows = [f"| {r['fill']} | {r['accounting']} | {r['objects per class']} | {r['fewest']}–{r['most']} "
            f"| {r['shared dimension']} | {r[f'classes keeping {lo}-{hi}']} of {m} |"
            for _, r in table.iterrows()]
    return "\n".join([head, *rows])


def training_grids(profile: str = "cpu"):
    """(grids bool (N, 30, 30, 30), labels (N,), classes) of the ``modelnet10-vox30`` training split as the
    ``profile``'s run selects it (empty grids skipped by the dataset)."""
    from hbeo import config
    from hbeo.data import datasets
    ds = datasets.get_dataset("modelnet10-vox30", profile=config.get_profile(profile))
    recs = datasets.select(ds, "train", profile)
    classes = tuple(ds.classes)
    grids = np.stack([r.grid() for r in recs]).astype(bool)
    return grids, np.array([classes.index(r.cls) for r in recs]), classes


def main(argv=None) -> int:
    import argparse
    import sys
    from hbeo.storage import atomic_text
    p = argparse.ArgumentParser(prog="python -m hbeo.subspace.size", description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="CSV to write")
    p.add_argument("--profile", default="cpu")
    p.add_argument("--fraction", type=float, default=0.6)
    a = p.parse_args(argv)
    grids, labels, classes = training_grids(a.profile)
    table = size_table(grids, labels, classes, fraction=a.fraction,
                       log=lambda s: print(s, file=sys.stderr, flush=True))
    atomic_text(a.out, table.to_csv(index=False))
    print(table.to_string())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
