"""Procedural ModelNet10-like furniture: the embedded default dataset.

``generate(cls, split, index, seed=0)`` builds one mesh of a ModelNet10 class from
parameterized parts; it is used instead of the real ModelNet10 meshes when nothing
has been downloaded. Every class has several structural variants (:data:`VARIANTS`),
each with continuous random sizes and proportions, so that a class is a
distribution of shapes, not a template.

Units
    Metres, realistic sizes (chair seats ~0.45 m high, beds ~2 m long, ...).

Frame (ModelNet's per-class alignment, see :mod:`hbeo.conventions`)
    Right-handed, +z up. Every mesh rests on z = 0 (its minimum z is exactly 0) and
    its bounding box is centred on x = y = 0.

    * chair, bed, toilet: the back (chair back, headboard, cistern) is toward +y;
      the object faces -y.
    * sofa: the back is toward +x; the sofa faces -x (its length runs along y).
    * desk, dresser, night_stand, monitor, bathtub, table: the front (drawer
      fronts, the screen, the side a person stands at) faces -y.
    * bed and bathtub: the long axis runs along y. Rectangular tables and desks
      have their long side along x.

Meshes
    A mesh is the concatenation of closed (watertight, outward-wound) primitive
    parts: boxes, vertical (elliptical) frusta and cylinders, hollow tubes, and
    cylinders between two points. Parts may overlap; no boolean operations are
    done. Hollow objects (bathtub basin, toilet bowl) are modelled as floor plus
    walls, so their cavity is open at the top and a voxelizer that fills closed
    cavities leaves it empty. A mesh has hundreds to a few thousand faces and is
    built in about a millisecond.

Determinism
    A mesh is a pure function of ``(cls, split, index, seed, variant)``: its random
    stream is ``np.random.default_rng([seed, class_index(cls), split_code, index])``
    with split_code 0 for "train" and 1 for "test"; any object can be made alone.
"""
from __future__ import annotations

import numpy as np
import trimesh

from hbeo.conventions import CLASSES, SPLITS, class_index

__all__ = ["VARIANTS", "VERSION", "generate"]

#: Generator version: bump whenever the geometry produced for some arguments changes
#: (it is part of the dataset fingerprint, so caches of the old shapes are not reused).
VERSION = 1

#: Structural variants per class; ``generate(..., variant=name)`` forces one.
VARIANTS: dict[str, tuple[str, ...]] = {
    "bathtub": ("rect", "rect/feet", "oval", "alcove"),
    "bed": ("legs", "legs/headboard", "legs/headboard/footboard",
            "base", "base/headboard", "base/headboard/footboard"),
    "chair": tuple(f"{a}/{b}/{c}" for a in ("noarms", "arms")
                   for b in ("legs", "pedestal") for c in ("straight", "slanted")),
    "desk": ("legs", "panels", "drawers_one_side", "drawers_both_sides"),
    "dresser": ("wide/legs", "wide/plinth", "tall/legs", "tall/plinth"),
    "monitor": ("stand/plate", "stand/disc", "wall", "crt"),
    "night_stand": ("drawers", "shelf", "drawer_shelf"),
    "sofa": ("arms2", "arms1", "arms0", "l_shape"),
    "table": ("rect/legs", "rect/pedestal", "round/legs", "round/pedestal"),
    "toilet": ("seat", "seat/lid_up", "seat/lid_down", "no_seat"),
}


def _chair_weights() -> tuple[float, ...]:
    p = {"arms": 0.35, "noarms": 0.65, "pedestal": 0.3, "legs": 0.7, "slanted": 0.4, "straight": 0.6}
    return tuple(float(np.prod([p[w] for w in v.split("/")])) for v in VARIANTS["chair"])


#: Relative frequency of each variant (uniform where a class is not listed).
_WEIGHTS: dict[str, tuple[float, ...]] = {
    "bed": (0.1, 0.25, 0.2, 0.1, 0.2, 0.15),
    "chair": _chair_weights(),
    "desk": (0.25, 0.2, 0.3, 0.25),
    "monitor": (0.4, 0.25, 0.15, 0.2),
    "night_stand": (0.55, 0.2, 0.25),
    "sofa": (0.5, 0.15, 0.1, 0.25),
    "toilet": (0.35, 0.3, 0.25, 0.1),
}

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


def rot_x(degrees, pivot=(0.0, 0.0, 0.0)):
    """4x4 rotation about the x axis through pivot (positive: +y turns toward +z)."""
    return trimesh.transformations.rotation_matrix(np.radians(degrees), [1, 0, 0], pivot)


def rot_z(degrees, pivot=(0.0, 0.0, 0.0)):
    """4x4 rotation about the z axis through pivot (positive: +x turns toward +y)."""
    return trimesh.transformations.rotation_matrix(np.radians(degrees), [0, 0, 1], pivot)


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


def _coin(rng, p) -> bool:
    return bool(rng.random() < p)


# ----------------------------------------------------------------------------
# Shared furniture sub-assemblies
# ----------------------------------------------------------------------------

def _pedestal(rng, top_z, reach, column_r, spokes, casters) -> list:
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


def _pick_handle(rng) -> str:
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


