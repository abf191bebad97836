"""Model files (``.hbeo``): the one reader and writer of trained models, HBEO's and the 3-D CNN's.

Owns the on-disk format of :class:`hbeo.model.inference.HBEO` (``model.hbeo``) and of
:class:`hbeo.baselines.voxcnn.VoxCNNBaseline` (``voxcnn.hbeo``), and the one-way conversion of
the old format. Reading never unpickles: a model file someone sent you runs no code.

Format (``format_version`` 2): a zip archive whose members are stored uncompressed:

``meta.json``
    UTF-8 JSON object (no NaN/Infinity): ``format`` = ``"hbeo-model"``, ``format_version`` = 2,
    ``kind`` = ``"hbeo"`` or ``"voxcnn"``, ``hbeo_version`` (the writer's), ``net_cfg`` (the
    network's configuration: :class:`~hbeo.model.network.NetConfig` or ``VoxCNNConfig`` as a
    dict), ``classes`` (names, in the network's output order), ``settings`` (preprocessing and
    inference settings, plain JSON values; kind ``hbeo``: :class:`ModelSettings`, whose
    ``from_dict`` refuses unknown keys and wrong types, naming the file), ``intrinsics`` (kind ``hbeo`` only: ``fx, fy, cx, cy``
    in pixels, ``width, height``: the camera the model was trained for) and, in a converted
    file, ``converted_from`` (``format_version`` and ``hbeo_version`` of the old file).
``weights.safetensors``
    the network's ``state_dict`` in the safetensors format (a JSON header, then raw tensors):
    float32 weights, int64 batch-norm counters, standard (contiguous) layout.
``subspace.npz``
    kind ``hbeo`` only: the object subspace as :meth:`ObjectSubspace.save` writes it, read back
    with ``np.load(..., allow_pickle=False)``.

:func:`read_model` checks all of it and raises :class:`~hbeo.errors.DataError` naming the file,
one line, on: a missing, truncated or corrupt file (the zip's CRCs), another container, a
missing or extra member, a compressed member, meta that is not JSON or lacks/mistypes a key,
another format version, the other ``kind``, a configuration that builds no network, tensors
whose names, shapes or dtypes differ from the network that configuration builds, and NaN or
infinite weights or subspace arrays. A file in the old format (``torch.save`` of a dict, format
1) is recognised without being opened and refused with a pointer to ``python -m hbeo
convert-model`` (:func:`convert_legacy`), which reads it with torch's restricted unpickler
(``weights_only=True``: tensors and plain containers only, nothing is called) and writes it anew.

Writes are atomic (:func:`hbeo.storage.atomic_file`) and deterministic: the same model gives
the same ``meta.json`` and ``weights.safetensors`` bytes (zip entries carry a fixed date).

Imports the foundation (:mod:`hbeo.storage`, :mod:`hbeo.errors`) and
:mod:`hbeo.subspace.basis` (and the sampler names of :mod:`hbeo.render.poses`); the network classes are passed in by the callers (``build``), so the
baselines layer can use this module without it importing them.
"""
from __future__ import annotations

import io
import json
import math
import os
import tempfile
import zipfile
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import safetensors.torch
import torch

from hbeo import __version__
from hbeo.errors import DataError, require_file
from hbeo.render.poses import SAMPLERS
from hbeo.storage import atomic_file
from hbeo.subspace.basis import FORMAT_VERSION as SUBSPACE_FORMAT_VERSION, ObjectSubspace

FORMAT = "hbeo-model"
#: The training's class balance a model file may record (:data:`hbeo.model.trainingdata.CLASS_BALANCE` says
#: what each does).
CLASS_BALANCE = ("none", "sampler", "loss")
FORMAT_VERSION = 2
KINDS = {"hbeo": "an HBEO model", "voxcnn": "a VoxCNN baseline (3-D CNN) model"}
META, WEIGHTS, SUBSPACE = "meta.json", "weights.safetensors", "subspace.npz"
MEMBERS = {"hbeo": (META, WEIGHTS, SUBSPACE), "voxcnn": (META, WEIGHTS)}
#: meta.json keys and their JSON types, per kind (``converted_from`` is optional)
_META_KEYS = {"format": str, "format_version": int, "kind": str, "hbeo_version": str, "net_cfg": dict,
              "classes": list, "settings": dict}
