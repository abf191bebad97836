"""The training-set factory: segmented synthetic depth images labelled with class, pose and shape.

:func:`render_set` renders ``views_per_object`` depth images of every object of a split from
random viewpoints (:class:`hbeo.render.poses.ViewSampler`) and writes them, a few objects at a time,
into compressed shards ``shard_NNNNN.npz``; ``manifest.json``, written last, describes the set
(:class:`Manifest`). The images of one object come from :class:`hbeo.render.views.ObjectViews`;
:mod:`hbeo.render.torch_datasets` reads a set for training (:class:`~hbeo.render.torch_datasets.DepthShards`)
or renders the same images on the fly (:class:`~hbeo.render.torch_datasets.StreamingDepth`).
Imports the foundation, :mod:`hbeo.render` (views, noise; the renderer in workers) and Dask.

Where it renders
    Shards are tasks on a Dask cluster: a new ``LocalCluster`` of ``workers`` processes, one thread
    each, or the running scheduler at ``scheduler`` (e.g. ``tcp://host:8786``; its workers must run
    the same hbeo and see ``out_dir`` at the same path: each shard's sha256 is read back here).
    Dask moves tasks and results with pickle: only use a scheduler you trust. ``workers=1`` with
    no scheduler renders in one child process instead (no cluster to start; the same bytes).

Shard arrays (N = images in the shard; all views of an object are consecutive)
    ``depth`` float16 (N, H, W), metres, 0 = no object; ``mask`` uint8 (N, ceil(H*W/8)), the
    bit-packed ``depth > 0`` (see :func:`hbeo.render.torch_datasets.load_shard`); ``label`` int64 (N,) into the dataset's
    classes; ``object_index`` int64 (N,), the object's position in the record list;
    ``object_id`` str (N,); ``view`` int64 (N,), the view's number within its object;
    ``rotation`` float32 (N, 3, 3) and ``axis_angle`` float32 (N, 3), the pose R (object ->
    camera, :mod:`hbeo.conventions`); ``translation`` float32 (N, 3), metres; ``intrinsics``
    float64 (6,) = (fx, fy, cx, cy, width, height); with a subspace, ``coeffs`` float32 (N, k):
    the coefficients of the object's complete 30^3 grid (the same for all its views).

Determinism
    Object ``p`` of the record list draws its views (and sensor noise) from
    ``np.random.default_rng([seed, split_code, p])`` (split_code 0 = train, 1 = test;
    :func:`hbeo.render.views.object_rng`), so a shard depends only on its own objects: the same bytes for any number of workers. Shards
    are zip files with fixed timestamps, so reruns reproduce their sha256 too.

Bad objects
    An object whose mesh cannot be loaded or prepared, or fails to render (a
    :class:`~hbeo.errors.DataError` from :class:`~hbeo.render.views.ObjectViews`), is left out: its
    shard holds the other objects' views, and the manifest lists it under ``failed``
    (``{file, reason, step, object, split, position}``, :attr:`Manifest.failures`). It keeps its
    position in ``object_ids`` (so ``object_index`` still indexes that list) with no image
    (:meth:`Manifest.image_objects`). If no object at all renders, :class:`~hbeo.errors.BatchError`
    (its ``failures`` attribute lists them) and no manifest.

Resuming
    A shard is written under a temporary name and renamed into place, then a
    ``shard_NNNNN.npz.sha256`` sidecar (``sha256sum`` format) records its hash -- only for a shard
    without failures, so a rerun tries its failed objects again. A rerun keeps the shards whose
    hash matches their sidecar and renders the rest; over a finished set it checks every shard
    against the manifest's sha256 and renders again (with a warning) what is missing, truncated or
    modified, and the shards of failed objects. ``manifest.partial.json`` (written first) and
    ``manifest.json`` (written last) hold the settings: a folder rendered with other settings is
    refused instead of mixed.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from hbeo.progress import tqdm

from hbeo import __version__
from hbeo.errors import BatchError, DataError
from hbeo.limits import check_render
from hbeo.rundir import RENDER_MANIFEST, failure
from hbeo.render.noise import SensorNoise
from hbeo.render.views import (ObjectViews, RenderSettings, _as_int, _noise_description, _record_name,
                               _split_code)
from hbeo.storage import (atomic_text, json_text, pack_bits, sha256_file, sidecar_path, verify_sidecar, write_npz,
                          write_sidecar)

FORMAT_VERSION = 1
MANIFEST = RENDER_MANIFEST        #: the set's description, written last (its name is RunDir's)
PARTIAL = "manifest.partial.json"
#: Default shard size in images (a 320x240 float16 shard of 1024 images is ~160 MB in memory).
IMAGES_PER_SHARD = 1024
CONNECT_TIMEOUT = "30s"           #: how long to try to reach a Dask scheduler (distributed's syntax)
SHARD_KEYS = ("depth", "mask", "label", "object_index", "object_id", "view", "rotation",
              "axis_angle", "translation", "intrinsics")


# --------------------------------------------------------------------------- shard files

def _write_npz(path: Path, arrays: dict) -> tuple[str, int]:
    """A compressed shard, written atomically with fixed bytes (:func:`hbeo.storage.write_npz`);
    returns (sha256, size)."""
    write_npz(path, None, compressed=True, **arrays)
    return sha256_file(path), path.stat().st_size


def _shard_name(k: int) -> str:
    return f"shard_{k:05d}.npz"


def _finished_shard(path: Path) -> tuple[str, int] | None:
    """(sha256, size) of a shard whose file matches its sidecar, else None (with a warning when a
    shard file is there but does not match: it is rendered again)."""
    digest = verify_sidecar(path)
    if digest:
        return digest, path.stat().st_size
    if path.is_file() and sidecar_path(path).is_file():
        warnings.warn(f"{path}: does not match its recorded sha256 (truncated or modified); rendering it again",
                      stacklevel=3)
    return None


def _damaged_shards(m: "Manifest") -> list[Path]:
    """The shards of a finished set that are missing or do not match the manifest's sha256 (each
    with a warning), and the shards holding objects that failed (to try them again)."""
    bad = []
    for s, p in zip(m.shards, m.shard_paths()):
        if not p.is_file():
            warnings.warn(f"{p}: shard listed in the manifest is missing; rendering it again", stacklevel=3)
        elif sha256_file(p) != s["sha256"]:
            warnings.warn(f"{p}: does not match its recorded sha256 (truncated or modified); rendering it again",
                          stacklevel=3)
        else:
            continue
        bad.append(p)
    return bad


# --------------------------------------------------------------------------- workers

def _render_shard(ctx: ObjectViews, path: Path, items, split: str) -> dict:
    """Render the objects ``items`` [(position, record, label)] into shard ``path``; an object that
    fails (DataError) is left out and reported under ``failed``. No file when every object failed;
    no sidecar when any did (a rerun renders the shard again)."""
    parts, failed = [], []
    for pos, rec, label in items:
        try:
            parts.append(ctx.views(rec, pos, label, split))
        except DataError as err:
            failed.append(failure(err.path or _record_name(rec), err.problem, "render",
                                  object=_record_name(rec), split=split, position=int(pos)))
    sidecar_path(path).unlink(missing_ok=True)
    if not parts:
        path.unlink(missing_ok=True)
        return {"sha256": None, "bytes": 0, "n_images": 0, "backend": ctx.backend, "failed": failed}
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    n = len(arrays["depth"])
    arrays["mask"] = pack_bits(arrays["mask"])
    arrays["intrinsics"] = np.array(ctx.intrinsics.as_tuple(), np.float64)
    digest, size = _write_npz(path, arrays)
    if not failed:
        write_sidecar(path, digest)
    return {"sha256": digest, "bytes": size, "n_images": n, "backend": ctx.backend, "failed": failed}


_THREAD = threading.local()      # in a worker: (set key, ObjectViews) of this thread


def _views(key: str, spec) -> ObjectViews:
    """This thread's :class:`ObjectViews` for the set ``key`` (``spec`` = (settings, subspace)):
    built once per worker thread and set (a renderer's GL context belongs to its thread), replaced
    when another set comes."""
    held = getattr(_THREAD, "views", None)
    if held is None or held[0] != key:
        import torch
        from threadpoolctl import threadpool_limits
        torch.set_num_threads(1)       # one thread per task: idle BLAS threads halve parallel workers' speed
        threadpool_limits(1)
        _THREAD.views = held = (key, ObjectViews(*spec))
    return held[1]


def _shard_task(key: str, spec, path: str, items, split: str) -> dict:
    """Worker side: render one shard (``spec`` is scattered once per set on Dask; None in the
    single child process, whose initializer built the renderer)."""
    res = _render_shard(_views(key, spec), Path(path), items, split)
    res["hbeo_version"] = __version__
    return res


def _start_child(key: str, spec) -> None:
    """The single child: dies with its parent (Linux; no orphan writes on); builds its renderer."""
    import ctypes
    import signal
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    _views(key, spec)


def _render_in_child(jobs: dict, split: str, key: str, spec, done) -> None:
    """``workers=1``, no scheduler: one spawned child (~1 s sooner than a LocalCluster) renders the
    shards in turn; not this process, where embree's threads would slow later torch work 100x."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=_start_child,
                             initargs=(key, spec)) as pool:
        for k, (path, items) in jobs.items():
            res = pool.submit(_shard_task, key, None, str(path), items, split).result()
            del res["hbeo_version"]
            done(k, res)


