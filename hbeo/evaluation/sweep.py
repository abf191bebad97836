"""Choosing the verify step's settings on validation objects: every candidate scored on
the same queries.

:func:`verify_sweep` renders each validation view once, runs the network once per view, then
verifies that one prediction with each candidate :class:`hbeo.model.verify.VerifyConfig` (None: HBEO
alone) and scores every candidate with :func:`hbeo.evaluation.evaluate.summarize`, so candidates
differ only by their settings. The test split is refused: choices are made on validation objects
(:func:`hbeo.data.datasets.validation_records`), then the test split is evaluated once per chosen row.
:func:`sweep_rows` flattens the results into the rows of ``verify_sweep.csv`` beside the model.

May import: foundation, data, render, model, :mod:`hbeo.evaluation.evaluate` and :mod:`hbeo.evaluation.method`.
"""
from __future__ import annotations

import json

from hbeo.evaluation.evaluate import EvaluationSetup, score_methods, summarize
from hbeo.evaluation.method import HBEOMethod


def verify_sweep(model, dataset, configs: dict, split: str = "val", views: int = 1, seed: int = 0,
                 per_class: int | None = None, rolls: int = 1, progress: bool = True,
                 thresholds: tuple = ()) -> dict[str, dict]:
    """{name: metrics dict (as ``evaluate``'s, with ``verify`` set)} for each of ``configs``
    ({name: VerifyConfig or None}) on ``views`` views of ``split``'s objects (``val`` or ``train``;
    the first ``per_class`` of each class when given). ``thresholds``: for each verify candidate
    also ``"<name> min_agreement=<x>"`` for each x, the same candidate with that ``min_agreement``
    (HBEO's own answer wherever verify's agreement is below x), derived from the same queries.

    Every candidate is an :class:`~hbeo.evaluation.method.HBEOMethod` sharing one prediction per
    view, scored by the evaluation's one loop (:func:`~hbeo.evaluation.evaluate.score_methods`)."""
    if split == "test":
        raise ValueError("verify_sweep chooses settings: run it on 'val' objects, never on the test split")
    first = None
    methods = {}
    for n, c in configs.items():
        m = HBEOMethod(model, rolls=rolls, verify=c, share=first)
        first = first or m
        methods[n] = m
    for n, c in configs.items():
        if c is None or c.min_agreement > 0:
            continue
        for x in thresholds:
            methods[f"{n} min_agreement={x:g}"] = HBEOMethod(model, rolls=rolls, verify=c, share=methods[n],
                                                             min_agreement=float(x))
    setup = EvaluationSetup.of_model(model, class_means=False)
    rows, failures, records, rs = score_methods({n: (m, "3dof") for n, m in methods.items()}, dataset, setup, split,
                                                views, seed, None, False, per_class, progress, 64,
                                                desc=f"verify sweep {dataset.name}/{split}", warm_up=False)
    out = {}
    for n, m in methods.items():
        summary = summarize(rows[n], tuple(model.classes), dataset.name, split, views, seed, rs.sampler, False,
                            len(records) - len(failures))
        out[n] = {"method": "hbeo", "rolls": rolls, "verify": m.describe()["verify"], **summary,
                  "failures": failures}
    return out


def sweep_rows(results: dict[str, dict], model_sha: str) -> list[dict]:
    """One flat row per candidate of :func:`verify_sweep`'s results (for ``verify_sweep.csv``)."""
    rows = []
    for n, m in results.items():
        rows.append({"name": n, "model_sha256": model_sha, "split": m["split"], "views": m["views"], "seed": m["seed"],
                     "rolls": m["rolls"], "n_objects": m["n_objects"], "n_queries": m["n_queries"],
                     "accuracy": m["accuracy"], "class_mean_accuracy": m.get("class_mean_accuracy"),
                     "pose_median_deg": m["pose_error_deg"]["median"],
                     "within_30": m["pose_error_deg"]["within_30"], "iou": m["completion"]["iou"],
                     "edt": m["completion"]["edt"], "ms_per_query": m["runtime_ms"]["mean_per_query"],
                     "verify": json.dumps(m["verify"], sort_keys=True)})
    return rows