_INTRINSICS = ("fx", "fy", "cx", "cy", "width", "height")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
CONVERT_HINT = "python -m hbeo convert-model"


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
        evaluation renders its queries with it and inference warns outside its distances. Its
        ``sampler``, when present, must be one of :data:`hbeo.render.poses.SAMPLERS`.
    ``profile``
        the profile the model was trained with, or None (not recorded: the whole split).
    ``augment_roll``
        trained with random camera rolls (False: before the option existed, no rolls).
    ``shape_loss``
        the shape term trained (``"coeffs"``: before the option existed, the coefficient loss).
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
        if not _number(self.object_size) or not self.object_size > 0:
            bad("object_size", "a positive number (metres)", self.object_size)
        set_(self, "object_size", float(self.object_size))
        if self.ref_distance is not None:
            if not _number(self.ref_distance) or not self.ref_distance > 0:
                bad("ref_distance", "a positive number (metres) or null", self.ref_distance)
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
        if self.profile is not None and not isinstance(self.profile, str):
            bad("profile", "a profile name or null", self.profile)
        if not isinstance(self.shape_loss, str):
            bad("shape_loss", "a shape loss name", self.shape_loss)
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


@dataclass
class ModelFile:
    """What :func:`read_model` returns: the checked meta, the network built from ``meta["net_cfg"]``
    holding the file's weights (eval mode, on the CPU), and the subspace (kind ``hbeo``; else None)."""

    kind: str
    meta: dict
    net: torch.nn.Module
    subspace: ObjectSubspace | None


# --------------------------------------------------------------------------- writing

