"""The paper's tables and claims, built from evaluation metrics (:mod:`hbeo.reproduction.evaluate` JSON dicts),
and writing any notebook table into the run folder.

Every paper table carries a ``source`` column: ``reported`` (the paper, :func:`paper_table`, from
``paper/reported/*.csv``) or ``reproduced`` (this run). :func:`to_markdown` formats any table as
Markdown; :func:`save_csv` and :func:`save_markdown` write one (atomically) to
:meth:`hbeo.rundir.RunDir.table`.

May import: foundation.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from hbeo import config
from hbeo.conventions import CLASSES
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text

#: The paper's reported numbers (``table1_classification.csv``, ``table2_runtime.csv``).
REPORTED = config.REPO_ROOT / "paper" / "reported"

#: Display names of (method, pose) settings, as the paper labels them.
LABELS = {("hbeo", "3dof"): "HBEO (3-DOF)", ("beo", "known"): "BEO (known pose)", ("beo", "1dof"): "BEO (1-DOF)",
          ("beo", "3dof"): "BEO (3-DOF, true class)", ("icp", "3dof"): "ICP (3-DOF, true class)",
          ("icp", "1dof"): "ICP (1-DOF, true class)", ("voxcnn", "known"): "3-D CNN on partial grid (known pose)",
          ("class_mean", "-"): "class mean shape (HBEO's class)"}
_PAPER_SETTING = {"known_pose": "known", "unknown_pose_1dof": "1dof", "unknown_pose_3dof": "3dof"}


def label(metrics: dict) -> str:
    key = (metrics["method"], metrics["pose"])
    return LABELS.get(key, f"{key[0]} ({key[1]})") + (" + verify" if metrics.get("verify") else "")


def paper_table(name: str) -> pd.DataFrame:
    """The paper's reported numbers: ``table1_classification`` or ``table2_runtime``."""
    return pd.read_csv(REPORTED / f"{name}.csv")


def save_csv(df: pd.DataFrame, run, name: str, index: bool = False) -> Path:
    """Write ``df`` to the run's table ``name`` (``NN_name.csv``) atomically; returns the path."""
    path = RunDir.of(run).table(name)
    atomic_text(path, df.to_csv(index=index))
    return path


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

    ``total`` is the accuracy over all queries (as the paper's totals, which weight classes by
    their test counts). Settings that were given the true class are left out (accuracy 1 by
    construction)."""
    rows = []
    for m in evals:
        if m.get("given_class"):
            continue
        r = {"source": "reproduced", "setting": m["pose"], "method": label(m)}
        for c in CLASSES:
            pc = m["per_class"].get(c)
            r[c] = 100 * pc["accuracy"] if pc else np.nan
        r["total"] = 100 * m["accuracy"]
        r["queries"] = m["n_queries"]
        rows.append(r)
    if reported is not None:
        for _, p in reported.iterrows():
            r = {"source": "reported", "setting": _PAPER_SETTING.get(p["setting"], p["setting"]), "method": p["method"]}
            r.update({c: float(p[c]) for c in CLASSES})
            r["total"], r["queries"] = float(p["total"]), np.nan
            rows.append(r)
    order = {"known": 0, "1dof": 1, "3dof": 2}
    df = pd.DataFrame(rows)
    df["_o"] = df["setting"].map(order)
    df["_s"] = (df["source"] == "reproduced").astype(int)            # the paper's rows first
    return df.sort_values(["_o", "_s", "method"]).drop(columns=["_o", "_s"]).reset_index(drop=True)


def pose_summary(evals: list[dict]) -> pd.DataFrame:
    """Mean / median raw and symmetry-aware pose error (degrees) per evaluation that estimates pose."""
    rows = []
    for m in evals:
        if m["pose"] == "known":
            continue
        q = m["per_query"]
        rows.append({"method": label(m), "queries": m["n_queries"], "mean (°)": float(np.mean(q["pose_deg"])),
                     "median (°)": float(np.median(q["pose_deg"])),
                     "mean mod. symmetry (°)": float(np.mean(q["pose_sym_deg"])),
                     "median mod. symmetry (°)": float(np.median(q["pose_sym_deg"])),
                     "share < 30° (%)": 100 * float(np.mean(np.asarray(q["pose_deg"]) < 30))})
    return pd.DataFrame(rows)


def pose_per_class(evals: list[dict]) -> pd.DataFrame:
    """Median raw pose error (degrees) per class (rows) and evaluation (columns)."""
    out = {}
    for m in evals:
        if m["pose"] != "known":
            out[label(m)] = {c: v["pose_median_deg"] for c, v in m["per_class"].items()}
    return pd.DataFrame(out).reindex([c for c in CLASSES if any(c in v for v in out.values())])


def completion_summary(evals: list[dict]) -> pd.DataFrame:
    """Completion errors per evaluation: EDT e' (the paper's metric), naive e, IoU, empty share;
    plus the trivial class-mean answer (from the HBEO evaluation) for scale."""
    rows = []
    for m in evals:
        c = m["completion"]
        rows.append({"method": label(m), "queries": m["n_queries"], "EDT e'": c["edt"], "naive e": c["naive"],
                     "IoU": c["iou"], "empty (%)": 100 * c.get("empty_fraction", np.nan)})
        if m["method"] == "hbeo" and "completion_baseline" in m:
            b = m["completion_baseline"]["predicted_class"]
            rows.append({"method": LABELS[("class_mean", "-")], "queries": m["n_queries"], "EDT e'": b["edt"],
                         "naive e": b["naive"], "IoU": b["iou"], "empty (%)": np.nan})
    return pd.DataFrame(rows)


def table2(evals: list[dict], reported: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table II: mean seconds per query of each evaluation, the paper's figure beside."""
    rep = {}
    if reported is not None:
        for _, p in reported.iterrows():
            pose = {"known_pose": "known"}.get(p["pose_setting"], p["pose_setting"])
            rep[(str(p["method"]).lower(), pose)] = float(p["mean_runtime_s"])
    rows = []
    for m in evals:
        key = (m["method"], m["pose"])
        rows.append({"method": label(m), "reproduced (s)": m["runtime_ms"]["mean_per_query"] / 1e3,
                     "paper (s)": rep.pop(key, np.nan), "queries": m["n_queries"]})
    for (meth, pose), v in rep.items():
        rows.append({"method": f"{meth} ({pose}), reported only", "reproduced (s)": np.nan, "paper (s)": v,
                     "queries": np.nan})
    return pd.DataFrame(rows)


