"""The training loop of every network in the project (HBEONet, the 3-D CNN baseline), in the
spirit of nanoGPT: one small function, :func:`train`.

A model enters through a :class:`TrainTask` (HBEONet's: :class:`hbeo.model.fit.HBEONetTask`; the
3-D CNN's: :class:`hbeo.baselines.voxcnn.VoxCNNTask`), which builds the ``nn.Module`` and says what
its loss and validation metrics are. The loop owns everything else: the device, CPU threads,
seeding, AdamW with linear warm-up then cosine decay (:func:`lr_at`), gradient clipping, mixed
precision on CUDA, ``max_steps``, data-parallel processes under ``torchrun``
(:mod:`hbeo.model.distributed`), tqdm, the CSV log, and checkpoints (atomic) after every epoch and
every ``checkpoint_every`` steps, from which a rerun with the same settings resumes exactly (model,
optimizer, schedule, RNG, data order and the position inside the epoch) and which a run with
other settings refuses.

Data enters as torch Datasets whose items are dicts of tensors (or numbers); one function,
:func:`data_loader`, turns them into batches (dicts whose values lead with the batch dimension):
it takes the epoch's order (:func:`epoch_order`: the dataset's own, e.g. shard by shard, or a
seeded permutation), this process's share of it and, on resume, skips the batches already done.

Checkpoints (``checkpoint.pt``, :data:`hbeo.rundir.CHECKPOINT`) hold only tensors and plain Python
values (configurations as dicts, RNG states as tensors and lists) and are read with
``torch.load(weights_only=True)``: nothing is unpickled. The CSV log (``train_log.csv``) has one
row per epoch: epoch, optimizer steps so far, learning rate, mean training loss (rank 0's examples),
training examples per second over all processes (``<unit>_per_s``) and the task's validation
metrics (``val_*``).

May import: foundation (hbeo.batches, hbeo.errors, hbeo.storage, hbeo.rundir), torch and
:mod:`hbeo.model.distributed`; no other model module.
"""
from __future__ import annotations

import csv
import math
import random
import time
from contextlib import contextmanager, nullcontext
from itertools import islice
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterable, Protocol

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset, IterableDataset
from hbeo.progress import tqdm

from hbeo.batches import collate
from hbeo.errors import DataError
from hbeo.limits import usable_cores
from hbeo.model import distributed
from hbeo.model.distributed import World, rank_slice
from hbeo.rundir import CHECKPOINT, RANKS, TRAIN_LOG
from hbeo.storage import atomic_file, json_text

CHECKPOINT_FORMAT = 1
#: TrainConfig fields that describe the machine, not the run: they may change between a run and its resume.
ENVIRONMENT = ("num_workers", "device", "threads", "progress", "checkpoint_every")


class TrainTask(Protocol):
    """What a model supplies to :func:`train`.

    ``kind`` names the model in checkpoints; ``unit`` names one example (the log's ``<unit>_per_s``).
    ``config()`` is a plain dict of everything that decides the model and its loss (checked on
    resume); ``build()`` makes the untrained module (called after seeding, so its initial weights
    depend on the seed only); ``loss(module, batch)`` returns the loss tensor to minimize and its
    parts as floats; ``validate(module, batches)`` returns metrics (floats) over an iterable of
    batches (already on the device; called in eval mode without gradients).
    """

    kind: str
    unit: str

    def config(self) -> dict: ...

    def build(self) -> nn.Module: ...

    def loss(self, module: nn.Module, batch: dict) -> tuple[torch.Tensor, dict[str, float]]: ...

    def validate(self, module: nn.Module, batches: Iterable[dict]) -> dict[str, float]: ...


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
    max_steps: int | None = None    #: stop after this many optimizer steps (the schedule ends there too)
    num_workers: int = 0
    device: str = "auto"            #: "auto", "cpu" or "cuda"
    amp: bool = True                #: mixed precision (CUDA only)
    #: the autocast type on CUDA: ``bfloat16`` (float32's range: no gradient scaler, nothing read back from the
    #: device) or ``float16`` (with torch's GradScaler)
    amp_dtype: str = "bfloat16"
    threads: int | None = None      #: torch threads on a CPU: None = torch's setting, 0 = half the cores
    progress: bool = True
    checkpoint_every: int | None = None   #: also write the checkpoint every this many steps (None: per epoch only)
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


