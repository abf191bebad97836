"""One grid file of a whole dataset in the published ``modelnet10_vox30.npz`` layout, and its
agreement with the published file.

Owns the layout of ``shared/modelnet10_vox30/modelnet10_vox30.npz`` (see its README) as this package
writes it: a compressed ``.npz`` with, in this order,

=================  ===========================  ===============================================
key                shape, dtype                 meaning
=================  ===========================  ===============================================
``X_train``        (N, 30, 30, 30) uint8        0/1 occupancy, 3D ShapeNets layout (voxels;
                                                axes x, y, z of the mesh file's object frame, +z up)
``y_train``        (N,) int64                   class index into ``classes``
``names_train``    (N,) <U16 (wider if needed)  the object's id (ModelNet file stem, ``chair_0001``)
``X_test`` ...     (M, ...)                     the same for the test split
``classes``        (K,) <U11 (wider if needed)  class names in :data:`hbeo.conventions.CLASSES` order
=================  ===========================  ===============================================

Objects are sorted by (class index, name), as in the published file. A dataset whose classes are all
ModelNet10 classes gets all ten in ``classes`` (its labels mean what the published file's mean,
whichever classes it holds); other class names follow the ten, sorted. There is no ``meta`` entry.

:func:`write_gridfile` voxelizes every object (all of both splits, whatever a profile selects)
through :func:`hbeo.data.gridset.build_gridset`, so it shares the per-object voxel cache: an
interrupted run resumes, a rerun voxelizes nothing. The file is written atomically (a temporary
name, then a rename: an interruption never leaves a complete-looking file). A bad mesh is skipped,
named in the result's ``failures`` (``{file, reason, step, object, split}``, as in ``failures.json``)
and in ``<FILE>.failures.json`` beside the file; with ``strict`` nothing is written and a
:class:`~hbeo.errors.DataError` names the bad files. :func:`compare_gridfiles` matches grids to the
published ones by name: per-object IoU and a summary. Imports the foundation and :mod:`hbeo.data`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hbeo import config
from hbeo import conventions as C
from hbeo.data.datasets import Dataset
from hbeo.data.gridset import GridSet, build_gridset
from hbeo.errors import DataError, MissingDataError
from hbeo.rundir import failure_summary
from hbeo.storage import atomic_text, check_outputs, json_text, write_npz

#: the published file's string widths (``names`` <U16, ``classes`` <U11); longer names widen them
NAME_WIDTH, CLASS_WIDTH = 16, 11
KEYS = tuple(f"{a}_{s}" for s in C.SPLITS for a in ("X", "y", "names")) + ("classes",)


def file_classes(dataset_classes) -> tuple[str, ...]:
    """The ``classes`` of a grid file for a dataset with these classes: all of
    :data:`~hbeo.conventions.CLASSES` (in that order) when they include every dataset class, else
    the dataset's ModelNet10 classes in that order followed by its other classes, sorted."""
    known = [c for c in C.CLASSES if c in dataset_classes]
    other = sorted(set(dataset_classes) - set(C.CLASSES))
    return C.CLASSES if not other else tuple(known + other)


def failures_path(path) -> Path:
    """Where the objects left out of grid file ``path`` are listed: ``<path>.failures.json``."""
    path = Path(path)
    return path.with_name(path.name + ".failures.json")


@dataclass
class GridFileResult:
    """What :func:`write_gridfile` wrote: ``counts`` {split: objects}, the objects left out
    (``failures``) among ``total``, and the agreement with the published file (or None)."""

    path: Path
    counts: dict
    total: int
    failures: list = field(default_factory=list)
    agreement: dict | None = None

    def report(self) -> str:
        """One line on what was written, one on the agreement with the published grids."""
        lines = [f"{self.path}: " + ", ".join(f"{n} {s}" for s, n in self.counts.items())
                 + f" grids in the modelnet10_vox30 layout ({len(self.failures)} of {self.total} objects failed)"]
        if self.agreement:
            lines.append(describe_agreement(self.agreement))
        return "\n".join(lines)

    def failure_report(self) -> str:
        """The bad objects, one line each (empty when none)."""
        return failure_summary(self.failures, self.total, failures_path(self.path))


