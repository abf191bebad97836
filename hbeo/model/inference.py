"""`HBEO`: one file holding a trained model, and the inference API.

The bundle holds HBEONet (configuration and weights), the object subspace, the model's
camera (intrinsics of the images it was trained on), class names and preprocessing
settings. ``predict(depth, intrinsics, mask=None)`` takes a user's depth image (metres,
0 = none) with its own intrinsics, brings it into the model's camera
(:mod:`hbeo.model.preprocess`), runs the network and back-projects the coefficients to a 30^3
grid. Poses come back in the user's camera frame (R: object -> camera, see
:mod:`hbeo.conventions`). The file format (``.hbeo``, never unpickled) is
:mod:`hbeo.model.modelfile`'s.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from hbeo.model.augment import roll_depth
from hbeo.conventions import Intrinsics
from hbeo.rotations import matrix_to_axis_angle, z_angle_to_matrix
from hbeo.errors import DataError
from hbeo.model.modelfile import read_model, write_model
from hbeo.model.network import HBEONet, NetConfig, bin_cosines
from hbeo.model.preprocess import to_model_view
from hbeo.subspace.basis import ObjectSubspace

#: inference precisions: float32 (default, exact) or bfloat16 (network weights and activations;
#: ~2.5x faster convolutions on CPUs with AVX512-BF16; class agreement with float32 ~99 %, see
#: benchmarks/README.md). The back-projection stays float32.
PRECISIONS = {"float32": torch.float32, "bfloat16": torch.bfloat16}


def _build_net(cfg: dict) -> HBEONet:
    """The HBEONet a model file's ``net_cfg`` describes (JSON lists back to tuples)."""
    return HBEONet(NetConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.items()}))


@dataclass
class Prediction:
    """Outputs for a batch of B images (arrays lead with B)."""

    probabilities: np.ndarray     #: (B, C) class probabilities
    labels: np.ndarray            #: (B,) class indices
    class_names: list[str]        #: (B,)
    rotation: np.ndarray          #: (B, 3, 3) object -> user camera
    axis_angle: np.ndarray        #: (B, 3) radians
    translation: np.ndarray       #: (B, 3) estimated object centre, user camera frame, metres
    scale: np.ndarray             #: (B,) metres per training object_size unit (1 without distance normalization)
    coeffs: np.ndarray            #: (B, k) subspace coefficients
    grids: np.ndarray             #: (B, 30, 30, 30) bool completed shapes (canonical frame)
    timing_ms: dict = field(default_factory=dict)   #: per stage, whole batch

    def to_dict(self, i: int = 0) -> dict:
        """JSON-ready summary of image ``i``."""
        return {"class": self.class_names[i], "label": int(self.labels[i]),
                "probabilities": self.probabilities[i].round(6).tolist(),
                "rotation": self.rotation[i].round(6).tolist(), "axis_angle": self.axis_angle[i].round(6).tolist(),
                "translation_m": self.translation[i].round(6).tolist(), "scale": float(self.scale[i]),
                "coeffs": self.coeffs[i].round(6).tolist(), "occupied_voxels": int(self.grids[i].sum()),
                "timing_ms": {k: round(v, 3) for k, v in self.timing_ms.items()}}


