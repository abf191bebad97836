"""The evaluation protocol of the reproduction and its cache: which (method, pose) settings each
notebook shows, how many test objects each sees, and the one cached :func:`evaluation` the
notebooks call.

Every setting is scored by :func:`hbeo.reproduction.evaluate.evaluate_model` on the same rendered
test views: one view per test object (``views=1``), seed :data:`SEED`, the run's HBEO model file
supplying the camera and distances. A result is written to
:meth:`hbeo.rundir.RunDir.evaluation` (``eval_<method>_<pose>.json``) together with the request
that produced it; a later call with the same request (same model file, settings and objects)
reads it instead of evaluating again.

Test objects per class: the profile's test split, fewer for BEO's slow pose search (the profile's
``beo_1dof_test_per_class`` and ``beo_3dof_test_per_class``, see :mod:`hbeo.config`).

May import: foundation, data, render, model, baselines and :mod:`hbeo.reproduction.evaluate`.
"""
from __future__ import annotations

import json
import os

import numpy as np

from hbeo import config
from hbeo.rundir import RunDir
from hbeo.storage import append_csv, atomic_text, sha256_file

SEED = 0
#: Every evaluation of a run, in the order the notebooks show them (Table II): (method, pose);
#: which of them get the true class is :data:`hbeo.baselines.methods.GIVEN_CLASS`.
EVALUATIONS = (("hbeo", "3dof"), ("beo", "known"), ("beo", "1dof"), ("voxcnn", "known"), ("beo", "3dof"),
               ("icp", "3dof"))
#: Table I (notebook 05): the settings that classify.
TABLE1 = (("hbeo", "3dof"), ("beo", "known"), ("beo", "1dof"), ("voxcnn", "known"))
#: The paper's pose figure (notebook 06).
POSE = (("hbeo", "3dof"), ("beo", "3dof"), ("icp", "3dof"))
#: The paper's completion figure (notebook 06).
COMPLETION = (("hbeo", "3dof"), ("beo", "known"), ("beo", "1dof"), ("beo", "3dof"), ("voxcnn", "known"))


def eval_per_class(profile, method: str, pose: str) -> int | None:
    """Test objects per class that ``method``/``pose`` is evaluated on under ``profile`` (None: all
    of the profile's test split)."""
    prof = config.get_profile(profile)
    fewer = {("beo", "1dof"): prof.beo_1dof_test_per_class,
             ("beo", "3dof"): prof.beo_3dof_test_per_class}.get((method, pose))
    test_n = prof.n_test_per_class
    return fewer if test_n is None or (fewer is not None and fewer < test_n) else test_n


def evaluation(run, dataset: str, profile, method: str = "hbeo", pose: str | None = None,
               per_class: int | None | str = "plan", views: int = 1, seed: int = SEED, progress: bool = True) -> dict:
    """Metrics of ``method``/``pose`` on the run's test views (:func:`hbeo.reproduction.evaluate.evaluate_model`),
    read from the run's ``eval_<method>_<pose>.json`` when that file answers the same request (same
    model file, settings and objects), else computed and written there (atomically).
    ``per_class="plan"``: :func:`eval_per_class`. ``run``: a RunDir or a path."""
    from hbeo.baselines.methods import check_method, load_method
    from hbeo.data import datasets
    from hbeo.model.inference import HBEO
    from hbeo.reproduction.evaluate import evaluate_model
    run = RunDir.of(run)
    prof = config.get_profile(profile)
    pose = check_method(method, pose)
    if per_class == "plan":
        per_class = eval_per_class(prof, method, pose)
    request = {"method": method, "pose": pose, "dataset": dataset, "per_class": per_class, "views": views,
               "seed": seed, "model_sha256": sha256_file(run.model)[:16]}
    path = run.evaluation(method, pose)
    if path.exists():
        try:
            old = json.loads(path.read_text())
            if old.get("request") == request:
                return old
        except (OSError, ValueError):
            pass
    model = HBEO.load(run.model)
    ds = datasets.get_dataset(dataset, profile=prof)
    meth = None if method == "hbeo" else load_method(method, run, prof, progress=progress)
    m = evaluate_model(model, ds, split="test", views=views, seed=seed, per_class=per_class, progress=progress,
                       method=meth, pose=pose)
    m["request"] = request
    atomic_text(path, json.dumps(m, indent=1))
    return m


