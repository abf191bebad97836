"""Files on disk: atomic writes, checksums, and the one array format (``.npz`` + JSON meta).

Owns how the project writes and reads its own data files, so that an interrupted job never
leaves a file that looks complete, and no file is ever unpickled:

- :func:`atomic_file` / :func:`atomic_text`: write to a temporary name, then rename (the file gets
  the user's umask, as a plain ``open`` would give it); :func:`read_json`: a JSON file read back, a
  :class:`~hbeo.errors.DataError` naming the file when it is truncated, damaged or of the wrong type;
- :func:`sha256_file`: the content hash used by manifests and sidecars; :func:`tree_digest`: of a source tree
  (the code version in evaluation cache keys);
- :func:`write_sidecar` / :func:`read_sidecar` / :func:`verify_sidecar`: a file's sha256 recorded
  beside it in ``<name>.sha256`` (``sha256sum`` format: ``<hex digest>  <name>``), so a later run
  can tell a finished file (download, render shard) from a damaged one;
- :func:`write_npz` / :func:`read_npz`: arrays plus a JSON ``meta`` entry (grid sets, BEO, ICP,
  subspace), read back with ``allow_pickle=False`` and a :class:`~hbeo.errors.DataError` naming
  the file;
- :func:`pack_bits` / :func:`unpack_bits`: boolean arrays (occupancy grids, masks) stored as
  bit-packed rows, one row of ``ceil(size / 8)`` uint8 per item;
- :func:`exclusive_lock`: one process at a time in a folder (a run being reproduced).

Imports nothing from the rest of the package but :mod:`hbeo.errors` and :mod:`hbeo.conventions`
(the grid shape).
"""
from __future__ import annotations

import errno
import hashlib
import json
import logging
import math
import os
import re
import tempfile
import time
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hbeo.conventions import RESOLUTION
from hbeo.errors import DataError

logger = logging.getLogger(__name__)

#: shape of one occupancy grid, the default of :func:`unpack_bits`
GRID_SHAPE = (RESOLUTION,) * 3


def current_umask() -> int:
    """The process's umask, read without changing it where the system tells it (Linux:
    ``/proc/self/status``); elsewhere set and restored at once (racy only against another thread
    creating a file in that instant)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def atomic_file(path, mode: str = "wb", **kw):
    """Open a temporary file beside ``path``; on a clean exit it is renamed onto ``path``
    (atomic on one file system) after its bytes reach the disk; on an error it is removed, and an
    OSError that names no file (a full disk) or the temporary names ``path`` instead.
    Parent folders are created. The file gets the mode a plain ``open`` would give a new file,
    0666 less the umask (``mkstemp`` creates it 0600). Several files at once: :func:`atomic_files`."""
    with atomic_files([(path, mode)], **kw) as (f,):
        yield f


def _temporary(path: Path) -> tuple[int, str]:
    """``mkstemp`` beside ``path``; its OSError names ``path`` (the temporary's name would hide the real
    problem: in ``/proc`` it is ENOENT for a folder that exists)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        return tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as err:
        if err.errno == errno.ENOENT and path.parent.is_dir():
            raise OSError(errno.EACCES, f"cannot create a file in the folder {path.parent}", str(path)) from None
        raise OSError(err.errno, err.strerror, str(path)) from None