def claims(evals: list[dict]) -> pd.DataFrame:
    """The paper's qualitative claims, each with the numbers that decide it on this run."""
    by = {(m["method"], m["pose"]): m for m in evals}
    rows = []

    def add(claim, values, holds):
        rows.append({"claim (paper)": claim, "this run": values, "holds": "yes" if holds else "no"})

    h, b3, i3 = by.get(("hbeo", "3dof")), by.get(("beo", "3dof")), by.get(("icp", "3dof"))
    if h and b3:
        hm, bm = h["pose_error_deg"]["mean"], b3["pose_error_deg"]["mean"]
        add("HBEO's mean 3-DOF pose error is less than half of BEO's", f"HBEO {hm:.1f}°, BEO {bm:.1f}°", hm < bm / 2)
    if h and i3:
        hm, im = h["pose_error_deg"]["mean"], i3["pose_error_deg"]["mean"]
        add("HBEO's pose error is below the ICP baseline's", f"HBEO {hm:.1f}°, ICP {im:.1f}°", hm < im)
    bk, b1 = by.get(("beo", "known")), by.get(("beo", "1dof"))
    if h and bk:
        ha, ba = h["accuracy"], bk["accuracy"]
        add("HBEO (unknown 3-DOF pose) classifies better than BEO with known pose",
            f"HBEO {100 * ha:.1f} %, BEO {100 * ba:.1f} %", ha > ba)
    if h and b1:
        add("HBEO's misclassification rate is less than half of BEO's (1-DOF)",
            f"HBEO {100 * (1 - h['accuracy']):.1f} %, BEO {100 * (1 - b1['accuracy']):.1f} %",
            (1 - h["accuracy"]) < (1 - b1["accuracy"]) / 2)
    if h and bk:
        he, be = h["completion"]["edt"], bk["completion"]["edt"]
        add("HBEO completion (depth, unknown pose) is competitive with BEO on known-pose input "
            "(EDT e' within 25 %)", f"HBEO {he:.1f}, BEO known {be:.1f}", he <= 1.25 * be)
    if h and b1:
        he, be = h["completion"]["edt"], b1["completion"]["edt"]
        add("HBEO completion is clearly better than BEO (1-DOF)", f"HBEO {he:.1f}, BEO 1-DOF {be:.1f}", he < be)
    v = by.get(("voxcnn", "known"))
    if h and v:
        he, ve = h["completion"]["edt"], v["completion"]["edt"]
        add("HBEO completion is better than an end-to-end network with known pose (3DShapeNets' role)",
            f"HBEO {he:.1f}, 3-D CNN {ve:.1f}", he < ve)
    return pd.DataFrame(rows)


def accuracy_summary(evals: list[dict]) -> pd.DataFrame:
    """Accuracy (%) and query count of each evaluation, one row each."""
    return pd.DataFrame([{"method": label(m), "accuracy (%)": 100 * m["accuracy"], "queries": m["n_queries"]}
                         for m in evals]).set_index("method")


def worse_than_chance(evals: list[dict]) -> list[str]:
    """Labels of the evaluations whose accuracy is not above chance (1 / number of classes)."""
    return [label(m) for m in evals if m["accuracy"] <= 1 / len(m["classes"])]


def per_class(metrics: dict) -> pd.DataFrame:
    """One evaluation's per-class metrics, a row per class."""
    return pd.DataFrame(metrics["per_class"]).T


def table2_note(hw: dict) -> str:
    """The hardware line under Table II (``hw`` from :func:`hbeo.reproduction.provenance.hardware`)."""
    return (f"\n\nReproduced on: {hw['cpu']}, {hw['cores']} cores, {hw['gpu'] or 'no GPU'}. "
            "Paper: 4-core Intel CPU + GTX 1070 (Matlab BEO, TensorFlow HBEONet).\n")
