"""hbeo.subspace.size on tiny inputs: fills, spectra, counts at a fraction, the shared dimension and the
table of cases; and the committed table agrees with the reference run's own components."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hbeo.subspace import size

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "results" / "cpu-modelnet10-vox30"


def _boxes(n=12, r=8, seed=0):
    """n solid boxes of random extents in an r^3 grid, two classes."""
    rng = np.random.default_rng(seed)
    g = np.zeros((n, r, r, r), bool)
    for i in range(n):
        lo = rng.integers(0, 3, 3)
        hi = lo + rng.integers(2, r - 2, 3)
        g[i, lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True
    return g, np.arange(n) % 2


def test_surface_shell_of_a_solid_cube():
    g = np.zeros((1, 6, 6, 6), bool)
    g[0, 1:5, 1:5, 1:5] = True                    # 4^3 = 64 voxels, 2^3 = 8 inside
    assert size.surface_shell(g).sum() == 56
    full = np.ones((1, 3, 3, 3), bool)             # outside the grid counts as empty
    assert size.surface_shell(full).sum() == 26


def test_without_margin_and_quarter_turns():
    g = np.zeros((1, 10, 10, 10), bool)
    g[0, 2:8, 2:8, 2:8] = True                     # fills the central 6^3 exactly
    assert size.without_margin(g, margin=2).all()
    t = size.quarter_turns(g[:, :, :, :] & (np.arange(10) < 5)[None, :, None, None])
    assert t.shape == (4, 10, 10, 10) and len({int(x.sum()) for x in t}) == 1
    assert not np.array_equal(t[0], t[1]) and np.array_equal(t[0], np.rot90(t[2], 2, axes=(0, 1)))
    with pytest.raises(ValueError, match="unknown fill"):
        size.fill(g, "hollow")


def test_counts_and_fraction_for_dim():
    r = size.ratios([6.0, 3.0, 1.0])
    assert np.allclose(r, [0.6, 0.3, 0.1])
    assert size.count_at(r, 0.6) == 1 and size.count_at(r, 0.61) == 2 and size.count_at(r, 1.0) == 3
    assert size.count_at([0.2, 0.1], 0.6) == 2                       # never reached: all of them
    spectra = {"a": r, "b": size.ratios([1.0, 1.0, 1.0, 1.0])}
    assert size.shared_dim({c: size.count_at(s, 0.6) for c, s in spectra.items()}) == 1 + 3 + 2
    f = size.fraction_for_dim(spectra, 7)                             # 2 + 3, +2 means
    assert size.shared_dim({c: size.count_at(s, f) for c, s in spectra.items()}) >= 7
    assert size.shared_dim({c: size.count_at(s, f - 1e-6) for c, s in spectra.items()}) < 7
    assert np.isnan(size.fraction_for_dim(spectra, 100))


def test_the_subspace_keeps_the_fewest_components_that_reach_the_fraction():
    """ObjectSubspace's own count rule, by hand: ratios [5, 3, 1, 1] / 10 have running sums 0.5, 0.8,
    0.9, 1.0, so a fraction of 0.6 needs 2 components, 0.5 and 0.8 (reached exactly) 1 and 2, 1.0 all 4."""
    from hbeo.subspace.basis import ObjectSubspace
    count = ObjectSubspace(max_components=2)._count_ratio
    r = np.array([5.0, 3.0, 1.0, 1.0]) / 10
    assert [count(r, f) for f in (0.1, 0.5, 0.6, 0.8, 0.85, 0.9, 1.0)] == [1, 1, 2, 2, 3, 3, 4]
    assert count(r, None) == 4 and count(np.array([]), 0.6) == 0
    assert count(np.array([1.0]), 0.6) == 1 and count(np.array([0.7, 0.3]), 0.6) == 1
    with pytest.warns(UserWarning, match="raise max_components"):
        assert count(np.array([0.2, 0.1]), 0.6) == 2                 # never reached: all of them
    with pytest.warns(UserWarning, match="limited by its training objects, not max_components"):
        ObjectSubspace(max_components=3)._count_ratio(np.array([0.2, 0.1]), 0.6)   # fewer than the cap
    for f in np.linspace(0.05, 1.0, 20):                              # the same rule as size.count_at
        assert count(r, f) == size.count_at(r, f)


def test_spectra_agree_with_numpy():
    g, _ = _boxes()
    X = g.reshape(len(g), -1).astype(float)
    lam = np.linalg.eigvalsh(np.cov(X.T, bias=True))[::-1][:len(X)]
    assert np.allclose(size.spectrum(g, "pca"), np.clip(lam, 0, None), atol=1e-9)
    assert np.allclose(size.spectrum(g, "singular-values") ** 2, size.spectrum(g, "pca"))
    assert size.spectrum(g, "uncentred")[0] > size.spectrum(g, "pca")[0]    # the mean's direction
    assert size.spectrum(g, "standardized").sum() == pytest.approx((X.std(0) > 0).sum())
    with pytest.raises(ValueError, match="covariance accounting"):
        size.spectrum(g, "vbpca")


def test_size_table_on_tiny_grids():
    g, y = _boxes(16)
    cases = (("solid", "pca", None), ("surface", "pca", 4), ("solid, 4 quarter turns", "pca", None),
             ("solid", "vbpca", None))
    t = size.size_table(g, y, ("a", "b"), cases=cases, target=6)
    assert list(t["fill"]) == [c[0] for c in cases] and list(t["objects per class"]) == ["all", 4, "all", "all"]
    assert (t["shared dimension"] == t["a"] + t["b"] + 2).all()
    assert t["objects (fewest-most)"].tolist() == ["8-8", "4-4", "32-32", "8-8"]
    assert t["basis rank"].iloc[3] != "" and t["basis rank"].iloc[0] == ""
    assert (t["most"] >= t["fewest"]).all()


def test_committed_table_matches_the_reference_run():
    """The committed table's default case (VBPCA, solid, all objects) is the run's own basis: the counts of
    02_components.csv and the counts at the 344-dimension fraction of 02_paper_counts.csv."""
    t = pd.read_csv(RUN / "02_subspace_size.csv")
    default = t[(t["fill"] == "solid") & (t["accounting"] == "vbpca") & (t["objects per class"] == "all")].iloc[0]
    comp = pd.read_csv(RUN / "02_components.csv", index_col=0)["components at 60 %"]
    assert {c: int(default[c]) for c in comp.index} == comp.to_dict()
    assert int(default["basis rank"]) == int(default["shared dimension"]) == comp.sum() + len(comp)
    paper = pd.read_csv(RUN / "02_paper_counts.csv", index_col=0)["at the 344-dim fraction"]
    assert int(default["fewest at 344"]) == paper.min() and int(default["most at 344"]) == paper.max()


def test_the_method_page_table_is_the_committed_file_s():
    t = pd.read_csv(RUN / "02_subspace_size.csv")
    assert size.markdown_table(t) in (ROOT / "docs" / "method.md").read_text(), \
        "stale table in docs/method.md: paste hbeo.subspace.size.markdown_table of 02_subspace_size.csv"
