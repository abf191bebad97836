"""From a run folder to a trained model file: the glue between rendering, training and `HBEO`.

:func:`fit_model` checks that the run's rendered training set (``RunDir.renders("train")``,
notebook 03) was made with the run's subspace (``RunDir.subspace``, notebook 02), gets the
training and validation data from :func:`~hbeo.model.trainingdata.training_data`, trains HBEONet through the project's
loop (:func:`hbeo.model.loop.train` with :class:`HBEONetTask`) and writes the model file
(``RunDir.model_file``).

The training images come from :func:`hbeo.model.trainingdata.training_data` (memory, shards or stream).

May import: foundation, data, subspace, render, and the other hbeo.model modules.
"""
from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch

from hbeo.errors import DataError
from hbeo.model.inference import HBEO
from hbeo.model.network import HBEONet, LossWeights, NetConfig, check_network, hbeo_loss
from hbeo.model import distributed
from hbeo.model.loop import TrainConfig, ValidationMeans, train
from hbeo.model.modelmeta import SHAPE_LOSSES
from hbeo.render.renderset import Manifest, subspace_info
from hbeo.render.views import RenderSettings
from hbeo.rotations import geodesic_deg
from hbeo.rundir import DEFAULT_MODEL, RunDir
from hbeo.subspace.basis import ObjectSubspace
from hbeo.model.trainingdata import (CLASS_BALANCE, DATA_SOURCES, ClassBalanced, ViewOptions, class_weights,
                                    training_data)




# --------------------------------------------------------------------------- HBEONet for the loop


