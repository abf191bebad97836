"""Reading triangle meshes from disk: OFF (with ModelNet's quirks), OBJ, PLY, STL.

``read_mesh(path)`` returns a :class:`trimesh.Trimesh` built with ``process=False``:
vertices (V, 3) float64 exactly as in the file (unused ones included, which matters for
the 3D ShapeNets grid layout), faces (F, 3) int64, polygons fan-triangulated. Units and
frame are the file's own. :func:`check_mesh` validates vertex/face arrays from anywhere.
Imports only :mod:`hbeo.errors`, numpy and trimesh.

OBJ, PLY and STL are read by trimesh. OFF is read by :func:`parse_off`, our own parser,
because trimesh's OFF loader (5.2), although it reads ModelNet's one-line header
``OFF490 518 0`` correctly, silently returns wrong vertices when a ``#`` comment comes
after the counts line (it repeats the text before the comment), silently drops the missing faces of a truncated file, accepts NaN
coordinates, and fails on polygons with more than four sides
(``tests/test_meshio.py::test_why_off_keeps_its_own_parser`` pins each case). parse_off
also reads ModelNet's files 1.5-3x faster (numpy fast path).
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import trimesh

from hbeo.errors import DataError, require_file

MESH_SUFFIXES = (".off", ".obj", ".ply", ".stl")


def _fan(polys: list[list[int]]) -> np.ndarray:
    """Fan-triangulate polygons given as index lists -> (F, 3) int64."""
    tris = [(p[0], p[i], p[i + 1]) for p in polys for i in range(1, len(p) - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def _numbers(block: list[str], width: int, dtype, path, what: str) -> np.ndarray:
    """Parse lines of at least ``width`` numbers each -> (len(block), width); extra columns dropped."""
    try:
        flat = np.array(" ".join(block).split(), dtype=dtype)
        if flat.size == width * len(block):
            return flat.reshape(-1, width)
        return np.array([ln.split()[:width] for ln in block], dtype=dtype).reshape(-1, width)
    except ValueError:
        raise DataError(path, f"unreadable {what} line (expected {width} numbers)") from None


def _faces(block: list[str], path) -> np.ndarray:
    """Parse OFF face lines ``n i1 .. in [colour]`` -> fan-triangulated (F, 3) int64."""
    try:
        flat = np.array(" ".join(block).split(), dtype=np.int64)
        if flat.size == 4 * len(block) and (flat[::4] == 3).all():   # the common all-triangle case
            return flat.reshape(-1, 4)[:, 1:]
    except ValueError:
        pass  # colours as floats, or garbage: take the per-line path below
    polys = []
    for ln in block:
        tok = ln.split()
        try:
            k = int(tok[0])
            if k < 3 or len(tok) < k + 1:
                raise ValueError
            polys.append([int(x) for x in tok[1:k + 1]])
        except (ValueError, IndexError):
            raise DataError(path, f"unreadable face line {ln[:60]!r} (expected 'n i1 ... in' with n >= 3)") from None
    return _fan(polys)


def _off_header(text: str, path) -> tuple[int, int, int]:
    """-> (n_vertices, n_faces, offset of the first data character) of OFF text."""
    pos, keyword, counts = 0, None, None
    while counts is None:
        if pos >= len(text):
            raise DataError(path, "OFF header has no vertex/face counts" if keyword else
                            "not an OFF file (empty)")
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end].split("#", 1)[0].strip()
        pos = end + 1
        if not line:
            continue
        if keyword is None:
            if not line.upper().startswith(("OFF", "COFF", "NOFF", "STOFF")):
                raise DataError(path, "not an OFF file (first line does not start with 'OFF')")
            keyword = line.split()[0].rstrip("0123456789")  # "OFF1234" -> "OFF"
            line = line[len(keyword):].strip()              # ModelNet's "OFF1234 5678 0"
            if not line:
                continue
        counts = line.split()
    try:
        n_v, n_f = int(counts[0]), int(counts[1])
    except (IndexError, ValueError):
        raise DataError(path, f"bad OFF counts line {' '.join(counts)!r}; expected 'V F E'") from None
    if n_v < 0 or n_f < 0:
        raise DataError(path, f"negative vertex/face count ({n_v}, {n_f})")
    return n_v, n_f, min(pos, len(text))


def parse_off(text: str, path=None) -> tuple[np.ndarray, np.ndarray]:
    """Parse OFF text -> (vertices (V, 3) float64, faces (F, 3) int64).

    Accepts the standard header (``OFF`` line, then ``V F E``), ModelNet's broken
    one-line header (``OFF1234 5678 0``), a leading UTF-8 byte-order mark, ``#`` comments,
    blank lines, per-vertex or per-face colours after the coordinates, and polygons with any
    number of sides (fan-triangulated). Raises :class:`DataError` naming ``path`` on anything
    else, including data lines beyond the header's counts (a wrong header, never silently dropped).
    """
    text = text[1:] if text.startswith("\ufeff") else text   # a UTF-8 byte-order mark (Windows editors)
    n_v, n_f, start = _off_header(text, path)
    body = text[start:]
    verts = faces = None
    if "#" not in body:   # fast path: plain x y z rows, then "3 i j k" rows (ModelNet's files)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            try:   # stops at text it cannot read: numpy 1 warns, numpy 2 raises
                flat = np.fromstring(body, sep=" ")
            except ValueError:
                flat = np.empty(0)
        if flat.size == 3 * n_v + 4 * n_f:
            tri = flat[3 * n_v:].reshape(-1, 4)
            if (tri[:, 0] == 3).all() and (tri == np.round(tri)).all():
                verts, faces = flat[:3 * n_v].reshape(-1, 3), tri[:, 1:].astype(np.int64)
    if verts is None:
        lines = [ln.split("#", 1)[0].strip() for ln in body.splitlines()]
        lines = [ln for ln in lines if ln]
        if len(lines) < n_v + n_f:
            raise DataError(path, f"truncated OFF: header promises {n_v} vertices and {n_f} faces, "
                                  f"file has {len(lines)} data lines")
        if len(lines) > n_v + n_f:   # extra vertices or faces: the header's counts are wrong
            raise DataError(path, f"OFF header promises {n_v} vertices and {n_f} faces ({n_v + n_f} data "
                                  f"lines) but the file has {len(lines)}; the {len(lines) - n_v - n_f} extra "
                                  f"(first: {lines[n_v + n_f][:60]!r}) would be lost: fix the counts line")
        verts = _numbers(lines[:n_v], 3, np.float64, path, "vertex")
        faces = _faces(lines[n_v:n_v + n_f], path)
    _bad_vertex(verts, path)
    bad = (faces < 0) | (faces >= n_v)
    if bad.any():
        k = int(np.flatnonzero(bad.any(axis=1))[0])
        raise DataError(path, f"face {k} refers to vertex {int(faces[k][bad[k]][0])} but the file has "
                              f"{n_v} vertices")
    return verts, faces


#: Largest coordinate magnitude accepted: beyond it a file is corrupt (1e30), whatever its unit.
MAX_COORD = 1e12
#: Relative size below which a spread (faces' extent, total area) counts as zero.
_TINY = 1e-9


def _xyz(v) -> str:
    return "(" + ", ".join(f"{float(x):.6g}" for x in v) + ")"


def _bad_vertex(v: np.ndarray, name) -> None:
    """DataError naming the first non-finite vertex, or one farther out than :data:`MAX_COORD`."""
    finite = np.isfinite(v).all(axis=1)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise DataError(name, f"vertex {i} has a NaN or infinite coordinate {_xyz(v[i])}")
    far = np.abs(v).max(axis=1) > MAX_COORD
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise DataError(name, f"vertex {i} at {_xyz(v[i])}: coordinates beyond +-{MAX_COORD:g} "
                              f"(a corrupt file?)")


def _line_like(v: np.ndarray, c: np.ndarray, extent: float, name) -> None:
    """DataError for vertices ``v`` (centred: ``c``) that lie within :data:`_TINY` of their span
    ``extent`` of one line: collinear, when they are on it up to rounding; else the coordinates
    span too wide a range (one far vertex, e.g. at 1e11 beside a unit-size mesh, makes the rest a
    point and the whole a line in the grid layout, which spans all vertices)."""
    axis = np.linalg.svd(c / extent, full_matrices=False)[2][0]
    along = c @ axis
    across = float(np.linalg.norm(c - np.outer(along, axis), axis=1).max())
    rounding = 64 * np.finfo(np.float64).eps * max(extent, float(np.abs(v).max()))
    if across <= rounding:
        raise DataError(name, f"degenerate mesh: all {len(v)} vertices are collinear (on one line)")
    i = int(np.argmax(np.abs(v - np.median(v, axis=0)).max(axis=1)))
    raise DataError(name, f"degenerate mesh: its coordinates span too wide a range: {float(np.ptp(along)):.3g} along one "
                          f"line but at most {across:.3g} across it (under {_TINY:g} of the span), so in the "
                          f"grid it is a line; vertex {i} at {_xyz(v[i])} lies farthest out (a stray vertex "
                          f"or a wrong coordinate?)")


def check_mesh(vertices, faces, name=None) -> tuple[np.ndarray, np.ndarray]:
    """Validated (vertices (V, 3) float64, faces (F, 3) int64) of a mesh; :class:`DataError`
    naming ``name`` (its file or id) and the offending value if the mesh is empty, has a
    non-finite or absurdly far vertex (beyond :data:`MAX_COORD`), a face indexing a vertex that
    does not exist, or is degenerate: all vertices coincide or lie on one line (or, to within
    :data:`_TINY` of their span, do: coordinates spanning too wide a range), one stray vertex
    so far away that the faces shrink to a point in the grid layout (which spans all vertices),
    or faces of zero total area."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1:] != (3,) or len(v) == 0:
        raise DataError(name, f"empty mesh: no vertices (shape {v.shape})")
    if f.ndim != 2 or f.shape[1:] != (3,) or len(f) == 0:
        raise DataError(name, "empty mesh: no triangle faces")
    _bad_vertex(v, name)
    bad = (f < 0) | (f >= len(v))
    if bad.any():
        k = int(np.flatnonzero(bad.any(axis=1))[0])
        raise DataError(name, f"face {k} refers to vertex {int(f[k][bad[k]][0])} but the mesh has "
                              f"{len(v)} vertices")
    extent = float(np.ptp(v, axis=0).max())
    if extent <= 0:
        raise DataError(name, "degenerate mesh: all vertices coincide")
    c = v - v.mean(axis=0)
    # singular values of the centred vertices themselves (descending): through c^T c (squared) the
    # rounding of an exact line's second value reaches ~1e-8 relative, above _TINY on some CPUs
    s = np.linalg.svd(c / extent, compute_uv=False)
    if s[1] <= _TINY * s[0]:
        _line_like(v, c, extent, name)
    used = v[np.unique(f)]
    if float(np.ptp(used, axis=0).max()) <= _TINY * extent:
        lo, hi = used.min(axis=0), used.max(axis=0)
        i = int(np.argmax(np.maximum(lo - v, v - hi).max(axis=1)))
        raise DataError(name, f"degenerate mesh: vertex {i} at {_xyz(v[i])} lies so far from the faces "
                              f"(extent {float(np.ptp(used, axis=0).max()):.3g}) that they shrink to a point")
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    if area <= _TINY * extent ** 2:
        raise DataError(name, f"degenerate mesh: its {len(f)} faces have zero total area")
    return v, f


def read_mesh(path) -> trimesh.Trimesh:
    """Read a mesh file (.off, .obj, .ply, .stl) -> Trimesh (process=False, unused vertices kept).

    Raises :class:`DataError` naming the file when it is missing, unreadable or empty.
    """
    path = Path(path)
    require_file(path, "mesh")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise DataError(path, f"unsupported mesh format {suffix!r}; expected one of {', '.join(MESH_SUFFIXES)}")
    if suffix == ".off":
        try:
            text = path.read_text(encoding="utf-8", errors="strict")
        except UnicodeDecodeError:
            raise DataError(path, "not a text OFF file (binary OFF is not supported)") from None
        verts, faces = parse_off(text, path)
        mesh = trimesh.Trimesh(verts, faces, process=False, validate=False)
    else:
        try:
            loaded = trimesh.load(os.fspath(path), process=False, force="mesh")
        except Exception as err:  # trimesh raises many types on malformed files
            raise DataError(path, f"unreadable {suffix} mesh ({type(err).__name__}: {err})") from None
        mesh = loaded
    if len(mesh.faces) == 0:
        raise DataError(path, "mesh has no faces")
    mesh.metadata["file"] = os.fspath(path)
    return mesh
