"""The figures of notebooks 05-07 (the paper's Table I, pose and completion figures, Table II),
drawn from evaluation metrics (:mod:`hbeo.evaluation.evaluate` dicts) and the tables of
:mod:`hbeo.report.tables`. Each function returns a matplotlib figure; notebooks save it with
:func:`hbeo.report.figures.save`.

Every method has one colour in every figure (:data:`hbeo.report.figures.METHOD_COLORS`; the
paper's reported figures in its light shade). Distributions are drawn beside their means, legends
sit outside the axes (right of the panels), and each axis says which direction is better
(:data:`BETTER`).

May import: foundation and the other reproduction modules (matplotlib lazily).
"""
from __future__ import annotations

import re

import numpy as np
import pandas as pd

from hbeo.conventions import CLASSES
from hbeo.report import figures
from hbeo.evaluation.method import LABELS, label
from hbeo.machine import describe

LOWER, HIGHER = "↓ lower is better", "↑ higher is better"
#: Which direction is better for each per-query column: errors and times lower; the naive score
#: e = 1 - |o - o_hat| / |o| (1 for a perfect completion, :func:`hbeo.subspace.metrics.naive_error`)
#: and IoU higher.
BETTER = {"edt": LOWER, "naive": HIGHER, "iou": HIGHER, "pose_deg": LOWER, "pose_sym_deg": LOWER, "ms": LOWER,
          "accuracy": HIGHER}
#: The completion panels: per-query column, axis name, log scale.
COMPLETION_PANELS = (("edt", "EDT error e' (the paper's metric)", True),
                     ("naive", "naive score e = 1 − ‖o − ô‖ / ‖o‖  (1 = perfect)", False),
                     ("iou", "IoU", False))
SYMBOL = {"edt": "e'", "naive": "e", "iou": "IoU"}
EDT_MEAN = "EDT e' mean"       # a column of tables.completion_summary (and ", non-empty")
_KEY_OF_LABEL = {v: k for k, v in LABELS.items()}


def row_key(name: str, setting: str | None = None):
    """:data:`~hbeo.report.figures.METHOD_COLORS` key of a table row: its ``method`` label
    (:func:`hbeo.evaluation.method.label`, a ``<method> (<pose>), reported only`` row of
    :func:`~hbeo.report.tables.table2`, or a paper method name with its ``setting``)."""
    key = _KEY_OF_LABEL.get(name)
    if key is None:
        m = re.fullmatch(r"(\S+) \((\w+)\)(, reported only)?", name)
        key = (m.group(1).lower(), m.group(2)) if m else (name.lower(), setting)
    if key[0] == "class_mean":
        return figures.CLASS_MEAN
    if key[0].endswith("-verify") or "verify" in name:
        return figures.HBEO_VERIFY
    return key


def empty_completions(per_query: dict) -> np.ndarray:
    """Bool (n,): the queries whose completed grid is empty (``empty`` where given, else IoU 0 and
    naive e exactly 0, which against a non-empty target only an empty grid gives)."""
    if "empty" in per_query:
        return np.asarray(per_query["empty"], bool)
    return (np.asarray(per_query["iou"], float) == 0) & (np.asarray(per_query["naive"], float) == 0)


def _wrap(name: str, width: int = 22) -> str:
    """Break a method label at spaces into lines of about ``width`` characters."""
    lines, cur = [], ""
    for word in name.split():
        if cur and len(cur) + 1 + len(word) > width:
            lines.append(cur)
            cur = word
        else:
            cur = f"{cur} {word}".strip()
    return "\n".join([*lines, cur])


def _outside_legend(fig, handles, loc: str = "outside right upper", **kw):
    """The figure's legend outside its panels (right, or ``loc``; constrained layout keeps it off the data)."""
    return fig.legend(handles=handles, loc=loc, fontsize=8, frameon=False, **kw)


