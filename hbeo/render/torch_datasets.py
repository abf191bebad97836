"""Rendered sets as training data: shard reading and the torch datasets.

:func:`load_shard` reads one shard of a set written by :func:`hbeo.render.renderset.render_set`;
:class:`DepthShards` serves a whole set as a map-style torch dataset, shuffled shard-wise by
:class:`ShardSampler` and split into train/validation by object with :func:`split_by_object`;
:class:`StreamingDepth` renders the same images on the fly (for sets too big for disk) and
:class:`FreshPoses` renders training views with a fresh pose per object per pass.

Items (dicts of tensors, what :mod:`hbeo.model.loop` takes)
    ``depth`` (1, H, W) float32 metres (0 = no object), ``label`` int64, ``rotation`` (3, 3)
    and ``axis_angle`` (3,) float32 (object -> camera, :mod:`hbeo.conventions`),
    ``translation`` (3,) float32 metres, ``object_index`` int64 and, if the set has them,
    ``coeffs`` (k,) float32.

Imports the foundation, torch and :mod:`hbeo.render` (views, renderset, gridcast).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset as TorchDataset, IterableDataset, Sampler, get_worker_info

from hbeo.batches import Stacked
from hbeo.data.datasets import split_objects
from hbeo.errors import DataError
from hbeo.render.posedraws import PoseDraws, rolled
from hbeo.render.renderset import SHARD_KEYS, Manifest
from hbeo.render.views import SPLIT_CODES, ObjectViews, RenderSettings, _split_code, check_grid_records
from hbeo.rotations import matrix_to_axis_angle
from hbeo.storage import unpack_bits


def load_shard(path) -> dict:
    """All arrays of one shard, ``mask`` unpacked to bool (N, H, W)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise DataError(path, "no such shard") from None
    except Exception as err:
        raise DataError(path, f"not a readable shard ({type(err).__name__}: {err})") from None
    if missing := [k for k in SHARD_KEYS if k not in data]:
        raise DataError(path, f"shard lacks arrays {missing}")
    n, h, w = data["depth"].shape
    data["mask"] = unpack_bits(data["mask"], (h, w))
    return data


def _item(arrays: dict, i: int) -> dict:
    """One image of shard-layout arrays -> the dict of tensors the training loop takes."""
    out = {
        "depth": torch.from_numpy(arrays["depth"][i].astype(np.float32))[None],
        "label": torch.tensor(int(arrays["label"][i]), dtype=torch.long),
        "rotation": torch.from_numpy(np.array(arrays["rotation"][i], np.float32)),
        "axis_angle": torch.from_numpy(np.array(arrays["axis_angle"][i], np.float32)),
        "translation": torch.from_numpy(np.array(arrays["translation"][i], np.float32)),
        "object_index": torch.tensor(int(arrays["object_index"][i]), dtype=torch.long),
    }
    if "coeffs" in arrays:
        out["coeffs"] = torch.from_numpy(np.array(arrays["coeffs"][i], np.float32))
    return out


class DepthShards(TorchDataset):
    """A rendered set (folder, ``manifest.json`` or :class:`Manifest`) as a map-style dataset.

    Shards are read lazily, whole, and the last ``cache_shards`` kept; random access across
    shards is slow, so shuffle with :class:`ShardSampler` (shard order, then within a shard).
    Items: ``depth`` (1, H, W) float32 metres, ``label``, ``rotation`` (3, 3), ``axis_angle``
    (3,), ``translation`` (3,), ``object_index`` and, if the set has them, ``coeffs`` (k,).
    """

    def __init__(self, path, cache_shards: int = 1):
        self.manifest = Manifest.load(path)
        self.cache_shards = max(1, int(cache_shards))
        sizes = np.array([s["n_images"] for s in self.manifest.shards], np.int64)
        self._starts = np.concatenate([[0], np.cumsum(sizes)])
        self._cache: OrderedDict[int, dict] = OrderedDict()
        self.image_objects = self.manifest.image_objects()          #: object position per image
        self.labels = self.manifest.object_labels[self.image_objects]  #: class index per image

    def __len__(self) -> int:
        return int(self._starts[-1])

    @property
    def classes(self) -> tuple[str, ...]:
        return self.manifest.classes

    @property
    def object_ids(self) -> list[str]:
        return self.manifest.object_ids

    def objects(self, indices=None) -> list[str]:
        """Ids of the objects seen by images ``indices`` (all by default), in position order."""
        pos = self.image_objects if indices is None else self.image_objects[np.asarray(indices, np.int64)]
        ids = self.manifest.object_ids
        return [ids[p] for p in np.unique(pos)]

    def shard_of(self, i) -> np.ndarray:
        """Shard number of image index(es) ``i``."""
        return np.searchsorted(self._starts, i, side="right") - 1

    def _shard(self, k: int) -> dict:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        path = self.manifest.root / self.manifest.shards[k]["file"]
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {n: z[n] for n in z.files if n != "mask"}
        except FileNotFoundError:
            raise DataError(path, "shard listed in the manifest is missing") from None
        except Exception as err:
            raise DataError(path, f"not a readable shard ({type(err).__name__}: {err})") from None
        self._cache[k] = arrays
        while len(self._cache) > self.cache_shards:
            self._cache.popitem(last=False)
        return arrays

    def __getitem__(self, i) -> dict:
        n = len(self)
        i = int(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"image {i} out of range for a set of {n}")
        k = int(self.shard_of(i))
        return _item(self._shard(k), i - int(self._starts[k]))

    def __getstate__(self):  # DataLoader workers start with an empty cache
        state = dict(self.__dict__)
        state["_cache"] = OrderedDict()
        return state