def _drawer_fronts(rng, x0, x1, z0, z1, y_face, cols_per_row, handle, graduated=1.0) -> list:
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


def _drawer_box(rng, x0, x1, y0, y1, z0, z1, cols_per_row, handle, graduated=1.0) -> list:
    """Closed carcass [x0,x1]x[y0,y1]x[z0,z1] with drawer fronts on its -y face (y = y0)."""
    x0, x1 = min(x0, x1), max(x0, x1)
    fw = rng.uniform(0.012, 0.035)   # carcass frame around the fronts
    parts = [box((x0, y0, z0), (x1, y1, z1))]
    return parts + _drawer_fronts(rng, x0 + fw, x1 - fw, z0 + fw, z1 - fw, y0,
                                  cols_per_row, handle, graduated)


def _open_box(x0, x1, y0, y1, z0, z1, pt, shelves=()) -> list:
    """Open-fronted carcass (bottom, top, sides, back; open toward -y) with shelves at heights."""
    parts = [box((x0, y0, z0), (x1, y1, z0 + pt)), box((x0, y0, z1 - pt), (x1, y1, z1)),
             box((x0, y0, z0), (x0 + pt, y1, z1)), box((x1 - pt, y0, z0), (x1, y1, z1)),
             box((x0, y1 - pt, z0), (x1, y1, z1))]
    parts += [box((x0, y0 + 0.02, z - pt / 2), (x1, y1, z + pt / 2)) for z in shelves]
    return parts


def _storage_base(rng, kind, x0, x1, y0, y1):
    """Short legs, a recessed plinth or nothing under a cabinet; returns (parts, carcass bottom z)."""
    u = rng.uniform
    if kind == "legs":
        lh, s, ins = u(0.05, 0.16), u(0.03, 0.05), u(0.0, 0.03)
        pts = corners((x1 - x0) / 2 - s / 2 - ins, (y1 - y0) / 2 - s / 2 - ins)
        pts = [((x0 + x1) / 2 + x, (y0 + y1) / 2 + y) for x, y in pts]
        return legs_at(pts, 0.0, lh + 0.005, s, round_=_coin(rng, 0.4),
                       taper=u(0.5, 1.0) if _coin(rng, 0.5) else 1.0), lh
    if kind == "plinth":
        ph, r = u(0.04, 0.10), u(0.0, 0.04)
        return [box((x0 + r, y0 + r, 0.0), (x1 - r, y1 - r / 2, ph + 0.005))], ph
    return [], 0.0


def _top_slab(rng, x0, x1, y0, y1, z_top):
    """Top board with a small overhang; returns (part, its bottom z)."""
    tt, oh = rng.uniform(0.018, 0.04), rng.uniform(0.0, 0.025)
    return box((x0 - oh, y0 - oh, z_top - tt), (x1 + oh, y1 + oh / 3, z_top)), z_top - tt


# ----------------------------------------------------------------------------
# Classes: each builder returns a list of parts (before centring)
# ----------------------------------------------------------------------------

def _bathtub(rng, variant) -> list:
    """Basin with long axis y: floor + walls, open top; rim, feet, tap, backrest optional."""
    u = rng.uniform
    L, W, H = u(1.4, 1.9), u(0.65, 0.9), u(0.42, 0.62)
    wt, ft = u(0.03, 0.08), u(0.03, 0.08)
    parts = []
    if variant == "oval":
        zb = u(0.06, 0.15)
        shrink = u(0.75, 0.95)
        rb, rt = (W / 2 * shrink, L / 2 * shrink), (W / 2, L / 2)
        parts.append(tube((0, 0), zb, zb + H, rb, rt, wt))
        parts.append(frustum((0, 0), zb, zb + ft, rb, sections=ROUND_SECTIONS))
        if _coin(rng, 0.6):   # feet
            parts += [frustum((x, y), 0.0, zb + 0.01, 0.025, 0.045, SMALL_SECTIONS)
                      for x, y in corners(rb[0] * 0.6, rb[1] * 0.75)]
        else:                 # skirt / plinth
            parts.append(frustum((0, 0), 0.0, zb + 0.01, (rb[0] * 0.8, rb[1] * 0.8), sections=ROUND_SECTIONS))
        return parts + _bath_tap(rng, L / 2 * 0.97, zb + H, wt)
    zb = u(0.06, 0.16) if variant == "rect/feet" else 0.0
    head = 0.0
    if variant == "alcove":
        wt, head = u(0.07, 0.14), u(0.15, 0.3)
    x0, x1, y0, y1, z1 = -W / 2, W / 2, -L / 2, L / 2, zb + H
    parts += [box((x0, y0, zb), (x1, y1, zb + ft)),
              box((x0, y0, zb), (x0 + wt, y1, z1)), box((x1 - wt, y0, zb), (x1, y1, z1)),
              box((x0, y0, zb), (x1, y0 + wt, z1)), box((x0, y1 - wt - head, zb), (x1, y1, z1))]
    if variant == "rect/feet":
        parts += [frustum((x, y), 0.0, zb + 0.01, 0.025, 0.04, SMALL_SECTIONS)
                  for x, y in corners(W / 2 - 0.08, L / 2 - 0.12)]
    if variant != "alcove" and _coin(rng, 0.6):   # rim lip, overhanging outward
        o, rt = u(0.01, 0.04), u(0.02, 0.04)
        parts += [box((x0 - o, y0 - o, z1 - rt), (x0 + wt, y1 + o, z1)),
                  box((x1 - wt, y0 - o, z1 - rt), (x1 + o, y1 + o, z1)),
                  box((x0 - o, y0 - o, z1 - rt), (x1 + o, y0 + wt, z1)),
                  box((x0 - o, y1 - wt, z1 - rt), (x1 + o, y1 + o, z1))]
    if _coin(rng, 0.4):   # sloped backrest at the -y end: top against the end wall, foot on the floor
        a, zt = u(20.0, 35.0), z1 - 0.02
        length = (zt - zb - ft) / np.cos(np.radians(a)) + 0.02
        slab = box((x0 + wt, y0 + wt, zt - length), (x1 - wt, y0 + wt + 0.03, zt))
        parts.append(transformed(slab, rot_x(a, (0, y0 + wt, zt))))
    return parts + _bath_tap(rng, y1 - wt / 2 - head, z1, wt)


