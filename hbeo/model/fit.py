"""From a run folder to a trained model file: the glue between rendering, training and `HBEO`.

:func:`fit_model` checks that the run's rendered training set (``RunDir.renders("train")``,
notebook 03) was made with the run's subspace (``RunDir.subspace``, notebook 02), gets the
training and validation data from :func:`training_data`, trains HBEONet through the project's
loop (:func:`hbeo.model.train.train` with :class:`HBEONetTask`) and writes the model file
(``RunDir.model_file``).

:func:`training_data` is the one place the rendered set becomes datasets: today every image is
held in memory (:class:`ViewArrays`), brought into the model's input view exactly as
:meth:`hbeo.model.inference.HBEO.predict` will (:mod:`hbeo.model.preprocess`), with standardized
coefficient targets, split by object into training and validation; streaming shards would
replace that function only.

May import: foundation, data, subspace, render, and the other hbeo.model modules.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, Subset
from tqdm.auto import tqdm

from hbeo import config
from hbeo.errors import DataError
from hbeo.model.augment import RollAugment
from hbeo.model.inference import HBEO
from hbeo.model.network import HBEONet, LossWeights, NetConfig, hbeo_loss
from hbeo.model.preprocess import to_model_view
from hbeo.model.train import TrainConfig, train
from hbeo.render.datasets import load_shard, split_by_object
from hbeo.render.renderset import Manifest, subspace_info
from hbeo.rotations import geodesic_deg, matrix_to_axis_angle
from hbeo.rundir import RunDir
from hbeo.subspace.basis import ObjectSubspace


@dataclass
class ViewOptions:
    """How images enter the network (the same at training and prediction time).

    recenter: turn each view to look straight at the object; ref_distance: zoom and shift so the
    object centre appears at this many metres (distance-insensitive input). The paper does
    neither (its renderings are centred already).
    """

    recenter: bool = False
    ref_distance: float | None = None


# --------------------------------------------------------------------------- HBEONet for the loop

@dataclass
class HBEONetTask:
    """HBEONet for :func:`hbeo.model.train.train`: the paper's loss (:func:`hbeo.model.network.hbeo_loss`
    with ``weights``) on batches of :class:`ViewArrays` items (``depth`` (B, 1, H, W) metres,
    ``label`` (B,), ``rotation`` (B, 3, 3), ``axis_angle`` (B, 3), ``coeffs`` (B, k) standardized).
    Validation: mean loss parts, accuracy and median geodesic pose error (degrees)."""

    net_cfg: NetConfig
    weights: LossWeights = field(default_factory=LossWeights)
    kind = "hbeonet"
    unit = "images"

    def config(self) -> dict:
        return {"net": self.net_cfg.to_dict(), "loss": asdict(self.weights)}

    def build(self) -> HBEONet:
        return HBEONet(self.net_cfg).to(memory_format=torch.channels_last)

    def loss(self, net: HBEONet, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        out = net(batch["depth"].contiguous(memory_format=torch.channels_last))
        return hbeo_loss(out, batch, self.net_cfg, self.weights, 1.0, getattr(net, "bin_rotations", None))

    def validate(self, net: HBEONet, batches) -> dict[str, float]:
        sums, n, correct, errors = {"loss": 0.0, "ce": 0.0, "pose": 0.0, "coeff": 0.0}, 0, 0, []
        for batch in batches:
            out = net(batch["depth"])
            loss, parts = hbeo_loss(out, batch, self.net_cfg, self.weights, 1.0, getattr(net, "bin_rotations", None))
            b = len(batch["label"])
            sums["loss"] += loss.item() * b
            for k, v in parts.items():
                sums[k] += v * b
            n += b
            correct += int((out["logits"].argmax(1) == batch["label"]).sum())
            R = net.pose_matrix(out["pose"].float()).cpu().numpy()
            errors.append(geodesic_deg(R, batch["rotation"].cpu().numpy()))
        if n == 0:
            return {}
        return {**{k: v / n for k, v in sums.items()}, "accuracy": correct / n,
                "pose_median_deg": float(np.median(np.concatenate(errors)))}


# --------------------------------------------------------------------------- the data

class ViewArrays(Dataset):
    """A rendered set held in memory, in the model's input view. Items: ``depth`` (1, H, W) float32
    metres, ``label``, ``rotation`` (3, 3) and ``axis_angle`` (3,) in the input view's camera,
    ``coeffs`` (k,) standardized with ``coeff_mean`` / ``coeff_std``, ``object_index``."""

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
                raise DataError(m.root, "the rendered set has no subspace coefficients; render it with the "
                                        "run's subspace (notebook 02 first)")
            coeffs.append(sh["coeffs"])
        self.depth, self.rotation = np.concatenate(depth), np.concatenate(rot)
        self.axis_angle = matrix_to_axis_angle(self.rotation).astype(np.float32)
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


@dataclass
class TrainingData:
    """What :func:`training_data` returns: the two datasets, the rendered set's manifest and the
    coefficient standardization (mean, std (k,)) the model must undo at prediction time."""

    train: Dataset
    val: Dataset
    manifest: Manifest
    coeff_mean: np.ndarray
    coeff_std: np.ndarray


def training_data(run, view: ViewOptions, val_fraction: float = 0.1, seed: int = 0, augment_roll: bool = False,
                  progress: bool = True) -> TrainingData:
    """The run's rendered training set as (training, validation) datasets, split by object
    (:func:`hbeo.render.datasets.split_by_object`): all images in memory (:class:`ViewArrays`);
    ``augment_roll`` rolls every training view by a random angle each time it is read (:class:`RollAugment`)."""
    data = ViewArrays(RunDir.of(run).renders("train"), view, progress=progress)
    tr_idx, va_idx = split_by_object(data.manifest, val_fraction, seed)
    train_set = Subset(data, tr_idx)
    if augment_roll:
        train_set = RollAugment(train_set, data.manifest.settings.intrinsics)
    return TrainingData(train_set, Subset(data, va_idx), data.manifest, data.coeff_mean, data.coeff_std)


# --------------------------------------------------------------------------- run folder -> model file

def fit_model(run, profile, epochs: int | None = None, rotation: str = "axis_angle", normalization: str = "none",
              view: ViewOptions | None = None, val_fraction: float = 0.1, seed: int = 0,
              out_name: str | None = None, progress: bool = True,
              loss: LossWeights | None = None, augment_roll: bool = False,
              max_steps: int | None = None) -> tuple[HBEO, Path]:
    """Train on the run's rendered training set with its subspace; writes the model file
    ``out_name`` (``RunDir.model_file``; None: the run's default model) into ``run`` (a RunDir or a
    path) and returns the model and its path. Checkpoints go to ``RunDir.training(out_name)`` (a rerun resumes exactly).
    ``loss``: the weights gamma_c, gamma_o, gamma_p of the paper's loss (default 1, 1, 1).
    ``augment_roll``: roll every training view by a random angle about the optical axis each
    epoch (:mod:`hbeo.model.augment`; exact, for uniform SO(3) views; not in the paper).
    ``max_steps``: stop after that many optimizer steps (the schedule ends there)."""
    run = RunDir.of(run)
    prof = config.get_profile(profile)
    view = view or ViewOptions()
    model_path = run.model_file(out_name)
    sub = ObjectSubspace.load(run.subspace)
    rendered_with = (Manifest.load(run.renders("train")).data.get("subspace") or {}).get("basis_sha256")
    if rendered_with != subspace_info(sub)["basis_sha256"]:
        raise DataError(run.renders("train"), f"rendered with another subspace than {run.subspace}; render it "
                                              f"again (notebook 03)")
    data = training_data(run, view, val_fraction, seed, augment_roll, progress)
    m = data.manifest
    cfg = NetConfig(image_size=tuple(m.settings.image_size), n_classes=len(m.classes), n_coeffs=sub.dim_,
                    conv_channels=tuple(prof.conv_channels), fc=tuple(prof.fc), kernel=prof.kernel, rotation=rotation,
                    normalization=normalization)
    tc = TrainConfig(epochs=epochs or prof.epochs, batch_size=prof.batch_size, lr=prof.lr, seed=seed,
                     progress=progress, warmup_steps=min(100, max(1, len(data.train) // prof.batch_size)),
                     max_steps=max_steps, data={"augment_roll": augment_roll, "recenter": view.recenter,
                                                "ref_distance": view.ref_distance, "val_fraction": val_fraction})
    net = train(HBEONetTask(cfg, loss or LossWeights()), data.train, data.val, run.training(model_path), tc)
    settings = {"object_size": m.settings.object_size, "recenter": view.recenter, "ref_distance": view.ref_distance,
                "coeff_mean": data.coeff_mean, "coeff_std": data.coeff_std, "render": m.settings.to_dict(),
                "profile": prof.name, "augment_roll": augment_roll}
    model = HBEO(net.cpu(), sub, m.settings.intrinsics, m.classes, settings)
    return model, model.save(model_path)