def confusion_grid(evals: list[dict], title: str):
    """One confusion matrix per evaluation, side by side, titled with its accuracy."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(evals), figsize=(4.2 * len(evals), 4.6), layout="constrained")
    for ax, m in zip(np.atleast_1d(axes), evals):
        figures.confusion(ax, m["confusion"], m["classes"], f"{label(m)}: {100 * m['accuracy']:.1f} %")
    fig.suptitle(title)
    return fig


def per_class_bars(t1: pd.DataFrame):
    """Table I per class as grouped bars, one bar per row of ``t1`` in its method's colour: this
    run's rows dark, the paper's reported rows in the light shade, hatched."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(13, 3.8), layout="constrained")
    w = 0.8 / len(t1)
    for k, (_, r) in enumerate(t1.iterrows()):
        rep = r["source"] == "reported"
        color = figures.method_color(row_key(r["method"], r["setting"]), "light" if rep else "dark")
        ax.bar(np.arange(len(CLASSES)) + k * w, [r[c] for c in CLASSES], w, color=color,
               edgecolor="0.35" if rep else color, linewidth=0.4, hatch="///" if rep else None,
               label=f"{'paper' if rep else 'this run'}: {r['method']} [{r['setting']}]")
    ax.set_xticks(np.arange(len(CLASSES)) + 0.4 - w / 2, [c.replace("_", " ") for c in CLASSES], fontsize=8)
    ax.set_xlabel("true class")
    ax.set_ylabel(f"accuracy (%)  {HIGHER}")
    ax.set_ylim(0, 104)
    ax.set_title("Table I per class: single-view classification accuracy "
                 "(light, hatched: the paper's reported figures; dark: this run)", fontsize=10)
    _outside_legend(fig, ax.get_legend_handles_labels()[0])
    return fig