def _plain(value, where: str):
    """``value`` as plain JSON values (tuples and arrays become lists, NumPy scalars numbers)."""
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise ValueError(f"{where}: dict keys must be strings for a model file")
        return {k: _plain(v, f"{where}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist(), where)
    if isinstance(value, np.generic):
        return _plain(value.item(), where)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(f"{where}: {type(value).__name__} cannot be stored in a model file (JSON values only)")


def _weights_bytes(weights: Mapping[str, torch.Tensor]) -> bytes:
    out = {}
    for name, t in weights.items():
        t = t.detach().to("cpu").contiguous()
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise ValueError(f"network weight {name} holds NaN or infinite values; not writing a model file")
        out[name] = t
    return safetensors.torch.save(out)


def write_model(path, kind: str, meta: dict, weights: Mapping[str, torch.Tensor],
                subspace: ObjectSubspace | bytes | None = None) -> Path:
    """Write a model file atomically and return its path.

    ``meta``: ``net_cfg``, ``classes``, ``settings`` and (kind ``hbeo``) ``intrinsics`` as a dict,
    optionally ``converted_from``; the format fields are added here. ``weights``: the network's
    ``state_dict`` (any device or memory layout). ``subspace``: kind ``hbeo`` only, an
    :class:`ObjectSubspace` or the bytes of its ``.npz``. ValueError on a value JSON cannot hold,
    NaN or infinite weights, or a subspace given for the wrong kind."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {tuple(KINDS)}, got {kind!r}")
    if (subspace is None) != (kind != "hbeo"):
        raise ValueError(f"a {kind} model file {'needs' if kind == 'hbeo' else 'has no'} subspace")
    full = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": kind, "hbeo_version": __version__,
            **_plain(meta, "meta")}
    members = {META: json.dumps(full, indent=1, allow_nan=False).encode(), WEIGHTS: _weights_bytes(weights)}
    if kind == "hbeo":
        if isinstance(subspace, ObjectSubspace):
            buf = io.BytesIO()
            subspace.save(buf)
            subspace = buf.getvalue()
        members[SUBSPACE] = bytes(subspace)
    _check_meta(None, full, kind)        # what is written must read back
    with atomic_file(path) as f, zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as z:
        for name in MEMBERS[kind]:
            z.writestr(zipfile.ZipInfo(name, date_time=_ZIP_DATE), members[name])
    return Path(path)


# --------------------------------------------------------------------------- reading

def _legacy_message(path) -> str:
    return (f"a torch pickle, which hbeo does not open (loading it could run code it carries): an old-format hbeo "
            f"model or another program's torch file; an old model converts once with `{CONVERT_HINT} {path} NEW.hbeo`")


def _is_legacy(head: bytes, names) -> bool:
    """torch.save's zip (``<archive>/data.pkl``) or its older bare pickle (protocol 2 magic)."""
    if names is None:
        return head[:2] == b"\x80\x02"
    return any(n == "data.pkl" or n.endswith("/data.pkl") for n in names)


def _read_members(path: Path) -> dict[str, bytes]:
    """The zip's members (CRC-checked); DataError on a missing, truncated or foreign file."""
    require_file(path, "model")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
            if not zipfile.is_zipfile(f):
                if _is_legacy(head, None):
                    raise DataError(path, _legacy_message(path))
                raise DataError(path, "not a readable hbeo model file (not a zip archive, or truncated)")
            f.seek(0)
            with zipfile.ZipFile(f) as z:
                infos = z.infolist()
                names = [i.filename for i in infos]
                if _is_legacy(head, names):
                    raise DataError(path, _legacy_message(path))
                if META not in names:
                    raise DataError(path, f"not an hbeo model file (no {META}; members: {', '.join(names[:5])})")
                if len(set(names)) != len(names):
                    raise DataError(path, "not a valid hbeo model file (a member name appears twice)")
                if bad := [i.filename for i in infos if i.compress_type != zipfile.ZIP_STORED]:
                    raise DataError(path, f"not a valid hbeo model file (compressed member {bad[0]}; "
                                          f"model files store members uncompressed)")
                return {n: z.read(n) for n in names}
    except DataError:
        raise
    except Exception as err:
        raise DataError(path, f"not a readable hbeo model file ({type(err).__name__}: {err})") from None


def _no_constants(name):
    raise ValueError(f"{name} is not allowed")


def _check_meta(path, meta, kind: str) -> None:
    """DataError (ValueError when writing, ``path`` None) unless ``meta`` is a complete meta.json."""
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
    if not classes or not all(isinstance(c, str) for c in classes) or len(set(classes)) != len(classes):
        bad(f"{META}: \"classes\" must be distinct class names")
    if meta["net_cfg"].get("n_classes") != len(classes):
        bad(f"{META}: {len(classes)} class names for a network with {meta['net_cfg'].get('n_classes')!r} classes")
    if kind == "hbeo":
        K = meta["intrinsics"]
        if sorted(K) != sorted(_INTRINSICS) or not all(isinstance(K[k], (int, float)) and not isinstance(K[k], bool)
                                                       for k in _INTRINSICS):
            bad(f"{META}: \"intrinsics\" must hold the numbers {', '.join(_INTRINSICS)}")


def _check_weights(path: Path, tensors: dict, net: torch.nn.Module) -> None:
    expected = net.state_dict()
    problems = [f"missing {k}" for k in expected if k not in tensors]
    problems += [f"unexpected {k}" for k in tensors if k not in expected]
    problems += [f"{k} is {tuple(tensors[k].shape)} {str(tensors[k].dtype)[6:]}, the network's is "
                 f"{tuple(v.shape)} {str(v.dtype)[6:]}" for k, v in expected.items()
                 if k in tensors and (tensors[k].shape != v.shape or tensors[k].dtype != v.dtype)]
    if problems:
        more = f" (and {len(problems) - 3} more)" if len(problems) > 3 else ""
        raise DataError(path, f"{WEIGHTS} does not match net_cfg: {'; '.join(problems[:3])}{more}")
    for k, t in tensors.items():
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise DataError(path, f"{WEIGHTS}: {k} holds NaN or infinite values")


def _read_subspace(path: Path, data: bytes) -> ObjectSubspace:
    """The subspace member: opened as an npz without pickles and checked here first, because
    :meth:`ObjectSubspace.load` names its file in its errors and a member has no file name."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except Exception as err:
        raise DataError(path, f"{SUBSPACE} is not a readable subspace ({type(err).__name__}: {err})") from None
    if not isinstance(meta, dict) or meta.get("format_version") != SUBSPACE_FORMAT_VERSION:
        got = meta.get("format_version") if isinstance(meta, dict) else None
        raise DataError(path, f"{SUBSPACE}: subspace format {got!r}, this hbeo reads {SUBSPACE_FORMAT_VERSION}")
    for name in ("basis", "means"):
        a = arrays.get(name)
        if a is not None and a.dtype.kind == "f" and not np.isfinite(a).all():
            raise DataError(path, f"{SUBSPACE}: {name} holds NaN or infinite values")
    try:
        return ObjectSubspace.load(io.BytesIO(data))
    except Exception as err:
        raise DataError(path, f"{SUBSPACE} is not a valid subspace ({type(err).__name__}: {err})") from None


def read_model(path, kind: str, build: Callable[[dict], torch.nn.Module]) -> ModelFile:
    """Read and check a model file of ``kind`` (``hbeo`` / ``voxcnn``); ``build(net_cfg)`` makes the
    network the weights must fit. Every problem is a DataError naming the file (see the module
    docstring); nothing is unpickled."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {tuple(KINDS)}, got {kind!r}")
    path = Path(path)
    members = _read_members(path)
    try:
        meta = json.loads(members[META].decode("utf-8"), parse_constant=_no_constants)
    except Exception as err:
        raise DataError(path, f"{META} is not JSON ({type(err).__name__}: {err})") from None
    _check_meta(path, meta, kind)
    if sorted(members) != sorted(MEMBERS[kind]):
        raise DataError(path, f"{KINDS[kind]} file must hold exactly {', '.join(MEMBERS[kind])}; "
                              f"it holds {', '.join(members)}")
    try:
        tensors = safetensors.torch.load(members[WEIGHTS])
    except Exception as err:
        raise DataError(path, f"{WEIGHTS} is not a readable safetensors file ({type(err).__name__}: {err})") from None
    try:
        net = build(meta["net_cfg"])
    except Exception as err:
        raise DataError(path, f"net_cfg builds no network ({type(err).__name__}: {err})") from None
    _check_weights(path, tensors, net)
    net.load_state_dict(tensors, strict=True)
    subspace = _read_subspace(path, members[SUBSPACE]) if kind == "hbeo" else None
    return ModelFile(kind, meta, net.eval(), subspace)


# --------------------------------------------------------------------------- the old format

@dataclass
class LegacyModel:
    """An old (format 1, torch pickle) model file's content: ``blob`` as stored, and the same in
    this format's terms (``meta`` without the format fields, ``weights``, ``subspace`` npz bytes)."""

    kind: str
    blob: dict
    meta: dict
    weights: dict
    subspace: bytes | None


def _torch_reason(err: Exception) -> str:
    """The line of a torch.load error that says what was refused (not its advice to load unsafely)."""
    lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
    useful = [ln for ln in lines if not ln.startswith(("Weights only load failed", "Check the documentation"))]
    reason = next((ln for ln in useful if "GLOBAL" in ln), useful[0] if useful else "")
    return reason.split(". Please use")[0]         # not torch's how-to-allowlist advice


def read_legacy(path) -> LegacyModel:
    """Read an old-format model file with torch's restricted unpickler (``weights_only=True``:
    tensors, numbers, strings, bytes and plain containers only; no function is called), so a file
    carrying code is refused, never run. DataError naming the file otherwise."""
    path = Path(path)
    require_file(path, "model")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:
        raise DataError(path, f"not an old hbeo model file that can be read without running code it carries "
                              f"({type(err).__name__}: {_torch_reason(err)})") from None
    if not isinstance(blob, dict) or blob.get("format_version") != 1:
        raise DataError(path, "not an old (format 1) hbeo model file")
    kind = "voxcnn" if blob.get("kind") == "hbeo-voxcnn" else "hbeo"
    need = ("net_cfg", "state_dict", "classes", "settings") + (("subspace", "intrinsics") if kind == "hbeo" else ())
    if missing := [k for k in need if k not in blob]:
        raise DataError(path, f"old {kind} model file lacks {', '.join(missing)}")
    meta = {"net_cfg": blob["net_cfg"], "classes": blob["classes"], "settings": blob["settings"],
            "converted_from": {"format_version": 1, "hbeo_version": str(blob.get("hbeo_version"))}}
    if kind == "hbeo":
        meta["intrinsics"] = dict(zip(_INTRINSICS, blob["intrinsics"]))
    weights = dict(blob["state_dict"])
    if not all(isinstance(t, torch.Tensor) for t in weights.values()):
        raise DataError(path, "old model file: state_dict holds something other than tensors")
    return LegacyModel(kind, blob, meta, weights, bytes(blob["subspace"]) if kind == "hbeo" else None)


def convert_legacy(old, new, check: Callable[[LegacyModel, Path], None] | None = None) -> tuple[str, Path]:
    """Convert an old-format model file ``old`` to this format at ``new`` (may be the same path);
    returns (kind, new). The new file is written under a temporary name beside ``new`` and
    renamed onto it only after it reads back (:func:`_read_members`, meta) with bit-identical
    tensors and subspace bytes and ``check(legacy, temporary path)`` (e.g. identical predictions)
    returned without raising."""
    old, new = Path(old), Path(new)
    if old.is_file() and zipfile.is_zipfile(old):
        with zipfile.ZipFile(old) as z:
            if META in z.namelist():
                raise DataError(old, "already in the current model file format; nothing to convert")
    legacy = read_legacy(old)
    new.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{new.name}.", suffix=".converting", dir=new.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        write_model(tmp, legacy.kind, legacy.meta, legacy.weights, legacy.subspace)
        members = _read_members(tmp)
        back = safetensors.torch.load(members[WEIGHTS])
        same = (back.keys() == legacy.weights.keys()
                and all(back[k].dtype == v.dtype and torch.equal(back[k], v) for k, v in legacy.weights.items())
                and members.get(SUBSPACE) == legacy.subspace)
        if not same:
            raise DataError(new, "the converted file does not hold the old file's exact weights; not written")
        if check is not None:
            check(legacy, tmp)
        os.replace(tmp, new)
    finally:
        tmp.unlink(missing_ok=True)
    return legacy.kind, new
