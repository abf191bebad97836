"""The completion gap, taken apart: ``06_completion_decomposition.csv/.md/.png`` of a run, its section of
``REPRODUCTION.md`` and its figure for notebook 06.

:func:`write_decomposition` (``python -m hbeo report --completion-decomposition RUN``) runs the run's HBEO model on
its validation and test query views (:func:`hbeo.evaluation.decompose.collect`), reads the run's evaluations of
the same test queries (``eval_hbeo_3dof.json``, ``eval_beo_known.json``, ``eval_voxcnn_known.json``) and writes
the table of :func:`hbeo.evaluation.decompose.decomposition` (columns :data:`~hbeo.evaluation.decompose.COLUMNS`;
e' in voxel units, IoU a fraction, elevations in degrees) as CSV and Markdown. :func:`section` builds the
Markdown section :data:`TITLE` from the CSV alone; :func:`figure` draws it. Nothing here changes a number.

May import: foundation, model, run, evaluation and :mod:`hbeo.report.tables`.
"""
from __future__ import annotations

import os

import numpy as np
import pandas as pd

from hbeo.model.completion_rule import NONEMPTY_THRESHOLD
from hbeo.report import tables as T
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text, read_json

#: the table's name in a run folder (``.csv`` and ``.md``)
NAME = "06_completion_decomposition"
TITLE = "The completion gap, taken apart"
COMMAND = "python -m hbeo report --completion-decomposition {run}"


def write_decomposition(run, progress: bool = True) -> list:
    """Compute and write ``NAME.csv``, ``NAME.md`` and the figure ``NAME.png`` in ``run``; returns their paths."""
    from hbeo.evaluation.decompose import collect, decomposition
    from hbeo.evaluation.protocol import eval_plan
    from hbeo.model.inference import HBEO
    from hbeo.run import load_dataset
    run = RunDir.of(run)
    evals = {k: read_json(run.evaluation(*mp), "metrics", dict) if run.evaluation(*mp).exists() else None
             for k, mp in (("hbeo", ("hbeo", "3dof")), ("beo", ("beo", "known")), ("voxcnn", ("voxcnn", "known")))}
    if evals["hbeo"] is None or evals["beo"] is None:
        raise FileNotFoundError(f"{run.path}: needs eval_hbeo_3dof.json and eval_beo_known.json (notebook 06)")
    model = HBEO.load(run.model)
    h = evals["hbeo"]
    lacking = [k for k in ("dataset", "views", "seed") if h.get(k) is None]
    if lacking:
        from hbeo.errors import DataError
        raise DataError(run.evaluation("hbeo", "3dof"), f"records no {', '.join(lacking)}: not a metrics file of "
                                                          "python -m hbeo evaluate (evaluate again)")
    ds = load_dataset(h["dataset"], model.settings.profile or "cpu")
    views, seed = int(h["views"]), int(h["seed"])
    # the test objects the evaluation files scored (the profile's first objects of each class, or all)
    per_class, _ = eval_plan(model.settings.profile or "cpu", "hbeo", "3dof")
    val = collect(model, ds, "val", views, seed, progress=progress)
    test = collect(model, ds, "test", views, seed, per_class=per_class, progress=progress)
    table, _ = decomposition(model, test, val, evals)
    csv, md = run.table(NAME), run.table(NAME, "md")
    atomic_text(csv, table.to_csv(index=False, float_format="%.6g"))
    atomic_text(md, "\n".join(markdown(table, os.path.relpath(run.path, _root()))) + "\n")
    import matplotlib.pyplot as plt
    from hbeo.report.figures import save
    fig = figure(run)
    png = save(fig, run, NAME)
    plt.close(fig)
    return [csv, md, png]


def _root():
    from hbeo import config
    return config.REPO_ROOT


def _ci(r) -> str:
    return f"{r.mean_edt:.0f} [{r.mean_edt_low:.0f}, {r.mean_edt_high:.0f}]"


def _block(t: pd.DataFrame, section: str, cols: dict) -> str:
    d = t[t["section"] == section]
    out = pd.DataFrame({head: (d.apply(f, axis=1) if callable(f) else d[f]) for head, f in cols.items()})
    return T.to_markdown(out.reset_index(drop=True))


def _count(r) -> str:
    return str(int(r["empty"]))           # not r.empty: a Series' own attribute (is it empty?)