@contextlib.contextmanager
def _dask_client(workers: int, scheduler: str | None):
    """A ``distributed.Client`` of the scheduler at ``scheduler``, or of a new LocalCluster of
    ``workers`` processes (one thread each; closed on exit; its worker processes exit when this
    process dies, through distributed's parent-alive pipe, so a killed job leaves no orphans)."""
    from distributed import Client, LocalCluster
    with contextlib.ExitStack() as stack:
        if scheduler:
            try:
                client = stack.enter_context(Client(scheduler, timeout=CONNECT_TIMEOUT))
            except (OSError, TimeoutError, ValueError) as err:
                raise DataError(scheduler, f"cannot reach the Dask scheduler ({type(err).__name__}: {err})") from None
            client.wait_for_workers(1, timeout=60)   # TimeoutError after a minute without a worker
        else:
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                silence_logs=logging.ERROR))
            client = stack.enter_context(Client(cluster))
        yield client


def _render_shards(jobs: dict, split: str, key: str, spec, workers: int, scheduler: str | None, done) -> None:
    """Render the shards ``jobs`` {k: (path, items)}, calling ``done(k, result)`` as each finishes,
    on Dask (the first error cancels the rest and is raised), or in one child process."""
    if workers == 1 and not scheduler:
        return _render_in_child(jobs, split, key, spec, done)
    from distributed import as_completed
    with _dask_client(workers, scheduler) as client:
        [shared] = client.scatter([spec], broadcast=True)
        futures = {client.submit(_shard_task, key, shared, str(path.resolve()), items, split, pure=False): k
                   for k, (path, items) in jobs.items()}
        try:
            for f in as_completed(futures):
                res, path = f.result(), jobs[futures[f]][0]
                if res.pop("hbeo_version") != __version__:
                    raise DataError(path, "rendered by a Dask worker running another hbeo version; "
                                          "install the same hbeo on every worker")
                if res["n_images"] and (not path.is_file() or sha256_file(path) != res["sha256"]):
                    raise DataError(path, "a Dask worker wrote this shard, but it is missing or different "
                                          "here: workers must see the output folder at the same path")
                done(futures[f], res)
        except BaseException:
            client.cancel(list(futures))
            raise


