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
    parts from :mod:`hbeo.data.procedural_parts`: boxes, vertical (elliptical) frusta
    and cylinders, hollow tubes, and cylinders between two points, plus the
    sub-assemblies several classes share (pedestals, drawers, carcasses). Parts may
    overlap; no boolean operations are done. Hollow objects (bathtub basin, toilet bowl) are modelled as floor plus
    walls, so their cavity is open at the top and a voxelizer that fills closed
    cavities leaves it empty. A mesh has hundreds to a few thousand faces and is
    built in about a millisecond.

Determinism
    A mesh is a pure function of ``(cls, split, index, seed, variant)``: its random
    stream is ``np.random.default_rng([seed, class_index(cls), split_code, index])``
    with split_code 0 for "train" and 1 for "test"; any object can be made alone.

Layout
    The ten class builders stay in one file because they are one catalogue: each is
    40-60 lines that read on their own, all follow the frame conventions above, and
    :data:`VARIANTS` / the variant weights at the top must list exactly what they build.
    The part library they share is :mod:`hbeo.data.procedural_parts`.

Imports :mod:`hbeo.conventions`, :mod:`hbeo.data.procedural_parts`, numpy and trimesh.
"""
from __future__ import annotations

import numpy as np
import trimesh

from hbeo.conventions import CLASSES, SPLITS, class_index
from hbeo.data.procedural_parts import (ROUND_SECTIONS, SMALL_SECTIONS, assemble, box, coin, corners, drawer_box,
                                        frustum, legs_at, open_box, pedestal, pick_handle, rod, rot_x, rot_z,
                                        storage_base, top_slab, transformed, tube)

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
        if coin(rng, 0.6):   # feet
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
    if variant != "alcove" and coin(rng, 0.6):   # rim lip, overhanging outward
        o, rt = u(0.01, 0.04), u(0.02, 0.04)
        parts += [box((x0 - o, y0 - o, z1 - rt), (x0 + wt, y1 + o, z1)),
                  box((x1 - wt, y0 - o, z1 - rt), (x1 + o, y1 + o, z1)),
                  box((x0 - o, y0 - o, z1 - rt), (x1 + o, y0 + wt, z1)),
                  box((x0 - o, y1 - wt, z1 - rt), (x1 + o, y1 + o, z1))]
    if coin(rng, 0.4):   # sloped backrest at the -y end: top against the end wall, foot on the floor
        a, zt = u(20.0, 35.0), z1 - 0.02
        length = (zt - zb - ft) / np.cos(np.radians(a)) + 0.02
        slab = box((x0 + wt, y0 + wt, zt - length), (x1 - wt, y0 + wt + 0.03, zt))
        parts.append(transformed(slab, rot_x(a, (0, y0 + wt, zt))))
    return parts + _bath_tap(rng, y1 - wt / 2 - head, z1, wt)


def _bath_tap(rng, y_wall, z_rim, wt) -> list:
    """Optional tap on the +y end: a short column and a spout reaching toward -y."""
    if not coin(rng, 0.5):
        return []
    zt = z_rim + rng.uniform(0.08, 0.16)
    return [rod((0, y_wall, z_rim - 0.01), (0, y_wall, zt), 0.015, SMALL_SECTIONS),
            rod((0, y_wall + 0.01, zt), (0, y_wall - rng.uniform(0.08, 0.15), zt), 0.012, SMALL_SECTIONS)]


def _bed_board(rng, half_w, y_edge, side, height, z_panel) -> list:
    """Head (side=+1) or foot (side=-1) board behind y = side*y_edge: a panel, or posts + panel."""
    u = rng.uniform
    t = u(0.03, 0.1)
    y0, y1 = side * y_edge, side * (y_edge + t)
    if coin(rng, 0.5):
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
        if W > 1.3 and coin(rng, 0.5):
            pts += [(0.0, -(yf - s / 2)), (0.0, yf - s / 2)]
        parts += legs_at(pts, 0.0, zf + 0.005, s, round_=coin(rng, 0.4))
        z_panel = zf
    else:
        r = u(0.0, 0.04)
        parts.append(box((-xf + r, -yf + r, 0.0), (xf - r, yf - r, zm + 0.01)))
        z_panel = 0.0
    if "headboard" in words:
        parts += _bed_board(rng, xf, yf, +1, u(0.8, 1.3), z_panel)
    if "footboard" in words:
        parts += _bed_board(rng, xf, yf, -1, Ht + u(-0.05, 0.25), z_panel)
    if coin(rng, 0.6):   # pillows at the head (+y)
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
    parts = legs_at(corners(x, y), 0.0, top + 0.005, s, round_=coin(rng, 0.4),
                    taper=u(0.6, 1.0) if coin(rng, 0.4) else 1.0)
    if coin(rng, 0.4):
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
    panel = coin(rng, 0.25)
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
        star = coin(rng, 0.8)
        parts += pedestal(rng, h - t - 0.04, u(0.24, 0.33) if star else u(0.2, 0.28), u(0.02, 0.04),
                           spokes=5 if star else 0, casters=star and coin(rng, 0.7))
    if arms == "arms":
        parts += _chair_arms(rng, w, d, h, t, bh, bt, front_posts=(base == "legs"))
    return parts


def _desk_support(rng, kind, side, x_out, y0, y1, top, handle):
    """One side support of a desk (legs, panel or drawer block); returns (parts, inner edge x)."""
    u = rng.uniform
    if kind == "legs":
        s = u(0.035, 0.06)
        x = side * (x_out - s / 2)
        parts = legs_at([(x, y0 + s / 2), (x, y1 - s / 2)], 0.0, top + 0.005, s, round_=coin(rng, 0.4))
        if coin(rng, 0.4):
            z = u(0.05, 0.2)
            parts.append(box((x - s / 3, y0, z), (x + s / 3, y1, z + 0.04)))
        return parts, side * (x_out - s)
    if kind == "panel":
        pt = u(0.02, 0.045)
        return [box((side * x_out, y0, 0.0), (side * (x_out - pt), y1, top + 0.005))], side * (x_out - pt)
    bw = u(0.35, 0.5)
    x0, x1 = side * x_out, side * (x_out - bw)
    base, zb = storage_base(rng, "legs" if coin(rng, 0.3) else "none", min(x0, x1), max(x0, x1), y0, y1)
    rows = [1] * int(rng.integers(2, 5))
    return base + drawer_box(rng, x0, x1, y0, y1, zb, top + 0.005, rows, handle), x1


def _desk(rng, variant) -> list:
    """Thin work top on legs/panels/drawer blocks with a knee hole; optional modesty panel, drawer, hutch."""
    u = rng.uniform
    W, D, H, tt = u(1.0, 1.8), u(0.5, 0.8), u(0.70, 0.80), u(0.02, 0.05)
    oh = u(0.0, 0.03)
    top = H - tt
    x_out, y0, y1 = W / 2 - oh, -D / 2 + oh, D / 2 - oh
    other = "legs" if coin(rng, 0.5) else "panel"
    kinds = {"legs": ("legs", "legs"), "panels": ("panel", "panel"),
             "drawers_one_side": ("block", other) if coin(rng, 0.5) else (other, "block"),
             "drawers_both_sides": ("block", "block")}[variant]
    handle = pick_handle(rng)
    parts = [box((-W / 2, -D / 2, top), (W / 2, D / 2, H))]
    inner = []
    for side, kind in zip((-1, 1), kinds):
        p, x_in = _desk_support(rng, kind, side, x_out, y0, y1, top, handle)
        parts += p
        inner.append(x_in)
    xl, xr = inner
    if coin(rng, 0.5 if variant == "legs" else 0.8):   # modesty panel at the back
        yb = y1 - u(0.0, 0.06)
        parts.append(box((xl, yb - 0.02, top - u(0.25, 0.45)), (xr, yb, top + 0.005)))
    if variant != "legs" and coin(rng, 0.35):          # shallow centre drawer under the top
        dh = u(0.06, 0.1)
        parts += drawer_box(rng, xl + 0.01, xr - 0.01, y0, y0 + D * 0.6, top - dh, top + 0.005, [1], handle)
    if coin(rng, 0.12):                                 # hutch: shelf unit at the back of the top
        hh, hd = u(0.3, 0.5), u(0.2, 0.3)
        parts += open_box(-x_out, x_out, y1 - hd, y1, H - 0.005, H + hh, u(0.015, 0.025))
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
        cols = 2 if W > 0.8 and coin(rng, 0.4) else 1
        rows = int(rng.integers(4, 7))
    cols_per_row = [cols] * rows
    if rows >= 3 and coin(rng, 0.35):   # small drawers in the top row
        cols_per_row[-1] = cols + 1
    x0, x1, y0, y1 = -W / 2, W / 2, -D / 2, D / 2
    parts, zb = storage_base(rng, base, x0, x1, y0, y1)
    slab, z_top = top_slab(rng, x0, x1, y0, y1, H)
    graduated = u(1.0, 1.2) if coin(rng, 0.5) else 1.0
    return parts + [slab] + drawer_box(rng, x0, x1, y0, y1, zb, z_top + 0.005, cols_per_row,
                                        pick_handle(rng), graduated)


def _night_stand(rng, variant) -> list:
    """Small, roughly cubic cabinet: 1-3 drawers, an open shelf, or a drawer over a shelf."""
    u = rng.uniform
    W, D, H = u(0.38, 0.65), u(0.32, 0.50), u(0.42, 0.75)
    x0, x1, y0, y1 = -W / 2, W / 2, -D / 2, D / 2
    base = "legs" if coin(rng, 0.55) else ("plinth" if coin(rng, 0.6) else "none")
    parts, zb = storage_base(rng, base, x0, x1, y0, y1)
    slab, z_top = top_slab(rng, x0, x1, y0, y1, H)
    parts.append(slab)
    handle, pt = pick_handle(rng), u(0.015, 0.03)
    if variant == "drawers":
        return parts + drawer_box(rng, x0, x1, y0, y1, zb, z_top + 0.005, [1] * int(rng.integers(1, 4)), handle)
    if variant == "shelf":
        shelves = [(zb + z_top) / 2] if coin(rng, 0.4) else []
        return parts + open_box(x0, x1, y0, y1, zb, z_top + 0.005, pt, shelves)
    zm = z_top - (z_top - zb) * u(0.3, 0.5)
    return (parts + drawer_box(rng, x0, x1, y0, y1, zm, z_top + 0.005, [1] * int(rng.integers(1, 3)), handle)
            + open_box(x0, x1, y0, y1, zb, zm + 0.005, pt))


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
    if coin(rng, 0.7):   # electronics housing bulging behind the panel
        hw, hh, hd = sw * u(0.25, 0.45), sh * u(0.3, 0.7), u(0.01, 0.05)
        zc = zs + sh * 0.5
        screen.append(box((-hw, 0.0, zc - hh / 2), (hw, pt / 2 + hd, zc + hh / 2)))
        y_back += hd
    if not stand:
        if coin(rng, 0.5):   # wall bracket
            screen.append(box((-0.06, y_back - 0.005, zs + sh * 0.35), (0.06, y_back + 0.02, zs + sh * 0.65)))
        return screen
    z_att = zs + sh * u(0.3, 0.55)
    tilt = u(0.0, 12.0)
    parts = [transformed(p, rot_x(-tilt, (0.0, y_back, z_att))) for p in screen]
    nd = u(0.012, 0.035)
    yn = y_back + nd / 2 - 0.004
    if coin(rng, 0.6):
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
    lh = u(0.03, 0.14) if coin(rng, 0.6) else 0.0
    if variant == "arms2":
        arms = (True, True)
    elif variant == "arms1":
        arms = (True, False) if coin(rng, 0.5) else (False, True)
    elif variant == "arms0":
        arms = (False, False)
    else:
        arms = (coin(rng, 0.8), coin(rng, 0.8))
    xl, xr = -L / 2 + aw * arms[0], L / 2 - aw * arms[1]
    y0, y1 = -D / 2, D / 2
    ext = u(0.5, 0.8) if variant == "l_shape" else 0.0
    cs = 1 if coin(rng, 0.5) else -1          # chaise side (l_shape)
    parts = [box((xl, y0, lh), (xr, y1 - bt, hs - ct)),       # base
             box((-L / 2, y1 - bt, lh), (L / 2, y1, Hb))]     # back
    n = max(1, int(round((xr - xl) / u(0.55, 0.8))))
    edges = np.linspace(xl, xr, n + 1)
    parts += [box((a + 0.005, y0 + u(0.0, 0.02), hs - ct), (b - 0.005, y1 - bt + 0.01, hs))
              for a, b in zip(edges[:-1], edges[1:])]
    if coin(rng, 0.5):   # back cushions
        cd, top = u(0.08, 0.16), Hb - u(0.03, 0.12)
        parts += [box((a + 0.005, y1 - bt - cd, hs - 0.01), (b - 0.005, y1 - bt + 0.01, top))
                  for a, b in zip(edges[:-1], edges[1:])]
    if ext:
        cw = u(0.6, 0.9)
        cx0, cx1 = (xr - cw, xr) if cs > 0 else (xl, xl + cw)
        parts += [box((cx0, y0 - ext, lh), (cx1, y0 + 0.01, hs - ct)),
                  box((cx0 + 0.005, y0 - ext, hs - ct), (cx1 - 0.005, y0 + 0.01, hs))]
    rolled = coin(rng, 0.35)
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
        parts += legs_at(pts, 0.0, lh + 0.005, s, round_=coin(rng, 0.5))
    return [transformed(p, rot_z(-90.0)) for p in parts]   # back +y -> +x


def _table_legs(rng, round_top, hx, hy, top) -> list:
    """3-6 legs under a round or rectangular top of half extents hx, hy; optional apron."""
    u = rng.uniform
    s = u(0.03, 0.07)
    parts = []
    if round_top:
        n = 3 if coin(rng, 0.3) else 4
        f = u(0.55, 0.8)
        a = (-np.pi / 2 if n == 3 else np.pi / 4) + 2 * np.pi * np.arange(n) / n
        pts = list(zip(f * hx * np.cos(a), f * hy * np.sin(a)))
    else:
        ins = u(0.02, 0.12)
        x, y = hx - s / 2 - ins, hy - s / 2 - ins
        pts = corners(x, y)
        if hx > 0.85 and coin(rng, 0.5):
            pts += [(0.0, -y), (0.0, y)]
        if coin(rng, 0.6):   # apron
            ah, at = u(0.05, 0.12), 0.02
            parts += [box((-x, sy - at / 2, top - ah), (x, sy + at / 2, top + 0.005)) for sy in (-y, y)]
            parts += [box((sx - at / 2, -y, top - ah), (sx + at / 2, y, top + 0.005)) for sx in (-x, x)]
    return parts + legs_at(pts, 0.0, top + 0.005, s, round_=coin(rng, 0.5),
                           taper=u(0.6, 1.0) if coin(rng, 0.3) else 1.0)


def _table_pedestal(rng, round_top, hx, hy, top) -> list:
    """One central column on a disc/star, or (long rectangular tops) two trestle ends."""
    u = rng.uniform
    if not round_top and hx > 0.6 and coin(rng, 0.7):
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
    return pedestal(rng, top, min(hx, hy) * u(0.45, 0.8), u(0.04, 0.09), spokes, casters=False)


def _table(rng, variant) -> list:
    """Rectangular or round/oval top (dining or coffee height) on legs or a pedestal."""
    u = rng.uniform
    shape, base = variant.split("/")
    coffee = coin(rng, 0.25)
    H, tt = (u(0.38, 0.50) if coffee else u(0.70, 0.78)), u(0.02, 0.06)
    if shape == "rect":
        hx = (u(0.8, 1.4) if coffee else u(0.8, 2.0)) / 2
        hy = float(np.clip(2 * hx * u(0.45, 0.95), 0.45, 1.1)) / 2
        parts = [box((-hx, -hy, H - tt), (hx, hy, H))]
    else:
        hx = u(0.3, 0.55) if coffee else u(0.35, 0.65)
        hy = hx if coin(rng, 0.6) else hx * u(0.6, 0.9)
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
    parts.append(box((-cw, ry - t / 2, 0.0 if coin(rng, 0.5) else zb), (cw, ty0 + td * 0.5, tz0 + 0.02)))
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
    mesh = assemble(_BUILDERS[cls](rng, variant))
    mesh.metadata.update({"class": cls, "variant": f"{cls}/{variant}", "split": split,
                          "index": int(index), "seed": int(seed)})
    return mesh
