"""The paper's tables, built from evaluation metrics (:mod:`hbeo.evaluation.evaluate` JSON dicts; the claims and
intervals are :mod:`hbeo.evaluation.paired`'s), the paper's claims judged on one reading's evaluations
(:func:`claims`), and writing any notebook table into the run folder.

Every paper table carries a ``source`` column: ``reported`` (the paper, :func:`paper_table`, from
``paper/reported/*.csv``) or ``reproduced`` (this run). :func:`to_markdown` formats any table as
Markdown; :func:`save_table` writes one as CSV and Markdown (:func:`save_csv` CSV only) atomically to
:meth:`hbeo.rundir.RunDir.table`. The tables' names are the constants below (``TABLE1 = "05_table1"``
...), shared by the notebooks that write them and the report that reads them.

May import: foundation and :mod:`hbeo.evaluation` (labels, the paired statistics, the protocol's settings).
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from hbeo import config
from hbeo.conventions import CLASSES
from hbeo.evaluation import paired
from hbeo.evaluation.method import LABELS, label
from hbeo.evaluation.protocol import VERIFIED
from hbeo.machine import describe
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text

#: The paper's reported numbers (``table1_classification.csv``, ``table2_runtime.csv``).
REPORTED = config.REPO_ROOT / "paper" / "reported"

#: Display names of (method, pose) settings, as the paper labels them.
_PAPER_SETTING = {"known_pose": "known", "unknown_pose_1dof": "1dof", "unknown_pose_3dof": "3dof"}


# The run folder's tables, by the notebook that writes them (``NN_`` is the notebook's number).
CLASS_COUNTS = "01_class_counts"            #: objects per class and split
COMPONENTS = "02_components"                #: subspace components per class
PAPER_COUNTS = "02_paper_counts"            #: the component counts the paper implies
COMPLETION_FULL = "02_completion_full"      #: completion from full grids
COMPLETION_PARTIAL = "02_completion_partial"  #: completion from partial grids
STORAGE = "03_storage"                      #: the rendered set's size on disk
OPTIONS = "04_options"                      #: notebook 04's training variants on the validation objects
ACCURACY_CI = "05_accuracy_ci"              #: classification accuracy with intervals
TABLE1 = "05_table1"                        #: the paper's Table I beside ours
POSE_CI = "06_pose_ci"                      #: pose error with intervals
POSE = "06_pose"                            #: pose error summary
POSE_PER_CLASS = "06_pose_per_class"        #: pose error per class
COMPLETION_CI = "06_completion_ci"          #: completion error with intervals
COMPLETION = "06_completion"                #: completion error summary
CLAIMS = "06_claims"                        #: the paper's claims, paired tests
PER_QUERY = "07_per_query"                  #: one row per query and method (timings)
TABLE2 = "07_table2"                        #: the paper's Table II (runtime) beside ours
SEEDS = "seeds_table"                       #: the spread over training seeds of several runs (hbeo.report.seeds)
SEEDS_CLAIMS = "seeds_claims"               #: the paper's claims judged on each of those runs


def paper_table(name: str) -> pd.DataFrame:
    """The paper's reported numbers: ``table1_classification`` or ``table2_runtime``."""
    return pd.read_csv(REPORTED / f"{name}.csv")


def save_csv(df: pd.DataFrame, run, name: str, index: bool = False) -> Path:
    """Write ``df`` to the run's table ``name`` (``NN_name.csv``) atomically; returns the path."""
    path = RunDir.of(run).table(name)
    atomic_text(path, df.to_csv(index=index))
    return path


def save_table(df: pd.DataFrame, run, name: str, index: bool = False, markdown: pd.DataFrame | None = None,
               floatfmt: str = "{:.1f}", note: str = "") -> tuple[Path, Path]:
    """Write a table both ways: ``df`` to the run's ``NN_name.csv`` (:func:`save_csv`) and ``markdown``
    (default ``df``, e.g. a wide view of a long table) to ``NN_name.md`` (:func:`save_markdown`);
    returns both paths."""
    return (save_csv(df, run, name, index=index),
            save_markdown(df if markdown is None else markdown, run, name, floatfmt=floatfmt, note=note))


