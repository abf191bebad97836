"""Evaluating a model on rendered views of a dataset: the metrics JSON.

:func:`evaluate_model` renders each test object from ``views`` random viewpoints with the
model's own camera and distances (its training render settings), predicts, and scores.
Keys of the returned dict (stable; the evaluation notebooks and outside checks read them):

``hbeo_version``, ``dataset``, ``split``, ``views``, ``seed``, ``sampler``, ``noise``,
``n_objects``, ``n_queries``
``accuracy``                         fraction of queries with the right class
``pose_error_deg``                   ``mean``, ``median`` (geodesic, raw: the paper's metric) and
                                     ``mean_sym``, ``median_sym`` (modulo each class's near-symmetry
                                     turns about the up axis, :data:`hbeo.conventions.UP_SYMMETRY`)
``completion``                       ``edt``, ``naive``, ``iou`` (means; see :mod:`hbeo.metrics`)
``runtime_ms``                       ``mean_per_query``, ``median_per_query`` (preprocessing + network +
                                     back-projection, one view per call, after one warm-up call)
``per_class``                        {class: {``n``, ``accuracy``, ``pose_mean_deg``,
                                     ``pose_median_deg``, ``pose_median_sym_deg``, ``edt``,
                                     ``naive``, ``iou``}}
``confusion``                        rows: true class, columns: predicted class (counts)
"""
from __future__ import annotations

import numpy as np
from tqdm.auto import tqdm

from . import __version__
from .conventions import UP_SYMMETRY, geodesic_deg
from .gridset import record_grid
from .metrics import edt_error, iou, naive_error


def symmetric_pose_error(R_pred: np.ndarray, R_true: np.ndarray, order: int) -> np.ndarray:
    """Geodesic error (degrees) modulo ``order``-fold turns of the object about its up axis (+z):
    min over k of angle(R_pred, R_true @ Rz(2 pi k / order))."""
    errs = []
    for k in range(max(1, order)):
        a = 2 * np.pi * k / max(1, order)
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
        errs.append(geodesic_deg(R_pred, R_true @ Rz))
    return np.min(errs, axis=0)


def evaluate_model(model, dataset, split: str = "test", views: int = 1, seed: int = 0, sampler: str | None = None,
                   noise: bool = False, per_class: int | None = None, progress: bool = True,
                   chunk: int = 64) -> dict:
    """Render, predict and score; returns the metrics dict described in the module docstring.

    Views come from :class:`hbeo.renderset.ObjectViews` with the model's render settings, ``views``
    per object, ``seed``, ``noise`` and (if given) ``sampler``: object i of the split gets the same
    random stream a rendered set of that split would give it."""
    from .renderset import ObjectViews, RenderSettings
    if views < 1:
        raise ValueError(f"views must be >= 1, got {views}")
    over = {"views_per_object": views, "seed": seed, "noise": bool(noise), **({"sampler": sampler} if sampler else {})}
    rs = RenderSettings.from_dict({**model.settings.get("render", {}), **over})
    K = model.intrinsics
    records = dataset.records(split=split, per_class=per_class)
    if not records:
        raise ValueError(f"{dataset.name}: no objects in split {split!r}")
    rows = []
    bar = tqdm(total=len(records), desc=f"evaluate {dataset.name}/{split}", disable=not progress)
    for start in range(0, len(records), chunk):
        # render a chunk with the renderer closed afterwards, then predict it: the renderer's
        # threads would otherwise compete with the network's and distort the runtimes
        viewer, batch = ObjectViews(rs), []
        try:
            for i in range(start, min(start + chunk, len(records))):
                v = viewer.views(records[i], i, -1, split)
                batch.append((records[i], v["rotation"], v["depth"].astype(np.float32), record_grid(records[i])))
        finally:
            viewer.close()
        if start == 0:                 # one untimed call: first-call set-up is not a per-query cost
            model.predict(batch[0][2][0], K)
        for rec, Rs, depth, truth in batch:
            for v in range(views):
                if not (depth[v] > 0).any():
                    continue          # nothing visible (cannot happen with sane settings; never scored as 0)
                p = model.predict(depth[v], K)
                rows.append({"class": rec.cls, "pred": p.class_names[0], "R_true": Rs[v], "R_pred": p.rotation[0],
                             "grid": p.grids[0], "truth": truth, "ms": p.timing_ms["total"]})
            bar.update(1)
    bar.close()
    return summarize(rows, model.classes, dataset.name, split, views, seed, rs.sampler, noise, len(records))


def summarize(rows: list[dict], classes, dataset: str, split: str, views: int, seed: int, sampler: str,
              noise: bool, n_objects: int) -> dict:
    """Metrics dict from per-query rows (class, pred, R_true, R_pred, grid, truth, ms)."""
    cls = np.array([r["class"] for r in rows])
    correct = np.array([r["class"] == r["pred"] for r in rows])
    Rt, Rp = np.stack([r["R_true"] for r in rows]), np.stack([r["R_pred"] for r in rows])
    raw = geodesic_deg(Rp, Rt)
    sym = np.array([symmetric_pose_error(p, t, UP_SYMMETRY.get(c, 1)) for p, t, c in zip(Rp, Rt, cls)])
    truth, pred = np.stack([r["truth"] for r in rows]), np.stack([r["grid"] for r in rows])
    edt, nai, io = edt_error(truth, pred), naive_error(truth, pred), iou(truth, pred)
    per = {}
    for c in classes:
        m = cls == c
        if m.any():
            per[c] = {"n": int(m.sum()), "accuracy": float(correct[m].mean()),
                      "pose_mean_deg": float(raw[m].mean()), "pose_median_deg": float(np.median(raw[m])),
                      "pose_median_sym_deg": float(np.median(sym[m])), "edt": float(edt[m].mean()),
                      "naive": float(nai[m].mean()), "iou": float(io[m].mean())}
    index = {c: i for i, c in enumerate(classes)}
    conf = np.zeros((len(classes), len(classes)), int)
    for r in rows:
        conf[index[r["class"]], index[r["pred"]]] += 1
    return {"hbeo_version": __version__, "dataset": dataset, "split": split, "views": views, "seed": seed,
            "sampler": sampler, "noise": bool(noise), "n_objects": n_objects, "n_queries": len(rows),
            "accuracy": float(correct.mean()),
            "pose_error_deg": {"mean": float(raw.mean()), "median": float(np.median(raw)),
                               "mean_sym": float(sym.mean()), "median_sym": float(np.median(sym))},
            "completion": {"edt": float(edt.mean()), "naive": float(nai.mean()), "iou": float(io.mean())},
            "runtime_ms": {"mean_per_query": float(np.mean([r["ms"] for r in rows])),
                           "median_per_query": float(np.median([r["ms"] for r in rows]))},
            "per_class": per, "classes": list(classes), "confusion": conf.tolist()}