def pose_errors(evals: list[dict]):
    """The paper's pose figure: violins of the per-query raw geodesic error and of the error modulo
    the classes' near-symmetric turns about the up axis, one per evaluation (degrees), each in its
    method's colour with a box (median, interquartile range) inside and the mean as a dot."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True, layout="constrained")
    groups = {_wrap(label(m), 18): m for m in evals}
    colors = {k: figures.method_color(m) for k, m in groups.items()}
    for a, key, title in ((ax[0], "pose_deg", "raw geodesic error (the paper's metric)"),
                          (ax[1], "pose_sym_deg", "modulo near-symmetric turns about the up axis")):
        handles = figures.error_violins(a, {k: m["per_query"][key] for k, m in groups.items()},
                                        f"pose error (degrees)  {BETTER[key]}", title, colors)
        a.set_xlabel("method (n: queries)")
        a.yaxis.set_tick_params(labelleft=True)
    ax[0].set_ylim(0, 180)
    ax[0].set_yticks(range(0, 181, 30))
    fig.suptitle("Pose error in 3-DOF per query", fontsize=11)
    _outside_legend(fig, handles)
    return fig


def _completion_row(ax, y: float, values: np.ndarray, empty: np.ndarray, color: str):
    """One method's box (all queries: median, interquartile range, whiskers 1.5 IQR), its non-empty
    outliers as dots, its empty completions as crosses, and the means (all queries / non-empty)."""
    from matplotlib import cbook
    stats = cbook.boxplot_stats(values)[0]
    lo, hi = stats["whislo"], stats["whishi"]
    stats["fliers"] = values[~empty & ((values < lo) | (values > hi))]
    ax.bxp([stats], positions=[y], orientation="horizontal", widths=0.55, patch_artist=True, showmeans=False,
           boxprops=dict(facecolor=color, edgecolor="k", alpha=0.75, linewidth=0.8),
           medianprops=dict(color="k", linewidth=1.8), whiskerprops=dict(color="k", linewidth=0.8),
           capprops=dict(color="k", linewidth=0.8),
           flierprops=dict(marker="o", markersize=2.5, markerfacecolor=color, markeredgecolor="none", alpha=0.6))
    if empty.any():
        jitter = np.random.default_rng(0).uniform(-0.18, 0.18, int(empty.sum()))
        ax.scatter(values[empty], y + jitter, marker="x", s=22, color="k", linewidths=0.9, zorder=4)
        ax.scatter([values[~empty].mean()], [y], marker="o", s=48, facecolor="white", edgecolor="k", zorder=5)
    ax.scatter([values.mean()], [y], marker="o", s=40, color="k", zorder=6)


def completion_bars(cs: pd.DataFrame, evals: list[dict]):
    """The completion figure: per method (the rows of ``cs``,
    :func:`hbeo.report.tables.completion_summary`) a box of the per-query EDT e', naive e and
    IoU of ``evals`` (the evaluations ``cs`` was made from) in the method's colour, the mean over all
    queries as a black dot, and the empty completions apart: crosses at their scores, the mean over
    the non-empty completions as an open circle, and their count in the labels and the title. A row
    without per-query scores (the class-mean answer in older metrics) shows its mean only."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    by = {label(m): m for m in evals}
    hbeo = next((m for m in evals if m["method"] == "hbeo" and not m.get("verify")), None)
    n = len(cs)
    fig, axes = plt.subplots(1, 3, figsize=(14, 1.9 + 0.62 * n), sharey=True, layout="constrained")
    ticks, notes = [], []
    for y, (_, r) in enumerate(cs.iterrows()):
        key = row_key(r["method"])
        m = by.get(r["method"])
        color = figures.method_color(key)
        q = m["per_query"] if m is not None else None
        if key == figures.CLASS_MEAN:               # per-query scores only where the metrics carry them
            q = {c: hbeo["per_query"][f"baseline_{c}"] for c in ("edt", "naive", "iou")} \
                if hbeo is not None and "baseline_edt" in hbeo["per_query"] else None
        if q is not None:
            empty = empty_completions(q)
            for ax, (col, _, _) in zip(axes, COMPLETION_PANELS):
                _completion_row(ax, y, np.asarray(q[col], float), empty, color)
            k = int(empty.sum())
            ticks.append(f"{_wrap(r['method'], 24)}\nn={int(r['queries'])}" + (f", {k} empty" if k else ""))
            if k:
                notes.append(f"{r['method']}: {k} of {len(empty)} completions empty; mean e' "
                             f"{r[EDT_MEAN]:.0f} with them, {r[EDT_MEAN + ', non-empty']:.0f} without")
        else:
            base = hbeo.get("completion_baseline", {}).get("predicted_class") if hbeo is not None else None
            for ax, (col, _, _) in zip(axes, COMPLETION_PANELS):
                v = base[col] if base is not None else (r[EDT_MEAN] if col == "edt" else np.nan)
                ax.scatter([v], [y], marker="o", s=40, color="k", zorder=6)
                ax.scatter([v], [y], marker="s", s=110, color=color, alpha=0.75, zorder=5)
            ticks.append(f"{_wrap(r['method'], 24)}\nn={int(r['queries'])} (mean only)")
    for ax, (col, name, log) in zip(axes, COMPLETION_PANELS):
        ax.set_title(f"{name}\n{BETTER[col]}", fontsize=9)
        ax.set_xlabel(f"{SYMBOL[col]} per query{' (log scale)' if log else ''}  {BETTER[col]}", fontsize=8)
        if log:
            ax.set_xscale("log")
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(range(n), ticks, fontsize=7)
    axes[0].set_ylim(n - 0.4, -0.6)
    axes[0].set_ylabel("method (n: queries)")
    handles = [Patch(facecolor="0.75", edgecolor="k", label="box: interquartile range of the queries,\n"
                                                            "line: median, whiskers: 1.5 IQR"),
               Line2D([], [], ls="", marker="o", markersize=3, color="0.5", label="non-empty query beyond whiskers"),
               Line2D([], [], ls="", marker="o", markersize=7, color="k", label="mean over all queries"),
               Line2D([], [], ls="", marker="x", markersize=6, color="k", label="empty completion (grid empty)"),
               Line2D([], [], ls="", marker="o", markersize=7, markerfacecolor="white", markeredgecolor="k",
                      label="mean over non-empty completions")]
    _outside_legend(fig, handles, loc="outside lower center", ncol=3)
    fig.suptitle("Completion of the test objects, per query" + ("\n" + "\n".join(notes) if notes else
                                                                " (no empty completions)"), fontsize=10)
    return fig


