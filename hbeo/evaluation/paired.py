"""Paired comparisons with confidence intervals, and the paper's claims judged by them.

Every method of a run is scored on the same (object, view) pairs (:mod:`hbeo.evaluation.protocol`),
so a difference between two methods is measured on the pairs both answered, and its uncertainty is
that of the *objects*: :class:`PairedBootstrap` draws ``n_boot`` resamples of the test objects (with
replacement, within each class, so every resample keeps the run's class counts; an object brings all of
its views), once per run, and every statistic of every method is computed on the same resamples. A method
that answers a subset of the objects (the slow searches: a few objects per class) sees the subset's class
counts vary from resample to resample (for 10 of ~90 objects a class, a class's weight is about
Binomial(90, 1/9)), which makes its intervals somewhat wider (conservative) than a bootstrap stratified on
the subset would; a resample that leaves a statistic undefined
(a class of the subset drawn zero times, for a class mean) is left out of the percentiles.
Intervals are percentile intervals at ``level`` (95 %); the same inputs and seed give the same
intervals.

Statistics (:data:`STATISTICS`; over the queries of one method, or over the pairs shared with another):
``accuracy``, ``error_rate``, ``class_accuracy`` (the mean of the per-class accuracies, how the
paper's Table I totals are read here), ``pose_mean``, ``pose_median``, ``within_30`` (share of
queries under 30 degrees), ``edt_mean``, ``edt_median``, ``edt_nonempty_mean`` (over non-empty
completions), ``iou_mean``, ``ms_median``.

Training seeds (:func:`contrast_seeds`): two configurations each trained with several seeds, their seed means
compared on the queries every file answered, with an interval over seeds (Welch's t) and one over objects.

A claim (:data:`CLAIMS`) is an inequality between two methods' statistics, written as a contrast that
the claim says is below zero (e.g. HBEO's mean pose error minus half of BEO's). Its verdict
(:func:`verdict`): ``holds`` when the whole interval of the contrast is below zero, ``fails`` when the
whole interval is at or above zero, ``inconclusive`` otherwise. A claim about time (:data:`TIMED`) whose two
files were timed on different machines (their ``hardware``, :func:`hbeo.machine.describe`) is ``not comparable``
(:data:`NOT_COMPARABLE`) whatever its interval: a ratio of times from two machines measures the machines too.

May import: foundation and the other reproduction modules.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from hbeo.errors import DataError
from hbeo.evaluation.method import label
from hbeo.machine import describe
from hbeo.storage import read_json

LEVEL = 0.95
N_BOOT = 2000


def _col(q: pd.DataFrame, name: str) -> np.ndarray:
    return q[name].to_numpy(np.float64)


#: statistic -> (per-query values, reduction): ``mean``, ``median`` or ``class_mean``.
STATISTICS: dict[str, tuple[Callable[[pd.DataFrame], np.ndarray], str]] = {
    "accuracy": (lambda q: (q["class"] == q["pred"]).to_numpy(np.float64), "mean"),
    "error_rate": (lambda q: (q["class"] != q["pred"]).to_numpy(np.float64), "mean"),
    "class_accuracy": (lambda q: (q["class"] == q["pred"]).to_numpy(np.float64), "class_mean"),
    "pose_mean": (lambda q: _col(q, "pose_deg"), "mean"),
    "pose_median": (lambda q: _col(q, "pose_deg"), "median"),
    "within_30": (lambda q: (_col(q, "pose_deg") < 30).astype(np.float64), "mean"),
    "edt_mean": (lambda q: _col(q, "edt"), "mean"),
    "edt_median": (lambda q: _col(q, "edt"), "median"),
    "edt_nonempty_mean": (lambda q: _col(q, "edt"), "mean"),
    "iou_mean": (lambda q: _col(q, "iou"), "mean"),
    "ms_median": (lambda q: _col(q, "ms"), "median"),
}


def read_metrics(paths) -> list[dict]:
    """The metrics dicts in ``paths`` (JSON files an evaluation wrote), in order. DataError (a ValueError) naming
    the file when one cannot be read or is not a metrics dict with per-query answers."""
    out = []
    for f in paths:
        try:
            m = read_json(f, "metrics", dict)
        except OSError as err:
            raise DataError(f, f"not a readable metrics file ({err.strerror or err})") from None
        if "per_query" not in m:
            raise DataError(f, "not a metrics file (no per_query answers)")
        out.append(m)
    return out


def queries(metrics: dict) -> pd.DataFrame:
    """The per-query table of one metrics dict, with ``key`` (class/object: the resampled unit) and
    ``empty`` (the completion had no filled voxel: the ``empty`` column when present, else an IoU of 0
    together with a naive error of exactly 0, which only an empty completion gives). ``per_query``: the file's
    columns (a dict of lists) or a table already made from them."""
    q = metrics["per_query"]
    q = q.copy() if isinstance(q, pd.DataFrame) else pd.DataFrame(q)
    if "object" not in q:
        raise ValueError(f"{label(metrics)}: per_query has no object ids (a file older than the paired "
                         f"protocol); evaluate again")
    q["key"] = q["class"].astype(str) + "/" + q["object"].astype(str)
    if "empty" not in q:
        q["empty"] = (q["iou"] == 0) & (q["naive"] == 0)
    return q


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Median of ``values`` (n,) under each row of ``weights`` (b, n), as ``np.median`` takes it at unit
    weights: the smallest value whose cumulative weight reaches half the row's total, averaged with the next
    value of positive weight where it reaches exactly half (an even count's two middle values)."""
    order = np.argsort(values, kind="stable")
    v, w = values[order], weights[:, order]
    cum = np.cumsum(w, axis=1)
    half = cum[:, -1:] / 2
    first = (cum >= half).argmax(axis=1)
    rows = np.arange(len(w))
    after = (cum > cum[rows, first][:, None]).argmax(axis=1)         # the next value with weight
    exact = np.isclose(cum[rows, first], half[:, 0], rtol=0, atol=1e-9) & (cum[rows, first] < cum[:, -1])
    return np.where(exact, (v[first] + v[after]) / 2, v[first])


