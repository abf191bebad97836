"""What a method of the evaluation is called: the display label of each (method, pose setting).

The metrics dicts of :mod:`hbeo.evaluation.evaluate` carry ``method`` (``hbeo``, ``hbeo-verify``,
``beo``, ``icp``, ``voxcnn``) and ``pose`` (``known``, ``1dof``, ``3dof``); tables, figures, the
paired statistics and the report all name a method by :func:`label`, from this one table.

May import: the foundation modules only.
"""
from __future__ import annotations

#: Display label of each (method, pose) pair; :func:`label` falls back to ``"method (pose)"``.
LABELS = {("hbeo", "3dof"): "HBEO (3-DOF)", ("hbeo-verify", "3dof"): "HBEO + rolls + verify (3-DOF, ours)",
          ("beo", "known"): "BEO (known pose)", ("beo", "1dof"): "BEO (1-DOF)",
          ("beo", "3dof"): "BEO (3-DOF, true class)", ("icp", "3dof"): "ICP (3-DOF, true class)",
          ("icp", "1dof"): "ICP (1-DOF, true class)", ("voxcnn", "known"): "3-D CNN on partial grid (known pose)",
          ("class_mean", "-"): "class mean shape (HBEO's class)"}


def label(metrics: dict) -> str:
    """The display label of a metrics dict (``+ verify`` added when HBEO's answers were verified)."""
    key = (metrics["method"], metrics["pose"])
    name = LABELS.get(key, f"{key[0]} ({key[1]})")
    return name + (" + verify" if metrics.get("verify") and "verify" not in name else "")
