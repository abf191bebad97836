"""ObjectSubspace (hbeo.subspace.basis) on the ci run's grids (conftest): the shared basis,
reconstruction and partial projection of held-out objects, fitting options, the file."""
import numpy as np
import pytest

from hbeo.subspace import metrics
from hbeo.errors import DataError
from hbeo.subspace.basis import ObjectSubspace

SOME = ("bed", "chair", "table")       #: the classes of the fitting-option tests (a fit of all ten takes ~1.5 s)


@pytest.fixture(scope="module")
def data(ci_grids):
    """(train, test) GridSets of the ci run: 6 + 3 procedural objects of each of the ten classes."""
    return ci_grids["train"], ci_grids["test"]


@pytest.fixture(scope="module")
def fitted(data, ci_subspace):
    """The ci run's subspace: fitted on ``data``'s training grids at 60 % variance per class."""
    tr, _ = data
    assert ci_subspace.classes_ == tr.classes and ci_subspace.variance == 0.6
    return ci_subspace


@pytest.fixture(scope="module")
def some(data):
    """(grids, labels) of the training objects of the classes ``SOME``, labels into ``SOME``."""
    tr, _ = data
    names = np.array(tr.classes)[tr.labels]
    keep = np.isin(names, SOME)
    return tr.grids[keep], np.array([SOME.index(c) for c in names[keep]])


def test_shared_basis_is_orthonormal_and_spans_components_and_means(fitted):
    S = fitted
    W = S.basis_.astype(np.float64)
    assert W.shape == (27000, S.dim_)
    assert np.allclose(W.T @ W, np.eye(S.dim_), atol=1e-4)
    assert len(S.classes_) == 10 and S.dim_ == sum(S.n_components_.values()) + 10   # generic data: full rank
    for i, c in enumerate(S.classes_):
        M = np.vstack([S.class_components_[c], S.class_means_[i]]).astype(np.float64)
        resid = M - (M @ W) @ W.T
        assert np.abs(resid).max() < 1e-3 * np.abs(M).max()
        assert np.cumsum(S.class_variance_ratio_[c])[-1] >= 0.6


def test_reconstruction_of_held_out_objects(fitted, data):
    _, te = data
    rec = fitted.reconstruct(fitted.project(te.grids), threshold=0.5)
    assert rec.dtype == bool and rec.shape == te.grids.shape
    assert metrics.iou(te.grids, rec).mean() > 0.5


def test_partial_projection_with_everything_known_is_full_projection(fitted, data):
    _, te = data
    known = np.ones_like(te.grids)
    exact = fitted.partial_project(te.grids, known, ridge=0.0)
    assert np.allclose(exact, fitted.project(te.grids), atol=1e-3)


def test_partial_projection_solves_the_masked_normal_equations(fitted, data):
    _, te = data
    rng = np.random.default_rng(0)
    for frac in (0.3, 0.8):                        # direct and complement ways of building A
        known = rng.random(te.grids.shape) < frac
        x = fitted.partial_project(te.grids, known, ridge=1e-3).astype(np.float64)
        W = fitted.basis_.astype(np.float64)
        for i in range(len(x)):
            k = known[i].ravel()
            grad = W[k].T @ (W[k] @ x[i] - te.grids[i].ravel()[k]) + 1e-3 * x[i]
            assert np.abs(grad).max() < 1e-3 * max(1.0, np.abs(W[k].T @ te.grids[i].ravel()[k]).max())


def test_partial_projection_completes_a_half_hidden_object(fitted, data):
    tr, _ = data
    g = tr.grids[:6]
    known = np.zeros_like(g)
    known[:, :, :15] = True                       # the y < 15 half is observed, the y >= 15 half is not
    hidden = ~known
    rec = fitted.reconstruct(fitted.partial_project(g, known), threshold=0.5)
    hidden_only = g.copy()                        # the truth in the unobserved half
    hidden_only[:, :, :15] = False
    assert hidden_only.reshape(len(g), -1).sum(1).min() > 100          # every object has a hidden part
    assert metrics.iou(g, rec).mean() > metrics.iou(g, g & known).mean()   # better than what was seen
    # in the unobserved half, the completion beats the mean shape of the object's own (true) class
    # (measured: IoU 0.82-1.0 against 0.34-0.69 for the class mean)
    labels = np.asarray(tr.labels)[:6]
    class_mean = np.stack([fitted.class_means_[c].reshape(g.shape[1:]) >= 0.5 for c in labels])
    got = metrics.iou(hidden_only, rec & hidden)
    baseline = metrics.iou(hidden_only, class_mean & hidden)
    assert (got > baseline).all() and got.mean() > 0.75, (got, baseline)


