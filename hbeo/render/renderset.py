"""The training-set factory: segmented synthetic depth images labelled with class, pose and shape.

:func:`render_set` renders ``views_per_object`` depth images of every object of a split from
random viewpoints (:class:`hbeo.render.poses.ViewSampler`) and writes them, a few objects at a time,
into compressed shards ``shard_NNNNN.npz``; ``manifest.json``, written last, describes the set.
:class:`DepthShards` reads such a set for training; :class:`StreamingDepth` renders the same
images on the fly, for sets too big for disk.

Shard arrays (N = images in the shard; all views of an object are consecutive)
    ``depth`` float16 (N, H, W), metres, 0 = no object; ``mask`` uint8 (N, ceil(H*W/8)), the
    bit-packed ``depth > 0`` (see :func:`load_shard`); ``label`` int64 (N,) into the dataset's
    classes; ``object_index`` int64 (N,), the object's position in the record list;
    ``object_id`` str (N,); ``view`` int64 (N,), the view's number within its object;
    ``rotation`` float32 (N, 3, 3) and ``axis_angle`` float32 (N, 3), the pose R (object ->
    camera, :mod:`hbeo.conventions`); ``translation`` float32 (N, 3), metres; ``intrinsics``
    float64 (6,) = (fx, fy, cx, cy, width, height); with a subspace, ``coeffs`` float32 (N, k):
    the coefficients of the object's complete 30^3 grid (the same for all its views).

Determinism
    Object ``p`` of the record list draws its views (and sensor noise) from
    ``np.random.default_rng([seed, split_code, p])`` (split_code 0 = train, 1 = test), so a
    shard depends only on its own objects: the same bytes for any number of workers. Shards
    are zip files with fixed timestamps, so reruns reproduce their sha256 too.

Resuming
    A shard is written under a temporary name and renamed into place, then a
    ``shard_NNNNN.npz.sha256`` sidecar (``sha256sum`` format) records its hash; a rerun keeps
    the shards whose hash matches their sidecar and renders the rest. ``manifest.partial.json``
    (written first) and ``manifest.json`` (written last) hold the settings: a folder rendered
    with other settings is refused instead of mixed.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
import zipfile
from collections import OrderedDict
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset as TorchDataset, IterableDataset, Sampler, get_worker_info
from tqdm.auto import tqdm

from hbeo import __version__
from hbeo import config
from hbeo import conventions as C
from hbeo.storage import atomic_file, atomic_text, sha256_file
from hbeo.errors import DataError
from hbeo.render.poses import SAMPLERS, ViewSampler

FORMAT_VERSION = 1
BACKENDS = ("auto", "pyrender", "embree")
SPLIT_CODES = {"train": 0, "test": 1}
MANIFEST = "manifest.json"
PARTIAL = "manifest.partial.json"
#: Default shard size in images (a 320x240 float16 shard of 1024 images is ~160 MB in memory).
IMAGES_PER_SHARD = 1024
SHARD_KEYS = ("depth", "mask", "label", "object_index", "object_id", "view", "rotation",
              "axis_angle", "translation", "intrinsics")


# --------------------------------------------------------------------------- settings

@dataclass(frozen=True)
class RenderSettings:
    """Everything that decides the rendered images (besides the objects themselves).

    image_size: (width, height) pixels; the camera is :meth:`Intrinsics.kinect` at that size.
    views_per_object: images per object. sampler: ``"so3"`` (uniform rotations) or
    ``"upright"``. object_size: longest side of every object, metres. distance: range of the
    object centre's depth, metres. shift: largest offset of the object centre from the
    optical axis, as a fraction of its depth. elevation_deg: camera elevation range of the
    upright sampler. backend: ``"auto"``, ``"pyrender"`` or ``"embree"``. noise: apply
    :class:`hbeo.render.renderer.SensorNoise`. seed: the set's seed (a non-negative integer).
    """

    image_size: tuple[int, int] = (80, 60)
    views_per_object: int = 2
    sampler: str = "so3"
    object_size: float = 1.0
    distance: tuple[float, float] = (1.4, 2.0)
    shift: float = 0.05
    elevation_deg: tuple[float, float] = (10.0, 50.0)
    backend: str = "auto"
    noise: bool = False
    seed: int = 0

    def __post_init__(self):
        def pair(name, conv):
            v = getattr(self, name)
            try:
                v = tuple(conv(x) for x in v)
            except (TypeError, ValueError):
                raise ValueError(f"RenderSettings.{name} must be a pair of numbers, got {v!r}") from None
            if len(v) != 2:
                raise ValueError(f"RenderSettings.{name} must be a pair, got {v!r}")
            object.__setattr__(self, name, v)
            return v

        w, h = pair("image_size", lambda x: _as_int(x, "RenderSettings.image_size"))
        if w < 1 or h < 1:
            raise ValueError(f"RenderSettings.image_size must be positive, got {w}x{h}")
        object.__setattr__(self, "views_per_object", _as_int(self.views_per_object, "RenderSettings.views_per_object"))
        if self.views_per_object < 1:
            raise ValueError(f"RenderSettings.views_per_object must be >= 1, got {self.views_per_object}")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"unknown sampler {self.sampler!r}; expected one of {', '.join(SAMPLERS)}")
        if self.backend not in BACKENDS:
            raise ValueError(f"unknown render backend {self.backend!r}; expected one of {', '.join(BACKENDS)}")
        object.__setattr__(self, "object_size", float(self.object_size))
        object.__setattr__(self, "shift", float(self.shift))
        if not (math.isfinite(self.object_size) and self.object_size > 0):
            raise ValueError(f"RenderSettings.object_size must be > 0 metres, got {self.object_size}")
        if not (math.isfinite(self.shift) and self.shift >= 0):
            raise ValueError(f"RenderSettings.shift must be >= 0, got {self.shift}")
        pair("distance", float)
        lo, hi = pair("elevation_deg", float)
        if not (-90 <= lo <= hi <= 90):
            raise ValueError(f"RenderSettings.elevation_deg must satisfy -90 <= min <= max <= 90, got {(lo, hi)}")
        if not isinstance(self.noise, (bool, np.bool_)):
            raise ValueError(f"RenderSettings.noise must be True or False, got {self.noise!r}")
        object.__setattr__(self, "noise", bool(self.noise))
        object.__setattr__(self, "seed", _as_int(self.seed, "RenderSettings.seed"))
        if self.seed < 0:
            raise ValueError(f"RenderSettings.seed must be a non-negative integer, got {self.seed}")
        self.view_sampler  # noqa: B018  (ViewSampler checks the distance range against the size)

    @property
    def intrinsics(self) -> C.Intrinsics:
        return C.Intrinsics.kinect(*self.image_size)

    @property
    def view_sampler(self) -> ViewSampler:
        return ViewSampler(sampler=self.sampler, elevation_deg=self.elevation_deg, distance=self.distance,
                           shift=self.shift, object_size=self.object_size)

    @classmethod
    def from_profile(cls, profile, **overrides) -> "RenderSettings":
        """Image size and views per object from a run profile (name or :class:`~hbeo.config.Profile`);
        keyword arguments override any field (``None`` values are ignored)."""
        prof = config.get_profile(profile)
        kw = {"image_size": tuple(prof.image_size), "views_per_object": prof.views_per_object}
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**kw)

    def to_dict(self) -> dict:
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "RenderSettings":
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


def _as_int(v, name="value") -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, float, np.floating)) \
            or float(v) != int(v):
        raise ValueError(f"{name} must be an integer, got {v!r}")
    return int(v)


def object_rng(seed: int, split: str, position: int, epoch: int = 0) -> np.random.Generator:
    """The random stream of the object at ``position`` of a split's record list:
    ``default_rng([seed, split_code, position])``, with the epoch appended when it is not 0."""
    key = [int(seed), SPLIT_CODES[split], int(position)]
    return np.random.default_rng(key + [int(epoch)] if epoch else key)


def _split_code(split: str) -> int:
    try:
        return SPLIT_CODES[split]
    except KeyError:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLIT_CODES)}") from None


# --------------------------------------------------------------------------- rendering one object

def _record_name(record) -> str:
    return f"{record.split}/{record.cls}/{record.id}"


def _noise_description(noise) -> dict | None:
    if noise is None:
        return None
    params = asdict(noise) if is_dataclass(noise) else {"repr": repr(noise)}
    return {"model": type(noise).__name__, **params}


class ObjectViews:
    """All views of one object at a time, with one Renderer per process (opened lazily): the one
    place that turns an object and the settings into labelled depth images (for :func:`render_set`,
    :class:`StreamingDepth` and :func:`hbeo.reproduction.evaluate.evaluate_model`)."""

    def __init__(self, settings: RenderSettings, subspace=None):
        from hbeo.render import renderer as render
        self.render = render
        self.settings = settings
        self.subspace = subspace
        self.intrinsics = settings.intrinsics
        self.noise = render.SensorNoise() if settings.noise else None
        self.renderer = None
        self._coeffs: dict[tuple, np.ndarray] = {}

    @property
    def backend(self) -> str:
        return self.renderer.backend if self.renderer is not None else self.settings.backend

    def open(self):
        if self.renderer is None:
            self.renderer = self.render.Renderer(self.intrinsics, backend=self.settings.backend)
        return self

    def close(self):
        if self.renderer is not None:
            try:
                self.renderer.close()
            finally:
                self.renderer = None

    def coeffs(self, record) -> np.ndarray:
        key = (record.split, record.cls, record.id)
        if key not in self._coeffs:
            from hbeo.data.gridset import record_grid       # raises DataError naming the object
            self._coeffs[key] = np.asarray(self.subspace.project(record_grid(record)[None])[0], np.float32)
        return self._coeffs[key]

    def views(self, record, position: int, label: int, split: str, epoch: int = 0) -> dict:
        """The arrays of all views of one object (shard layout, mask still unpacked)."""
        s = self.settings
        rng = object_rng(s.seed, split, position, epoch)
        R, t = s.view_sampler.sample(s.views_per_object, rng)
        try:
            mesh = self.render.record_mesh(record, object_size=s.object_size)
        except Exception as err:
            raise DataError(record.path or _record_name(record),
                            f"cannot render object {_record_name(record)}: no usable mesh "
                            f"({type(err).__name__}: {err})") from err
        self.open()
        try:
            depth = np.asarray(self.renderer.render_many(mesh, R, t), np.float32)
        except Exception as err:
            raise DataError(record.path or _record_name(record),
                            f"rendering object {_record_name(record)} failed ({type(err).__name__}: {err})") from err
        n, (w, h) = s.views_per_object, s.image_size
        if depth.shape != (n, h, w):
            raise RuntimeError(f"renderer returned depth of shape {depth.shape}, expected {(n, h, w)}")
        if self.noise is not None:
            depth = np.asarray(self.noise.apply(depth, self.intrinsics, rng), np.float32)
        depth = np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float16)
        depth[~(depth > 0)] = 0                      # 0 = no object, never negative
        out = {
            "depth": depth,
            "mask": depth > 0,
            "label": np.full(n, label, np.int64),
            "object_index": np.full(n, position, np.int64),
            "object_id": np.full(n, str(record.id)),
            "view": np.arange(n, dtype=np.int64),
            "rotation": R.astype(np.float32),
            "axis_angle": C.rotation_to_axis_angle(R).astype(np.float32),
            "translation": t.astype(np.float32),
        }
        if self.subspace is not None:
            out["coeffs"] = np.repeat(self.coeffs(record)[None], n, axis=0)
        return out


# --------------------------------------------------------------------------- shard files

def _write_npz(path: Path, arrays: dict) -> tuple[str, int]:
    """Compressed .npz with fixed zip timestamps (same arrays -> same bytes), written atomically.
    Returns (sha256, size)."""
    with atomic_file(path) as f:
        with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for name, arr in arrays.items():
                info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                with zf.open(info, "w", force_zip64=True) as fid:
                    np.lib.format.write_array(fid, np.asanyarray(arr), allow_pickle=False)
    return sha256_file(path), path.stat().st_size


def _sidecar(path: Path) -> Path:
    return path.with_name(path.name + ".sha256")


def _shard_name(k: int) -> str:
    return f"shard_{k:05d}.npz"


def _finished_shard(path: Path) -> tuple[str, int] | None:
    """(sha256, size) of a shard whose file matches its sidecar, else None."""
    side = _sidecar(path)
    if not (path.is_file() and side.is_file()):
        return None
    try:
        recorded = side.read_text().split()[0]
    except (OSError, IndexError):
        return None
    digest = sha256_file(path)
    return (digest, path.stat().st_size) if digest == recorded else None


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
    data["mask"] = np.unpackbits(data["mask"], axis=1, count=h * w).astype(bool).reshape(n, h, w)
    return data


# --------------------------------------------------------------------------- workers

_WORKER: ObjectViews | None = None


def _die_with_parent() -> None:
    """Linux: have the kernel kill this worker when its parent dies (a killed job leaves no
    orphans that go on writing shards)."""
    import ctypes
    import signal
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _init_worker(settings, subspace):
    global _WORKER
    _die_with_parent()
    torch.set_num_threads(1)
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)           # idle OpenBLAS threads halve the speed of parallel workers
    _WORKER = ObjectViews(settings, subspace)


def _render_shard(ctx: ObjectViews, path: Path, items, split: str) -> dict:
    """Render the objects ``items`` [(position, record, label)] into shard ``path``."""
    parts = [ctx.views(rec, pos, label, split) for pos, rec, label in items]
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    n = len(arrays["depth"])
    arrays["mask"] = np.packbits(arrays["mask"].reshape(n, -1), axis=1)
    arrays["intrinsics"] = np.array(ctx.intrinsics.as_tuple(), np.float64)
    digest, size = _write_npz(path, arrays)
    atomic_text(_sidecar(path), f"{digest}  {path.name}\n")
    return {"sha256": digest, "bytes": size, "n_images": n, "backend": ctx.backend}


def _clean_context():
    """Worker processes that start clean (spawned children): forking a process whose renderer or
    torch threads are running can deadlock the child, and a spawned worker is a direct child, so
    it dies with this process (see :func:`_die_with_parent`)."""
    import multiprocessing
    return multiprocessing.get_context("spawn")


def _shard_job(args):
    """Worker side: render one shard with this process's renderer."""
    path, items, split = args
    return _render_shard(_WORKER, path, items, split)


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

    def image_objects(self) -> np.ndarray:
        """Object position (index into :attr:`object_ids`) of every image, in set order."""
        return np.repeat(np.arange(len(self.data["object_ids"])), int(self.data["views_per_object"]))

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
               workers: int = 1, objects_per_shard: int | None = None, progress: bool = True) -> Manifest:
    """Render ``settings.views_per_object`` views of every record into ``out_dir`` (see the module
    docstring for the layout); resumes an interrupted run and returns the :class:`Manifest`
    (with ``images_per_s`` of this call). Same bytes for any ``workers``. ``objects_per_shard``
    defaults to about :data:`IMAGES_PER_SHARD` images per shard (at least one object)."""
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
    noise = None
    if settings.noise:
        from hbeo.render import renderer as render
        noise = _noise_description(render.SensorNoise())
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ident = _identity(dataset, records, split, settings, subspace, objects_per_shard, noise)
    final, partial = out / MANIFEST, out / PARTIAL
    if final.exists():
        m = Manifest.load(final)
        _check_same(final, m.data, ident)
        missing = [p for p in m.shard_paths() if not p.is_file()]
        if not missing:
            return m
        atomic_text(partial, json.dumps(ident, indent=1))   # a shard was deleted: render it again
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
        atomic_text(partial, json.dumps(ident, indent=1))
    for tmp in out.glob(".shard_*.tmp"):         # left behind by a killed run
        tmp.unlink(missing_ok=True)

    n_views = settings.views_per_object
    starts = list(range(0, len(records), objects_per_shard))
    chunks = [[(p, records[p], labels[p]) for p in range(s, min(s + objects_per_shard, len(records)))]
              for s in starts]
    paths = [out / _shard_name(k) for k in range(len(chunks))]
    info: dict[int, dict] = {}
    for k, p in enumerate(paths):
        done = _finished_shard(p)
        if done is not None:
            info[k] = {"sha256": done[0], "bytes": done[1], "n_images": len(chunks[k]) * n_views}
    todo = [k for k in range(len(chunks)) if k not in info]
    total = len(records) * n_views
    bar = tqdm(total=total, initial=total - sum(len(chunks[k]) for k in todo) * n_views, unit="img",
               desc=f"render {dataset.name}/{split}", disable=not progress, smoothing=0.1)
    backends = set()
    t0 = time.perf_counter()
    try:
        if todo:
            # always in child processes, even for one worker: embree's thread pool would otherwise
            # stay in this process and slow any torch work after it (100x seen on 2 cores)
            with ProcessPoolExecutor(max_workers=min(workers, len(todo)), initializer=_init_worker,
                                     initargs=(settings, subspace), mp_context=_clean_context()) as pool:
                futures = {pool.submit(_shard_job, (paths[k], chunks[k], split)): k for k in todo}
                pending = set(futures)
                try:
                    while pending:
                        finished, pending = wait(pending, return_when=FIRST_EXCEPTION)
                        for f in finished:
                            res = f.result()
                            info[futures[f]] = res
                            backends.add(res.pop("backend"))
                            bar.update(res["n_images"])
                except BaseException:
                    for f in pending:
                        f.cancel()
                    raise
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    rendered = sum(len(chunks[k]) for k in todo) * n_views

    counts = {c: 0 for c in dataset.classes}
    obj_counts = {c: 0 for c in dataset.classes}
    for r in records:
        counts[r.cls] += n_views
        obj_counts[r.cls] += 1
    w, h = settings.image_size
    data = dict(ident)
    data.update({
        "hbeo_version": __version__,
        "classes": list(dataset.classes),
        "n_images": total,
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
                   for k in range(len(chunks))],
    })
    atomic_text(final, json.dumps(data, indent=1))
    partial.unlink(missing_ok=True)
    rate = rendered / seconds if rendered and seconds > 0 else None
    return Manifest(final, data, images_per_s=rate, rendered=rendered, seconds=seconds)


