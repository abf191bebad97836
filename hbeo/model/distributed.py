"""Data-parallel training across processes (``torchrun``): who this process is, the process group,
how an epoch's examples are dealt out, and the check that every process ends with the same weights.

A process started by ``torchrun`` finds ``RANK``, ``WORLD_SIZE`` and ``LOCAL_RANK`` in its
environment (:func:`world`); without them it is the only process (rank 0 of 1) and nothing here
does anything. :func:`setup` joins the process group once (``gloo`` on a CPU, ``nccl`` on CUDA;
the rendezvous address comes from torchrun's ``MASTER_ADDR``/``MASTER_PORT``). Rank 0 ("main")
alone prepares shared files (grids, subspace, renderings), validates, writes checkpoints, logs and
model files; the others wait for it at :func:`barrier`. Multi-node runs need the output folder on a
file system every node sees (the ranks resume from rank 0's checkpoint).

The data of one epoch: the epoch's order of examples (the same in every process, from the seed and
the epoch) is padded by wrapping round to a multiple of the number of processes and cut into
contiguous equal slices, one per rank (:func:`rank_slice`; contiguous so a shard-by-shard order
stays shard by shard). Every rank therefore takes the same number of steps; the batch of one step
is ``batch_size`` examples per process (``world_size * batch_size`` in all).

May import: foundation and torch; no other model module.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel


@dataclass(frozen=True)
class World:
    """This process's place among the processes of one training run."""

    rank: int = 0
    size: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """True for the process that writes files (rank 0)."""
        return self.rank == 0

    @property
    def parallel(self) -> bool:
        return self.size > 1


def world() -> World:
    """This process's :class:`World` from torchrun's environment (``RANK``, ``WORLD_SIZE``,
    ``LOCAL_RANK``); rank 0 of 1 without them. ValueError when they are inconsistent."""
    try:
        size = int(os.environ.get("WORLD_SIZE", "1"))
        rank = int(os.environ.get("RANK", "0"))
        local = int(os.environ.get("LOCAL_RANK", str(rank)))
    except ValueError:
        raise ValueError(f"RANK/WORLD_SIZE/LOCAL_RANK must be integers, got RANK={os.environ.get('RANK')!r} "
                         f"WORLD_SIZE={os.environ.get('WORLD_SIZE')!r}") from None
    if size < 1 or not 0 <= rank < size:
        raise ValueError(f"RANK={rank} and WORLD_SIZE={size} do not describe a process of the run")
    return World(rank, size, local)


def setup(device: str = "auto") -> World:
    """Join the process group of a torchrun launch (once; later calls return at once) and return
    this process's :class:`World`; a lone process joins nothing. ``device`` picks the backend:
    ``nccl`` when this run trains on CUDA, ``gloo`` otherwise."""
    w = world()
    if w.parallel and not dist.is_initialized():
        cuda = device in ("auto", "cuda") and torch.cuda.is_available()
        if cuda:
            torch.cuda.set_device(w.local_rank % torch.cuda.device_count())
        dist.init_process_group("nccl" if cuda else "gloo")
    return w


def barrier() -> None:
    """Wait until every process of the run gets here (nothing for a lone process)."""
    if dist.is_available() and dist.is_initialized():
        dist.barrier()


def finish() -> None:
    """Leave the process group (nothing for a lone process)."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def rank_slice(order: np.ndarray, w: World) -> np.ndarray:
    """Rank ``w.rank``'s share of an epoch's ``order`` (example indices, the same in every process):
    padded by wrapping round to a multiple of ``w.size``, then cut into ``w.size`` contiguous equal
    slices. A lone process gets ``order`` itself."""
    order = np.asarray(order, np.int64)
    if not w.parallel:
        return order
    per = -(-len(order) // w.size)
    padded = np.resize(order, per * w.size)          # np.resize repeats the array to fill
    return padded[w.rank * per:(w.rank + 1) * per]


class DataParallel(DistributedDataParallel):
    """DistributedDataParallel that also answers for the wrapped module's own attributes (a task's
    loss may read e.g. ``net.bin_rotations``); the forward pass still goes through DDP."""

    def __getattr__(self, name):
        try:
            return super().__getattr__(name)
        except AttributeError:
            return getattr(self.module, name)


def wrap(module: nn.Module, w: World, device: torch.device) -> nn.Module:
    """``module`` for training in this process: itself alone, :class:`DataParallel` in a launch."""
    if not w.parallel:
        return module
    return DataParallel(module, device_ids=[device.index] if device.type == "cuda" else None)


def unwrap(module: nn.Module) -> nn.Module:
    return module.module if isinstance(module, DistributedDataParallel) else module


def weights_sha256(module: nn.Module) -> str:
    """sha256 of a module's state (names, dtypes, shapes and bytes, in order)."""
    h = hashlib.sha256()
    for name, t in unwrap(module).state_dict().items():
        t = t.detach().cpu().contiguous()
        h.update(f"{name}:{t.dtype}:{tuple(t.shape)};".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def agree(module: nn.Module, w: World) -> list[str]:
    """Give every rank rank 0's buffers (e.g. batch-norm running statistics, which DDP copies from
    rank 0 before each forward pass, so after the last one they are rank 0's in effect), then the
    sha256 of every rank's whole state (:func:`weights_sha256`, in rank order), gathered as raw bytes
    (nothing pickled); RuntimeError when they differ. A lone process: its own digest."""
    if not w.parallel:
        return [weights_sha256(module)]
    for b in unwrap(module).buffers():
        dist.broadcast(b.data, src=0)
    mine = weights_sha256(module)
    t = torch.frombuffer(bytearray(bytes.fromhex(mine)), dtype=torch.uint8)
    if dist.get_backend() == "nccl":
        t = t.cuda()
    out = [torch.empty_like(t) for _ in range(w.size)]
    dist.all_gather(out, t)
    digests = [bytes(o.cpu().numpy()).hex() for o in out]
    if len(set(digests)) != 1:
        raise RuntimeError(f"data-parallel ranks ended with different weights: {digests}")
    return digests
