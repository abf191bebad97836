"""Where large pose errors point: is a wrong pose a front/back flip about the object's up axis?

HBEO's pose errors are bimodal (``docs/experiments.md``, "Targets: met and missed"): most answers are within
30 degrees or near 180. A 180-degree error can be a turn about the object's up axis (front and back
swapped: what a symmetric-looking silhouette invites) or about a horizontal axis (top and bottom
swapped). This module measures which, per class.

The error turn of a query is ``E = R_true^T R_pred`` (R: object -> camera, :mod:`hbeo.conventions`),
the rotation *in the object's frame* that turns the true pose into the predicted one
(``R_pred = R_true E``); its angle is the geodesic pose error. An error is *large* at or above
``big_deg``; a large error is *about the up axis* when its turn axis is within ``acos(up_cos)``
of the canonical frame's up axis (:data:`hbeo.conventions.UP_AXIS`, either sense).

May import: foundation, :mod:`hbeo.evaluation.evaluate` and :mod:`hbeo.evaluation.method`.
"""
from __future__ import annotations

import numpy as np

from hbeo.conventions import UP_AXIS
from hbeo.rotations import check_rotation_matrices, matrix_to_axis_angle

BIG_DEG = 150.0      #: an error at least this large counts as a flip
UP_COS = 0.9         #: |cos| between the turn axis and the up axis at or above which a flip is "about up" (~26 deg)


def error_turns(R_pred, R_true) -> tuple[np.ndarray, np.ndarray]:
    """Predicted and true rotations (n, 3, 3) -> (angle in degrees (n,), unit turn axis in the object's
    frame (n, 3)) of ``R_true^T R_pred``; the axis of a zero error is (0, 0, 0)."""
    R_pred = check_rotation_matrices(np.asarray(R_pred, np.float64).reshape(-1, 3, 3), "R_pred")
    R_true = check_rotation_matrices(np.asarray(R_true, np.float64).reshape(-1, 3, 3), "R_true")
    if len(R_pred) != len(R_true):
        raise ValueError(f"{len(R_pred)} predicted rotations for {len(R_true)} true ones")
    v = matrix_to_axis_angle(np.einsum("nji,njk->nik", R_true, R_pred))
    angle = np.linalg.norm(v, axis=1)
    axis = np.where(angle[:, None] > 1e-9, v / np.maximum(angle, 1e-12)[:, None], 0.0)
    return np.degrees(angle), axis


def flip_table(rows: list[dict], big_deg: float = BIG_DEG, up_cos: float = UP_COS) -> list[dict]:
    """Per class (sorted) and over all queries (``class`` "all"): queries ``n``, the share of large errors
    ``flips``, and of those the share ``about_up`` whose turn axis is within ``acos(up_cos)`` of the up axis
    (None where there is no flip). ``rows``: per-query dicts with ``class``, ``R_pred``, ``R_true``
    (:func:`hbeo.evaluation.evaluate.score_methods`'s rows)."""
    if not rows:
        raise ValueError("no queries to tabulate")
    cls = np.array([r["class"] for r in rows])
    deg, axis = error_turns(np.stack([r["R_pred"] for r in rows]), np.stack([r["R_true"] for r in rows]))
    big, up = deg >= big_deg, np.abs(axis[:, UP_AXIS]) >= up_cos
    out = []
    for name in [*sorted(set(cls)), "all"]:
        m = np.ones(len(cls), bool) if name == "all" else cls == name
        nb = int((m & big).sum())
        out.append({"class": str(name), "n": int(m.sum()), "flips": float((m & big).mean() / m.mean()),
                    "about_up": float((m & big & up).sum() / nb) if nb else None})
    return out


def pose_flips(model, dataset, split: str = "val", views: int = 3, seed: int = 0, per_class: int | None = None,
               rolls: int = 1, progress: bool = True) -> dict:
    """Score HBEO ``model`` (one pass, or ``rolls``) on the paired query views of ``split`` (the evaluation's
    own views: :func:`hbeo.evaluation.evaluate.score_methods`) and tabulate its flips (:func:`flip_table`)."""
    from hbeo.evaluation.evaluate import EvaluationSetup, score_methods
    from hbeo.evaluation.method import HBEOMethod
    method = HBEOMethod(model, rolls=rolls)
    rows, failures, records, rs = score_methods({"hbeo": (method, "3dof")}, dataset,
                                                EvaluationSetup.of_model(model, class_means=False), split, views,
                                                seed, per_class=per_class, progress=progress)
    return {"split": split, "views": views, "seed": seed, "rolls": rolls, "sampler": rs.sampler,
            "n_objects": len(records) - len(failures), "big_deg": BIG_DEG, "up_cos": UP_COS,
            "classes": flip_table(rows["hbeo"])}
