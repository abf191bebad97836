"""Choosing the verify step's settings on validation objects (issue 16): every candidate scored on
the same queries.

:func:`verify_sweep` renders each validation view once, runs the network once per view, then
verifies that one prediction with each candidate :class:`hbeo.model.verify.VerifyConfig` (None: HBEO
alone) and scores every candidate with :func:`hbeo.evaluation.evaluate.summarize`, so candidates
differ only by their settings. The test split is refused: choices are made on validation objects
(:func:`hbeo.data.datasets.validation_records`), then the test split is evaluated once per chosen row.
:func:`sweep_rows` flattens the results into the rows of ``verify_sweep.csv`` beside the model.

May import: foundation, data, render, model and :mod:`hbeo.evaluation.evaluate`.
"""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
from tqdm.auto import tqdm

from hbeo.evaluation.evaluate import rendered_chunks, split_records, summarize


def verify_sweep(model, dataset, configs: dict, split: str = "val", views: int = 1, seed: int = 0,
                 per_class: int | None = None, rolls: int = 1, progress: bool = True,
                 thresholds: tuple = ()) -> dict[str, dict]:
    """{name: metrics dict (as ``evaluate``'s, with ``verify`` set)} for each of ``configs``
    ({name: VerifyConfig or None}) on ``views`` views of ``split``'s objects (``val`` or ``train``;
    the first ``per_class`` of each class when given). ``thresholds``: for each verify candidate
    also ``"<name> min_agreement=<x>"`` for each x, the same candidate with that ``min_agreement``
    (HBEO's own answer wherever verify's agreement is below x), derived from the same queries."""
    from hbeo.model.verify import Verifier
    from hbeo.render.views import RenderSettings
    if split == "test":
        raise ValueError("verify_sweep chooses settings: run it on 'val' objects, never on the test split")
    rs = RenderSettings.from_dict({**model.settings.render, "views_per_object": views, "seed": seed,
                                   "noise": False})
    records = split_records(dataset, split, per_class, model.settings.profile)
    verifiers = {n: (Verifier(model, c) if c is not None else None) for n, c in configs.items()}
    rows: dict[str, list] = {n: [] for n in configs}
    plain, agreement = [], {n: [] for n in configs}
    failures: list = []
    K = model.intrinsics
    bar = tqdm(total=len(records), desc=f"verify sweep {dataset.name}/{split}", disable=not progress)
    for batch in rendered_chunks(rs, records, split, 64, failures, bar):
        for i, rec, v, truth in batch:
            for j in range(views):
                depth = v["depth"][j].astype(np.float32)
                if not (depth > 0).any():
                    continue
                p = model.predict(depth, K, rolls=rolls)
                row = {"object": rec.id, "view": j, "class": rec.cls, "R_true": v["rotation"][j], "truth": truth}
                plain.append({**row, "pred": p.class_names[0], "R_pred": p.rotation[0], "grid": p.grids[0],
                              "ms": p.timing_ms["total"]})
                for n, ver in verifiers.items():
                    if ver is None:
                        rows[n].append(plain[-1])
                        continue
                    x = ver.verify(depth, K, p)
                    rows[n].append({**row, "pred": model.classes[x["label"]], "R_pred": x["rotation"],
                                    "grid": x["grid"], "ms": p.timing_ms["total"] + x["ms"]})
                    agreement[n].append(x["agreement"])
            bar.update(1)
    bar.close()
    derived = {}
    for n, c in configs.items():
        if c is None or c.min_agreement > 0:
            continue
        for x in thresholds:
            name = f"{n} min_agreement={x:g}"
            derived[name] = replace(c, min_agreement=float(x))
            rows[name] = [v if a >= x else {**h, "ms": v["ms"]} for v, h, a in zip(rows[n], plain, agreement[n])]
    configs = {**configs, **derived}
    out = {}
    for n, c in configs.items():
        m = summarize(rows[n], tuple(model.classes), dataset.name, split, views, seed, rs.sampler, False,
                      len(records) - len(failures))
        out[n] = {"method": "hbeo", "rolls": rolls, "verify": c.to_dict() if c is not None else None, **m,
                  "failures": failures}
    return out


def sweep_rows(results: dict[str, dict], model_sha: str) -> list[dict]:
    """One flat row per candidate of :func:`verify_sweep`'s results (for ``verify_sweep.csv``)."""
    rows = []
    for n, m in results.items():
        rows.append({"name": n, "model_sha256": model_sha, "split": m["split"], "views": m["views"], "seed": m["seed"],
                     "rolls": m["rolls"], "n_objects": m["n_objects"], "n_queries": m["n_queries"],
                     "accuracy": m["accuracy"], "pose_median_deg": m["pose_error_deg"]["median"],
                     "within_30": m["pose_error_deg"]["within_30"], "iou": m["completion"]["iou"],
                     "edt": m["completion"]["edt"], "ms_per_query": m["runtime_ms"]["mean_per_query"],
                     "verify": json.dumps(m["verify"], sort_keys=True)})
    return rows