# --------------------------------------------------------------------------- reading

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


def split_by_object(manifest, val_fraction: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Image indices (train, validation) of a rendered set, split by object: all views of an
    object fall on the same side. Stratified: each class gives ``round(val_fraction * n)`` of
    its n objects (at least one when it has two or more and val_fraction > 0)."""
    m = manifest.manifest if isinstance(manifest, DepthShards) else Manifest.load(manifest)
    if not 0 <= val_fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    labels = m.object_labels
    rng = np.random.default_rng([int(seed), 0x5EED])
    val = np.zeros(len(labels), bool)
    for c in np.unique(labels):
        objs = np.flatnonzero(labels == c)
        k = int(round(val_fraction * len(objs)))
        if val_fraction > 0 and len(objs) >= 2:
            k = min(max(k, 1), len(objs) - 1)
        val[rng.permutation(objs)[:k]] = True
    img_obj = m.image_objects()
    idx = np.arange(len(img_obj), dtype=np.int64)
    return idx[~val[img_obj]], idx[val[img_obj]]


class ShardSampler(Sampler):
    """Shuffles a :class:`DepthShards` (or a subset of its image ``indices``) shard-wise: shards in
    random order, images in random order within each, so each shard is loaded once per epoch.
    Yields positions into ``indices`` (use with ``torch.utils.data.Subset(data, indices)``), or
    image indices when ``indices`` is None. ``set_epoch(e)`` changes the order."""

    def __init__(self, data: DepthShards, indices=None, shuffle: bool = True, seed: int = 0):
        self.indices = np.arange(len(data)) if indices is None else np.asarray(indices, np.int64)
        shard = data.shard_of(self.indices)
        self._groups = [np.flatnonzero(shard == k) for k in np.unique(shard)]
        self.shuffle, self.seed, self.epoch = shuffle, int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self):
        if not self.shuffle:
            yield from (int(i) for g in self._groups for i in g)
            return
        rng = np.random.default_rng([self.seed, self.epoch])
        for g in rng.permutation(len(self._groups)):
            yield from (int(i) for i in rng.permutation(self._groups[g]))


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

    def object_order(self) -> np.ndarray:
        """Object positions in this epoch's order (before dealing them to workers)."""
        n = len(self.records)
        if not self.shuffle:
            return np.arange(n)
        seq = np.random.SeedSequence([self.settings.seed, SPLIT_CODES[self.split], self.epoch], spawn_key=(1,))
        return np.random.default_rng(seq).permutation(n)

    def __iter__(self):
        info = get_worker_info()
        wid, nw = (0, 1) if info is None else (info.id, info.num_workers)
        mine = self.object_order()[wid::nw]
        ctx = ObjectViews(self.settings, self.subspace)
        try:
            for p in mine:
                arrays = ctx.views(self.records[p], int(p), self.labels[p], self.split, self.epoch)
                for v in range(self.settings.views_per_object):
                    yield _item(arrays, v)
        finally:
            ctx.close()