@dataclass
class HBEONetTask:
    """HBEONet for :func:`hbeo.model.loop.train`: the paper's loss (:func:`hbeo.model.network.hbeo_loss`
    with ``weights``) on batches of :class:`ViewArrays` items (``depth`` (B, 1, H, W) metres,
    ``label`` (B,), ``rotation`` (B, 3, 3), ``axis_angle`` (B, 3), ``coeffs`` (B, k) standardized).
    Validation: mean loss parts, accuracy and median geodesic pose error (degrees).
    ``coeff_std`` (k,): the targets' standard deviations, given for the ``voxels`` shape loss
    (:data:`~hbeo.model.modelmeta.SHAPE_LOSSES`): the coefficient error is then measured on raw coefficients.
    ``class_weights`` (C,): the cross-entropy's class weights (the ``loss`` class balance,
    :func:`class_weights`); None: unweighted, the paper's."""

    net_cfg: NetConfig
    weights: LossWeights = field(default_factory=LossWeights)
    coeff_std: np.ndarray | None = None
    class_weights: tuple | None = None
    _on_device: dict = field(default_factory=dict, init=False, repr=False, compare=False)   # :meth:`_kept`'s
    kind = "hbeonet"
    unit = "images"

    def config(self) -> dict:
        cfg = {"net": self.net_cfg.to_dict(), "loss": asdict(self.weights)}
        if self.coeff_std is not None:          # the paper's loss keeps the configuration it always had
            cfg["shape_loss"] = "voxels"
        if self.class_weights is not None:      # likewise: unweighted runs keep theirs
            cfg["class_weights"] = [float(x) for x in self.class_weights]
        return cfg

    def _kept(self, name: str, like: torch.Tensor, make):
        """``make(device, dtype)`` (a tensor) for ``like``'s device and dtype, kept after its first use: a host
        array copied to a GPU every step is a copy the host waits for (torch synchronises a blocking
        host-to-device copy), so each step would wait for the previous one's kernels."""
        key = (name, str(like.device), like.dtype)
        if key not in self._on_device:
            self._on_device[key] = make(like.device, like.dtype)
        return self._on_device[key]

    def _class_weights(self, like: torch.Tensor):
        """The cross-entropy's class weights on ``like``'s device in its dtype; None: unweighted."""
        if self.class_weights is None:
            return None
        return self._kept("class_weights", like, lambda device, dtype: torch.as_tensor(
            self.class_weights, dtype=torch.float32).to(device, dtype))

    def _scale(self, like: torch.Tensor):
        """Divisor of the standardized coefficient error: 1 (paper) or rms(std) / std (raw coefficients,
        rescaled: :data:`~hbeo.model.modelmeta.SHAPE_LOSSES`), on ``like``'s device in its dtype."""
        if self.coeff_std is None:
            return 1.0

        def make(device, dtype):
            std = torch.as_tensor(self.coeff_std, dtype=dtype, device=device)
            return std.square().mean().sqrt() / std
        return self._kept("scale", like, make)

    def build(self) -> HBEONet:
        return HBEONet(self.net_cfg).to(memory_format=torch.channels_last)

    def loss(self, net: HBEONet, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        out = net(batch["depth"].contiguous(memory_format=torch.channels_last))
        return hbeo_loss(out, batch, self.net_cfg, self.weights, self._scale(out["coeffs"]),
                         getattr(net, "bin_rotations", None), self._class_weights(out["logits"]))

    def validate(self, net: HBEONet, batches) -> dict[str, float]:
        means, errors = ValidationMeans(), []
        for batch in batches:
            out = net(batch["depth"])
            loss, parts = hbeo_loss(out, batch, self.net_cfg, self.weights, self._scale(out["coeffs"]),
                                    getattr(net, "bin_rotations", None), self._class_weights(out["logits"]))
            means.add(loss, parts, out["logits"], batch["label"])
            R = net.pose_matrix(out["pose"].float()).cpu().numpy()
            errors.append(geodesic_deg(R, batch["rotation"].cpu().numpy()))
        if means.n == 0:
            return {}
        return {**means.means(), "pose_median_deg": float(np.median(np.concatenate(errors)))}


# --------------------------------------------------------------------------- run folder -> model file

@dataclass(frozen=True)
class TrainOptions:
    """How to train a run's model (``python -m hbeo train``'s options), one default per field; ``None``
    means "the profile's": ``epochs``, the recipe (``rotation``, ``augment_roll``, ``shape_loss``:
    :meth:`hbeo.config.RecipeConfig.fit_kwargs`), the data source ``data`` (:data:`DATA_SOURCES`) and
    ``class_balance`` (:data:`CLASS_BALANCE`; the profile's :attr:`~hbeo.config.RecipeConfig.class_balance`).

    normalization: depth input ``none`` (metres, the paper) or ``center``; view: :class:`ViewOptions`;
    sampler / views / backend: the training views' sampler, views per object and render backend (render
    settings; ``torch`` with ``data="stream"``: batches rendered on the training device); loss: the
    weights gamma_c, gamma_o, gamma_p of the paper's loss; fc: the widths of HBEONet's three shared fully
    connected layers (None: the profile's :attr:`hbeo.config.NetworkConfig.fc`); val_fraction: objects held
    out for validation;
    seed: the training seed (initial weights, batch order, augmentation; None: the run's,
    :attr:`hbeo.run.Run.training_seed`, 0 unless asked, and 0 outside a Run); name: the model file in
    the run folder; max_steps: stop after that many optimizer steps (the schedule ends there);
    checkpoint_every: also checkpoint every that many steps; loader_workers: DataLoader worker processes
    (0: in this process); render_ahead: ``stream`` data with render backend ``torch``: images rendered in
    one march (:meth:`hbeo.model.trainingdata.ModelView.plan_reads`; None: up to 2,048 on a GPU as its memory allows, a batch on the
    CPU); it changes the speed, not the images; draw_workers: the same data, processes that draw the next march's
    poses while this one renders (:class:`hbeo.render.posedraws.DrawAhead`; None: up to 8 on a GPU, none on the
    CPU); it changes the speed, not the images; augment_mirror: mirror each training view with probability 1/2,
    its object across its class's left-right plane (data ``memory``; :class:`hbeo.model.mirror.MirrorAugment`);
    image_size: (width, height) of the training images (None: the profile's), the camera
    :meth:`~hbeo.conventions.Intrinsics.kinect` scaled to it: the same views at another resolution;
    batch_size / lr: the optimizer's batch and peak learning rate (None: the profile's); warmup_steps: the linear
    warm-up's steps (None: 100, or one epoch when shorter); noise: train on views with the Kinect-like sensor
    noise (:class:`hbeo.render.noise.SensorNoise`, each view its own draw; render settings: a run folder holds
    one rendered set, so a clean set already there is refused, not mixed); noise_scale: with noise, where it is
    applied (:attr:`hbeo.render.views.RenderSettings.noise_scale`: each view rendered at that many times the
    image's size, the noise applied there, the image read at the pixel nearest each pixel's centre, as
    ``predict`` reads a sensor's frame; 8 at 80x60 is a 640x480 sensor; views rendered one object at a time,
    so not the streamed ``torch`` renderer); noise_fraction: with noise, the share of each object's views that
    carry it (:attr:`hbeo.render.views.RenderSettings.noise_fraction`: its first views, the rest clean at the
    image's size; a rendered set's views, so not ``data="stream"``, which draws one view per object a pass)."""

    epochs: int | None = None
    rotation: str | None = None
    augment_roll: bool | None = None
    shape_loss: str | None = None
    data: str | None = None
    class_balance: str | None = None
    normalization: str = "none"
    view: ViewOptions = field(default_factory=lambda: ViewOptions())
    sampler: str = "so3"
    views: int | None = None
    backend: str = "auto"
    loss: LossWeights = field(default_factory=LossWeights)
    fc: tuple[int, int, int] | None = None
    val_fraction: float = 0.1
    seed: int | None = None
    name: str = DEFAULT_MODEL
    max_steps: int | None = None
    checkpoint_every: int | None = None
    loader_workers: int = 0
    render_ahead: int | None = None
    draw_workers: int | None = None
    augment_mirror: bool = False
    image_size: tuple[int, int] | None = None
    batch_size: int | None = None
    lr: float | None = None
    warmup_steps: int | None = None
    noise: bool = False
    noise_scale: int = 1
    noise_fraction: float = 1.0

    def recipe(self, prof) -> dict:
        """The profile's recipe with this run's overrides: ``rotation``, ``augment_roll``, ``shape_loss``,
        ``class_balance``."""
        return {k: v if (v := getattr(self, k)) is not None else d for k, d in prof.recipe.fit_kwargs().items()}

    def net_config(self, prof, image_size, n_classes: int, n_coeffs: int) -> NetConfig:
        """HBEONet's sizes for this training: the profile's network (:class:`hbeo.config.NetworkConfig`) with
        this run's ``fc``, its recipe's rotation and its normalization, for images of ``image_size`` (W, H)."""
        return NetConfig(image_size=tuple(image_size), n_classes=int(n_classes), n_coeffs=int(n_coeffs),
                         conv_channels=tuple(prof.network.conv_channels), fc=tuple(self.fc or prof.network.fc),
                         kernel=prof.network.kernel, rotation=self.recipe(prof)["rotation"],
                         normalization=self.normalization)

    def changed(self) -> dict:
        """The fields that differ from their defaults, JSON-ready (for provenance)."""
        out = {}
        for f in fields(self):
            v, d = getattr(self, f.name), f.default if f.default is not MISSING else f.default_factory()
            if v != d:
                out[f.name] = asdict(v) if hasattr(v, "__dataclass_fields__") else v
        return out


def parse_loss_weights(text: str) -> LossWeights:
    """``"gamma_c,gamma_o,gamma_p"`` (``python -m hbeo train --loss-weights``) -> :class:`LossWeights`;
    ValueError naming the option for anything but three non-negative numbers."""
    try:
        c, o, p = (float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--loss-weights takes three numbers gamma_c,gamma_o,gamma_p, got {text!r}") from None
    if not all(math.isfinite(v) and v >= 0 for v in (c, o, p)) or c + o + p == 0:
        raise ValueError(f"--loss-weights must be finite, not negative and not all zero, got {text!r}")
    return LossWeights(c, o, p)


def parse_fc(text: str) -> tuple[int, int, int]:
    """``"W1,W2,W3"`` (``python -m hbeo train --fc``) -> the three shared layer widths; ValueError naming the
    option for anything but three positive whole numbers."""
    try:
        widths = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--fc takes three whole numbers W1,W2,W3, got {text!r}") from None
    if len(widths) != 3 or min(widths) < 1:
        raise ValueError(f"--fc takes three positive widths (HBEONet has three shared layers), got {text!r}")
    return widths


def fit_model(run, prof, options: TrainOptions | None = None, dataset=None, settings: RenderSettings | None = None,
              progress: bool = True) -> tuple[HBEO, Path]:
    """Train on the run's training images with its subspace: ``run`` a RunDir or a path, ``prof`` a
    :class:`hbeo.config.Profile`, ``options`` a :class:`TrainOptions`. Writes the model file
    ``options.name`` (``RunDir.model_file``) and returns the model and its
    path; checkpoints go to ``RunDir.training(name)`` (a rerun resumes exactly). ``stream`` data renders
    ``dataset`` (a loaded :class:`hbeo.data.datasets.Dataset`) with ``settings`` (default: the profile's)
    on the fly, the other sources read the run's rendered training set. Most callers want
    :meth:`hbeo.run.Run.train`, which also prepares the data and writes the provenance.
    Under ``torchrun`` every process trains and returns the model; rank 0 alone writes the file."""
    run = RunDir.of(run)
    opts = options or TrainOptions()
    recipe = opts.recipe(prof)
    augment_roll, shape_loss = recipe["augment_roll"], recipe["shape_loss"]
    balance = recipe["class_balance"]
    view = opts.view
    source = opts.data or prof.data.train_data
    if source not in DATA_SOURCES:
        raise ValueError(f"unknown training data source {source!r}; expected one of {', '.join(DATA_SOURCES)}")
    if shape_loss not in SHAPE_LOSSES:
        raise ValueError(f"unknown shape loss {shape_loss!r}; expected one of {', '.join(SHAPE_LOSSES)}")
    if balance not in CLASS_BALANCE:
        raise ValueError(f"unknown class balance {balance!r}; expected one of {', '.join(CLASS_BALANCE)}")
    if balance == "sampler" and source == "shards":
        raise ValueError("class balance 'sampler' draws images in random order across the rendered set; data "
                         "'shards' reads it a few shards at a time: use data 'memory' or 'stream' (or class "
                         "balance 'loss')")
    model_path = run.model_file(opts.name)
    sub = ObjectSubspace.load(run.subspace)
    if source != "stream":
        rendered_with = (Manifest.load(run.renders("train")).data.get("subspace") or {}).get("basis_sha256")
        if rendered_with != subspace_info(sub)["basis_sha256"]:
            raise DataError(run.renders("train"), f"rendered with another subspace than {run.subspace}; render it "
                                                  f"again (notebook 03)")
    settings = settings or RenderSettings.from_profile(prof, backend=opts.backend)
    data = training_data(run, view, opts.val_fraction, augment_roll, progress, source, dataset, prof, settings,
                         prof.data.val_split, prof.data.twin_iou, opts.augment_mirror)
    cfg = opts.net_config(prof, data.settings.image_size, len(data.classes), sub.dim_)
    check_network(cfg)                # refused before the network is built
    how = {"augment_roll": augment_roll, "recenter": view.recenter, "ref_distance": view.ref_distance,
           "val_fraction": opts.val_fraction}
    if prof.data.val_split != "object":    # object-split runs keep the settings (and checkpoints) they had
        how["val_split"], how["twin_iou"] = prof.data.val_split, prof.data.twin_iou
    if source != "memory":            # memory runs keep the settings (and checkpoints) they always had
        how["source"] = source
    if opts.augment_mirror:           # runs without it keep the settings (and checkpoints) they had
        how["augment_mirror"] = True
    if data.settings.noise:           # clean runs keep the settings (and checkpoints) they had
        how["noise"] = True
        if data.settings.noise_scale != 1:
            how["noise_scale"] = data.settings.noise_scale
        if data.settings.noise_fraction != 1:
            how["noise_fraction"] = data.settings.noise_fraction
    if source == "stream" and data.settings.backend == "torch":    # other backends: the settings they had
        how["backend"] = "torch"
        if augment_roll:                    # rolls drawn by reading position (render_batch's roll_keys)
            how["roll"] = "position"
        if opts.render_ahead is not None:
            data.train.ahead = opts.render_ahead
        if opts.draw_workers is not None:
            data.train.draw_workers = opts.draw_workers
    counts = np.bincount(data.train_labels, minlength=len(data.classes))
    train_set = data.train
    if balance == "sampler":                # unbalanced runs keep the settings (and checkpoints) they had
        how["class_balance"] = "sampler"
        train_set = ClassBalanced(data.train, data.train_labels)
    batch = opts.batch_size or prof.recipe.batch_size
    warmup = opts.warmup_steps or min(100, max(1, len(data.train) // batch))
    tc = TrainConfig(epochs=opts.epochs or prof.recipe.epochs, batch_size=batch, lr=opts.lr or prof.recipe.lr,
                     seed=opts.seed or 0, progress=progress, warmup_steps=warmup,
                     max_steps=opts.max_steps, data=how, checkpoint_every=opts.checkpoint_every,
                     num_workers=opts.loader_workers)
    task = HBEONetTask(cfg, opts.loss, np.asarray(data.coeff_std) if shape_loss == "voxels" else None,
                       tuple(class_weights(counts)) if balance == "loss" else None)
    try:
        net = train(task, train_set, data.val, run.training(model_path), tc)
    finally:
        getattr(data.train, "close", lambda: None)()     # processes drawing poses ahead, if any
    model_settings = {"object_size": data.settings.object_size, "recenter": view.recenter,
                      "ref_distance": view.ref_distance, "coeff_mean": data.coeff_mean, "coeff_std": data.coeff_std,
                      "render": data.settings.to_dict(), "profile": prof.name, "augment_roll": augment_roll,
                      "shape_loss": shape_loss, "class_counts": counts,
                      "class_balance": balance}
    model = HBEO(net.cpu(), sub, data.settings.intrinsics, data.classes, model_settings)
    if not distributed.world().main:
        return model, model_path
    return model, model.save(model_path)
