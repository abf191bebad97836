"""What notebook 02 shows about the run's subspace: components per class, the VBPCA spectra, what
the paper's 344 dimensions would take, and completions of held-out test grids (full projection
and from a half-hidden grid).

Grids are bool (N, 30, 30, 30); completion errors are :mod:`hbeo.subspace.metrics`' (EDT e' and
Chamfer in voxels, naive e and IoU unitless), tabled by :mod:`hbeo.subspace.completion`.

May import: foundation, data, subspace, and :mod:`hbeo.report.figures` (matplotlib lazily).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from hbeo.report import figures
from hbeo.subspace import completion

#: The paper's shared dimension and its per-class component range at 60 % of the variance.
PAPER_DIM = 344
PAPER_RANGE = (30, 70)
#: The half-hidden mask: every voxel with y >= HIDDEN_FROM is unknown.
HIDDEN_FROM = 15


def component_counts(sub, train) -> pd.DataFrame:
    """Per class: training grids, components kept, and VBPCA's noise variance."""
    return pd.DataFrame({"training grids": train.counts(), "components at 60 %": sub.n_components_,
                         "noise variance": sub.class_noise_variance_})


def spectrum_figure(sub, variance: float = 0.6):
    """Cumulative explained variance per class against the number of components (log scale, plain
    tick labels), with ``variance`` marked by a dashed line in the legend."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    fig, ax = plt.subplots(figsize=(7.5, 4), layout="constrained")
    for c, r in sub.class_spectrum_.items():
        ax.plot(np.arange(1, len(r) + 1), np.cumsum(r), label=c)
    ax.axhline(variance, color="k", ls="--", lw=0.8, label=f"{variance:.0%} of the variance:\ncomponents kept")
    ax.set(xscale="log", xlabel="components (log scale)", ylabel="cumulative explained variance")
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1, 2, 3, 5)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    fig.suptitle("VBPCA spectrum per class: variance explained by the first k components", fontsize=11)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    return fig


def _fraction_for(spectrum, k: int) -> float:
    """The variance fraction at which a class keeps ``k`` components (NaN: it has fewer)."""
    return float(np.cumsum(spectrum)[k - 1]) if len(spectrum) >= k else np.nan


def paper_counts(sub) -> pd.DataFrame:
    """Per class: components at 60 %, at the one fraction giving :data:`PAPER_DIM` dimensions, and
    the fractions at which the class would keep :data:`PAPER_RANGE` components. Prints that common
    fraction (NaN, with the reason, when the run has too few grids for that many directions)."""
    try:
        f = sub.fraction_for_dim(PAPER_DIM)
        at = sub.counts_at(f)
    except ValueError as err:          # small runs have too few grids per class for 344 directions
        f, at = np.nan, {c: np.nan for c in sub.classes_}
        print(f"{PAPER_DIM} dimensions out of reach on this run:", err)
    print(f"common fraction giving {PAPER_DIM} dimensions: {f:.3f}")
    lo, hi = PAPER_RANGE
    return pd.DataFrame({"at 60 %": sub.n_components_, f"at the {PAPER_DIM}-dim fraction": at,
                         f"fraction for {lo}": {c: _fraction_for(r, lo) for c, r in sub.class_spectrum_.items()},
                         f"fraction for {hi}": {c: _fraction_for(r, hi) for c, r in sub.class_spectrum_.items()}})


def one_per_class(gridset) -> list[int]:
    """Index of the first grid of each class present in ``gridset``, in class order."""
    return [int(np.flatnonzero(gridset.labels == i)[0]) for i in range(len(gridset.classes))
            if (gridset.labels == i).any()]


def reconstruction_gallery(sub, test, full: pd.DataFrame):
    """One test grid per class beside its full-projection completion, titled with the IoU from
    ``full`` (:func:`hbeo.subspace.completion.evaluate` rows of ``test``)."""
    pick = one_per_class(test)
    recon = sub.reconstruct(sub.project(test.grids[pick]), threshold=0.5)
    grids = [g for pair in zip(test.grids[pick], recon) for g in pair]
    titles = [t for i in pick for t in (f"{test.ids[i]}\ntruth", f"full projection\nIoU {full.iou[i]:.2f}")]
    title = ("Held-out test grids, one per class (truth), beside their completion from the full projection "
             "onto the shared subspace (field thresholded at 0.5), titled with its IoU with the truth")
    return figures.gallery(grids, titles, ncols=6, size=110, panel=1.4, title=title)


def half_mask(shape) -> np.ndarray:
    """Known-voxel mask of ``shape`` (N, 30, 30, 30): voxels with y < :data:`HIDDEN_FROM` known."""
    known = np.zeros(shape, bool)
    known[:, :, :HIDDEN_FROM] = True
    return known


def partial_table(sub, test, full: pd.DataFrame, known: np.ndarray, seed: int = 0) -> pd.DataFrame:
    """Mean completion errors per class (rows) for the full projection (``full``), the
    ``known``-masked partial projection and a random half of the voxels hidden (``seed``);
    columns (setting, error)."""
    half = completion.evaluate(sub, test, known)
    rand = completion.evaluate(sub, test, completion.random_mask(test.grids.shape, 0.5, seed=seed))
    return pd.concat({"full": completion.by_class(full), "y-half hidden": completion.by_class(half),
                      "random half hidden": completion.by_class(rand)}, axis=1)


def partial_gallery(sub, test, known: np.ndarray):
    """One test grid per class: what ``known`` lets through, its partial-projection completion,
    and the truth (titles assume :func:`half_mask`)."""
    pick = one_per_class(test)
    obs = test.grids[pick] & known[pick]
    comp = sub.reconstruct(sub.partial_project(test.grids[pick], known[pick]), threshold=0.5)
    grids = [g for trio in zip(obs, comp, test.grids[pick]) for g in trio]
    titles = [t for i in pick for t in (f"{test.ids[i]}\nseen (y < {HIDDEN_FROM})",
                                        f"partial projection,\ny ≥ {HIDDEN_FROM} hidden", "truth")]
    title = (f"Completion from half a grid: the voxels with y ≥ {HIDDEN_FROM} (grid index) are hidden, "
             "and the partial projection fits the subspace coordinates to the seen voxels only; per test grid: "
             "seen half, completion, truth")
    return figures.gallery(grids, titles, ncols=6, size=110, panel=1.4, title=title)
