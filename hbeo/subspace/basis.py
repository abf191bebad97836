"""The shared object subspace of BEO/HBEO: per-class VBPCA, one orthonormal basis.

Each class c gets a VBPCA model on its flattened training grids (d = 27,000); the
shared basis spans ``[W_1 ... W_m, mu_1 ... mu_m]`` (the kept principal directions
and the means of all classes) and is orthonormalized by an SVD that keeps singular
values above ``rank_tol`` x the largest (rank-revealing). Each basis column (and each
class's VBPCA direction) has its entry of largest magnitude positive (:func:`~hbeo.subspace.vbpca.fix_signs`),
so the same grids give the same basis on any LAPACK build. Objects are coordinates
in that basis::

    project       o' = W^T o                       (complete grids)
    reconstruct   o_hat = W o'  (>= 0.5 -> filled when rebinarized)
    partial_project  o' from known-filled / known-empty voxels only:
                  least squares  A o' = b,  A = W^T V^T V W,  b = W^T V^T w
                  or an L1 version  argmin 1/2 ||A o' - b||^2 + lam ||o'||_1  (the paper's Eq. 10
                  has the unsquared norm ||A o' - b||_2; the squared one is the standard lasso, solved
                  by FISTA, with the same minimizers along lam's path but lam on another scale)

V (the selection of known voxels) is never formed: A is built from the known rows
of W, or as I - (unknown rows)^T (unknown rows) when fewer voxels are unknown.
"""
from __future__ import annotations

import hashlib
import os
import warnings

import numpy as np
from scipy import linalg
from scipy.linalg import blas
from sklearn.exceptions import ConvergenceWarning

from hbeo.progress import tqdm

from hbeo import conventions as C
from hbeo.errors import DataError
from hbeo.storage import read_npz, write_npz
from hbeo.subspace.vbpca import VBPCA, fix_signs

FORMAT_VERSION = 1


def _flat(grids) -> np.ndarray:
    g = np.asarray(grids)
    if g.ndim == 4:
        return g.reshape(len(g), -1)
    if g.ndim == 2:
        return g
    raise ValueError(f"expected grids (N, R, R, R) or flat (N, d), got shape {g.shape}")


def data_fingerprint(grids, labels) -> str:
    """Short hash of training grids and labels (saved with the subspace)."""
    h = hashlib.sha256(np.packbits(_flat(grids) > 0.5).tobytes())
    h.update(np.asarray(labels, np.int64).tobytes())
    return h.hexdigest()[:16]


