"""Confidence intervals for evaluation figures: a bootstrap over objects.

The views of one object are not independent queries (three views of a monitor share its shape), so
intervals resample *objects* with replacement, keeping all of each object's views (a cluster
bootstrap), using the ``object`` column of a metrics dict's ``per_query``
(:mod:`hbeo.evaluation.evaluate`). Percentile intervals, ``n_boot`` resamples from a seeded
generator: the same inputs give the same interval.

May import: foundation.
"""
from __future__ import annotations

import numpy as np

#: What :func:`interval` can summarize: statistic over a per-query column.
STATISTICS = {
    "accuracy": lambda q: np.asarray(q["class"]) == np.asarray(q["pred"]),
    "pose_median": lambda q: np.asarray(q["pose_deg"], np.float64),
    "within_30": lambda q: np.asarray(q["pose_deg"], np.float64) < 30,
    "iou": lambda q: np.asarray(q["iou"], np.float64),
}


def cluster_bootstrap(values: np.ndarray, groups, stat=np.mean, n_boot: int = 2000, level: float = 0.95,
                      seed: int = 0) -> tuple[float, float, float]:
    """(estimate, low, high): ``stat`` of ``values`` (n,) and its percentile interval at ``level``
    from ``n_boot`` resamples of the ``groups`` (n,) labels with replacement (each drawn group
    brings all of its values)."""
    values = np.asarray(values, np.float64)
    groups = np.asarray(groups)
    if values.shape != groups.shape or values.ndim != 1 or len(values) == 0:
        raise ValueError(f"values {values.shape} and groups {groups.shape} must be equal, non-empty 1-D")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    _, idx = np.unique(groups, return_inverse=True)
    members = np.split(np.argsort(idx, kind="stable"), np.cumsum(np.bincount(idx))[:-1])
    rng = np.random.default_rng(seed)
    draws = np.empty(n_boot)
    for b in range(n_boot):
        pick = rng.integers(0, len(members), len(members))
        draws[b] = stat(values[np.concatenate([members[g] for g in pick])])
    lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2])
    return float(stat(values)), float(lo), float(hi)


def interval(metrics: dict, what: str, **kw) -> tuple[float, float, float]:
    """(estimate, low, high) of ``what`` (:data:`STATISTICS`: accuracy, pose_median, within_30, iou)
    for a metrics dict, objects resampled (:func:`cluster_bootstrap`); a metrics dict without
    per-query object ids (older files) resamples queries."""
    if what not in STATISTICS:
        raise ValueError(f"unknown statistic {what!r}; expected one of {', '.join(STATISTICS)}")
    q = metrics["per_query"]
    values = STATISTICS[what](q).astype(np.float64)
    groups = q.get("object") or list(range(len(values)))
    stat = np.median if what == "pose_median" else np.mean
    return cluster_bootstrap(values, np.asarray(groups), stat=stat, **kw)