def markdown(table: pd.DataFrame, run_rel: str = "RUN") -> list[str]:
    """The Markdown lines of the decomposition (tables of each section) from its table alone."""
    t = table
    val = t[t["section"] == "validation"]
    chosen = float(val.iloc[-1]["threshold"])
    comp = t[t["section"] == "completion"]
    hbeo = comp[comp["row"].str.startswith("HBEO (paper")].iloc[0]
    n_empty = int(hbeo["empty"])
    edt_cols = {"": "row", "n": lambda r: str(int(r.n)), "mean e' [95 %]": _ci,
                "median e'": lambda r: f"{r.median_edt:.0f}", "mean IoU": lambda r: f"{r.mean_iou:.3f}",
                "empty": _count}
    chk = t[t["section"] == "check"]
    agree = (f" The model run again for this table gives the evaluation file's class on "
             f"{100 * float(chk.iloc[0]['accuracy']):.2f} % of the {int(chk.iloc[0]['n'])} test queries, and an empty "
             f"completion at 0.5 where the file has one on all but {int(chk.iloc[0]['empty'])}." if len(chk) else "")
    lines = [f"Regenerate: `{COMMAND.format(run=run_rel)}` (`hbeo.evaluation.decompose`). e' in voxels; "
             "95 % bootstrap intervals over objects; every row scores the same paired queries. The metric gives an "
             "empty completion the grid's diagonal as its distance field everywhere (`hbeo.subspace.metrics`), so "
             + (f"each of HBEO's {n_empty} empty test completions costs" if n_empty != 1 else
              "HBEO's one empty test completion costs") + " several thousand e'." + agree, "",
             "**Test queries** (the threshold row and the never-empty row are deviations from the paper, chosen on "
             "validation; the paper's 0.5 beside them):", "",
             _block(t, "completion", {**edt_cols, "accuracy": lambda r: "–" if pd.isna(r.accuracy) else
                                      f"{100 * r.accuracy:.1f} %"}), "",
             *_validation(val, chosen), "",
             "**HBEO's coefficients against the target W^T o** (test; R² about the overall mean, and about each "
             "class's mean target: 0 there is no better than each class's average coefficients):", "",
             _block(t, "coefficients", {"": "row", "share of squared error": lambda r: f"{100 * r.error_share:.1f} %",
                                        "R² (overall)": lambda r: f"{r.r2_global:.3f}",
                                        "R² (within class)": lambda r: f"{r.r2_class:.3f}"}), "",
             "**HBEO's completions by whether its class and pose were right** (test, paper's rule):", "",
             _block(t, "hbeo_split", edt_cols), "",
             "**By camera elevation** (test; the optical axis's elevation above the object's horizon, recovered from "
             "each query's view stream):", "",
             _block(t, "elevation", {**edt_cols, "accuracy": lambda r: f"{100 * r.accuracy:.1f} %"}), "",
             "**Empty completions per class** (test):", "",
             _empty_block(t), ""]
    return lines


def _validation(val: pd.DataFrame, chosen: float) -> list[str]:
    """The validation scan's heading and table: one line per threshold, the paper's rule and the never-empty rule
    beside it (a table from the rule's first version has the never-empty rule at the chosen threshold only)."""
    from hbeo.evaluation.decompose import SCAN_NONEMPTY, SCAN_PAPER
    paper = val[val["row"].str.startswith(SCAN_PAPER)].set_index("threshold")
    never = val[val["row"].str.startswith(SCAN_NONEMPTY)].set_index("threshold")
    first = never.empty
    if first:
        never = val.iloc[[-1]].set_index("threshold")
    ts = sorted(set(paper.index) | set(never.index))
    edge = chosen in (min(ts), max(ts)) and len(ts) > 2
    by = ("lowest mean e' of the paper's rule (the rule's first version, no fallback)" if first else
          "lowest mean e' of the never-empty rule, the rule HBEO answers by")
    head = (f"**Validation queries** (the threshold scan; chosen by {by}: **{chosen:g}**"
            + (", the edge of the scanned range, which was fixed with the rule before the scan ran: a threshold "
               "beyond it was not tried" if edge else "")
            + ("" if chosen == NONEMPTY_THRESHOLD else
               f"; HBEO's default never-empty rule keeps {NONEMPTY_THRESHOLD:g}, chosen the same way on the ModelNet10 "
               "reference run's validation queries, and the rows above use this run's own choice") + "):")

    def cell(d, t, f):
        return f(d.loc[t]) if t in d.index else "–"
    cols = {"threshold": [f"{t:g}" + (" (chosen)" if t == chosen else "") for t in ts],
            "n": [str(int((paper.loc[t] if t in paper.index else never.loc[t])["n"])) for t in ts]}
    for who, d in (("paper's rule", paper), ("never empty", never)):
        cols[f"{who}: mean e' [95 %]"] = [cell(d, t, _ci) for t in ts]
        cols[f"{who}: median e'"] = [cell(d, t, lambda r: f"{r.median_edt:.0f}") for t in ts]
        cols[f"{who}: mean IoU"] = [cell(d, t, lambda r: f"{r.mean_iou:.3f}") for t in ts]
        if d is paper:
            cols["paper's rule: empty"] = [cell(paper, t, lambda r: str(int(r["empty"]))) for t in ts]
    return [head, "", T.to_markdown(pd.DataFrame(cols))]