def _sorted_records(dataset: Dataset, split: str, classes: tuple[str, ...]):
    recs = sorted(dataset.records(split=split), key=lambda r: (classes.index(r.cls), r.id))
    ids = [r.id for r in recs]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise DataError(dataset.name, f"{split} split names objects twice ({', '.join(dup[:5])}); a grid "
                                      f"file names each object once")
    return recs


def write_gridfile(dataset: Dataset, path, cache=None, workers: int = 1, progress: bool = True,
                   strict: bool = False, compare: bool = True, chunk: int = 32) -> GridFileResult:
    """Voxelize every object of ``dataset`` (both splits) and write them to ``path`` in the published
    ``modelnet10_vox30.npz`` layout (module docstring), atomically. Grids come from the voxel cache
    under ``cache`` (default :func:`hbeo.config.cache_dir`) where present; ``workers`` processes;
    finished grids reach the cache ``chunk`` objects at a time (what an interruption can lose).

    Bad objects are left out and returned in ``failures`` (also written to ``<path>.failures.json``;
    a stale list is removed); with ``strict``, a DataError naming them and nothing written. DataError
    too when no object at all could be voxelized, or ``path`` cannot be written or is the dataset's
    own file. ``compare``: also measure the agreement with the published file by name
    (:func:`compare_gridfiles`) when it is found and shares names with this one."""
    path = Path(path)
    check_outputs({"--out": path}, {"--dataset": getattr(dataset, "path", None)})
    classes = file_classes(dataset.classes)
    arrays, failures, total, sets = {}, [], 0, {}
    for split in C.SPLITS:
        recs = _sorted_records(dataset, split, classes)
        total += len(recs)
        try:
            gs = build_gridset(dataset, recs, split, cache=cache, workers=workers, chunk=chunk,
                               progress=progress)
        except DataError as err:     # every object of the split failed
            if not getattr(err, "failures", None):
                raise
            failures += err.failures
            gs = GridSet(np.zeros((0,) + (C.RESOLUTION,) * 3, bool), np.zeros(0, np.int64),
                         np.zeros(0, str), tuple(dataset.classes), split)
        failures += gs.failures
        sets[split] = gs
        width = max([NAME_WIDTH] + [len(i) for i in gs.ids])
        arrays[f"X_{split}"] = gs.grids.astype(np.uint8)
        arrays[f"y_{split}"] = np.array([classes.index(gs.classes[k]) for k in gs.labels], np.int64)
        arrays[f"names_{split}"] = np.array([str(i) for i in gs.ids], dtype=f"<U{width}")
    if total and len(failures) == total:
        raise DataError(dataset.name, f"none of the {total} objects could be voxelized; first: "
                                      f"{failures[0]['file']}: {failures[0]['reason']}")
    if strict and failures:
        more = [f["file"] for f in failures[1:4]] + (["..."] if len(failures) > 4 else [])
        raise DataError(failures[0]["file"], f"{failures[0]['reason']} ({len(failures)} of {total} objects could "
                                             f"not be voxelized{'; also ' + ', '.join(more) if more else ''}); "
                                             f"{path} not written")
    arrays["classes"] = np.array(classes, dtype=f"<U{max([CLASS_WIDTH] + [len(c) for c in classes])}")
    write_npz(path, None, compressed=True, **arrays)
    if failures:
        atomic_text(failures_path(path), json_text(failures, indent=1) + "\n")
    else:
        failures_path(path).unlink(missing_ok=True)
    result = GridFileResult(path, {s: len(g) for s, g in sets.items()}, total, failures)
    published = config.vox30_path()
    if compare and published is not None and published.is_file() and published.resolve() != path.resolve():
        named = {str(n): g for gs in sets.values() for n, g in zip(gs.ids, gs.grids)}
        agreement = compare_gridfiles(named, published)
        result.agreement = agreement if agreement["n_matched"] else None
    return result