def split_by_object(manifest, val_fraction: float = 0.1, seed: int = 0, mask=None) -> tuple[np.ndarray, np.ndarray]:
    """Image indices (train, validation) of a rendered set, split by object: all views of an
    object fall on the same side. Stratified: each class gives ``round(val_fraction * n)`` of
    its n objects (at least one when it has two or more and val_fraction > 0). ``mask``: which of the
    set's objects (bool, one per ``object_ids``) are validation objects, instead of that rule (e.g.
    :func:`hbeo.data.datasets.validation_mask`'s grouped split)."""
    m = manifest.manifest if isinstance(manifest, DepthShards) else Manifest.load(manifest)
    if mask is None:
        val = split_objects(m.object_labels, val_fraction, seed)
    else:
        val = np.asarray(mask, bool)
        if val.shape != (len(m.object_labels),):
            raise ValueError(f"split_by_object: mask has shape {val.shape}; the set has {len(m.object_labels)} objects")
    img_obj = m.image_objects()
    idx = np.arange(len(img_obj), dtype=np.int64)
    return idx[~val[img_obj]], idx[val[img_obj]]


class ShardSampler(Sampler):
    """Shuffles a :class:`DepthShards` (or a subset of its image ``indices``) a few shards at a time:
    the shards in random order, cut into blocks of ``mix`` shards, the images of each block in
    random order; so each shard is loaded once per epoch when the dataset caches ``mix`` shards
    (``DepthShards(cache_shards=mix)``), and memory holds ``mix`` shards. Why blocks: a rendered set
    writes its objects in class order, so a shard holds one or two classes, and batches drawn from
    one shard at a time (``mix=1``) are nearly single-class (the loss stalls; measured). Yields
    positions into ``indices`` (use with ``torch.utils.data.Subset(data, indices)``), or image
    indices when ``indices`` is None. ``set_epoch(e)`` changes the order."""

    def __init__(self, data: DepthShards, indices=None, shuffle: bool = True, seed: int = 0, mix: int = 1):
        self.indices = np.arange(len(data)) if indices is None else np.asarray(indices, np.int64)
        shard = data.shard_of(self.indices)
        self._groups = [np.flatnonzero(shard == k) for k in np.unique(shard)]
        self.shuffle, self.seed, self.epoch = shuffle, int(seed), 0
        if int(mix) < 1:
            raise ValueError(f"ShardSampler: mix must be >= 1, got {mix}")
        self.mix = int(mix)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self):
        if not self.shuffle:
            yield from (int(i) for g in self._groups for i in g)
            return
        rng = np.random.default_rng([self.seed, self.epoch])
        order = rng.permutation(len(self._groups))
        for b in range(0, len(order), self.mix):
            block = np.concatenate([self._groups[g] for g in order[b:b + self.mix]])
            yield from (int(i) for i in rng.permutation(block))


