"""A set of 30^3 grids with labels, built from a dataset in parallel and cached on disk.

:func:`build_gridset` voxelizes a dataset's records (or reads their grids) in chunks;
each chunk is written as its own file (temporary name, then rename), so an
interrupted run resumes where it stopped and never leaves a file that looks
complete but is not. The cache directory is keyed by the dataset fingerprint
and the voxelization settings.
"""
from __future__ import annotations

import hashlib
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from hbeo import config
from hbeo import conventions as C
from hbeo.data.datasets import Dataset, ObjectRecord
from hbeo.errors import DataError
from hbeo.rundir import RunDir
from hbeo.storage import pack_bits, read_npz, unpack_bits, write_npz
from hbeo.data.voxel import voxelize

FORMAT_VERSION = 1
VOXEL_SETTINGS = {"resolution": C.RESOLUTION, "step": 0.5, "close": 1, "algorithm": 1}


@dataclass
class GridSet:
    """Grids of one split: ``grids`` bool (N, 30, 30, 30), ``labels`` int (N,) into ``classes``,
    ``ids`` (N,) str."""

    grids: np.ndarray
    labels: np.ndarray
    ids: np.ndarray
    classes: tuple[str, ...]
    split: str
    meta: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.grids)

    def __post_init__(self):
        n = len(self.grids)
        if self.grids.ndim != 4 or len(self.labels) != n or len(self.ids) != n:
            raise ValueError(f"inconsistent GridSet: grids {self.grids.shape}, "
                             f"labels {np.shape(self.labels)}, ids {np.shape(self.ids)}")

    def counts(self) -> dict[str, int]:
        """Objects per class name."""
        return {c: int((self.labels == i).sum()) for i, c in enumerate(self.classes)}

    def save(self, path) -> Path:
        """Write to ``path`` (.npz, grids bit-packed) atomically."""
        path = Path(path)
        meta = dict(self.meta, format_version=FORMAT_VERSION, split=self.split,
                    classes=list(self.classes), resolution=int(self.grids.shape[1]))
        return write_npz(path, meta, compressed=True, packed=pack_bits(self.grids),
                         labels=self.labels.astype(np.int64), ids=self.ids.astype(str))

    @classmethod
    def load(cls, path) -> "GridSet":
        """Read a file written by :meth:`save`; :class:`DataError` naming the file if it is not one."""
        path = Path(path)
        meta, a = read_npz(path, ("packed", "labels", "ids"), "grid set", FORMAT_VERSION, "; rebuild it")
        packed, labels, ids = a["packed"], a["labels"], a["ids"]
        r = int(meta["resolution"])
        try:
            grids = unpack_bits(packed, (r, r, r))
        except ValueError as err:
            raise DataError(path, f"corrupt grid set ({err})") from None
        return cls(grids, labels, ids, tuple(meta["classes"]), meta["split"], meta)


def record_grid(record: ObjectRecord, settings: dict = VOXEL_SETTINGS) -> np.ndarray:
    """The object's grid: the stored one if the source has grids, else its mesh voxelized."""
    if record.has_grid:
        return np.asarray(record.grid(), dtype=bool)
    mesh = record.mesh()
    try:
        return voxelize(mesh, resolution=settings["resolution"], step=settings["step"],
                        close=settings["close"])
    except DataError:
        raise
    except Exception as err:  # name the object, whatever went wrong deep inside
        raise DataError(record.path or record.id, f"voxelization failed ({type(err).__name__}: {err})") from err


def _chunk_job(args):
    records, settings = args
    return np.stack([record_grid(r, settings) for r in records])


def cache_key(dataset: Dataset, records: list[ObjectRecord], settings: dict = VOXEL_SETTINGS) -> str:
    """Hash of dataset fingerprint + voxel settings + the exact record list."""
    h = hashlib.sha256()
    h.update(dataset.fingerprint().encode())
    h.update(json.dumps(settings, sort_keys=True).encode())
    h.update("\n".join(f"{r.split}/{r.cls}/{r.id}" for r in records).encode())
    return h.hexdigest()[:20]


