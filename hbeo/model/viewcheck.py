"""Whether the model can have understood one image: the checks :meth:`hbeo.model.inference.HBEO.predict` makes
on each image once it is brought into the model's camera (a :class:`hbeo.model.preprocess.View`).

An image the model cannot have understood raises :class:`~hbeo.errors.DataError`: an object at an implausible
distance (outside :data:`hbeo.model.depthfile.DEPTH_RANGE_M` metres, e.g. millimetres given as metres) or one
that reaches none of the network's input pixels (wrong intrinsics, wrong mask). One that is usable but
suspicious gets warnings (plain sentences): the object partly outside the model's view (below
:data:`MIN_COVERAGE` of its pixels inside), tiny in it or in the image it came from (below
:func:`min_input_pixels`), off the optical axis a model trained without recentering was trained near
(:data:`OFF_AXIS_FACTOR`), or far from the training distances (:data:`DISTANCE_FACTOR`). Notebook 08's table of checks (:func:`hbeo.lessons.yourdepth.checks`)
shows the same limits on one frame.

May import: foundation and the other hbeo.model modules.
"""
from __future__ import annotations

import math

import numpy as np

from hbeo.conventions import Intrinsics
from hbeo.errors import DataError
from hbeo.model.depthfile import DEPTH_RANGE_M

#: below this fraction of the object's pixels inside the model's view, a prediction is low confidence
MIN_COVERAGE = 0.9
#: fewer non-zero input pixels than this fraction of the model's image (and at least 16): low confidence
MIN_INPUT_FRACTION = 0.005
#: an object centre farther than this factor outside the training distances: low confidence
#: (models trained without distance normalization only)
DISTANCE_FACTOR = 1.5
#: a model trained without recentering warns when the object's centre is off the optical axis (x or y, as a
#: fraction of its depth) by more than this times its renderings' ``shift`` (the largest it was trained on)
OFF_AXIS_FACTOR = 2.0


def min_input_pixels(K: Intrinsics) -> int:
    """The fewest filled input pixels of the model's camera ``K`` without a warning."""
    return int(max(16, MIN_INPUT_FRACTION * K.width * K.height))


def check_view(v, K: Intrinsics, settings, recenter: bool, index: int | None = None) -> list[str]:
    """Warnings (list of str) for one image's model view ``v`` (model camera ``K``, the model's
    :class:`~hbeo.model.modelmeta.ModelSettings`; ``recenter``: whether the view was turned to the object);
    DataError when the network's input would be empty or the object's distance is implausible. ``index``: the
    image's place in a batch, named in the messages."""
    who = "" if index is None else f"image {index}: "
    lo, hi = DEPTH_RANGE_M
    if not lo <= v.distance <= hi:
        raise DataError(None, f"{who}the object is {v.distance:.3g} m away, outside the plausible {lo:g}..{hi:g} m; "
                              f"depth must be in metres (check the depth scale)")
    if v.filled == 0:
        raise DataError(None, f"{who}the object falls outside the model's view ({v.coverage:.0%} of its pixels "
                              f"inside, no input pixel filled); check the intrinsics (fx,fy,cx,cy of this "
                              f"image) and the mask")
    out = []
    if v.coverage < MIN_COVERAGE:
        out.append(f"only {v.coverage:.0%} of the object's pixels fall inside the model's view (the rest is cut "
                   f"off); check the intrinsics and the mask")
    if v.filled < min_input_pixels(K):
        out.append(f"the object fills only {v.filled} of the model's {K.width}x{K.height} input pixels")
    elif 0 < v.points < min_input_pixels(K):
        out.append(f"the object is seen by only {v.points} pixels of the image; the model's view of it "
                   f"({v.filled} pixels) is stretched from them, too few to show its shape")
    shift = settings.render.get("shift")
    if shift and not recenter and v.center[2] > 0:
        off = float(np.max(np.abs(v.center[:2])) / v.center[2])
        if off > OFF_AXIS_FACTOR * shift:
            out.append(f"the object's centre is {math.degrees(math.atan(off)):.0f} degrees off the optical axis; this "
                       f"model was trained without --recenter within {math.degrees(math.atan(shift)):.0f} degrees "
                       f"of it: predict --face-object turns the view to the object")
    dist = settings.render.get("distance")
    if dist and not settings.ref_distance:
        d_lo, d_hi = float(min(dist)), float(max(dist))
        if not d_lo / DISTANCE_FACTOR <= v.distance <= d_hi * DISTANCE_FACTOR:
            out.append(f"the object is {v.distance:.2f} m away; the model was trained at {d_lo:g}..{d_hi:g} m")
    return out