class StreamingDepth(IterableDataset):
    """The images :func:`render_set` would write, rendered on the fly (for sets too big for disk).

    Same settings, same per-object random streams: at epoch 0 it yields exactly the images of
    the rendered set (depth quantized to float16 likewise); ``set_epoch(e)`` with e > 0 draws
    new views from ``default_rng([seed, split_code, position, e])``. Objects are dealt out to
    DataLoader workers (each with its own Renderer); with ``shuffle`` the object order is a
    permutation drawn per epoch. Yields the dicts :class:`DepthShards` gives.
    """

    def __init__(self, dataset, records, split: str, settings: RenderSettings, subspace=None,
                 shuffle: bool = True):
        records = list(records)
        if not records:
            raise ValueError(f"StreamingDepth: no records for split {split!r}")
        _split_code(split)
        if not isinstance(settings, RenderSettings):
            raise ValueError(f"StreamingDepth: settings must be a RenderSettings, got {type(settings).__name__}")
        if any(r.split != split for r in records):
            raise ValueError(f"StreamingDepth: all records must be from split {split!r}")
        self.classes = tuple(dataset.classes)
        self.records = records
        self.labels = [self.classes.index(r.cls) for r in records]
        self.split, self.settings, self.subspace = split, settings, subspace
        self.shuffle = bool(shuffle)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.records) * self.settings.views_per_object

    def object_order(self, epoch: int | None = None) -> np.ndarray:
        """Object positions in the order of ``epoch`` (default: this epoch's), before dealing them to workers."""
        n = len(self.records)
        if not self.shuffle:
            return np.arange(n)
        epoch = self.epoch if epoch is None else int(epoch)
        seq = np.random.SeedSequence([self.settings.seed, SPLIT_CODES[self.split], epoch], spawn_key=(1,))
        return np.random.default_rng(seq).permutation(n)

    def __iter__(self):
        info = get_worker_info()
        wid, nw = (0, 1) if info is None else (info.id, info.num_workers)
        mine = self.object_order()[wid::nw]
        ctx = ObjectViews(self.settings, self.subspace)
        block = MANY_OBJECTS if ctx.batched() else 1   # on a GPU objects ray-marched together: the same arrays
        try:
            for k in range(0, len(mine), block):
                part = [int(p) for p in mine[k:k + block]]
                for arrays in ctx.views_many([self.records[p] for p in part], part, [self.labels[p] for p in part],
                                             self.split, self.epoch):
                    for v in range(self.settings.views_per_object):
                        yield _item(arrays, v)
        finally:
            ctx.close()