def test_lasso_matches_lstsq_without_penalty_and_sparsifies_with_it(fitted, data):
    _, te = data
    known = np.ones_like(te.grids)
    plain = fitted.partial_project(te.grids, known, ridge=0.0)
    l0 = fitted.partial_project(te.grids, known, method="lasso", lam=0.0, max_iter=50)
    assert np.allclose(l0, plain, atol=1e-3)
    big = fitted.partial_project(te.grids, known, method="lasso", lam=1e6)
    assert not big.any()
    small = fitted.partial_project(te.grids, known, method="lasso", lam=0.5)
    assert (small == 0).sum() > (plain == 0).sum()


def test_fixed_counts_and_shared_dim_target(some):
    G, L = some
    fixed = ObjectSubspace(n_components={"bed": 2, "chair": 3, "table": 1}).fit(G, L, SOME, progress=False)
    assert fixed.n_components_ == {"bed": 2, "chair": 3, "table": 1} and fixed.dim_ == 9
    target = ObjectSubspace(shared_dim=15).fit(G, L, SOME, progress=False)
    assert target.dim_ >= 15
    lower = ObjectSubspace(variance=target.variance_used_ - 1e-6).fit(G, L, SOME, progress=False)
    assert lower.dim_ < 15                         # the smallest fraction that reaches the target
    with pytest.raises(ValueError, match="out of reach.*fewer than its training objects.*more training objects"):
        ObjectSubspace(shared_dim=10_000).fit(G, L, SOME, progress=False)
    with pytest.raises(ValueError, match=r"out of reach.*raise max_components \(2; reached by chair, table\)"):
        ObjectSubspace(shared_dim=10_000, max_components=2).fit(G, L, SOME, progress=False)


def test_save_load_round_trip(fitted, data, tmp_path):
    _, te = data
    back = ObjectSubspace.load(fitted.save(tmp_path / "s.npz"))
    assert back.dim_ == fitted.dim_ and back.fingerprint_ == fitted.fingerprint_
    assert back.n_components_ == fitted.n_components_ and back.classes_ == fitted.classes_
    assert np.array_equal(back.project(te.grids), fitted.project(te.grids))
    for c in fitted.classes_:
        assert np.array_equal(back.class_components_[c], fitted.class_components_[c])
    (tmp_path / "bad.npz").write_text("nope")
    with pytest.raises(DataError, match=r"bad\.npz"):
        ObjectSubspace.load(tmp_path / "bad.npz")


def test_bad_training_data(data):
    tr, _ = data
    g = tr.grids.copy()
    g[3] = False
    with pytest.raises(ValueError, match="empty grids"):
        ObjectSubspace().fit(g, tr.labels, tr.classes, progress=False)
    with pytest.raises(ValueError, match="labels"):
        ObjectSubspace().fit(tr.grids, tr.labels[:-1], tr.classes, progress=False)
    with pytest.raises(RuntimeError, match="not fitted"):
        ObjectSubspace().project(tr.grids)


def test_eigen_objects_and_counts_from_spectra(fitted):
    S = fitted
    c = "chair"
    i = S.classes_.index(c)
    assert np.allclose(S.eigen_object(c).ravel(), S.class_means_[i])
    moved = S.eigen_object(c, 0, 2.0).ravel() - S.class_means_[i]
    std = np.sqrt(S.class_variance_ratio_[c][0] * S.class_total_variance_[c])
    assert np.allclose(moved, 2.0 * std * S.class_components_[c][0], atol=1e-5)
    assert S.counts_at(0.6) == S.n_components_
    f = S.fraction_for_dim(S.dim_ + 3)
    n = len(S.classes_)
    assert sum(S.counts_at(f).values()) + n >= S.dim_ + 3 > sum(S.counts_at(f - 1e-6).values()) + n