@contextmanager
def atomic_files(specs, **kw):
    """Write several files together, each as :func:`atomic_file` does: ``specs`` is ``[(path, mode), ...]``
    and the files are yielded in that order. On a clean exit every file reaches the disk before any is
    renamed into place, so a failure (a full disk) leaves all of them as they were, and no temporary. A path
    that is a link is written through (the file it names is replaced, the link stays); one that names a device
    or a pipe (``--out /dev/null``) is written in place, not atomically (replacing it would replace the device)."""
    made: list = []                     # (temporary, path, file); temporary None: written in place
    current = None                      # the path an OSError without a file name is about
    try:
        for path, mode in specs:
            current = Path(path)
            real = Path(os.path.realpath(current))      # through a link: the file it names is written
            if real.exists() and not real.is_file():    # a device or a pipe (/dev/null): in place, never replaced
                made.append((None, current, open(real, mode, **kw)))
                continue
            fd, tmp = _temporary(real)
            made.append((tmp, real, None))
            f = os.fdopen(fd, mode, **kw)
            made[-1] = (tmp, real, f)
            os.fchmod(f.fileno(), 0o666 & ~current_umask())
        current = made[0][1] if made else None
        yield [f for _, _, f in made]
        for tmp, current, f in made:
            f.flush()
            if tmp is not None:
                os.fsync(f.fileno())
            f.close()
        for tmp, current, _ in made:
            if tmp is not None:
                os.replace(tmp, current)
    except BaseException as err:
        for tmp, _, f in made:
            if f is not None:
                try:
                    f.close()
                except OSError:
                    pass
            if tmp is not None:
                Path(tmp).unlink(missing_ok=True)
        if isinstance(err, OSError) and current is not None and err.filename in (None, *(t for t, _, _ in made if t)):
            raise OSError(err.errno, err.strerror, str(current)) from err
        raise


@contextmanager
def exclusive_lock(path, what: str):
    """Hold an exclusive lock on the file ``path`` (created; it records the holder's pid and start) for the
    ``with`` block, or raise DataError naming ``path``'s folder when another process holds it (``what``: what
    that process is doing, for the message). The operating system drops the lock when its holder exits,
    however it exits, so a crashed run leaves no stale lock. Without ``fcntl`` (not POSIX) nothing is locked."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    f = open(path, "a+", encoding="utf-8")
    try:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            if err.errno not in (errno.EACCES, errno.EAGAIN):
                raise
            f.seek(0)
            holder = f.read().strip() or "another process"
            raise DataError(path.parent, f"{what} is already running here ({holder}); wait for it to finish, "
                                         "or write elsewhere") from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}")
        f.flush()
        yield
    finally:
        f.close()                                       # closing the file releases the lock


def finite_json(obj):
    """``obj`` with every non-finite float (NaN, inf) replaced by None, in nested dicts, lists and tuples:
    the rule for every JSON file hbeo writes (a number that does not exist is ``null``, never ``NaN``)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    return obj


def json_text(obj, **kw) -> str:
    """Strict JSON text of ``obj`` (``json.dumps`` keywords ``kw``): non-finite floats become ``null``
    (:func:`finite_json`); anything else JSON cannot hold is an error, never an invalid file."""
    if kw.get("default") is not None:
        default = kw["default"]
        kw["default"] = lambda o: finite_json(default(o))
    return json.dumps(finite_json(obj), allow_nan=False, **kw)


_JSON_TYPES = {dict: "a JSON object", list: "a JSON list"}


def read_json(path, what: str = "JSON", kind: type | None = None, hint: str = ""):
    """The value of the JSON file ``path``. DataError naming the file when it is not valid JSON (truncated,
    damaged, not UTF-8) or, given ``kind`` (``dict`` or ``list``), holds another type; ``what`` names the file's kind in the message
    (``"metrics"``: ``not a readable metrics file``), ``hint`` is appended (e.g. ``"; evaluate again"``). A
    missing file or a folder is the OSError, which names the path (the command line prints it as one line)."""
    path = Path(path)
    data = path.read_bytes()
    try:
        value = json.loads(data)
    except ValueError as err:            # JSONDecodeError, UnicodeDecodeError
        why = "empty" if not data.strip() else f"{type(err).__name__}: {err}"
        raise DataError(path, f"not a readable {what} file: not valid JSON ({why}); truncated or damaged?{hint}") \
            from None
    if kind is not None and not isinstance(value, kind):
        raise DataError(path, f"not a {what} file: it holds {json_type(value)}, not {_JSON_TYPES.get(kind, kind)}"
                              f"{hint}")
    return value