@dataclass
class Estimate:
    """A statistic with its interval and what it rests on."""
    value: float
    low: float
    high: float
    n_queries: int
    n_objects: int

    def text(self, fmt: str = "{:.1f}", scale: float = 1.0) -> str:
        return (f"{fmt.format(scale * self.value)} [{fmt.format(scale * self.low)}, "
                f"{fmt.format(scale * self.high)}]")


class PairedBootstrap:
    """Resamples of a run's test objects shared by every method (see the module docstring).
    ``evals``: metrics dicts; a method is addressed by its ``(method, pose)`` key."""

    def __init__(self, evals: list[dict], n_boot: int = N_BOOT, level: float = LEVEL, seed: int = 0):
        if not 0 < level < 1:
            raise ValueError(f"level must be in (0, 1), got {level}")
        self.level, self.n_boot = level, n_boot
        self.q = {(m["method"], m["pose"]): queries(m) for m in evals}
        self.metrics = {(m["method"], m["pose"]): m for m in evals}
        objs = pd.concat([q[["key", "class"]] for q in self.q.values()]).drop_duplicates("key")
        objs = objs.sort_values(["class", "key"]).reset_index(drop=True)
        self.index = {k: i for i, k in enumerate(objs["key"])}
        rng = np.random.default_rng(seed)
        self.weights = np.zeros((n_boot, len(objs)), np.float64)       # times each object is drawn
        rows = np.arange(n_boot)[:, None] * len(objs)
        for _, members in objs.groupby("class").groups.items():
            members = np.asarray(members)
            draws = rng.integers(0, len(members), (n_boot, len(members)))
            self.weights += np.bincount((rows + members[draws]).ravel(), minlength=self.weights.size).reshape(
                self.weights.shape)

    def _table(self, key, on=None) -> pd.DataFrame:
        if key not in self.q:
            raise KeyError(f"no evaluation {key} in this comparison; it has {sorted(self.q)}")
        q = self.q[key]
        if on is not None:                  # restrict to pairs that every method in ``on`` answered
            for other in on:
                o = self.q[other]
                q = q[q.set_index(["key", "view"]).index.isin(o.set_index(["key", "view"]).index)]
        return q

    def draws(self, key, what: str, on=None) -> tuple[float, np.ndarray, pd.DataFrame]:
        """(value on the data, values on every resample (n_boot,), the queries used) of statistic
        ``what`` for method ``key``, over its queries or the pairs it shares with the keys in ``on``."""
        if what not in STATISTICS:
            raise ValueError(f"unknown statistic {what!r}; expected one of {', '.join(STATISTICS)}")
        q = self._table(key, on)
        if what == "edt_nonempty_mean":
            q = q[~q["empty"].astype(bool)]
        if q.empty:
            raise ValueError(f"{key}: no queries for {what}" + (f" shared with {on}" if on else ""))
        fn, how = STATISTICS[what]
        v = fn(q)
        obj = q["key"].map(self.index).to_numpy()
        if how == "median":
            return float(np.median(v)), _weighted_median(v, self.weights[:, obj]), q
        # a resample's mean is sum(weight of the object * its values' sum) / sum(weight * its query count): one
        # column of weights per object rather than per query
        objs, first, of = np.unique(obj, return_index=True, return_inverse=True)
        W = self.weights if len(objs) == self.weights.shape[1] else self.weights[:, objs]    # objs: sorted
        total, count = np.bincount(of, v, len(objs)), np.bincount(of, None, len(objs))
        if how == "mean":
            return float(v.mean()), (W @ total) / (W @ count), q
        cls = q["class"].to_numpy()
        obj_cls = cls[first]                                # each object's class, from its first query
        per = [(v[cls == c].mean(), (W[:, k] @ total[k]) / (W[:, k] @ count[k]))
               for c in np.unique(cls) for k in [obj_cls == c]]
        return float(np.mean([p[0] for p in per])), np.mean([p[1] for p in per], axis=0), q

    def _interval(self, draws: np.ndarray) -> tuple[float, float]:
        lo, hi = np.nanquantile(draws, [(1 - self.level) / 2, (1 + self.level) / 2])
        return float(lo), float(hi)

    def estimate(self, key, what: str, on=None) -> Estimate:
        """Statistic ``what`` of method ``key`` with its interval."""
        value, d, q = self.draws(key, what, on)
        return Estimate(value, *self._interval(d), len(q), q["key"].nunique())

    def contrast(self, a, b, what: str, factor: float = 1.0) -> Estimate:
        """``what``(a) - ``factor`` * ``what``(b) on the (object, view) pairs both answered, with its
        paired interval (the same resamples for both)."""
        va, da, q = self.draws(a, what, on=[b])
        vb, db, _ = self.draws(b, what, on=[a])
        return Estimate(va - factor * vb, *self._interval(da - factor * db), len(q), q["key"].nunique())


