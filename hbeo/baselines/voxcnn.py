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

Files in a run folder
    ``partial_train.npz`` (``partial_train_vK.npz`` for K views per object): the partial grids of
    ``render_train`` (computed once, atomically written, recomputed when the rendered set, the
    grids or ``hbeo/partial.py`` change); ``train_voxcnn/`` checkpoint and CSV log (a rerun
    resumes exactly); ``voxcnn.pt`` the trained baseline (:class:`VoxCNNBaseline`).
"""
from __future__ import annotations

import json
import math
import os
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from tqdm.auto import tqdm

from hbeo import __version__
from hbeo import config
from hbeo import conventions as C
from hbeo.storage import atomic_file, sha256_file
from hbeo.errors import DataError
from hbeo.render.renderset import Manifest, load_shard, split_by_object
from hbeo.model.train import _atomic_save, _write_log, lr_at, pick_device, seed_everything

FORMAT_VERSION = 1
KIND = "hbeo-voxcnn"
CHECKPOINT = "checkpoint.pt"
LOG = "train_log.csv"
R3 = C.RESOLUTION ** 3
OCCUPANCY_PRIOR_LOGIT = -2.0      #: initial occupancy logit (sigmoid = 0.12, about the filled fraction)
PACKED = (R3 + 7) // 8

#: Sizes per run profile (hbeo.config profiles ci / cpu / full). ``views_per_object``: rendered
#: views per training object turned into partial grids (None = all the set has).
PROFILES: dict[str, dict] = {
    "ci": {"channels": (8, 16, 32), "bottleneck": 64, "epochs": 3, "batch_size": 16, "lr": 3e-3,
           "views_per_object": None, "pos_weight": 1.5},
    "cpu": {"channels": (8, 16, 32), "bottleneck": 128, "epochs": 5, "batch_size": 32, "lr": 2e-3,
            "views_per_object": 3, "pos_weight": 1.5},
    "full": {"channels": (32, 64, 128), "bottleneck": 512, "epochs": 20, "batch_size": 64, "lr": 1e-3,
             "views_per_object": 32, "pos_weight": 1.5},
}


def profile_sizes(profile) -> dict:
    """The VoxCNN sizes of a profile (name or :class:`hbeo.config.Profile`)."""
    name = profile.name if isinstance(profile, config.Profile) else str(profile)
    try:
        return dict(PROFILES[name])
    except KeyError:
        raise ValueError(f"unknown profile {name!r}; expected one of {', '.join(PROFILES)}") from None


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

def _pack(grids: np.ndarray) -> np.ndarray:
    return np.packbits(np.asarray(grids, bool).reshape(len(grids), R3), axis=1)


def _unpack(packed: np.ndarray) -> np.ndarray:
    return np.unpackbits(packed, axis=1, count=R3).astype(bool).reshape((-1,) + (C.RESOLUTION,) * 3)


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
        f, k = _unpack(self.filled[idx]), _unpack(self.known[idx])
        target = _unpack(self.grids[self.object_index[idx]])
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
        return _unpack(self.filled[idx]), _unpack(self.known[idx])

    def targets(self, indices) -> np.ndarray:
        """Complete grids bool (n, 30, 30, 30) of views ``indices``."""
        return _unpack(self.grids[self.object_index[np.asarray(indices, np.int64)]])

    def split(self, val_fraction: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Indices (train, validation) into this set, split by object
        (:func:`hbeo.render.renderset.split_by_object` on the rendered set)."""
        tr, va = split_by_object(self.manifest, val_fraction, seed)
        idx = np.arange(len(self), dtype=np.int64)
        return idx[np.isin(self.image, tr)], idx[np.isin(self.image, va)]


def _depth_partial(pm, depth, K, R, t, object_size) -> tuple[np.ndarray, np.ndarray]:
    """(filled, known) of one view; a view without object pixels gives an all-unknown grid."""
    depth = np.asarray(depth, np.float32)
    if not (depth > 0).any():
        empty = np.zeros((C.RESOLUTION,) * 3, bool)
        return empty, empty.copy()
    f, k = pm.depth_to_partial(depth, K, np.asarray(R, np.float64), np.asarray(t, np.float64),
                               object_size=object_size)
    return np.asarray(f, bool), np.asarray(k, bool)