def _bath_tap(rng, y_wall, z_rim, wt) -> list:
    """Optional tap on the +y end: a short column and a spout reaching toward -y."""
    if not _coin(rng, 0.5):
        return []
    zt = z_rim + rng.uniform(0.08, 0.16)
    return [rod((0, y_wall, z_rim - 0.01), (0, y_wall, zt), 0.015, SMALL_SECTIONS),
            rod((0, y_wall + 0.01, zt), (0, y_wall - rng.uniform(0.08, 0.15), zt), 0.012, SMALL_SECTIONS)]


def _bed_board(rng, half_w, y_edge, side, height, z_panel) -> list:
    """Head (side=+1) or foot (side=-1) board behind y = side*y_edge: a panel, or posts + panel."""
    u = rng.uniform
    t = u(0.03, 0.1)
    y0, y1 = side * y_edge, side * (y_edge + t)
    if _coin(rng, 0.5):
        return [box((-half_w, y0, 0.0), (half_w, y1, height))]
    ps = u(0.05, 0.1)
    posts = [box((s * half_w, y0 - side * 0.01, 0.0), (s * (half_w - ps), y1 + side * 0.01, height + u(0.0, 0.08)))
             for s in (-1, 1)]
    return posts + [box((-half_w + ps, y0, z_panel), (half_w - ps, y1, height))]


def _bed(rng, variant) -> list:
    """Mattress on a frame with legs or on a solid base; optional head/foot boards and pillows."""
    u = rng.uniform
    words = variant.split("/")
    L = u(1.9, 2.2)
    W = min(u(0.9, 2.0), L - 0.1)
    mt, Ht, oh = u(0.15, 0.30), u(0.42, 0.65), u(0.0, 0.05)
    zm = Ht - mt                       # mattress bottom
    xf, yf = W / 2 + oh, L / 2 + oh    # frame half extents
    parts = [box((-W / 2, -L / 2, zm), (W / 2, L / 2, Ht))]
    if words[0] == "legs":
        zf = max(zm - u(0.06, 0.2), 0.08)
        parts.append(box((-xf, -yf, zf), (xf, yf, zm + 0.01)))
        s = u(0.04, 0.08)
        pts = corners(xf - s / 2, yf - s / 2)
        if W > 1.3 and _coin(rng, 0.5):
            pts += [(0.0, -(yf - s / 2)), (0.0, yf - s / 2)]
        parts += legs_at(pts, 0.0, zf + 0.005, s, round_=_coin(rng, 0.4))
        z_panel = zf
    else:
        r = u(0.0, 0.04)
        parts.append(box((-xf + r, -yf + r, 0.0), (xf - r, yf - r, zm + 0.01)))
        z_panel = 0.0
    if "headboard" in words:
        parts += _bed_board(rng, xf, yf, +1, u(0.8, 1.3), z_panel)
    if "footboard" in words:
        parts += _bed_board(rng, xf, yf, -1, Ht + u(-0.05, 0.25), z_panel)
    if _coin(rng, 0.6):   # pillows at the head (+y)
        n = 1 if W < 1.2 else 2
        pw, pd, pt = (W - 0.1) / n, u(0.3, 0.45), u(0.08, 0.15)
        for i in range(n):
            xa = -W / 2 + 0.05 + i * pw
            parts.append(box((xa + 0.02, L / 2 - 0.05 - pd, Ht - 0.01), (xa + pw - 0.02, L / 2 - 0.05, Ht + pt)))
    return parts


