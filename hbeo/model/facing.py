"""Where ``predict --face-object`` turns the view: toward an estimate of the object's centre, and only as far as
the model needs (:meth:`hbeo.model.inference.HBEO.set_face_object`).

A model trained without ``recenter`` saw each object's *centre* within ``shift`` (a fraction of its depth, x and y)
of the optical axis (its renderings' settings), so the observed surface lies wherever the object's hidden parts
put it, and the network reads that offset. Turning the view to the observed points' median (the ``recenter``
rule, :func:`hbeo.model.preprocess.to_model_view`) removes it: on the reference model's validation views that
cost 6.4 points of class mean, while the camera turned to the true centre cost nothing
(``docs/history/recenter-at-inference-2026-12-06/``). So the view is turned in two passes:

1. the view turned to the observed points' median gives a pose, a shape and a scale (one network answer);
2. the centre at which that shape, at that pose, shows the depth (:func:`hbeo.model.verify.align_translation` on
   :func:`hbeo.model.verify.working_view`) is the estimate; the view is turned by the part of its offset beyond
   ``shift`` (per axis), so an object the model could have been trained on is answered as it is, and one farther
   off is brought to the edge of that range. The network answers that view.

:func:`aims` gives step 2's turn per image; :meth:`~hbeo.model.inference.HBEO.predict` runs both passes.

May import: foundation and the other hbeo.model modules.
"""
from __future__ import annotations

import numpy as np

#: an aim (:func:`aims`): the view as it is (no turn)
PLAIN = "plain"
#: an aim: the view turned to the observed points' median (the ``recenter`` rule; step 1)
MEDIAN = "median"


def aims(model, depth: np.ndarray, masks, intrinsics, first) -> list:
    """Step 2's aim for each image of ``depth`` (B, H, W) with ``masks`` (B of (H, W) bool or None) and
    ``intrinsics``, from ``first``, the :class:`~hbeo.model.inference.Prediction` of step 1: :data:`PLAIN`, or the
    direction (3,) in the camera frame that the view's optical axis turns to; :data:`MEDIAN` when the answer has no
    shape to align (an empty back-projection at 0.5)."""
    from hbeo.model.verify import align_translation, surface_points, working_view
    shift = float(model.settings.render.get("shift") or 0.0)
    out = []
    for i, d in enumerate(depth):
        d = np.asarray(d, np.float64)
        if masks[i] is not None:
            d = d * np.asarray(masks[i], bool)
        size = model.settings.object_size * float(first.scale[i])
        pts = surface_points(model.paper_grids(first.coeffs[i][None])[0], size)
        if not len(pts):
            out.append(MEDIAN)
            continue
        dw, Kw = working_view(d, intrinsics, model.intrinsics)
        t = align_translation(dw, first.rotation[i], first.translation[i], pts, Kw)
        if not t[2] > 0:
            out.append(MEDIAN)
            continue
        off = t[:2] / t[2]
        excess = off - np.clip(off, -shift, shift)
        out.append(PLAIN if not excess.any() else np.array([excess[0], excess[1], 1.0]))
    return out