# --------------------------------------------------------------------------- the manifest

@dataclass
class Manifest:
    """A rendered set's ``manifest.json``. ``images_per_s`` and ``rendered`` describe the call
    of :func:`render_set` that returned it (None / 0 when nothing had to be rendered)."""

    path: Path
    data: dict
    images_per_s: float | None = None
    rendered: int = 0
    seconds: float = 0.0

    @classmethod
    def load(cls, path) -> "Manifest":
        """From a set's folder or its ``manifest.json`` (DataError naming the file otherwise)."""
        if isinstance(path, Manifest):
            return path
        p = Path(path)
        if p.is_dir():
            p = p / MANIFEST
        try:
            data = json.loads(p.read_text())
        except FileNotFoundError:
            hint = " (rendering not finished?)" if (p.parent / PARTIAL).exists() else ""
            raise DataError(p, f"no rendered set manifest{hint}") from None
        except Exception as err:
            raise DataError(p, f"not a readable manifest ({type(err).__name__}: {err})") from None
        if data.get("format_version") != FORMAT_VERSION:
            raise DataError(p, f"rendered set format {data.get('format_version')}, this hbeo reads "
                               f"{FORMAT_VERSION}; render it again")
        return cls(p, data)

    @property
    def root(self) -> Path:
        return self.path.parent

    @property
    def settings(self) -> RenderSettings:
        return RenderSettings.from_dict(self.data["settings"])

    @property
    def split(self) -> str:
        return self.data["split"]

    @property
    def classes(self) -> tuple[str, ...]:
        return tuple(self.data["classes"])

    @property
    def n_images(self) -> int:
        return int(self.data["n_images"])

    def __len__(self) -> int:
        return self.n_images

    @property
    def counts(self) -> dict[str, int]:
        """Images per class name."""
        return dict(self.data["counts"])

    @property
    def object_ids(self) -> list[str]:
        return list(self.data["object_ids"])

    @property
    def object_labels(self) -> np.ndarray:
        return np.asarray(self.data["object_labels"], np.int64)

    @property
    def coeffs_dim(self) -> int | None:
        sub = self.data.get("subspace")
        return None if sub is None else int(sub["dim"])

    @property
    def shards(self) -> list[dict]:
        return list(self.data["shards"])

    def shard_paths(self) -> list[Path]:
        return [self.root / s["file"] for s in self.shards]

    @property
    def failures(self) -> list[dict]:
        """The objects left out because they could not be rendered (module docstring); [] if none."""
        return list(self.data.get("failed", []))

    def image_objects(self) -> np.ndarray:
        """Object position (index into :attr:`object_ids`) of every image, in set order (objects
        that failed have no image)."""
        per = np.full(len(self.data["object_ids"]), int(self.data["views_per_object"]), np.int64)
        per[[int(f["position"]) for f in self.failures]] = 0
        return np.repeat(np.arange(len(per)), per)

    def verify(self) -> None:
        """Check every shard against its sha256 (DataError naming the first bad one)."""
        for s, p in zip(self.shards, self.shard_paths()):
            if not p.is_file():
                raise DataError(p, "shard listed in the manifest is missing")
            if sha256_file(p) != s["sha256"]:
                raise DataError(p, "shard does not match the sha256 in the manifest")

    def __repr__(self):
        return (f"<Manifest {self.data['dataset']}/{self.split}: {self.n_images} images of "
                f"{len(self.data['object_ids'])} objects in {len(self.shards)} shards, {self.root}>")