def _chair_back(rng, w, d, h, bh, bt) -> list:
    """Upright back (before tilting) over the rear seat edge: panel, posts + rails, or posts + slats."""
    u = rng.uniform
    y0, y1 = d / 2 - bt, d / 2
    style = int(rng.integers(3))
    if style == 0:
        ins = u(0.0, 0.03)
        return [box((-w / 2 + ins, y0, h - 0.01), (w / 2 - ins, y1, h + bh))]
    pw, rh = u(0.03, 0.05), u(0.05, 0.14)
    xp = w / 2 - pw / 2
    parts = [box((s * xp - pw / 2, y0, h - 0.01), (s * xp + pw / 2, y1, h + bh)) for s in (-1, 1)]
    parts.append(box((-xp, y0, h + bh - rh), (xp, y1, h + bh)))
    if style == 1:   # horizontal rails
        for z in np.linspace(h + 0.06, h + bh - rh, int(rng.integers(1, 3)) + 1)[:-1]:
            parts.append(box((-xp, y0 + bt * 0.2, z), (xp, y1 - bt * 0.2, z + 0.04)))
    else:            # vertical slats
        n = int(rng.integers(2, 6))
        sw = u(0.015, 0.04)
        for x in np.linspace(-xp, xp, n + 2)[1:-1]:
            parts.append(box((x - sw / 2, y0 + bt * 0.2, h - 0.01), (x + sw / 2, y1 - bt * 0.2, h + bh - rh)))
    return parts


def _chair_legs(rng, w, d, top) -> list:
    """Four legs under the seat corners, optional stretchers."""
    u = rng.uniform
    s, ins = u(0.025, 0.05), u(0.0, 0.03)
    x, y = w / 2 - s / 2 - ins, d / 2 - s / 2 - ins
    parts = legs_at(corners(x, y), 0.0, top + 0.005, s, round_=_coin(rng, 0.4),
                    taper=u(0.6, 1.0) if _coin(rng, 0.4) else 1.0)
    if _coin(rng, 0.4):
        z, st = u(0.10, 0.22), s * 0.6
        parts += [box((sx - st / 2, -y, z), (sx + st / 2, y, z + st)) for sx in (-x, x)]
        parts.append(box((-x, y - st / 2, z), (x, y + st / 2, z + st)))
    return parts


def _chair_arms(rng, w, d, h, t, bh, bt, front_posts) -> list:
    """Two arm rests above the seat sides on front posts, central posts or solid side panels."""
    u = rng.uniform
    aw, at, pw = u(0.04, 0.08), u(0.025, 0.05), u(0.025, 0.045)
    ah = min(u(0.18, 0.26), bh - 0.1)
    xa = w / 2 + u(-0.5, 0.4) * aw
    yf = -d / 2 + u(0.0, 0.06)
    panel = _coin(rng, 0.25)
    parts = []
    for s in (-1, 1):
        x = s * xa
        parts.append(box((x - aw / 2, yf, h + ah - at), (x + aw / 2, d / 2 - bt / 2, h + ah)))
        if panel:
            parts.append(box((x - aw * 0.35, yf + 0.02, h - t), (x + aw * 0.35, d / 2 - bt, h + ah - at)))
        else:
            py = yf + pw / 2 + 0.01 if front_posts else u(-0.08, 0.02)
            parts.append(box((x - pw / 2, py - pw / 2, h - t), (x + pw / 2, py + pw / 2, h + ah - at)))
    return parts


def _chair(rng, variant) -> list:
    """Seat, back toward +y (optionally tilted back), four legs or a pedestal, optional arms."""
    u = rng.uniform
    arms, base, back = variant.split("/")
    w, d, h, t = u(0.40, 0.56), u(0.40, 0.52), u(0.40, 0.50), u(0.03, 0.08)
    bh, bt = u(0.32, 0.60), u(0.02, 0.06)
    tilt = u(8.0, 22.0) if back == "slanted" else u(0.0, 3.0)
    parts = [box((-w / 2, -d / 2, h - t), (w / 2, d / 2, h))]
    pivot = (0.0, d / 2 - bt, h)
    parts += [transformed(p, rot_x(-tilt, pivot)) for p in _chair_back(rng, w, d, h, bh, bt)]
    if base == "legs":
        parts += _chair_legs(rng, w, d, h - t)
    else:
        parts.append(box((-0.1, -0.1, h - t - 0.04), (0.1, 0.1, h - t + 0.005)))   # seat plate
        star = _coin(rng, 0.8)
        parts += _pedestal(rng, h - t - 0.04, u(0.24, 0.33) if star else u(0.2, 0.28), u(0.02, 0.04),
                           spokes=5 if star else 0, casters=star and _coin(rng, 0.7))
    if arms == "arms":
        parts += _chair_arms(rng, w, d, h, t, bh, bt, front_posts=(base == "legs"))
    return parts


def _desk_support(rng, kind, side, x_out, y0, y1, top, handle):
    """One side support of a desk (legs, panel or drawer block); returns (parts, inner edge x)."""
    u = rng.uniform
    if kind == "legs":
        s = u(0.035, 0.06)
        x = side * (x_out - s / 2)
        parts = legs_at([(x, y0 + s / 2), (x, y1 - s / 2)], 0.0, top + 0.005, s, round_=_coin(rng, 0.4))
        if _coin(rng, 0.4):
            z = u(0.05, 0.2)
            parts.append(box((x - s / 3, y0, z), (x + s / 3, y1, z + 0.04)))
        return parts, side * (x_out - s)
    if kind == "panel":
        pt = u(0.02, 0.045)
        return [box((side * x_out, y0, 0.0), (side * (x_out - pt), y1, top + 0.005))], side * (x_out - pt)
    bw = u(0.35, 0.5)
    x0, x1 = side * x_out, side * (x_out - bw)
    base, zb = _storage_base(rng, "legs" if _coin(rng, 0.3) else "none", min(x0, x1), max(x0, x1), y0, y1)
    rows = [1] * int(rng.integers(2, 5))
    return base + _drawer_box(rng, x0, x1, y0, y1, zb, top + 0.005, rows, handle), x1


