"""Predict, then verify: HBEONet's hypotheses checked against the observed depth (ours, not the paper's).

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
   at the model's centre estimate moved so that HBEO's completion, rendered at that rotation, shows
   what the depth shows (:func:`align_translation`; ``refine_translation=False``: as estimated);
   ``realign`` > 0 aligns again on the best MAP completion at that rotation and solves again.
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
5. **Check.** The best completion is rendered at its pose and compared with the depth
   (:func:`depth_agreement`); below ``min_agreement`` verify keeps HBEO's own answer (a wrong
   rotation carves the view into the wrong voxels, and its completion is worse than the network's).

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

from hbeo.conventions import OBJECT_VOXELS, Intrinsics
from hbeo.limits import one_blas_thread
from hbeo.model.network import bin_cosines
from hbeo.rotations import matrix_to_axis_angle, project_to_so3, z_angle_to_matrix
from hbeo.subspace.partial import iter_partial
from hbeo.subspace.projection import MaskedProjector


@dataclass(frozen=True)
class VerifyConfig:
    """Settings of the verify step. The defaults were chosen on validation views of the `cpu`
    ModelNet10 reference model (``scripts/tune_verify.py``, ``verify_sweep.csv``; ``docs/experiments.md``): the class
    stays the network's (letting the shape fit pick the class lost 10-14 points of accuracy), the
    two most probable rotation modes are verified."""

    classes: int = 1              #: most probable classes tried (1: the network's class stands)
    rotations: int = 2            #: rotation modes tried
    radius_deg: float = 40.0      #: modes at least this far apart (bins heads)
    noise_var: float = 0.3        #: s^2: variance of an observed voxel's 0/1 value around W o
    prior_scale: float = 1.0      #: the network prior's std, in training coefficient stds
    class_weight: float = 0.0     #: weight of the class density (0: network prior only)
    net_weight: float = 1.0       #: weight of the network's log probabilities
    refine_translation: bool = True   #: align the centre per rotation: HBEO's completion rendered onto the depth
    realign: int = 0              #: then this many times: re-align on the best completion at that rotation, re-solve
    min_agreement: float = 0.45   #: below this depth agreement of the best hypothesis, keep HBEO's own answer
    agreement_tol: float = 2.0    #: depth difference (voxels) under which a pixel agrees

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
            if kind is float and not math.isfinite(kw[key]):
                raise ValueError(f"verify setting {part!r}: must be a finite number")
        cfg = cls(**kw)
        if cfg.classes < 1 or cfg.rotations < 1 or cfg.noise_var <= 0 or cfg.prior_scale <= 0 or cfg.realign < 0 or \
                min(cfg.radius_deg, cfg.class_weight, cfg.net_weight, cfg.min_agreement, cfg.agreement_tol) < 0:
            raise ValueError(f"verify settings out of range: {cfg} (classes, rotations >= 1; noise_var, "
                             f"prior_scale > 0; realign, radius_deg, class_weight, net_weight, min_agreement, "
                             f"agreement_tol >= 0)")
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


#: 8 sub-voxel offsets (voxels) at which :func:`surface_points` samples each surface voxel
_SUB = np.array([[a, b, c] for a in (-0.25, 0.25) for b in (-0.25, 0.25) for c in (-0.25, 0.25)])


def surface_points(shape: np.ndarray, object_size: float) -> np.ndarray:
    """A shape's (30^3 bool, canonical frame) surface as points (N, 3), object frame, metres: each
    surface voxel as 8 sub-voxel points (dense enough that a view at the training distances has no
    holes). What :func:`shape_depth` renders; compute once per shape."""
    from scipy import ndimage
    shape = np.asarray(shape, bool)
    surf = np.argwhere(shape & ~ndimage.binary_erosion(shape)).astype(np.float64)
    vox, res = OBJECT_VOXELS / object_size, shape.shape[0]
    return ((surf[:, None, :] + 0.5 + _SUB[None]).reshape(-1, 3) - res / 2) / vox


def shape_depth(points: np.ndarray, R: np.ndarray, t: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """The depth image (H, W), metres, 0 = nothing, that camera ``intrinsics`` sees of a shape's
    :func:`surface_points` (N, 3) at rotation R, centre t (metres): the points z-buffered per pixel
    (a fast approximation of rendering the voxels)."""
    K = intrinsics
    cam = points @ np.asarray(R, np.float64).T + np.asarray(t, np.float64)
    cam = cam[cam[:, 2] > 1e-6]
    u = np.rint(K.fx * cam[:, 0] / cam[:, 2] + K.cx).astype(np.int64)        # pixel centres are integers
    v = np.rint(K.fy * cam[:, 1] / cam[:, 2] + K.cy).astype(np.int64)
    ok = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
    near = np.full(K.width * K.height, np.inf)
    np.minimum.at(near, v[ok] * K.width + u[ok], cam[ok, 2])
    return np.where(np.isfinite(near), near, 0.0).reshape(K.height, K.width)


def working_stride(intrinsics: Intrinsics, model_intrinsics: Intrinsics) -> int:
    """:func:`working_view`'s s: the whole number of image pixels per model pixel, ``min(fx / fx_model,
    fy / fy_model)`` rounded down, at least 1."""
    return max(1, int(min(intrinsics.fx / model_intrinsics.fx, intrinsics.fy / model_intrinsics.fy)))


def working_view(depth: np.ndarray, intrinsics: Intrinsics, model_intrinsics: Intrinsics) -> tuple[np.ndarray, Intrinsics]:
    """The image verify works on: ``depth`` (H, W) seen with ``intrinsics``, reduced to the model camera's pixel
    density, at which :func:`surface_points` cover a shape without holes and the settings were chosen. Every
    s-th pixel in each direction from pixel s // 2, with s the whole number of image pixels per model pixel
    (:func:`working_stride`): the kept pixels are exactly the originals,
    the intrinsics theirs (f / s; c' = (c - s // 2) / s). s = 1 (the model's own camera, a coarser one)
    returns the inputs."""
    K = intrinsics
    s = working_stride(K, model_intrinsics)
    if s == 1:
        return depth, K
    o = s // 2
    d = np.ascontiguousarray(np.asarray(depth)[o::s, o::s])
    return d, Intrinsics(K.fx / s, K.fy / s, (K.cx - o) / s, (K.cy - o) / s, d.shape[1], d.shape[0])


def depth_agreement(observed: np.ndarray, rendered: np.ndarray, tol: float) -> float:
    """How well a rendered depth image (H, W) explains an observed one: the fraction of the pixels
    either covers where both do and their depths differ by less than ``tol`` metres (1: the same
    silhouette and surface; 0: nothing in common)."""
    a, b = np.asarray(observed) > 0, np.asarray(rendered) > 0
    union = np.count_nonzero(a | b)
    if union == 0:
        return 0.0
    both = a & b
    return float(np.count_nonzero(np.abs(observed[both] - rendered[both]) < tol)) / union


def align_translation(depth: np.ndarray, R: np.ndarray, t: np.ndarray, points: np.ndarray,
                      intrinsics: Intrinsics, iters: int = 3) -> np.ndarray:
    """The object centre (3,), metres, at which a shape (its :func:`surface_points` (N, 3)) seen at
    rotation R shows the observed depth image ``depth`` (H, W): from a start ``t``, each step renders
    the shape (:func:`shape_depth`) and moves t along the optical axis by the median depth difference
    over the pixels both images cover, and across it by the shift of the silhouettes' centroids.
    Unlike nearest-surface ICP it compares what the camera sees with what it would see, so the back
    of the shape cannot pull the centre."""
    t = np.asarray(t, np.float64).copy()
    obs = np.asarray(depth) > 0
    if not obs.any() or not len(points):
        return t
    rows, cols = np.nonzero(obs)
    cu, cv = cols.mean(), rows.mean()
    K = intrinsics
    for _ in range(iters):
        syn = shape_depth(points, R, t, K)
        seen = syn > 0
        if not seen.any():
            break
        both = obs & seen
        dz = float(np.median(depth[both] - syn[both])) if both.any() else 0.0
        r2, c2 = np.nonzero(seen)
        z = t[2] + dz
        step = np.array([(cu - c2.mean()) * z / K.fx, (cv - r2.mean()) * z / K.fy, 0.0])
        step += t / t[2] * dz if t[2] > 0 else np.array([0.0, 0.0, dz])        # depth change along the ray
        t += step
        if np.linalg.norm(step) < 1e-3:
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
        std = model.settings.coeff_std
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
        # and the rotation grid of a bins head
        self.class_weighted = [self.cfg.class_weight * P for P in self.class_prec]
        self.class_weighted_mean = [P @ a for P, a in zip(self.class_weighted, self.class_mean)]
        self.bin_grid = (model.net.bin_rotations.double().numpy() if model.net.cfg.rotation == "bins" else None)

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
        "grid" (30^3 bool, under the model's completion rule), "grid_paper" (the same coefficients at 0.5, the
        paper's rule), "score", "n_hypotheses", "agreement" (:func:`depth_agreement` of the best hypothesis'
        completion at 0.5 rendered at its pose), "kept_network" (agreement below
        ``min_agreement``: the answer is HBEO's own), "stride" (:func:`working_view`'s s), "ms"}."""
        t0 = time.perf_counter()
        cfg, model = self.cfg, self.model
        stride = working_stride(intrinsics, model.intrinsics)
        depth, intrinsics = working_view(depth, intrinsics, model.intrinsics)
        Rs, log_pr = self.hypotheses_rotations(pred, i)
        probs = np.asarray(pred.probabilities[i], np.float64)
        top = np.argsort(-probs)[:cfg.classes]
        o_net = np.asarray(pred.coeffs[i], np.float64)
        P_net = 1.0 / (cfg.prior_scale * self.coeff_std) ** 2                          # (k,)
        size = model.settings.object_size * float(pred.scale[i])
        scores = np.full((len(Rs), len(top)), -np.inf)
        coeffs = np.zeros((len(Rs), len(top), self.k))
        ts = np.repeat(np.asarray(pred.translation[i], np.float64)[None], len(Rs), axis=0)
        if cfg.refine_translation:
            # the network's shape at the paper's 0.5, whatever the model's completion rule: the rule changes the
            # answered grid only, not the search
            pts = surface_points(model.paper_grids(pred.coeffs[i][None])[0], size)
            ts = np.stack([align_translation(depth, R, ts[0], pts, intrinsics) for R in Rs])
        with one_blas_thread():
            for r in range(len(Rs)):                         # each rotation carved at its own translation
                for rep in range(1 + (cfg.realign if cfg.refine_translation else 0)):
                    if rep:                                   # the best completion at this rotation, aligned
                        best_o = coeffs[r, int(np.argmax(scores[r]))]
                        shape = model.subspace.reconstruct(best_o[None].astype(np.float32), threshold=0.5)[0]
                        ts[r] = align_translation(depth, Rs[r], ts[r], surface_points(shape, size), intrinsics)
                    scores[r], coeffs[r] = self._solve(depth, intrinsics, Rs[r], ts[r], size, top, probs, o_net,
                                                       P_net, log_pr[r])
        r, ci = np.unravel_index(int(np.argmax(scores)), scores.shape)
        if len(top) > 1:                                 # the classes' best posteriors, normalized
            best = np.full(len(probs), -np.inf)
            best[top] = scores.max(axis=0)
            out_probs = np.exp(best - logsumexp(best))
        else:                                            # one class tried: the network's probabilities stand
            out_probs = probs
        o = coeffs[r, ci].astype(np.float32)
        grid = model.subspace.reconstruct(o[None], threshold=0.5)[0]
        agree = depth_agreement(depth, shape_depth(surface_points(grid, size), Rs[r], ts[r], intrinsics),
                                cfg.agreement_tol * size / OBJECT_VOXELS) if grid.any() else 0.0
        out = {"probabilities": out_probs, "label": int(top[ci]), "rotation": Rs[r], "translation": ts[r],
               "coeffs": o, "grid": grid, "score": float(scores[r, ci]), "n_hypotheses": int(scores.size),
               "agreement": agree, "kept_network": agree < cfg.min_agreement,
               "stride": stride}
        if out["kept_network"]:                          # unsure: HBEO's own answer, as if not verified
            out.update(probabilities=np.asarray(pred.probabilities[i], np.float64), label=int(pred.labels[i]),
                       rotation=pred.rotation[i], translation=pred.translation[i],
                       coeffs=np.asarray(pred.coeffs[i], np.float32), grid=pred.grids[i])
            out["grid_paper"] = model.paper_grids(out["coeffs"][None])[0]
        else:                                            # the model's completion rule (the agreement used 0.5's)
            out["grid_paper"] = grid
            out["grid"] = model.complete(o[None], [out["label"]])[0]
        out["ms"] = (time.perf_counter() - t0) * 1e3
        return out

    def _solve(self, depth, intrinsics, R, t, size, top, probs, o_net, P_net, log_pr) -> tuple[np.ndarray, np.ndarray]:
        """One rotation's hypotheses: the view carved at (R, t), the MAP coefficients of each class of
        ``top`` and their log posteriors -> (scores (len(top),), coefficients (len(top), k))."""
        cfg, s2 = self.cfg, self.cfg.noise_var
        scores, coeffs = np.full(len(top), -np.inf), np.zeros((len(top), self.k))
        _, f, kn, outside = next(iter_partial(depth, intrinsics, R[None], t, size, chunk=1))
        (A,), (b,), (nf,) = self.projector.normal_equations(f, kn)
        for ci, c in enumerate(top):
            H = A / s2 + self.class_weighted[c]
            H[np.diag_indices(self.k)] += P_net
            rhs = b / s2 + P_net * o_net + self.class_weighted_mean[c]
            o = cho_solve(cho_factor(H, check_finite=False), rhs, check_finite=False)
            sse = max(0.0, nf - 2 * b @ o + o @ A @ o) + outside[0]
            dn, dc = o - o_net, o - self.class_mean[c]
            scores[ci] = (-sse / (2 * s2) - 0.5 * dn @ (P_net * dn)
                          - cfg.class_weight * 0.5 * (dc @ self.class_prec[c] @ dc + self.class_logdet[c])
                          + cfg.net_weight * (np.log(max(probs[c], 1e-12)) + log_pr))
            coeffs[ci] = o
        return scores, coeffs

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
                       verified=[{"agreement": round(float(x["agreement"]), 6), "kept_network": bool(x["kept_network"]),
                                  "n_hypotheses": x["n_hypotheses"], "stride": x["stride"]} for x in res],
                       timing_ms={**pred.timing_ms, "verify": sum(x["ms"] for x in res),
                                  "total": pred.timing_ms.get("total", 0.0) + sum(x["ms"] for x in res)})