def subspace_info(subspace) -> dict | None:
    """What a manifest records of the subspace its coefficients come from (None without one)."""
    if subspace is None:
        return None
    basis = np.ascontiguousarray(subspace.basis_)
    return {"dim": int(basis.shape[1]), "fingerprint": getattr(subspace, "fingerprint_", None),
            "basis_sha256": hashlib.sha256(basis.tobytes()).hexdigest()[:16]}


def _identity(dataset, records, split, settings, subspace, objects_per_shard, noise) -> dict:
    """What decides the set's content: a folder holding a set with another identity is refused."""
    h = hashlib.sha256("\n".join(_record_name(r) for r in records).encode()).hexdigest()[:16]
    return {"format_version": FORMAT_VERSION, "dataset": dataset.name,
            "dataset_fingerprint": dataset.fingerprint(), "split": split, "n_objects": len(records),
            "objects_sha256": h, "objects_per_shard": int(objects_per_shard),
            "settings": settings.to_dict(), "noise_model": noise, "subspace": subspace_info(subspace)}


def _check_same(path: Path, old: dict, new: dict) -> None:
    diff = []
    for k, v in new.items():
        o = old.get(k)
        if isinstance(o, dict) and isinstance(v, dict):
            diff += [(f"{k}.{kk}", o.get(kk), v.get(kk)) for kk in sorted(set(o) | set(v)) if o.get(kk) != v.get(kk)]
        elif o != v:
            diff.append((k, o, v))
    if diff:
        details = "; ".join(f"{k}: {o!r} there, {v!r} now" for k, o, v in diff[:4])
        raise DataError(path, f"this folder holds a rendered set with different settings ({details}). "
                              f"Render into another folder or delete this one; sets are never mixed")