def json_type(value) -> str:
    """What a JSON value is, in words for a message: ``a JSON object``, ``text ('x')``, ``a number (3)``, ..."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"true/false ({str(value).lower()})"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})"
    if isinstance(value, str):
        return f"text ({value[:40]!r})"
    return _JSON_TYPES.get(type(value), type(value).__name__)


def atomic_text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_file(path, "w") as f:
        f.write(text)


def atomic_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_file(path) as f:
        f.write(data)


def append_csv(path, rows: list[dict]) -> None:
    """Append ``rows`` (dicts, one per line) to the CSV table at ``path`` (created with a header when
    missing; columns new to it are added, left empty in older rows). The whole table is rewritten
    atomically (:func:`atomic_text`), so an interruption never leaves a half-written file; the older rows'
    cells are read and written back as the text they were (a float such as 20.958594736930078 would come
    back from pandas' default parser one digit off, an integer column with gaps as floats)."""
    import pandas as pd
    path = Path(path)
    old = pd.read_csv(path, dtype=str, keep_default_na=False) if path.exists() else pd.DataFrame()
    atomic_text(path, pd.concat([old, pd.DataFrame(rows, dtype=object)], ignore_index=True).to_csv(index=False))


def sha256_file(path, chunk_size: int = 1 << 20) -> str:
    """Hex sha256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_size):
            h.update(chunk)
    return h.hexdigest()


def tree_digest(root, pattern: str = "*.py", skip=()) -> str:
    """Hex sha256 over the relative paths and contents of the files under ``root`` matching
    ``pattern`` (sorted), leaving out relative paths listed in ``skip``: the code version of a
    package, whatever the git state."""
    root = Path(root)
    h = hashlib.sha256()
    for p in sorted(root.rglob(pattern)):
        if "__pycache__" in p.parts or p.relative_to(root).as_posix() in skip:
            continue
        h.update(p.relative_to(root).as_posix().encode() + b"\0")
        h.update(sha256_file(p).encode() + b"\n")
    return h.hexdigest()


# --------------------------------------------------------------------------- checksum sidecars

def sidecar_path(path) -> Path:
    """Where the checksum of ``path`` is recorded: ``<path>.sha256`` beside it."""
    path = Path(path)
    return path.with_name(path.name + ".sha256")


def write_sidecar(path, digest: str | None = None) -> str:
    """Record ``digest`` (the sha256 of ``path``, computed when None) in ``<path>.sha256``,
    atomically, in ``sha256sum`` format; returns the digest."""
    path = Path(path)
    digest = (digest or sha256_file(path)).lower()
    atomic_text(sidecar_path(path), f"{digest}  {path.name}\n")
    return digest


def read_sidecar(path) -> str | None:
    """The sha256 recorded for ``path`` (lower-case hex); None if there is no record, or one that
    cannot be read (logged)."""
    side = sidecar_path(path)
    try:
        token = side.read_text().split()[0].lower()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, IndexError):
        token = ""
    if re.fullmatch(r"[0-9a-f]{64}", token):
        return token
    logger.warning("ignoring unreadable checksum record %s", side)
    return None


def verify_sidecar(path) -> str | None:
    """The sha256 of ``path`` if the file exists and matches its recorded checksum, else None."""
    path = Path(path)
    recorded = read_sidecar(path) if path.is_file() else None
    if recorded is None:
        return None
    digest = sha256_file(path)
    return digest if digest == recorded else None


# --------------------------------------------------------------------------- arrays

def pack_bits(masks) -> np.ndarray:
    """Boolean arrays (N, ...) -> uint8 (N, ceil(size / 8)): each item's values in C order,
    eight to a byte (numpy's ``packbits``, first value in the high bit)."""
    m = np.asarray(masks, dtype=bool)
    if m.ndim < 2:
        raise ValueError(f"pack_bits: expected a stack of arrays (N, ...), got shape {m.shape}")
    return np.packbits(m.reshape(len(m), int(np.prod(m.shape[1:]))), axis=1)


def unpack_bits(packed, shape=GRID_SHAPE) -> np.ndarray:
    """Rows (N, ceil(size / 8)) written by :func:`pack_bits` -> bool (N, *shape); ``shape`` is
    one item's (default: a 30^3 occupancy grid). ValueError if the rows do not fit ``shape``."""
    p = np.asarray(packed)
    shape = tuple(int(n) for n in shape)
    count = int(np.prod(shape))
    if p.dtype != np.uint8 or p.ndim != 2 or p.shape[1] != (count + 7) // 8:
        raise ValueError(f"unpack_bits: expected uint8 rows (N, {(count + 7) // 8}) holding items of "
                         f"shape {shape}, got {p.dtype} {p.shape}")
    return np.unpackbits(p, axis=1, count=count).astype(bool).reshape((len(p),) + shape)


def _describe(path) -> str | None:
    """A file's name for messages: the path, or an open file's ``name`` (None for an anonymous buffer)."""
    if hasattr(path, "read") or hasattr(path, "write"):
        name = getattr(path, "name", None)
        return name if isinstance(name, (str, os.PathLike)) else None
    return os.fspath(path)


def _write_zip_npz(f, arrays: dict, compressed: bool) -> None:
    """The .npz layout numpy reads, with fixed zip timestamps: the same arrays give the same bytes."""
    method = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with zipfile.ZipFile(f, "w", compression=method) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as fid:
                np.lib.format.write_array(fid, np.asanyarray(arr), allow_pickle=False)


def write_npz(path, meta: dict | None, compressed: bool = False, **arrays) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-able dict; None: no meta entry) to ``path`` atomically, or
    into an open binary file. Deterministic: the same arrays and meta give the same bytes."""
    if meta is not None:
        arrays["meta"] = np.array(json.dumps(meta))
    if hasattr(path, "write"):
        _write_zip_npz(path, arrays, compressed)
        return path
    with atomic_file(path) as f:
        _write_zip_npz(f, arrays, compressed)
    return Path(path)


def read_npz(path, keys, what: str, format_version: int, hint: str = "") -> tuple[dict, dict]:
    """(meta, {key: array}) from a file (path or open binary file) written by :func:`write_npz`.

    DataError naming the file when it is missing, unreadable, lacks one of ``keys``, or holds
    another ``format_version`` than this hbeo reads (``hint`` is appended, e.g. "; rebuild it").
    """
    name = _describe(path)
    src = path if hasattr(path, "read") else Path(path)
    try:
        with np.load(src, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in keys}
    except FileNotFoundError:
        raise DataError(name, f"no such {what} file") from None
    except Exception as err:
        raise DataError(name, f"not a readable {what} file ({type(err).__name__}: {err})") from None
    got = meta.get("format_version") if isinstance(meta, dict) else None
    if got != format_version:
        raise DataError(name, f"{what} format {got}, this hbeo reads {format_version}{hint}")
    return meta, arrays


# --------------------------------------------------------------------------- output paths

def check_outputs(outputs: dict, inputs: dict | None = None) -> None:
    """Check, before any work, that a command can write its output files and will not overwrite
    one of its inputs. ``outputs`` / ``inputs``: {option name (e.g. ``"--out"``): path or None}.

    DataError naming the option and the file when an output is a folder, its folder is missing
    or not a folder or not writable, or it is the same file as an input or another output (resolved
    paths; ``os.path.samefile`` where both exist, so links and hard links count)."""
    def same(a: Path, b: Path) -> bool:
        if a.resolve() == b.resolve():
            return True
        try:
            return a.exists() and b.exists() and os.path.samefile(a, b)
        except OSError:
            return False

    outs = [(k, Path(v)) for k, v in outputs.items() if v is not None]
    ins = [(k, Path(v)) for k, v in (inputs or {}).items() if v is not None]
    for i, (opt, path) in enumerate(outs):
        parent = path.parent
        if path.is_dir():
            raise DataError(path, f"{opt} names a folder; give a file name")
        if not parent.exists():
            raise DataError(path, f"{opt}: folder {parent} does not exist")
        if not parent.is_dir():
            raise DataError(path, f"{opt}: {parent} is not a folder")
        if not os.access(parent, os.W_OK | os.X_OK):
            ro = hasattr(os, "statvfs") and os.statvfs(parent).f_flag & os.ST_RDONLY
            raise DataError(path, f"{opt}: folder {parent} is on a read-only file system" if ro
                            else f"{opt}: no permission to write in folder {parent}")
        for other, p in ins + outs[:i]:
            if same(path, p):
                raise DataError(path, f"{opt} is the same file as {other}; it would be overwritten")