def evaluations(run, dataset: str, profile, settings=EVALUATIONS, progress: bool = True) -> list[dict]:
    """:func:`evaluation` of each (method, pose) in ``settings``, in order."""
    return [evaluation(run, dataset, profile, m, p, progress=progress) for m, p in settings]


def evaluate_unsaved(model, dataset: str, profile, progress: bool = True) -> dict:
    """HBEO metrics of another ``model`` (a variant trained in the same run) on the protocol's test
    views, not cached: the same objects, view and seed as :func:`evaluation` ``("hbeo", "3dof")``."""
    from hbeo.data import datasets
    from hbeo.reproduction.evaluate import evaluate_model
    prof = config.get_profile(profile)
    ds = datasets.get_dataset(dataset, profile=prof)
    return evaluate_model(model, ds, split="test", views=1, seed=SEED, progress=progress,
                          per_class=eval_per_class(prof, "hbeo", "3dof"))


def sample_completions(run, dataset: str, profile, n: int = 6, seed: int = SEED) -> list[dict]:
    """Completions of ``n`` test objects (one per class, in class order) for a gallery: the same
    views the evaluations score (object i of the test split, ``seed``). Each item: ``class``,
    ``depth`` (H, W) metres, ``truth``, ``hbeo`` and ``beo`` (known pose) grids (30, 30, 30) bool,
    and the classes HBEO and BEO predicted (``hbeo_class``, ``beo_class``)."""
    from hbeo.baselines.methods import load_method
    from hbeo.data import datasets
    from hbeo.data.gridset import record_grid
    from hbeo.model.inference import HBEO
    from hbeo.render.views import ObjectViews, RenderSettings
    run = RunDir.of(run)
    prof = config.get_profile(profile)
    model = HBEO.load(run.model)
    beo = load_method("beo", run, prof)
    ds = datasets.get_dataset(dataset, profile=prof)
    records = ds.records(split="test", per_class=eval_per_class(prof, "hbeo", "3dof"))
    first = {}
    for i, r in enumerate(records):
        first.setdefault(r.cls, (i, r))
    picks = list(first.values())[:n]
    rs = RenderSettings.from_dict({**model.settings.get("render", {}), "views_per_object": 1, "seed": seed})
    viewer, views = ObjectViews(rs), []
    try:
        for i, r in picks:
            views.append((r, viewer.views(r, i, -1, "test")))
    finally:
        viewer.close()
    out = []
    for r, v in views:
        depth = v["depth"][0].astype(np.float32)
        p = model.predict(depth, model.intrinsics)
        b = beo.predict_view(depth, model.intrinsics, R_true=v["rotation"][0].astype(np.float64),
                             t_true=v["translation"][0].astype(np.float64), object_size=rs.object_size, pose="known",
                             label_true=None, rng=np.random.default_rng(seed))
        out.append({"class": r.cls, "depth": depth, "truth": record_grid(r), "hbeo": p.grids[0],
                    "hbeo_class": p.class_names[0], "beo": b["grid"],
                    "beo_class": model.classes[int(np.argmax(b["probabilities"]))]})
    return out


def record_validation(run, model_path, model, metrics: dict) -> dict:
    """Add one row to the run's ``validation.csv`` (:attr:`RunDir.validation_log`): when, which model
    file (name, sha256, rotation head, roll augmentation), how it was evaluated and its validation
    scores; the file is rewritten atomically. Every configuration tried is meant to leave its row,
    so a choice made on validation can be checked against all the others. Returns the row."""
    import datetime
    run = RunDir.of(run)
    pe = metrics["pose_error_deg"]
    row = {"time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "model": os.path.basename(str(model_path)), "model_sha256": sha256_file(model_path)[:16],
           "rotation_head": model.net.cfg.rotation, "augment_roll": bool(model.settings.get("augment_roll", False)),
           "method": metrics["method"] + ("+verify" if metrics.get("verify") else ""), "pose": metrics["pose"],
           "rolls": metrics.get("rolls"), "verify": json.dumps(metrics.get("verify"), sort_keys=True),
           "views": metrics["views"], "seed": metrics["seed"], "n_objects": metrics["n_objects"],
           "n_queries": metrics["n_queries"], "accuracy": metrics["accuracy"], "pose_median_deg": pe["median"],
           "pose_median_sym_deg": pe["median_sym"], "within_30": pe["within_30"],
           "iou": metrics["completion"]["iou"]}
    append_csv(run.validation_log, [row])
    return row
