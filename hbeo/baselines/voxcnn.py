"""VoxCNN: the end-to-end deep baseline (the role 3D ShapeNets plays in the paper).

A 3D CNN maps the partial 30^3 grid seen from one depth image (pose known, so the grid is in
the object's canonical frame) straight to a class and a completed 30^3 occupancy grid: direct
regression into 27,000 dimensions, trained on the same training objects and renderings as
HBEONet, so the paper's "subspace vs. direct regression" question is measured here.

Input (B, 2, 30, 30, 30) float: channel 0 = known-filled voxels, channel 1 = known-empty voxels
(both 0 = unknown), from :func:`hbeo.subspace.partial.depth_to_partial`. Network (:class:`VoxCNN`): three
stride-2 3D convolutions (30 -> 15 -> 8 -> 4), a fully connected bottleneck read by the class
head, and a decoder (fully connected back to 4^3, 3D transposed convolutions 4 -> 8 -> 15, a
convolutional head giving the 8 sub-voxel logits of every 15^3 cell, depth-to-space to 30^3),
with U-Net skip connections (encoder features, and the input's 2x2x2 cells, concatenated at each
resolution; ``skips=False`` gives the plain encoder-bottleneck-decoder, which at the ci scale
learns to predict an empty grid). Loss: cross-entropy + ``occupancy_weight`` x binary
cross-entropy over all voxels (``pos_weight`` on filled ones).

Training: :class:`VoxCNNTask` in the project's loop (:func:`hbeo.model.loop.train`), sizes from
the profile's ``voxcnn_*`` fields (:class:`hbeo.config.Profile`).

Files in a run folder (:class:`hbeo.rundir.RunDir`)
    ``RunDir.partial_train(K)``: the partial grids of the rendered training set (computed once,
    atomically written, recomputed when the rendered set, the grids or
    ``hbeo/subspace/partial.py`` change); ``RunDir.training(...)`` (``train_voxcnn/``): checkpoint
    and CSV log (a rerun resumes exactly); ``RunDir.baseline("voxcnn")`` (``voxcnn.hbeo``): the
    trained baseline (:class:`VoxCNNBaseline`).

May import: foundation, data, subspace, render, model.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from torch.utils.data import Subset
from hbeo.progress import tqdm

from hbeo import config
from hbeo import conventions as C
from hbeo.errors import DataError
from hbeo.baselines.methods import METHODS
from hbeo.model.loop import TrainConfig, ValidationMeans, train, training_history
from hbeo.render.torch_datasets import load_shard, split_by_object
from hbeo.render.renderset import Manifest
from hbeo.rundir import RunDir
from hbeo.storage import pack_bits, sha256_file, unpack_bits, write_npz
from hbeo.subspace import partial as partial_mod

FORMAT_VERSION = 1                #: of the partial-grid cache
R3 = C.RESOLUTION ** 3
OCCUPANCY_PRIOR_LOGIT = -2.0      #: initial occupancy logit (sigmoid = 0.12, about the filled fraction)
PACKED = (R3 + 7) // 8


# --------------------------------------------------------------------------- the network

@dataclass(frozen=True)
class VoxCNNConfig:
    """Sizes of :class:`VoxCNN`: ``channels`` of the three stride-2 encoder stages, ``bottleneck``
    width, ``skips`` (U-Net skip connections in the decoder), ``dropout`` before the class head."""

    channels: tuple[int, int, int] = (16, 32, 64)
    n_classes: int = 10
    bottleneck: int = 256
    skips: bool = True
    dropout: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "channels", tuple(int(c) for c in self.channels))
        if len(self.channels) != 3 or min(self.channels) < 1:
            raise ValueError(f"VoxCNNConfig.channels must be three positive widths, got {self.channels}")
        if int(self.n_classes) < 2 or int(self.bottleneck) < 1:
            raise ValueError(f"VoxCNNConfig needs n_classes >= 2 and bottleneck >= 1, "
                             f"got {self.n_classes}, {self.bottleneck}")
        if not 0 <= float(self.dropout) < 1:
            raise ValueError(f"VoxCNNConfig.dropout must be in [0, 1), got {self.dropout}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["channels"] = list(self.channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "VoxCNNConfig":
        names = {f.name for f in fields(cls)}
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names})


def _block(c_in, c_out, stride):
    return nn.Sequential(nn.Conv3d(c_in, c_out, 3, stride=stride, padding=1, bias=False),
                         nn.BatchNorm3d(c_out), nn.ReLU(inplace=True))


def _up(c_in, c_out, kernel):
    """Transposed convolution doubling the size (kernel 4: n -> 2n; kernel 3: n -> 2n - 1)."""
    return nn.Sequential(nn.ConvTranspose3d(c_in, c_out, kernel, stride=2, padding=1, bias=False),
                         nn.BatchNorm3d(c_out), nn.ReLU(inplace=True))


def space_to_depth(x: torch.Tensor) -> torch.Tensor:
    """(B, C, 2n, 2n, 2n) -> (B, 8C, n, n, n): each 2x2x2 cell's voxels as channels."""
    b, c, d, h, w = x.shape
    x = x.view(b, c, d // 2, 2, h // 2, 2, w // 2, 2)
    return x.permute(0, 1, 3, 5, 7, 2, 4, 6).reshape(b, c * 8, d // 2, h // 2, w // 2)


def depth_to_space(x: torch.Tensor) -> torch.Tensor:
    """(B, 8C, n, n, n) -> (B, C, 2n, 2n, 2n); inverse of :func:`space_to_depth`."""
    b, c8, d, h, w = x.shape
    c = c8 // 8
    x = x.view(b, c, 2, 2, 2, d, h, w)
    return x.permute(0, 1, 5, 2, 6, 3, 7, 4).reshape(b, c, 2 * d, 2 * h, 2 * w)


class VoxCNN(nn.Module):
    """Partial grid (B, 2, 30, 30, 30) -> {"logits": (B, C), "occupancy": (B, 30, 30, 30) logits}.

    Encoder: 3x3x3 convolutions with stride 2 (30 -> 15 -> 8 -> 4), batch norm, ReLU; bottleneck:
    a fully connected layer of ``bottleneck`` units, which the class head reads; decoder: a fully
    connected layer back to 4^3, transposed convolutions 4 -> 8 -> 15 and, at 15^3, a head
    (1x1x1, 3x3x3, 1x1x1 convolutions) that outputs the 8 occupancy logits of each 2x2x2 cell
    (depth-to-space to 30^3: about 4x faster on a CPU than a transposed convolution and a
    convolution at 30^3, at a small cost in IoU). With ``skips``, each decoder stage also sees
    the encoder features of its resolution and the head sees the input's 2x2x2 cells (space-to-depth).
    The output bias starts at the log-odds of a typical occupancy (~12 %).
    """

    def __init__(self, cfg: VoxCNNConfig):
        super().__init__()
        self.cfg = cfg
        c1, c2, c3 = cfg.channels
        s = int(cfg.skips)
        self.enc1 = _block(2, c1, 2)          # 30 -> 15
        self.enc2 = _block(c1, c2, 2)         # 15 -> 8
        self.enc3 = _block(c2, c3, 2)         # 8 -> 4
        flat = c3 * 4 ** 3
        self.squeeze = nn.Sequential(nn.Flatten(), nn.Linear(flat, cfg.bottleneck), nn.ReLU(inplace=True))
        self.class_head = nn.Sequential(nn.Dropout(cfg.dropout), nn.Linear(cfg.bottleneck, cfg.n_classes))
        self.expand = nn.Sequential(nn.Linear(cfg.bottleneck, flat), nn.ReLU(inplace=True))
        self.dec3 = _up(c3 * (1 + s), c2, 4)          # 4 -> 8
        self.dec2 = _up(c2 * (1 + s), c1, 3)          # 8 -> 15
        h = 2 * c1
        self.head = nn.Sequential(nn.Conv3d(c1 * (1 + s) + 16 * s, h, 1), nn.ReLU(inplace=True),
                                  nn.Conv3d(h, h, 3, padding=1), nn.ReLU(inplace=True),
                                  nn.Conv3d(h, 8, 1))        # 8 sub-voxel logits per 15^3 cell
        nn.init.constant_(self.head[-1].bias, OCCUPANCY_PRIOR_LOGIT)

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        if x.ndim != 5 or tuple(x.shape[1:]) != (2,) + (C.RESOLUTION,) * 3:
            raise ValueError(f"VoxCNN input must be (B, 2, 30, 30, 30), got {tuple(x.shape)}")
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        z = self.squeeze(e3)
        d = self.expand(z).view_as(e3)
        if self.cfg.skips:
            d = self.dec2(torch.cat([self.dec3(torch.cat([d, e3], 1)), e2], 1))
            d = torch.cat([d, e1, space_to_depth(x)], 1)
        else:
            d = self.dec2(self.dec3(d))
        occ = depth_to_space(self.head(d))[:, 0]
        return {"logits": self.class_head(z), "occupancy": occ}

    def n_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


def voxcnn_loss(out: dict, label: torch.Tensor, target: torch.Tensor, pos_weight: float = 1.0,
                occupancy_weight: float = 1.0) -> tuple[torch.Tensor, dict[str, float]]:
    """CE(class) + occupancy_weight * BCE(occupancy logits, target), BCE averaged over voxels."""
    ce = F.cross_entropy(out["logits"], label)
    pw = torch.tensor(float(pos_weight), dtype=out["occupancy"].dtype, device=out["occupancy"].device)
    bce = F.binary_cross_entropy_with_logits(out["occupancy"], target, pos_weight=pw)
    return ce + occupancy_weight * bce, {"ce": ce.item(), "bce": bce.item()}


def network_input(filled, known) -> torch.Tensor:
    """Partial grids (B, 30, 30, 30) or (30, 30, 30) bool -> network input (B, 2, 30, 30, 30) float:
    known-filled and known-empty (voxels that are filled but not known count as unknown)."""
    f, k = np.asarray(filled, bool), np.asarray(known, bool)
    if f.shape != k.shape or f.shape[-3:] != (C.RESOLUTION,) * 3:
        raise ValueError(f"filled {f.shape} and known {k.shape} must be matching (.., 30, 30, 30) grids")
    if f.ndim == 3:
        f, k = f[None], k[None]
    return torch.from_numpy(np.stack([f & k, k & ~f], axis=1).astype(np.float32))


# --------------------------------------------------------------------------- the partial training set

class PartialSet(torch.utils.data.Dataset):
    """Partial grids of a rendered training set, with class labels and complete target grids.

    Arrays (N views): ``filled`` / ``known`` bit-packed (N, 3375) uint8, ``labels``, ``object_index``
    (position in the rendered set's object list), ``image`` (index in the rendered set);
    ``grids`` bit-packed (n_objects, 3375), the complete grid of each object position.
    Items: ``x`` (2, 30, 30, 30) float (:func:`network_input`), ``label``, ``target`` (30, 30, 30)
    float, ``object_index``. :meth:`batch` gives the same for many indices at once.
    """

    def __init__(self, filled, known, labels, object_index, image, grids, classes, manifest: Manifest,
                 meta: dict | None = None):
        self.filled, self.known = np.asarray(filled, np.uint8), np.asarray(known, np.uint8)
        self.labels = np.asarray(labels, np.int64)
        self.object_index = np.asarray(object_index, np.int64)
        self.image = np.asarray(image, np.int64)
        self.grids = np.asarray(grids, np.uint8)
        self.classes = tuple(classes)
        self.manifest = manifest
        self.meta = dict(meta or {})

    def __len__(self) -> int:
        return len(self.labels)

    def batch(self, indices) -> dict[str, torch.Tensor]:
        idx = np.asarray(indices, np.int64)
        f, k = unpack_bits(self.filled[idx]), unpack_bits(self.known[idx])
        target = unpack_bits(self.grids[self.object_index[idx]])
        return {"x": network_input(f, k), "label": torch.from_numpy(self.labels[idx].copy()),
                "target": torch.from_numpy(target.astype(np.float32)),
                "object_index": torch.from_numpy(self.object_index[idx].copy())}

    def __getitem__(self, i) -> dict:
        n = len(self)
        i = int(i) + (n if int(i) < 0 else 0)
        if not 0 <= i < n:
            raise IndexError(f"view {i} out of range for a set of {n}")
        b = self.batch([i])
        return {k: v[0] for k, v in b.items()}

    def partial(self, indices) -> tuple[np.ndarray, np.ndarray]:
        """(filled, known) bool (n, 30, 30, 30) of views ``indices``."""
        idx = np.asarray(indices, np.int64)
        return unpack_bits(self.filled[idx]), unpack_bits(self.known[idx])

    def targets(self, indices) -> np.ndarray:
        """Complete grids bool (n, 30, 30, 30) of views ``indices``."""
        return unpack_bits(self.grids[self.object_index[np.asarray(indices, np.int64)]])

    def split(self, val_fraction: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Indices (train, validation) into this set, split by object
        (:func:`hbeo.render.torch_datasets.split_by_object` on the rendered set)."""
        tr, va = split_by_object(self.manifest, val_fraction, seed)
        idx = np.arange(len(self), dtype=np.int64)
        return idx[np.isin(self.image, tr)], idx[np.isin(self.image, va)]


def _depth_partial(depth, K, R, t, object_size) -> tuple[np.ndarray, np.ndarray]:
    """(filled, known) of one view; a view without object pixels gives an all-unknown grid."""
    depth = np.asarray(depth, np.float32)
    if not (depth > 0).any():
        empty = np.zeros((C.RESOLUTION,) * 3, bool)
        return empty, empty.copy()
    f, k = partial_mod.depth_to_partial(depth, K, np.asarray(R, np.float64), np.asarray(t, np.float64),
                                        object_size=object_size)
    return np.asarray(f, bool), np.asarray(k, bool)


def _cache_meta(run: RunDir, m: Manifest, views: int) -> dict:
    src = getattr(partial_mod, "__file__", None)
    return {"format_version": FORMAT_VERSION, "views_per_object": int(views),
            "object_size": float(m.settings.object_size),
            "shards": [s["sha256"] for s in m.shards],
            "grids_sha256": sha256_file(run.grids("train")),
            "partial_sha256": sha256_file(src) if src and Path(src).is_file() else None}


def _object_grids(run: RunDir, m: Manifest) -> np.ndarray:
    """Packed complete grids (n_objects, 3375) in the rendered set's object order (empty for the objects
    the set failed to render: they have no images)."""
    from hbeo.data.gridset import GridSet
    path = run.grids("train")
    if not path.exists():
        raise DataError(path, "no training grids in the run folder (notebook 01, or hbeo.run.Run.renders, "
                              "writes them)")
    gs = GridSet.load(path)
    where = {(gs.classes[int(lab)], str(i)): n for n, (lab, i) in enumerate(zip(gs.labels, gs.ids))}
    classes = m.classes
    failed = {int(f["position"]) for f in m.failures if "position" in f}   # no images: their row is never read
    grids = np.zeros((len(m.object_ids),) + gs.grids.shape[1:], bool)
    for n, (lab, i) in enumerate(zip(m.object_labels, m.object_ids)):
        if n in failed:
            continue
        try:
            grids[n] = gs.grids[where[(classes[int(lab)], str(i))]]
        except KeyError:
            raise DataError(path, f"has no grid for rendered object {(classes[int(lab)], str(i))}; the grids "
                                  f"and {m.root} come from different runs") from None
    return pack_bits(grids)


def _load_cache(path: Path, meta: dict) -> dict | None:
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if json.loads(str(z["meta"])) != meta:
                return None
            return {k: z[k] for k in z.files if k != "meta"}
    except Exception:       # unreadable cache: compute it again
        return None


def partial_training_set(run, views_per_object: int | None = None, progress: bool = True) -> PartialSet:
    """The partial grids of the rendered training set of ``run`` (a RunDir or a path; all views, or
    the first ``views_per_object`` of each object) with labels and the complete training grids
    (``RunDir.grids("train")``) as targets.

    Computed once with :func:`hbeo.subspace.partial.depth_to_partial` (pose and object size from the rendered
    set) and cached in ``RunDir.partial_train`` (atomic); the cache is recomputed when the
    rendered set, the grids or ``hbeo/subspace/partial.py`` change."""
    run = RunDir.of(run)
    m = Manifest.load(run.renders("train"))
    n_views = int(m.data["views_per_object"])
    k = n_views if views_per_object is None else int(views_per_object)
    if k < 1:
        raise ValueError(f"views_per_object must be >= 1, got {views_per_object}")
    k = min(k, n_views)
    meta = _cache_meta(run, m, k)
    path = run.partial_train(None if k == n_views else k)
    arrays = _load_cache(path, meta)
    if arrays is None:
        grids = _object_grids(run, m)
        size = m.settings.object_size
        parts = {n: [] for n in ("filled", "known", "labels", "object_index", "image")}
        bar = tqdm(total=len(m.object_ids) * k, desc="partial grids", unit="view", disable=not progress)
        start = 0
        for shard in m.shard_paths():
            sh = load_shard(shard)
            n = len(sh["label"])
            sel = np.flatnonzero(sh["view"] < k)
            fx, fy, cx, cy, w, h = (float(v) for v in sh["intrinsics"])
            K = C.Intrinsics(fx, fy, cx, cy, int(w), int(h))
            f_out, k_out = np.empty((len(sel), PACKED), np.uint8), np.empty((len(sel), PACKED), np.uint8)
            for j, i in enumerate(sel):
                f, kn = _depth_partial(sh["depth"][i], K, sh["rotation"][i], sh["translation"][i], size)
                f_out[j], k_out[j] = pack_bits(f[None])[0], pack_bits(kn[None])[0]
                bar.update(1)
            parts["filled"].append(f_out)
            parts["known"].append(k_out)
            parts["labels"].append(sh["label"][sel])
            parts["object_index"].append(sh["object_index"][sel])
            parts["image"].append(start + sel)
            start += n
        bar.close()
        arrays = {name: np.concatenate(v) for name, v in parts.items()}
        arrays["grids"] = grids
        write_npz(path, meta, compressed=True, **arrays)
    return PartialSet(arrays["filled"], arrays["known"], arrays["labels"], arrays["object_index"],
                      arrays["image"], arrays["grids"], m.classes, m, meta)


# --------------------------------------------------------------------------- training

@dataclass
class VoxCNNTask:
    """VoxCNN for :func:`hbeo.model.loop.train`: :func:`voxcnn_loss` on :class:`PartialSet` batches
    (``x``, ``label``, ``target``). Validation: mean loss parts, class accuracy and mean completion
    IoU (occupancy probability >= 0.5; an empty target and prediction count as 1)."""

    net_cfg: VoxCNNConfig
    pos_weight: float = 1.5           #: BCE weight of filled voxels
    occupancy_weight: float = 1.0     #: weight of the BCE term against the CE term
    kind = "voxcnn"
    unit = "grids"

    def config(self) -> dict:
        return {"net": self.net_cfg.to_dict(), "pos_weight": float(self.pos_weight),
                "occupancy_weight": float(self.occupancy_weight)}

    def build(self) -> VoxCNN:
        return VoxCNN(self.net_cfg)

    def loss(self, net: VoxCNN, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        return voxcnn_loss(net(batch["x"]), batch["label"], batch["target"], self.pos_weight, self.occupancy_weight)

    def validate(self, net: VoxCNN, batches) -> dict[str, float]:
        means, ious = ValidationMeans(), []
        for b in batches:
            out = net(b["x"])
            loss, parts = voxcnn_loss(out, b["label"], b["target"], self.pos_weight, self.occupancy_weight)
            means.add(loss, parts, out["logits"], b["label"])
            pred, tgt = out["occupancy"] >= 0, b["target"] > 0.5
            inter = (pred & tgt).flatten(1).sum(1).float()
            union = (pred | tgt).flatten(1).sum(1).float()
            ious.append(torch.where(union > 0, inter / union.clamp_min(1), torch.ones_like(union)).cpu())
        if means.n == 0:
            return {}
        return {**means.means(), "iou": float(torch.cat(ious).mean())}


def train_voxcnn(run, profile, epochs: int | None = None, seed: int = 0, progress: bool = True,
                 val_fraction: float = 0.1, stop_after_epoch: int | None = None, threads: int | None = 0,
                 max_steps: int | None = None) -> "VoxCNNBaseline":
    """Train VoxCNN on the partial training grids of ``run`` (a RunDir or a path;
    :func:`partial_training_set`) with the profile's ``voxcnn_*`` sizes, split by object for
    validation (with seed 0 whatever ``seed`` is: the training seed changes the initial weights and
    the batch order, never which objects are held out), in the project's loop (checkpoints in ``RunDir.training``; a rerun resumes
    exactly); writes ``RunDir.baseline("voxcnn")`` once training is done and returns the
    :class:`VoxCNNBaseline`. ``epochs`` overrides the profile's; ``max_steps`` ends training after
    that many optimizer steps; ``stop_after_epoch`` (< epochs) ends early without writing the model
    file (to simulate an interruption); ``threads``: torch threads on a CPU (0 = half the cores,
    None = torch's setting; see :func:`hbeo.model.loop.cpu_threads`)."""
    run = RunDir.of(run)
    prof = config.get_profile(profile)
    data = partial_training_set(run, prof.baselines.voxcnn_views_per_object, progress=progress)
    tr, va = data.split(val_fraction, 0)
    task = VoxCNNTask(VoxCNNConfig(channels=prof.baselines.voxcnn_channels, n_classes=len(data.classes),
                                   bottleneck=prof.baselines.voxcnn_bottleneck), pos_weight=prof.baselines.voxcnn_pos_weight)
    tc = TrainConfig(epochs=int(epochs or prof.baselines.voxcnn_epochs), batch_size=prof.baselines.voxcnn_batch_size, lr=prof.baselines.voxcnn_lr,
                     warmup_steps=min(100, max(1, len(tr) // prof.baselines.voxcnn_batch_size)), seed=seed,
                     max_steps=max_steps, threads=threads, progress=progress,
                     data={"views_per_object": int(data.meta["views_per_object"]), "val_fraction": val_fraction})
    path = run.baseline("voxcnn")
    net = train(task, Subset(data, tr), Subset(data, va), run.training(path), tc, stop_after_epoch=stop_after_epoch)
    history = training_history(run.training(path))
    settings = {"object_size": float(data.manifest.settings.object_size), "threshold": 0.5, "profile": prof.name,
                "views_per_object": int(data.meta["views_per_object"]),
                "loss": {"pos_weight": task.pos_weight, "occupancy_weight": task.occupancy_weight},
                "train": tc.to_dict(), "final": history[-1] if history else {}}
    model = VoxCNNBaseline(net.cpu(), data.classes, settings)
    if stop_after_epoch is None or stop_after_epoch >= tc.epochs:
        model.save(path)
    return model


# --------------------------------------------------------------------------- the baseline

class VoxCNNBaseline:
    """A trained VoxCNN with its class names and settings, in one file; known-pose inference."""

    #: the :class:`hbeo.evaluation.method.Method` contract: registry name and pose settings (default first)
    name = "voxcnn"
    poses = METHODS["voxcnn"]

    def describe(self) -> dict:
        """Settings the metrics dict records beyond name and pose: none for a baseline."""
        return {}

    def __init__(self, net: VoxCNN, classes, settings: dict | None = None):
        self.net = net.eval()
        self.classes = tuple(classes)
        self.settings = {"object_size": 1.0, "threshold": 0.5, **(settings or {})}
        if net.cfg.n_classes != len(self.classes):
            raise ValueError(f"network has {net.cfg.n_classes} classes, {len(self.classes)} names given")

    def save(self, path) -> Path:
        """Write the baseline to one file, atomically (:mod:`hbeo.model.modelfile`, kind ``voxcnn``)."""
        from hbeo.model.modelfile import write_model
        meta = {"net_cfg": self.net.cfg.to_dict(), "classes": list(self.classes), "settings": self.settings}
        return write_model(path, "voxcnn", meta, self.net.state_dict())

    @classmethod
    def load(cls, path) -> "VoxCNNBaseline":
        """Read a file written by :meth:`save` (nothing is unpickled); DataError naming the file on a
        missing, corrupt, old-format or inconsistent one."""
        from hbeo.model.modelfile import read_model
        mf = read_model(path, "voxcnn", lambda cfg: VoxCNN(VoxCNNConfig(**cfg)))
        try:
            return cls(mf.net, mf.meta["classes"], mf.meta["settings"])
        except (TypeError, ValueError) as err:
            raise DataError(path, f"inconsistent VoxCNN baseline file ({err})") from None

    @torch.no_grad()
    def predict_partial(self, filled, known, batch_size: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """Partial grids (B, 30, 30, 30) or one (30, 30, 30), bool -> (class probabilities (B, C),
        occupancy probabilities (B, 30, 30, 30) float32)."""
        x = network_input(filled, known)
        probs, occ = [], []
        for s in range(0, len(x), batch_size):
            out = self.net(x[s:s + batch_size])
            probs.append(torch.softmax(out["logits"].double(), 1).numpy())
            occ.append(torch.sigmoid(out["occupancy"]).numpy())
        return np.concatenate(probs), np.concatenate(occ)

    def predict_view(self, depth, intrinsics: C.Intrinsics, R_true, t_true, object_size: float = 1.0,
                     pose: str = "known", label_true=None, rng=None) -> dict:
        """One depth image (H, W) metres, 0 = none, with the true pose (R: object -> camera, t metres)
        -> {"probabilities": (C,), "rotation": R_true, "grid": (30, 30, 30) bool}. Only ``pose="known"``:
        the baseline has no pose estimate (ValueError otherwise). ``label_true`` and ``rng`` are
        accepted for the evaluation's common call and not used."""
        if pose != "known":
            raise ValueError(f"the VoxCNN baseline needs the true pose (pose='known'), got pose={pose!r}")
        R = np.asarray(R_true, np.float64)
        f, k = _depth_partial(depth, intrinsics, R, t_true, object_size)
        probs, occ = self.predict_partial(f, k)
        return {"probabilities": probs[0], "rotation": R, "grid": occ[0] >= self.settings["threshold"]}
