"""From a run folder to a trained model file: the glue between rendering, training and `HBEO`.

:func:`fit_model` reads the run's rendered training set (``render_train/``, notebook 03) and
subspace (``subspace.npz``, notebook 02), brings every image into the model's input view
exactly as :meth:`hbeo.model.inference.HBEO.predict` will (:mod:`hbeo.model.preprocess`), standardizes the
coefficient targets, splits by object into training and validation, trains HBEONet
(:mod:`hbeo.model.train`) and writes ``model.hbeo``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, Subset
from tqdm.auto import tqdm

from hbeo import config
from hbeo.model.augment import RollAugment
from hbeo.conventions import rotation_to_axis_angle
from hbeo.model.inference import HBEO
from hbeo.model.network import LossWeights, NetConfig
from hbeo.model.preprocess import to_model_view
from hbeo.render.renderset import Manifest, load_shard, split_by_object, subspace_info
from hbeo.subspace.basis import ObjectSubspace
from hbeo.model.train import TrainConfig, train


@dataclass
class ViewOptions:
    """How images enter the network (the same at training and prediction time).

    recenter: turn each view to look straight at the object; ref_distance: zoom and shift so the
    object centre appears at this many metres (distance-insensitive input). The paper does
    neither (its renderings are centred already).
    """

    recenter: bool = False
    ref_distance: float | None = None


class ViewArrays(Dataset):
    """A rendered set held in memory, in the model's input view. Items as :class:`DepthShards`."""

    def __init__(self, manifest, opts: ViewOptions, coeff_mean=None, coeff_std=None, progress=True):
        m = Manifest.load(manifest)
        K = m.settings.intrinsics
        depth, rot, lab, coeffs, objs = [], [], [], [], []
        for path in tqdm(m.shard_paths(), desc="load views", disable=not progress):
            sh = load_shard(path)
            d, R = sh["depth"].astype(np.float32), sh["rotation"].astype(np.float64)
            if opts.recenter or opts.ref_distance:
                for i in np.flatnonzero((d > 0).reshape(len(d), -1).any(1)):
                    # views that show nothing (a handful of degenerate grids seen edge-on) stay empty
                    v = to_model_view(d[i], K, K, recenter=opts.recenter, ref_distance=opts.ref_distance)
                    d[i], R[i] = v.depth, v.Q.T @ R[i]
            depth.append(d.astype(np.float16))
            rot.append(R.astype(np.float32))
            lab.append(sh["label"])
            objs.append(sh["object_index"])
            if "coeffs" not in sh:
                raise ValueError(f"{m.root}: the rendered set has no subspace coefficients; render it with "
                                 f"the run's subspace (notebook 02 first)")
            coeffs.append(sh["coeffs"])
        self.depth, self.rotation = np.concatenate(depth), np.concatenate(rot)
        self.axis_angle = rotation_to_axis_angle(self.rotation).astype(np.float32)
        self.labels, self.object_index = np.concatenate(lab), np.concatenate(objs)
        self.coeffs_raw = np.concatenate(coeffs).astype(np.float32)
        self.coeff_mean = self.coeffs_raw.mean(0) if coeff_mean is None else np.asarray(coeff_mean, np.float32)
        self.coeff_std = (self.coeffs_raw.std(0) + 1e-6) if coeff_std is None else np.asarray(coeff_std, np.float32)
        self.coeffs = ((self.coeffs_raw - self.coeff_mean) / self.coeff_std).astype(np.float32)
        self.manifest = m

    def __len__(self):
        return len(self.depth)

    def __getitem__(self, i):
        return {"depth": torch.from_numpy(self.depth[i].astype(np.float32))[None], "label": int(self.labels[i]),
                "rotation": torch.from_numpy(self.rotation[i]), "axis_angle": torch.from_numpy(self.axis_angle[i]),
                "coeffs": torch.from_numpy(self.coeffs[i]), "object_index": int(self.object_index[i])}


def fit_model(run, profile, epochs: int | None = None, rotation: str = "axis_angle", normalization: str = "none",
              view: ViewOptions | None = None, val_fraction: float = 0.1, seed: int = 0,
              out_name: str = "model.hbeo", progress: bool = True,
              loss: LossWeights | None = None, augment_roll: bool = False) -> tuple[HBEO, Path]:
    """Train on ``run/render_train`` with ``run/subspace.npz``; writes ``run/<out_name>`` and
    returns the model and its path. Checkpoints go to ``run/train_<stem>/`` (resumable).
    ``loss``: the weights gamma_c, gamma_o, gamma_p of the paper's loss (default 1, 1, 1).
    ``augment_roll``: roll every training view by a random angle about the optical axis each
    epoch (:mod:`hbeo.model.augment`; exact, for uniform SO(3) views; not in the paper)."""
    run = Path(run)
    prof = config.get_profile(profile)
    view = view or ViewOptions()
    sub = ObjectSubspace.load(run / "subspace.npz")
    data = ViewArrays(run / "render_train", view, progress=progress)
    m = data.manifest
    rendered_with = (m.data.get("subspace") or {}).get("basis_sha256")
    if rendered_with != subspace_info(sub)["basis_sha256"]:
        raise ValueError(f"{run / 'render_train'} was rendered with another subspace than {run / 'subspace.npz'}; "
                         f"render it again (notebook 03)")
    tr_idx, va_idx = split_by_object(m, val_fraction, seed)
    cfg = NetConfig(image_size=tuple(m.settings.image_size), n_classes=len(m.classes), n_coeffs=sub.dim_,
                    conv_channels=tuple(prof.conv_channels), fc=tuple(prof.fc), kernel=prof.kernel, rotation=rotation,
                    normalization=normalization)
    tc = TrainConfig(epochs=epochs or prof.epochs, batch_size=prof.batch_size, lr=prof.lr, seed=seed,
                     progress=progress, warmup_steps=min(100, max(1, len(tr_idx) // prof.batch_size)),
                     loss=loss or LossWeights(), data={"augment_roll": augment_roll, "recenter": view.recenter,
                                                      "ref_distance": view.ref_distance})
    train_set = Subset(data, tr_idx)
    if augment_roll:
        train_set = RollAugment(train_set, m.settings.intrinsics)
    net = train(cfg, train_set, Subset(data, va_idx), run / f"train_{Path(out_name).stem}", tc)
    settings = {"object_size": m.settings.object_size, "recenter": view.recenter, "ref_distance": view.ref_distance,
                "coeff_mean": data.coeff_mean, "coeff_std": data.coeff_std, "render": m.settings.to_dict(),
                "profile": prof.name, "augment_roll": augment_roll}
    model = HBEO(net.cpu(), sub, m.settings.intrinsics, m.classes, settings)
    return model, model.save(run / out_name)