class ValidationMeans:
    """Example-weighted means over validation batches of a task's loss, its parts and class accuracy,
    and the class-mean accuracy (the mean over the classes present of each class's accuracy: the
    paper's Table I total, whatever the validation objects' class mix); what every
    :meth:`TrainTask.validate` reports; the task adds its own metrics."""

    def __init__(self):
        self.sums: dict[str, float] = {}
        self.n = self.correct = 0
        self.per_class: dict[int, list[int]] = {}      #: label -> [correct, n]

    def add(self, loss: torch.Tensor, parts: dict[str, float], logits: torch.Tensor, labels: torch.Tensor) -> None:
        m = len(labels)
        for k, v in {"loss": loss, **parts}.items():
            self.sums[k] = self.sums.get(k, 0.0) + float(v) * m
        self.n += m
        hit = (logits.argmax(1) == labels).cpu().numpy()
        self.correct += int(hit.sum())
        for c, h in zip(labels.cpu().numpy().tolist(), hit.tolist()):
            cell = self.per_class.setdefault(int(c), [0, 0])
            cell[0] += int(h)
            cell[1] += 1

    def means(self) -> dict[str, float]:
        """{loss, each part, accuracy, class_mean_accuracy}; {} when no example was added."""
        if self.n == 0:
            return {}
        return {**{k: v / self.n for k, v in self.sums.items()}, "accuracy": self.correct / self.n,
                "class_mean_accuracy": float(np.mean([k / n for k, n in self.per_class.values()]))}


def lr_at(step: int, total: int, cfg: TrainConfig) -> float:
    """Linear warm-up to ``lr`` then cosine decay to ``lr * min_lr_ratio`` at step ``total``."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    progress = min(1.0, (step - cfg.warmup_steps) / max(1, total - cfg.warmup_steps))
    return cfg.lr * (cfg.min_lr_ratio + (1 - cfg.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress)))


def train_step(task, net, module, batch: dict, opt, scaler, lr: float, grad_clip: float, amp_dtype=None):
    """One optimizer step of the loop on ``batch`` (already on the device): the learning rate set, the loss under
    autocast to ``amp_dtype`` (None: none), backward through ``scaler`` (a disabled one for bfloat16 or none), the
    gradients clipped to ``grad_clip``, the step. ``net`` is what runs the batch (``module`` or its
    data-parallel wrapper), ``module`` whose parameters are clipped. Reads nothing back from the device; returns
    the loss (a device tensor)."""
    for g in opt.param_groups:
        g["lr"] = lr
    with torch.autocast(batch_device(batch).type, dtype=amp_dtype or torch.float32, enabled=amp_dtype is not None):
        loss, _ = task.loss(net, batch)
    opt.zero_grad(set_to_none=True)
    scaler.scale(loss).backward()
    scaler.unscale_(opt)
    torch.nn.utils.clip_grad_norm_(module.parameters(), grad_clip)
    scaler.step(opt)
    scaler.update()
    return loss


def batch_device(batch: dict) -> torch.device:
    """The device of a batch's first tensor."""
    return next(v.device for v in batch.values() if torch.is_tensor(v))


#: on a GPU the progress bar reads the loss (a host wait) every this many steps only
BAR_EVERY = 50


def optimizer(params, cfg: TrainConfig, device: torch.device) -> torch.optim.AdamW:
    """The loop's AdamW. On CUDA its fused kernel: one launch for all parameters instead of a few per group,
    and the AMP gradient scaler's step then hands it the inf/NaN flag on the device instead of reading it
    back (``GradScaler.step`` calls ``.item()`` for other optimizers: a host wait every step, while a small
    network's kernels take less time than their launches). Elsewhere torch's default implementation, as
    before: the CPU's trainings and their committed weights are unchanged."""
    return torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay,
                             fused=True if device.type == "cuda" else None)