class ObjectSubspace:
    """Shared BEO subspace over all classes.

    Parameters
    ----------
    variance : fraction of each class's variance its components must reach (paper: 0.6).
    n_components : int or {class: int}; a fixed component count per class instead of
        ``variance`` (kept even where ARD would switch a direction off; at most n_c - 1).
    shared_dim : if set, ignore ``variance`` and choose one common variance fraction,
        the smallest for which the shared basis reaches this many dimensions (e.g. 344,
        the paper's); the fraction found is ``variance_used_``.
    max_components : cap on each class's VBPCA latent dimension.
    rank_tol : singular values below ``rank_tol`` x the largest are dropped.
    vbpca : extra keyword arguments for :class:`hbeo.subspace.vbpca.VBPCA`.

    Fitted attributes: ``basis_`` (d, k) float32 orthonormal; ``dim_`` = k; ``classes_``;
    ``class_means_`` (m, d); ``class_components_`` {class: (k_c, d)};
    ``class_variance_ratio_`` {class: (k_c,)}; ``class_spectrum_`` {class: variance ratios of
    all active VBPCA directions (up to max_components)}; ``n_components_`` {class: k_c};
    ``class_total_variance_`` {class: mean squared distance of its grids to its mean};
    ``variance_used_``; ``singular_values_``; ``fingerprint_``.
    """

    def __init__(self, variance: float | None = 0.6, n_components=None, shared_dim: int | None = None,
                 max_components: int = 150, rank_tol: float = 1e-6, vbpca: dict | None = None):
        self.variance = variance
        self.n_components = n_components
        self.shared_dim = shared_dim
        self.max_components = max_components
        self.rank_tol = rank_tol
        self.vbpca = vbpca or {}

    def get_params(self) -> dict:
        return {"variance": self.variance, "n_components": self.n_components, "shared_dim": self.shared_dim,
                "max_components": self.max_components, "rank_tol": self.rank_tol, "vbpca": self.vbpca}

    # ------------------------------------------------------------------ fit
    def fit(self, grids, labels, classes=None, progress: bool = True) -> "ObjectSubspace":
        """Fit on training grids (N, 30, 30, 30) bool and labels (N,) int into ``classes``."""
        X = _flat(grids)
        labels = np.asarray(labels)
        if len(labels) != len(X):
            raise ValueError(f"{len(X)} grids but {len(labels)} labels")
        classes = tuple(classes) if classes is not None else tuple(C.CLASSES[:int(labels.max()) + 1])
        empty = ~(X > 0).any(axis=1)
        if empty.any():
            raise ValueError(f"{int(empty.sum())} empty grids among the training data (first at index "
                             f"{int(np.argmax(empty))}); drop them before fitting")
        fixed = self.n_components
        models, means, unconverged = {}, [], []
        for ci, name in enumerate(tqdm(classes, desc="VBPCA per class", disable=not progress)):
            Xc = X[labels == ci]
            if len(Xc) == 0:
                raise ValueError(f"class {name!r} has no training grids")
            cap = self.max_components
            if fixed is not None:
                cap = fixed[name] if isinstance(fixed, dict) else int(fixed)
            kw = dict(self.vbpca, prune=False) if fixed is not None else self.vbpca
            with warnings.catch_warnings():                 # said once for every class below
                warnings.simplefilter("ignore", ConvergenceWarning)
                models[name] = VBPCA(n_components=cap, variance=None, **kw).fit(Xc)
            m = models[name]
            change = abs(m.elbo_[-1] - m.elbo_[-2]) / abs(m.elbo_[-1]) if len(m.elbo_) > 1 else 0.0
            if m.n_iter_ >= m.max_iter and change > m.tol:
                unconverged.append(f"{name} ({change:.0e})")
            means.append(models[name].mean_.astype(np.float32))
        if unconverged:
            m = next(iter(models.values()))
            warnings.warn(f"VBPCA stopped at its cap of {m.max_iter} iterations before the lower bound converged "
                          f"(relative change <= {m.tol:g}) for {len(unconverged)} of {len(classes)} classes: "
                          f"{', '.join(unconverged)} (the last relative change); their spectra are approximate "
                          f"(raise the vbpca setting max_iter for exact ones)", ConvergenceWarning, stacklevel=2)
        spectra = {c: m.explained_variance_ratio_ for c, m in models.items()}
        if fixed is not None:
            f = None
        elif self.shared_dim is not None:
            f = self._fraction_for_dim(spectra, int(self.shared_dim))
        else:
            f = self.variance
        counts = {c: self._count_ratio(r, f) for c, r in spectra.items()}
        self.classes_ = classes
        self.variance_used_ = f
        self.n_components_ = counts
        self.class_components_ = {c: models[c].components_[:counts[c]].astype(np.float32) for c in classes}
        self.class_variance_ratio_ = {c: models[c].explained_variance_ratio_[:counts[c]] for c in classes}
        self.class_spectrum_ = spectra
        self.class_noise_variance_ = {c: float(models[c].noise_variance_) for c in classes}
        self.class_total_variance_ = {c: float(models[c].total_variance_) for c in classes}
        self.class_means_ = np.stack(means)
        self._orthonormalize()
        self.fingerprint_ = data_fingerprint(X, labels)
        return self

    def _count_ratio(self, ratio: np.ndarray, f: float | None) -> int:
        """Fewest leading directions whose variance ratios reach ``f`` (all of them if f is None)."""
        if f is None or len(ratio) == 0:
            return len(ratio)
        reach = np.cumsum(ratio) >= f - 1e-12
        if not reach.any():
            cause = ("raise max_components" if len(ratio) >= self.max_components else
                     "its components are limited by its training objects, not max_components")
            warnings.warn(f"a class reaches only {ratio.sum():.3f} of its variance with {len(ratio)} "
                          f"components (< {f}); {cause}", stacklevel=3)
            return len(ratio)
        return int(np.argmax(reach)) + 1

    def _fraction_for_dim(self, spectra, target: int) -> float:
        """Smallest common variance fraction whose counts sum (plus one mean per class) to >= target."""
        def dim(f):
            return sum(self._count_ratio(r, f) for r in spectra.values()) + len(spectra)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if dim(1.0) < target:
                capped = [c for c, r in spectra.items() if len(r) >= self.max_components]
                how = (f"raise max_components ({self.max_components}; reached by {', '.join(capped)})" if capped
                       else f"each class keeps at most one component fewer than its training objects (fewest: "
                            f"{min(len(r) for r in spectra.values())}), below max_components "
                            f"({self.max_components}): more training objects per class")
                raise ValueError(f"shared_dim={target} is out of reach: all components of all classes give "
                                 f"{dim(1.0)}; {how}")
            lo, hi = 0.0, 1.0
            for _ in range(60):
                mid = (lo + hi) / 2
                lo, hi = (mid, hi) if dim(mid) < target else (lo, mid)
        return hi

    def _orthonormalize(self):
        M = np.concatenate([self.class_components_[c] for c in self.classes_] + [self.class_means_]).astype(np.float64)
        G = M @ M.T                                           # (K, K), K = sum k_c + m
        s2, R = linalg.eigh(G)
        order = np.argsort(s2)[::-1]
        s2, R = np.clip(s2[order], 0, None), R[:, order]
        s = np.sqrt(s2)
        keep = s > self.rank_tol * s[0]
        self.singular_values_ = s
        basis = fix_signs(((R[:, keep] / s[keep]).T @ M).T)          # (d, k), signs as on any machine
        self.basis_ = np.ascontiguousarray(basis.astype(np.float32))
        self.dim_ = int(keep.sum())

    # ------------------------------------------------------------ inference
    def _check(self):
        if not hasattr(self, "basis_"):
            raise RuntimeError("ObjectSubspace is not fitted; call fit() or ObjectSubspace.load()")

    def project(self, grids) -> np.ndarray:
        """Complete grids (N, 30, 30, 30) or (N, d) -> coefficients (N, k): o' = W^T o."""
        self._check()
        return _flat(grids).astype(np.float32) @ self.basis_

    def _support(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows of the basis that are not all zero, those rows (s, k) contiguous), cached: voxels no
        training grid ever fills (most of the margin) have zero rows, and skipping them halves the
        memory traffic of :meth:`reconstruct`."""
        cache = getattr(self, "_support_cache", None)
        if cache is None or cache[2] is not self.basis_:
            rows = np.flatnonzero(np.any(self.basis_ != 0, axis=1))
            cache = (rows, np.ascontiguousarray(self.basis_[rows]), self.basis_)
            self._support_cache = cache
        return cache[0], cache[1]

    def reconstruct(self, coeffs, threshold: float | None = None) -> np.ndarray:
        """Coefficients (N, k) -> grids (N, 30, 30, 30): float W o', or bool (>= threshold) if given."""
        self._check()
        coeffs = np.atleast_2d(np.asarray(coeffs, np.float32))
        d = self.basis_.shape[0]
        r = round(d ** (1 / 3))
        rows, sub = self._support()
        out = np.zeros((len(coeffs), d), np.float32)
        out[:, rows] = coeffs @ sub.T                 # the other rows of W are exactly zero
        out = out.reshape(len(coeffs), r, r, r)
        return out >= threshold if threshold is not None else out

    def _normal_matrix(self, known: np.ndarray) -> np.ndarray:
        """A = W^T V^T V W for one flat known-mask; upper triangle valid (float32)."""
        W = self.basis_
        n_known = int(known.sum())
        if n_known <= W.shape[0] - n_known:
            return blas.ssyrk(1.0, W[known].T)            # (W_K^T)(W_K^T)^T, no copy
        eye = np.eye(W.shape[1], dtype=np.float32)
        return blas.ssyrk(-1.0, W[~known].T, beta=1.0, c=eye)

    def partial_project(self, observed, known, method: str = "lstsq", ridge: float = 1e-3,
                        lam: float = 0.01, max_iter: int = 500, tol: float = 1e-6) -> np.ndarray:
        """Coefficients (N, k) from partially observed grids.

        Parameters
        ----------
        observed : (N, 30, 30, 30) values at the known voxels (True = filled; ignored where unknown).
        known : same shape, True where the voxel is known (filled or empty), False = unobserved.
        method : ``"lstsq"`` solves (A + ridge I) o' = b (ridge, relative to A's scale of at most 1,
            keeps directions the mask does not observe at 0 instead of arbitrary values; ridge=0
            gives the minimum-norm least-squares solution); ``"lasso"`` minimizes
            1/2 ||A o' - b||^2 + lam ||o'||_1 by FISTA (step 1, since A <= I): the paper's Eq. 10 with the
            residual's norm squared (the paper's is unsquared), so lam is on another scale than the paper's.
        """
        self._check()
        obs = _flat(observed) > 0.5
        kn = _flat(known).astype(bool)
        if obs.shape != kn.shape or obs.shape[1] != self.basis_.shape[0]:
            raise ValueError(f"observed {obs.shape} and known {kn.shape} must both be (N, {self.basis_.shape[0]})")
        if method not in ("lstsq", "lasso"):
            raise ValueError(f"method must be 'lstsq' or 'lasso', got {method!r}")
        k = self.basis_.shape[1]
        b = ((obs & kn).astype(np.float32) @ self.basis_).astype(np.float64)   # W^T V^T w, all queries
        if method == "lasso":
            A = np.empty((len(obs), k, k))
            for i in range(len(obs)):
                a = self._normal_matrix(kn[i])
                A[i] = np.triu(a) + np.triu(a, 1).T
            return _fista_lasso(A, b, lam, max_iter, tol).astype(np.float32)
        out = np.empty((len(obs), k), np.float32)
        for i in range(len(obs)):
            a = self._normal_matrix(kn[i]).astype(np.float64)               # upper triangle valid
            if ridge > 0:
                a[np.diag_indices(k)] += ridge
                out[i] = linalg.cho_solve(linalg.cho_factor(a, lower=False, check_finite=False), b[i],
                                          check_finite=False)
            else:
                a = np.triu(a) + np.triu(a, 1).T
                out[i] = linalg.lstsq(a, b[i], check_finite=False)[0]
        return out

    # ------------------------------------------------------------ persistence
    def save(self, path):
        """Write basis, class means and components, settings and data fingerprint (.npz), atomically;
        ``path`` may also be an open binary file."""
        self._check()
        meta = {"format_version": FORMAT_VERSION, "params": self.get_params(), "classes": list(self.classes_),
                "n_components": self.n_components_, "variance_used": self.variance_used_,
                "dim": self.dim_, "fingerprint": self.fingerprint_,
                "class_noise_variance": self.class_noise_variance_,
                "class_total_variance": self.class_total_variance_}
        comps = np.concatenate([self.class_components_[c] for c in self.classes_])
        ratios = np.concatenate([self.class_variance_ratio_[c] for c in self.classes_])
        spectra = np.concatenate([self.class_spectrum_[c] for c in self.classes_])
        meta["spectrum_sizes"] = [len(self.class_spectrum_[c]) for c in self.classes_]
        return write_npz(path, meta, basis=self.basis_, means=self.class_means_, components=comps, ratios=ratios,
                         spectra=spectra, singular_values=self.singular_values_)

    @classmethod
    def load(cls, path) -> "ObjectSubspace":
        """Read a file (path or open binary file) written by :meth:`save` (DataError naming the
        file if it is not one)."""
        meta, arrays = read_npz(path, ("basis", "means", "components", "ratios", "spectra", "singular_values"),
                                "subspace", FORMAT_VERSION)
        try:
            return cls._from_stored(meta, arrays)
        except (LookupError, TypeError, ValueError, AttributeError) as err:   # meta of another writer
            name = getattr(path, "name", None) if hasattr(path, "read") else path
            raise DataError(name if isinstance(name, (str, os.PathLike)) else None,
                            f"not a valid subspace file ({type(err).__name__}: {err})") from None

    @classmethod
    def _from_stored(cls, meta: dict, arrays: dict) -> "ObjectSubspace":
        self = cls(**meta["params"])
        self.classes_ = tuple(meta["classes"])
        self.n_components_ = meta["n_components"]
        self.variance_used_ = meta["variance_used"]
        self.fingerprint_ = meta["fingerprint"]
        self.class_noise_variance_ = meta["class_noise_variance"]
        self.class_total_variance_ = meta["class_total_variance"]
        self.basis_, self.class_means_ = arrays["basis"], arrays["means"]
        self.singular_values_ = arrays["singular_values"]
        self.dim_ = self.basis_.shape[1]
        splits = np.cumsum([self.n_components_[c] for c in self.classes_])[:-1]
        self.class_components_ = dict(zip(self.classes_, np.split(arrays["components"], splits)))
        self.class_variance_ratio_ = dict(zip(self.classes_, np.split(arrays["ratios"], splits)))
        self.class_spectrum_ = dict(zip(self.classes_, np.split(arrays["spectra"],
                                                                np.cumsum(meta["spectrum_sizes"])[:-1])))
        return self

    def eigen_object(self, cls: str, mode: int | None = None, sigmas: float = 0.0) -> np.ndarray:
        """Float grid (30, 30, 30): the class mean, moved ``sigmas`` standard deviations along
        component ``mode`` (0-based) when given."""
        self._check()
        i = self.classes_.index(cls)
        field = self.class_means_[i].astype(np.float64)
        if mode is not None:
            std = np.sqrt(self.class_variance_ratio_[cls][mode] * self.class_total_variance_[cls])
            field = field + sigmas * std * self.class_components_[cls][mode]
        r = round(field.size ** (1 / 3))
        return field.reshape(r, r, r)

    def fraction_for_dim(self, target: int) -> float:
        """Smallest common variance fraction that would give a shared dimension >= ``target``
        (counted as components plus one mean per class, from the stored spectra)."""
        self._check()
        return self._fraction_for_dim(self.class_spectrum_, int(target))

    def counts_at(self, fraction: float) -> dict[str, int]:
        """Components each class would keep at another variance fraction (from the stored spectra)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return {c: self._count_ratio(r, fraction) for c, r in self.class_spectrum_.items()}


def _fista_lasso(A: np.ndarray, b: np.ndarray, lam: float, max_iter: int, tol: float) -> np.ndarray:
    """Batched FISTA for min_x 1/2 ||A x - b||^2 + lam ||x||_1 with A (N, k, k), 0 <= A <= I."""
    AtA = A @ A                     # A symmetric
    Atb = np.einsum("nij,nj->ni", A, b)
    x = np.zeros_like(b)
    z, t = x.copy(), 1.0
    for _ in range(max_iter):
        grad = np.einsum("nij,nj->ni", AtA, z) - Atb
        x_new = np.sign(z - grad) * np.maximum(np.abs(z - grad) - lam, 0.0)   # step 1/L, L <= 1
        t_new = (1 + np.sqrt(1 + 4 * t * t)) / 2
        z = x_new + ((t - 1) / t_new) * (x_new - x)
        done = np.max(np.abs(x_new - x)) <= tol * max(1.0, np.max(np.abs(x_new)))
        x, t = x_new, t_new
        if done:
            break
    return x
