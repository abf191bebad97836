"""What a batch is between a dataset and the training loop: :class:`Stacked`, the items of a batch a dataset
read together, kept stacked, and :func:`collate`, the loaders' ``collate_fn``
(:func:`hbeo.model.loop.data_loader`), which hands such a batch to the loop as it is.

A batch is a dict of tensors whose first dimension is the batch (B): for HBEONet ``depth`` (B, 1, H, W)
metres, ``label`` (B,) int64, ``rotation`` (B, 3, 3), ``axis_angle`` (B, 3), ``coeffs`` (B, K) float32 and
``object_index`` (B,) int64 (:mod:`hbeo.model.trainingdata`). Depends on torch only.
"""
from __future__ import annotations

import torch
from torch.utils.data import default_collate


class Stacked:
    """A batch's items kept stacked, as a dataset's ``__getitems__`` returns a batch it read together (the
    ray-marched views of :class:`hbeo.render.torch_datasets.FreshPoses`): ``batch``, a dict of tensors with
    the items along the first dimension. It reads as the sequence of its items (views of ``batch``);
    :func:`collate` hands the loop ``batch`` itself, where torch's default collation would index every
    tensor once an item and stack the pieces again: on a GPU six small launches an image and a stack a key,
    every step, while the device waits (measured on an H200: about half of a streamed step was host work
    between kernels; ``benchmarks/README.md``, *Training and evaluation on a GPU*)."""

    def __init__(self, batch: dict):
        if not batch or not all(torch.is_tensor(v) for v in batch.values()):
            raise TypeError("Stacked: a batch is a non-empty dict of tensors")
        n = {len(v) for v in batch.values()}
        if len(n) != 1:
            raise ValueError(f"Stacked: the batch's tensors lead with different lengths {sorted(n)}")
        self.batch, self._n = batch, n.pop()

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i: int) -> dict:
        if not -self._n <= i < self._n:
            raise IndexError(f"item {i} of a batch of {self._n}")
        return {k: v[i] for k, v in self.batch.items()}

    def __iter__(self):
        return (self[i] for i in range(self._n))


def collate(items) -> dict:
    """The loaders' ``collate_fn``: a :class:`Stacked` batch as it is (the values, shapes and dtypes torch's
    default collation would give by stacking its items), any other list of items by ``default_collate``."""
    if isinstance(items, Stacked):
        return dict(items.batch)
    return default_collate(items)