@contextmanager
def cpu_threads(n: int | None):
    """Run the block with ``n`` torch threads (0 = half the usable cores, at least one; None =
    unchanged), then restore the previous count. Why: on a 2-core machine shared with other jobs,
    3-D CNN training steps took 3-10x longer with two threads than with one (every small 3-D
    operation waits for its slowest thread, which another process may have pushed off its core)."""
    before = torch.get_num_threads()
    if n is None:
        yield before
        return
    cores = usable_cores(fallback=2)
    torch.set_num_threads(max(1, cores // 2) if n == 0 else int(n))
    try:
        yield torch.get_num_threads()
    finally:
        torch.set_num_threads(before)


def epoch_order(dataset: Dataset, cfg: TrainConfig, epoch: int) -> np.ndarray:
    """The indices of a map-style ``dataset`` in the training order of ``epoch``, from (seed, epoch)
    only, the same in every process: the dataset's own ``epoch_sampler(seed, epoch)`` when it has
    one (e.g. shard by shard), otherwise a permutation from a generator seeded with (seed, epoch)
    (drawn as torch's DataLoader drew it before this function existed, so earlier runs repeat)."""
    if hasattr(dataset, "epoch_sampler"):
        return np.fromiter((int(i) for i in dataset.epoch_sampler(cfg.seed, epoch)), np.int64)
    gen = torch.Generator().manual_seed(cfg.seed * 100_003 + epoch)
    torch.empty((), dtype=torch.int64).random_(generator=gen)      # the loader's base seed came first
    return torch.randperm(len(dataset), generator=gen).numpy()


def data_loader(dataset: Dataset, cfg: TrainConfig, epoch: int | None = None, world: World = World(),
                skip_batches: int = 0) -> DataLoader:
    """The one place a dataset becomes batches. ``epoch``: the training order of that epoch
    (:func:`epoch_order`), this process's share of it (:func:`hbeo.model.distributed.rank_slice`),
    without its first ``skip_batches`` batches (a resumed run); None: validation, in order.

    A dataset with ``set_epoch`` is told the epoch first (e.g. views rendered on the fly draw that
    epoch's poses). An iterable dataset orders itself; in a data-parallel run it must offer
    ``shard(rank, size)``, and skipping batches is the caller's business. Training loaders draw
    their worker seeds from a generator of their own, so making one leaves torch's global
    generator alone (validation loaders take theirs from it, as torch does)."""
    if epoch is None:
        return DataLoader(dataset, batch_size=cfg.batch_size, shuffle=False, num_workers=cfg.num_workers,
                          collate_fn=collate)
    if hasattr(dataset, "set_epoch"):
        dataset.set_epoch(epoch)
    gen = torch.Generator().manual_seed(cfg.seed * 100_003 + epoch)
    if isinstance(dataset, IterableDataset):
        if world.parallel:
            if not hasattr(dataset, "shard"):
                raise ValueError(f"{type(dataset).__name__} cannot be split between processes (no shard method)")
            dataset.shard(world.rank, world.size)
        return DataLoader(dataset, batch_size=cfg.batch_size, num_workers=cfg.num_workers, generator=gen,
                          collate_fn=collate)
    mine = rank_slice(epoch_order(dataset, cfg, epoch), world)
    order = mine[skip_batches * cfg.batch_size:]
    if hasattr(dataset, "plan_reads"):     # the order it will be read in, and where that starts in the epoch's
        dataset.plan_reads(order, (world.rank * len(mine) if world.parallel else 0) + skip_batches * cfg.batch_size)
    return DataLoader(dataset, batch_size=cfg.batch_size, sampler=order, num_workers=cfg.num_workers,
                      generator=gen, collate_fn=collate)


def _to(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}


def _batch_len(batch: dict) -> int:
    return len(next(v for v in batch.values() if torch.is_tensor(v)))


# --------------------------------------------------------------------------- checkpoint contents

def _plain(obj, where: str = "checkpoint"):
    """``obj`` with tuples as lists and numpy scalars as Python numbers; TypeError on anything that
    is not a tensor, dict, list, str, int, float, bool or None (what ``weights_only`` loads)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v, f"{where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, (str, int, float, bool, torch.Tensor)):
        return obj
    raise TypeError(f"{where}: {type(obj).__name__} is not a tensor or plain Python value")


def rng_state() -> dict:
    """torch's (CPU and CUDA), numpy's and Python's global generator states, as tensors and plain values."""
    _, keys, pos, has_gauss, cached = np.random.get_state()
    version, internal, gauss_next = random.getstate()
    return {"torch": torch.get_rng_state(),
            "cuda": list(torch.cuda.get_rng_state_all()) if torch.cuda.is_available() else [],
            "numpy": {"keys": keys.tolist(), "pos": int(pos), "has_gauss": int(has_gauss),
                      "cached_gaussian": float(cached)},
            "python": {"version": version, "state": list(internal), "gauss_next": gauss_next}}


def set_rng_state(state: dict) -> None:
    """Restore what :func:`rng_state` returned."""
    torch.set_rng_state(state["torch"].cpu())
    if state["cuda"] and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda"]])
    n = state["numpy"]
    np.random.set_state(("MT19937", np.array(n["keys"], np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"]))
    p = state["python"]
    random.setstate((p["version"], tuple(p["state"]), p["gauss_next"]))


def save_checkpoint(ck: dict, path) -> None:
    """Write a checkpoint atomically (its values must be tensors or plain Python values)."""
    with atomic_file(path) as f:
        torch.save(ck, f)


def load_checkpoint(path) -> dict:
    """A checkpoint written by :func:`train`, on the CPU, read with ``weights_only=True``;
    DataError naming the file when it cannot be read that way or is not one."""
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:
        first = (str(err).strip().splitlines() or [""])[0]
        raise DataError(path, f"not a readable checkpoint ({type(err).__name__}: {first}); delete it to "
                              f"start again") from None
    if not isinstance(ck, dict) or ck.get("format_version") != CHECKPOINT_FORMAT:
        got = ck.get("format_version") if isinstance(ck, dict) else None
        raise DataError(path, f"checkpoint format {got}, this hbeo writes {CHECKPOINT_FORMAT}; delete it to "
                              f"start again")
    return ck


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) and v else {f"{prefix}{k}": v})
    return out


def _check_resume(path: Path, ck: dict, kind: str, settings: dict) -> None:
    """DataError unless checkpoint ``ck`` was made by the same kind of model with the same settings."""
    if ck.get("kind") != kind:
        raise DataError(path, f"checkpoint is for a {ck.get('kind')} model, not {kind}; use another output "
                              f"folder or delete it")
    was, now = _flat(ck["settings"]), _flat(settings)
    if diff := [k for k in sorted(set(was) | set(now)) if was.get(k) != now.get(k)]:
        details = ", ".join(f"{k} {was.get(k)!r} there, {now.get(k)!r} now" for k in diff)
        raise DataError(path, f"checkpoint was made with other settings ({details}); use another output "
                              f"folder or delete it")


def write_log(history: list[dict], path) -> None:
    """The whole CSV log (one row per epoch) from the checkpoint's history, written atomically."""
    with atomic_file(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for row in history for k in row)))
        w.writeheader()
        w.writerows(history)


# --------------------------------------------------------------------------- the loop

@torch.no_grad()
def _validate(task: TrainTask, module: nn.Module, val_set, cfg: TrainConfig, device) -> dict:
    module.eval()
    try:
        metrics = task.validate(module, (_to(b, device) for b in data_loader(val_set, cfg)))
    finally:
        module.train()
    return {k: float(v) for k, v in metrics.items()}


def train(task: TrainTask, train_set: Dataset, val_set: Dataset | None, out_dir, cfg: TrainConfig | None = None,
          stop_after_epoch: int | None = None, stop_after_step: int | None = None) -> nn.Module:
    """Train (or resume training) ``task``'s module; returns it (eval mode, unwrapped) after the last step.

    ``out_dir`` (:meth:`hbeo.rundir.RunDir.training`) receives ``checkpoint.pt`` and ``train_log.csv``
    after every epoch, every ``cfg.checkpoint_every`` steps, and after the last step. A rerun with
    the same settings resumes from the checkpoint (mid-epoch too) and ends with the weights an
    uninterrupted run would have (exactly, with ``num_workers`` 0); one with other settings
    (model, loss, schedule, data, number of processes; not :data:`ENVIRONMENT`) is refused
    (DataError). ``val_set`` None: no validation. ``stop_after_epoch`` ends early after that epoch's
    checkpoint; ``stop_after_step`` returns at once after that step, writing nothing (a kill; both
    simulate interruptions in tests).

    Under ``torchrun`` (:mod:`hbeo.model.distributed`) every process trains its share of each epoch
    with gradients averaged by DDP; rank 0 alone validates and writes the checkpoint and log, and at
    the end every rank's weights digest is compared and written to ``ranks.json``."""
    cfg = cfg or TrainConfig()
    w = distributed.setup(cfg.device)
    device = pick_device(cfg.device)
    if device.type == "cuda" and w.parallel:
        device = torch.device("cuda", torch.cuda.current_device())
    with nullcontext() if device.type == "cuda" else cpu_threads(cfg.threads):
        return _train(task, train_set, val_set, Path(out_dir), cfg, device, w, stop_after_epoch, stop_after_step)


def _checkpoint(ck_path, log_path, base: dict, module, opt, scaler, epoch_done: int, step: int, history: list,
                in_epoch: dict | None = None) -> None:
    save_checkpoint({**base, "model": distributed.unwrap(module).state_dict(), "optimizer": opt.state_dict(),
                     "scaler": scaler.state_dict(), "epoch": epoch_done, "step": step, "rng": rng_state(),
                     "history": history, **({"in_epoch": in_epoch} if in_epoch else {})}, ck_path)
    write_log(history, log_path)


def _train(task, train_set, val_set, out, cfg, device, w, stop_after_epoch, stop_after_step):
    if len(train_set) == 0:
        raise ValueError(f"{out}: the training set is empty")
    if cfg.max_steps is not None and cfg.max_steps < 1:
        raise ValueError(f"max_steps must be >= 1 or None, got {cfg.max_steps}")
    if cfg.checkpoint_every is not None and cfg.checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be >= 1 or None, got {cfg.checkpoint_every}")
    train_settings = {k: v for k, v in cfg.to_dict().items() if k not in ENVIRONMENT}
    if w.parallel:                        # the schedule depends on it; a lone process keeps its old settings
        train_settings["world_size"] = w.size
    if torch.device(device).type != "cuda" or not cfg.amp:   # autocast runs on CUDA only: elsewhere its type is
        train_settings.pop("amp_dtype", None)                 # moot, and checkpoints made before it existed resume
    settings = _plain({"model": task.config(), "train": train_settings})
    seed_everything(cfg.seed)
    module = task.build().to(device)
    if w.parallel:                        # same initial weights everywhere, other dropout/augmentation draws
        seed_everything(cfg.seed * 1_000 + w.rank)
    opt = optimizer(module.parameters(), cfg, device)
    use_amp = cfg.amp and device.type == "cuda"
    if cfg.amp_dtype not in ("bfloat16", "float16"):
        raise ValueError(f"amp_dtype must be bfloat16 or float16, got {cfg.amp_dtype!r}")
    amp_dtype = torch.bfloat16 if cfg.amp_dtype == "bfloat16" else torch.float16
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)
    if device.type == "cuda":             # fixed input sizes: let cuDNN pick its fastest kernels once
        torch.backends.cudnn.benchmark = True
    total_steps = len(data_loader(train_set, cfg, 0, w)) * cfg.epochs
    if cfg.max_steps is not None:
        total_steps = min(total_steps, cfg.max_steps)
    start_epoch, step, history, in_epoch, rng = 0, 0, [], None, None
    ckpt_path, log_path = out / CHECKPOINT, out / TRAIN_LOG
    if ckpt_path.exists():
        ck = load_checkpoint(ckpt_path)
        _check_resume(ckpt_path, ck, task.kind, settings)
        module.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        scaler.load_state_dict(ck["scaler"])
        start_epoch, step, history, in_epoch = ck["epoch"] + 1, ck["step"], ck["history"], ck.get("in_epoch")
        rng = ck["rng"]
        if w.main and history and not log_path.exists():     # a checkpoint brought without its log (copied)
            write_log(history, log_path)
        if w.parallel:                    # the checkpoint holds rank 0's generators only
            rng = None
            seed_everything(cfg.seed * 1_000 + w.rank + 7_919 * step)
    base = {"format_version": CHECKPOINT_FORMAT, "kind": task.kind, "settings": settings}
    net = distributed.wrap(module, w, device)
    net.train()
    for epoch in range(start_epoch, cfg.epochs):
        if step >= total_steps:           # max_steps reached (in a run this call resumed)
            break
        skip = in_epoch["batches"] if in_epoch else 0
        loader = data_loader(train_set, cfg, epoch, w, skip)
        batches = iter(loader)
        if skip and isinstance(train_set, IterableDataset):
            batches = islice(batches, skip, None)
        if rng is not None:               # after the loader exists, as in the run that wrote the checkpoint
            set_rng_state(rng)
            rng = None
        done, seen, loss_sum, elapsed = skip, *((in_epoch["seen"], in_epoch["loss_sum"], in_epoch["elapsed"])
                                                if in_epoch else (0, 0.0, 0.0))
        # the epoch's summed loss stays on the device (float64, the same sums as on the host): reading a
        # loss every step would make the host wait for the device at each one
        run_loss = torch.tensor(loss_sum, dtype=torch.float64, device=device)
        in_epoch = None
        n_batches = len(loader) + (0 if isinstance(train_set, IterableDataset) else skip)
        bar = tqdm(batches, total=n_batches, initial=skip, disable=not (cfg.progress and w.main),
                   desc=f"{task.kind} epoch {epoch + 1}/{cfg.epochs}", leave=False)
        t0 = time.perf_counter() - elapsed
        for batch in bar:
            batch = _to(batch, device)
            loss = train_step(task, net, module, batch, opt, scaler, lr_at(step, total_steps, cfg), cfg.grad_clip,
                              amp_dtype if use_amp else None)
            step += 1
            done += 1
            n = _batch_len(batch)
            seen += n
            run_loss += loss.detach().double() * n
            if not bar.disable and (device.type != "cuda" or step % BAR_EVERY == 0):   # .item() waits on a GPU
                bar.set_postfix({"loss": f"{loss.item():.3f}",
                                 f"{task.unit}_s": f"{seen / (time.perf_counter() - t0):.0f}"})
            if stop_after_step is not None and step >= stop_after_step:
                return module.eval()      # a kill: nothing written since the last checkpoint
            if step >= total_steps:
                break
            if cfg.checkpoint_every and step % cfg.checkpoint_every == 0 and done < n_batches and w.main:
                _checkpoint(ckpt_path, log_path, base, module, opt, scaler, epoch - 1, step, history,
                            {"batches": done, "seen": seen, "loss_sum": float(run_loss),
                             "elapsed": time.perf_counter() - t0})
        # the host runs ahead of a GPU (no reads in the step): wait for the queued kernels, so that the epoch's
        # images/s counts them (the device job chooses its steps from a calibration's)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        elapsed = time.perf_counter() - t0
        if w.main:
            val = _validate(task, module, val_set, cfg, device) if val_set is not None else {}
            history.append(_plain({"epoch": epoch + 1, "step": step, "lr": lr_at(step, total_steps, cfg),
                                   "train_loss": float(run_loss) / max(seen, 1),
                                   f"{task.unit}_per_s": seen * w.size / max(elapsed, 1e-9),
                                   **{f"val_{k}": v for k, v in val.items()}}))
            _checkpoint(ckpt_path, log_path, base, module, opt, scaler, epoch, step, history)
        distributed.barrier()
        if stop_after_epoch is not None and epoch + 1 >= stop_after_epoch:
            break
    if w.parallel:
        digests = distributed.agree(module, w)
        if w.main:
            with atomic_file(out / RANKS, "w") as f:
                f.write(json_text({"world_size": w.size, "backend": torch.distributed.get_backend(), "step": step,
                                   "weights_sha256": digests}, indent=2))
    return module.eval()


def training_history(out_dir) -> list[dict]:
    """The per-epoch rows (as in ``train_log.csv``) of the checkpoint in ``out_dir``; [] without one."""
    path = Path(out_dir) / CHECKPOINT
    return load_checkpoint(path)["history"] if path.exists() else []
