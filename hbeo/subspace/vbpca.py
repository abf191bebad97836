"""Variational Bayesian PCA (Bishop, "Variational principal components", ICANN 1999).

Model, for data ``t_n`` in R^d (n samples)::

    t_n = W x_n + mu + eps,   x_n ~ N(0, I_q),   eps ~ N(0, I_d / tau)
    W[:, i] ~ N(0, I_d / alpha_i)      (ARD: one precision per loading column)
    mu ~ N(0, I_d / beta)              (beta = 1: the zero-mean, unit-variance prior the paper uses)
    alpha_i ~ Gamma(a_alpha, b_alpha),  tau ~ Gamma(a_tau, b_tau)

with the factorized posterior q(X) q(mu) q(W) q(alpha) q(tau), updated in turn
(coordinate ascent on the evidence lower bound, which never decreases).

Made for d >> n (voxel grids: d = 27,000, n = 100-900): all posterior means lie in
the span of the n data vectors, so the updates run in n-dimensional coordinates of
that span with d entering only through the isotropic terms. The result is the
same as the d-dimensional algorithm, at O(n^2 q + q^3) per iteration after one
O(n^2 d) Gram matrix, and O(n d) memory; a d x d matrix is never formed.
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg
from scipy.special import digamma, gammaln
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.exceptions import ConvergenceWarning
from threadpoolctl import threadpool_limits

_LOG2PI = np.log(2 * np.pi)


def fix_signs(columns: np.ndarray) -> np.ndarray:
    """Columns (d, k) -> the same columns, each with the sign that makes its entry of largest magnitude
    positive (magnitudes compared to 6 significant digits of the column's largest, the first in order on a
    tie, as for a mirror-antisymmetric shape mode). An eigenvector's sign is whatever the LAPACK build
    returns: two machines fitting the same grids got 12 of the 143 shared directions with opposite signs,
    so models trained on them learned opposite coefficients. Span and orthonormality are
    unchanged; an all-zero column stays as it is."""
    if columns.size == 0:
        return columns
    mag = np.abs(columns)
    top = mag.max(axis=0)
    lead = np.argmax(np.round(mag / np.where(top > 0, top, 1.0), 6), axis=0)   # first of the (rounded) maxima
    sign = np.sign(columns[lead, np.arange(columns.shape[1])])
    return columns * np.where(sign < 0, -1, 1).astype(columns.dtype)


class VBPCA(TransformerMixin, BaseEstimator):
    """Variational Bayesian PCA with ARD, scikit-learn style.

    Parameters
    ----------
    n_components : int or None
        Cap on the latent dimension q (default: n_samples - 1). ARD switches off
        columns the data do not support, so fewer may remain active.
    variance : float in (0, 1] or None
        If set, keep the fewest leading components whose explained variance
        reaches this fraction of the data's total variance (the paper uses 0.6).
    max_iter, tol : iteration cap and relative lower-bound change that stops the fit
        (a :class:`ConvergenceWarning` is issued when the cap is hit first).
    mean_precision : beta, precision of the Gaussian prior on the mean (1.0: unit variance).
    ard_a, ard_b, noise_a, noise_b : Gamma hyperprior shape/rate on alpha and tau (broad).
    prune_tol : a direction counts as switched off by ARD, and is dropped, when its
        variance is below ``prune_tol`` x the total variance or below its own posterior
        spread (d x the posterior variance of the loading: the prior, not the data,
        determines it).
    prune : set False to keep all ``n_components`` directions (a fixed count) even where ARD
        switched them off.

    Fitted attributes
    -----------------
    components_ : (k, d) orthonormal principal directions, by decreasing variance.
    explained_variance_ : (k,) variance of the signal along each direction (W W^T eigenvalues).
    explained_variance_ratio_ : (k,) the same divided by the data's total variance.
    mean_ : (d,) posterior mean of mu.    noise_variance_ : 1 / E[tau].
    alpha_ : (k,) ARD precisions E[alpha] of the kept directions (in the rotated basis).
    n_components_ : k, the number kept.   n_active_ : components ARD left on.
    n_iter_ : iterations run.             elbo_ : (n_iter_,) lower bound after each iteration.
    total_variance_ : mean squared distance of the samples to ``mean_``.
    """

    def __init__(self, n_components=None, variance=None, max_iter=1000, tol=1e-7,
                 mean_precision=1.0, ard_a=1e-3, ard_b=1e-3, noise_a=1e-3, noise_b=1e-3,
                 prune_tol=1e-6, prune=True):
        self.n_components = n_components
        self.variance = variance
        self.max_iter = max_iter
        self.tol = tol
        self.mean_precision = mean_precision
        self.ard_a = ard_a
        self.ard_b = ard_b
        self.noise_a = noise_a
        self.noise_b = noise_b
        self.prune_tol = prune_tol
        self.prune = prune

    # ------------------------------------------------------------------ fitting
    def _check_X(self, X, fitted=False):
        X = np.asarray(X)
        if X.ndim != 2:
            raise ValueError(f"VBPCA expects a 2-D array (n_samples, n_features), got shape {X.shape}")
        if X.shape[0] < 1 or X.shape[1] < 1:
            raise ValueError(f"VBPCA needs at least one sample and one feature, got shape {X.shape}")
        if X.dtype.kind not in "biuf":
            raise ValueError(f"VBPCA expects numeric data, got dtype {X.dtype}")
        if X.dtype.kind == "f" and not np.isfinite(X).all():
            raise ValueError("VBPCA input contains NaN or infinity")
        if fitted and X.shape[1] != self.mean_.shape[0]:
            raise ValueError(f"X has {X.shape[1]} features, the model was fitted with {self.mean_.shape[0]}")
        return X

    def fit(self, X, y=None):
        """Fit to X (n_samples, n_features); bool, integer, float32 or float64."""
        if self.variance is not None and not 0 < self.variance <= 1:
            raise ValueError(f"variance must be in (0, 1], got {self.variance}")
        if self.n_components is not None and int(self.n_components) < 0:
            raise ValueError(f"n_components must be >= 0, got {self.n_components}")
        X = self._check_X(X)
        n, d = X.shape
        out_dtype = np.float32 if X.dtype == np.float32 else np.float64

        # Coordinates of the data in an orthonormal basis V of its span: X = C V^T.
        if n <= d:   # d >> n: V from the n x n Gram matrix, V = X^T U S^-1, never d x d
            exact32 = X.dtype.kind in "bu" or (X.dtype.kind == "i" and np.abs(X).max() <= 1)
            Xg = X.astype(np.float32 if exact32 and d < 2 ** 24 else np.float64, copy=False)
            G = (Xg @ Xg.T).astype(np.float64)           # integer-exact in float32 for 0/1 data
            sq_norms = np.diag(G).copy()                  # ||t_n||^2
            evals, U = linalg.eigh(G)
            keep = evals > max(evals.max(initial=0.0), 0.0) * 1e-12 * n
            evals, U = evals[keep][::-1], U[:, keep][:, ::-1]
            S = np.sqrt(evals)
            C = U * S                                     # (n, r)
            proj = U / S

            def to_features(A):                           # span coordinates (r, j) -> (d, j)
                return Xg.T @ (proj @ A)
        else:        # n > d: the standard basis will do
            C = X.astype(np.float64)
            sq_norms = np.einsum("ij,ij->i", C, C)

            def to_features(A):
                return A
        r = C.shape[1]

        q_max = min(n - 1, r) if r else 0
        q = q_max if self.n_components is None else min(int(self.n_components), q_max)
        self.n_features_in_ = d
        with threadpool_limits(1 if q < 256 else None, user_api="blas"):  # small: threads only cost
            self._fit_coords(C, sq_norms, d, q)

        Mw, mmu = self._Mw, self._mmu
        self.mean_ = to_features(mmu).astype(out_dtype) if r else np.zeros(d, out_dtype)
        total = float(np.mean(sq_norms) - 2 * np.mean(C @ mmu) + mmu @ mmu) if r else 0.0
        self.total_variance_ = max(total, 0.0)
        if q:
            s2, R = linalg.eigh(Mw.T @ Mw)            # W^T W = Mw^T Mw (V orthonormal)
            order = np.argsort(s2)[::-1]
            s2, R = np.clip(s2[order], 0, None), R[:, order]
            # switched off by ARD: the posterior mean of the column is smaller than its posterior
            # spread (d x its variance), i.e. the prior, not the data, determines it
            spread = d * np.einsum("ik,ij,jk->k", R, self._Sw, R)
            floor = max(self.prune_tol * self.total_variance_, np.finfo(float).tiny)
            active = ((s2 > spread) & (s2 > floor)) if self.prune else s2 > np.finfo(float).tiny
            s2, R = s2[active], R[:, active]
            dirs_coords = (Mw @ R) / np.sqrt(s2)      # (r, k) orthonormal
            comps = fix_signs(to_features(dirs_coords)).T
            alpha_rot = np.einsum("ik,i,ik->k", R, self._alpha, R)
        else:
            s2, comps, alpha_rot = np.zeros(0), np.zeros((0, d)), np.zeros(0)
        self.n_active_ = len(s2)
        ratio = s2 / self.total_variance_ if self.total_variance_ > 0 else np.zeros_like(s2)
        k = len(s2)
        if self.variance is not None and k:
            reach = np.cumsum(ratio) >= self.variance - 1e-12
            if reach.any():
                k = int(np.argmax(reach)) + 1
            else:
                warnings.warn(f"VBPCA: the {k} active components explain {ratio.sum():.3f} of the variance, "
                              f"less than variance={self.variance}; keeping all of them", stacklevel=2)
        self.components_ = comps[:k].astype(out_dtype)
        self.explained_variance_ = s2[:k]
        self.explained_variance_ratio_ = ratio[:k]
        self.alpha_ = alpha_rot[:k]
        self.n_components_ = k
        self.noise_variance_ = 1.0 / self._tau
        del self._Mw, self._mmu, self._Sw
        return self

    def _fit_coords(self, C, sq_norms, d, q):
        """Coordinate-ascent VB in span coordinates. Sets _Mw (r, q), _mmu (r,), _tau, _alpha."""
        n, r = C.shape
        beta = float(self.mean_precision)
        a_a, b_a, a_t, b_t = self.ard_a, self.ard_b, self.noise_a, self.noise_b
        # PCA initialisation
        mmu = C.mean(axis=0) if r else np.zeros(0)
        Cc = C - mmu
        total = float((Cc ** 2).sum() / n) if r else 0.0
        if q:
            _, sv, vt = linalg.svd(Cc, full_matrices=False)
            lam = sv ** 2 / n
            sigma2 = max((total - lam[:q].sum()) / max(d - q, 1), 1e-6 * max(total, 1e-12) / d)
            Mw = vt[:q].T * np.sqrt(np.clip(lam[:q] - sigma2, 1e-12, None))
        else:
            sigma2 = max(total / d, 1e-12)
            Mw = np.zeros((r, 0))
        tau = 1.0 / sigma2
        Sw = np.zeros((q, q))
        alpha = d / np.maximum((Mw ** 2).sum(axis=0), 1e-12)
        Smu = 0.0
        a_t_post = a_t + n * d / 2.0
        a_a_post = a_a + d / 2.0
        sum_sq = float(sq_norms.sum())
        Csum = C.sum(axis=0)
        elbo, prev = [], None
        self.n_iter_ = 0
        for it in range(1, self.max_iter + 1):
            # q(X)
            WtW = Mw.T @ Mw + d * Sw
            Sx = linalg.inv(np.eye(q) + tau * WtW) if q else np.zeros((0, 0))
            Sx = (Sx + Sx.T) / 2
            Mx = tau * ((C - mmu) @ Mw) @ Sx                     # (n, q)
            Sxx = n * Sx + Mx.T @ Mx
            # q(mu)
            Smu = 1.0 / (beta + n * tau)
            mmu = tau * Smu * (Csum - Mw @ Mx.sum(axis=0))
            # q(W)
            if q:
                Sw = linalg.inv(np.diag(alpha) + tau * Sxx)
                Sw = (Sw + Sw.T) / 2
                Mw = tau * ((C - mmu).T @ Mx) @ Sw              # (r, q)
            # q(alpha)
            w_sq = (Mw ** 2).sum(axis=0) + d * np.diag(Sw)
            b_a_post = b_a + w_sq / 2.0
            alpha = a_a_post / b_a_post
            # q(tau)
            WtW = Mw.T @ Mw + d * Sw
            mu_sq = mmu @ mmu + d * Smu
            resid = (sum_sq + n * mu_sq + np.sum(WtW * Sxx)
                     + 2 * mmu @ (Mw @ Mx.sum(axis=0)) - 2 * np.sum((C @ Mw) * Mx) - 2 * Csum @ mmu)
            b_t_post = b_t + max(resid, 0.0) / 2.0
            tau = a_t_post / b_t_post
            # lower bound
            e_ln_tau = digamma(a_t_post) - np.log(b_t_post)
            e_ln_alpha = digamma(a_a_post) - np.log(b_a_post)
            L = (n * d / 2.0) * (e_ln_tau - _LOG2PI) - tau * max(resid, 0.0) / 2.0
            if q:
                L += -0.5 * (np.sum(Mx ** 2) + n * np.trace(Sx)) + 0.5 * n * (q + np.linalg.slogdet(Sx)[1])
                L += np.sum(d / 2.0 * (e_ln_alpha - _LOG2PI) - alpha * w_sq / 2.0)
                L += 0.5 * d * (q * (1 + _LOG2PI) + np.linalg.slogdet(Sw)[1])
                L += np.sum(a_a * np.log(b_a) - gammaln(a_a) + (a_a - 1) * e_ln_alpha - b_a * alpha)
                L += np.sum(gammaln(a_a_post) - (a_a_post - 1) * digamma(a_a_post) - np.log(b_a_post) + a_a_post)
            L += d / 2.0 * (np.log(beta) - _LOG2PI) - beta * mu_sq / 2.0
            L += d / 2.0 * (1 + _LOG2PI + np.log(Smu))
            L += a_t * np.log(b_t) - gammaln(a_t) + (a_t - 1) * e_ln_tau - b_t * tau
            L += gammaln(a_t_post) - (a_t_post - 1) * digamma(a_t_post) - np.log(b_t_post) + a_t_post
            elbo.append(float(L))
            self.n_iter_ = it
            if prev is not None and abs(L - prev) <= self.tol * abs(L):
                break
            prev = L
        else:
            warnings.warn(f"VBPCA stopped at max_iter={self.max_iter} before the lower bound "
                          f"converged (tol={self.tol})", ConvergenceWarning, stacklevel=3)
        self.elbo_ = np.array(elbo)
        self._Mw, self._mmu, self._tau, self._alpha, self._Sw = Mw, mmu, float(tau), alpha, Sw

    # --------------------------------------------------------------- inference
    def _scaled(self):
        s = np.sqrt(self.explained_variance_)
        return s, s / (self.explained_variance_ + self.noise_variance_)

    def transform(self, X):
        """Posterior mean of the latent coordinates (n, k) of X (n, d), unit prior variance."""
        X = self._check_X(X, fitted=True)
        _, gain = self._scaled()
        return ((X - self.mean_) @ self.components_.T) * gain

    def inverse_transform(self, Z):
        """Latent coordinates (n, k) -> feature space (n, d): W z + mean."""
        s, _ = self._scaled()
        return (np.asarray(Z) * s) @ self.components_ + self.mean_

    def score_samples(self, X):
        """Log-likelihood of each sample under N(mean, W W^T + sigma^2 I), without forming it."""
        X = self._check_X(X, fitted=True)
        d = X.shape[1]
        s2, sig2 = self.explained_variance_, self.noise_variance_
        R = X - self.mean_
        proj = R @ self.components_.T
        quad = (np.einsum("ij,ij->i", R, R) - (proj ** 2 * (s2 / (s2 + sig2))).sum(axis=1)) / sig2
        logdet = np.log(s2 + sig2).sum() + (d - len(s2)) * np.log(sig2)
        return -0.5 * (d * _LOG2PI + logdet + quad)

    def score(self, X, y=None):
        """Mean log-likelihood of the samples of X."""
        return float(np.mean(self.score_samples(X)))