def _desk(rng, variant) -> list:
    """Thin work top on legs/panels/drawer blocks with a knee hole; optional modesty panel, drawer, hutch."""
    u = rng.uniform
    W, D, H, tt = u(1.0, 1.8), u(0.5, 0.8), u(0.70, 0.80), u(0.02, 0.05)
    oh = u(0.0, 0.03)
    top = H - tt
    x_out, y0, y1 = W / 2 - oh, -D / 2 + oh, D / 2 - oh
    other = "legs" if _coin(rng, 0.5) else "panel"
    kinds = {"legs": ("legs", "legs"), "panels": ("panel", "panel"),
             "drawers_one_side": ("block", other) if _coin(rng, 0.5) else (other, "block"),
             "drawers_both_sides": ("block", "block")}[variant]
    handle = _pick_handle(rng)
    parts = [box((-W / 2, -D / 2, top), (W / 2, D / 2, H))]
    inner = []
    for side, kind in zip((-1, 1), kinds):
        p, x_in = _desk_support(rng, kind, side, x_out, y0, y1, top, handle)
        parts += p
        inner.append(x_in)
    xl, xr = inner
    if _coin(rng, 0.5 if variant == "legs" else 0.8):   # modesty panel at the back
        yb = y1 - u(0.0, 0.06)
        parts.append(box((xl, yb - 0.02, top - u(0.25, 0.45)), (xr, yb, top + 0.005)))
    if variant != "legs" and _coin(rng, 0.35):          # shallow centre drawer under the top
        dh = u(0.06, 0.1)
        parts += _drawer_box(rng, xl + 0.01, xr - 0.01, y0, y0 + D * 0.6, top - dh, top + 0.005, [1], handle)
    if _coin(rng, 0.12):                                 # hutch: shelf unit at the back of the top
        hh, hd = u(0.3, 0.5), u(0.2, 0.3)
        parts += _open_box(-x_out, x_out, y1 - hd, y1, H - 0.005, H + hh, u(0.015, 0.025))
    return parts


def _dresser(rng, variant) -> list:
    """Chest of drawers, wide and low or tall and narrow, on short legs or a plinth."""
    u = rng.uniform
    shape, base = variant.split("/")
    if shape == "wide":
        W, H, D = u(0.9, 1.7), u(0.68, 1.05), u(0.40, 0.58)
        cols = int(rng.integers(2, 4)) if W > 1.3 else int(rng.integers(1, 3))
        rows = int(rng.integers(2, 5))
    else:
        W, H, D = u(0.55, 1.0), u(1.05, 1.6), u(0.40, 0.55)
        cols = 2 if W > 0.8 and _coin(rng, 0.4) else 1
        rows = int(rng.integers(4, 7))
    cols_per_row = [cols] * rows
    if rows >= 3 and _coin(rng, 0.35):   # small drawers in the top row
        cols_per_row[-1] = cols + 1
    x0, x1, y0, y1 = -W / 2, W / 2, -D / 2, D / 2
    parts, zb = _storage_base(rng, base, x0, x1, y0, y1)
    slab, z_top = _top_slab(rng, x0, x1, y0, y1, H)
    graduated = u(1.0, 1.2) if _coin(rng, 0.5) else 1.0
    return parts + [slab] + _drawer_box(rng, x0, x1, y0, y1, zb, z_top + 0.005, cols_per_row,
                                        _pick_handle(rng), graduated)


def _night_stand(rng, variant) -> list:
    """Small, roughly cubic cabinet: 1-3 drawers, an open shelf, or a drawer over a shelf."""
    u = rng.uniform
    W, D, H = u(0.38, 0.65), u(0.32, 0.50), u(0.42, 0.75)
    x0, x1, y0, y1 = -W / 2, W / 2, -D / 2, D / 2
    base = "legs" if _coin(rng, 0.55) else ("plinth" if _coin(rng, 0.6) else "none")
    parts, zb = _storage_base(rng, base, x0, x1, y0, y1)
    slab, z_top = _top_slab(rng, x0, x1, y0, y1, H)
    parts.append(slab)
    handle, pt = _pick_handle(rng), u(0.015, 0.03)
    if variant == "drawers":
        return parts + _drawer_box(rng, x0, x1, y0, y1, zb, z_top + 0.005, [1] * int(rng.integers(1, 4)), handle)
    if variant == "shelf":
        shelves = [(zb + z_top) / 2] if _coin(rng, 0.4) else []
        return parts + _open_box(x0, x1, y0, y1, zb, z_top + 0.005, pt, shelves)
    zm = z_top - (z_top - zb) * u(0.3, 0.5)
    return (parts + _drawer_box(rng, x0, x1, y0, y1, zm, z_top + 0.005, [1] * int(rng.integers(1, 3)), handle)
            + _open_box(x0, x1, y0, y1, zb, zm + 0.005, pt))