class FreshPoses(TorchDataset):
    """Training views rendered on the fly, a fresh pose per object per pass, as a map-style dataset:
    each epoch makes ``passes`` (default ``settings.views_per_object``) passes over the objects.
    Image ``i`` of epoch ``e`` is object ``i % n`` in pass ``i // n``, seen from the pose that a
    one-view :class:`StreamingDepth` draws at its epoch ``e * passes + pass``; ``epoch_sampler``
    gives each pass its own object order (:meth:`StreamingDepth.object_order`). So an epoch has as
    many images as the rendered set, every batch comes from many objects, no pose repeats between
    epochs, any subset of an epoch can be rendered alone (a data-parallel rank's share, a resumed
    epoch's rest, a DataLoader worker's items) and memory holds one view at a time. Each process
    opens its own renderer on first use. Yields the dicts :class:`DepthShards` gives. With render
    backend ``torch`` a DataLoader's batch is rendered at once on the training device
    (:meth:`render_batch`, :meth:`__getitems__`) from every object's grid held there.
    """

    def __init__(self, dataset, records, split: str, settings: RenderSettings, subspace=None,
                 passes: int | None = None):
        self.passes = int(settings.views_per_object if passes is None else passes)
        if self.passes < 1:
            raise ValueError(f"FreshPoses: passes must be >= 1, got {self.passes}")
        self.base = StreamingDepth(dataset, records, split, replace(settings, views_per_object=1), subspace,
                                   shuffle=True)
        self.epoch = 0
        self._ctx = None
        self._caster = None
        self._coeff_table = None    #: (n_objects, k) every object's coefficients, once the first batch asks
        self.device = None          #: backend "torch": the device batches are rendered on (None: auto)
        if settings.backend == "torch":
            check_grid_records(self.base.records)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.passes * len(self.base)

    def epoch_sampler(self, seed: int, epoch: int) -> np.ndarray:
        """Image indices of ``epoch`` in training order: pass by pass, each pass's objects in the
        order that pass draws (from the render settings' seed; ``seed`` is not used)."""
        n = len(self.base)
        orders = []
        for j in range(self.passes):
            orders.append(j * n + self.base.object_order(epoch * self.passes + j))
        return np.concatenate(orders)

    def __getitem__(self, i) -> dict:
        n = len(self.base)
        i = int(i)
        if not 0 <= i < len(self):
            raise IndexError(f"image {i} out of range for {len(self)} views per epoch")
        j, p = divmod(i, n)
        if self._ctx is None:
            self._ctx = ObjectViews(self.base.settings, self.base.subspace)
        b = self.base
        return _item(self._ctx.views(b.records[p], p, b.labels[p], b.split, self.epoch * self.passes + j), 0)

    def close(self) -> None:
        if self._ctx is not None:
            self._ctx.close()
            self._ctx = None

    def __getstate__(self):  # DataLoader workers open renderers of their own
        state = dict(self.__dict__)
        state["_ctx"] = state["_caster"] = None
        return state

    # -- backend "torch": whole batches on the training device
    @property
    def renders_batches(self) -> bool:
        """Whether :meth:`render_batch` renders a batch at once (render backend ``torch``)."""
        return self.base.settings.backend == "torch"

    def _device(self) -> torch.device:
        if get_worker_info() is not None:           # a DataLoader worker process renders on its CPU
            return torch.device("cpu")
        if self.device is not None:
            return torch.device(self.device)
        if torch.cuda.is_available():               # where hbeo.model.loop trains: the current CUDA device
            return torch.device("cuda", torch.cuda.current_device())
        return torch.device("cpu")

    def caster(self):
        """The :class:`hbeo.render.gridcast.GridCaster` of all objects' grids on this process's device
        (:attr:`device`; None: CUDA's current device when there is one, else the CPU), built once, and
        shared in this process with any other FreshPoses of the same grids, camera and device
        (:func:`shared_caster`: a device job trains three times over the same objects)."""
        dev = self._device()
        if self._caster is None or self._caster.device != dev:
            from hbeo.data.gridset import record_grid
            b = self.base
            self._caster = shared_caster([record_grid(r) for r in b.records], b.settings, dev)
        return self._caster

    def _prefill_coeffs(self) -> None:
        """Every object's subspace coefficients, projected together (a matrix product by blocks of
        :data:`COEFF_BLOCK` objects) into this dataset's :class:`ObjectViews` cache, which items and
        batches then read: one projection of a 30^3 grid at a time reads the whole basis (~37 MB for
        ModelNet10's), which made an epoch's first pass over the objects slow."""
        b = self.base
        if b.subspace is not None and not self._ctx.prefilled:
            self._ctx.prefill_coeffs(b.records, COEFF_BLOCK)

    @property
    def draws(self) -> PoseDraws:
        """The host-side pose draws of this dataset's images (picklable: :class:`hbeo.render.posedraws.DrawAhead`
        draws them in worker processes)."""
        b = self.base
        return PoseDraws(b.settings, b.split, len(b), self.passes)

    def render_batch(self, indices, roll: bool = False, roll_keys=None, drawn: dict | None = None) -> dict:
        """Images ``indices`` of this epoch rendered together (render backend ``torch``): the items of
        :meth:`__getitem__` stacked, ``depth`` (B, 1, H, W) on the caster's device (:meth:`caster`), the
        rest on the CPU; the same images as :meth:`__getitem__` gives one by one. ``roll``: each camera
        first turns about its optical axis by a uniform random angle (``rotation`` and ``translation`` turn
        with it): an exact rolled view, rendered, not resampled. The angle of image k comes from
        :func:`hbeo.render.posedraws.roll_rng` of ``roll_keys[k]`` (an int: the image's position in the epoch's
        reading order, which the training loader plans, :meth:`hbeo.model.trainingdata.ModelView.plan_reads`), so a
        batch renders the same whichever chunk it is rendered in, and an object drawn twice in an epoch is rolled
        twice; without keys, from torch's global generator. ``drawn``: the poses already drawn,
        :meth:`PoseDraws.draw` of ``indices``, this epoch and ``roll_keys`` (when ``roll``), e.g. ahead in
        worker processes (:class:`hbeo.render.posedraws.DrawAhead`); not with sensor noise, which draws
        from each image's generator after its pose."""
        b, n = self.base, len(self.base)
        s = b.settings
        if not self.renders_batches:
            raise ValueError(f"render_batch needs render backend 'torch', not {s.backend!r}")
        if s.noise and s.noise_scale != 1:
            raise ValueError(f"render_batch applies sensor noise at the image's size; noise_scale "
                             f"{s.noise_scale} is for views rendered one object at a time (ObjectViews)")
        idx = [int(i) for i in indices]
        if bad := [i for i in idx if not 0 <= i < len(self)]:
            raise IndexError(f"image {bad[0]} out of range for {len(self)} views per epoch")
        if self._ctx is None:
            self._ctx = ObjectViews(s, b.subspace)
        if drawn is None:
            pos, rngs = self.draws.positions(idx, self.epoch)
            R, t = s.view_sampler.sample_each(rngs)       # each image's sample(1, rng), the arithmetic batched
            if roll:
                if roll_keys is None:
                    angles = torch.rand(len(idx), dtype=torch.float64).numpy() * 2 * np.pi
                else:
                    if len(roll_keys) != len(idx):
                        raise ValueError(f"render_batch: {len(roll_keys)} roll keys for {len(idx)} images")
                    angles = self.draws.roll_angles(self.epoch, roll_keys)
                R, t = rolled(R, t, angles)
        else:
            if s.noise:
                raise ValueError("render_batch: poses drawn ahead cannot carry sensor noise (it draws from each "
                                 "image's generator after the pose)")
            if roll and roll_keys is None:
                raise ValueError("render_batch: rolled poses drawn ahead need the roll keys they were drawn with")
            pos, R, t = drawn["pos"], drawn["R"], drawn["t"]
            if len(pos) != len(idx) or not np.array_equal(pos, np.asarray(idx, np.int64) % n):
                raise ValueError("render_batch: the poses drawn ahead are not those of these images")
        caster = self.caster()
        depth = caster.render(torch.as_tensor(pos), R, t)
        if s.noise:                                  # the numpy noise model, each view with its own stream
            arr = depth.cpu().numpy()
            depth = torch.from_numpy(np.stack([self._ctx.noise.apply(d, s.intrinsics, g) for d, g in zip(arr, rngs)]))
            depth = torch.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0).to(caster.device)
        depth = depth.half().float()                 # as a rendered set stores it (float16)
        depth[~(depth > 0)] = 0
        out = {"depth": depth[:, None], "label": torch.from_numpy(np.asarray(b.labels, np.int64)[pos]),
               "rotation": torch.from_numpy(R.astype(np.float32)),
               "axis_angle": torch.from_numpy(matrix_to_axis_angle(R).astype(np.float32)),
               "translation": torch.from_numpy(t.astype(np.float32)),
               "object_index": torch.tensor(pos, dtype=torch.long)}
        if b.subspace is not None:
            self._prefill_coeffs()
            if self._coeff_table is None:            # every object's coefficients, one gather a batch
                self._coeff_table = np.stack([self._ctx.coeffs(r) for r in b.records])
            out["coeffs"] = torch.from_numpy(self._coeff_table[pos])
        return out

    def __getitems__(self, indices):
        """The items ``indices`` (what a DataLoader fetches for a batch): rendered together with the
        ``torch`` backend (:meth:`render_batch`, kept stacked: :class:`hbeo.batches.Stacked`), one by one
        otherwise."""
        if not self.renders_batches:
            return [self[i] for i in indices]
        return Stacked(self.render_batch(indices))


