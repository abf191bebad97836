
import numpy as np
import pytest
from scipy.linalg import subspace_angles
from sklearn.decomposition import PCA
from sklearn.exceptions import ConvergenceWarning

from hbeo.subspace.vbpca import VBPCA


def planted(n, d, scales, noise, seed=0, offset=3.0):
    rng = np.random.default_rng(seed)
    B = np.linalg.qr(rng.normal(size=(d, len(scales))))[0]
    X = (rng.normal(size=(n, len(scales))) * scales) @ B.T + noise * rng.normal(size=(n, d)) + offset
    return X, B


def test_recovers_planted_subspace_with_d_much_larger_than_n():
    X, B = planted(n=150, d=3000, scales=[12, 10, 8, 6], noise=0.1)
    m = VBPCA(n_components=20, max_iter=2000).fit(X)
    # ARD switches off most of the 16 surplus columns; the few left (n << d lets noise
    # fluctuations reach 1-2x the noise variance) carry a negligible share of the variance
    assert m.n_active_ == 4
    assert m.explained_variance_[:4].sum() > 0.999 * m.explained_variance_.sum()
    angles = np.degrees(subspace_angles(m.components_[:4].T, B))
    best = np.degrees(subspace_angles(PCA(4).fit(X).components_.T, B))   # what this sample allows
    assert angles.max() < 6 and angles.max() < best.max() + 0.5
    assert abs(m.noise_variance_ - 0.01) < 0.001
    assert np.allclose(m.components_ @ m.components_.T, np.eye(m.n_components_), atol=1e-6)
    assert np.all(np.diff(m.explained_variance_) <= 0)


def test_lower_bound_never_decreases_and_converges():
    X, _ = planted(n=80, d=500, scales=[5, 3], noise=0.3, seed=1)
    m = VBPCA(n_components=10, tol=1e-9, max_iter=3000).fit(X)
    steps = np.diff(m.elbo_)
    assert steps.min() >= -1e-9 * abs(m.elbo_[-1])
    assert m.n_iter_ < 3000 and m.n_iter_ == len(m.elbo_)


def test_warns_when_stopping_on_the_iteration_cap():
    X, _ = planted(n=40, d=200, scales=[5, 3], noise=0.3, seed=2)
    with pytest.warns(ConvergenceWarning, match="max_iter=3"):
        VBPCA(max_iter=3, tol=1e-15).fit(X)


def test_agrees_with_ppca_in_the_large_n_limit():
    X, _ = planted(n=20000, d=12, scales=[4, 3, 2], noise=0.5, seed=3)
    m = VBPCA(n_components=3).fit(X)
    p = PCA(n_components=3).fit(X)
    assert np.degrees(subspace_angles(m.components_.T, p.components_.T)).max() < 0.5
    assert np.allclose(m.explained_variance_, p.explained_variance_ - p.noise_variance_, rtol=0.01)
    assert np.isclose(m.noise_variance_, p.noise_variance_, rtol=0.01)
    assert np.allclose(m.mean_, X.mean(0), atol=1e-3)
    assert np.isclose(m.score(X), p.score(X), rtol=1e-3)


def test_variance_keeps_fewest_components_reaching_the_fraction():
    X, _ = planted(n=200, d=400, scales=[10, 6, 4, 2], noise=0.1, seed=4)
    full = VBPCA().fit(X)
    cum = np.cumsum(full.explained_variance_ratio_)
    m = VBPCA(variance=0.6).fit(X)
    k = int(np.argmax(cum >= 0.6)) + 1
    assert m.n_components_ == k and cum[k - 2] < 0.6 <= cum[k - 1]
    with pytest.warns(UserWarning, match="less than variance=0.999"):
        VBPCA(n_components=2, variance=0.999).fit(X)


def test_transform_inverse_round_trip_and_score():
    X, _ = planted(n=100, d=300, scales=[9, 5], noise=0.05, seed=5)
    m = VBPCA(n_components=2).fit(X)
    Z = m.transform(X)
    assert Z.shape == (100, m.n_components_)
    err = np.linalg.norm(m.inverse_transform(Z) - X)
    p = PCA(n_components=m.n_components_).fit(X)
    err_pca = np.linalg.norm(p.inverse_transform(p.transform(X)) - X)   # the best rank-k fit
    assert m.n_components_ == 2 and err < 1.01 * err_pca
    assert np.isfinite(m.score(X))
    with pytest.raises(ValueError, match="features"):
        m.transform(X[:, :10])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, bool])
def test_dtypes(dtype):
    X, _ = planted(n=60, d=200, scales=[6, 4], noise=0.2, seed=6)
    X = (X > 3.0) if dtype is bool else X.astype(dtype)
    m = VBPCA().fit(X)
    assert m.components_.dtype == (np.float32 if dtype is np.float32 else np.float64)
    assert m.n_components_ >= 1 and np.isfinite(m.elbo_).all()


def test_degenerate_inputs_give_clear_results():
    rng = np.random.default_rng(0)
    one = rng.random((1, 30))
    m = VBPCA().fit(one)
    assert m.n_components_ == 0 and np.allclose(m.mean_, one[0], atol=0.02)   # prior shrinks slightly
    same = np.tile(one, (6, 1))
    m = VBPCA().fit(same)
    assert m.n_components_ == 0 and m.transform(same).shape == (6, 0)
    zero = VBPCA().fit(np.zeros((5, 30)))
    assert zero.n_components_ == 0 and not zero.mean_.any()
    with pytest.raises(ValueError, match="2-D"):
        VBPCA().fit(np.zeros(30))
    with pytest.raises(ValueError, match="NaN"):
        VBPCA().fit(np.full((3, 4), np.nan))
    with pytest.raises(ValueError, match="variance"):
        VBPCA(variance=1.5).fit(one)
