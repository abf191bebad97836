"""The part library of the procedural furniture (:mod:`hbeo.data.procedural`).

Primitives (:func:`box`, :func:`frustum`, :func:`tube`, :func:`rod`, :func:`legs_at`) are closed,
outward-wound triangle meshes given as a :data:`Part` = (vertices (V, 3) float64, faces (F, 3)
int64); :func:`transformed`, :func:`rot_x`, :func:`rot_z` move them. The furniture
sub-assemblies shared by several classes (pedestals, drawer fronts with handles, carcasses,
cabinet bases, top slabs) draw their sizes from the object's random stream and return lists
of parts; :func:`assemble` joins parts into one mesh resting on z = 0.

Units and frame: metres, the object frame of :mod:`hbeo.data.procedural` (+z up, fronts face -y).
Deterministic: randomness comes only from the ``rng`` (a numpy Generator) passed in.
Imports :mod:`hbeo.rotations`, numpy and trimesh only.
"""
from __future__ import annotations

import numpy as np
import trimesh

from hbeo.rotations import x_angle_to_matrix, z_angle_to_matrix

SECTIONS = 16         #: sections of ordinary cylinders (legs, columns)
ROUND_SECTIONS = 24   #: sections of large round parts (table tops, discs, basins)
SMALL_SECTIONS = 8    #: sections of tiny parts (knobs, casters)

Part = tuple  # (vertices (V, 3) float, faces (F, 3) int), a closed outward-wound mesh

# ----------------------------------------------------------------------------
# Part helpers (all coordinates in metres, object frame)
# ----------------------------------------------------------------------------

_UNIT_BOX = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
_BOX_V = np.asarray(_UNIT_BOX.vertices, dtype=np.float64) + 0.5   # unit cube [0, 1]^3
_BOX_F = np.asarray(_UNIT_BOX.faces, dtype=np.int64)


def box(lo, hi) -> Part:
    """Axis-aligned box between two opposite corners (any order)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    a, b = np.minimum(lo, hi), np.maximum(lo, hi)
    return a + _BOX_V * (b - a), _BOX_F


def _ring(cx, cy, z, r, n, phase):
    rx, ry = np.broadcast_to(np.asarray(r, dtype=np.float64), (2,))
    t = phase + 2.0 * np.pi * np.arange(n) / n
    return np.column_stack([cx + rx * np.cos(t), cy + ry * np.sin(t), np.full(n, float(z))])


def _band(a, b, n):
    """Faces of the side band between rings starting at indices a (lower) and b (upper)."""
    k = np.arange(n)
    k1 = (k + 1) % n
    return np.concatenate([np.column_stack([a + k, a + k1, b + k1]),
                           np.column_stack([a + k, b + k1, b + k])])


def frustum(center, z0, z1, r0, r1=None, sections=SECTIONS, phase=0.0) -> Part:
    """Solid vertical frustum (cylinder if r1 is None) from z0 to z1 around center=(x, y).

    Radii are scalars or (rx, ry) pairs (elliptical section). sections=4 with
    phase=pi/4 and radii (a*sqrt2, b*sqrt2) gives a box-shaped frustum of half sizes a, b.
    """
    n = int(sections)
    r1 = r0 if r1 is None else r1
    cx, cy = center
    v = np.vstack([_ring(cx, cy, z0, r0, n, phase), _ring(cx, cy, z1, r1, n, phase),
                   [[cx, cy, z0], [cx, cy, z1]]])
    k = np.arange(n)
    k1 = (k + 1) % n
    top = np.column_stack([np.full(n, 2 * n + 1), n + k, n + k1])
    bottom = np.column_stack([np.full(n, 2 * n), k1, k])
    return v, np.concatenate([_band(0, n, n), top, bottom])


def tube(center, z0, z1, r0, r1, thickness, sections=ROUND_SECTIONS) -> Part:
    """Hollow vertical (elliptical) frustum wall, open at both ends: outer radii r0 at z0, r1 at z1.

    The inner radii are the outer ones minus ``thickness``.
    """
    n = int(sections)
    cx, cy = center
    ro0 = np.broadcast_to(np.asarray(r0, dtype=np.float64), (2,))
    ro1 = np.broadcast_to(np.asarray(r1, dtype=np.float64), (2,))
    v = np.vstack([_ring(cx, cy, z0, ro0, n, 0.0), _ring(cx, cy, z1, ro1, n, 0.0),
                   _ring(cx, cy, z0, ro0 - thickness, n, 0.0),
                   _ring(cx, cy, z1, ro1 - thickness, n, 0.0)])
    ob, ot, ib, it = 0, n, 2 * n, 3 * n
    k = np.arange(n)
    k1 = (k + 1) % n
    outer = _band(ob, ot, n)
    inner = _band(ib, it, n)[:, ::-1]
    top = np.concatenate([np.column_stack([it + k, ot + k, ot + k1]),
                          np.column_stack([it + k, ot + k1, it + k1])])
    bottom = np.concatenate([np.column_stack([ib + k, ob + k1, ob + k]),
                             np.column_stack([ib + k, ib + k1, ob + k1])])
    return v, np.concatenate([outer, inner, top, bottom])


def rod(p0, p1, radius, sections=SECTIONS) -> Part:
    """Solid cylinder of the given radius between two points."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    v, f = frustum((0.0, 0.0), 0.0, length, radius, sections=sections)
    rot = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / length)[:3, :3]
    return v @ rot.T + p0, f