def _crt(rng) -> list:
    """Old CRT monitor: bezel facing -y, tapered tube body behind it, small base."""
    u = rng.uniform
    sw = u(0.32, 0.5)
    sh, bd, depth, taper = sw * u(0.72, 0.8), u(0.03, 0.06), sw * u(0.8, 1.1), u(0.45, 0.7)
    base_h = u(0.0, 0.05)
    zs = base_h + u(0.0, 0.02)
    parts = [box((-sw / 2, 0.0, zs), (sw / 2, bd, zs + sh))]
    r0 = np.sqrt(2.0) * np.array([sw, sh]) * 0.95 / 2
    body = frustum((0, 0), 0.0, depth, r0, r0 * taper, sections=4, phase=np.pi / 4)
    body = transformed(body, rot_x(-90.0))   # local +z -> +y
    parts.append((body[0] + [0.0, bd - 0.005, zs + sh / 2], body[1]))
    if base_h > 0.0:
        parts.append(box((-sw * 0.3, bd, 0.0), (sw * 0.3, bd + depth * 0.6, zs + 0.02)))
    return parts


def _monitor(rng, variant) -> list:
    """Flat screen panel (facing -y) on a neck and a plate/disc foot or wall-style; or a CRT."""
    if variant == "crt":
        return _crt(rng)
    u = rng.uniform
    sw, aspect, pt = u(0.35, 0.75), u(1.25, 2.4), u(0.012, 0.04)
    sh = sw / aspect
    stand = variant.startswith("stand")
    ft = u(0.008, 0.025)
    zs = ft + u(0.04, 0.16) if stand else 0.0
    screen = [box((-sw / 2, -pt / 2, zs), (sw / 2, pt / 2, zs + sh))]
    y_back = pt / 2
    if _coin(rng, 0.7):   # electronics housing bulging behind the panel
        hw, hh, hd = sw * u(0.25, 0.45), sh * u(0.3, 0.7), u(0.01, 0.05)
        zc = zs + sh * 0.5
        screen.append(box((-hw, 0.0, zc - hh / 2), (hw, pt / 2 + hd, zc + hh / 2)))
        y_back += hd
    if not stand:
        if _coin(rng, 0.5):   # wall bracket
            screen.append(box((-0.06, y_back - 0.005, zs + sh * 0.35), (0.06, y_back + 0.02, zs + sh * 0.65)))
        return screen
    z_att = zs + sh * u(0.3, 0.55)
    tilt = u(0.0, 12.0)
    parts = [transformed(p, rot_x(-tilt, (0.0, y_back, z_att))) for p in screen]
    nd = u(0.012, 0.035)
    yn = y_back + nd / 2 - 0.004
    if _coin(rng, 0.6):
        nw = u(0.03, 0.1)
        parts.append(box((-nw / 2, yn - nd / 2, ft - 0.003), (nw / 2, yn + nd / 2, z_att + 0.03)))
    else:
        parts.append(frustum((0.0, yn), ft - 0.003, z_att + 0.03, u(0.012, 0.025)))
    if variant == "stand/plate":
        fw = u(0.08, 0.2)
        parts.append(box((-fw, yn - u(0.05, 0.12), 0.0), (fw, yn + u(0.06, 0.14), ft)))
    else:
        rx = u(0.08, 0.15)
        parts.append(frustum((0.0, yn), 0.0, ft, (rx, rx * u(0.6, 1.0)), sections=ROUND_SECTIONS))
    return parts


