"""A set of 30^3 grids with labels, built from a dataset in parallel and cached on disk.

:func:`build_gridset` voxelizes a dataset's records (or reads their grids) in chunks. A bad
object (a mesh that cannot be read or is degenerate: :class:`~hbeo.errors.DataError`) does not
stop the batch: it is left out of the set, and named with its reason in the set's
:attr:`GridSet.failures` (also in its meta, so the saved file says which objects it lacks).
Only when no object at all succeeds is a DataError raised (its ``failures`` attribute lists them).

The cache is per object: ``<cache>/<dataset>-<split>-<settings key>/chunk_<hash>.npz`` files hold
bit-packed grids under item keys (the object's name plus its file's size and mtime, or the dataset
fingerprint for objects without a file). Each chunk is written atomically as soon as it is done, so
an interrupted run resumes where it stopped; failures are never cached, so a rerun reuses every
finished grid and voxelizes only the objects that failed or changed (a repaired file). Imports the
foundation and :mod:`hbeo.data` only.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hbeo.progress import tqdm

from hbeo import config
from hbeo import conventions as C
from hbeo.data.datasets import Dataset, ObjectRecord
from hbeo.limits import check_workers
from hbeo.errors import BatchError, DataError
from hbeo.rundir import RunDir, failure
from hbeo.storage import pack_bits, read_npz, unpack_bits, write_npz
from hbeo.data.voxel import voxelize

FORMAT_VERSION = 1
CACHE_VERSION = 2   #: of the cache's chunk files
VOXEL_SETTINGS = {"resolution": C.RESOLUTION, "step": 0.5, "close": 1, "algorithm": 1}


@dataclass
class GridSet:
    """Grids of one split: ``grids`` bool (N, 30, 30, 30), ``labels`` int (N,) into ``classes``,
    ``ids`` (N,) str, each a different object (DataError otherwise: :func:`unique_ids`)."""

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
        unique_ids(self.ids, self.meta.get("dataset"))

    @property
    def failures(self) -> list[dict]:
        """The objects of the split left out because they failed: ``{file, reason, step, object,
        split}`` each (:func:`build_gridset`); empty for a complete set."""
        return list(self.meta.get("failed", []))

    def rows_of(self, ids) -> np.ndarray:
        """The row of each of ``ids`` in this set (int64 (n,), matched as strings; -1 for an id not here)."""
        rows = {str(i): k for k, i in enumerate(self.ids)}
        return np.array([rows.get(str(i), -1) for i in ids], np.int64)

    def grids_of(self, ids) -> np.ndarray:
        """The grids of ``ids`` by id, bool (n, R, R, R); an id not here (it failed to voxelize) gets an empty
        grid."""
        at = self.rows_of(ids)
        out = np.zeros((len(at),) + self.grids.shape[1:], bool)
        out[at >= 0] = self.grids[at[at >= 0]]
        return out

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
        """Read a file written by :meth:`save`; :class:`DataError` naming the file if it is not one:
        meta lacking or mistyping ``resolution`` / ``classes`` / ``split``, a resolution other than
        30, bit rows that do not fit, labels that are not integers in ``0..len(classes) - 1``,
        counts of grids, labels and ids that differ, or an id that appears twice (:func:`unique_ids`)."""
        path = Path(path)
        meta, a = read_npz(path, ("packed", "labels", "ids"), "grid set", FORMAT_VERSION, "; rebuild it")
        packed, labels, ids = a["packed"], a["labels"], a["ids"]
        for key, typ in (("resolution", int), ("classes", list), ("split", str)):
            if key not in meta:
                raise DataError(path, f"grid set meta lacks \"{key}\"; rebuild it")
        r, classes = meta["resolution"], meta["classes"]
        if not isinstance(r, int) or isinstance(r, bool):
            raise DataError(path, f"grid set meta: \"resolution\" must be an integer, got {r!r}")
        if r != C.RESOLUTION:
            raise DataError(path, f"grid set of resolution {r}; expected {C.RESOLUTION}")
        if (not isinstance(classes, list) or not classes or not all(isinstance(c, str) for c in classes)
                or len(set(classes)) != len(classes)):
            raise DataError(path, "grid set meta: \"classes\" must be a list of distinct class names")
        try:
            grids = unpack_bits(packed, (r, r, r))
        except ValueError as err:
            raise DataError(path, f"corrupt grid set ({err})") from None
        if labels.ndim != 1 or ids.ndim != 1 or not len(grids) == len(labels) == len(ids):
            raise DataError(path, f"corrupt grid set: {len(grids)} grids, labels {labels.shape}, ids {ids.shape}")
        if labels.dtype.kind not in "iu":
            raise DataError(path, f"corrupt grid set: labels must be integers, got {labels.dtype}")
        if labels.size and (labels.min() < 0 or labels.max() >= len(classes)):
            raise DataError(path, f"corrupt grid set: labels outside 0..{len(classes) - 1}")
        unique_ids(ids, path)
        return cls(grids, labels, ids, tuple(classes), str(meta["split"]), meta)


def unique_ids(ids, where) -> None:
    """DataError naming ``where`` (a grid set's file, a dataset) when ``ids`` repeat one: a set is looked
    up by id (:meth:`GridSet.rows_of`), and a repeated one would silently give another object's grid."""
    names, counts = np.unique(np.asarray(ids).astype(str), return_counts=True)
    if (counts > 1).any():
        twice = [str(i) for i in names[counts > 1]]
        raise DataError(where, f"{len(twice)} object id(s) appear more than once ({', '.join(twice[:5])}"
                               f"{', ...' if len(twice) > 5 else ''}); each object needs an id of its own, "
                               f"so lookups by id cannot return another object's grid")


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


def _record_name(r: ObjectRecord) -> str:
    return f"{r.split}/{r.cls}/{r.id}"


def _chunk_job(args):
    """Worker side: grids of ``records`` -> (positions that succeeded, packed grids (n_ok, bytes),
    failures [dict]). A DataError or any other error of one object fails that object only."""
    records, settings = args
    ok, grids, failed = [], [], []
    for k, r in enumerate(records):
        try:
            grids.append(record_grid(r, settings))
            ok.append(k)
        except Exception as err:   # noqa: BLE001 -- any error of one object is that object's failure
            reason = err.problem if isinstance(err, DataError) else f"{type(err).__name__}: {err}"
            where = (err.path if isinstance(err, DataError) else None) or r.path or _record_name(r)
            failed.append(failure(where, reason, "voxelize", object=_record_name(r), split=r.split))
    r = settings["resolution"]
    packed = pack_bits(np.stack(grids)) if grids else np.zeros((0, -(-r ** 3 // 8)), np.uint8)
    return ok, packed, failed


def _item_keys(dataset: Dataset, records: list[ObjectRecord]) -> list[str]:
    """What identifies one object's grid: its name plus its file's size and mtime (a repaired or
    replaced file gets a new key), or the dataset fingerprint for objects without a file."""
    fp = None
    keys = []
    for r in records:
        if r.path is not None and Path(r.path).exists():
            st = Path(r.path).stat()
            keys.append(f"{_record_name(r)}|{Path(r.path).resolve()}|{st.st_size}|{st.st_mtime_ns}")
        else:
            fp = fp or dataset.fingerprint()
            keys.append(f"{_record_name(r)}|{fp}")
    return keys


def cache_key(dataset: Dataset, split: str, settings: dict = VOXEL_SETTINGS) -> str:
    """The cache folder's key: dataset name, split and voxel settings (objects are keyed inside)."""
    h = hashlib.sha256()
    h.update(f"{CACHE_VERSION}\n{dataset.name}\n{split}\n".encode())
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:20]


def _chunk_path(folder: Path, keys: list[str]) -> Path:
    return folder / f"chunk_{hashlib.sha256(chr(10).join(keys).encode()).hexdigest()[:16]}.npz"


def _write_chunk(folder: Path, keys: list[str], packed: np.ndarray) -> Path:
    path = _chunk_path(folder, keys)
    write_npz(path, {"format_version": CACHE_VERSION}, compressed=True, grids=packed, keys=np.array(keys, str))
    return path


def _read_cache(folder: Path) -> tuple[dict[str, np.ndarray], dict[Path, list[str]]]:
    """Every cached grid of ``folder``: ({item key: packed row}, {chunk file: its keys}). An unreadable
    chunk (a damaged file) is deleted: its objects are simply voxelized again."""
    rows, files = {}, {}
    for p in sorted(folder.glob("chunk_*.npz")):
        try:
            _, a = read_npz(p, ("grids", "keys"), "voxel cache chunk", CACHE_VERSION)
            if len(a["grids"]) != len(a["keys"]):
                raise DataError(p, "grids and keys differ in length")
        except DataError:
            p.unlink(missing_ok=True)
            continue
        keys = [str(k) for k in a["keys"]]
        rows.update(zip(keys, a["grids"]))
        files[p] = keys
    return rows, files


def build_gridset(dataset: Dataset, records: list[ObjectRecord], split: str,
                  cache: str | os.PathLike | None = None, workers: int = 1,
                  chunk: int = 32, progress: bool = True, settings: dict = VOXEL_SETTINGS) -> GridSet:
    """Grids for ``records`` (all of one split), computed in ``workers`` processes and cached.

    Objects that fail are left out and listed in the result's :attr:`GridSet.failures`; if every
    object fails, DataError (with the list as its ``failures``). Cached grids are reused object by
    object (see the module docstring); a rerun voxelizes only what failed or changed. Same result
    for any worker count and chunk size. ``cache=None`` uses :func:`hbeo.config.cache_dir`.
    """
    if any(r.split != split for r in records):
        raise ValueError(f"build_gridset: all records must be from split {split!r}")
    unique_ids([r.id for r in records], dataset.name)     # before any work
    cdir = Path(cache) if cache is not None else config.cache_dir()
    if cdir.exists() and not cdir.is_dir():       # fail before any work, naming the setting's file
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(cdir))
    folder = cdir / f"{dataset.name.replace(os.sep, '_').strip('_')}-{split}-{cache_key(dataset, split, settings)}"
    keys = _item_keys(dataset, records)
    rows, files = _read_cache(folder) if folder.is_dir() else ({}, {})
    todo = [i for i, k in enumerate(keys) if k not in rows]
    chunks = [todo[i:i + chunk] for i in range(0, len(todo), chunk)]
    bar = tqdm(total=len(records), desc=f"voxelize {dataset.name}/{split}", unit="obj",
               disable=not progress, initial=len(records) - len(todo))
    failed: dict[int, dict] = {}

    def done(items, result):
        ok, packed, fails = result
        if ok:
            ck = [keys[items[k]] for k in ok]
            files[_write_chunk(folder, ck, packed)] = ck
            rows.update(zip(ck, packed))
        bad = sorted(set(range(len(items))) - set(ok))
        failed.update((items[k], f) for k, f in zip(bad, fails))
        bar.update(len(items))

    jobs = [([records[i] for i in items], settings) for items in chunks]
    needs_mesh = any(not records[i].has_grid for i in todo)
    if workers > 1 and len(chunks) > 1 and needs_mesh:
        check_workers(min(workers, len(chunks)), "--workers")      # before the processes start
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for items, result in zip(chunks, pool.map(_chunk_job, jobs)):
                done(items, result)
    else:
        for items, job in zip(chunks, jobs):
            done(items, _chunk_job(job))
    bar.close()
    failures = [failed[i] for i in sorted(failed)]
    good = [i for i in range(len(records)) if i not in failed]
    if records and not good:
        raise BatchError(dataset.name, f"none of the {len(records)} {split} objects could be voxelized; first: "
                                       f"{failures[0]['file']}: {failures[0]['reason']}", failures)
    _consolidate(folder, [keys[i] for i in good], rows, files)
    r = settings["resolution"]
    packed = np.stack([rows[keys[i]] for i in good]) if good else np.zeros((0, -(-r ** 3 // 8)), np.uint8)
    labels = np.array([dataset.classes.index(records[i].cls) for i in good], dtype=np.int64)
    ids = np.array([records[i].id for i in good], dtype=str)
    meta = {"dataset": dataset.name, "fingerprint": dataset.fingerprint(), "settings": settings,
            "failed": failures}
    return GridSet(unpack_bits(packed, (r, r, r)), labels, ids, tuple(dataset.classes), split, meta)


def _consolidate(folder: Path, keys: list[str], rows: dict, files: dict[Path, list[str]]) -> None:
    """Merge the cached grids of ``keys`` into one chunk file and delete the chunk files it covers
    (chunks holding other objects, of another selection of the dataset, stay)."""
    if not keys:
        return
    path, wanted = _chunk_path(folder, keys), set(keys)
    covered = [p for p, ks in files.items() if p != path and wanted.issuperset(ks)]
    if path in files and not covered:
        return
    _write_chunk(folder, keys, np.stack([rows[k] for k in keys]))
    for p in covered:
        p.unlink(missing_ok=True)


def run_gridsets(run, ds: Dataset, prof, progress: bool = True, rebuild: bool = False) -> dict[str, GridSet]:
    """The run's ``{"train": GridSet, "test": GridSet}``: read from the run folder's grid sets
    (:meth:`hbeo.rundir.RunDir.grids`) when present, else built from the dataset ``ds`` (a loaded
    :class:`~hbeo.data.datasets.Dataset`) with the profile ``prof`` (a :class:`~hbeo.config.Profile`)
    (cached, see :func:`build_gridset`) and written there. ``rebuild``: build and write them even when present
    (notebook 01, the step that owns them). ``run``: a :class:`~hbeo.rundir.RunDir` or a path (most
    callers: :meth:`hbeo.run.Run.grids`). Objects that failed are left out of the sets and listed in the
    run's ``failures.json``."""
    from hbeo.data import datasets
    run = RunDir.of(run)
    out = {}
    for split in C.SPLITS:
        path = run.grids(split)
        if path.exists() and not rebuild:
            out[split] = GridSet.load(path)
            continue
        try:
            out[split] = build_gridset(ds, datasets.select(ds, split, prof), split, workers=prof.data.workers,
                                       progress=progress)
        except DataError as err:
            run.write_failures("voxelize", err.failures if isinstance(err, BatchError) else [], splits=[split])
            raise
        out[split].save(path)
        run.write_failures("voxelize", out[split].failures, splits=[split])
    return out
