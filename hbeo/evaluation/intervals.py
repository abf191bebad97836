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


def class_mean(values, classes) -> float:
    """The mean over the classes present in ``classes`` (n,) of each class's mean of ``values`` (n,): with
    ``values`` the per-query correctness, the class-mean accuracy
    (:func:`hbeo.evaluation.evaluate.class_mean_accuracy`); every class counts the same however many queries
    it has. NaN for no queries.

    >>> class_mean([1, 1, 0, 0], ["a", "a", "a", "b"])   # (2/3 + 0) / 2
    0.3333333333333333
    """
    values, classes = np.asarray(values, np.float64), np.asarray(classes)
    if values.shape != classes.shape or values.ndim != 1:
        raise ValueError(f"class_mean: values {values.shape} and classes {classes.shape} must be the same (n,)")
    if not len(values):
        return float("nan")
    _, code = np.unique(classes, return_inverse=True)
    n = np.bincount(code)
    return float(np.mean(np.bincount(code, weights=values)[n > 0] / n[n > 0]))


def _correct(q) -> np.ndarray:
    return np.asarray(q["class"]) == np.asarray(q["pred"])


def _within_30(column: str):
    return lambda q: np.asarray(q[column], np.float64) < 30


#: What :func:`interval` can summarize: statistic -> (per-query column, reduction: ``mean``, ``median`` or
#: ``class_mean``, the mean over classes of each class's mean, :func:`class_mean`).
STATISTICS = {
    "accuracy": (_correct, "mean"),
    "class_mean": (_correct, "class_mean"),
    "pose_median": (lambda q: np.asarray(q["pose_deg"], np.float64), "median"),
    "within_30": (_within_30("pose_deg"), "mean"),
    "within_30_sym": (_within_30("pose_sym_deg"), "mean"),       # modulo each class's symmetry turns
    "iou": (lambda q: np.asarray(q["iou"], np.float64), "mean"),
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


def _values_and_stat(metrics: dict, what: str):
    """(values (n,), stat) of ``what`` for a metrics dict: for ``class_mean`` the values are query indices
    and the statistic looks up their correctness and class (a resample keeps each query's class)."""
    if what not in STATISTICS:
        raise ValueError(f"unknown statistic {what!r}; expected one of {', '.join(STATISTICS)}")
    q = metrics["per_query"]
    column, reduce = STATISTICS[what]
    values = column(q).astype(np.float64)
    if reduce == "class_mean":
        classes = np.asarray(q["class"])
        return np.arange(len(values), dtype=np.float64), lambda i: class_mean(values[i.astype(int)],
                                                                                 classes[i.astype(int)])
    return values, np.median if reduce == "median" else np.mean


def estimate(metrics: dict, what: str) -> float:
    """``what`` (:data:`STATISTICS`) of a metrics dict's ``per_query`` columns, without resampling."""
    values, stat = _values_and_stat(metrics, what)
    return float(stat(values))


def interval(metrics: dict, what: str, **kw) -> tuple[float, float, float]:
    """(estimate, low, high) of ``what`` (:data:`STATISTICS`: accuracy, class_mean, pose_median, within_30,
    within_30_sym, iou) for a metrics dict, objects resampled (:func:`cluster_bootstrap`); a metrics dict
    without per-query object ids (older files) resamples queries."""
    values, stat = _values_and_stat(metrics, what)
    groups = metrics["per_query"].get("object") or list(range(len(values)))
    return cluster_bootstrap(values, np.asarray(groups), stat=stat, **kw)