#: The statistics :func:`contrast_pair` reports, in order.
CONTRASTS = ("class_accuracy", "accuracy", "within_30", "pose_median", "iou_mean")


def contrast_pair(a: dict, b: dict, stats=CONTRASTS, n_boot: int = N_BOOT, seed: int = 0) -> dict[str, Estimate]:
    """Two metrics dicts of the same queries (e.g. two models' validation files): each statistic of ``a``
    minus ``b`` on the pairs both answered, with its paired interval over objects. The two may carry the
    same method key (two HBEO models): ``a`` is then re-keyed. ValueError (from
    :meth:`PairedBootstrap.draws`) when they share no pair."""
    a = dict(a, method=f"{a['method']} (a)") if (a["method"], a["pose"]) == (b["method"], b["pose"]) else a
    boot = PairedBootstrap([a, b], n_boot=n_boot, seed=seed)
    ka, kb = (a["method"], a["pose"]), (b["method"], b["pose"])
    return {what: boot.contrast(ka, kb, what) for what in stats}


@dataclass
class SeedContrast:
    """One statistic of two configurations, each trained with several seeds and scored on the same queries:
    each arm's per-seed values (``a``, ``b``), the difference of the arms' means (``value``), and two 95 %
    intervals for it. ``seeds_low``/``seeds_high``: Welch's t over the per-seed values (the spread of
    training runs, the queries fixed). ``objects_low``/``objects_high``: the paired bootstrap over objects of
    the seed-averaged statistic (the spread of objects, the trained models fixed)."""
    a: list[float]
    b: list[float]
    value: float
    seeds_low: float
    seeds_high: float
    objects_low: float
    objects_high: float
    n_queries: int
    n_objects: int


def _welch(a: np.ndarray, b: np.ndarray, level: float) -> tuple[float, float]:
    """The ``level`` interval of mean(a) - mean(b) by Welch's t (each arm its own variance)."""
    from scipy import stats
    d = a.mean() - b.mean()
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = np.sqrt(va + vb)
    if se == 0:
        return float(d), float(d)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    half = stats.t.ppf((1 + level) / 2, df) * se
    return float(d - half), float(d + half)


