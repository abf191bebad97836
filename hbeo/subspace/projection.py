"""Partial projection for many known-masks at once, with a Gaussian prior: :class:`MaskedProjector`.

Given flat voxel masks of one or more partial views (``filled``: known-filled, ``known``: known
filled or empty; (m, d) bool, d = 30^3, :mod:`hbeo.subspace.partial`) and the shared basis
W (d, k) of an :class:`~hbeo.subspace.basis.ObjectSubspace`, the coefficients o' (k,) of each
view minimize

    ||V W o' - w||^2 + (o' - mu)^T P (o' - mu)

(V selects the known voxels, w their 0/1 values; P a diagonal precision, a scalar ridge or a
vector (k,); mu a prior mean, 0 when not given): ``(A + P) o' = b + P mu`` with ``A = W_K^T W_K``
and ``b = W^T V^T w``. ``P = ridge`` and ``mu = 0`` is BEO's partial projection; a precision
around a network's coefficients is the MAP estimate of HBEO's verify step
(:mod:`hbeo.model.verify`). Also returned: the squared residual on the known voxels,
``||V W o' - w||^2 = ||w||^2 - b^T o' + o'^T P (mu - o')``, the data term of a Gaussian voxel
likelihood.

A is one float32 GEMM over the gathered rows of W for the smaller of the known and unknown voxel
sets (``A = I - W_U^T W_U`` when fewer are unknown; W has orthonormal columns), restricted to the
voxels where the basis is not identically zero, then a Cholesky solve in float64.
"""
from __future__ import annotations

import numpy as np
from scipy import linalg
from scipy.linalg import lapack


class MaskedProjector:
    """Partial projections onto the basis ``W`` (d, k), float32, orthonormal columns."""

    def __init__(self, W: np.ndarray):
        W = np.asarray(W)
        if W.ndim != 2:
            raise ValueError(f"basis must be (d, k), got shape {W.shape}")
        self.d, self.k = W.shape
        self.active = np.nonzero(np.abs(W).max(axis=1) > 0)[0]               # rows that can matter
        self.Wa = np.ascontiguousarray(W[self.active], dtype=np.float32)       # (d_a, k)
        self.WaT = np.ascontiguousarray(self.Wa.T)                              # (k, d_a)

    def normal_equations(self, filled, known) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flat masks (m, d) bool -> ``A`` (m, k, k) = W_K^T W_K (float64, symmetric), ``b`` (m, k) =
        W^T V^T w and ``||w||^2`` (m,): the squared residual of coefficients o is
        ``||w||^2 - 2 b^T o + o^T A o``."""
        filled, known = np.asarray(filled, bool), np.asarray(known, bool)
        if filled.ndim != 2 or filled.shape != known.shape or filled.shape[1] != self.d:
            raise ValueError(f"filled {filled.shape} and known {known.shape} must both be (m, {self.d})")
        m, k, da = len(filled), self.k, len(self.active)
        kn = known[:, self.active]
        b = (filled[:, self.active].astype(np.float32) @ self.Wa).astype(np.float64)   # W^T V^T w
        n_known = kn.sum(axis=1)
        A = np.empty((m, k, k))
        diag = np.diag_indices(k)
        for i in range(m):
            if n_known[i] <= da - n_known[i]:
                X = self.WaT[:, kn[i]]
                A[i] = (X @ X.T).astype(np.float64)
            else:
                X = self.WaT[:, ~kn[i]]
                A[i] = -(X @ X.T).astype(np.float64)
                A[i][diag] += 1.0
        return A, b, filled.sum(axis=1).astype(np.float64)

    def project(self, filled, known, precision=1e-3, prior_mean=None) -> tuple[np.ndarray, np.ndarray]:
        """Flat masks (m, d) bool -> coefficients (m, k) float64 and squared residuals (m,).

        ``precision``: a scalar (ridge) or (k,) diagonal, the same for every mask, or (m, k);
        ``prior_mean``: None (0), (k,) or (m, k)."""
        A, b, n_filled = self.normal_equations(filled, known)
        m, k = b.shape
        scalar = np.ndim(precision) == 0
        P = float(precision) if scalar else np.broadcast_to(np.asarray(precision, np.float64), (m, k))
        rhs = b
        if prior_mean is not None:
            mu = np.broadcast_to(np.asarray(prior_mean, np.float64), (m, k))
            rhs = b + P * mu
        coeffs = np.empty((m, k))
        sse = np.empty(m)
        diag = np.diag_indices(k)
        for i in range(m):
            a = A[i].copy()
            a[diag] += P if scalar else P[i]
            cf, info = lapack.dpotrf(a, lower=0, clean=0, overwrite_a=1)
            if info == 0:
                o, info = lapack.dpotrs(cf, rhs[i], lower=0)
            if info != 0:                                         # zero precision and a singular A
                o = linalg.lstsq(A[i], rhs[i], check_finite=False)[0]
            coeffs[i] = o
            if prior_mean is None and scalar:
                sse[i] = max(0.0, n_filled[i] - b[i] @ o - P * (o @ o))
            else:
                pm = 0.0 if prior_mean is None else mu[i]
                sse[i] = max(0.0, n_filled[i] - b[i] @ o + o @ ((P if scalar else P[i]) * (pm - o)))
        return coeffs, sse
