"""The BEO baseline (Burchfiel & Konidaris, RSS 2017) behind one interface: :class:`BEO`.

BEO works in the shared object subspace (:class:`hbeo.subspace.basis.ObjectSubspace`):

1. **Voxelize the view** under each rotation candidate r: the segmented depth image becomes a
   partial 30^3 grid of known-filled, known-empty and unknown voxels
   (:func:`hbeo.subspace.partial.iter_partial`). As in the paper, BEO is handed the object's translation
   ``t_true`` and size ``object_size`` ("BEOs assume that a partially observed object with unknown
   pose can be properly (and consistently) voxelized"); only the rotation is searched.
2. **Partial projection** for every candidate: ``(A + ridge I) o' = b``, ``A = W^T V^T V W``,
   ``b = W^T V^T w`` (as :meth:`ObjectSubspace.partial_project`). A is one float32 GEMM over the
   gathered rows of W for the smaller of the known and unknown voxel sets (``A = I - W_U^T W_U``
   when fewer are unknown), restricted to the voxels where the basis is not identically zero
   (voxels no training object ever occupied: about half the grid on ModelNet10), then a Cholesky
   solve. No loop over voxels; one small loop over candidates (BLAS on one thread).
3. **Score** every (rotation, class) pair and take the argmax (the paper's {r_hat, c_hat});
   P(r) is uniform over the candidates, P(c) the training class frequencies.

Scores (``score=``)
    ``"paper"``  log P(r) + log D(o'^r | c) + log P(c), D a per-class Gaussian mixture over the
                 training objects' coefficients (scikit-learn ``GaussianMixture``, full
                 covariances; ``reg_covar`` x the mean per-dimension coefficient variance is added
                 to every diagonal, since k can exceed the number of training objects per class).
    ``"joint"``  (default) the paper's score plus the log-likelihood of the *observed* voxels under
                 the reconstruction W o' with Gaussian voxel noise, - ||V W o' - w||^2 / (2 s^2),
                 where surface points that fall outside the grid under a candidate count as
                 unexplained filled voxels. s^2 = ``noise_var``, default: the mean squared residual
                 of the training objects' own projections on their surface voxels (:meth:`BEO.fit`).
                 The density alone cannot tell a rotation that explains the view from one whose
                 partial projection merely lands on a typical class member: on ModelNet10
                 (benchmarks/README.md) the paper's score finds the 1-DOF yaw (class given)
                 within 15 degrees for 53 % of the views against 89 % with the joint score,
                 classifies 68 % against 79 % (yaw searched too), and at 3-DOF (2,048 candidates, class given)
                 finds 9 % against 56 % of the views within 15 degrees.

Outputs of :meth:`BEO.predict_view`: ``probabilities`` (C,) over classes, each class at its best
rotation (max over r of P(r, c | view), normalized over c, so its argmax is the paper's c_hat);
``label`` (that class's index); ``rotation`` (3, 3) object -> camera of the best pair; ``coeffs``
(k,) and ``grid`` (30^3 bool, W o' >= 0.5) of that candidate; ``n_candidates``; ``score``.

Pose modes
    ``"known"`` one candidate, the true rotation. ``"1dof"`` the true up axis is known, the yaw
    about the object's +z is not: ``R_true @ Rz(2 pi k / n + phi)``, k < n = ``pose_bins_1dof``,
    phi uniform in [0, 2 pi / n) from ``rng`` (so the truth is not on the grid). ``"3dof"``:
    the ``so3_grid`` rotations of a super-Fibonacci spiral (:func:`so3_grid`; deterministic,
    near-uniform), left-multiplied by one uniformly random rotation from ``rng``.
"""
from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
from scipy.special import logsumexp
from threadpoolctl import threadpool_limits

from hbeo import conventions as C
from hbeo.errors import DataError
from hbeo.baselines.methods import METHODS
from hbeo.rotations import matrix_to_quaternion, super_fibonacci, uniform_so3, z_angle_to_matrix
from hbeo.storage import read_npz, write_npz
from hbeo.subspace.partial import iter_partial
from hbeo.subspace.projection import MaskedProjector
from hbeo.subspace.basis import ObjectSubspace

FORMAT_VERSION = 1
POSES = ("known", "1dof", "3dof")
SCORES = ("paper", "joint")

#: default size of the 3-DOF candidate grid: the finest that fits the 60 s target per query on a
#: shared 2-core machine with a 83-dimensional subspace (benchmarks/README.md); nearest-neighbour
#: spacing 9.6 deg mean / 11.6 max, a random rotation lies 6.0 deg (mean) / 10.5 (max) from it
DEFAULT_SO3_GRID = 8192