class HBEO:
    """A trained model: network + subspace + camera + classes + preprocessing settings.

    settings: ``object_size`` (m, training objects' longest side), ``recenter`` (turn the view
    to the object), ``ref_distance`` (m or None: distance normalization), and optional
    ``coeff_mean`` / ``coeff_std`` (k,) with which the network's coefficient output is
    de-standardized.
    """

    def __init__(self, net: HBEONet, subspace: ObjectSubspace, intrinsics: Intrinsics, classes,
                 settings: dict | None = None, precision: str = "float32"):
        # channels_last: oneDNN's fast convolution layout on CPU (convolutions ~1.7x faster at 320x240)
        self.net = net.eval().to(memory_format=torch.channels_last)
        self.subspace = subspace
        self.intrinsics = intrinsics
        self.classes = tuple(classes)
        self.settings = {"object_size": 1.0, "recenter": True, "ref_distance": None, **(settings or {})}
        if net.cfg.n_coeffs != subspace.dim_:
            raise ValueError(f"network predicts {net.cfg.n_coeffs} coefficients, the subspace has {subspace.dim_}")
        if net.cfg.n_classes != len(self.classes):
            raise ValueError(f"network has {net.cfg.n_classes} classes, {len(self.classes)} names given")
        if tuple(net.cfg.image_size) != (intrinsics.width, intrinsics.height):
            raise ValueError(f"network input {net.cfg.image_size} does not match the camera "
                             f"{intrinsics.width}x{intrinsics.height}")
        self._roll_perms: dict = {}
        self.set_precision(precision)

    def set_precision(self, precision: str) -> "HBEO":
        """Run the network in ``float32`` or ``bfloat16`` (:data:`PRECISIONS`); returns self.

        ``self.net`` keeps its float32 weights (they are what :meth:`save` writes); predictions use a
        copy whose layers hold ``precision`` weights (made now: change the weights first). The
        rotation-bin grid and all outputs stay float32 or better."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {tuple(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        self._net = self.net
        if precision != "float32":
            self._net = copy.deepcopy(self.net)
            for m in self._net.modules():
                if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear, torch.nn.BatchNorm2d)):
                    m.to(PRECISIONS[precision])
        return self

    # ------------------------------------------------------------ persistence
    def save(self, path) -> Path:
        """Write the model to one file, atomically (:mod:`hbeo.model.modelfile`; float32 weights
        whatever the precision)."""
        meta = {"net_cfg": self.net.cfg.to_dict(), "classes": list(self.classes),
                "intrinsics": asdict(self.intrinsics), "settings": self.settings}
        return write_model(path, "hbeo", meta, self.net.state_dict(), self.subspace)

    @classmethod
    def load(cls, path, precision: str = "float32") -> "HBEO":
        """Read a model file (:func:`hbeo.model.modelfile.read_model`: nothing is unpickled) onto the
        CPU; DataError naming the file on a missing, corrupt, old-format or inconsistent one.
        ``precision``: see :meth:`set_precision`."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {tuple(PRECISIONS)}, got {precision!r}")
        mf = read_model(path, "hbeo", _build_net)
        m = mf.meta
        try:
            return cls(mf.net, mf.subspace, Intrinsics(**m["intrinsics"]), m["classes"], m["settings"], precision)
        except (TypeError, ValueError) as err:
            raise DataError(path, f"inconsistent model file ({err})") from None

    # ------------------------------------------------------------ inference
    @torch.inference_mode()
    def predict(self, depth, intrinsics: Intrinsics, mask=None, rolls: int = 1) -> Prediction:
        """Depth (H, W) or (B, H, W), metres, 0 = none, seen by ``intrinsics`` -> :class:`Prediction`.

        ``mask`` (same shape, bool) selects the object's pixels (default: all pixels > 0).
        ``rolls`` > 1 (rotation-bins models only): test-time augmentation over that many camera rolls
        about the optical axis (exact, :mod:`hbeo.model.augment`), ``rolls`` times the network's cost: the
        class probabilities and coefficients (roll-invariant) are averaged, and each roll's rotation
        distribution is turned back and averaged before decoding.
        """
        t0 = time.perf_counter()
        if int(rolls) != rolls or rolls < 1:
            raise ValueError(f"rolls must be a positive integer, got {rolls!r}")
        if rolls > 1 and self.net.cfg.rotation != "bins":
            raise ValueError(f"rolls > 1 needs a rotation-bins model; this one regresses {self.net.cfg.rotation}")
        depth = np.asarray(depth)
        batch = depth[None] if depth.ndim == 2 else depth
        masks = [None] * len(batch) if mask is None else (np.asarray(mask)[None] if np.ndim(mask) == 2 else mask)
        if len(masks) != len(batch):
            raise ValueError(f"{len(masks)} masks for {len(batch)} depth images")
        s = self.settings
        views = [to_model_view(d, intrinsics, self.intrinsics, m, recenter=s["recenter"],
                               ref_distance=s["ref_distance"]) for d, m in zip(batch, masks)]
        x = np.stack([v.depth for v in views])
        angles = [2 * math.pi * k / rolls for k in range(rolls)]
        x = np.concatenate([x] + [np.stack([roll_depth(d, self.intrinsics, a) for d in x]) for a in angles[1:]])
        x = torch.from_numpy(x[:, None]).to(PRECISIONS[self.precision]).contiguous(memory_format=torch.channels_last)
        t1 = time.perf_counter()
        out = {k: v.float().view(rolls, len(views), -1) for k, v in self._net(x).items()}
        t2 = time.perf_counter()
        probs = torch.softmax(out["logits"], dim=2).mean(0).numpy()
        if rolls == 1:
            R_virtual = self.net.pose_matrix(out["pose"][0].double()).numpy()
        else:
            p = torch.softmax(out["pose"].double(), dim=2)
            P = sum(p[k][:, self._roll_permutation(a)] for k, a in enumerate(angles)) / rolls
            R_virtual = self.net.pose_matrix(torch.log(P.clamp_min(1e-300))).numpy()
        out["coeffs"] = out["coeffs"].mean(0)
        Q = np.stack([v.Q for v in views])
        R = Q @ R_virtual
        coeffs = out["coeffs"].numpy().astype(np.float64)
        if s.get("coeff_std") is not None:
            coeffs = coeffs * np.asarray(s["coeff_std"]) + np.asarray(s["coeff_mean"])
        grids = self.subspace.reconstruct(coeffs.astype(np.float32), threshold=0.5)
        t3 = time.perf_counter()
        scale = np.array([v.distance / s["ref_distance"] if s["ref_distance"] else 1.0 for v in views])
        trans = np.stack([v.center / np.linalg.norm(v.center) * v.distance for v in views])
        labels = probs.argmax(1)
        return Prediction(probs, labels, [self.classes[i] for i in labels], R, matrix_to_axis_angle(R), trans,
                          scale, coeffs, grids, {"preprocess": (t1 - t0) * 1e3, "network": (t2 - t1) * 1e3,
                                                 "reconstruct": (t3 - t2) * 1e3, "total": (t3 - t0) * 1e3})

    def _roll_permutation(self, angle: float) -> torch.Tensor:
        """(N,) index of the grid rotation nearest Rz(angle) G_j for each bin j (cached): a view rolled by
        ``angle`` sees the object at Rz(angle) R, so its probability for R = G_j sits at that bin."""
        cache = self._roll_perms
        key = round(angle, 12)
        if key not in cache:
            G = self.net.bin_rotations.float()
            RG = torch.from_numpy(z_angle_to_matrix(angle)).float() @ G
            cache[key] = torch.cat([bin_cosines(RG[i:i + 512], G).argmax(1) for i in range(0, len(G), 512)])
        return cache[key]

    def to_mesh(self, pred: Prediction, i: int = 0):
        """The completed shape of image ``i`` as a trimesh mesh placed in the user's camera frame
        (metres): grid surface, scaled, rotated by the predicted pose, moved to the estimated centre."""
        from hbeo.render.renderer import grid_mesh
        if not pred.grids[i].any():
            raise ValueError("the completed grid is empty (no coefficient combination above 0.5)")
        mesh = grid_mesh(pred.grids[i], object_size=self.settings["object_size"] * float(pred.scale[i]))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = pred.rotation[i], pred.translation[i]
        mesh.apply_transform(T)
        return mesh