def _sofa(rng, variant) -> list:
    """Built facing -y with the back at +y, then turned so the back is toward +x."""
    u = rng.uniform
    L, D = u(1.4, 2.4), u(0.8, 1.0)
    hs, Hb = u(0.38, 0.48), u(0.70, 1.0)
    aw, bt, ct = u(0.08, 0.25), u(0.15, 0.28), u(0.08, 0.16)
    ha = min(u(0.52, 0.70), Hb - 0.08 - aw / 2)
    lh = u(0.03, 0.14) if _coin(rng, 0.6) else 0.0
    if variant == "arms2":
        arms = (True, True)
    elif variant == "arms1":
        arms = (True, False) if _coin(rng, 0.5) else (False, True)
    elif variant == "arms0":
        arms = (False, False)
    else:
        arms = (_coin(rng, 0.8), _coin(rng, 0.8))
    xl, xr = -L / 2 + aw * arms[0], L / 2 - aw * arms[1]
    y0, y1 = -D / 2, D / 2
    ext = u(0.5, 0.8) if variant == "l_shape" else 0.0
    cs = 1 if _coin(rng, 0.5) else -1          # chaise side (l_shape)
    parts = [box((xl, y0, lh), (xr, y1 - bt, hs - ct)),       # base
             box((-L / 2, y1 - bt, lh), (L / 2, y1, Hb))]     # back
    n = max(1, int(round((xr - xl) / u(0.55, 0.8))))
    edges = np.linspace(xl, xr, n + 1)
    parts += [box((a + 0.005, y0 + u(0.0, 0.02), hs - ct), (b - 0.005, y1 - bt + 0.01, hs))
              for a, b in zip(edges[:-1], edges[1:])]
    if _coin(rng, 0.5):   # back cushions
        cd, top = u(0.08, 0.16), Hb - u(0.03, 0.12)
        parts += [box((a + 0.005, y1 - bt - cd, hs - 0.01), (b - 0.005, y1 - bt + 0.01, top))
                  for a, b in zip(edges[:-1], edges[1:])]
    if ext:
        cw = u(0.6, 0.9)
        cx0, cx1 = (xr - cw, xr) if cs > 0 else (xl, xl + cw)
        parts += [box((cx0, y0 - ext, lh), (cx1, y0 + 0.01, hs - ct)),
                  box((cx0 + 0.005, y0 - ext, hs - ct), (cx1 - 0.005, y0 + 0.01, hs))]
    rolled = _coin(rng, 0.35)
    for s, has in zip((-1, 1), arms):
        if not has:
            continue
        ya = y0 - (ext if s == cs else 0.0)
        parts.append(box((s * L / 2, ya, lh), (s * (L / 2 - aw), y1, ha)))
        if rolled:
            parts.append(rod((s * (L / 2 - aw / 2), ya, ha), (s * (L / 2 - aw / 2), y1 - bt / 2, ha),
                             aw / 2 * 1.05, 12))
    if lh > 0.0:
        s = u(0.03, 0.06)
        pts = corners(L / 2 - s, D / 2 - s)
        if ext:
            xc = (L / 2 - s) * cs
            pts[0 if cs < 0 else 1] = (xc, y0 - ext + s)
        parts += legs_at(pts, 0.0, lh + 0.005, s, round_=_coin(rng, 0.5))
    return [transformed(p, rot_z(-90.0)) for p in parts]   # back +y -> +x


def _table_legs(rng, round_top, hx, hy, top) -> list:
    """3-6 legs under a round or rectangular top of half extents hx, hy; optional apron."""
    u = rng.uniform
    s = u(0.03, 0.07)
    parts = []
    if round_top:
        n = 3 if _coin(rng, 0.3) else 4
        f = u(0.55, 0.8)
        a = (-np.pi / 2 if n == 3 else np.pi / 4) + 2 * np.pi * np.arange(n) / n
        pts = list(zip(f * hx * np.cos(a), f * hy * np.sin(a)))
    else:
        ins = u(0.02, 0.12)
        x, y = hx - s / 2 - ins, hy - s / 2 - ins
        pts = corners(x, y)
        if hx > 0.85 and _coin(rng, 0.5):
            pts += [(0.0, -y), (0.0, y)]
        if _coin(rng, 0.6):   # apron
            ah, at = u(0.05, 0.12), 0.02
            parts += [box((-x, sy - at / 2, top - ah), (x, sy + at / 2, top + 0.005)) for sy in (-y, y)]
            parts += [box((sx - at / 2, -y, top - ah), (sx + at / 2, y, top + 0.005)) for sx in (-x, x)]
    return parts + legs_at(pts, 0.0, top + 0.005, s, round_=_coin(rng, 0.5),
                           taper=u(0.6, 1.0) if _coin(rng, 0.3) else 1.0)


def _table_pedestal(rng, round_top, hx, hy, top) -> list:
    """One central column on a disc/star, or (long rectangular tops) two trestle ends."""
    u = rng.uniform
    if not round_top and hx > 0.6 and _coin(rng, 0.7):
        xs, cw, fh = hx - u(0.15, 0.35), u(0.05, 0.12), u(0.03, 0.06)
        fl = hy * u(0.7, 0.95)
        parts = []
        for s in (-1, 1):
            x = s * xs
            parts += [box((x - cw / 2, -cw, fh - 0.005), (x + cw / 2, cw, top + 0.005)),
                      box((x - cw * 0.7, -fl, 0.0), (x + cw * 0.7, fl, fh)),
                      box((x - cw * 0.6, -fl * 0.9, top - 0.05), (x + cw * 0.6, fl * 0.9, top + 0.005))]
        z = u(0.15, 0.35)
        return parts + [box((-xs, -cw / 3, z), (xs, cw / 3, z + 0.06))]
    spokes = int(rng.choice([0, 3, 4]))
    return _pedestal(rng, top, min(hx, hy) * u(0.45, 0.8), u(0.04, 0.09), spokes, casters=False)


def _table(rng, variant) -> list:
    """Rectangular or round/oval top (dining or coffee height) on legs or a pedestal."""
    u = rng.uniform
    shape, base = variant.split("/")
    coffee = _coin(rng, 0.25)
    H, tt = (u(0.38, 0.50) if coffee else u(0.70, 0.78)), u(0.02, 0.06)
    if shape == "rect":
        hx = (u(0.8, 1.4) if coffee else u(0.8, 2.0)) / 2
        hy = float(np.clip(2 * hx * u(0.45, 0.95), 0.45, 1.1)) / 2
        parts = [box((-hx, -hy, H - tt), (hx, hy, H))]
    else:
        hx = u(0.3, 0.55) if coffee else u(0.35, 0.65)
        hy = hx if _coin(rng, 0.6) else hx * u(0.6, 0.9)
        parts = [frustum((0, 0), H - tt, H, (hx, hy), sections=ROUND_SECTIONS)]
    support = _table_legs if base == "legs" else _table_pedestal
    return parts + support(rng, shape == "round", hx, hy, H - tt)


