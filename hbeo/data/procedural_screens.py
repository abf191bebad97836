"""The monitor class of the procedural furniture: flat screens on a stand or wall-style, and CRTs.

Each builder (:func:`monitor`) takes the object's random stream and a variant name of
:data:`hbeo.data.procedural.VARIANTS` and returns the object's parts (before centring); call them
through :func:`hbeo.data.procedural.generate`, which draws the variant and joins the parts.

Frame: metres, +z up (:mod:`hbeo.data.procedural`). The screen faces -y.
Imports :mod:`hbeo.data.procedural_parts` and numpy only.
"""
from __future__ import annotations

import numpy as np

from hbeo.data.procedural_parts import ROUND_SECTIONS, box, coin, frustum, rot_x, transformed

__all__ = ["monitor"]


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


def monitor(rng, variant) -> list:
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
