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
    inference settings, plain JSON values; kind ``hbeo``:
    :class:`~hbeo.model.modelmeta.ModelSettings`, whose ``from_dict`` refuses unknown keys and wrong
    types, naming the file), ``intrinsics`` (kind ``hbeo`` only: ``fx, fy, cx, cy`` in pixels, ``width,
    height`` whole pixels: the camera the model was trained for) and, in a converted
    file, ``converted_from`` (``format_version`` and ``hbeo_version`` of the old file).
``weights.safetensors``
    the network's ``state_dict`` in the safetensors format (a JSON header, then raw tensors):
    float32 weights, int64 batch-norm counters, standard (contiguous) layout.
``subspace.npz``
    kind ``hbeo`` only: the object subspace as :meth:`ObjectSubspace.save` writes it, read back
    with ``np.load(..., allow_pickle=False)``.

:func:`read_model` checks all of it and raises :class:`~hbeo.errors.DataError` naming the file,
one line, on: a missing, truncated or corrupt file (the zip's CRCs), another container, a
missing or extra member, a compressed member, a ``meta.json`` that
:func:`~hbeo.model.modelmeta.check_meta` refuses (the one check of its content, naming the field:
duplicate keys, numbers out of range, a missing, mistyped or out-of-range value, another format version,
the other ``kind``), class names that are not the subspace's, a configuration that builds no network, tensors
whose names, shapes or dtypes differ from the network that configuration builds, and NaN or
infinite weights or subspace arrays. A file in the old format (``torch.save`` of a dict, format
1) is recognised without being opened and refused with a pointer to ``python -m hbeo
convert-model`` (:func:`convert_legacy`), which reads it with torch's restricted unpickler
(``weights_only=True``: tensors and plain containers only, nothing is called) and writes it anew;
an old file that cannot be converted (a value of the wrong type, settings or weights the current
format refuses) is a DataError naming the old file.

Writes are atomic (:func:`hbeo.storage.atomic_file`) and deterministic: the same model gives
the same ``meta.json`` and ``weights.safetensors`` bytes (zip entries carry a fixed date).

Imports the foundation (:mod:`hbeo.storage`, :mod:`hbeo.errors`), :mod:`hbeo.model.modelmeta` and
:mod:`hbeo.subspace.basis`; the network classes are passed in by the callers (``build``), so the
baselines layer can use this module without it importing them.
"""
from __future__ import annotations

import io
import json
import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import safetensors.torch
import torch

from hbeo import __version__
from hbeo.errors import DataError, require_file
from hbeo.model.modelmeta import (CLASS_BALANCE, FORMAT, FORMAT_VERSION, INTRINSICS, KINDS, META,  # noqa: F401
                                  ModelSettings, check_meta, parse_meta)         # (CLASS_BALANCE, ModelSettings: re-exported)
from hbeo.storage import atomic_file
from hbeo.subspace.basis import FORMAT_VERSION as SUBSPACE_FORMAT_VERSION, ObjectSubspace

WEIGHTS, SUBSPACE = "weights.safetensors", "subspace.npz"
MEMBERS = {"hbeo": (META, WEIGHTS, SUBSPACE), "voxcnn": (META, WEIGHTS)}
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
CONVERT_HINT = "python -m hbeo convert-model"


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
    check_meta(None, full, kind)         # what is written must read back
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


def _checked_members(path: Path, kind: str) -> tuple[dict, dict]:
    """The members of model file ``path`` and its parsed metadata, checked for ``kind``: the metadata, and
    exactly the members that kind holds (DataError naming the file)."""
    members = _read_members(path)
    meta = parse_meta(path, members[META])
    check_meta(path, meta, kind)
    if sorted(members) != sorted(MEMBERS[kind]):
        raise DataError(path, f"{KINDS[kind]} file must hold exactly {', '.join(MEMBERS[kind])}; "
                              f"it holds {', '.join(members)}")
    return members, meta


def read_subspace(path) -> ObjectSubspace:
    """The subspace an ``hbeo`` model file holds (the one its network was trained on), checked as
    :func:`read_model` checks it, without reading the weights or building the network."""
    path = Path(path)
    members, _ = _checked_members(path, "hbeo")
    return _read_subspace(path, members[SUBSPACE])


def read_model(path, kind: str, build: Callable[[dict], torch.nn.Module]) -> ModelFile:
    """Read and check a model file of ``kind`` (``hbeo`` / ``voxcnn``); ``build(net_cfg)`` makes the
    network the weights must fit. Every problem is a DataError naming the file (see the module
    docstring); nothing is unpickled."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {tuple(KINDS)}, got {kind!r}")
    path = Path(path)
    members, meta = _checked_members(path, kind)
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
    if subspace is not None and (alien := [c for c in meta["classes"] if c not in subspace.classes_]):
        raise DataError(path, f"{META}: classes {', '.join(map(repr, alien))} are not classes of {SUBSPACE} "
                              f"(its classes: {', '.join(subspace.classes_)})")
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