def test_run_gridsets_reads_what_it_wrote(ci_run, ci_grids, monkeypatch, tmp_path):
    """The session's ci run was built by run_gridsets; a second call reads its files (an empty
    voxel cache and unchanged files show nothing was voxelized or written) and gives the same sets."""
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.data.gridset import run_gridsets
    assert ci_run.grids("train").exists() and len(ci_grids["test"]) == 30 and len(ci_grids["train"]) == 60
    stamps = {s: ci_run.grids(s).stat().st_mtime_ns for s in ("train", "test")}
    monkeypatch.setenv("HBEO_CACHE", str(tmp_path / "cache"))
    again = run_gridsets(ci_run, datasets.get_dataset("procedural", profile="ci"), config.get_profile("ci"),
                         progress=False)
    assert not (tmp_path / "cache").exists()
    assert {s: ci_run.grids(s).stat().st_mtime_ns for s in ("train", "test")} == stamps
    for s in ("train", "test"):
        a, b = ci_grids[s], again[s]
        assert np.array_equal(a.grids, b.grids) and np.array_equal(a.labels, b.labels)
        assert list(a.ids) == list(b.ids) and a.classes == b.classes


def test_reconstruct_equals_the_dense_product(fitted):
    """reconstruct skips the basis rows that are all zero; the answer is W o' exactly."""
    rng = np.random.default_rng(0)
    c = rng.normal(size=(4, fitted.dim_)).astype(np.float32)
    dense = (c @ fitted.basis_.T).reshape(4, 30, 30, 30)
    assert np.allclose(fitted.reconstruct(c), dense, atol=1e-5)
    assert np.array_equal(fitted.reconstruct(c, threshold=0.1), dense >= 0.1) or \
        np.abs(dense - 0.1).min() < 1e-5              # only a value at the threshold itself could differ


def test_fix_signs_makes_the_largest_entry_positive_first_on_ties():
    from hbeo.subspace.vbpca import fix_signs
    A = np.array([[0.1, -0.5, 0.0, 0.7], [-0.9, 0.2, 0.0, -0.7], [0.3, 0.4, 0.0, 0.1]])
    out = fix_signs(A)
    assert np.array_equal(out, A * np.array([-1, -1, 1, 1]))   # zero column kept; tie (0.7, -0.7): the first
    flipped = A * np.array([1, -1, -1, -1])
    assert np.array_equal(fix_signs(flipped), out)
    assert np.array_equal(fix_signs(A[:, :0]), A[:, :0])


def test_basis_signs_do_not_depend_on_the_eigensolver(some, monkeypatch):
    """Two LAPACK builds return eigenvectors with arbitrary signs (the reference VM and another one
    disagreed on 12 of 143 directions); the basis is the same whichever signs eigh returns."""
    from scipy import linalg
    import hbeo.subspace.basis as basis
    G, L = some
    first = ObjectSubspace(n_components={"bed": 2, "chair": 3, "table": 1}).fit(G, L, SOME, progress=False)
    eigh = linalg.eigh

    def eigh_flipped(a, *args, **kw):                  # every other eigenvector negated, in VBPCA too
        w, v = eigh(a, *args, **kw)
        return w, v * np.where(np.arange(v.shape[1]) % 2, -1.0, 1.0)
    monkeypatch.setattr(basis.linalg, "eigh", eigh_flipped)
    again = ObjectSubspace(n_components={"bed": 2, "chair": 3, "table": 1}).fit(G, L, SOME, progress=False)
    assert np.allclose(again.basis_, first.basis_, atol=1e-6)
    lead = np.abs(first.basis_).argmax(axis=0)
    assert (first.basis_[lead, np.arange(first.dim_)] > 0).all()


def test_component_counts_are_the_fewest_that_reach_the_variance_fraction(fitted):
    """Each class keeps the fewest leading components whose ratios reach 60 %: all but the last fall short."""
    for c in fitted.classes_:
        k, spectrum = fitted.n_components_[c], fitted.class_spectrum_[c]
        assert 1 <= k <= len(spectrum)
        assert np.sum(spectrum[:k]) >= 0.6 - 1e-9
        assert np.sum(spectrum[:k - 1]) < 0.6, (c, k, np.cumsum(spectrum))
        assert len(fitted.class_components_[c]) == k


def test_a_class_whose_fit_did_not_converge_is_named(some):
    """A per-class VBPCA stopped by its iteration cap warns, naming the class (no filter hides it)."""
    from sklearn.exceptions import ConvergenceWarning
    X, y = some
    with pytest.warns(ConvergenceWarning, match=r"cap of 2 iterations .* for 3 of 3 classes: bed \(\de-\d\d\), ch"):
        ObjectSubspace(vbpca={"max_iter": 2}).fit(X, y, classes=SOME, progress=False)
