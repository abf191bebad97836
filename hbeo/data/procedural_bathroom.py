"""The bathroom classes of the procedural furniture: bathtub and toilet.

Each builder (:func:`bathtub`, :func:`toilet`) takes the object's random stream and a variant name of
:data:`hbeo.data.procedural.VARIANTS` and returns the object's parts (before centring); call them
through :func:`hbeo.data.procedural.generate`, which draws the variant and joins the parts.

Frame: metres, +z up (:mod:`hbeo.data.procedural`). Both are hollow (a floor plus walls, open at the
top); the bathtub's long axis runs along y, its tap end and the toilet's cistern are toward +y.
Imports :mod:`hbeo.data.procedural_parts` and numpy only.
"""
from __future__ import annotations

import numpy as np

from hbeo.data.procedural_parts import (ROUND_SECTIONS, SMALL_SECTIONS, box, coin, corners, frustum, rod, rot_x,
                                        transformed, tube)

__all__ = ["bathtub", "toilet"]


def bathtub(rng, variant) -> list:
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


def toilet(rng, variant) -> list:
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