def _partial_module():
    try:
        from hbeo.subspace import partial
    except ImportError as err:
        raise ImportError("hbeo.subspace.partial (depth_to_partial) is needed for the VoxCNN baseline") from err
    return partial


def _cache_meta(run: Path, m: Manifest, views: int, partial_mod) -> dict:
    src = getattr(partial_mod, "__file__", None)
    return {"format_version": FORMAT_VERSION, "views_per_object": int(views),
            "object_size": float(m.settings.object_size),
            "shards": [s["sha256"] for s in m.shards],
            "grids_sha256": sha256_file(run / "grids_train.npz"),
            "partial_sha256": sha256_file(src) if src and Path(src).is_file() else None}


def _object_grids(run: Path, m: Manifest) -> np.ndarray:
    """Packed complete grids (n_objects, 3375) in the rendered set's object order."""
    from hbeo.data.gridset import GridSet
    path = run / "grids_train.npz"
    if not path.exists():
        raise DataError(path, "no training grids in the run folder (notebook 01, or hbeo.model.pipeline.ensure_render, "
                              "writes them)")
    gs = GridSet.load(path)
    where = {(gs.classes[int(lab)], str(i)): n for n, (lab, i) in enumerate(zip(gs.labels, gs.ids))}
    classes = m.classes
    try:
        pos = [where[(classes[int(lab)], str(i))] for lab, i in zip(m.object_labels, m.object_ids)]
    except KeyError as err:
        raise DataError(path, f"has no grid for rendered object {err.args[0]}; the grids and "
                              f"{m.root} come from different runs") from None
    return _pack(gs.grids[np.asarray(pos, np.int64)])


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
    """The partial grids of ``run/render_train`` (all views, or the first ``views_per_object`` of each
    object) with labels and the complete grids of ``run/grids_train.npz`` as targets.

    Computed once with :func:`hbeo.subspace.partial.depth_to_partial` (pose and object size from the rendered
    set) and cached in ``run/partial_train[_vK].npz`` (atomic); the cache is recomputed when the
    rendered set, the grids or ``hbeo/partial.py`` change."""
    run = Path(run)
    m = Manifest.load(run / "render_train")
    n_views = int(m.data["views_per_object"])
    k = n_views if views_per_object is None else int(views_per_object)
    if k < 1:
        raise ValueError(f"views_per_object must be >= 1, got {views_per_object}")
    k = min(k, n_views)
    pm = _partial_module()
    meta = _cache_meta(run, m, k, pm)
    path = run / ("partial_train.npz" if k == n_views else f"partial_train_v{k}.npz")
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
                f, kn = _depth_partial(pm, sh["depth"][i], K, sh["rotation"][i], sh["translation"][i], size)
                f_out[j], k_out[j] = _pack(f[None])[0], _pack(kn[None])[0]
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
        with atomic_file(path) as fh:
            np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)
    return PartialSet(arrays["filled"], arrays["known"], arrays["labels"], arrays["object_index"],
                      arrays["image"], arrays["grids"], m.classes, m, meta)


# --------------------------------------------------------------------------- training

@dataclass
class VoxTrainConfig:
    """Training settings of :func:`train_loop` (same schedule as :class:`hbeo.model.train.TrainConfig`)."""

    epochs: int = 10
    batch_size: int = 32
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 20
    min_lr_ratio: float = 0.05
    grad_clip: float = 5.0
    pos_weight: float = 1.5           #: BCE weight of filled voxels
    occupancy_weight: float = 1.0     #: weight of the BCE term against the CE term
    seed: int = 0
    device: str = "auto"
    threads: int | None = 0           #: CPU threads for torch: 0 = auto (half the cores), None = torch's setting
    progress: bool = True

    def to_dict(self) -> dict:
        return asdict(self)