def save_markdown(df: pd.DataFrame, run, name: str, floatfmt: str = "{:.1f}", note: str = "") -> Path:
    """Write ``df`` as :func:`to_markdown` (followed by ``note``) to the run's ``NN_name.md``
    atomically; returns the path."""
    path = RunDir.of(run).table(name, "md")
    atomic_text(path, to_markdown(df, floatfmt=floatfmt) + note)
    return path


def to_markdown(df: pd.DataFrame, floatfmt: str = "{:.1f}", index: bool = False) -> str:
    """A GitHub Markdown table (no extra dependency); floats formatted with ``floatfmt``."""
    d = df.reset_index() if index else df

    def cell(v, col):
        if isinstance(v, (float, np.floating)):
            if not np.isfinite(v):
                return "–"
            return str(int(v)) if col == "queries" else floatfmt.format(v)
        return str(v)

    head = "| " + " | ".join(map(str, d.columns)) + " |"
    rule = "|" + "|".join(" ---: " if pd.api.types.is_numeric_dtype(d[c]) else " --- " for c in d.columns) + "|"
    rows = ["| " + " | ".join(cell(v, c) for v, c in zip(r, d.columns)) + " |" for r in d.itertuples(index=False)]
    return "\n".join([head, rule, *rows])


def table1(evals: list[dict], reported: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table I: per-class and total accuracy (%) of each evaluation, the paper's rows beside.

    ``class mean`` is the mean of the per-class accuracies (the paper's HBEO total is exactly that:
    81.8 = the mean of its ten class figures), ``total`` the accuracy over all queries. Settings that
    were given the true class are left out (accuracy 1 by construction)."""
    rows = []
    for m in evals:
        if m.get("given_class"):
            continue
        r = {"source": "reproduced", "setting": m["pose"], "method": label(m)}
        for c in CLASSES:
            pc = m["per_class"].get(c)
            r[c] = 100 * pc["accuracy"] if pc else np.nan
        r["class mean"] = float(np.mean([100 * v["accuracy"] for v in m["per_class"].values()]))
        r["total"] = 100 * m["accuracy"]
        r["queries"] = m["n_queries"]
        rows.append(r)
    if reported is not None:
        for _, p in reported.iterrows():
            r = {"source": "reported", "setting": _PAPER_SETTING.get(p["setting"], p["setting"]), "method": p["method"]}
            r.update({c: float(p[c]) for c in CLASSES})
            r["class mean"] = float(np.mean([r[c] for c in CLASSES]))
            r["total"], r["queries"] = float(p["total"]), np.nan
            rows.append(r)
    order = {"known": 0, "1dof": 1, "3dof": 2}
    df = pd.DataFrame(rows)
    df["_o"] = df["setting"].map(order)
    df["_s"] = (df["source"] == "reproduced").astype(int)            # the paper's rows first
    return df.sort_values(["_o", "_s", "method"]).drop(columns=["_o", "_s"]).reset_index(drop=True)


def pose_summary(evals: list[dict]) -> pd.DataFrame:
    """Pose error (degrees) per evaluation that estimates pose, from its per-query errors: the raw
    geodesic error and the error modulo near-symmetric turns about the up axis, each as median and
    interquartile range (``p25``, ``p75``) for every method; the mean of the raw error beside (the
    statistic the paper's pose figure marks), and the share of queries within 30°."""
    rows = []
    for m in evals:
        if m["pose"] == "known":
            continue
        raw = np.asarray(m["per_query"]["pose_deg"], float)
        sym = np.asarray(m["per_query"]["pose_sym_deg"], float)
        (r25, r50, r75), (s25, s50, s75) = np.percentile(raw, [25, 50, 75]), np.percentile(sym, [25, 50, 75])
        rows.append({"method": label(m), "queries": m["n_queries"], "median (°)": r50, "p25 (°)": r25,
                     "p75 (°)": r75, "mean (°, the paper's statistic)": float(raw.mean()),
                     "median mod. symmetry (°)": s50, "p25 mod. symmetry (°)": s25, "p75 mod. symmetry (°)": s75,
                     "share < 30° (%)": 100 * float(np.mean(raw < 30))})
    return pd.DataFrame(rows)


def pose_per_class(evals: list[dict]) -> pd.DataFrame:
    """Median raw pose error (degrees) per class (rows) and evaluation (columns)."""
    out = {}
    for m in evals:
        if m["pose"] != "known":
            out[label(m)] = {c: v["pose_median_deg"] for c, v in m["per_class"].items()}
    return pd.DataFrame(out).reindex([c for c in CLASSES if any(c in v for v in out.values())])


def completion_summary(evals: list[dict]) -> pd.DataFrame:
    """Completion errors per evaluation from its per-query scores (:mod:`hbeo.subspace.metrics`):
    EDT e' (the paper's metric; lower is better), naive e (1 is perfect; higher is better) and IoU
    (higher is better), each as median and interquartile range (``p25``, ``p75``) over all queries
    for every method. ``empty completions`` counts the queries whose completed grid is empty (per-query
    ``empty`` where the metrics carry it, else IoU 0 with naive e exactly 0, which against a non-empty
    target only an empty grid gives; checked against ``completion.empty_fraction``). An empty grid's
    e' is an order of magnitude above a typical one, so e' is also given over the non-empty
    completions (median and mean), beside the mean over all queries (``completion.edt``, the claims'
    statistic). Plus the trivial class-mean answer (from the HBEO evaluation) for scale: from per-query
    ``baseline_edt``, ``baseline_naive``, ``baseline_iou`` where the metrics carry them, else its mean e'."""
    def row(name, n, q, mean_edt, fraction=None):
        r = {"method": name, "queries": n, "empty completions": np.nan}
        if q is None:
            return {**r, "EDT e' mean": mean_edt}
        edt, nai, io = (np.asarray(q[k], float) for k in ("edt", "naive", "iou"))
        empty = np.asarray(q["empty"], bool) if "empty" in q else (io == 0) & (nai == 0)
        if fraction is not None and int(empty.sum()) != int(round(fraction * len(empty))):
            raise ValueError(f"{name}: {int(empty.sum())} empty completions found in per_query, but "
                             f"completion.empty_fraction says {fraction * len(empty):.0f}")
        r["empty completions"] = int(empty.sum())
        for tag, v in (("EDT e'", edt), ("naive e", nai), ("IoU", io)):
            r[f"{tag} p25"], r[f"{tag} median"], r[f"{tag} p75"] = np.percentile(v, [25, 50, 75])
        full = edt[~empty]
        r["EDT e' mean"] = float(edt.mean())
        r["EDT e' median, non-empty"] = float(np.median(full)) if len(full) else np.nan
        r["EDT e' mean, non-empty"] = float(full.mean()) if len(full) else np.nan
        return r

    rows = []
    for m in evals:
        rows.append(row(label(m), m["n_queries"], m["per_query"], None, m["completion"].get("empty_fraction")))
        if m["method"] == "hbeo" and not m.get("verify") and "completion_baseline" in m:
            q = m["per_query"]
            bq = {k: q[f"baseline_{k}"] for k in ("edt", "naive", "iou")} if "baseline_edt" in q else None
            rows.append(row(LABELS[("class_mean", "-")], m["n_queries"], bq,
                            m["completion_baseline"]["predicted_class"]["edt"]))
    cols = ["method", "queries", "empty completions", *[f"{t} {s}" for t in ("EDT e'", "naive e", "IoU")
                                                         for s in ("median", "p25", "p75")],
            "EDT e' mean", "EDT e' median, non-empty", "EDT e' mean, non-empty"]
    return pd.DataFrame(rows).reindex(columns=cols)


def table2(evals: list[dict], reported: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table II: seconds per query of each evaluation, from its per-query timings (``per_query``
    ``ms``): median and interquartile range (``p25``, ``p75``) for every method, and the mean beside
    ``paper: mean (s)`` (the paper reports means). Settings only the paper ran get a row
    ``<method> (<pose>), reported only``; HBEO with the verify step has no paper figure."""
    rep = {}
    if reported is not None:
        for _, p in reported.iterrows():
            pose = {"known_pose": "known"}.get(p["pose_setting"], p["pose_setting"])
            rep[(str(p["method"]).lower(), pose)] = float(p["mean_runtime_s"])
    rows, used = [], set()
    for m in evals:
        key = None if m.get("verify") else (m["method"], m["pose"])
        s = np.asarray(m["per_query"].get("ms", []), float) / 1e3
        if len(s):
            (p25, med, p75), mean = np.percentile(s, [25, 50, 75]), float(s.mean())
        else:               # metrics without per-query timings: no interquartile range to give
            p25 = p75 = np.nan
            med, mean = m["runtime_ms"]["median_per_query"] / 1e3, m["runtime_ms"]["mean_per_query"] / 1e3
        used.add(key)
        rows.append({"method": label(m), "queries": m["n_queries"], "median (s)": med, "p25 (s)": p25,
                     "p75 (s)": p75, "mean (s)": mean, "paper: mean (s)": rep.get(key, np.nan)})
    for (meth, pose), v in rep.items():
        if (meth, pose) not in used:
            rows.append({"method": f"{meth} ({pose}), reported only", "queries": np.nan, "median (s)": np.nan,
                         "p25 (s)": np.nan, "p75 (s)": np.nan, "mean (s)": np.nan, "paper: mean (s)": v})
    return pd.DataFrame(rows)


#: Who plays HBEO in the claims, in the claims table's order: HBEO as the paper trains it, then HBEO with
#: roll averaging and the verify step (ours), judged the same way.
PLAYERS = (paired.HBEO, (VERIFIED, "3dof"))


def claim_methods(claim: paired.Claim, player: tuple) -> tuple[tuple, tuple]:
    """The two (method, pose) settings ``claim`` compares when ``player`` plays HBEO (as
    :func:`hbeo.evaluation.paired.judge` substitutes it)."""
    return tuple(player if k == paired.HBEO else k for k in (claim.a, claim.b))


def claims(evals: Mapping[tuple, dict], players=PLAYERS) -> pd.DataFrame:
    """The paper's claims (:data:`hbeo.evaluation.paired.CLAIMS`) judged on one reading's evaluations
    ``evals`` ({(method, pose): metrics dict}, every one under the same reading of the view protocol):
    one :class:`~hbeo.evaluation.paired.PairedBootstrap` over all of them, then
    :func:`~hbeo.evaluation.paired.judge` with each of ``players`` playing HBEO. A row per claim whose two
    settings are both in ``evals``, players in order, claims in :data:`~hbeo.evaluation.paired.CLAIMS`
    order (the table ``06_claims`` holds); the index says which: (player's method, claim number)."""
    boot = paired.PairedBootstrap(list(evals.values()))
    rows, index = [], []
    for p in players:
        for i, c in enumerate(paired.CLAIMS):
            judged = paired.judge(boot, (c,), hbeo=p)
            if len(judged):
                rows.append(judged.iloc[0])
                index.append((p[0], i))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["player", "claim"]) if index else None)


def worse_than_chance(evals: list[dict]) -> list[str]:
    """Labels of the evaluations whose accuracy is not above chance (1 / number of classes)."""
    return [label(m) for m in evals if m["accuracy"] <= 1 / len(m["classes"])]


def per_class(metrics: dict) -> pd.DataFrame:
    """One evaluation's per-class metrics, a row per class."""
    return pd.DataFrame(metrics["per_class"]).T


def table2_note(hw: dict, evals=()) -> str:
    """The lines under Table II: the statistic, the machines its times were measured on and the paper's.

    Each evaluation file records the machine that timed it (``hardware``, :func:`hbeo.machine.hardware`); the
    note names it once when all agree, and the rows of each when they differ (times from two machines do not
    compare). Files made before evaluations recorded their machine are named as such, with ``hw`` (where this
    table is made: cpu, cores, gpu, torch threads) beside; without ``evals`` the note names ``hw``."""
    groups, unknown = {}, []
    for m in evals:
        rec = m.get("hardware")
        if isinstance(rec, dict):
            groups.setdefault(describe(rec), []).append(label(m))
        else:
            unknown.append(label(m))
    parts = [] if evals else [f"Reproduced on: {describe(hw)}."]
    if len(groups) == 1 and not unknown:
        parts.append(f"Timed on: {next(iter(groups))}.")
    elif groups:
        parts.append("Timed on: " + "; ".join(f"{d} ({', '.join(rows)})" for d, rows in groups.items()) + ".")
    if unknown:
        parts.append(f"Not recorded for {', '.join(unknown)} (evaluation files made before each recorded its "
                     f"machine; this table was made on {describe(hw)}).")
    where = " ".join(parts)
    return ("\n\nSeconds per query: median and interquartile range (p25-p75) over each evaluation's queries "
            "(one view per call, after one untimed warm-up call); the mean beside, as the paper reports means.\n"
            f"{where} Paper: 4-core Intel CPU + GTX 1070 (Matlab BEO, TensorFlow HBEONet).\n")
