"""What the rendered images of one object are: :class:`RenderSettings` and :class:`ObjectViews`.

:class:`RenderSettings` holds everything besides the objects that decides a rendered image
(image size, views per object, view sampler, object size and distance, backend, noise, seed).
:class:`ObjectViews` turns an object and the settings into its labelled depth images, the same
for a written set (:func:`hbeo.render.renderset.render_set`), an on-the-fly one
(:class:`hbeo.render.torch_datasets.StreamingDepth`) and evaluation
(:func:`hbeo.evaluation.evaluate.evaluate_model`).

Arrays of one object (n = views per object; shard layout, see :mod:`hbeo.render.renderset`)
    ``depth`` float16 (n, H, W), metres, 0 = no object; ``mask`` bool (n, H, W); ``label``,
    ``object_index``, ``view`` int64 (n,); ``object_id`` str (n,); ``rotation`` float32
    (n, 3, 3) and ``axis_angle`` float32 (n, 3), the pose R (object -> camera,
    :mod:`hbeo.conventions`); ``translation`` float32 (n, 3), metres; with a subspace,
    ``coeffs`` float32 (n, k).

Determinism
    Object ``p`` of a split's record list draws its views (and sensor noise) from
    ``np.random.default_rng([seed, split_code, p])`` (split_code 0 = train, 1 = test;
    :func:`object_rng`), so its images depend on nothing else.

Query views (the paired test protocol)
    Evaluation draws view ``j`` of an object from ``default_rng([seed, split_code, object_key, j])``
    (:func:`query_rng`), where ``object_key`` (:func:`object_key`) is a hash of the object's class
    and id: the same (object, view) is the same image whatever list the object sits in, however
    many views are asked for, and for every method. The key leaves the sampler out: under one
    sampler (one reading of the view protocol, :mod:`hbeo.render.poses`) view j of an object is
    one image for every method; under two samplers it comes from the same stream, drawn into
    different poses and offsets, so readings are paired by object and view index, not by image.

Imports the foundation, :mod:`hbeo.data.gridset` and :mod:`hbeo.render` (poses, renderer, gridcast, noise).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, is_dataclass, replace

import numpy as np

from hbeo import config
from hbeo import conventions as C
from hbeo.errors import DataError
from hbeo.render.noise import MAX_NOISE_SCALE, SensorNoise, whole_noisy_views
from hbeo.render.poses import ViewSampler, check_sampler
from hbeo.rotations import matrix_to_axis_angle

#: render backends: the mesh renderers of :mod:`hbeo.render.renderer` and ``torch``, the grid ray
#: marcher of :mod:`hbeo.render.gridcast` (objects with a grid only)
BACKENDS = ("auto", "pyrender", "embree", "torch")
#: random-stream codes: a rendered split, and "val" for the query views of validation objects (from "train")
SPLIT_CODES = {"train": 0, "test": 1, "val": 2}


# --------------------------------------------------------------------------- settings

@dataclass(frozen=True)
class RenderSettings:
    """Everything that decides the rendered images (besides the objects themselves).

    image_size: (width, height) pixels; the camera is :meth:`Intrinsics.kinect` at that size.
    views_per_object: images per object. sampler: the reading of the view protocol, one of
    :data:`hbeo.render.poses.SAMPLERS` (``"so3"``: uniform rotations, the main one).
    object_size: longest side of every object, metres. distance: range of the object centre's
    depth, metres. shift: largest offset of the object centre from the
    optical axis, as a fraction of its depth. elevation_deg: camera elevation range of the
    upright sampler. backend: ``"auto"``, ``"pyrender"``, ``"embree"`` (meshes) or ``"torch"`` (the
    surface of each object's grid, ray-marched in torch: :mod:`hbeo.render.gridcast`). noise: apply
    :class:`hbeo.render.noise.SensorNoise`. noise_scale: with noise, sensor pixels per image pixel along each
    axis: each view is rendered at ``noise_scale`` times the image's size (the camera scaled with it), the noise
    applied there and the image read at the sensor pixel nearest each image pixel's centre (index
    ``noise_scale * u + noise_scale // 2``), as ``predict`` reads a finer frame; 8 at 80x60 is a 640x480
    sensor. 1 (the default) applies the noise at the image's own size, where its pixel-sized parts are
    coarser relative to the object. seed: the set's seed (a non-negative integer). noise_fraction: with noise,
    the share of each object's views that carry it: views ``0 .. k-1`` (k = ``noise_fraction *
    views_per_object``, a whole number from 1 to ``views_per_object``; the views' poses are independent draws,
    so which views is no choice) are rendered as ``noise`` and ``noise_scale`` say, the rest clean at the
    image's size, the images a clean set with the same seed holds for those views; 1 (the default): every view.
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
    noise_scale: int = 1
    noise_fraction: float = 1.0

    def __post_init__(self):
        def pair(name, conv):
            v = getattr(self, name)
            if not isinstance(v, (list, tuple, np.ndarray)):
                raise ValueError(f"RenderSettings.{name} must be a pair of numbers, got {v!r}")
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
        check_sampler(self.sampler)
        if self.backend not in BACKENDS:
            raise ValueError(f"unknown render backend {self.backend!r}; expected one of {', '.join(BACKENDS)}")
        object.__setattr__(self, "object_size", _as_float(self.object_size, "RenderSettings.object_size"))
        object.__setattr__(self, "shift", _as_float(self.shift, "RenderSettings.shift"))
        if not (math.isfinite(self.object_size) and self.object_size > 0):
            raise ValueError(f"RenderSettings.object_size must be > 0 metres, got {self.object_size}")
        if not (math.isfinite(self.shift) and self.shift >= 0):
            raise ValueError(f"RenderSettings.shift must be >= 0, got {self.shift}")
        lo, hi = pair("distance", lambda x: _as_float(x, "RenderSettings.distance"))
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ValueError(f"RenderSettings.distance must be finite metres with 0 < min <= max, got {(lo, hi)}")
        lo, hi = pair("elevation_deg", lambda x: _as_float(x, "RenderSettings.elevation_deg"))
        if not (-90 <= lo <= hi <= 90):
            raise ValueError(f"RenderSettings.elevation_deg must satisfy -90 <= min <= max <= 90, got {(lo, hi)}")
        if not isinstance(self.noise, (bool, np.bool_)):
            raise ValueError(f"RenderSettings.noise must be True or False, got {self.noise!r}")
        object.__setattr__(self, "noise", bool(self.noise))
        object.__setattr__(self, "noise_scale", _as_int(self.noise_scale, "RenderSettings.noise_scale"))
        if not 1 <= self.noise_scale <= MAX_NOISE_SCALE:
            raise ValueError(f"RenderSettings.noise_scale must be a whole number in 1..{MAX_NOISE_SCALE}, got "
                             f"{self.noise_scale}")
        if self.noise_scale != 1 and not self.noise:
            raise ValueError(f"RenderSettings.noise_scale {self.noise_scale} needs noise: it says where the noise "
                             f"is applied")
        object.__setattr__(self, "noise_fraction", _as_float(self.noise_fraction, "RenderSettings.noise_fraction"))
        if not 0 < self.noise_fraction <= 1:
            raise ValueError(f"RenderSettings.noise_fraction must be in (0, 1], got {self.noise_fraction}")
        if self.noise_fraction != 1:
            if not self.noise:
                raise ValueError(f"RenderSettings.noise_fraction {self.noise_fraction} needs noise: it says which "
                                 f"views carry it")
            if not whole_noisy_views(self.noise_fraction, self.views_per_object):
                raise ValueError(f"RenderSettings.noise_fraction {self.noise_fraction} of {self.views_per_object} "
                                 f"views per object is {self.noise_fraction * self.views_per_object:g} views: it "
                                 f"must be a whole number of at least 1")
        object.__setattr__(self, "seed", _as_int(self.seed, "RenderSettings.seed"))
        if self.seed < 0:
            raise ValueError(f"RenderSettings.seed must be a non-negative integer, got {self.seed}")
        self.view_sampler  # noqa: B018  (ViewSampler checks the distance range against the size)

    @property
    def intrinsics(self) -> C.Intrinsics:
        return C.Intrinsics.kinect(*self.image_size)

    @property
    def sensor_intrinsics(self) -> C.Intrinsics:
        """The camera the views are rendered with: :attr:`intrinsics` at ``noise_scale`` times the size (the same
        field of view and principal ray; ``noise_scale`` is 1 without noise)."""
        return C.Intrinsics.kinect(self.image_size[0] * self.noise_scale, self.image_size[1] * self.noise_scale)

    @property
    def noisy_views(self) -> int:
        """How many of an object's views carry the sensor noise (its first ones): ``noise_fraction *
        views_per_object`` with noise, 0 without."""
        return round(self.noise_fraction * self.views_per_object) if self.noise else 0

    @property
    def view_sampler(self) -> ViewSampler:
        return ViewSampler(sampler=self.sampler, elevation_deg=self.elevation_deg, distance=self.distance,
                           shift=self.shift, object_size=self.object_size)

    @classmethod
    def from_profile(cls, profile, **overrides) -> "RenderSettings":
        """Image size, views per object and renderer from a run profile (name or :class:`~hbeo.config.Profile`);
        keyword arguments override any field (``None`` values are ignored; ``backend="auto"`` means the profile's)."""
        prof = config.get_profile(profile)
        kw = {"image_size": tuple(prof.data.image_size), "views_per_object": prof.data.views_per_object,
              "backend": prof.data.render_backend}
        if overrides.get("backend") == "auto":
            overrides = {**overrides, "backend": None}
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**kw)

    def to_dict(self) -> dict:
        """The fields, JSON-ready; ``noise_scale`` and ``noise_fraction`` only where they are not 1, so sets,
        checkpoints and model files made before they existed keep the settings they had."""
        d = asdict(self)
        for name in ("noise_scale", "noise_fraction"):
            if d[name] == 1:
                del d[name]
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def for_queries(cls, training: dict, views: int, seed: int, sampler: str | None = None, noise: bool = False,
                    noise_scale: int = 1) -> "RenderSettings":
        """The settings of query views for a model trained on images rendered with ``training`` (a
        :meth:`to_dict` dict, the model file's ``settings.render``): its camera, object size and distances, with
        the queries' own ``views`` per object, ``seed``, ``sampler`` (None: the training one) and sensor noise
        (clean unless asked, whatever the training images carried; on every query view when asked)."""
        return cls.from_dict({**training, "views_per_object": views, "seed": seed, "noise": bool(noise),
                              "noise_scale": int(noise_scale), "noise_fraction": 1.0,
                              **({"sampler": sampler} if sampler else {})})

    @classmethod
    def from_dict(cls, d: dict, strict: bool = False) -> "RenderSettings":
        """From :meth:`to_dict`'s dict, the keys left out taking their defaults. A key that is no field is
        ignored (settings recorded by another version), or with ``strict`` refused (ValueError naming it)."""
        names = {f.name for f in fields(cls)}
        if strict and (unknown := sorted(set(d) - names, key=str)):
            raise ValueError(f"unknown keys {', '.join(map(str, unknown))} (known: {', '.join(f.name for f in fields(cls))})")
        return cls(**{k: v for k, v in d.items() if k in names})