# --------------------------------------------------------------------------- render_set

def render_set(dataset, records, split: str, out_dir, settings: RenderSettings, subspace=None,
               workers: int = 1, objects_per_shard: int | None = None, progress: bool = True,
               scheduler: str | None = None) -> Manifest:
    """Render ``settings.views_per_object`` views of every record into ``out_dir`` (see the module
    docstring for the layout); resumes an interrupted run and returns the :class:`Manifest`
    (with ``images_per_s`` of this call). Shards are rendered by a LocalCluster of ``workers``
    processes, or by the Dask cluster whose scheduler is at ``scheduler`` (``workers`` is then
    unused); the same bytes either way; too big for memory or disk: refused first (:mod:`hbeo.limits`).
    ``objects_per_shard``: by default about :data:`IMAGES_PER_SHARD` images per shard (>= 1 object)."""
    records = list(records)
    if not records:
        raise ValueError(f"render_set: no records to render for split {split!r}")
    code = _split_code(split)  # noqa: F841 (validates split)
    if not isinstance(settings, RenderSettings):
        raise ValueError(f"render_set: settings must be a RenderSettings, got {type(settings).__name__}")
    if objects_per_shard is None:
        objects_per_shard = max(1, IMAGES_PER_SHARD // settings.views_per_object)
    if any(r.split != split for r in records):
        raise ValueError(f"render_set: all records must be from split {split!r}")
    if (workers := _as_int(workers, "render_set: workers")) < 1:
        raise ValueError(f"render_set: workers must be >= 1, got {workers}")
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise ValueError(f"render_set: scheduler must be an address such as 'tcp://host:8786', got {scheduler!r}")
    if (objects_per_shard := _as_int(objects_per_shard, "render_set: objects_per_shard")) < 1:
        raise ValueError(f"render_set: objects_per_shard must be >= 1, got {objects_per_shard}")
    if subspace is not None and not hasattr(subspace, "basis_"):
        raise ValueError("render_set: the subspace is not fitted")
    try:
        labels = [dataset.classes.index(r.cls) for r in records]
    except ValueError:
        bad = next(r for r in records if r.cls not in dataset.classes)
        raise ValueError(f"render_set: {_record_name(bad)} has class {bad.cls!r}, not one of the "
                         f"dataset's classes") from None
    check_render(len(records), settings.views_per_object, settings.image_size, out_dir, objects_per_shard, not scheduler and workers)
    noise = _noise_description(SensorNoise()) if settings.noise else None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ident = _identity(dataset, records, split, settings, subspace, objects_per_shard, noise)
    final, partial = out / MANIFEST, out / PARTIAL
    if final.exists():
        m = Manifest.load(final)
        _check_same(final, m.data, ident)
        damaged = _damaged_shards(m)
        if not damaged and not m.failures:
            return m
        for p in damaged:                                   # rendered again below
            p.unlink(missing_ok=True)
            sidecar_path(p).unlink(missing_ok=True)
        atomic_text(partial, json_text(ident, indent=1))
        final.unlink()
    if partial.exists():
        try:
            old = json.loads(partial.read_text())
        except Exception as err:
            raise DataError(partial, f"unreadable ({type(err).__name__}: {err}); delete the folder") from None
        _check_same(partial, old, ident)
    elif any(out.glob("shard_*.npz")):
        raise DataError(out, "holds shards but no manifest: not a set this hbeo is rendering; "
                             "render into another folder or delete it")
    else:
        atomic_text(partial, json_text(ident, indent=1))
    for tmp in out.glob(".shard_*.tmp"):         # left behind by a killed run
        tmp.unlink(missing_ok=True)

    n_views = settings.views_per_object
    starts = list(range(0, len(records), objects_per_shard))
    chunks = [[(p, records[p], labels[p]) for p in range(s, min(s + objects_per_shard, len(records)))]
              for s in starts]
    paths = [out / _shard_name(k) for k in range(len(chunks))]
    info: dict[int, dict] = {}
    for k, p in enumerate(paths):
        kept = _finished_shard(p)
        if kept is not None:
            info[k] = {"sha256": kept[0], "bytes": kept[1], "n_images": len(chunks[k]) * n_views}
    todo = [k for k in range(len(chunks)) if k not in info]
    total = len(records) * n_views
    bar = tqdm(total=total, initial=total - sum(len(chunks[k]) for k in todo) * n_views, unit="img",
               desc=f"render {dataset.name}/{split}", disable=not progress, smoothing=0.1)
    backends = set()

    def done(k: int, res: dict) -> None:     # a shard is finished
        info[k] = res
        backends.add(res.pop("backend"))
        bar.update(len(chunks[k]) * n_views)

    t0 = time.perf_counter()
    try:
        if todo:
            key = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()
            _render_shards({k: (paths[k], chunks[k]) for k in todo}, split, key, (settings, subspace),
                           min(workers, len(todo)), scheduler, done)
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    rendered = sum(info[k]["n_images"] for k in todo)
    failed = sorted((f for k in todo for f in info[k].get("failed", [])), key=lambda f: f["position"])
    if not any(i["n_images"] for i in info.values()):
        raise BatchError(out, f"none of the {len(records)} {split} objects could be rendered; first: "
                              f"{failed[0]['file']}: {failed[0]['reason']}", failed)
    bad = {f["position"] for f in failed}

    counts = {c: 0 for c in dataset.classes}
    obj_counts = {c: 0 for c in dataset.classes}
    for p, r in enumerate(records):
        if p not in bad:
            counts[r.cls] += n_views
            obj_counts[r.cls] += 1
    w, h = settings.image_size
    data = dict(ident)
    data.update({
        "hbeo_version": __version__,
        "classes": list(dataset.classes),
        "n_images": sum(i["n_images"] for i in info.values()),
        "views_per_object": n_views,
        "image_size": [w, h],
        "intrinsics": list(settings.intrinsics.as_tuple()),
        "counts": counts,
        "object_counts": obj_counts,
        "object_ids": [r.id for r in records],
        "object_labels": labels,
        "backend_used": sorted(backends) or None,
        "shards": [{"file": paths[k].name, "sha256": info[k]["sha256"], "bytes": info[k]["bytes"],
                    "n_images": info[k]["n_images"], "objects": [starts[k], starts[k] + len(chunks[k])]}
                   for k in range(len(chunks)) if info[k]["n_images"]],
        "failed": failed,
    })
    atomic_text(final, json_text(data, indent=1))
    partial.unlink(missing_ok=True)
    rate = rendered / seconds if rendered and seconds > 0 else None
    return Manifest(final, data, images_per_s=rate, rendered=rendered, seconds=seconds)
