"""Fitted objects stored as one ``.npz`` of arrays plus a JSON ``meta`` entry (no pickle).

Used by the grid sets, the BEO baseline and the ICP baseline: each writes atomically and reads
back with a :class:`~hbeo.errors.DataError` that names the file and says what is wrong.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .atomic import atomic_file
from .errors import DataError


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