def _as_float(v, name="value") -> float:
    """A number (not a string, a bool or None) as a float; ValueError naming ``name`` otherwise."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, float, np.floating)):
        raise ValueError(f"{name} must be a number, got {type(v).__name__} {v!r:.40}")
    return float(v)


def _as_int(v, name="value") -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, float, np.floating)) \
            or not math.isfinite(float(v)) or float(v) != int(v):
        raise ValueError(f"{name} must be an integer, got {v!r}")
    return int(v)


def object_rng(seed: int, split: str, position: int, epoch: int = 0) -> np.random.Generator:
    """The random stream of the object at ``position`` of a split's record list:
    ``default_rng([seed, split_code, position])``, with the epoch appended when it is not 0."""
    key = [int(seed), SPLIT_CODES[split], int(position)]
    return np.random.default_rng(key + [int(epoch)] if epoch else key)


def object_key(record) -> int:
    """A stable integer of an object (class and id; below 2**62, far above any list position), the
    key of its query views (:func:`query_rng`)."""
    import hashlib
    digest = hashlib.sha256(f"{record.cls}/{record.id}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 2


def query_rng(seed: int, split: str, record, view: int) -> np.random.Generator:
    """The random stream of query view ``view`` of ``record`` (pose and sensor noise):
    ``default_rng([seed, split_code, object_key(record), view])``."""
    return np.random.default_rng([int(seed), _split_code(split), object_key(record), int(view)])


def check_grid_records(records) -> None:
    """ValueError unless every record has a grid: the ``torch`` backend renders grids, not meshes."""
    if bad := [r for r in records if not r.has_grid]:
        raise ValueError(f"render backend 'torch' ray-marches occupancy grids, and {len(bad)} object(s) have a "
                         f"mesh only (e.g. {_record_name(bad[0])}); use a grid dataset (modelnet10-vox30) or "
                         f"backend embree / pyrender")


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
    """All views of one object at a time (or of many, ray-marched together on a GPU: :meth:`views_many`,
    :meth:`query_views_many`), with one Renderer per process (opened lazily): the one place that turns an
    object and the settings into labelled depth images (for :func:`render_set`,
    :class:`hbeo.render.torch_datasets.StreamingDepth` and :func:`hbeo.evaluation.evaluate.evaluate_model`)."""

    def __init__(self, settings: RenderSettings, subspace=None):
        from hbeo.render import renderer as render
        self.render = render
        self.settings = settings
        self.subspace = subspace
        self.intrinsics = settings.intrinsics
        self.sensor = settings.sensor_intrinsics            # the camera rendered with (noise_scale)
        self.noise = SensorNoise() if settings.noise else None
        self.renderer = None
        self._caster = None                     # backend "torch": (object key, GridCaster) of the last object
        self._clean = None                      # noise_fraction < 1 with noise_scale > 1: the clean views' renderer
        self._coeffs: dict[tuple, np.ndarray] = {}
        self.prefilled = False                  #: :meth:`prefill_coeffs` has run

    @property
    def backend(self) -> str:
        return self.renderer.backend if self.renderer is not None else self.settings.backend

    def open(self):
        if self.renderer is None and self.settings.backend != "torch":
            self.renderer = self.render.Renderer(self.sensor, backend=self.settings.backend)
        return self

    def close(self):
        try:
            if self.renderer is not None:
                try:
                    self.renderer.close()
                finally:
                    self.renderer = None
        finally:
            if self._clean is not None:
                self._clean.close()

    def coeffs(self, record) -> np.ndarray:
        key = (record.split, record.cls, record.id)
        if key not in self._coeffs:
            from hbeo.data.gridset import record_grid       # raises DataError naming the object
            self._coeffs[key] = np.asarray(self.subspace.project(record_grid(record)[None])[0], np.float32)
        return self._coeffs[key]

    def prefill_coeffs(self, records, block: int = 256) -> None:
        """:meth:`coeffs` of every record not yet cached, projected ``block`` objects at a time (one
        matrix product each, where :meth:`coeffs` reads the whole basis for one object)."""
        from hbeo.data.gridset import record_grid
        todo = [r for r in records if (r.split, r.cls, r.id) not in self._coeffs]
        for i in range(0, len(todo), block):
            part = todo[i:i + block]
            C = np.asarray(self.subspace.project(np.stack([record_grid(r) for r in part])), np.float32)
            for r, c in zip(part, C):
                self._coeffs[(r.split, r.cls, r.id)] = c
        self.prefilled = True

    def views(self, record, position: int, label: int, split: str, epoch: int = 0) -> dict:
        """The arrays of all views of one object (shard layout, mask still unpacked)."""
        return self.views_many([record], [position], [label], split, epoch, batched=False)[0]

    def query_views(self, record, split: str, views: int, label: int = -1) -> dict:
        """Query views 0 .. ``views``-1 of one object for evaluation, each from its own stream
        (:func:`query_rng`: paired across methods and view counts); same arrays as :meth:`views`."""
        return self.query_views_many([record], split, views, [label], batched=False)[0]

    def batched(self) -> bool:
        """Whether :meth:`views_many` and :meth:`query_views_many` ray-march many objects together: the
        ``torch`` backend on a GPU, where a march is mostly the cost of its launches (an H200 evaluated 398
        objects one at a time in 59 s, ``docs/history/gpu-cpu-stream/lease-2026-11-27b``). On the CPU a
        larger march is no faster, and they render object by object: the same arrays either way."""
        import torch
        return self.settings.backend == "torch" and torch.cuda.is_available()

    def views_many(self, records, positions, labels, split: str, epoch: int = 0, batched: bool | None = None):
        """:meth:`views` of each of ``records`` (with its position and label): the same arrays, ray-marched
        together where :meth:`batched` (or ``batched``) says so."""
        s = self.settings
        rngs = [object_rng(s.seed, split, p, epoch) for p in positions]
        poses = [s.view_sampler.sample(s.views_per_object, g) for g in rngs]
        return self._render_many(records, positions, labels, poses, [[g] * s.views_per_object for g in rngs],
                                 self.batched() if batched is None else batched)

    def query_views_many(self, records, split: str, views: int, labels=None, batched: bool | None = None):
        """:meth:`query_views` of each of ``records`` (labels -1 unless given): the same arrays, ray-marched
        together where :meth:`batched` (or ``batched``) says so."""
        labels = [-1] * len(records) if labels is None else list(labels)
        rngs = [[query_rng(self.settings.seed, split, r, j) for j in range(views)] for r in records]
        poses = [self.settings.view_sampler.sample_each(g) for g in rngs]
        return self._render_many(records, [object_key(r) for r in records], labels, poses, rngs,
                                 self.batched() if batched is None else batched)

    #: rays marched together by :meth:`_render_many` (~128 bytes a ray: ~1 GiB; 1,747 views at 80x60, 109 at 320x240)
    MANY_RAYS = 2**23

    def _render_many(self, records, positions, labels, poses, rngs, batched: bool) -> list[dict]:
        """Each object's views at its ``poses`` ((R, t) each) with its ``rngs``, as :meth:`_render` gives them.
        ``batched`` (the ``torch`` backend): one :class:`hbeo.render.gridcast.GridCaster` of their grids, every
        view marched together, at most :data:`MANY_RAYS` rays a march, then :meth:`finish` per object; if that
        fails, without ``batched``, and where only some views carry the noise (``noise_fraction``), object by object
        (:meth:`_render`, which names an object at fault)."""
        if batched and self.settings.noise_fraction == 1:
            import torch
            from hbeo.render.gridcast import GridCaster
            try:
                check_grid_records(records)
                caster = GridCaster([r.grid() for r in records], self.sensor, self.settings.object_size,
                                    device="cuda" if torch.cuda.is_available() else "cpu")
                idx = np.concatenate([np.full(len(R), k, np.int64) for k, (R, _) in enumerate(poses)])
                R, t = np.concatenate([R for R, _ in poses]), np.concatenate([t for _, t in poses])
                M = max(1, self.MANY_RAYS // (self.sensor.width * self.sensor.height))
                depth = np.concatenate([caster.render(idx[i:i + M], R[i:i + M], t[i:i + M]).cpu().numpy()
                                        for i in range(0, len(idx), M)])
            except Exception:
                pass
            else:
                out, at = [], 0
                for r, p, lab, (R, t), g in zip(records, positions, labels, poses, rngs):
                    out.append(self.finish(r, p, lab, R, t, g, depth[at:at + len(R)]))
                    at += len(R)
                return out
        return [self._render(r, p, lab, R, t, g) for r, p, lab, (R, t), g in
                zip(records, positions, labels, poses, rngs)]

    def _render(self, record, position: int, label: int, R: np.ndarray, t: np.ndarray, rngs: list) -> dict:
        s = self.settings
        k = self._noisy(len(R))
        try:
            if k < len(R) and s.noise_scale != 1:      # the clean views at the image's size, as a clean set's
                depth, clean = self._depth(record, R[:k], t[:k]), self._clean_views()._depth(record, R[k:], t[k:])
            else:
                depth, clean = self._depth(record, R, t), None
        except DataError:
            raise
        except Exception as err:
            raise DataError(record.path or _record_name(record),
                            f"rendering object {_record_name(record)} failed ({type(err).__name__}: {err})") from err
        return self.finish(record, position, label, R, t, rngs, depth, clean)

    def _noisy(self, n: int) -> int:
        """How many of ``n`` views of one object (its first) carry the noise where the settings ask for it: all
        unless ``noise_fraction`` leaves some clean."""
        return self.settings.noisy_views if self.settings.noise_fraction != 1 else n

    def _depth(self, record, R, t) -> np.ndarray:
        return self._grid_depth(record, R, t) if self.settings.backend == "torch" else self._mesh_depth(record, R, t)

    def _clean_views(self) -> "ObjectViews":
        """The views of these settings without noise (at the image's size), for the views ``noise_fraction`` leaves
        clean."""
        if self._clean is None:
            self._clean = ObjectViews(replace(self.settings, noise=False, noise_scale=1, noise_fraction=1.0))
        return self._clean

    def _mesh_depth(self, record, R, t) -> np.ndarray:
        try:
            mesh = self.render.record_mesh(record, object_size=self.settings.object_size)
        except Exception as err:
            raise DataError(record.path or _record_name(record),
                            f"cannot render object {_record_name(record)}: no usable mesh "
                            f"({type(err).__name__}: {err})") from err
        self.open()
        return np.asarray(self.renderer.render_many(mesh, R, t), np.float32)

    def _grid_depth(self, record, R, t) -> np.ndarray:
        """The ``torch`` backend, one object at a time (:class:`hbeo.render.gridcast.GridCaster`) on the
        GPU where there is one (a lent GPU machine's evaluation: its CPU would take ~0.1 s a 320×240 view),
        else on the CPU. The caster is deterministic on one device; CPU and GPU images may differ in the
        last bits of a few pixels."""
        import torch
        from hbeo.render.gridcast import GridCaster
        check_grid_records([record])
        key = (record.split, record.cls, record.id)
        if self._caster is None or self._caster[0] != key:
            device = "cuda" if torch.cuda.is_available() else "cpu"
            self._caster = (key, GridCaster([record.grid()], self.sensor, self.settings.object_size,
                                            device=device))
        return self._caster[1].render(np.zeros(len(R), np.int64), R, t).cpu().numpy()

    def finish(self, record, position: int, label: int, R: np.ndarray, t: np.ndarray, rngs: list,
               depth: np.ndarray, clean: np.ndarray | None = None) -> dict:
        """The arrays of rendered views ``depth`` (n, H', W', at the sensor's size) of one object at poses R, t:
        sensor noise (if the settings ask for it) from ``rngs`` (one per view, or one stream for all) on its first
        :attr:`RenderSettings.noisy_views` views (all where ``noise_fraction`` is 1), float16 depth. ``clean``:
        the last views, clean and rendered at the image's size, where ``depth`` holds the first ones only."""
        s = self.settings
        depth = np.asarray(depth, np.float32)
        n, (w, h) = len(R), (self.sensor.width, self.sensor.height)
        m = n if clean is None else n - len(clean)   # the views in depth
        if depth.shape != (m, h, w):
            raise RuntimeError(f"renderer returned depth of shape {depth.shape}, expected {(m, h, w)}")
        if self.noise is not None:
            k = self._noisy(n)
            if all(g is rngs[0] for g in rngs[:k]):   # one stream for all views (a rendered set)
                noisy = np.asarray(self.noise.apply(depth[:k], self.sensor, rngs[0]), np.float32)
            else:                                     # each query view's own stream
                noisy = np.concatenate([np.asarray(self.noise.apply(depth[j:j + 1], self.sensor, g), np.float32)
                                        for j, g in enumerate(rngs[:k])])
            depth = np.concatenate([noisy, depth[k:]]) if k < m else noisy
        if (k := s.noise_scale) > 1:                  # the sensor pixel nearest each pixel's centre
            depth = np.ascontiguousarray(depth[:, k // 2::k, k // 2::k])
        if clean is not None:
            depth = np.concatenate([depth, np.asarray(clean, np.float32)])
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
            "axis_angle": matrix_to_axis_angle(R).astype(np.float32),
            "translation": t.astype(np.float32),
        }
        if self.subspace is not None:
            out["coeffs"] = np.repeat(self.coeffs(record)[None], n, axis=0)
        return out