def so3_grid(n: int) -> np.ndarray:
    """n near-uniform rotations (n, 3, 3): the super-Fibonacci spiral of Alexa (CVPR 2022),
    deterministic, any n. Sample i in [0, n): s = i + 1/2, r = sqrt(s/n), R = sqrt(1 - s/n),
    quaternion (r sin(2 pi s / sqrt 2), r cos(..), R sin(2 pi s / psi), R cos(..)), psi^4 = psi + 4.
    Measured geodesic spacing (:func:`grid_spacing`; nearest neighbour mean / max, and distance of a
    random rotation to the grid mean / max, degrees): n = 512: 26.1 / 29.7, 15.0 / 27.4;
    n = 2048: 14.9 / 18.4, 9.5 / 16.3; n = 4096: 11.1 / 14.6, 7.7 / 13.2; n = 8192: 9.6 / 11.6,
    6.0 / 10.5."""
    return super_fibonacci(n)


def grid_spacing(Rs: np.ndarray, n_probe: int = 20000, seed: int = 0) -> dict:
    """Geodesic spacing of a rotation set (degrees): ``nn_mean`` / ``nn_max`` (nearest-neighbour
    distance within the set) and ``cover_mean`` / ``cover_max`` (distance from ``n_probe`` uniformly
    random rotations to the nearest member: the error of an exact search on this grid)."""
    q = matrix_to_quaternion(Rs)
    def nearest(p, exclude_self):
        out = np.empty(len(p))
        for i in range(0, len(p), 1024):
            dots = np.abs(p[i:i + 1024] @ q.T)
            if exclude_self:
                dots[np.arange(len(dots)), np.arange(i, i + len(dots))] = -1
            out[i:i + 1024] = 2 * np.degrees(np.arccos(np.clip(dots.max(1), -1, 1)))
        return out
    nn = nearest(q, True)
    cover = nearest(matrix_to_quaternion(uniform_so3(n_probe, np.random.default_rng(seed))), False)
    return {"n": len(q), "nn_mean": float(nn.mean()), "nn_max": float(nn.max()),
            "cover_mean": float(cover.mean()), "cover_max": float(cover.max())}