def transformed(part: Part, matrix) -> Part:
    """Part moved by a 4x4 rigid transform."""
    v, f = part
    m = np.asarray(matrix, dtype=np.float64)
    return v @ m[:3, :3].T + m[:3, 3], f


def _about(R, pivot) -> np.ndarray:
    """4x4 rigid transform turning by the rotation R (3, 3) about the point ``pivot``."""
    p = np.asarray(pivot, dtype=np.float64)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, p - R @ p
    return m


def rot_x(degrees, pivot=(0.0, 0.0, 0.0)):
    """4x4 rotation about the x axis through pivot (positive: +y turns toward +z)."""
    return _about(x_angle_to_matrix(np.radians(degrees)), pivot)


def rot_z(degrees, pivot=(0.0, 0.0, 0.0)):
    """4x4 rotation about the z axis through pivot (positive: +x turns toward +y)."""
    return _about(z_angle_to_matrix(np.radians(degrees)), pivot)


def corners(x, y):
    """The four points (+-x, +-y)."""
    return [(-x, -y), (x, -y), (x, y), (-x, y)]


def legs_at(points, z0, z1, size, round_=False, taper=1.0) -> list:
    """Vertical legs of width/diameter ``size`` centred at points (x, y), from z0 to z1.

    taper < 1 makes them thinner at the bottom.
    """
    legs = []
    for x, y in points:
        if round_:
            legs.append(frustum((x, y), z0, z1, size / 2 * taper, size / 2, sections=12))
        elif taper == 1.0:
            legs.append(box((x - size / 2, y - size / 2, z0), (x + size / 2, y + size / 2, z1)))
        else:
            r = size / 2 * np.sqrt(2.0)
            legs.append(frustum((x, y), z0, z1, r * taper, r, sections=4, phase=np.pi / 4))
    return legs


def coin(rng, p) -> bool:
    """True with probability p."""
    return bool(rng.random() < p)


# ----------------------------------------------------------------------------
# Furniture sub-assemblies shared by several classes
# ----------------------------------------------------------------------------

def pedestal(rng, top_z, reach, column_r, spokes, casters) -> list:
    """Central column up to top_z on a disc (spokes=0) or a star of feet of radius ``reach``."""
    u = rng.uniform
    parts = []
    if spokes == 0:
        dt = u(0.015, 0.035)
        parts.append(frustum((0, 0), 0.0, dt, reach, reach * u(0.8, 1.0), ROUND_SECTIONS))
        zb = dt
    else:
        zc = u(0.04, 0.07) if casters else 0.0
        sh, sw = u(0.03, 0.05), u(0.03, 0.06)
        phase = u(0.0, 360.0)
        for k in range(spokes):
            a = phase + 360.0 * k / spokes
            parts.append(transformed(box((0, -sw / 2, zc), (reach, sw / 2, zc + sh)), rot_z(a)))
            if casters:
                c = 0.9 * reach * np.array([np.cos(np.radians(a)), np.sin(np.radians(a))])
                parts.append(frustum(c, 0.0, zc + 0.005, 0.018, 0.025, SMALL_SECTIONS))
        parts.append(frustum((0, 0), zc, zc + sh * 1.3, column_r * 1.7, sections=SECTIONS))
        zb = zc + sh
    parts.append(frustum((0, 0), zb, top_z + 0.005, column_r, sections=SECTIONS))
    return parts


def pick_handle(rng) -> str:
    return str(rng.choice(["knob", "knobs", "bar", "none"], p=[0.35, 0.2, 0.35, 0.1]))


def _handle(style, x0, x1, zc, y_face) -> list:
    """Handle(s) on a drawer front spanning [x0, x1] whose front face is at y_face."""
    xc, w = (x0 + x1) / 2, x1 - x0
    if style == "bar":
        hw = min(0.14, 0.4 * w) / 2
        return [box((xc - hw, y_face - 0.022, zc - 0.008), (xc + hw, y_face + 0.001, zc + 0.008))]
    if style in ("knob", "knobs"):
        xs = [xc] if style == "knob" or w < 0.3 else [xc - w / 4, xc + w / 4]
        return [rod((x, y_face + 0.001, zc), (x, y_face - 0.025, zc), 0.013, SMALL_SECTIONS) for x in xs]
    return []


