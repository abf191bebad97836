"""Training HBEONet: a plain loop in the spirit of nanoGPT.

AdamW with linear warm-up then cosine decay, channels_last, mixed precision on CUDA,
a checkpoint after every epoch (atomic) from which a rerun resumes exactly (model,
optimizer, schedule, RNG and data order), a CSV log and tqdm with loss and images/s.
Batches are dicts of tensors as yielded by :mod:`hbeo.render.renderset` datasets:
``depth`` (B, 1, H, W) metres, ``label`` (B,), ``rotation`` (B, 3, 3),
``axis_angle`` (B, 3), ``coeffs`` (B, k).
"""
from __future__ import annotations

import csv
import math
import random
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from hbeo.storage import atomic_file
from hbeo.conventions import geodesic_deg
from hbeo.model.network import HBEONet, LossWeights, NetConfig, hbeo_loss

CHECKPOINT = "checkpoint.pt"
LOG = "train_log.csv"


@dataclass
class TrainConfig:
    epochs: int = 10
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    min_lr_ratio: float = 0.05
    grad_clip: float = 5.0
    seed: int = 0
    loss: LossWeights = field(default_factory=LossWeights)
    num_workers: int = 0
    device: str = "auto"            #: "auto", "cpu" or "cuda"
    amp: bool = True                #: mixed precision (CUDA only)
    progress: bool = True
    data: dict = field(default_factory=dict)   #: how the data was made (e.g. augmentation); checked on resume

    def to_dict(self) -> dict:
        return asdict(self)


def pick_device(name: str = "auto") -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def lr_at(step: int, total: int, cfg: TrainConfig) -> float:
    """Linear warm-up to ``lr`` then cosine decay to ``lr * min_lr_ratio``."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    progress = min(1.0, (step - cfg.warmup_steps) / max(1, total - cfg.warmup_steps))
    return cfg.lr * (cfg.min_lr_ratio + (1 - cfg.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress)))


def _to(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}


def _grid(net: HBEONet):
    """The rotation-bin grid (N, 3, 3) of a ``bins`` network, else None."""
    return getattr(net, "bin_rotations", None)


@torch.no_grad()
def evaluate_batches(net: HBEONet, loader, device, coeff_scale, weights: LossWeights) -> dict:
    """Mean loss parts, accuracy and median geodesic pose error (degrees) over a loader."""
    net.eval()
    sums, n, correct, errors = {"loss": 0.0, "ce": 0.0, "pose": 0.0, "coeff": 0.0}, 0, 0, []
    for batch in loader:
        batch = _to(batch, device)
        out = net(batch["depth"])
        loss, parts = hbeo_loss(out, batch, net.cfg, weights, coeff_scale, _grid(net))
        b = len(batch["label"])
        sums["loss"] += loss.item() * b
        for k, v in parts.items():
            sums[k] += v * b
        n += b
        correct += int((out["logits"].argmax(1) == batch["label"]).sum())
        R = net.pose_matrix(out["pose"].float()).cpu().numpy()
        errors.append(geodesic_deg(R, batch["rotation"].cpu().numpy()))
    net.train()
    if n == 0:
        return {}
    return {**{k: v / n for k, v in sums.items()}, "accuracy": correct / n,
            "pose_median_deg": float(np.median(np.concatenate(errors)))}


def _atomic_save(obj, path: Path) -> None:
    with atomic_file(path) as f:
        torch.save(obj, f)


def _write_log(history: list[dict], path: Path) -> None:
    """The whole CSV log from the checkpoint's history, written atomically."""
    with atomic_file(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(history[0]))
        w.writeheader()
        w.writerows(history)


