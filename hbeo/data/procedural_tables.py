"""The table classes of the procedural furniture: desk and table.

Each builder (:func:`desk`, :func:`table`) takes the object's random stream and a variant name of
:data:`hbeo.data.procedural.VARIANTS` and returns the object's parts (before centring); call them
through :func:`hbeo.data.procedural.generate`, which draws the variant and joins the parts.

Frame: metres, +z up (:mod:`hbeo.data.procedural`). Work tops and rectangular table tops have their
long side along x; a desk's knee hole opens toward -y.
Imports :mod:`hbeo.data.procedural_parts` and numpy only.
"""
from __future__ import annotations

import numpy as np

from hbeo.data.procedural_parts import (ROUND_SECTIONS, box, coin, corners, drawer_box, frustum, legs_at, open_box,
                                        pedestal, pick_handle, storage_base)

__all__ = ["desk", "table"]


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


def desk(rng, variant) -> list:
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


def table(rng, variant) -> list:
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