def drawer_fronts(rng, x0, x1, z0, z1, y_face, cols_per_row, handle, graduated=1.0) -> list:
    """Drawer fronts: slabs protruding toward -y from the face y = y_face.

    Row i (from the bottom) has cols_per_row[i] fronts over [x0, x1]; rows fill
    [z0, z1], lower rows ``graduated`` times taller than the row above.
    """
    u = rng.uniform
    gap, ft = u(0.004, 0.014), u(0.012, 0.025)
    rows = len(cols_per_row)
    heights = graduated ** np.arange(rows)[::-1].astype(float)
    zs = z0 + np.concatenate([[0.0], np.cumsum(heights / heights.sum() * (z1 - z0))])
    parts = []
    for i, cols in enumerate(cols_per_row):
        xs = np.linspace(x0, x1, cols + 1)
        for j in range(cols):
            a = (xs[j] + gap / 2, zs[i] + gap / 2)
            b = (xs[j + 1] - gap / 2, zs[i + 1] - gap / 2)
            parts.append(box((a[0], y_face - ft, a[1]), (b[0], y_face + 0.001, b[1])))
            zc = (a[1] + b[1]) / 2 if zs[i + 1] - zs[i] < 0.25 else b[1] - 0.06
            parts += _handle(handle, a[0], b[0], zc, y_face - ft)
    return parts


def drawer_box(rng, x0, x1, y0, y1, z0, z1, cols_per_row, handle, graduated=1.0) -> list:
    """Closed carcass [x0,x1]x[y0,y1]x[z0,z1] with drawer fronts on its -y face (y = y0)."""
    x0, x1 = min(x0, x1), max(x0, x1)
    fw = rng.uniform(0.012, 0.035)   # carcass frame around the fronts
    parts = [box((x0, y0, z0), (x1, y1, z1))]
    return parts + drawer_fronts(rng, x0 + fw, x1 - fw, z0 + fw, z1 - fw, y0,
                                  cols_per_row, handle, graduated)


def open_box(x0, x1, y0, y1, z0, z1, pt, shelves=()) -> list:
    """Open-fronted carcass (bottom, top, sides, back; open toward -y) with shelves at heights."""
    parts = [box((x0, y0, z0), (x1, y1, z0 + pt)), box((x0, y0, z1 - pt), (x1, y1, z1)),
             box((x0, y0, z0), (x0 + pt, y1, z1)), box((x1 - pt, y0, z0), (x1, y1, z1)),
             box((x0, y1 - pt, z0), (x1, y1, z1))]
    parts += [box((x0, y0 + 0.02, z - pt / 2), (x1, y1, z + pt / 2)) for z in shelves]
    return parts


def storage_base(rng, kind, x0, x1, y0, y1):
    """Short legs, a recessed plinth or nothing under a cabinet; returns (parts, carcass bottom z)."""
    u = rng.uniform
    if kind == "legs":
        lh, s, ins = u(0.05, 0.16), u(0.03, 0.05), u(0.0, 0.03)
        pts = corners((x1 - x0) / 2 - s / 2 - ins, (y1 - y0) / 2 - s / 2 - ins)
        pts = [((x0 + x1) / 2 + x, (y0 + y1) / 2 + y) for x, y in pts]
        return legs_at(pts, 0.0, lh + 0.005, s, round_=coin(rng, 0.4),
                       taper=u(0.5, 1.0) if coin(rng, 0.5) else 1.0), lh
    if kind == "plinth":
        ph, r = u(0.04, 0.10), u(0.0, 0.04)
        return [box((x0 + r, y0 + r, 0.0), (x1 - r, y1 - r / 2, ph + 0.005))], ph
    return [], 0.0


def top_slab(rng, x0, x1, y0, y1, z_top):
    """Top board with a small overhang; returns (part, its bottom z)."""
    tt, oh = rng.uniform(0.018, 0.04), rng.uniform(0.0, 0.025)
    return box((x0 - oh, y0 - oh, z_top - tt), (x1 + oh, y1 + oh / 3, z_top)), z_top - tt


def assemble(parts) -> trimesh.Trimesh:
    """Concatenate parts, then move the bounding box to centre x = y = 0 and min z = 0."""
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    v = np.vstack(verts)
    lo, hi = v.min(axis=0), v.max(axis=0)
    v = v - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    return trimesh.Trimesh(vertices=v, faces=np.vstack(faces), process=False)