#: an old file's entries: the types they must have, in words
_LEGACY_TYPES = {"net_cfg": (dict, "a dict"), "state_dict": (dict, "a dict of tensors"),
                 "classes": ((list, tuple), "a list of class names"), "settings": (dict, "a dict"),
                 "subspace": ((bytes, bytearray), "bytes (a subspace .npz)"),
                 "intrinsics": ((list, tuple), "a list of numbers")}


def read_legacy(path) -> LegacyModel:
    """Read an old-format model file with torch's restricted unpickler (``weights_only=True``:
    tensors, numbers, strings, bytes and plain containers only; no function is called), so a file
    carrying code is refused, never run. DataError naming the file otherwise, and on an entry of the wrong
    type or size (:data:`_LEGACY_TYPES`) or a subspace that does not read."""
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
    for k in need:
        want, words = _LEGACY_TYPES[k]
        if not isinstance(blob[k], want):
            raise DataError(path, f"old {kind} model file: {k} must be {words}, got {type(blob[k]).__name__}")
    if kind == "hbeo" and len(blob["intrinsics"]) != len(INTRINSICS):
        raise DataError(path, f"old hbeo model file: intrinsics must hold {len(INTRINSICS)} numbers "
                              f"({', '.join(INTRINSICS)}), it holds {len(blob['intrinsics'])}")
    meta = {"net_cfg": blob["net_cfg"], "classes": list(blob["classes"]), "settings": blob["settings"],
            "converted_from": {"format_version": 1, "hbeo_version": str(blob.get("hbeo_version"))}}
    subspace = None
    if kind == "hbeo":
        meta["intrinsics"] = dict(zip(INTRINSICS, blob["intrinsics"]))
        subspace = bytes(blob["subspace"])
        try:
            _read_subspace(path, subspace)
        except DataError as err:
            raise DataError(path, f"old hbeo model file: {err.problem.replace(SUBSPACE, 'subspace')}") from None
    weights = dict(blob["state_dict"])
    if not all(isinstance(t, torch.Tensor) for t in weights.values()):
        raise DataError(path, "old model file: state_dict holds something other than tensors")
    return LegacyModel(kind, blob, meta, weights, subspace)


def convert_legacy(old, new, check: Callable[[LegacyModel, Path], None] | None = None) -> tuple[str, Path]:
    """Convert an old-format model file ``old`` to this format at ``new`` (may be the same path);
    returns (kind, new). The new file is written under a temporary name beside ``new`` and
    renamed onto it only after it reads back (:func:`_read_members`, meta) with bit-identical
    tensors and subspace bytes and ``check(legacy, temporary path)`` (e.g. identical predictions)
    returned without raising. Whatever stops it (settings or weights this format refuses, a failed
    check) is a DataError naming ``old``; ``new`` is then left as it was."""
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
    except OSError:
        raise
    except DataError as err:           # about the converted file (a temporary) or its meta: the old file's fault
        raise DataError(old, f"cannot be converted: {err.problem.removeprefix(f'{META}: ')}") from None
    except (ValueError, TypeError, RuntimeError, KeyError, IndexError) as err:
        words = (str(err).strip().splitlines() or [""])[0].removeprefix(f"{META}: ")
        raise DataError(old, f"cannot be converted ({type(err).__name__}: {words})") from None
    finally:
        tmp.unlink(missing_ok=True)
    return legacy.kind, new
