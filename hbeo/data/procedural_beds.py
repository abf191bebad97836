"""The bed class of the procedural furniture: a mattress on legs or a base, head and foot boards.

Each builder (:func:`bed`) takes the object's random stream and a variant name of
:data:`hbeo.data.procedural.VARIANTS` and returns the object's parts (before centring); call them
through :func:`hbeo.data.procedural.generate`, which draws the variant and joins the parts.

Frame: metres, +z up (:mod:`hbeo.data.procedural`). The long axis runs along y, the headboard toward +y.
Imports :mod:`hbeo.data.procedural_parts` only.
"""
from __future__ import annotations

from hbeo.data.procedural_parts import box, coin, corners, legs_at

__all__ = ["bed"]


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


def bed(rng, variant) -> list:
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
