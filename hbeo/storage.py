"""Files on disk: atomic writes, checksums, and the one array format (``.npz`` + JSON meta).

Owns how the project writes and reads its own data files, so that an interrupted job never
leaves a file that looks complete, and no file is ever unpickled:

- :func:`atomic_file` / :func:`atomic_text`: write to a temporary name, then rename;
- :func:`sha256_file`: the content hash used by manifests and sidecars;
- :func:`write_npz` / :func:`read_npz`: arrays plus a JSON ``meta`` entry (grid sets, BEO, ICP,
  subspace), read back with ``allow_pickle=False`` and a :class:`~hbeo.errors.DataError` naming
  the file.

Imports nothing from the rest of the package but :mod:`hbeo.errors`.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hbeo.errors import DataError


@contextmanager
def atomic_file(path, mode: str = "wb", **kw):
    """Open a temporary file beside ``path``; on a clean exit it is renamed onto ``path``
    (atomic on one file system) after its bytes reach the disk; on an error it is removed.
    Parent folders are created."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **kw) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_file(path, "w") as f:
        f.write(text)


def sha256_file(path, chunk_size: int = 1 << 20) -> str:
    """Hex sha256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_size):
            h.update(chunk)
    return h.hexdigest()



def write_npz(path, meta: dict | None, compressed: bool = False, **arrays) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-able dict; None: no meta entry) to ``path`` atomically."""
    if meta is not None:
        arrays["meta"] = np.array(json.dumps(meta))
    with atomic_file(path) as f:
        (np.savez_compressed if compressed else np.savez)(f, **arrays)
    return Path(path)


def read_npz(path, keys, what: str, format_version: int, hint: str = "") -> tuple[dict, dict]:
    """(meta, {key: array}) from a file written by :func:`write_npz`.

    DataError naming the file when it is missing, unreadable, lacks one of ``keys``, or holds
    another ``format_version`` than this hbeo reads (``hint`` is appended, e.g. "; rebuild it").
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in keys}
    except FileNotFoundError:
        raise DataError(path, f"no such {what} file") from None
    except Exception as err:
        raise DataError(path, f"not a readable {what} file ({type(err).__name__}: {err})") from None
    got = meta.get("format_version") if isinstance(meta, dict) else None
    if got != format_version:
        raise DataError(path, f"{what} format {got}, this hbeo reads {format_version}{hint}")
    return meta, arrays