def _empty_block(t: pd.DataFrame) -> str:
    e = t[t["section"] == "empty"].copy()
    e[["method", "class"]] = e["row"].str.rsplit(": ", n=1, expand=True)
    wide = e.pivot_table(index="class", columns="method", values="empty", aggfunc="first", sort=False)
    n = e.drop_duplicates("class").set_index("class")["n"]
    wide = wide.astype(int)
    wide.insert(0, "queries", n.loc[wide.index].astype(int))
    return T.to_markdown(wide.reset_index().astype({c: str for c in wide.columns}))


def section(run, man: dict | None = None) -> list[str]:
    """The lines of the section :data:`TITLE` of ``REPRODUCTION.md`` from the run's ``NAME.csv`` (a line saying
    how to make it when the run has none)."""
    run = RunDir.of(run)
    path = run.table(NAME)
    head = [f"## {TITLE}", ""]
    if not path.exists():
        return head + [f"Not computed for this run: `{COMMAND.format(run=run.path)}` writes it.", ""]
    return head + markdown(pd.read_csv(path), os.path.relpath(run.path, _root())) + [""]


def figure(run):
    """Notebook 06's figure of the decomposition: mean e' of each test row, the validation threshold scan, and
    accuracy and IoU by camera elevation. Returns the matplotlib figure."""
    import matplotlib.pyplot as plt
    t = pd.read_csv(RunDir.of(run).table(NAME))
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    comp = t[t["section"] == "completion"]
    y = np.arange(len(comp))
    ax[0].barh(y, comp["mean_edt"], xerr=[comp["mean_edt"] - comp["mean_edt_low"],
                                          comp["mean_edt_high"] - comp["mean_edt"]], color="tab:blue")
    ax[0].set_yticks(y, [r if len(r) < 40 else r[:38] + "…" for r in comp["row"]], fontsize=7)
    ax[0].invert_yaxis()
    ax[0].set_xlabel("mean e' (test, voxels)")
    from hbeo.evaluation.decompose import SCAN_NONEMPTY, SCAN_PAPER
    val = t[t["section"] == "validation"]
    for prefix, who, mark in ((SCAN_PAPER, "paper's rule", "o"), (SCAN_NONEMPTY, "never empty", "^")):
        d = val[val["row"].str.startswith(prefix)]
        if len(d):
            ax[1].plot(d["threshold"], d["mean_edt"], mark + "-", label=f"{who}: mean e'")
            ax[1].plot(d["threshold"], d["median_edt"], mark + "--", alpha=0.6, label=f"{who}: median e'")
    ax[1].set_xlabel("completion threshold (validation)")
    ax[1].set_ylabel("e' (voxels)")
    ax[1].legend()
    el = t[t["section"] == "elevation"]
    for who, mark in (("HBEO", "o-"), ("BEO, known pose", "s--")):
        d = el[el["row"].str.startswith(who + ",")]
        names = [r.split(", ")[-1].split(" (")[0] for r in d["row"]]
        ax[2].plot(names, d["accuracy"], mark, label=f"{who}: accuracy")
        ax[2].plot(names, d["mean_iou"], mark, alpha=0.5, label=f"{who}: IoU")
    ax[2].set_ylim(0, 1)
    ax[2].set_xlabel("camera elevation (test)")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    return fig