def train(net_cfg: NetConfig, train_set, val_set, out_dir, cfg: TrainConfig | None = None,
          coeff_scale: torch.Tensor | None = None, stop_after_epoch: int | None = None) -> HBEONet:
    """Train (or resume training) HBEONet; returns the network after the last epoch.

    ``out_dir`` receives ``checkpoint.pt`` after every epoch and ``train_log.csv``. A rerun with
    the same arguments resumes from the checkpoint and gives the same result as an
    uninterrupted run. ``coeff_scale`` (k,) divides coefficient errors (default: ones).
    ``stop_after_epoch`` ends early after that epoch (to simulate an interruption in tests).
    """
    cfg = cfg or TrainConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    device = pick_device(cfg.device)
    seed_everything(cfg.seed)
    net = HBEONet(net_cfg).to(device).to(memory_format=torch.channels_last)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    use_amp = cfg.amp and device.type == "cuda"
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp)
    scale = (coeff_scale if coeff_scale is not None else torch.ones(net_cfg.n_coeffs)).to(device)
    steps_per_epoch = math.ceil(len(train_set) / cfg.batch_size)
    total_steps = steps_per_epoch * cfg.epochs
    start_epoch, step, history = 0, 0, []
    ckpt_path, log_path = out / CHECKPOINT, out / LOG
    if ckpt_path.exists():
        ck = torch.load(ckpt_path, map_location=device, weights_only=False)
        if ck["net_cfg"] != net_cfg.to_dict():
            raise ValueError(f"{ckpt_path}: checkpoint is for another network configuration; "
                             f"use another output folder or delete it")
        was = ck.get("train_cfg", {})
        for key, now in (("loss", cfg.to_dict()["loss"]), ("data", cfg.data)):
            if key in was and was[key] != now:       # (checkpoints from before "data" existed: not checked)
                raise ValueError(f"{ckpt_path}: checkpoint was trained with {key} {was[key]}, this run asks "
                                 f"for {now}; use another output folder (--name) or delete it")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        scaler.load_state_dict(ck["scaler"])
        start_epoch, step, history = ck["epoch"] + 1, ck["step"], ck["history"]
        torch.set_rng_state(ck["torch_rng"])
    val_loader = DataLoader(val_set, batch_size=cfg.batch_size, shuffle=False, num_workers=cfg.num_workers)
    net.train()
    for epoch in range(start_epoch, cfg.epochs):
        gen = torch.Generator().manual_seed(cfg.seed * 100_003 + epoch)   # data order depends on epoch only
        loader = DataLoader(train_set, batch_size=cfg.batch_size, shuffle=True, generator=gen,
                            num_workers=cfg.num_workers, drop_last=False)
        bar = tqdm(loader, desc=f"epoch {epoch + 1}/{cfg.epochs}", disable=not cfg.progress, leave=False)
        t0, seen, run_loss = time.perf_counter(), 0, 0.0
        for batch in bar:
            batch = _to(batch, device)
            for g in opt.param_groups:
                g["lr"] = lr_at(step, total_steps, cfg)
            with torch.autocast(device.type, enabled=use_amp):
                outp = net(batch["depth"].contiguous(memory_format=torch.channels_last))
                loss, parts = hbeo_loss(outp, batch, net_cfg, cfg.loss, scale, _grid(net))
            opt.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.unscale_(opt)
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
            scaler.step(opt)
            scaler.update()
            step += 1
            seen += len(batch["label"])
            run_loss += loss.item() * len(batch["label"])
            bar.set_postfix(loss=f"{loss.item():.3f}", img_s=f"{seen / (time.perf_counter() - t0):.0f}")
        ips = seen / max(time.perf_counter() - t0, 1e-9)
        val = evaluate_batches(net, val_loader, device, scale, cfg.loss)
        row = {"epoch": epoch + 1, "step": step, "lr": lr_at(step, total_steps, cfg),
               "train_loss": run_loss / max(seen, 1), "images_per_s": ips,
               **{f"val_{k}": v for k, v in val.items()}}
        history.append(row)
        _atomic_save({"model": net.state_dict(), "optimizer": opt.state_dict(), "scaler": scaler.state_dict(),
                      "epoch": epoch, "step": step, "torch_rng": torch.get_rng_state(), "history": history,
                      "net_cfg": net_cfg.to_dict(), "train_cfg": cfg.to_dict()}, ckpt_path)
        _write_log(history, log_path)
        if stop_after_epoch is not None and epoch + 1 >= stop_after_epoch:
            break
    net.eval()
    return net
