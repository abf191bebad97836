"""The storage classes of the procedural furniture: dresser and night stand.

Each builder (:func:`dresser`, :func:`night_stand`) takes the object's random stream and a variant name of
:data:`hbeo.data.procedural.VARIANTS` and returns the object's parts (before centring); call them
through :func:`hbeo.data.procedural.generate`, which draws the variant and joins the parts.

Frame: metres, +z up (:mod:`hbeo.data.procedural`). Drawer fronts and open shelves face -y.
Imports :mod:`hbeo.data.procedural_parts` only.
"""
from __future__ import annotations

from hbeo.data.procedural_parts import coin, drawer_box, open_box, pick_handle, storage_base, top_slab

__all__ = ["dresser", "night_stand"]


def dresser(rng, variant) -> list:
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


def night_stand(rng, variant) -> list:
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