def contrast_seeds(a: list[dict], b: list[dict], stats=CONTRASTS, n_boot: int = N_BOOT, seed: int = 0,
                   level: float = LEVEL) -> dict[str, SeedContrast]:
    """Two configurations' metrics dicts, one per training seed (at least two each), on the queries that
    every file answered: per statistic, the mean over ``a``'s seeds minus the mean over ``b``'s, with
    :class:`SeedContrast`'s two intervals. ValueError when an arm has fewer than two files or the files
    share no query."""
    for arm, ms in (("a", a), ("b", b)):
        if len(ms) < 2:
            raise ValueError(f"arm {arm} has {len(ms)} metrics file(s); a spread over seeds needs at least two")
    evals = [dict(m, method=f"{m['method']} ({arm}{i})") for arm, ms in (("a", a), ("b", b))
             for i, m in enumerate(ms)]
    tables = [queries(m) for m in evals]
    shared = set.intersection(*(set(zip(q["key"], q["view"])) for q in tables))
    if not shared:
        raise ValueError("the metrics files share no (object, view) query")
    # resample only the objects every file answered: an object some file lacks would leave resamples empty
    evals = [dict(m, per_query=q[[kv in shared for kv in zip(q["key"], q["view"])]].reset_index(drop=True))
             for m, q in zip(evals, tables)]
    boot = PairedBootstrap(evals, n_boot=n_boot, level=level, seed=seed)
    keys = [(m["method"], m["pose"]) for m in evals]
    out = {}
    for what in stats:
        got = [boot.draws(k, what) for k in keys]       # every file now holds exactly the shared pairs
        va, vb = (np.array([g[0] for g in got[s]]) for s in (slice(0, len(a)), slice(len(a), None)))
        da = np.mean([g[1] for g in got[:len(a)]], axis=0)
        db = np.mean([g[1] for g in got[len(a):]], axis=0)
        q = got[0][2]
        out[what] = SeedContrast([float(v) for v in va], [float(v) for v in vb], float(va.mean() - vb.mean()),
                                 *_welch(va, vb, level), *boot._interval(da - db), len(q), q["key"].nunique())
    return out


def verdict(e: Estimate) -> str:
    """``holds`` (interval below 0), ``fails`` (interval at or above 0) or ``inconclusive``."""
    if e.high < 0:
        return "holds"
    if e.low >= 0:
        return "fails"
    return "inconclusive"


@dataclass(frozen=True)
class Claim:
    """The paper says ``what``(a) < ``factor`` * ``what``(b); ``show``: how a value is printed."""
    text: str
    a: tuple
    b: tuple
    what: str
    factor: float = 1.0
    unit: str = ""
    scale: float = 1.0
    fmt: str = "{:.1f}"


HBEO, BEO_KNOWN, BEO_1DOF, BEO_3DOF = ("hbeo", "3dof"), ("beo", "known"), ("beo", "1dof"), ("beo", "3dof")
ICP, VOXCNN = ("icp", "3dof"), ("voxcnn", "known")
#: The paper's claims (its text, sections V.A-V.D), as contrasts of paired statistics. "Competitive" is read
#: as a mean EDT error at most 25 % above BEO's with known pose; 3DShapeNets' role is played by the 3-D CNN.
CLAIMS = (
    Claim("HBEO (unknown 3-DOF pose) classifies better than BEO with known pose", HBEO, BEO_KNOWN, "error_rate",
          unit=" % error", scale=100),
    Claim("HBEO classifies better than the end-to-end network with known pose (3DShapeNets' role)", HBEO, VOXCNN,
          "error_rate", unit=" % error", scale=100),
    Claim("HBEO's misclassification rate is less than half of BEO's with 1-DOF pose", HBEO, BEO_1DOF, "error_rate",
          factor=0.5, unit=" % error", scale=100),
    Claim("HBEO's mean 3-DOF pose error is less than half of BEO's (BEO given the class)", HBEO, BEO_3DOF,
          "pose_mean", factor=0.5, unit="°"),
    Claim("HBEO's mean pose error is below the ICP baseline's (ICP given the class)", HBEO, ICP, "pose_mean",
          unit="°"),
    Claim("HBEO's completion is competitive with BEO's on known-pose input (mean EDT e' at most 25 % above)",
          HBEO, BEO_KNOWN, "edt_mean", factor=1.25, fmt="{:.0f}"),
    Claim("HBEO's completion is clearly better than BEO's with 1-DOF pose (mean EDT e')", HBEO, BEO_1DOF,
          "edt_mean", fmt="{:.0f}"),
    Claim("HBEO's completion is better than the end-to-end network's with known pose (mean EDT e')", HBEO, VOXCNN,
          "edt_mean", fmt="{:.0f}"),
    Claim("HBEO is orders of magnitude faster than BEO in 3-DOF (median time per query, 100x)", HBEO, BEO_3DOF,
          "ms_median", factor=0.01, unit=" ms", fmt="{:.3g}"),
)


#: Statistics measured in time: a claim on one compares the machines that timed its two files as well.
TIMED = frozenset({"ms_median"})
#: The verdict of a claim about time whose two files name different machines.
NOT_COMPARABLE = "not comparable (timed on different machines)"


