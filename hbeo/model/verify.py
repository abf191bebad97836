"""Predict, then verify: HBEONet's hypotheses checked against the observed depth (issue 16).

HBEONet answers in one pass but cannot see what it got wrong; BEO checks a pose against the depth
but must search for it. Verify does both: the network proposes, the depth decides.

For one query (a depth image, the :class:`~hbeo.model.inference.Prediction` of
:meth:`HBEO.predict`):

1. **Hypotheses.** The ``classes`` most probable classes times ``rotations`` rotation modes. A
   rotation-bins model's modes come from its distribution (:func:`rotation_modes`: the most
   probable bin, then the most probable bin farther than ``radius_deg`` from every mode taken, ...,
   each decoded as the network decodes its best bin and weighted by the probability mass within
   ``radius_deg``). A regression head gives one rotation; its modes are that rotation turned by
   2 pi j / ``rotations`` about the object's up axis (+z), the flips one regressed answer cannot
   resolve, equally weighted. The translation is the model's estimate of the object centre.
2. **Carving.** The depth image becomes known-filled / known-empty / unknown voxels at each
   rotation (:func:`hbeo.subspace.partial.iter_partial`), surface points beyond the grid counted,
   at the model's centre estimate moved by translation-only ICP onto the most probable class's
   mean shape at that rotation (:func:`refine_translation`; ``refine_translation=False``: as estimated).
3. **MAP completion.** For each (class c, rotation r) the coefficients o minimize
   ``||V W o - w||^2 / (2 s^2)`` (the observed voxels, ``s^2 = noise_var``) plus two Gaussian
   priors: the network's guess, N(o_net, diag((prior_scale * std)^2)) with std the training
   coefficients' standard deviation, and class c's VBPCA density restricted to the subspace,
   N(W^T m_c, B_c^T diag(lambda_c) B_c + sigma_c^2 I) (B_c = U_c W: the class's components in the
   shared basis), weighted by ``class_weight``. So the network's guess fills what the camera cannot see.
4. **Score.** The log posterior of each hypothesis: the voxel log-likelihood at the MAP
   coefficients, both prior log densities there, ``net_weight`` x (log p_net(c) + log p_net(r)).
   The best hypothesis gives class, rotation and completion; class probabilities are the softmax
   of each class's best score.

Frames and units are those of :mod:`hbeo.conventions` (R: object -> user camera; t metres).
Per query: one GEMM of the basis over the known voxels and one carving per rotation, a k x k
Cholesky per hypothesis (k = subspace dimension).

May import: foundation, subspace and the other hbeo.model modules.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, fields, replace

import numpy as np
import torch
from scipy.linalg import cho_factor, cho_solve
from scipy.special import logsumexp
from threadpoolctl import threadpool_limits

from hbeo.conventions import OBJECT_VOXELS, Intrinsics, backproject
from hbeo.model.network import bin_cosines
from hbeo.rotations import matrix_to_axis_angle, project_to_so3, z_angle_to_matrix
from hbeo.subspace.partial import iter_partial
from hbeo.subspace.projection import MaskedProjector


@dataclass(frozen=True)
class VerifyConfig:
    """Settings of the verify step (chosen on validation objects; see README)."""

    classes: int = 3              #: most probable classes tried
    rotations: int = 4            #: rotation modes tried
    radius_deg: float = 40.0      #: modes at least this far apart (bins heads)
    noise_var: float = 0.1        #: s^2: variance of an observed voxel's 0/1 value around W o
    prior_scale: float = 1.0      #: the network prior's std, in training coefficient stds
    class_weight: float = 1.0     #: weight of the class density (0: network prior only)
    net_weight: float = 1.0       #: weight of the network's log probabilities
    refine_translation: bool = True   #: ICP the model's centre estimate onto the top class's mean shape, per rotation

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def parse(cls, text: str | None) -> "VerifyConfig":
        """Settings from ``key=value,key=value`` (the command line's ``--verify-set``) over the
        defaults; empty or None: the defaults. Unknown keys and bad values raise ValueError naming them."""
        kw: dict = {}
        types = {f.name: f.type for f in fields(cls)}
        for part in filter(None, (x.strip() for x in (text or "").split(","))):
            key, eq, value = part.partition("=")
            key = key.strip().replace("-", "_")
            if not eq or key not in types:
                raise ValueError(f"verify setting {part!r}: expected key=value with key one of {', '.join(types)}")
            kind = {"int": int, "float": float, "bool": _bool}[types[key]]
            try:
                kw[key] = kind(value.strip())
            except ValueError:
                raise ValueError(f"verify setting {part!r}: {value.strip()!r} is not a {types[key]}") from None
        cfg = cls(**kw)
        if cfg.classes < 1 or cfg.rotations < 1 or cfg.noise_var <= 0 or cfg.prior_scale <= 0 or \
                min(cfg.radius_deg, cfg.class_weight, cfg.net_weight) < 0:
            raise ValueError(f"verify settings out of range: {cfg} (classes, rotations >= 1; noise_var, "
                             f"prior_scale > 0; radius_deg, class_weight, net_weight >= 0)")
        return cfg


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise ValueError(text)


def rotation_modes(probs: np.ndarray, grid: np.ndarray, n: int, radius_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n`` modes of a distribution ``probs`` (N,) over rotations ``grid`` (N, 3, 3): greedily
    the most probable bin farther than ``radius_deg`` from the modes taken, refined as the
    probability-weighted mean (projected onto SO(3)) of the bins within ``radius_deg``. Returns the
    rotations (m, 3, 3) and each mode's probability mass within ``radius_deg`` (m,; a bin near two
    modes counts for the first, so the masses sum to at most 1)."""
    p = np.asarray(probs, np.float64)
    G = torch.as_tensor(np.asarray(grid, np.float64))
    cos_r = math.cos(math.radians(radius_deg))
    free = np.ones(len(p), bool)
    Rs, mass = [], []
    for _ in range(n):
        if not free.any():
            break
        g = int(np.flatnonzero(free)[np.argmax(p[free])])
        near = bin_cosines(G[g][None], G)[0].numpy() >= cos_r
        w = np.where(near, p, 0.0)
        Rs.append(project_to_so3((w @ G.flatten(1).numpy()).reshape(3, 3)))
        mass.append(float(p[near & free].sum()))        # bins of an earlier mode count there only
        free &= ~near
    return np.stack(Rs), np.asarray(mass)


def surface_targets(shape: np.ndarray) -> np.ndarray | None:
    """For every voxel of a shape's grid (R^3 bool, canonical frame), the centre of the nearest voxel
    of the shape's surface, in grid coordinates (R, R, R, 3); None for an empty shape. What
    :func:`refine_translation` matches points to (compute once per shape)."""
    from scipy import ndimage
    shape = np.asarray(shape, bool)
    if not shape.any():
        return None
    surf = shape & ~ndimage.binary_erosion(shape)
    _, idx = ndimage.distance_transform_edt(~surf, return_indices=True)
    return np.moveaxis(idx, 0, -1).astype(np.float64) + 0.5


def refine_translation(points: np.ndarray, R: np.ndarray, t: np.ndarray, shape: np.ndarray, object_size: float,
                       iters: int = 10, targets: np.ndarray | None = None) -> np.ndarray:
    """Translation-only ICP of camera-frame surface points (N, 3) onto a shape (30^3 bool, canonical
    frame) seen at rotation R from a start ``t`` (3,), metres: each step moves every point's
    object-frame position to its nearest voxel of the shape's surface and shifts t by the mean
    displacement (points beyond the grid are taken to its border first). Returns the refined t.
    ``targets``: the shape's :func:`surface_targets`, when already computed."""
    nearest = surface_targets(shape) if targets is None else targets
    if nearest is None or len(points) == 0:
        return np.asarray(t, np.float64)
    vox = OBJECT_VOXELS / object_size                                                # voxels per metre
    res = nearest.shape[0]
    t = np.asarray(t, np.float64).copy()
    for _ in range(iters):
        u = (points - t) @ R * vox + res / 2                                          # grid coordinates (N, 3)
        cell = np.clip(np.floor(u).astype(np.int64), 0, res - 1)
        target = nearest[cell[:, 0], cell[:, 1], cell[:, 2]]
        step = (u - target).mean(axis=0) / vox                                        # object frame, metres
        t += R @ step
        if np.linalg.norm(step) < 0.25 / vox:
            break
    return t


class Verifier:
    """The verify step for one model (:class:`hbeo.model.inference.HBEO`), with its per-model
    quantities (class densities in the subspace, coefficient scale) computed once."""

    def __init__(self, model, cfg: VerifyConfig | None = None):
        self.model, self.cfg = model, cfg or VerifyConfig()
        sub = model.subspace
        W = sub.basis_.astype(np.float64)
        self.k = W.shape[1]
        self.projector = MaskedProjector(sub.basis_)
        std = model.settings.get("coeff_std")
        self.coeff_std = np.asarray(std, np.float64) if std is not None else np.ones(self.k)
        # each class's VBPCA density in the subspace: mean a_c (k,) and precision (k, k)
        self.class_mean, self.class_prec, self.class_logdet = [], [], []
        for c in model.classes:
            j = sub.classes_.index(c)
            U = np.asarray(sub.class_components_[c], np.float64) @ W                  # (q, k)
            lam = np.asarray(sub.class_variance_ratio_[c], np.float64) * sub.class_total_variance_[c]
            cov = U.T @ (lam[:, None] * U) + max(sub.class_noise_variance_[c], 1e-6) * np.eye(self.k)
            L = np.linalg.cholesky(cov)
            self.class_mean.append(sub.class_means_[j].astype(np.float64) @ W)
            self.class_prec.append(np.linalg.inv(cov))
            self.class_logdet.append(2 * np.log(np.diag(L)).sum())
        # what every query reuses: the weighted class precisions and their products with the means,
        # the rotation grid of a bins head, and (lazily) each class mean shape's surface targets
        self.class_weighted = [self.cfg.class_weight * P for P in self.class_prec]
        self.class_weighted_mean = [P @ a for P, a in zip(self.class_weighted, self.class_mean)]
        self.bin_grid = (model.net.bin_rotations.double().numpy() if model.net.cfg.rotation == "bins" else None)
        self._targets: dict[int, np.ndarray | None] = {}

    def mean_shape_targets(self, c: int) -> np.ndarray | None:
        """:func:`surface_targets` of class ``c``'s mean shape (the subspace's class mean >= 0.5), cached."""
        if c not in self._targets:
            self._targets[c] = surface_targets(self.model.subspace.eigen_object(self.model.classes[c]) >= 0.5)
        return self._targets[c]

    def hypotheses_rotations(self, pred, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Rotation modes of query ``i`` in the user's camera (m, 3, 3) and their log weights (m,)."""
        cfg = self.cfg
        if pred.pose_probs is not None:
            Rv, mass = rotation_modes(pred.pose_probs[i], self.bin_grid, cfg.rotations, cfg.radius_deg)
            return pred.view_rotation[i] @ Rv, np.log(np.maximum(mass, 1e-12))
        turns = z_angle_to_matrix(2 * np.pi * np.arange(cfg.rotations) / cfg.rotations)
        return pred.rotation[i][None] @ turns, np.zeros(cfg.rotations)

    def verify(self, depth: np.ndarray, intrinsics: Intrinsics, pred, i: int = 0) -> dict:
        """Verify query ``i`` of ``pred`` (made from ``depth`` (H, W) metres with ``intrinsics``).
        Returns {"probabilities" (C,), "label", "rotation" (3, 3), "translation" (3,), "coeffs" (k,),
        "grid" (30^3 bool), "score", "n_hypotheses", "ms"}."""
        t0 = time.perf_counter()
        cfg, model = self.cfg, self.model
        s2 = cfg.noise_var
        Rs, log_pr = self.hypotheses_rotations(pred, i)
        probs = np.asarray(pred.probabilities[i], np.float64)
        top = np.argsort(-probs)[:cfg.classes]
        o_net = np.asarray(pred.coeffs[i], np.float64)
        P_net = 1.0 / (cfg.prior_scale * self.coeff_std) ** 2                          # (k,)
        size = model.settings["object_size"] * float(pred.scale[i])
        scores = np.full((len(Rs), len(top)), -np.inf)
        coeffs = np.zeros((len(Rs), len(top), self.k))
        ts = np.repeat(np.asarray(pred.translation[i], np.float64)[None], len(Rs), axis=0)
        if cfg.refine_translation:
            targets = self.mean_shape_targets(int(top[0]))
            pts, _ = backproject(np.asarray(depth), intrinsics)
            ts = np.stack([refine_translation(pts, R, ts[0], None, size, targets=targets) for R in Rs])
        with threadpool_limits(1, user_api="blas"):
            for r in range(len(Rs)):                         # each rotation carved at its own translation
                _, f, kn, outside = next(iter_partial(depth, intrinsics, Rs[r:r + 1], ts[r], size, chunk=1))
                (A,), (b,), (nf,) = self.projector.normal_equations(f, kn)
                for ci, c in enumerate(top):
                    H = A / s2 + self.class_weighted[c]
                    H[np.diag_indices(self.k)] += P_net
                    rhs = b / s2 + P_net * o_net + self.class_weighted_mean[c]
                    o = cho_solve(cho_factor(H, check_finite=False), rhs, check_finite=False)
                    sse = max(0.0, nf - 2 * b @ o + o @ A @ o) + outside[0]
                    dn, dc = o - o_net, o - self.class_mean[c]
                    s = (-sse / (2 * s2) - 0.5 * dn @ (P_net * dn)
                         - cfg.class_weight * 0.5 * (dc @ self.class_prec[c] @ dc + self.class_logdet[c])
                         + cfg.net_weight * (np.log(max(probs[c], 1e-12)) + log_pr[r]))
                    scores[r, ci], coeffs[r, ci] = s, o
        r, ci = np.unravel_index(int(np.argmax(scores)), scores.shape)
        best = np.full(len(probs), -np.inf)
        best[top] = scores.max(axis=0)
        out_probs = np.exp(best - logsumexp(best))
        o = coeffs[r, ci].astype(np.float32)
        grid = model.subspace.reconstruct(o[None], threshold=0.5)[0]
        return {"probabilities": out_probs, "label": int(top[ci]), "rotation": Rs[r], "translation": ts[r],
                "coeffs": o, "grid": grid,
                "score": float(scores[r, ci]), "n_hypotheses": int(scores.size),
                "ms": (time.perf_counter() - t0) * 1e3}

    def apply(self, depth, intrinsics: Intrinsics, pred):
        """A copy of ``pred`` (from ``depth`` (H, W) or (B, H, W)) with every query verified;
        ``timing_ms["verify"]`` added."""
        batch = np.asarray(depth)
        batch = batch[None] if batch.ndim == 2 else batch
        res = [self.verify(batch[i], intrinsics, pred, i) for i in range(len(batch))]
        R = np.stack([x["rotation"] for x in res])
        labels = np.array([x["label"] for x in res])
        return replace(pred, probabilities=np.stack([x["probabilities"] for x in res]), labels=labels,
                       translation=np.stack([x["translation"] for x in res]),
                       class_names=[self.model.classes[j] for j in labels], rotation=R,
                       axis_angle=matrix_to_axis_angle(R), coeffs=np.stack([x["coeffs"] for x in res]),
                       grids=np.stack([x["grid"] for x in res]),
                       timing_ms={**pred.timing_ms, "verify": sum(x["ms"] for x in res),
                                  "total": pred.timing_ms.get("total", 0.0) + sum(x["ms"] for x in res)})