def completion_gallery(samples: list[dict]):
    """Rows of input depth, true grid, HBEO's and BEO's (known pose) completion, from
    :func:`hbeo.evaluation.protocol.sample_completions`; an empty completion's panel says so in its title."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(samples), 4, figsize=(7.2, 1.9 * len(samples)), squeeze=False)
    for row, s in zip(axes, samples):
        figures.show_depth(row[0], s["depth"], f"input: {s['class']}")
        for a, key, title in zip(row[1:], ["truth", "hbeo", "beo"],
                                 ["truth", f"HBEO: {s['hbeo_class']}", f"BEO known pose: {s['beo_class']}"]):
            a.imshow(figures.render_voxels(s[key], size=110))
            empty = not np.asarray(s[key]).any()
            a.set_title(title + ("\n(empty completion)" if empty else ""), fontsize=8)
            a.axis("off")
    fig.tight_layout()
    return fig


def runtime_bars(t2: pd.DataFrame, hw: dict, evals=()):
    """Table II (:func:`hbeo.report.tables.table2`) as bars per method in its colour, seconds
    per query on a log scale: this run's median with interquartile-range error bars (dark) and mean
    (diamond) beside the paper's reported mean (light, hatched). The legend names the machine that timed
    ``evals`` (the metrics dicts behind ``t2``; each records its ``hardware``) when they all record one, else
    points to the note under Table II (:func:`hbeo.report.tables.table2_note`); without ``evals``, ``hw``
    (:func:`hbeo.machine.hardware`)."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    fig, ax = plt.subplots(figsize=(11, 1.4 + 0.55 * len(t2)), layout="constrained")
    y = np.arange(len(t2))
    for i, (_, r) in enumerate(t2.iterrows()):
        key = row_key(r["method"])
        med, p25, p75 = r["median (s)"], r["p25 (s)"], r["p75 (s)"]
        if np.isfinite(med):
            err = [[med - p25], [p75 - med]] if np.isfinite(p25) and np.isfinite(p75) else None
            ax.barh(i - 0.2, med, 0.4, color=figures.method_color(key), xerr=err,
                    error_kw=dict(ecolor="k", capsize=3, linewidth=1))
            ax.scatter([r["mean (s)"]], [i - 0.2], marker="D", s=22, color="k", zorder=4)
            ax.text(max(p75 if np.isfinite(p75) else med, r["mean (s)"]) * 1.25, i - 0.2, _seconds(med),
                    va="center", fontsize=7)
        if np.isfinite(r["paper: mean (s)"]):
            ax.barh(i + 0.2, r["paper: mean (s)"], 0.4, color=figures.method_color(key, "light"), hatch="///",
                    edgecolor="0.35", linewidth=0.4)
            ax.text(r["paper: mean (s)"] * 1.25, i + 0.2, _seconds(r["paper: mean (s)"]), va="center", fontsize=7)
    ax.set_yticks(y, [_wrap(m, 26) for m in t2["method"]], fontsize=8)
    ax.set_ylim(len(t2) - 0.4, -0.6)
    ax.set_xscale("log")
    lo = np.nanmin(t2[["p25 (s)", "median (s)", "paper: mean (s)"]].to_numpy(float))
    hi = np.nanmax(t2[["p75 (s)", "mean (s)", "paper: mean (s)"]].to_numpy(float))
    ax.set_xlim(lo / 2, hi * 8)
    ax.set_xlabel(f"seconds per query (log scale)  {BETTER['ms']}")
    ax.set_ylabel("method")
    ax.grid(axis="x", alpha=0.3)
    ax.set_title("Table II: inference time per query, this run beside the paper", fontsize=10)
    handles = [Patch(facecolor="0.35", label=f"this run: median, error bar: p25-p75\n({_timed_on(hw, evals)})"),
               Line2D([], [], ls="", marker="D", markersize=5, color="k", label="this run: mean"),
               Patch(facecolor="0.8", hatch="///", edgecolor="0.35",
                     label="paper: mean (reported)\n(4-core CPU + GTX 1070)")]
    _outside_legend(fig, handles)
    return fig


def _timed_on(hw: dict, evals) -> str:
    """The machine for :func:`runtime_bars`' legend: the one every file of ``evals`` records, else where
    to read them; ``hw`` when no ``evals`` are given."""
    recs = [m.get("hardware") for m in evals]
    if recs and all(isinstance(r, dict) for r in recs) and len({describe(r) for r in recs}) == 1:
        hw = recs[0]
    elif recs:
        return "timed on several machines, or not recorded: the note under Table II"
    return f"{hw.get('cores')}-core CPU, {hw.get('gpu') or 'no GPU'}, torch threads {hw.get('torch_threads')}"


def _seconds(s: float) -> str:
    """A duration for a bar label: ms below one second, else seconds."""
    return f"{s * 1e3:.3g} ms" if s < 1 else f"{s:.3g} s" if s < 100 else f"{s:.0f} s"
