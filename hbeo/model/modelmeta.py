"""A model file's ``meta.json``: its reading (:func:`parse_meta`), its one check (:func:`check_meta`) and the
HBEO settings it holds (:class:`ModelSettings`).

:mod:`hbeo.model.modelfile` reads and writes the file; every check of ``meta.json``'s content is here, run
once when a file is read (and before one is written), so that nothing later meets a value it cannot use.
Each problem is a :class:`~hbeo.errors.DataError` naming the file and the field (``ValueError`` when
writing, no file): JSON that is not one object of unique keys, a number out of range (``1e400``
reads as infinity), a missing or mistyped key, another format version or kind, class names that are
empty, repeated or not one per network class, a camera that is not finite focal lengths and principal
point with a whole positive image size, and, kind ``hbeo``, settings :class:`ModelSettings` refuses or whose
coefficient statistics or class counts do not fit the network's coefficients and classes.

Imports the foundation (:mod:`hbeo.config`, :mod:`hbeo.errors`) and :mod:`hbeo.render.views`
(:class:`~hbeo.render.views.RenderSettings` checks the recorded render settings).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from typing import Mapping

import numpy as np

from hbeo import __version__
from hbeo.config import PROFILES
from hbeo.errors import DataError
from hbeo.render.poses import SAMPLERS
from hbeo.render.views import RenderSettings

FORMAT = "hbeo-model"
FORMAT_VERSION = 2
KINDS = {"hbeo": "an HBEO model", "voxcnn": "a VoxCNN baseline (3-D CNN) model"}
META = "meta.json"
#: The training's class balance a model file may record (:data:`hbeo.model.trainingdata.CLASS_BALANCE` says
#: what each does).
CLASS_BALANCE = ("none", "sampler", "loss")
#: What the shape term of the loss measures (``python -m hbeo train --shape-loss``, :mod:`hbeo.model.fit`):
#: ``coeffs`` (the paper's L2 norm of the coefficient error, here on standardized coefficients, this project's
#: choice: every coefficient weighted alike) or ``voxels`` (the L2 norm of the completed grid's occupancy error:
#: the basis is orthonormal, so ``||W c_hat - W c|| = ||c_hat - c||`` on raw coefficients; the leading
#: components, which carry most voxels, weigh most), divided by the root-mean-square coefficient standard
#: deviation so that both terms have the same size, sqrt(k), for a network that answers the mean coefficients.
SHAPE_LOSSES = ("coeffs", "voxels")
#: meta.json keys and their JSON types, per kind (``converted_from`` is optional)
_META_KEYS = {"format": str, "format_version": int, "kind": str, "hbeo_version": str, "net_cfg": dict,
              "classes": list, "settings": dict}
INTRINSICS = ("fx", "fy", "cx", "cy", "width", "height")


def _number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _vector(value, name: str):
    """(k,) finite numbers (list, tuple or array) -> tuple of floats; None passes through."""
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or not value or not all(_number(v) for v in value):
        raise ValueError(f"settings: {name} must be a non-empty list of numbers or null, got {_type(value)}")
    if not all(math.isfinite(v) for v in value):
        raise ValueError(f"settings: {name} holds NaN or infinite values")
    return tuple(float(v) for v in value)


def _type(value) -> str:
    return type(value).__name__ if not isinstance(value, (list, tuple)) else f"{type(value).__name__} of {len(value)}"


@dataclass(frozen=True)
class ModelSettings:
    """An HBEO model file's preprocessing and inference settings (``meta.json`` ``settings``): one
    typed field each, with the one default a file that lacks the key has always meant (every file
    :func:`hbeo.model.fit.fit_model` wrote holds every key it knew; these defaults are what the
    reader, ``HBEO(...)``, filled in since format 1).

    ``object_size``
        metres: the training objects' longest side (1.0).
    ``recenter``
        turn the view to look straight at the object before the network sees it (True: the
        reader's default since the first model file; a training run's ``--recenter`` option
        defaults to off, and fit records what it used).
    ``ref_distance``
        metres, or None: the distance normalization's reference distance (None: none).
    ``coeff_mean`` / ``coeff_std``
        (k,) or None: the network's coefficient output is ``coeffs * std + mean`` (both or neither;
        None: the output is the coefficients).
    ``render``
        the training images' :class:`hbeo.render.views.RenderSettings` as a dict ({}: unknown);
        evaluation renders its queries with it and inference warns outside its distances. Keys left
        out take RenderSettings' defaults; the whole must be settings RenderSettings accepts (its
        ``sampler`` one of :data:`hbeo.render.poses.SAMPLERS`, finite distances with 0 < min <= max,
        ...), and an unknown key is refused.
    ``profile``
        the profile the model was trained with (a name of :data:`hbeo.config.PROFILES`), or None (not
        recorded: the whole split).
    ``augment_roll``
        trained with random camera rolls (False: before the option existed, no rolls).
    ``shape_loss``
        the shape term trained (:data:`SHAPE_LOSSES`; ``"coeffs"``: before the option existed, the
        coefficient loss).
    ``class_counts``
        (C,) training images per class, in the order of the model's classes (the images one training
        epoch draws from, before any class balancing), or None (not recorded: files written before
        the field existed). The training class prior of the prior correction
        (:meth:`hbeo.model.inference.HBEO.set_prior_tau`).
    ``class_balance``
        how training countered the class imbalance (:data:`CLASS_BALANCE`; ``"none"``: the counts above
        are the class prior the network learnt, and files written before the field existed). A balanced
        model saw its classes about equally often, so ``class_counts`` is not its prior.

    Frozen: a model's settings are what its file says. :meth:`from_dict` / :meth:`to_dict` are the
    file's reader and writer."""

    object_size: float = 1.0
    recenter: bool = True
    ref_distance: float | None = None
    coeff_mean: tuple | None = None
    coeff_std: tuple | None = None
    render: dict = field(default_factory=dict)
    profile: str | None = None
    augment_roll: bool = False
    shape_loss: str = "coeffs"
    class_counts: tuple | None = None
    class_balance: str = "none"

    def __post_init__(self):
        def bad(name, want, value):
            raise ValueError(f"settings: {name} must be {want}, got {_type(value)} {value!r:.40}")
        set_ = object.__setattr__
        if not _number(self.object_size) or not math.isfinite(self.object_size) or not self.object_size > 0:
            bad("object_size", "a positive number (finite, metres)", self.object_size)
        set_(self, "object_size", float(self.object_size))
        if self.ref_distance is not None:
            if not _number(self.ref_distance) or not math.isfinite(self.ref_distance) or not self.ref_distance > 0:
                bad("ref_distance", "a positive number (finite, metres) or null", self.ref_distance)
            set_(self, "ref_distance", float(self.ref_distance))
        for name in ("recenter", "augment_roll"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                bad(name, "true or false", getattr(self, name))
            set_(self, name, bool(getattr(self, name)))
        set_(self, "coeff_mean", _vector(self.coeff_mean, "coeff_mean"))
        set_(self, "coeff_std", _vector(self.coeff_std, "coeff_std"))
        if (self.coeff_mean is None) != (self.coeff_std is None) or (
                self.coeff_mean is not None and len(self.coeff_mean) != len(self.coeff_std)):
            raise ValueError("settings: coeff_mean and coeff_std must be given together, of one length")
        if not isinstance(self.render, dict) or not all(isinstance(k, str) for k in self.render):
            bad("render", "an object (the render settings)", self.render)
        if "sampler" in self.render and self.render["sampler"] not in SAMPLERS:
            bad("render.sampler", f"one of {', '.join(SAMPLERS)} (hbeo.render.poses)", self.render["sampler"])
        if self.render:             # {}: not recorded; else what RenderSettings accepts, no unknown key
            try:
                RenderSettings.from_dict(self.render, strict=True)
            except (TypeError, ValueError) as err:
                raise ValueError(f"settings: render: {str(err).replace('RenderSettings.', '')}") from None
        if self.profile is not None and (not isinstance(self.profile, str) or self.profile not in PROFILES):
            bad("profile", f"a profile name (one of {', '.join(PROFILES)}: hbeo.config.PROFILES) or null", self.profile)
        if self.shape_loss not in SHAPE_LOSSES:
            bad("shape_loss", f"one of {', '.join(SHAPE_LOSSES)}", self.shape_loss)
        if self.class_balance not in CLASS_BALANCE:
            bad("class_balance", f"one of {', '.join(CLASS_BALANCE)}", self.class_balance)
        if self.class_counts is not None:
            counts = self.class_counts.tolist() if isinstance(self.class_counts, np.ndarray) else self.class_counts
            if (not isinstance(counts, (list, tuple)) or not counts
                    or not all(_number(v) and math.isfinite(v) and float(v) == int(v) and v >= 0 for v in counts) or not sum(counts) > 0):
                bad("class_counts", "a list of non-negative whole numbers with a positive sum, or null", counts)
            set_(self, "class_counts", tuple(int(v) for v in counts))

    @classmethod
    def from_dict(cls, data, source=None) -> "ModelSettings":
        """From ``meta.json``'s ``settings`` (or an in-memory dict: arrays allowed). Keys left out take
        their defaults; an unknown key or a wrong type raises :class:`~hbeo.errors.DataError`
        naming ``source`` (the file; None: no file) and the key."""
        if isinstance(data, cls):
            return data
        if not isinstance(data, Mapping):
            raise DataError(source, f"{META}: \"settings\" must be an object, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        if unknown := sorted(set(data) - known):
            raise DataError(source, f"{META}: settings: unknown keys {', '.join(map(str, unknown))} "
                                    f"(known: {', '.join(f.name for f in fields(cls))})")
        try:
            return cls(**data)
        except ValueError as err:
            raise DataError(source, f"{META}: {err}") from None

    def to_dict(self) -> dict:
        """Plain JSON values, every field, in field order (what :meth:`from_dict` reads back)."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}




# --------------------------------------------------------------------------- reading and checking

class _Unreadable(ValueError):
    """What :func:`parse_meta`'s JSON hooks raise: a problem of the text, said in words."""


def _no_constants(name):
    raise _Unreadable(f"{name} is not allowed (no NaN or infinite numbers)")


def _unique_keys(pairs) -> dict:
    """json's ``object_pairs_hook``: an object whose key appears twice is refused (which would count?)."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise _Unreadable(f"key \"{k}\" appears twice in one object")
        out[k] = v
    return out


def _not_finite(value, where: str) -> str | None:
    """The first place (``settings.object_size``) in a parsed JSON value holding a float that is not finite."""
    if isinstance(value, float):
        return None if math.isfinite(value) else where
    if isinstance(value, dict):
        items = ((f"{where}.{k}" if where else k, v) for k, v in value.items())
    elif isinstance(value, list):
        items = ((f"{where}[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    return next((w for k, v in items if (w := _not_finite(v, k))), None)


def parse_meta(path, data: bytes) -> dict:
    """``meta.json``'s bytes -> its object, for :func:`check_meta`. DataError naming ``path`` when it is not
    UTF-8 JSON, repeats a key within an object, or holds NaN or a number too large to be finite (``1e400``),
    naming where."""
    try:
        meta = json.loads(data.decode("utf-8"), parse_constant=_no_constants, object_pairs_hook=_unique_keys)
    except _Unreadable as err:
        raise DataError(path, f"{META} is not JSON ({err})") from None
    except Exception as err:
        raise DataError(path, f"{META} is not JSON ({type(err).__name__}: {err})") from None
    if where := _not_finite(meta, ""):
        raise DataError(path, f"{META}: {where} is not a finite number (too large for a float)")
    return meta


def _finite(value) -> bool:
    return _number(value) and math.isfinite(value)


def check_meta(path, meta, kind: str) -> None:
    """DataError naming ``path`` and the field (ValueError when writing, ``path`` None) unless ``meta`` is a
    complete, usable meta.json of ``kind`` (see the module docstring); nothing later needs to check it again."""
    def bad(problem):
        raise (DataError(path, problem) if path is not None else ValueError(problem))

    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        bad(f"not an hbeo model file ({META} has no \"format\": \"{FORMAT}\")")
    if meta.get("format_version") != FORMAT_VERSION:
        bad(f"model format {meta.get('format_version')!r}, this hbeo ({__version__}) reads format {FORMAT_VERSION}")
    got = meta.get("kind")
    if got not in KINDS:
        bad(f"{META}: unknown kind {got!r}, expected one of {', '.join(KINDS)}")
    if got != kind:
        bad(f"holds {KINDS[got]}, not {KINDS[kind]}")
    keys = dict(_META_KEYS, **({"intrinsics": dict} if kind == "hbeo" else {}))
    for k, typ in keys.items():
        if k not in meta:
            bad(f"{META} lacks \"{k}\"")
        if not isinstance(meta[k], typ) or isinstance(meta[k], bool) != (typ is bool):
            bad(f"{META}: \"{k}\" must be a {typ.__name__}, got {type(meta[k]).__name__}")
    if extra := sorted(set(meta) - set(keys) - {"converted_from"}):
        bad(f"{META}: unknown keys {', '.join(extra)}")
    classes = meta["classes"]
    if not classes:
        bad(f"{META}: \"classes\" must be a non-empty list of class names, got []")
    if (i := next((i for i, c in enumerate(classes) if not isinstance(c, str) or not c.strip()), None)) is not None:
        bad(f"{META}: classes[{i}] must be a class name (a non-empty string), got {classes[i]!r:.40}")
    if dup := sorted({c for c in classes if classes.count(c) > 1}):
        bad(f"{META}: \"classes\" must be distinct class names; {', '.join(map(repr, dup))} appears twice")
    net_cfg = meta["net_cfg"]
    if net_cfg.get("n_classes") != len(classes):
        bad(f"{META}: {len(classes)} class names for a network with {net_cfg.get('n_classes')!r} classes")
    if kind != "hbeo":
        return
    K = meta["intrinsics"]
    if sorted(K) != sorted(INTRINSICS) or not all(_number(K[k]) for k in INTRINSICS):
        bad(f"{META}: \"intrinsics\" must hold the numbers {', '.join(INTRINSICS)}")
    for k in ("width", "height"):
        if not isinstance(K[k], (int, np.integer)) or K[k] < 1:
            bad(f"{META}: intrinsics.{k} must be a whole positive number of pixels, got {K[k]!r}")
    for k in ("fx", "fy", "cx", "cy"):
        if not _finite(K[k]) or (k in ("fx", "fy") and not K[k] > 0):
            bad(f"{META}: intrinsics.{k} must be a finite{' positive' if k in ('fx', 'fy') else ''} number "
                f"of pixels, got {K[k]!r}")
    try:
        s = ModelSettings.from_dict(meta["settings"], path)
    except DataError as err:
        bad(err.problem)
    n = net_cfg.get("n_coeffs")
    for name in ("coeff_mean", "coeff_std"):
        if getattr(s, name) is not None and len(getattr(s, name)) != n:
            bad(f"{META}: settings: {name} has {len(getattr(s, name))} values for a network with {n!r} coefficients")
    if s.class_counts is not None and len(s.class_counts) != len(classes):
        bad(f"{META}: settings: class_counts has {len(s.class_counts)} entries for {len(classes)} classes")
