"""The figures of notebooks 05-07 (the paper's Table I, pose and completion figures, Table II),
drawn from evaluation metrics (:mod:`hbeo.reproduction.evaluate` dicts) and the tables of
:mod:`hbeo.reproduction.tables`. Each function returns a matplotlib figure; notebooks save it with
:func:`hbeo.reproduction.figures.save`.

May import: foundation and the other reproduction modules (matplotlib lazily).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from hbeo.conventions import CLASSES
from hbeo.reproduction import figures
from hbeo.reproduction.tables import label


def confusion_grid(evals: list[dict], title: str):
    """One confusion matrix per evaluation, side by side, titled with its accuracy."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(evals), figsize=(4.2 * len(evals), 4.4))
    for ax, m in zip(np.atleast_1d(axes), evals):
        figures.confusion(ax, m["confusion"], m["classes"], f"{label(m)}: {100 * m['accuracy']:.1f} %")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def per_class_bars(t1: pd.DataFrame):
    """Table I per class as grouped bars, one bar per row of ``t1`` (reported rows hatched)."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(11, 3.4))
    rows = t1.set_index(t1["source"] + ": " + t1["method"] + " [" + t1["setting"] + "]")
    w = 0.8 / len(rows)
    for k, (name, r) in enumerate(rows.iterrows()):
        ax.bar(np.arange(len(CLASSES)) + k * w, [r[c] for c in CLASSES], w, label=name,
               hatch="//" if r["source"] == "reported" else None, alpha=0.85)
    ax.set_xticks(np.arange(len(CLASSES)) + 0.4 - w / 2, [c.replace("_", " ") for c in CLASSES], fontsize=8)
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=6, ncol=2)
    ax.set_title("Table I per class (hatched: the paper's reported figures)")
    fig.tight_layout()
    return fig


def pose_errors(evals: list[dict]):
    """The paper's pose figure: violins of the raw geodesic error and of the error modulo the
    classes' near-symmetric turns about the up axis, one per evaluation (degrees)."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for a, key, title in ((ax[0], "pose_deg", "raw geodesic error (the paper's metric)"),
                          (ax[1], "pose_sym_deg", "modulo near-symmetric turns about the up axis")):
        figures.error_violins(a, {label(m).replace(" (", "\n("): m["per_query"][key] for m in evals},
                              "pose error (degrees)", title)
    ax[0].set_ylim(0, 180)
    fig.tight_layout()
    return fig


def completion_bars(cs: pd.DataFrame):
    """The completion summary (:func:`hbeo.reproduction.tables.completion_summary`) as bars of EDT
    e', naive e and IoU per method (HBEO blue, the class-mean answer grey, the others orange)."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.6))
    colors = ["C0" if "HBEO" in m else "C7" if "mean" in m else "C1" for m in cs["method"]]
    for a, col in zip(ax, ["EDT e'", "naive e", "IoU"]):
        a.barh(cs["method"], cs[col], color=colors)
        a.set_xlabel(col + (" (higher is better)" if col == "IoU" else " (lower is better)"))
        a.invert_yaxis()
    for a in ax[1:]:
        a.set_yticklabels([])
    fig.suptitle("Completion of the test objects (mean over queries)")
    fig.tight_layout()
    return fig


def completion_gallery(samples: list[dict]):
    """Rows of input depth, true grid, HBEO's and BEO's (known pose) completion, from
    :func:`hbeo.reproduction.protocol.sample_completions`."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(samples), 4, figsize=(7.2, 1.9 * len(samples)), squeeze=False)
    for row, s in zip(axes, samples):
        figures.show_depth(row[0], s["depth"], f"input: {s['class']}")
        for a, key, title in zip(row[1:], ["truth", "hbeo", "beo"],
                                 ["truth", f"HBEO: {s['hbeo_class']}", f"BEO known pose: {s['beo_class']}"]):
            a.imshow(figures.render_voxels(s[key], size=110))
            a.set_title(title, fontsize=8)
            a.axis("off")
    fig.tight_layout()
    return fig


def runtime_bars(t2: pd.DataFrame, hw: dict):
    """Table II as bars, this run beside the paper, seconds per query on a log scale (``hw`` from
    :func:`hbeo.reproduction.provenance.hardware`)."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.6))
    y = np.arange(len(t2))
    ax.barh(y - 0.2, t2["reproduced (s)"], 0.4, label=f"this run ({hw['cores']}-core CPU, {hw['gpu'] or 'no GPU'})")
    ax.barh(y + 0.2, t2["paper (s)"], 0.4, label="paper (4-core CPU + GTX 1070)", hatch="//", alpha=0.7)
    ax.set_yticks(y, t2["method"], fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("seconds per query (log scale)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
