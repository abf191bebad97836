"""Training images as torch datasets: the one place they become the network's items.

:func:`training_data` gives the training and validation data from one of three sources
(:data:`DATA_SOURCES`): the rendered set held in memory (:class:`ViewArrays`), the rendered set read
shard by shard, or views rendered on the fly. Every source gives the same items: views brought into the
model's input view exactly as :meth:`hbeo.model.inference.HBEO.predict` will
(:mod:`hbeo.model.preprocess`), standardized coefficient targets, optionally rolled, split by object into
training and validation (:func:`hbeo.data.datasets.validation_mask`: by object or by near-duplicate group);
``memory`` does that once at load (:class:`ViewArrays`), the others item by item (:func:`model_item` in
:class:`ModelView`; :class:`ModelViewStream` for validation views rendered in order), so their memory does
not grow with the number of images. :class:`ClassBalanced` and :func:`class_weights` are the class balance
options (:data:`CLASS_BALANCE`).

Items: ``depth`` (1, H, W) metres in the model's camera, ``label`` class index, ``rotation`` (3, 3) object
to camera, ``axis_angle`` (3,), ``coeffs`` (k,) standardized.

May import: foundation, data, subspace, render, and the hbeo.model modules below fit.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, Subset, get_worker_info
from hbeo.progress import tqdm

from hbeo.batches import Stacked
from hbeo.errors import DataError
from hbeo.limits import check_in_memory
from hbeo.data import datasets
from hbeo.data.datasets import VAL_SEED
from hbeo.data.gridset import run_gridsets
from hbeo.model import modelfile
from hbeo.model.augment import RollAugment, roll_item
from hbeo.model.mirror import MirrorAugment, mirror_targets
from hbeo.model.preprocess import to_model_view
from hbeo.render.torch_datasets import (DepthShards, FreshPoses, ShardSampler, StreamingDepth, load_shard, split_by_object,
                                        split_objects)
from hbeo.render.gridcast import auto_render_ahead
from hbeo.render.renderset import Manifest
from hbeo.render.views import RenderSettings
from hbeo.rotations import matrix_to_axis_angle
from hbeo.rundir import RunDir
from hbeo.subspace.basis import ObjectSubspace


#: Where training images come from (:func:`training_data`; ``python -m hbeo train --data``).
DATA_SOURCES = ("memory", "shards", "stream")
#: ``shards``: shards shuffled together (and held in memory) at a time (:class:`ShardSampler`).
SHARD_MIX = 8


#: How training counters the training split's class imbalance (ModelNet10: 9:1 between chair and bathtub;
#: ``python -m hbeo train --class-balance``, :attr:`hbeo.config.RecipeConfig.class_balance`): ``none`` (the
#: paper's), ``sampler`` (each epoch draws as many training images as it has, with replacement, image i with
#: weight 1 / its class's count: every class equally often; :class:`ClassBalanced`) or ``loss`` (the
#: cross-entropy weighted by inverse class frequency, mean weight 1 over the classes: :func:`class_weights`).
CLASS_BALANCE = modelfile.CLASS_BALANCE


@dataclass(frozen=True)
class ViewOptions:
    """How images enter the network (the same at training and prediction time).

    recenter: turn each view to look straight at the object; ref_distance: zoom and shift so the
    object centre appears at this many metres (distance-insensitive input). The paper does
    neither (its renderings are centred already).
    """

    recenter: bool = False
    ref_distance: float | None = None


def class_weights(counts) -> np.ndarray:
    """(C,) training examples per class -> (C,) float64 weights ``1 / count`` normalized to mean 1 over
    the classes that have examples (0 for a class with none): the ``loss`` class balance.

    >>> class_weights([1, 3]).tolist()
    [1.5, 0.5]
    """
    counts = np.asarray(counts, np.float64)
    if counts.ndim != 1 or (counts < 0).any() or not (counts > 0).any():
        raise ValueError(f"class_weights: counts must be (C,) non-negative with one positive, got {counts.tolist()}")
    inv = np.where(counts > 0, 1.0 / np.maximum(counts, 1e-300), 0.0)
    return inv / inv[counts > 0].mean()


class ClassBalanced(Dataset):
    """A training dataset whose epochs draw classes equally often: ``epoch_sampler(seed, epoch)`` gives
    ``len(base)`` item indices drawn with replacement, item i with weight 1 / (items of its class), from a
    generator seeded with (seed, epoch) only, so a run and its exact resume draw the same order
    (:func:`hbeo.model.loop.epoch_order`). Items, ``set_epoch`` and batch reads (``__getitems__``) are
    ``base``'s. ``labels`` (len(base),): each item's class index."""

    def __init__(self, base: Dataset, labels):
        labels = np.asarray(labels, np.int64)
        if labels.shape != (len(base),):
            raise ValueError(f"ClassBalanced: {len(labels)} labels for {len(base)} items")
        self.base, self.labels = base, labels
        self.weights = torch.from_numpy(1.0 / np.bincount(labels)[labels])

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        return self.base[i]

    def __getitems__(self, indices):
        if getattr(self.base, "__getitems__", None):
            return self.base.__getitems__(indices)
        return [self.base[i] for i in indices]

    def plan_reads(self, order, start: int = 0) -> None:
        if hasattr(self.base, "plan_reads"):
            self.base.plan_reads(order, start)

    def set_epoch(self, epoch: int) -> None:
        if hasattr(self.base, "set_epoch"):
            self.base.set_epoch(epoch)

    def epoch_sampler(self, seed: int, epoch: int) -> np.ndarray:
        gen = torch.Generator().manual_seed(seed * 100_003 + epoch)
        return torch.multinomial(self.weights, len(self.labels), replacement=True, generator=gen).numpy()


class ViewArrays(Dataset):
    """A rendered set held in memory, in the model's input view. Items: ``depth`` (1, H, W) float32
    metres, ``label``, ``rotation`` (3, 3) and ``axis_angle`` (3,) in the input view's camera,
    ``coeffs`` (k,) standardized with ``coeff_mean`` / ``coeff_std``, ``object_index``."""

    def __init__(self, manifest, opts: ViewOptions, coeff_mean=None, coeff_std=None, progress=True):
        m = Manifest.load(manifest)
        K = m.settings.intrinsics
        check_in_memory(m.n_images, m.settings.image_size, m.coeffs_dim or 0, f"{m.root}")   # before loading
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


def model_item(raw: dict, K, opts: ViewOptions, coeff_mean, coeff_std) -> dict:
    """One view as a rendered set gives it (a :class:`DepthShards` / :class:`StreamingDepth` item)
    -> the item :class:`ViewArrays` holds for it: the same arithmetic, so the three data sources
    feed the loop the same items."""
    d, R = raw["depth"][0].numpy().astype(np.float32), raw["rotation"].numpy().astype(np.float64)
    if (opts.recenter or opts.ref_distance) and (d > 0).any():
        v = to_model_view(d, K, K, recenter=opts.recenter, ref_distance=opts.ref_distance)
        d, R = np.asarray(v.depth, np.float32), v.Q.T @ R
    R = R.astype(np.float32)
    coeffs = ((raw["coeffs"].numpy().astype(np.float32) - coeff_mean) / coeff_std).astype(np.float32)
    return {"depth": torch.from_numpy(d.astype(np.float16).astype(np.float32))[None], "label": int(raw["label"]),
            "rotation": torch.from_numpy(R), "axis_angle": torch.from_numpy(matrix_to_axis_angle(R).astype(np.float32)),
            "coeffs": torch.from_numpy(coeffs), "object_index": int(raw["object_index"])}


def model_batch(raw: dict, K, opts: ViewOptions, coeff_mean, coeff_std) -> dict:
    """:func:`model_item` for a whole batch (the stacked items of :meth:`FreshPoses.render_batch`, depth
    on the training device), the same arithmetic with the depth left where it is; views that must be
    re-centred or zoomed go through :func:`model_item` one by one (on the CPU)."""
    if opts.recenter or opts.ref_distance:
        items = [model_item({k: v[i].cpu() if k == "depth" else v[i] for k, v in raw.items()}, K, opts, coeff_mean,
                            coeff_std) for i in range(len(raw["label"]))]
        return {k: torch.stack([torch.as_tensor(it[k]) for it in items]) for k in items[0]}
    R = raw["rotation"].numpy().astype(np.float32)
    coeffs = ((raw["coeffs"].numpy().astype(np.float32) - coeff_mean) / coeff_std).astype(np.float32)
    return {"depth": raw["depth"].half().float(), "label": raw["label"], "rotation": torch.from_numpy(R),
            "axis_angle": torch.from_numpy(matrix_to_axis_angle(R).astype(np.float32)),
            "coeffs": torch.from_numpy(coeffs), "object_index": raw["object_index"]}


class ModelView(Dataset):
    """A map-style view dataset (e.g. a :class:`DepthShards` subset) read lazily and brought into
    the model's input view item by item (:func:`model_item`), rolled if ``roll``; ``order(seed,
    epoch)`` gives each epoch's sampler (:func:`hbeo.model.loop.data_loader`). A base that renders
    whole batches (:class:`FreshPoses` with render backend ``torch``) is read a batch at a time
    (:meth:`__getitems__`, :func:`model_batch`), each roll then rendered, not resampled."""

    def __init__(self, base, K, opts: ViewOptions, coeff_mean, coeff_std, roll: bool = False, order=None,
                 ahead: int | None = None, draw_workers: int | None = None):
        self.base, self.K, self.opts, self.roll, self.order = base, K, opts, roll, order
        self.coeff_mean, self.coeff_std = np.asarray(coeff_mean, np.float32), np.asarray(coeff_std, np.float32)
        self.ahead = ahead          #: images rendered in one march (:meth:`plan_reads`); None: auto
        self.draw_workers = draw_workers    #: processes drawing poses ahead (posedraws.drawer_for; None: auto)
        self._plan, self._start, self._cursor, self._chunk, self._drawer = None, 0, 0, None, None

    def plan_reads(self, order, start: int = 0) -> None:
        """The order in which the training loader will read this epoch's items (its sampler, this
        process's share, a resumed epoch's rest), ``start`` the position of ``order[0]`` in the epoch's
        whole reading order (:func:`hbeo.model.loop.data_loader`). A base that renders whole batches
        then (1) rolls the image read at position q by :func:`hbeo.render.posedraws.roll_rng` of q,
        so the images do not depend on how they are grouped, and (2) renders :attr:`ahead` images of the
        plan in one march (``None``: :func:`hbeo.render.gridcast.auto_render_ahead` of the device's free memory,
        chosen at the first march; none on the CPU, where a larger march is no faster) and serves the next batches
        from them. On a GPU a march is mostly a fixed cost of launches and host syncs: a streamed step
        of 64 images at 80x60 took 79 ms on an H200, one of 128 at 320x240 191 ms
        (the device job's leases, ``docs/history/gpu-*``), and the marcher alone rendered 404 images/s in
        batches of 32 and 2,722 in batches of 2,048 at 320x240 (``benchmarks/README.md``). Reads outside the plan render
        alone, as before."""
        self._plan, self._start = np.asarray(order, np.int64), int(start)
        self._cursor, self._chunk = 0, None
        if self._drawer:            # a draw made ahead for an earlier plan is never taken
            self._drawer.cancel()

    def _planned_at(self, idx: np.ndarray) -> int | None:
        """Where in the plan ``idx`` is read (the cursor first, else the first place it matches), or None."""
        plan, n = self._plan, len(idx)
        if plan is None or n == 0:
            return None
        c = self._cursor
        if c + n <= len(plan) and np.array_equal(plan[c:c + n], idx):
            return c
        for c in np.flatnonzero(plan[:len(plan) - n + 1] == idx[0]):
            if np.array_equal(plan[c:c + n], idx):
                return int(c)
        return None

    def _ahead(self, n: int) -> int:
        if self.ahead is None:
            caster = self.base.caster()
            dev = caster.device
            free = torch.cuda.mem_get_info(dev)[0] if dev.type == "cuda" else 0
            self.ahead = auto_render_ahead(free, caster.intrinsics.height * caster.intrinsics.width)
        return -(-max(int(self.ahead), n) // n) * n             # whole batches

    def _rendered(self, idx: list[int]) -> dict:
        """The model batch of ``idx`` (:func:`model_batch` of :meth:`FreshPoses.render_batch`)."""
        at = self._planned_at(np.asarray(idx, np.int64))
        if at is None:
            raw = self.base.render_batch(idx, roll=self.roll)
            return self._on_device(model_batch(raw, self.K, self.opts, self.coeff_mean, self.coeff_std))
        n, ch = len(idx), self._chunk
        if ch is None or not ch[0] <= at or at + n > ch[0] + ch[1]:
            size = self._ahead(n)
            chunk = self._plan[at:at + size]
            keys = self._keys(at, len(chunk))
            drawer, epoch, end = self._draw_ahead(), getattr(self.base, "epoch", 0), at + len(chunk)
            drawn = drawer.take((epoch, at, len(chunk))) if drawer else None
            if drawer and len(nxt := self._plan[end:end + size]):     # the next march's poses, drawn meanwhile
                drawer.submit((epoch, end, len(nxt)), nxt, epoch, self._keys(end, len(nxt)))
            raw = self.base.render_batch(chunk.tolist(), roll=self.roll, roll_keys=keys, drawn=drawn)
            ch = self._chunk = (at, len(chunk), self._on_device(model_batch(raw, self.K, self.opts, self.coeff_mean,
                                                                            self.coeff_std)))
        self._cursor = at + n
        a = at - ch[0]
        return {k: v[a:a + n] for k, v in ch[2].items()}

    def _keys(self, at: int, n: int):
        return self._start + at + np.arange(n) if self.roll else None     # the images' reading positions

    def _draw_ahead(self):
        if self._drawer is None:          # decided on the first march (False: none draws ahead)
            from hbeo.render.posedraws import drawer_for
            self._drawer = drawer_for(self.base, self.draw_workers) or False
        return self._drawer or None

    def close(self) -> None:
        """Stop the processes drawing poses ahead, if any."""
        if self._drawer:
            self._drawer.close()

    @staticmethod
    def _on_device(batch: dict) -> dict:
        """A rendered batch with every tensor where its depth is (the training device): copied once a march,
        not a few small host-to-device copies every step."""
        dev = batch["depth"].device
        return {k: v.to(dev) for k, v in batch.items()}

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        if getattr(self.base, "renders_batches", False):
            return self.__getitems__([i])[0]
        item = model_item(self.base[i], self.K, self.opts, self.coeff_mean, self.coeff_std)
        return roll_item(item, self.K) if self.roll else item

    def __getitems__(self, indices):
        """The items ``indices``: read one by one, or, from a base that renders whole batches, rendered
        together and kept stacked (:class:`hbeo.batches.Stacked`, which the loader's collation passes on)."""
        if not getattr(self.base, "renders_batches", False):
            return [self[i] for i in indices]
        return Stacked(self._rendered([int(i) for i in indices]))

    def set_epoch(self, epoch: int) -> None:
        if hasattr(self.base, "set_epoch"):
            self.base.set_epoch(epoch)

    def epoch_sampler(self, seed: int, epoch: int):
        if self.order is not None:
            return self.order(seed, epoch)
        if hasattr(self.base, "epoch_sampler"):
            return self.base.epoch_sampler(seed, epoch)
        return torch.utils.data.RandomSampler(self, generator=torch.Generator().manual_seed(seed * 100_003 + epoch))


#: :class:`ModelViewStream` keeps a pass's items for the next one up to this many depth pixels (4 bytes each)
STREAM_CACHE_PIXELS = 2**28


#: passes of :class:`ModelViewStream` kept for other trainings of this process, by their ``share`` key: the
#: last one only, held until another replaces it (at most :data:`STREAM_CACHE_PIXELS` float32 depth pixels:
#: 15 MB for the ``cpu`` profile's 398 validation objects x 2 views at 80x60)
_SHARED_PASSES: dict = {}


class ModelViewStream(IterableDataset):
    """:class:`ModelView` for an iterable view dataset (validation views rendered on the fly, in order).
    Without ``roll``, a pass that ran to its end is kept (up to :data:`STREAM_CACHE_PIXELS` depth pixels)
    and the next pass of the same epoch yields it again instead of rendering the same images: validation
    scores the same views after every training epoch, and rendering them one object at a time cost the
    streamed training most of its time outside the loop (the second GPU lease). With a ``share`` key (any
    hashable naming everything the items depend on: :func:`training_data` gives one) the kept pass also
    serves a later ModelViewStream of this process with the same key: a device job trains three times over
    the same validation objects (warm-up, calibration, the run), and rendering them one object at a time
    cost ~30 s of the lease each time (``docs/history/gpu-cpu-stream/lease-2026-11-27b``: 31 s of each
    training outside its loop)."""

    def __init__(self, base, K, opts: ViewOptions, coeff_mean, coeff_std, roll: bool = False, share=None):
        self.base, self.K, self.opts, self.roll = base, K, opts, roll
        self.coeff_mean, self.coeff_std = np.asarray(coeff_mean, np.float32), np.asarray(coeff_std, np.float32)
        self.share = None if roll else share
        self._kept: tuple[int, list] | None = None          # (the base's epoch, the items of a whole pass)
        if self.share is not None and self.share in _SHARED_PASSES:
            self._kept = _SHARED_PASSES[self.share]

    def set_epoch(self, epoch: int) -> None:
        self.base.set_epoch(epoch)

    def __len__(self):
        return len(self.base)

    def __iter__(self):
        epoch = getattr(self.base, "epoch", 0)
        if self._kept is not None and self._kept[0] == epoch:
            yield from self._kept[1]
            return
        keep, pixels = (None if self.roll else []), 0         # rolled views differ every pass: never kept
        for raw in self.base:
            item = model_item(raw, self.K, self.opts, self.coeff_mean, self.coeff_std)
            item = roll_item(item, self.K) if self.roll else item
            if keep is not None:
                pixels += item["depth"].numel()
                if pixels > STREAM_CACHE_PIXELS:
                    keep = None
                else:
                    keep.append(item)
            yield item
        if keep is not None:
            self._kept = (epoch, keep)
            if self.share is not None and get_worker_info() is None:
                _SHARED_PASSES.clear()
                _SHARED_PASSES[self.share] = self._kept

    def __getstate__(self):          # DataLoader workers start without the kept pass
        return {**self.__dict__, "_kept": None}


@dataclass
class TrainingData:
    """What :func:`training_data` returns: the two datasets, the render settings and classes of the
    images, the coefficient standardization (mean, std (k,)) the model must undo at prediction
    time, the rendered set's manifest (None when the views are rendered on the fly) and ``train_labels``
    (len(train),) each training item's class index (None: not known)."""

    train: Dataset
    val: Dataset
    settings: RenderSettings
    classes: tuple[str, ...]
    coeff_mean: np.ndarray
    coeff_std: np.ndarray
    manifest: Manifest | None = None
    train_labels: np.ndarray | None = None


def _shard_coeff_stats(m: Manifest, progress: bool) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std (+1e-6) of every image's coefficients, read shard by shard (float64 sums)."""
    n, s1, s2 = 0, 0.0, 0.0
    for path in tqdm(m.shard_paths(), desc="coefficient statistics", disable=not progress):
        with np.load(path, allow_pickle=False) as z:
            if "coeffs" not in z.files:
                raise DataError(m.root, "the rendered set has no subspace coefficients; render it with the "
                                        "run's subspace (notebook 02 first)")
            c = z["coeffs"].astype(np.float64)
        n, s1, s2 = n + len(c), s1 + c.sum(0), s2 + (c * c).sum(0)
    mean = s1 / n
    return mean.astype(np.float32), (np.sqrt(np.maximum(s2 / n - mean * mean, 0)) + 1e-6).astype(np.float32)


def _val_mask(run: RunDir, labels, ids, val_fraction: float, val_split: str, twin_iou: float | None,
              gridset=None):
    """The validation objects among a run's training objects (``labels``, ``ids``) by ``val_split``
    (:func:`hbeo.data.datasets.validation_mask`); None for ``object`` (the callers' own rule, the same).
    ``grouped`` takes the objects' grids from ``gridset`` or the run's training grid set by id."""
    if val_split == "object":
        return None
    from hbeo.data.gridset import GridSet
    if gridset is None:
        if not run.grids("train").exists():
            raise DataError(run.grids("train"), "val_split 'grouped' needs the run's training grids (notebook 01)")
        gridset = GridSet.load(run.grids("train"))
    return datasets.validation_mask(labels, val_fraction, VAL_SEED, val_split, gridset.grids_of(ids), twin_iou)


def training_data(run, view: ViewOptions, val_fraction: float = 0.1, augment_roll: bool = False,
                  progress: bool = True, source: str = "memory", dataset=None, profile=None,
                  settings: RenderSettings | None = None, val_split: str = "object",
                  twin_iou: float | None = None, augment_mirror: bool = False) -> TrainingData:
    """The run's training images as (training, validation) datasets of the same items, split by
    object (:func:`hbeo.render.torch_datasets.split_by_object` with the fixed
    :data:`hbeo.data.datasets.VAL_SEED`, whatever the training seed: with the default
    ``val_fraction`` the validation objects are :func:`hbeo.data.datasets.validation_records`, on
    which ``evaluate --split val`` scores; ``val_split`` "grouped" holds out whole groups of near-duplicates
    instead, IoU >= ``twin_iou``: :func:`hbeo.data.datasets.validation_mask`); ``augment_roll`` rolls every training
    view by a random angle each time it is read (:mod:`hbeo.model.augment`); ``augment_mirror`` (data ``memory``
    only) mirrors every training view with probability 1/2 each time it is read, its object across its class's
    left-right plane (:mod:`hbeo.model.mirror`, before the roll). ``source``: ``memory``, the rendered training
    set, all in memory (:class:`ViewArrays`), or

    ``shards``
        the rendered training set read lazily, :data:`SHARD_MIX` shards in memory at a time, shuffled by blocks of
        that many shards (:class:`ShardSampler`); coefficients standardized with the statistics of every image (as
        ``memory``, up to rounding).
    ``stream``
        rendered on the fly (:class:`FreshPoses`, a fresh pose per object per pass, any image renderable alone) from
        ``dataset``'s (a loaded Dataset) training records of ``profile`` (a Profile) with render ``settings``;
        validation: ``profile.stream_val_views`` views of each validation object, rendered once; coefficients
        standardized with the statistics of the run's training grids. Needs the run's subspace, renders nothing
        first. With render ``settings.backend`` "torch" (grid datasets only) each training batch is rendered at once
        on the training device from the objects' grids kept there (:meth:`FreshPoses.render_batch`). The memory use of
        ``shards`` and ``stream`` does not grow with the number of images."""
    run = RunDir.of(run)
    if source == "memory":
        data = ViewArrays(run.renders("train"), view, progress=progress)
        m = data.manifest
        mask = _val_mask(run, m.object_labels, m.object_ids, val_fraction, val_split, twin_iou)
        tr_idx, va_idx = split_by_object(m, val_fraction, VAL_SEED, mask)
        train_set = Subset(data, tr_idx)
        if augment_mirror:
            axes, mirrored = mirror_targets(run, data, tr_idx, progress)
            train_set = MirrorAugment(train_set, data.manifest.settings.intrinsics, axes, mirrored)
        if augment_roll:
            train_set = RollAugment(train_set, data.manifest.settings.intrinsics)
        return TrainingData(train_set, Subset(data, va_idx), data.manifest.settings, data.manifest.classes,
                            data.coeff_mean, data.coeff_std, data.manifest, data.labels[tr_idx])
    if augment_mirror:
        raise ValueError(f"mirror augmentation needs data 'memory' (the rendered set in memory), not {source!r}")
    if source == "shards":
        shards = DepthShards(run.renders("train"), cache_shards=SHARD_MIX)
        m = shards.manifest
        mean, std = _shard_coeff_stats(m, progress)
        mask = _val_mask(run, m.object_labels, m.object_ids, val_fraction, val_split, twin_iou)
        tr_idx, va_idx = split_by_object(m, val_fraction, VAL_SEED, mask)
        K = m.settings.intrinsics

        def order(seed_, epoch):
            sampler = ShardSampler(shards, tr_idx, seed=seed_, mix=SHARD_MIX)
            sampler.set_epoch(epoch)
            return sampler
        return TrainingData(ModelView(Subset(shards, tr_idx), K, view, mean, std, augment_roll, order),
                            ModelView(Subset(shards, va_idx), K, view, mean, std), m.settings, m.classes,
                            mean, std, m, shards.labels[tr_idx])
    if source == "stream":
        if dataset is None or profile is None or settings is None:
            raise ValueError("training_data: source 'stream' needs dataset, profile and settings")
        prof, ds = profile, dataset
        sub = ObjectSubspace.load(run.subspace)
        gridset = run_gridsets(run, ds, prof, progress=progress)["train"]
        grids = gridset.grids
        coeffs = np.concatenate([sub.project(grids[i:i + 512]) for i in range(0, len(grids), 512)])
        mean, std = coeffs.mean(0), coeffs.std(0) + 1e-6
        records = datasets.select(ds, "train", prof)
        labels = [ds.classes.index(r.cls) for r in records]
        val = _val_mask(run, labels, [r.id for r in records], val_fraction, val_split, twin_iou, gridset)
        if val is None:
            val = split_objects(labels, val_fraction, VAL_SEED)
        K = settings.intrinsics
        train_views = FreshPoses(ds, [r for r, v in zip(records, val) if not v], "train", settings, sub)
        obj_labels = np.array([lab for lab, v in zip(labels, val) if not v], np.int64)    # image i: object i % n
        val_views = StreamingDepth(ds, [r for r, v in zip(records, val) if v], "train",
                                   replace(settings, views_per_object=prof.data.stream_val_views), sub, shuffle=False)
        share = ("stream validation", str(Path(run.subspace).resolve()), Path(run.subspace).stat().st_mtime_ns,
                 ds.name, str(getattr(ds, "path", "")), tuple(map(repr, val_views.records)), val_views.settings, view,
                 hashlib.sha256(mean.astype(np.float32).tobytes() + std.astype(np.float32).tobytes()).hexdigest())
        return TrainingData(ModelView(train_views, K, view, mean, std, augment_roll),
                            ModelViewStream(val_views, K, view, mean, std, share=share), settings, tuple(ds.classes),
                            mean, std,
                            train_labels=obj_labels[np.arange(len(train_views)) % len(obj_labels)])
    raise ValueError(f"unknown training data source {source!r}; expected one of {', '.join(DATA_SOURCES)}")