def read_gridfile(path) -> dict[str, np.ndarray]:
    """{name: bool grid (30, 30, 30)} of every object of a grid file in this layout (both splits).
    DataError naming the file when it is unreadable or lacks one of the arrays."""
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("X_train", "names_train", "X_test", "names_test") if k not in z.files]
            if missing:
                raise DataError(path, f"not a grid file: missing arrays {missing}; expected {list(KEYS)}")
            out = {}
            for split in C.SPLITS:
                X, names = z[f"X_{split}"], z[f"names_{split}"]
                if X.ndim != 4 or X.shape[1:] != (C.RESOLUTION,) * 3 or len(X) != len(names):
                    raise DataError(path, f"X_{split} has shape {X.shape}; expected (N, 30, 30, 30) for "
                                          f"{len(names)} names")
                out.update(zip((str(n) for n in names), X.astype(bool)))
            return out
    except DataError:
        raise
    except FileNotFoundError:
        raise DataError(path, "no such grid file") from None
    except Exception as err:
        raise DataError(path, f"unreadable grid file ({type(err).__name__}: {err})") from None


def compare_gridfiles(grids, published=None) -> dict:
    """Agreement of ``grids`` with the published grids, matched by object name.

    ``grids``: a grid file path (this layout), a :class:`~hbeo.data.gridset.GridSet`, or a mapping
    {name: grid (30, 30, 30)}; ``published``: the reference file (default
    :func:`hbeo.config.vox30_path`; MissingDataError when not found). IoU of two empty grids is 1.
    Returns ``n_matched``, ``unmatched`` (names not in the reference), ``mean_iou``, ``median_iou``,
    ``min_iou`` with ``min_name``, ``identical_fraction`` (grids equal voxel for voxel) and ``iou``
    {name: IoU} (NaN statistics when nothing matched)."""
    published = published if published is not None else config.vox30_path()
    if published is None:
        raise MissingDataError("published grid file not found (shared/modelnet10_vox30); set HBEO_VOX30")
    if isinstance(grids, GridSet):
        grids = dict(zip((str(i) for i in grids.ids), grids.grids))
    elif not hasattr(grids, "items"):
        grids = read_gridfile(grids)
    ref = read_gridfile(published)
    ious, identical, unmatched = {}, 0, []
    for name, g in grids.items():
        if name not in ref:
            unmatched.append(name)
            continue
        g, r = np.asarray(g, bool), ref[name]
        if g.shape != r.shape:
            raise ValueError(f"{name}: grid of shape {g.shape}; the published one is {r.shape}")
        union = int((g | r).sum())
        ious[name] = float((g & r).sum() / union) if union else 1.0
        identical += bool((g == r).all())
    vals = np.array(list(ious.values()), float)
    worst = min(ious, key=ious.get) if ious else None
    return {"n_matched": len(ious), "unmatched": unmatched,
            "mean_iou": float(vals.mean()) if len(vals) else float("nan"),
            "median_iou": float(np.median(vals)) if len(vals) else float("nan"),
            "min_iou": ious[worst] if worst else float("nan"), "min_name": worst,
            "identical_fraction": identical / len(ious) if ious else float("nan"), "iou": ious}


def describe_agreement(summary: dict) -> str:
    """One line from a :func:`compare_gridfiles` summary."""
    s = summary
    return (f"agreement with the published grids ({s['n_matched']} objects by name): IoU mean "
            f"{s['mean_iou']:.3f}, median {s['median_iou']:.3f}, min {s['min_iou']:.3f} ({s['min_name']}); "
            f"{s['identical_fraction']:.1%} identical")