@contextmanager
def cpu_threads(n: int | None):
    """Run the block with ``n`` torch threads (0 = half the usable cores, at least one; None =
    unchanged), then restore the previous count. Why: on a 2-core machine shared with other jobs,
    VoxCNN training steps took 3-10x longer with two threads than with one (every small 3D
    operation waits for its slowest thread, which another process may have pushed off its core)."""
    before = torch.get_num_threads()
    if n is None:
        yield before
        return
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 2)
    want = max(1, cores // 2) if n == 0 else int(n)
    torch.set_num_threads(want)
    try:
        yield want
    finally:
        torch.set_num_threads(before)


def _batches(n: int, batch_size: int, gen: torch.Generator | None):
    order = torch.randperm(n, generator=gen).numpy() if gen is not None else np.arange(n)
    for s in range(0, n, batch_size):
        yield order[s:s + batch_size]


@torch.no_grad()
def evaluate_partial(net: VoxCNN, data: PartialSet, indices, device, cfg: VoxTrainConfig,
                     batch_size: int = 64) -> dict:
    """Mean loss parts, class accuracy and mean completion IoU (threshold 0.5) over views ``indices``."""
    was = net.training
    net.eval()
    idx = np.asarray(indices, np.int64)
    sums, n, correct, ious = {"loss": 0.0, "ce": 0.0, "bce": 0.0}, 0, 0, []
    for sel in _batches(len(idx), batch_size, None):
        b = {k: v.to(device) for k, v in data.batch(idx[sel]).items()}
        out = net(b["x"])
        loss, parts = voxcnn_loss(out, b["label"], b["target"], cfg.pos_weight, cfg.occupancy_weight)
        m = len(sel)
        sums["loss"] += loss.item() * m
        for k, v in parts.items():
            sums[k] += v * m
        n += m
        correct += int((out["logits"].argmax(1) == b["label"]).sum())
        pred, tgt = out["occupancy"] >= 0, b["target"] > 0.5
        inter = (pred & tgt).flatten(1).sum(1).float()
        union = (pred | tgt).flatten(1).sum(1).float()
        ious.append(torch.where(union > 0, inter / union.clamp_min(1), torch.ones_like(union)).cpu())
    net.train(was)
    if n == 0:
        return {}
    return {**{k: v / n for k, v in sums.items()}, "accuracy": correct / n, "iou": float(torch.cat(ious).mean())}


def train_loop(net_cfg: VoxCNNConfig, data: PartialSet, train_idx, val_idx, out_dir,
               cfg: VoxTrainConfig | None = None, stop_after_epoch: int | None = None) -> VoxCNN:
    """Train (or resume training) VoxCNN on views ``train_idx`` of ``data``; validation on ``val_idx``.

    The pattern of :func:`hbeo.model.train.train`: AdamW, linear warm-up then cosine decay, an atomic
    ``checkpoint.pt`` and ``train_log.csv`` in ``out_dir`` after every epoch; a rerun resumes from
    the checkpoint and ends with the same weights as an uninterrupted run (data order depends on
    seed and epoch only). ``stop_after_epoch`` ends early (to simulate an interruption). On a CPU
    it runs with ``cfg.threads`` torch threads (:func:`cpu_threads`)."""
    cfg = cfg or VoxTrainConfig()
    if pick_device(cfg.device).type != "cpu":
        return _train_loop(net_cfg, data, train_idx, val_idx, out_dir, cfg, stop_after_epoch)
    with cpu_threads(cfg.threads):
        return _train_loop(net_cfg, data, train_idx, val_idx, out_dir, cfg, stop_after_epoch)


def _train_loop(net_cfg, data, train_idx, val_idx, out_dir, cfg, stop_after_epoch):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    device = pick_device(cfg.device)
    seed_everything(cfg.seed)
    net = VoxCNN(net_cfg).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    train_idx, val_idx = np.asarray(train_idx, np.int64), np.asarray(val_idx, np.int64)
    if len(train_idx) == 0:
        raise ValueError("train_loop: no training views")
    total_steps = math.ceil(len(train_idx) / cfg.batch_size) * cfg.epochs
    start_epoch, step, history = 0, 0, []
    ckpt_path, log_path = out / CHECKPOINT, out / LOG
    if ckpt_path.exists():
        try:
            ck = torch.load(ckpt_path, map_location=device, weights_only=False)
        except Exception as err:
            raise DataError(ckpt_path, f"not a readable checkpoint ({type(err).__name__}: {err}); "
                                       f"delete it to start again") from None
        if ck.get("kind") != KIND or ck.get("net_cfg") != net_cfg.to_dict():
            raise ValueError(f"{ckpt_path}: checkpoint is for another network configuration; "
                             f"use another output folder or delete it")
        old_cfg, new_cfg = ck.get("train_cfg", {}), cfg.to_dict()
        if diff := [k for k in new_cfg if k not in ("progress", "device", "threads")
                    and old_cfg.get(k) != new_cfg[k]]:
            details = ", ".join(f"{k} {old_cfg.get(k)!r} there, {new_cfg[k]!r} now" for k in diff)
            raise ValueError(f"{ckpt_path}: checkpoint was trained with other settings ({details}); "
                             f"use another output folder or delete it")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        start_epoch, step, history = ck["epoch"] + 1, ck["step"], ck["history"]
        torch.set_rng_state(ck["torch_rng"])
    net.train()
    for epoch in range(start_epoch, cfg.epochs):
        gen = torch.Generator().manual_seed(cfg.seed * 100_003 + epoch)   # data order depends on epoch only
        n_batches = math.ceil(len(train_idx) / cfg.batch_size)
        bar = tqdm(_batches(len(train_idx), cfg.batch_size, gen), total=n_batches,
                   desc=f"voxcnn epoch {epoch + 1}/{cfg.epochs}", disable=not cfg.progress, leave=False)
        t0, seen, run_loss = time.perf_counter(), 0, 0.0
        for sel in bar:
            b = {k: v.to(device) for k, v in data.batch(train_idx[sel]).items()}
            for g in opt.param_groups:
                g["lr"] = lr_at(step, total_steps, cfg)
            outp = net(b["x"])
            loss, _ = voxcnn_loss(outp, b["label"], b["target"], cfg.pos_weight, cfg.occupancy_weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
            opt.step()
            step += 1
            seen += len(sel)
            run_loss += loss.item() * len(sel)
            bar.set_postfix(loss=f"{loss.item():.3f}", grids_s=f"{seen / (time.perf_counter() - t0):.0f}")
        gps = seen / max(time.perf_counter() - t0, 1e-9)
        val = evaluate_partial(net, data, val_idx, device, cfg) if len(val_idx) else {}
        history.append({"epoch": epoch + 1, "step": step, "lr": lr_at(step, total_steps, cfg),
                        "train_loss": run_loss / max(seen, 1), "grids_per_s": gps,
                        **{f"val_{k}": v for k, v in val.items()}})
        _atomic_save({"kind": KIND, "model": net.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch,
                      "step": step, "torch_rng": torch.get_rng_state(), "history": history,
                      "net_cfg": net_cfg.to_dict(), "train_cfg": cfg.to_dict()}, ckpt_path)
        _write_log(history, log_path)
        if stop_after_epoch is not None and epoch + 1 >= stop_after_epoch:
            break
    net.eval()
    return net


def train_voxcnn(run, profile, epochs: int | None = None, seed: int = 0, progress: bool = True,
                 val_fraction: float = 0.1, stop_after_epoch: int | None = None,
                 out_name: str = "voxcnn.pt", threads: int | None = 0) -> "VoxCNNBaseline":
    """Train VoxCNN on the run's partial training grids (:func:`partial_training_set`) with the
    profile's sizes (:data:`PROFILES`), split by object for validation; checkpoints go to
    ``run/train_<stem>/`` (a rerun resumes exactly); writes ``run/<out_name>`` (atomically) once all
    epochs are done and returns the :class:`VoxCNNBaseline`. ``epochs`` overrides the profile's;
    ``stop_after_epoch`` ends early without writing the model file (to simulate an interruption);
    ``threads``: torch threads on a CPU (0 = half the cores, None = torch's setting; see :func:`cpu_threads`)."""
    run = Path(run)
    sizes = profile_sizes(profile)
    data = partial_training_set(run, sizes["views_per_object"], progress=progress)
    tr, va = data.split(val_fraction, seed)
    net_cfg = VoxCNNConfig(channels=sizes["channels"], n_classes=len(data.classes), bottleneck=sizes["bottleneck"])
    tc = VoxTrainConfig(epochs=int(epochs or sizes["epochs"]), batch_size=sizes["batch_size"], lr=sizes["lr"],
                        pos_weight=sizes["pos_weight"], seed=seed, progress=progress, threads=threads,
                        warmup_steps=min(100, max(1, len(tr) // sizes["batch_size"])))
    stem = Path(out_name).stem
    net = train_loop(net_cfg, data, tr, va, run / f"train_{stem}", tc, stop_after_epoch=stop_after_epoch)
    history = torch.load(run / f"train_{stem}" / CHECKPOINT, map_location="cpu", weights_only=False)["history"]
    settings = {"object_size": float(data.manifest.settings.object_size), "threshold": 0.5,
                "profile": profile.name if isinstance(profile, config.Profile) else str(profile),
                "views_per_object": int(data.meta["views_per_object"]), "train": tc.to_dict(),
                "final": history[-1] if history else {}}
    model = VoxCNNBaseline(net.cpu(), data.classes, settings)
    if len(history) >= tc.epochs:          # an interrupted run (stop_after_epoch) leaves no model file
        model.save(run / out_name)
    return model


# --------------------------------------------------------------------------- the baseline

class VoxCNNBaseline:
    """A trained VoxCNN with its class names and settings, in one file; known-pose inference."""

    def __init__(self, net: VoxCNN, classes, settings: dict | None = None):
        self.net = net.eval()
        self.classes = tuple(classes)
        self.settings = {"object_size": 1.0, "threshold": 0.5, **(settings or {})}
        if net.cfg.n_classes != len(self.classes):
            raise ValueError(f"network has {net.cfg.n_classes} classes, {len(self.classes)} names given")

    def save(self, path) -> Path:
        """Write the baseline to one file (atomically)."""
        blob = {"format_version": FORMAT_VERSION, "kind": KIND, "hbeo_version": __version__,
                "net_cfg": self.net.cfg.to_dict(), "state_dict": self.net.state_dict(),
                "classes": list(self.classes), "settings": self.settings}
        with atomic_file(path) as f:
            torch.save(blob, f)
        return Path(path)

    @classmethod
    def load(cls, path) -> "VoxCNNBaseline":
        """Read a file written by :meth:`save`; DataError naming the file on a missing, corrupt or
        incompatible one."""
        path = Path(path)
        if not path.is_file():
            raise DataError(path, "no such VoxCNN baseline file")
        try:
            blob = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as err:
            raise DataError(path, f"not a readable VoxCNN baseline file ({type(err).__name__}: {err})") from None
        if not isinstance(blob, dict) or blob.get("kind") != KIND:
            raise DataError(path, "not a VoxCNN baseline file")
        if blob.get("format_version") != FORMAT_VERSION:
            raise DataError(path, f"VoxCNN baseline format {blob.get('format_version')}, this hbeo ({__version__}) "
                                  f"reads format {FORMAT_VERSION}")
        try:
            net = VoxCNN(VoxCNNConfig.from_dict(blob["net_cfg"]))
            net.load_state_dict(blob["state_dict"])
            return cls(net, blob["classes"], blob["settings"])
        except Exception as err:
            raise DataError(path, f"inconsistent VoxCNN baseline file ({type(err).__name__}: {err})") from None

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
        f, k = _depth_partial(_partial_module(), depth, intrinsics, R, t_true, object_size)
        probs, occ = self.predict_partial(f, k)
        return {"probabilities": probs[0], "rotation": R, "grid": occ[0] >= self.settings["threshold"]}