def build_gridset(dataset: Dataset, records: list[ObjectRecord], split: str,
                  cache: str | os.PathLike | None = None, workers: int = 1,
                  chunk: int = 32, progress: bool = True, settings: dict = VOXEL_SETTINGS) -> GridSet:
    """Grids for ``records`` (all of one split), computed in ``workers`` processes and cached.

    Finished chunks live in ``<cache>/<key>/chunk_NNNNN.npz``; a rerun loads them and
    computes only the missing ones. Same result for any worker count. ``cache=None``
    uses :func:`hbeo.config.cache_dir`.
    """
    if any(r.split != split for r in records):
        raise ValueError(f"build_gridset: all records must be from split {split!r}")
    cdir = Path(cache) if cache is not None else config.cache_dir()
    folder = cdir / f"{dataset.name.replace(os.sep, '_').strip('_')}-{split}-{cache_key(dataset, records, settings)}"
    final = folder / "grids.npz"
    labels = np.array([dataset.classes.index(r.cls) for r in records], dtype=np.int64)
    ids = np.array([r.id for r in records], dtype=str)
    meta = {"dataset": dataset.name, "fingerprint": dataset.fingerprint(), "settings": settings}
    if final.exists():
        gs = GridSet.load(final)
        if len(gs) == len(records) and list(gs.ids) == list(ids):
            return gs
    chunks = [records[i:i + chunk] for i in range(0, len(records), chunk)]
    paths = [folder / f"chunk_{k:05d}.npz" for k in range(len(chunks))]
    todo = [k for k, p in enumerate(paths) if not p.exists()]
    bar = tqdm(total=len(records), desc=f"voxelize {dataset.name}/{split}", unit="obj",
               disable=not progress, initial=len(records) - sum(len(chunks[k]) for k in todo))

    def done(k, grids):
        write_npz(paths[k], None, compressed=True, grids=pack_bits(grids))
        bar.update(len(chunks[k]))

    needs_mesh = any(not r.has_grid for r in records)
    if workers > 1 and len(todo) > 1 and needs_mesh:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for k, grids in zip(todo, pool.map(_chunk_job, [(chunks[k], settings) for k in todo])):
                done(k, grids)
    else:
        for k in todo:
            done(k, _chunk_job((chunks[k], settings)))
    bar.close()
    r = settings["resolution"]
    parts = []
    for p in paths:
        with np.load(p) as z:
            parts.append(unpack_bits(z["grids"], (r, r, r)))
    grids = np.concatenate(parts) if parts else np.zeros((0, r, r, r), bool)
    gs = GridSet(grids, labels, ids, tuple(dataset.classes), split, meta)
    gs.save(final)
    for p in paths:
        p.unlink(missing_ok=True)
    return gs


def run_gridsets(dataset: str, profile, run, progress: bool = True, rebuild: bool = False) -> dict[str, GridSet]:
    """The run's ``{"train": GridSet, "test": GridSet}``: read from the run folder's grid sets
    (:meth:`hbeo.rundir.RunDir.grids`) when present, else built from the dataset (cached, see
    :func:`build_gridset`) and written there. ``rebuild``: build and write them even when present
    (notebook 01, the step that owns them). ``run``: a :class:`~hbeo.rundir.RunDir` or a path."""
    from hbeo.data import datasets
    prof = config.get_profile(profile)
    run = RunDir.of(run)
    out, ds = {}, None
    for split in C.SPLITS:
        path = run.grids(split)
        if path.exists() and not rebuild:
            out[split] = GridSet.load(path)
            continue
        if ds is None:
            ds = datasets.get_dataset(dataset, profile=prof)
        out[split] = build_gridset(ds, datasets.select(ds, split, prof), split, workers=prof.workers,
                                   progress=progress)
        out[split].save(path)
    return out