def timed_apart(a: dict, b: dict) -> bool:
    """True when metrics dicts ``a`` and ``b`` both record the machine that timed them and the two differ
    (:func:`hbeo.machine.describe`). Files older than that record are taken as they are (False): Table II's
    note says their machine is not recorded."""
    ha, hb = a.get("hardware"), b.get("hardware")
    return isinstance(ha, dict) and isinstance(hb, dict) and describe(ha) != describe(hb)


def judge(boot: PairedBootstrap, claims=CLAIMS, hbeo=HBEO) -> pd.DataFrame:
    """Each claim whose two methods are in ``boot``: both statistics on their shared pairs (with
    intervals), the contrast's interval, the pairs and objects it rests on, and the verdict
    (:func:`verdict`; :data:`NOT_COMPARABLE` for a claim about time whose files were timed on two machines).
    ``hbeo``: the key that plays HBEO (e.g. HBEO + verify, to judge the extension the same way)."""
    rows = []
    for c in claims:
        a, b = (hbeo if c.a == HBEO else c.a), (hbeo if c.b == HBEO else c.b)
        if a not in boot.q or b not in boot.q:
            continue
        ea, eb = boot.estimate(a, c.what, on=[b]), boot.estimate(b, c.what, on=[a])
        d = boot.contrast(a, b, c.what, c.factor)
        who = {a: label(boot.metrics[a]), b: label(boot.metrics[b])}
        apart = c.what in TIMED and timed_apart(boot.metrics[a], boot.metrics[b])
        rows.append({"claim (paper)": c.text, "HBEO played by": who[hbeo],
                     "ours (95 % CI)": f"{who[a]}: {ea.text(c.fmt, c.scale)}{c.unit}; "
                                       f"{who[b]}: {eb.text(c.fmt, c.scale)}{c.unit}",
                     "contrast (claim: < 0)": d.text(c.fmt, c.scale),
                     "pairs": d.n_queries, "objects": d.n_objects, "verdict": NOT_COMPARABLE if apart else verdict(d)})
    return pd.DataFrame(rows)


#: How each statistic is printed: (format, scale, unit).
SHOW = {"accuracy": ("{:.1f}", 100, " %"), "error_rate": ("{:.1f}", 100, " %"), "class_accuracy": ("{:.1f}", 100, " %"),
        "pose_mean": ("{:.1f}", 1, "°"), "pose_median": ("{:.1f}", 1, "°"), "within_30": ("{:.1f}", 100, " %"),
        "edt_mean": ("{:.0f}", 1, ""), "edt_median": ("{:.0f}", 1, ""), "edt_nonempty_mean": ("{:.0f}", 1, ""),
        "iou_mean": ("{:.3f}", 1, ""), "ms_median": ("{:.3g}", 1, " ms")}


#: Column names of :func:`wide`.
NAMES = {"accuracy": "accuracy", "error_rate": "error rate", "class_accuracy": "class mean accuracy",
         "pose_mean": "mean pose error", "pose_median": "median pose error", "within_30": "within 30°",
         "edt_mean": "mean EDT e′ (lower is better)", "edt_median": "median EDT e′",
         "edt_nonempty_mean": "mean EDT e′ of non-empty completions", "iou_mean": "mean IoU (higher is better)",
         "ms_median": "median time per query"}


def estimates(boot: PairedBootstrap, stats, keys=None) -> pd.DataFrame:
    """Long table: one row per (method, statistic) with ``value``, ``low``, ``high`` (95 % interval
    over objects), ``n_queries``, ``n_objects``; methods in ``keys`` order (default: all)."""
    rows = []
    for key in keys or list(boot.q):
        if key not in boot.q:
            continue
        for what in stats:
            e = boot.estimate(key, what)
            rows.append({"method": key[0], "pose": key[1], "label": label(boot.metrics[key]), "statistic": what,
                         "value": e.value, "low": e.low, "high": e.high, "n_queries": e.n_queries,
                         "n_objects": e.n_objects})
    return pd.DataFrame(rows)


def wide(long: pd.DataFrame) -> pd.DataFrame:
    """:func:`estimates` as one row per method, each statistic printed "value [low, high]" in its unit
    (:data:`SHOW`), with the objects and queries it rests on."""
    rows = {}
    for _, r in long.iterrows():
        fmt, scale, unit = SHOW[r["statistic"]]
        row = rows.setdefault(r["label"], {"objects": int(r["n_objects"]), "queries": int(r["n_queries"])})
        row[NAMES[r["statistic"]] + (f", {unit.strip()}" if unit.strip() else "")] = \
            Estimate(r["value"], r["low"], r["high"], 0, 0).text(fmt, scale)
    out = pd.DataFrame(rows).T
    out.index.name = "method"
    return out.reset_index()
