"""The paper's ICP pose baseline: align the partial view with the class's mean training shape.

Given the *true* class (the paper gives ICP the class), the back-projected depth points are
registered to the surface of that class's mean training grid from several initial rotations,
and the best fit is kept. ICP estimates pose only; its "completion" is the class mean shape.

Frames and units are those of :mod:`hbeo.conventions`: the estimate (R, t) puts an object point
x (metres, origin at the bounding-box centre, longest side ``object_size``) at ``R @ x + t`` in
the camera frame (OpenCV axes). Internally everything is divided by ``object_size``, so the model
surface lives in ``object_size = 1`` units (grid coordinate u = x * 24 + 15).

Algorithm (all initializations at once, numpy + one :class:`scipy.spatial.cKDTree` per class)
    model     the class mean grid (float mean of the training grids) thresholded at 0.5, meshed
              by :func:`hbeo.render.renderer.grid_mesh` and sampled (area-uniform) to ``n_model`` points
              with their outward normals.
    data      the depth image back-projected (:func:`hbeo.conventions.backproject`) and randomly
              subsampled to ``n_points`` points.
    inits     ``"3dof"``: ``n_init`` rotations of a super-Fibonacci spiral (near-uniform over
              SO(3), deterministic); ``"1dof"``: ``n_yaw`` turns about the object's up axis with
              the true up direction (``R_true @ Rz(yaw)``), a random offset from ``rng``. Each
              initial translation puts the centroid of the model points that face the camera
              under that rotation onto the centroid of the data (the data only shows the near
              side of the object, so the object centre lies behind the data's centroid).
    iterate   data -> model closest points (KD-tree, all points of all inits in one query),
              trimmed: the ``trim`` fraction of closest pairs is kept. The update (``metric``):
              ``"plane"`` (default) one Gauss-Newton step of point-to-plane ICP (model normals;
              a batched 6x6, or for ``"1dof"`` 4x4, Cholesky solve per init), ``"point"``
              point-to-point Kabsch/SVD, or its closed form about the known up axis for
              ``"1dof"``. With ``"1dof"`` the rotation only turns about the true up direction,
              which stays exact. Point-to-plane converges in far fewer iterations (point-to-point
              often stalled 10-30 degrees from the truth; ``bench_icp.py --metric point``).
              Coarse to fine: every init runs ``coarse_iter`` iterations on ``n_coarse`` points;
              the ``n_refine`` best continue on all ``n_points`` for up to ``max_iter``. An init
              stops when its pose moves less than ``tol`` or its score has not improved by 0.1 %
              for 3 iterations (changing correspondences make ICP cycle); its best pose is kept.
    score     trimmed mean distance of the data points to the closest model points (the ``trim``
              fraction closest), lowest wins; reported in metres as ``fitness`` (lower = better).
              The partial view only shows one side, so mean shapes often fit a turned-around pose
              about as well as the true one: most 3-DOF failures are 90/180 degree flips.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from hbeo import conventions as C
from hbeo.errors import DataError
from hbeo.baselines.methods import METHODS
from hbeo.rotations import (axis_and_angle_to_matrix, axis_angle_to_matrix, check_rotation_matrices, geodesic,
                            project_to_so3, super_fibonacci, z_angle_to_matrix)
from hbeo.storage import pack_bits, read_npz, unpack_bits, write_npz

FORMAT_VERSION = 1
POSES = ("3dof", "1dof")
_PATIENCE, _REL_GAIN = 3, 1e-3     # an init stops after 3 iterations without a 0.1 % better score


# ----------------------------------------------------------------------------- rigid updates

def _weighted_centroids(w, X):
    """w (K, n) >= 0, X (K, n, 3) -> (K, 3)."""
    return np.einsum("kn,knd->kd", w, X) / np.maximum(w.sum(axis=1), 1e-12)[:, None]


def _kabsch(M, P, w):
    """Rigid (R, t) per init minimizing sum w ||R m + t - p||^2. M, P (K, n, 3), w (K, n)."""
    mc, pc = _weighted_centroids(w, M), _weighted_centroids(w, P)
    H = np.einsum("kn,kni,knj->kij", w, M - mc[:, None], P - pc[:, None])   # sum w m' p'^T
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    d[d == 0] = 1.0
    D = np.zeros((len(d), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, 1, 2) @ D @ np.swapaxes(U, 1, 2)
    return R, pc - np.einsum("kij,kj->ki", R, mc)


def _yaw_update(M, P, w, R_up, axis):
    """Best (R, t) with R = Rot(axis, phi) @ R_up (rotation about the fixed camera-frame ``axis``
    only), minimizing sum w ||R m + t - p||^2, closed form. M, P (K, n, 3), w (K, n)."""
    Q = np.einsum("kij,knj->kni", R_up, M)
    qc, pc = _weighted_centroids(w, Q), _weighted_centroids(w, P)
    Qc, Pc = Q - qc[:, None], P - pc[:, None]
    cross = np.cross(axis, Qc)                                      # a x q
    sin_term = np.einsum("kn,knd,knd->k", w, Pc, cross)
    cos_term = (np.einsum("kn,knd,knd->k", w, Pc, Qc)
                - np.einsum("kn,kn,kn->k", w, Pc @ axis, Qc @ axis))
    phi = np.arctan2(sin_term, cos_term)
    A = axis_and_angle_to_matrix(axis, phi)
    R = A @ R_up
    return R, pc - np.einsum("kij,kj->ki", A, qc)


def _cho_solve(A, b):
    """Solve the SPD systems A x = b, A (K, d, d), b (K, d), by Cholesky and substitution over d
    (numpy's batched ``solve`` costs ~30 us per tiny system; this is ~10x cheaper)."""
    L = np.linalg.cholesky(A)
    d = A.shape[1]
    y = np.empty_like(b)
    for i in range(d):
        y[:, i] = (b[:, i] - np.einsum("kj,kj->k", L[:, i, :i], y[:, :i])) / L[:, i, i]
    x = np.empty_like(b)
    for i in reversed(range(d)):
        x[:, i] = (y[:, i] - np.einsum("kj,kj->k", L[:, i + 1:, i], x[:, i + 1:])) / L[:, i, i]
    return x


def _plane_update(M, Nm, P, w, R, t, axis, damping=1e-6):
    """One Gauss-Newton step of point-to-plane ICP per init: minimize
    sum w (n . (q + omega x (q - c) + delta - p))^2 over the small motion (omega, delta) of the
    model points q = R m + t (camera frame), about the data centroid c, with n = R n_m;
    omega = theta * axis when ``axis`` (camera frame, the known up direction) is given.
    M, Nm, P (K, n, 3) matched model points / model normals / data; w (K, n)."""
    Q = M @ np.swapaxes(R, 1, 2) + t[:, None]
    N = Nm @ np.swapaxes(R, 1, 2)
    c = _weighted_centroids(w, P)
    r = np.einsum("knd,knd->kn", N, Q - P)                              # signed plane distances
    qxn = np.cross(Q - c[:, None], N)
    J = np.concatenate([qxn if axis is None else (qxn @ axis)[..., None], N], axis=2)
    Jw = J * w[..., None]
    A = np.swapaxes(Jw, 1, 2) @ J
    b = -np.einsum("kni,kn->ki", Jw, r)
    dim = A.shape[1]
    A += (damping * np.trace(A, axis1=1, axis2=2) / dim + 1e-12)[:, None, None] * np.eye(dim)
    x = _cho_solve(A, b)
    omega = x[:, :3] if axis is None else x[:, :1] * axis
    E = axis_angle_to_matrix(omega)
    Rn = E @ R
    tn = np.einsum("kij,kj->ki", E, t - c) + c + x[:, -3:]
    return Rn, tn


# ----------------------------------------------------------------------------- the baseline

class ICPBaseline:
    """ICP pose baseline given the true class; see the module docstring.

    n_init: initial rotations for ``pose="3dof"`` (super-Fibonacci set). n_yaw: initial yaws for
    ``pose="1dof"``. max_iter: iterations of the refinement stage. n_points: depth points used
    (random subsample). trim: fraction of closest pairs kept in each update and in the score.
    n_model: points sampled on each class's mean surface. n_coarse, coarse_iter, n_refine: the
    coarse stage (every init, fewer points) and how many inits go on to the refinement.
    tol: convergence threshold (radians and object_size units of pose change). metric: ``"plane"``
    (point-to-plane, default) or ``"point"`` (point-to-point). seed: default random stream of
    :meth:`predict_view` (subsampling, 1-DOF yaw offset) and of the model sampling in :meth:`fit`.
    """

    #: the :class:`hbeo.evaluation.method.Method` contract: registry name and pose settings (default first)
    name = "icp"
    poses = METHODS["icp"]

    def describe(self) -> dict:
        """Settings the metrics dict records beyond name and pose: none for a baseline."""
        return {}

    def __init__(self, n_init: int = 48, max_iter: int = 40, n_points: int = 500, trim: float = 0.9,
                 seed: int = 0, n_yaw: int = 12, n_model: int = 4000, n_coarse: int = 150,
                 coarse_iter: int = 12, n_refine: int = 4, tol: float = 1e-3, metric: str = "plane"):
        self.n_init, self.max_iter, self.n_points, self.trim = int(n_init), int(max_iter), int(n_points), float(trim)
        self.seed, self.n_yaw, self.n_model = int(seed), int(n_yaw), int(n_model)
        self.n_coarse, self.coarse_iter, self.n_refine = int(n_coarse), int(coarse_iter), int(n_refine)
        self.tol = float(tol)
        for name in ("n_init", "n_yaw", "n_points", "n_model", "n_coarse", "n_refine"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_iter < 1 or self.coarse_iter < 0:
            raise ValueError(f"need max_iter >= 1 and coarse_iter >= 0, got {self.max_iter}, {self.coarse_iter}")
        self.metric = str(metric)
        if self.metric not in ("plane", "point"):
            raise ValueError(f"metric must be 'plane' or 'point', got {metric!r}")
        if not 0 < self.trim <= 1:
            raise ValueError(f"trim must be in (0, 1], got {self.trim}")
        self._trees = {}

    def get_params(self) -> dict:
        return {k: getattr(self, k) for k in ("n_init", "max_iter", "n_points", "trim", "seed", "n_yaw",
                                              "n_model", "n_coarse", "coarse_iter", "n_refine", "tol", "metric")}

    def __repr__(self):
        fitted = f", {len(self.classes_)} classes" if hasattr(self, "classes_") else ""
        return f"<ICPBaseline n_init={self.n_init} n_points={self.n_points} trim={self.trim}{fitted}>"

    # ------------------------------------------------------------ fitting
    def fit(self, grids, labels, classes=None) -> "ICPBaseline":
        """Class means of training grids (N, 30, 30, 30) bool with labels (N,) (int into
        ``classes``, or class names) and the points of each mean shape's surface."""
        from hbeo.render.renderer import grid_mesh
        g = np.asarray(grids)
        if g.ndim != 4 or len(set(g.shape[1:])) != 1:
            raise ValueError(f"grids must have shape (N, R, R, R), got {g.shape}")
        labels = np.asarray(labels)
        if len(labels) != len(g):
            raise ValueError(f"{len(g)} grids but {len(labels)} labels")
        if classes is None:
            classes = (tuple(dict.fromkeys(labels.tolist())) if labels.dtype.kind in "USO"
                       else tuple(C.CLASSES[:int(labels.max()) + 1]))
        classes = tuple(str(c) for c in classes)
        if labels.dtype.kind in "USO":
            unknown = sorted(set(labels.tolist()) - set(classes))
            if unknown:
                raise ValueError(f"labels {unknown} are not among the classes {list(classes)}")
            labels = np.array([classes.index(s) for s in labels.tolist()], dtype=np.int64)
        rng = np.random.default_rng(self.seed)
        means, shapes, pts, nrm, offsets = [], [], [], [], [0]
        for ci, name in enumerate(classes):
            sel = labels == ci
            if not sel.any():
                raise ValueError(f"class {name!r} has no training grids")
            mean = g[sel].astype(np.float32).mean(axis=0)
            shape = mean >= 0.5
            if not shape.any():                 # training shapes that overlap nowhere by half
                if not (mean > 0).any():
                    raise ValueError(f"class {name!r}: all training grids are empty")
                shape = mean >= 0.5 * mean.max()
            p, n = _sample_surface(grid_mesh(shape, object_size=1.0), self.n_model, rng)
            means.append(mean)
            shapes.append(shape)
            pts.append(p)
            nrm.append(n)
            offsets.append(offsets[-1] + len(p))
        self.classes_ = classes
        self.means_ = np.stack(means)
        self.shapes_ = np.stack(shapes)
        self.model_points_ = np.concatenate(pts).astype(np.float32)
        self.model_normals_ = np.concatenate(nrm).astype(np.float32)
        self.model_offsets_ = np.asarray(offsets, dtype=np.int64)
        self._trees = {}
        return self

    def _check(self):
        if not hasattr(self, "classes_"):
            raise RuntimeError("ICPBaseline is not fitted; call fit() or load() first")

    def _model(self, ci: int):
        """Model points, normals (float64, object_size = 1 units) and KD-tree of class ci (cached)."""
        if ci not in self._trees:
            lo, hi = self.model_offsets_[ci], self.model_offsets_[ci + 1]
            pts = self.model_points_[lo:hi].astype(np.float64)
            self._trees[ci] = (pts, self.model_normals_[lo:hi].astype(np.float64), cKDTree(pts))
        return self._trees[ci]

    def _class_index(self, label) -> int:
        if label is None:
            raise ValueError("the ICP baseline needs the true class: pass label_true (class name or index)")
        if isinstance(label, (str, np.str_)):
            if str(label) not in self.classes_:
                raise ValueError(f"unknown class {label!r}; fitted classes: {', '.join(self.classes_)}")
            return self.classes_.index(str(label))
        i = int(label)
        if i != label or not 0 <= i < len(self.classes_):
            raise ValueError(f"label_true {label!r} is not a class index in 0..{len(self.classes_) - 1}")
        return i

    # ------------------------------------------------------------ prediction
    def predict_view(self, depth, intrinsics: C.Intrinsics, R_true=None, t_true=None, object_size: float = 1.0,
                     pose: str = "3dof", label_true=None, rng=None) -> dict:
        """Pose of one segmented depth image (H, W), metres, 0 = no object, of an object of the
        known class ``label_true`` (name or index) and known size ``object_size`` (metres).

        ``pose="3dof"``: rotation unknown. ``pose="1dof"``: the up direction is known
        (``R_true[:, 2]``), only the yaw about it is estimated. ``t_true`` is not used.
        Returns ``probabilities`` (C,) one-hot of the given class, ``rotation`` (3, 3) object ->
        camera, ``translation`` (3,) metres, ``grid`` (30, 30, 30) bool (the class mean shape at
        0.5), ``fitness`` (trimmed mean distance of the depth points to the model surface, metres;
        lower is better) and ``n_points`` (depth points used).
        """
        self._check()
        ci = self._class_index(label_true)
        if pose not in POSES:
            raise ValueError(f"unknown pose setting {pose!r}; expected one of {', '.join(POSES)}")
        size = float(object_size)
        if not np.isfinite(size) or size <= 0:
            raise ValueError(f"object_size must be a positive number of metres, got {object_size!r}")
        if not isinstance(intrinsics, C.Intrinsics):
            raise TypeError(f"intrinsics must be hbeo.conventions.Intrinsics, got {type(intrinsics).__name__}")
        depth = np.asarray(depth)
        if depth.ndim != 2:
            raise ValueError(f"depth must be one image (H, W), got shape {depth.shape}")
        if not np.isfinite(depth).all():
            depth = np.where(np.isfinite(depth), depth, 0)
        pts, _ = C.backproject(depth, intrinsics)
        if len(pts) < 3:
            raise ValueError(f"depth image shows no object ({len(pts)} pixels with depth > 0; need >= 3)")
        rng = np.random.default_rng(self.seed if rng is None else rng)      # a Generator passes through
        pts = C.subsample_points(pts, self.n_points, rng)
        P = pts / size                                          # object_size = 1 units
        model, normals, tree = self._model(ci)

        if pose == "3dof":
            R0, axis = super_fibonacci(self.n_init), None
        else:
            if R_true is None:
                raise ValueError('pose="1dof" needs R_true (its up direction R_true[:, 2] is given to ICP)')
            R_up = np.asarray(R_true, dtype=np.float64)
            if R_up.shape != (3, 3) or not np.isfinite(R_up).all():
                raise ValueError(f"R_true must be a finite (3, 3) rotation matrix, got shape {R_up.shape}")
            check_rotation_matrices(R_up, "R_true")
            yaw = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(self.n_yaw) / self.n_yaw
            R0, axis = R_up @ z_angle_to_matrix(yaw), R_up[:, C.UP_AXIS] / np.linalg.norm(R_up[:, C.UP_AXIS])
        t0 = self._initial_translations(P, R0, model, normals)

        # coarse: every init, few points; refine: the best few, all points
        R, t = R0, t0
        if self.coarse_iter > 0 and len(R0) > self.n_refine:
            sub = P[rng.choice(len(P), min(self.n_coarse, len(P)), replace=False)]
            R, t, s = self._icp(sub, R, t, tree, model, normals, axis, self.coarse_iter)
            keep = np.argsort(s, kind="stable")[: self.n_refine]
            R, t = R[keep], t[keep]
        R, t, score = self._icp(P, R, t, tree, model, normals, axis, self.max_iter)
        b = int(np.argmin(score))
        probs = np.zeros(len(self.classes_))
        probs[ci] = 1.0
        R_best = project_to_so3(R[b])
        return {"probabilities": probs, "rotation": R_best, "translation": t[b] * size,
                "grid": self.shapes_[ci].copy(), "fitness": float(score[b] * size), "n_points": int(len(P))}

    @staticmethod
    def _initial_translations(P, R0, model, normals):
        """Per initial rotation: t putting the centroid of the model points that face the camera
        (normal against the viewing ray) onto the data centroid."""
        c = P.mean(axis=0)
        view = c / np.linalg.norm(c)
        facing = (normals @ (view @ R0).T).T < 0                             # (K, Nm): (R n) . view < 0
        cnt = facing.sum(axis=1)
        vis = (facing.astype(np.float64) @ model) / np.maximum(cnt, 1)[:, None]
        vis[cnt == 0] = 0.0
        return c - np.einsum("kij,kj->ki", R0, vis)

    def _pairs(self, P, R, t, tree, model):
        """Closest model points of the data under each pose: distances (K, n), their indices (K, n)."""
        Y = (P[None] - t[:, None]) @ R                                       # R^T (p - t), rows
        d, idx = tree.query(Y.reshape(-1, 3), k=1)
        K, n = len(R), len(P)
        return d.reshape(K, n), idx.reshape(K, n)

    def _trimmed(self, d):
        """Trimmed mean distance (K,) and 0/1 weights (K, n) of the kept pairs, per init."""
        n = d.shape[1]
        keep = min(n, max(3, int(np.ceil(self.trim * n))))
        part = np.partition(d, keep - 1, axis=1)
        score = part[:, :keep].mean(axis=1)
        return score, (d <= part[:, keep - 1: keep]).astype(np.float64)

    def _icp(self, P, R, t, tree, model, normals, axis, iters):
        """Trimmed ICP for all inits at once. Each iteration scores the current poses (trimmed
        mean distance) and updates them; an init stops once its pose moves less than ``tol`` or
        its score has not improved by 0.1 % for 3 iterations (correspondence flips make ICP
        cycle). Returns the best-scoring pose seen per init and its score: R, t, score."""
        K = len(R)
        R, t = R.copy(), t.copy()
        best_R, best_t, best_s = R.copy(), t.copy(), np.full(K, np.inf)
        stall, still = np.zeros(K, dtype=int), np.zeros(K, dtype=bool)
        active = np.ones(K, dtype=bool)
        Pk = np.broadcast_to(P, (K,) + P.shape)
        for it in range(iters + 1):
            a = np.nonzero(active)[0]
            d, idx = self._pairs(P, R[a], t[a], tree, model)
            s, w = self._trimmed(d)
            better = s < best_s[a]
            gain = s < best_s[a] * (1 - _REL_GAIN)
            stall[a] = np.where(gain, 0, stall[a] + 1)
            b = a[better]
            best_R[b], best_t[b], best_s[b] = R[b], t[b], s[better]
            done = (stall[a] >= _PATIENCE) | still[a] | (it == iters)
            active[a[done]] = False
            go = ~done
            if not go.any():
                break
            a, idx, w = a[go], idx[go], w[go]
            M = model[idx]
            if self.metric == "plane":
                Rn, tn = _plane_update(M, normals[idx], Pk[a], w, R[a], t[a], axis)
            elif axis is None:
                Rn, tn = _kabsch(M, Pk[a], w)
            else:
                Rn, tn = _yaw_update(M, Pk[a], w, R[a], axis)
            dang = geodesic(Rn, R[a])
            still[a] = (dang < self.tol) & (np.linalg.norm(tn - t[a], axis=1) < self.tol)
            R[a], t[a] = Rn, tn
        return best_R, best_t, best_s

    # ------------------------------------------------------------ persistence
    def save(self, path) -> Path:
        """Write settings, class means and model surface points (.npz) atomically."""
        self._check()
        meta = {"format_version": FORMAT_VERSION, "params": self.get_params(), "classes": list(self.classes_)}
        return write_npz(path, meta, compressed=True, means=self.means_.astype(np.float32),
                         shapes=pack_bits(self.shapes_), points=self.model_points_, normals=self.model_normals_,
                         offsets=self.model_offsets_)

    @classmethod
    def load(cls, path) -> "ICPBaseline":
        """Read a file written by :meth:`save`; :class:`DataError` naming the file if it is not one."""
        path = Path(path)
        meta, arrays = read_npz(path, ("means", "shapes", "points", "normals", "offsets"), "ICP baseline",
                                FORMAT_VERSION)
        try:
            self = cls(**meta["params"])
            classes = tuple(meta["classes"])
            means = arrays["means"]
            n = len(classes)
            if means.ndim != 4 or len(means) != n:
                raise ValueError(f"means have shape {means.shape} for {n} classes")
            # rows; earlier files hold the same bytes flat (30^3 bits fill whole bytes)
            shapes = unpack_bits(arrays["shapes"].reshape(n, -1), means.shape[1:])
            offsets = arrays["offsets"].astype(np.int64)
            pts, nrm = arrays["points"], arrays["normals"]
            if (offsets.shape != (n + 1,) or offsets[0] != 0 or offsets[-1] != len(pts) or np.any(np.diff(offsets) < 1)
                    or pts.shape != nrm.shape or pts.ndim != 2 or pts.shape[1] != 3):
                raise ValueError("inconsistent model point arrays")
        except Exception as err:
            raise DataError(path, f"corrupt ICP baseline file ({type(err).__name__}: {err})") from None
        self.classes_, self.means_, self.shapes_ = classes, means, shapes
        self.model_points_, self.model_normals_, self.model_offsets_ = pts, nrm, offsets
        return self


def _sample_surface(mesh, n: int, rng: np.random.Generator):
    """n points area-uniformly on a triangle mesh, with its face normals: (n, 3), (n, 3)."""
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cr = np.cross(b - a, c - a)
    area = np.linalg.norm(cr, axis=1)
    ok = area > 0
    a, b, c, cr, area = a[ok], b[ok], c[ok], cr[ok], area[ok]
    face = rng.choice(len(area), n, p=area / area.sum())
    u, w = rng.random(n), rng.random(n)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    pts = a[face] + u[:, None] * (b[face] - a[face]) + w[:, None] * (c[face] - a[face])
    return pts, cr[face] / area[face][:, None]