def _toilet(rng, variant) -> list:
    """Hollow bowl (open top) on a pedestal, facing -y, with the cistern behind (+y); seat/lid optional."""
    u = rng.uniform
    hr = u(0.36, 0.44)                                 # rim height
    rx, ry = u(0.16, 0.21), u(0.21, 0.29)             # outer rim half widths
    s, bh, t = u(0.6, 0.8), u(0.14, 0.22), u(0.018, 0.035)
    zb = hr - bh                                       # bowl bottom
    fth = u(0.02, 0.04)
    rb = (rx * s, ry * s)
    parts = [tube((0, 0), zb, hr, rb, (rx, ry), t),
             frustum((0, 0), zb - 0.01, zb + fth, rb, sections=ROUND_SECTIONS)]
    py = u(0.0, 0.05)
    pr = (rb[0] * u(0.6, 0.9), rb[1] * u(0.6, 0.9))
    parts.append(frustum((0, py), 0.0, zb + 0.005, (pr[0] * u(1.0, 1.3), pr[1] * u(1.0, 1.2)), pr,
                         sections=ROUND_SECTIONS))
    tw, td, th = u(0.34, 0.5), u(0.14, 0.22), u(0.28, 0.42)
    ty0 = ry * u(0.85, 1.05)
    tz0 = hr + u(-0.05, 0.08)
    lid_top = tz0 + th + u(0.02, 0.035)
    parts += [box((-tw / 2, ty0, tz0), (tw / 2, ty0 + td, tz0 + th)),                       # cistern
              box((-tw / 2 - 0.01, ty0 - 0.01, tz0 + th - 0.005), (tw / 2 + 0.01, ty0 + td + 0.01, lid_top))]
    cw = min(tw / 2, rx) * 0.6   # connector behind the bowl wall, down to the floor or to the bowl bottom
    parts.append(box((-cw, ry - t / 2, 0.0 if _coin(rng, 0.5) else zb), (cw, ty0 + td * 0.5, tz0 + 0.02)))
    if variant == "no_seat":
        return parts
    st, so = u(0.015, 0.03), (rx + u(0.0, 0.015), ry + u(0.0, 0.015))
    parts.append(tube((0, 0), hr - 0.002, hr + st, so, so, u(0.05, 0.09)))
    lt = u(0.012, 0.025)
    if variant == "seat/lid_down":
        parts.append(frustum((0, 0), hr + st - 0.002, hr + st + lt, so, sections=ROUND_SECTIONS))
    elif variant == "seat/lid_up":
        lid = transformed(frustum((0, 0), 0.0, lt, so, sections=ROUND_SECTIONS), rot_x(-90.0))
        yl = min(ty0, so[1]) - lt - 0.005
        parts.append((lid[0] + [0.0, yl, hr + st + so[1]], lid[1]))
    return parts


_BUILDERS = {
    "bathtub": _bathtub, "bed": _bed, "chair": _chair, "desk": _desk, "dresser": _dresser,
    "monitor": _monitor, "night_stand": _night_stand, "sofa": _sofa, "table": _table, "toilet": _toilet,
}
assert set(_BUILDERS) == set(CLASSES) == set(VARIANTS)


# ----------------------------------------------------------------------------
# Public entry point
# ----------------------------------------------------------------------------

def _assemble(parts) -> trimesh.Trimesh:
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


def generate(cls: str, split: str, index: int, seed: int = 0, variant: str | None = None) -> trimesh.Trimesh:
    """One procedural mesh of class ``cls`` (metres, +z up, min z = 0, bbox centred in x, y).

    cls: a ModelNet10 class name; split: "train" or "test"; index >= 0 and seed >= 0
    select the object; variant: one of ``VARIANTS[cls]`` to force a structure
    (the random sizes are unchanged), None to draw it. ``mesh.metadata`` holds
    "class", "variant" (e.g. "chair/arms/pedestal/slanted"), "split", "index", "seed".
    """
    if cls not in CLASSES:
        raise ValueError(f"unknown class {cls!r}; expected one of {', '.join(CLASSES)}")
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"index must be a non-negative integer, got {index!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    names = VARIANTS[cls]
    if variant is not None and variant not in names:
        raise ValueError(f"unknown variant {variant!r} for {cls}; expected one of {', '.join(names)}")
    rng = np.random.default_rng([int(seed), class_index(cls), SPLITS.index(split), int(index)])
    weights = np.asarray(_WEIGHTS.get(cls, (1.0,) * len(names)), dtype=np.float64)
    drawn = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    variant = drawn if variant is None else variant
    mesh = _assemble(_BUILDERS[cls](rng, variant))
    mesh.metadata.update({"class": cls, "variant": f"{cls}/{variant}", "split": split,
                          "index": int(index), "seed": int(seed)})
    return mesh
