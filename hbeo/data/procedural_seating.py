"""The seating classes of the procedural furniture: chair and sofa.

Each builder (:func:`chair`, :func:`sofa`) takes the object's random stream and a variant name of
:data:`hbeo.data.procedural.VARIANTS` and returns the object's parts (before centring); call them
through :func:`hbeo.data.procedural.generate`, which draws the variant and joins the parts.

Frame: metres, +z up (:mod:`hbeo.data.procedural`). A chair's back is toward +y (it faces -y); a
sofa is built the same way, then turned so that its back is toward +x.
Imports :mod:`hbeo.data.procedural_parts` and numpy only.
"""
from __future__ import annotations

import numpy as np

from hbeo.data.procedural_parts import box, coin, corners, legs_at, pedestal, rod, rot_x, rot_z, transformed

__all__ = ["chair", "sofa"]


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


def chair(rng, variant) -> list:
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


def sofa(rng, variant) -> list:
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
