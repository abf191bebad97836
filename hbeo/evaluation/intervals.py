"""Confidence intervals for evaluation figures: a bootstrap over objects.

The views of one object are not independent queries (three views of a monitor share its shape), so
intervals resample *objects* with replacement, keeping all of each object's views (a cluster
bootstrap), using the ``object`` column of a metrics dict's ``per_query``
(:mod:`hbeo.evaluation.evaluate`). Percentile intervals, ``n_boot`` resamples from a seeded
generator: the same inputs give the same interval. :func:`intervals` gives several statistics on the
same resamples, among them per-class ones (the mean and the lowest of the class accuracies), which a
resample computes over the classes it holds. Used for one run's figures alone (the seed table,
:mod:`hbeo.report.seeds`); comparisons between methods use :mod:`hbeo.evaluation.paired`.

May import: foundation.
"""
from __future__ import annotations

import numpy as np


def _correct(q) -> np.ndarray:
    return np.asarray(q["class"]) == np.asarray(q["pred"])


def _class_means(values: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """Mean of ``values`` per class present (``classes``: (n,) integer codes)."""
    n = np.bincount(classes)
    return (np.bincount(classes, weights=values) / np.maximum(n, 1))[n > 0]


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
    return float(np.mean(_class_means(values, np.unique(classes, return_inverse=True)[1])))


#: How a statistic reduces its per-query values; ``class_mean`` and ``class_min`` see each query's class
#: (the mean and the lowest of the per-class means: every class counts the same).
REDUCTIONS = {"mean": lambda v, c: float(np.mean(v)), "median": lambda v, c: float(np.median(v)),
              "class_mean": lambda v, c: float(np.mean(_class_means(v, c))),
              "class_min": lambda v, c: float(np.min(_class_means(v, c)))}

#: What :func:`interval` can summarize: statistic -> (per-query values, reduction of :data:`REDUCTIONS`).
STATISTICS = {
    "accuracy": (_correct, "mean"),
    "class_mean": (_correct, "class_mean"),                 # the paper's Table I total
    "lowest_class": (_correct, "class_min"),                # the accuracy of the worst class
    "pose_median": (lambda q: np.asarray(q["pose_deg"], np.float64), "median"),
    "within_30": (lambda q: np.asarray(q["pose_deg"], np.float64) < 30, "mean"),
    "within_30_sym": (lambda q: np.asarray(q["pose_sym_deg"], np.float64) < 30, "mean"),
    "iou": (lambda q: np.asarray(q["iou"], np.float64), "mean"),
}


def _resamples(groups: np.ndarray, n_boot: int, seed: int):
    """``n_boot`` index arrays, each the queries of as many groups drawn with replacement: the drawn groups'
    queries one group after another, in the order drawn (each group's in their order in ``groups``)."""
    _, idx = np.unique(groups, return_inverse=True)
    order = np.argsort(idx, kind="stable")              # the queries, group after group
    sizes = np.bincount(idx)
    starts = np.cumsum(sizes) - sizes                   # where each group begins in ``order``
    rng = np.random.default_rng(seed)
    for _ in range(n_boot):
        pick = rng.integers(0, len(sizes), len(sizes))
        n = sizes[pick]
        # output position j of the k-th drawn group reads order[starts[pick[k]] + j - (where group k begins)]
        yield order[np.repeat(starts[pick] - (np.cumsum(n) - n), n) + np.arange(n.sum())]


def _check(values: np.ndarray, groups: np.ndarray, level: float) -> None:
    if values.shape != groups.shape or values.ndim != 1 or len(values) == 0:
        raise ValueError(f"values {values.shape} and groups {groups.shape} must be equal, non-empty 1-D")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")


def cluster_bootstrap(values: np.ndarray, groups, stat=np.mean, n_boot: int = 2000, level: float = 0.95,
                      seed: int = 0) -> tuple[float, float, float]:
    """(estimate, low, high): ``stat`` of ``values`` (n,) and its percentile interval at ``level``
    from ``n_boot`` resamples of the ``groups`` (n,) labels with replacement (each drawn group
    brings all of its values)."""
    values = np.asarray(values, np.float64)
    groups = np.asarray(groups)
    _check(values, groups, level)
    draws = np.array([stat(values[i]) for i in _resamples(groups, n_boot, seed)])
    lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2])
    return float(stat(values)), float(lo), float(hi)


def intervals(metrics: dict, whats, n_boot: int = 2000, level: float = 0.95,
              seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """{what: (estimate, low, high)} for each of ``whats`` (:data:`STATISTICS`) of a metrics dict, all on
    the same ``n_boot`` resamples of its objects (:func:`cluster_bootstrap`'s, so each equals
    :func:`interval` of that statistic alone); a metrics dict without per-query object ids (older
    files) resamples queries."""
    unknown = [w for w in whats if w not in STATISTICS]
    if unknown:
        raise ValueError(f"unknown statistic {unknown[0]!r}; expected one of {', '.join(STATISTICS)}")
    q = metrics["per_query"]
    values = {w: STATISTICS[w][0](q).astype(np.float64) for w in whats}
    n = len(q["class"])
    groups = np.asarray(q.get("object") or list(range(n)))
    _, classes = np.unique(np.asarray(q["class"]), return_inverse=True)
    for v in values.values():
        _check(v, groups, level)
    red = {w: REDUCTIONS[STATISTICS[w][1]] for w in whats}
    draws = {w: [] for w in whats}
    for i in _resamples(groups, n_boot, seed):
        for w in whats:
            draws[w].append(red[w](values[w][i], classes[i]))
    out = {}
    for w in whats:
        lo, hi = np.quantile(draws[w], [(1 - level) / 2, (1 + level) / 2])
        out[w] = (red[w](values[w], classes), float(lo), float(hi))
    return out


def estimate(metrics: dict, what: str) -> float:
    """``what`` (:data:`STATISTICS`) of a metrics dict's ``per_query`` columns, without resampling."""
    if what not in STATISTICS:
        raise ValueError(f"unknown statistic {what!r}; expected one of {', '.join(STATISTICS)}")
    q = metrics["per_query"]
    column, reduce = STATISTICS[what]
    return REDUCTIONS[reduce](column(q).astype(np.float64), np.unique(np.asarray(q["class"]), return_inverse=True)[1])


def interval(metrics: dict, what: str, **kw) -> tuple[float, float, float]:
    """(estimate, low, high) of ``what`` (:data:`STATISTICS`: accuracy, class_mean, lowest_class,
    pose_median, within_30, within_30_sym, iou) for a metrics dict, objects resampled
    (:func:`cluster_bootstrap`); a metrics dict without per-query object ids (older files) resamples
    queries."""
    return intervals(metrics, [what], **kw)[what]