#: objects a :class:`StreamingDepth` pass renders together on a GPU (:meth:`hbeo.render.views.ObjectViews.views_many`)
MANY_OBJECTS = 128


#: Objects projected onto the subspace together by :meth:`FreshPoses._prefill_coeffs`.
COEFF_BLOCK = 256
#: :func:`shared_caster`'s casters kept in a process (the training objects' and one other set).
SHARED_CASTERS = 2
_CASTERS: OrderedDict = OrderedDict()


def shared_caster(grids: list, settings: RenderSettings, device) -> "GridCaster":
    """A :class:`hbeo.render.gridcast.GridCaster` of ``grids`` for ``settings``' camera and object size on
    ``device``, built once a process for the same grids (by content: a hash of the packed grids), camera,
    size and device; the last :data:`SHARED_CASTERS` are kept. Building one smooths every grid (~20-50 ms
    a grid on one core), which a device job's warm-up, calibration and training paid three times."""
    import hashlib
    from hbeo.render.gridcast import GridCaster
    h = hashlib.blake2b(digest_size=16)
    for g in grids:
        a = np.asarray(g)
        h.update(repr(a.shape).encode())
        h.update(np.packbits(a.astype(bool)).tobytes())
    K = settings.intrinsics
    key = (h.hexdigest(), (K.width, K.height, K.fx, K.fy, K.cx, K.cy), float(settings.object_size), str(device))
    if key in _CASTERS:
        _CASTERS.move_to_end(key)
        return _CASTERS[key]
    caster = GridCaster(grids, K, settings.object_size, device=device)
    _CASTERS[key] = caster
    while len(_CASTERS) > SHARED_CASTERS:
        _CASTERS.popitem(last=False)
    return caster