class BEO:
    """Bayesian Eigenobjects: classification, pose by search and completion from one depth view.

    Parameters
    ----------
    subspace : fitted :class:`~hbeo.subspace.basis.ObjectSubspace`.
    n_mixture : Gaussian components per class density D(o' | c) (at most the class's count).
    reg_covar : added to the diagonal of every covariance, as a fraction of the mean
        per-dimension variance of the training coefficients (scale-free).
    pose_bins_1dof : yaw candidates for ``pose="1dof"``.
    so3_grid : candidate rotations for ``pose="3dof"`` (super-Fibonacci spiral, :func:`so3_grid`).
    score : ``"joint"`` (default) or ``"paper"``; see the module docstring.
    noise_var : voxel noise variance of the ``"joint"`` score (None: estimated in :meth:`fit`).
    given_class : when :meth:`predict_view` gets ``label_true``, search only that class (the
        paper's pose experiment gives BEO the class); probabilities are then one-hot.
    ridge : ridge of the partial projection (as :meth:`ObjectSubspace.partial_project`).
    chunk : candidates voxelized and projected together.

    Notes
    -----
    Fitted attributes: ``classes_``, ``class_prior_`` (C,), ``weights_`` (C, J), ``means_``
    (C, J, k), ``precisions_cholesky_`` (C, J, k, k) (scikit-learn's convention: precision =
    P P^T), ``coef_scale_`` (mean per-dimension coefficient variance), ``noise_var_``,
    ``n_train_`` (per class).
    """

    #: the :class:`hbeo.evaluation.method.Method` contract: registry name and pose settings (default first)
    name = "beo"
    poses = METHODS["beo"]

    def describe(self) -> dict:
        """Settings the metrics dict records beyond name and pose: none for a baseline."""
        return {}

    def __init__(self, subspace: ObjectSubspace, n_mixture: int = 1, reg_covar: float = 0.05,
                 pose_bins_1dof: int = 36, so3_grid: int = DEFAULT_SO3_GRID, score: str = "joint",
                 noise_var: float | None = None, given_class: bool = True, ridge: float = 1e-3,
                 chunk: int = 32):
        if not hasattr(subspace, "basis_"):
            raise ValueError("BEO needs a fitted ObjectSubspace (call fit() or ObjectSubspace.load())")
        if score not in SCORES:
            raise ValueError(f"score must be one of {', '.join(SCORES)}, got {score!r}")
        for name, v in (("n_mixture", n_mixture), ("pose_bins_1dof", pose_bins_1dof), ("so3_grid", so3_grid),
                        ("chunk", chunk)):
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not (np.isfinite(reg_covar) and reg_covar > 0):
            raise ValueError(f"reg_covar must be > 0, got {reg_covar!r}")
        if noise_var is not None and not (np.isfinite(noise_var) and noise_var > 0):
            raise ValueError(f"noise_var must be > 0 or None, got {noise_var!r}")
        self.subspace = subspace
        self.n_mixture, self.reg_covar = int(n_mixture), float(reg_covar)
        self.pose_bins_1dof, self.so3_grid = int(pose_bins_1dof), int(so3_grid)
        self.score, self.noise_var, self.given_class = score, noise_var, bool(given_class)
        self.ridge, self.chunk = float(ridge), int(chunk)
        self._prepare_basis()

    def get_params(self) -> dict:
        return {"n_mixture": self.n_mixture, "reg_covar": self.reg_covar, "pose_bins_1dof": self.pose_bins_1dof,
                "so3_grid": self.so3_grid, "score": self.score, "noise_var": self.noise_var,
                "given_class": self.given_class, "ridge": self.ridge, "chunk": self.chunk}

    def _prepare_basis(self):
        self._projector = MaskedProjector(self.subspace.basis_)

    # ------------------------------------------------------------------ fit
    def fit(self, grids, labels, classes=None, progress: bool = False) -> "BEO":
        """Fit the class densities on training grids (N, 30, 30, 30) bool with labels (N,) indexing
        ``classes`` (default: the subspace's). Class priors are the class frequencies. ``progress``:
        a bar over the classes' mixtures."""
        from sklearn.mixture import GaussianMixture
        from hbeo.progress import tqdm
        g = np.asarray(grids)
        labels = np.asarray(labels)
        if g.ndim != 4 or g.shape[1:] != (C.RESOLUTION,) * 3:
            raise ValueError(f"grids must be (N, 30, 30, 30), got {g.shape}")
        if labels.shape != (len(g),):
            raise ValueError(f"{len(g)} grids but labels of shape {labels.shape}")
        classes = tuple(classes) if classes is not None else tuple(self.subspace.classes_)
        if len(labels) and (labels.min() < 0 or labels.max() >= len(classes)):
            raise ValueError(f"labels must index the {len(classes)} classes")
        X = self.subspace.project(g).astype(np.float64)
        k = X.shape[1]
        counts = np.bincount(labels, minlength=len(classes))
        if (counts == 0).any():
            raise ValueError(f"no training grids for class(es) {[c for c, n in zip(classes, counts) if n == 0]}")
        self.coef_scale_ = float(X.var(axis=0).mean())
        reg = self.reg_covar * self.coef_scale_
        J = self.n_mixture
        weights = np.zeros((len(classes), J))
        means = np.zeros((len(classes), J, k))
        pchol = np.zeros((len(classes), J, k, k))
        for ci in tqdm(range(len(classes)), desc="BEO class densities", disable=not progress):
            Xc = X[labels == ci]
            j = min(J, len(Xc))
            if len(Xc) == 1:      # scikit-learn cannot fit one point: a ball of variance reg around it
                weights[ci, 0], means[ci, 0] = 1.0, Xc[0]
                pchol[ci, 0] = np.eye(k) / np.sqrt(reg)
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                gm = GaussianMixture(j, covariance_type="full", reg_covar=reg, random_state=0, n_init=1,
                                     max_iter=200).fit(Xc)
            weights[ci, :j], means[ci, :j], pchol[ci, :j] = gm.weights_, gm.means_, gm.precisions_cholesky_
            for jj in range(j, J):                                   # unused slots: weight 0
                pchol[ci, jj] = np.eye(k)
        self.classes_ = classes
        self.class_prior_ = counts / counts.sum()
        self.n_train_ = counts
        self.weights_, self.means_, self.precisions_cholesky_ = weights, means, pchol
        self.noise_var_ = float(self.noise_var) if self.noise_var is not None else self._estimate_noise(g)
        return self

    def _estimate_noise(self, grids) -> float:
        """Mean squared residual of the training objects' own projections on their *surface*
        voxels (filled, with an empty 6-neighbour): the voxels a depth image observes as filled,
        and where a linear subspace errs most. (Averaged over whole bounding boxes it is ~3.5x
        smaller on ModelNet10, and that sharper score loses the 3-DOF search to near-symmetric
        poses: see benchmarks/README.md.)"""
        from scipy import ndimage
        W = self.subspace.basis_
        st = ndimage.generate_binary_structure(3, 1)
        errs = []
        for i in range(0, len(grids), 64):
            g = np.asarray(grids[i:i + 64], bool)
            x = g.reshape(len(g), -1).astype(np.float32)
            res = ((x - (x @ W) @ W.T) ** 2).reshape(g.shape)
            for gi, ri in zip(g, res):
                surf = gi & ~ndimage.binary_erosion(gi, st, border_value=0)
                errs.append(float(ri[surf].mean()))
        return float(np.mean(errs))

    def _check(self):
        if not hasattr(self, "means_"):
            raise RuntimeError("BEO is not fitted; call fit() or BEO.load()")

    # ------------------------------------------------------------ scoring
    def log_density(self, coeffs) -> np.ndarray:
        """log D(o' | c) for coefficients (M, k): (M, C)."""
        self._check()
        X = np.atleast_2d(np.asarray(coeffs, np.float64))
        Cn, J, k = self.means_.shape
        out = np.empty((len(X), Cn))
        const = -0.5 * k * np.log(2 * np.pi)
        for c in range(Cn):
            comps = []
            for j in range(J):
                if self.weights_[c, j] <= 0:
                    continue
                P = self.precisions_cholesky_[c, j]
                y = (X - self.means_[c, j]) @ P
                comps.append(np.log(self.weights_[c, j]) + const + np.log(np.diag(P)).sum()
                             - 0.5 * np.einsum("ij,ij->i", y, y))
            out[:, c] = logsumexp(np.stack(comps), axis=0)
        return out

    def _project(self, filled, known):
        """Partial projection of flat masks (m, d) -> coefficients (m, k) float64 and the squared
        residual ||V W o' - w||^2 of the reconstruction on the known voxels (m,): ``(A + ridge I) o' = b``
        (:class:`hbeo.subspace.projection.MaskedProjector`)."""
        return self._projector.project(filled, known, precision=self.ridge)

    def candidates(self, R_true, pose: str = "known", rng=None) -> np.ndarray:
        """Candidate rotations (M, 3, 3) object -> camera for a pose mode (see the module docstring)."""
        if pose not in POSES:
            raise ValueError(f"pose must be one of {', '.join(POSES)}, got {pose!r}")
        R_true = np.asarray(R_true, np.float64)
        if pose == "known":
            return R_true[None]
        rng = _rng(rng)
        if pose == "1dof":
            n = self.pose_bins_1dof
            phi = rng.uniform(0, 2 * np.pi / n)
            return R_true[None] @ z_angle_to_matrix(2 * np.pi * np.arange(n) / n + phi)
        return uniform_so3(1, rng)[0][None] @ self._so3_base()

    def _so3_base(self):
        if getattr(self, "_so3_cache", (None,))[0] != self.so3_grid:
            self._so3_cache = (self.so3_grid, so3_grid(self.so3_grid))
        return self._so3_cache[1]

    def _class_index(self, label) -> int:
        if isinstance(label, str):
            if label not in self.classes_:
                raise ValueError(f"unknown class {label!r}; this BEO has {', '.join(self.classes_)}")
            return self.classes_.index(label)
        if int(label) != label or not 0 <= int(label) < len(self.classes_):
            raise ValueError(f"label_true must be a class name or an index in 0..{len(self.classes_) - 1}, "
                             f"got {label!r}")
        return int(label)

    def predict_view(self, depth, intrinsics: C.Intrinsics, R_true, t_true, object_size: float = 1.0,
                     pose: str = "known", label_true=None, rng=None, given_class: bool | None = None) -> dict:
        """Class, rotation and completed shape from one segmented depth image (H, W), metres, 0 = none.

        R_true (3, 3) object -> camera: the rotation itself (``pose="known"``), or what fixes the up
        axis (``"1dof"``); for ``"3dof"`` only its shape is checked. t_true (3,) metres and
        ``object_size`` (metres) are given to BEO (the paper assumes a correctly voxelized input).
        label_true (name or index) with ``given_class`` (default: the constructor's) restricts the
        search to that class. rng: np.random.Generator, an int seed or None (seed 0) for the
        off-grid offsets of the 1-/3-DOF candidates.

        Returns {"probabilities" (C,), "label", "rotation" (3, 3), "grid" (30, 30, 30) bool,
        "coeffs" (k,), "n_candidates", "score" (the best pair's log score)}.
        """
        self._check()
        R_true = np.asarray(R_true, np.float64)
        if R_true.shape != (3, 3):
            raise ValueError(f"R_true must have shape (3, 3), got {R_true.shape}")
        given = self.given_class if given_class is None else bool(given_class)
        only = self._class_index(label_true) if (label_true is not None and given) else None
        Rs = self.candidates(R_true, pose, rng)
        Cn = len(self.classes_)
        M = len(Rs)
        scores = np.empty((M, Cn))
        coeffs = np.empty((M, self.subspace.dim_))
        log_prior = np.log(self.class_prior_) - np.log(M)                 # log P(c) + log P(r)
        with threadpool_limits(1, user_api="blas"):    # small GEMMs: idle threads only spin
            for a, f, kn, outside in iter_partial(depth, intrinsics, Rs, t_true, object_size, chunk=self.chunk):
                m = len(f)
                o, sse = self._project(f, kn)
                sse = sse + outside        # observed surface voxels beyond the grid: W o' is 0 there
                coeffs[a:a + m] = o
                s = self.log_density(o) + log_prior
                if self.score == "joint":
                    s = s - sse[:, None] / (2 * self.noise_var_)
                scores[a:a + m] = s
        if only is not None:
            mask = np.full(Cn, -np.inf)
            mask[only] = 0.0
            scores = scores + mask
        r, c = np.unravel_index(int(np.argmax(scores)), scores.shape)
        best = scores.max(axis=0)                                            # each class at its best rotation
        if only is not None:
            probs = np.zeros(Cn)
            probs[only] = 1.0
        else:
            probs = np.exp(best - logsumexp(best))
        grid = self.subspace.reconstruct(coeffs[r][None], threshold=0.5)[0]
        return {"probabilities": probs, "label": int(c), "rotation": Rs[r].copy(), "grid": grid,
                "coeffs": coeffs[r].astype(np.float32), "n_candidates": int(M), "score": float(scores[r, c])}

    # ------------------------------------------------------------ persistence
    def save(self, path):
        """Write the fitted BEO with its subspace to one ``.npz`` (no pickle), atomically."""
        self._check()
        sub = io.BytesIO()
        self.subspace.save(sub)
        meta = {"format_version": FORMAT_VERSION, "params": self.get_params(), "classes": list(self.classes_),
                "coef_scale": self.coef_scale_, "noise_var": self.noise_var_,
                "subspace_fingerprint": getattr(self.subspace, "fingerprint_", None)}
        arrays = dict(weights=self.weights_, means=self.means_, precisions_cholesky=self.precisions_cholesky_,
                      class_prior=self.class_prior_, n_train=self.n_train_,
                      subspace=np.frombuffer(sub.getvalue(), np.uint8))
        return write_npz(path, meta, **arrays)

    @classmethod
    def load(cls, path) -> "BEO":
        """Read a file written by :meth:`save` (DataError naming the file if it is not one)."""
        path = Path(path)
        meta, arrays = read_npz(path, ("weights", "means", "precisions_cholesky", "class_prior", "n_train",
                                       "subspace"), "BEO", FORMAT_VERSION)
        try:
            sub = ObjectSubspace.load(io.BytesIO(arrays["subspace"].tobytes()))
        except DataError as err:
            raise DataError(path, f"its subspace is unreadable ({err.problem})") from None
        Cn, J, k = arrays["means"].shape
        if k != sub.dim_ or arrays["precisions_cholesky"].shape != (Cn, J, k, k) or len(meta["classes"]) != Cn:
            raise DataError(path, f"inconsistent BEO file: means {arrays['means'].shape}, subspace dimension "
                                  f"{sub.dim_}, {len(meta['classes'])} classes")
        self = cls(sub, **meta["params"])
        self.classes_ = tuple(meta["classes"])
        self.coef_scale_, self.noise_var_ = meta["coef_scale"], meta["noise_var"]
        self.weights_, self.means_ = arrays["weights"], arrays["means"]
        self.precisions_cholesky_ = arrays["precisions_cholesky"]
        self.class_prior_, self.n_train_ = arrays["class_prior"], arrays["n_train"]
        return self


def _rng(rng) -> np.random.Generator:
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng must be a numpy Generator, an int seed or None, got {type(rng).__name__}")
