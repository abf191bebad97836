"""The paired evaluation protocol of the reproduction and its cache: which (method, pose) settings
each notebook shows, which test objects and views each scores, and the one cached :func:`evaluation`
the notebooks call.

Pairs
    Every setting is scored by :func:`hbeo.evaluation.evaluate.evaluate_model` on query views drawn
    from seed :data:`SEED` and each object's stable id (:func:`hbeo.render.views.query_rng`): view j
    of object o is the same image for every method. The plan (:func:`eval_plan`): every test object
    of the profile's split with the profile's ``eval_views`` views; the slow searches (BEO 3-DOF, ICP,
    and BEO 1-DOF where the profile says so) the first objects of each class with view 0 only, a
    subset of the same pairs. Per-query results (``per_query``: object, view, class, errors) are kept
    in each metrics file and gathered in one table per run (:func:`per_query_table`).

Readings
    The views are drawn by the model's training sampler unless another reading of the view
    protocol is asked for (:data:`hbeo.render.poses.SAMPLERS`; :func:`evaluation`'s ``sampler``,
    :func:`readings` for all of them). Under one reading view j of object o is one image for every
    method; across readings the objects and each view's random stream are the same, the images not.

Cache
    A result is written to :meth:`hbeo.rundir.RunDir.evaluation` (``eval_<method>_<pose>.json``, or
    ``eval_<method>_<pose>_<sampler>.json`` under another reading than the model's own)
    with the request that produced it (:func:`request`): the setting, reading, objects and views, the code
    version (:func:`hbeo.storage.tree_digest` of the package), the dataset's fingerprint (the grid
    file's sha256), and the sha256 of the HBEO model file and of the baseline's file. A later call
    with the same request reads it; anything else evaluates again.

May import: foundation, data, render, model, baselines, run and :mod:`hbeo.evaluation.evaluate`.
"""
from __future__ import annotations

import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from hbeo import config
from hbeo.rundir import RunDir
from hbeo.storage import append_csv, atomic_text, json_text, sha256_file, tree_digest

SEED = 0
#: HBEO with the extensions chosen on validation objects: test-time roll averaging (bins models) and
#: the verify step (:class:`hbeo.model.verify.VerifyConfig`'s defaults). Not the paper's method.
VERIFIED = "hbeo-verify"
VERIFIED_ROLLS = 4
#: Every evaluation of a run, in the order the notebooks show them (Table II): (method, pose);
#: which of them get the true class is :data:`hbeo.baselines.methods.GIVEN_CLASS`.
EVALUATIONS = (("hbeo", "3dof"), (VERIFIED, "3dof"), ("beo", "known"), ("beo", "1dof"), ("voxcnn", "known"),
               ("beo", "3dof"), ("icp", "3dof"))
#: Table I (notebook 05): the settings that classify.
TABLE1 = (("hbeo", "3dof"), (VERIFIED, "3dof"), ("beo", "known"), ("beo", "1dof"), ("voxcnn", "known"))
#: The paper's pose figure (notebook 06).
POSE = (("hbeo", "3dof"), (VERIFIED, "3dof"), ("beo", "3dof"), ("icp", "3dof"))
#: The paper's completion figure (notebook 06).
COMPLETION = (("hbeo", "3dof"), (VERIFIED, "3dof"), ("beo", "known"), ("beo", "1dof"), ("beo", "3dof"),
              ("voxcnn", "known"))


def eval_per_class(profile, method: str, pose: str) -> int | None:
    """Test objects per class that ``method``/``pose`` is evaluated on under ``profile`` (None: all
    of the profile's test split)."""
    return eval_plan(profile, method, pose)[0]


def eval_plan(profile, method: str, pose: str) -> tuple[int | None, int]:
    """(test objects per class or None for all, views per object) of ``method``/``pose``: the
    profile's test split with ``eval_views`` views, or for the slow searches (``beo_1dof_test_per_class``,
    ``beo_3dof_test_per_class``, ``icp_test_per_class``) the first objects of each class, view 0 only."""
    prof = config.get_profile(profile)
    fewer = {("beo", "1dof"): prof.evaluation.beo_1dof_test_per_class, ("beo", "3dof"): prof.evaluation.beo_3dof_test_per_class,
             ("icp", "3dof"): prof.evaluation.icp_test_per_class, ("icp", "1dof"): prof.evaluation.icp_test_per_class}.get((method, pose))
    test_n = prof.data.n_test_per_class
    if fewer is None or (test_n is not None and fewer >= test_n):
        return test_n, prof.evaluation.eval_views
    return fewer, 1


#: The layers above the evaluation: they present numbers and never change one, so the code version leaves
#: them out (with the command line). Every other module of the package is hashed, by rule.
PRESENTATION_LAYERS = ("report", "lessons")


@lru_cache(maxsize=1)
def code_version() -> str:
    """sha256 (16 hex digits) of the ``hbeo`` source that computes an evaluation: every module but the
    command line and the layers above the evaluation (:data:`PRESENTATION_LAYERS`: tables, figures,
    reports, the notebooks' lessons). A change to any other file invalidates every cached evaluation."""
    root = Path(__file__).resolve().parent.parent
    shown = {p.relative_to(root).as_posix() for layer in PRESENTATION_LAYERS for p in (root / layer).rglob("*.py")}
    return tree_digest(root, skip={"cli.py", "__main__.py", *shown})[:16]


def _sha(path: Path) -> str | None:
    return sha256_file(path)[:16] if path.exists() else None


def request(run, method: str, pose: str, sampler: str | None = None, batched: bool = False) -> dict:
    """What decides an evaluation's result (its cache key): the setting, the reading of the view
    protocol (``sampler``; None: the model's own), the objects and views, the seed, the code version,
    the dataset's fingerprint and the model and baseline files' hashes, and ``batched`` where true (the same
    answers, per-query times shared over a batch). ``run``: a :class:`hbeo.run.Run`."""
    per_class, views = eval_plan(run.profile, method, pose)
    base = method.split("-")[0]
    return {"method": method, "pose": pose, "sampler": sampler, "dataset": run.dataset.name,
            "dataset_fingerprint": run.dataset.fingerprint(), "per_class": per_class, "views": views, "seed": SEED,
            "code": code_version(), "model_sha256": _sha(run.dir.model),
            "baseline_sha256": None if base == "hbeo" else _sha(run.dir.baseline(base)),
            **({"batched": True} if batched else {})}


def training_sampler(model) -> str:
    """The view sampler an HBEO ``model`` was trained with (its render settings'; a file that does not
    record one: :class:`~hbeo.render.views.RenderSettings`' default), the reading its evaluations use
    when none is asked for."""
    from hbeo.render.views import RenderSettings
    return RenderSettings.from_dict(dict(model.settings.render)).sampler


def evaluation(run, method: str = "hbeo", pose: str | None = None, progress: bool = True,
               sampler: str | None = None, device: str | None = None, batched: bool = False) -> dict:
    """Metrics of ``method``/``pose`` on the run's paired test views (:func:`eval_plan`,
    :func:`hbeo.evaluation.evaluate.evaluate_model`), read from the run's ``eval_<method>_<pose>.json``
    when that file answers the same :func:`request`, else computed and written there (atomically).
    ``method`` :data:`VERIFIED` is HBEO with roll averaging and the verify step. The run's model is
    trained first if missing (:meth:`hbeo.run.Run.model`). ``run``: a :class:`hbeo.run.Run`.

    ``sampler``: the reading of the view protocol (:data:`hbeo.render.poses.SAMPLERS`); None or the
    model's own training sampler (:func:`training_sampler`): the file above; another one: the views
    drawn by that sampler from the same per-view streams, in ``eval_<method>_<pose>_<sampler>.json``
    (:meth:`hbeo.rundir.RunDir.evaluation`). ``device``: where HBEO's network runs when computed (None: the
    CPU; :meth:`hbeo.model.inference.HBEO.to`; the device job's ``cuda``). ``batched``: HBEO's one pass on a
    chunk of views per network call (the same answers; the device job's, where per-query calls would idle a GPU;
    the notebooks keep per-query calls, whose times Table II reports)."""
    from hbeo.baselines.methods import check_method
    from hbeo.evaluation.evaluate import evaluate_model
    verified = method == VERIFIED
    pose = "3dof" if verified else check_method(method, pose)
    model = None
    if sampler is not None:
        from hbeo.render.poses import check_sampler
        check_sampler(sampler)
        model = run.model(progress=progress)
        if sampler == training_sampler(model):
            sampler = None
    path = run.dir.evaluation(method, pose, sampler)
    if path.exists():
        try:
            old = json.loads(path.read_text())
            if old.get("request") == request(run, method, pose, sampler, batched):
                return old
        except (OSError, ValueError):
            pass
    model = model or run.model(progress=progress)
    if device is not None:
        model.to(device)
    meth = None if method in ("hbeo", VERIFIED) else run.baseline(method, progress=progress)
    verify, rolls = None, 1
    if verified:
        from hbeo.model.verify import VerifyConfig
        verify, rolls = VerifyConfig(), VERIFIED_ROLLS if model.net.cfg.rotation == "bins" else 1
    per_class, views = eval_plan(run.profile, method, pose)
    m = evaluate_model(model, run.dataset, split="test", views=views, seed=SEED, per_class=per_class,
                       progress=progress, method=meth, pose=pose, rolls=rolls, verify=verify, sampler=sampler,
                       batched=batched and method == "hbeo")
    if verified:
        m["method"] = VERIFIED
    m["request"] = request(run, method, pose, sampler, batched and method == "hbeo")
    atomic_text(path, json_text(m, indent=1))
    return m


def evaluations(run, settings=EVALUATIONS, progress: bool = True, sampler: str | None = None) -> list[dict]:
    """:func:`evaluation` of each (method, pose) in ``settings``, in order, under reading ``sampler``."""
    return [evaluation(run, m, p, progress=progress, sampler=sampler) for m, p in settings]


def readings(run, samplers=None, settings=EVALUATIONS, progress: bool = True) -> dict[str, list[dict]]:
    """Every (method, pose) of ``settings`` under each reading of the view protocol: {sampler:
    :func:`evaluations`} for each of ``samplers`` (default: every one of :data:`hbeo.render.poses.SAMPLERS`),
    in order. Under one reading every method scores the same images; the readings share the objects
    and the per-view streams (:func:`hbeo.render.views.query_rng`)."""
    from hbeo.render.poses import SAMPLERS
    return {s: evaluations(run, settings, progress=progress, sampler=s) for s in (samplers or SAMPLERS)}


def per_query_table(evals: list[dict]):
    """One table of every query of ``evals`` (a pandas DataFrame): ``method``, ``pose``, then the
    ``per_query`` columns (object, view, class, pred, errors, ms); rows of different methods with
    the same (object, view) saw the same image."""
    import pandas as pd
    frames = [pd.DataFrame(m["per_query"]).assign(method=m["method"], pose=m["pose"]) for m in evals]
    df = pd.concat(frames, ignore_index=True)
    return df[["method", "pose", *[c for c in df.columns if c not in ("method", "pose")]]]


def evaluate_validation(model, run, progress: bool = True) -> dict:
    """HBEO metrics of ``model`` (a variant trained in ``run``, a :class:`hbeo.run.Run`) on the validation
    objects (training objects its training held out, :func:`hbeo.data.datasets.validation_records`) with
    the profile's ``eval_views`` query views, not cached: where options are compared, never on the test split."""
    from hbeo.evaluation.evaluate import evaluate_model
    return evaluate_model(model, run.dataset, split="val", views=run.profile.evaluation.eval_views, seed=SEED, progress=progress)


def sample_completions(run, n: int = 6, seed: int = SEED) -> list[dict]:
    """Completions of ``n`` test objects (one per class, in class order) of ``run`` (a :class:`hbeo.run.Run`)
    for a gallery: the same views the evaluations score (object i of the test split, ``seed``). Each item:
    ``class``, ``depth`` (H, W) metres, ``truth``, ``hbeo`` and ``beo`` (known pose) grids (30, 30, 30) bool,
    and the classes HBEO and BEO predicted (``hbeo_class``, ``beo_class``)."""
    from hbeo.data.gridset import record_grid
    from hbeo.model.inference import HBEO
    from hbeo.render.views import ObjectViews, RenderSettings
    model = HBEO.load(run.dir.model)
    beo = run.baseline("beo")
    records = run.dataset.records(split="test", per_class=eval_per_class(run.profile, "hbeo", "3dof"))
    first = {}
    for i, r in enumerate(records):
        first.setdefault(r.cls, (i, r))
    picks = list(first.values())[:n]
    rs = RenderSettings.for_queries(model.settings.render, 1, seed)
    viewer, views = ObjectViews(rs), []
    try:
        for i, r in picks:
            views.append((r, viewer.query_views(r, "test", 1)))
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


def evaluate_file(model_path, dataset: str, out, split: str = "test", views: int = 1, seed: int = 0, sampler=None,
                  noise: bool = False, per_class: int | None = None, method: str = "hbeo", pose: str | None = None,
                  precision: str = "float32", rolls: int = 1, verify=None, max_steps: int | None = None,
                  progress: bool = True, prior_tau: float = 0.0, members=(), mirror: bool = False,
                  completion: str | None = None, batched: bool = False, noise_scale: int = 1) -> dict:
    """``python -m hbeo evaluate``: the metrics of ``method`` (HBEO, or a baseline fitted/trained beside the
    model file when missing) on ``dataset``'s ``split`` (read with the model's profile), written to ``out``
    (JSON); ``split="val"`` also adds a row to the model folder's ``validation.csv``; objects that could not
    be evaluated go to its ``failures.json``. ``prior_tau``: HBEO's prior correction
    (:meth:`hbeo.model.inference.HBEO.set_prior_tau`) with the model file's training class counts, or, for a
    file without them, the dataset's (:func:`hbeo.data.datasets.training_class_counts` of the model's profile;
    the metrics' ``class_prior.source`` says so). ``members``: model files averaged with HBEO's
    (:meth:`hbeo.model.inference.HBEO.add_members`; the metrics' ``ensemble`` names them). ``mirror``: HBEO's class
    answer averaged with the mirrored image's (:meth:`hbeo.model.inference.HBEO.set_mirror`). ``completion``: HBEO's
    completion rule (:meth:`hbeo.model.inference.HBEO.set_completion`; None: its default, never empty). ``batched``:
    HBEO's one pass answers each chunk of views in one network call (the same answers; not with ``verify``).
    ``noise_scale``: with ``noise``, where the noise is applied (:attr:`hbeo.render.views.RenderSettings.noise_scale`).
    Returns the metrics."""
    from hbeo.limits import check_rolls
    from hbeo.storage import atomic_file, check_outputs
    check_outputs({"--out": out}, {"--model": model_path, **{f"--ensemble {f}": f for f in members}})
    if members and method != "hbeo":
        raise ValueError(f"--ensemble averages HBEO models; method {method!r} is not HBEO")
    if mirror and method != "hbeo":
        raise ValueError(f"--mirror averages HBEO's class answer; method {method!r} is not HBEO")
    if batched and (method != "hbeo" or verify is not None):
        raise ValueError("--batch is HBEO's one network pass: not with --verify or a baseline")
    if completion is not None and method != "hbeo":
        raise ValueError(f"--completion is HBEO's completion rule; method {method!r} is not HBEO")
    check_rolls(rolls)                                  # before the model is read (and before torch is imported)
    from hbeo.render.noise import check_noise_scale
    check_noise_scale(noise, noise_scale, "a query")
    from hbeo.baselines.methods import check_method, load_method
    from hbeo.evaluation.evaluate import evaluate_model
    from hbeo.model.inference import HBEO
    from hbeo.run import baseline_inputs, load_dataset, record_failures
    pose = check_method(method, pose)
    model = HBEO.load(model_path, precision=precision, members=members)
    folder = RunDir(Path(model_path).parent)
    profile = model.settings.profile or "cpu"
    ds = load_dataset(dataset, profile)
    baseline_inputs(folder, method, model, ds, dataset, progress=progress)     # grids, basis: built if missing
    model_prior(model, ds, prior_tau)
    model.set_mirror(mirror).set_completion(completion)
    meth = None if method == "hbeo" else load_method(method, folder, profile, progress=progress, max_steps=max_steps)
    metrics = evaluate_model(model, ds, split=split, views=views, seed=seed, sampler=sampler, noise=noise,
                             per_class=per_class, progress=progress, method=meth, pose=pose, rolls=rolls, verify=verify,
                             batched=batched, noise_scale=noise_scale)
    metrics["model"] = str(model_path)
    with atomic_file(out, "w") as f:
        f.write(json_text(metrics, indent=2))
    if split == "val":
        record_validation(folder, model_path, model, metrics)
    record_failures(folder, "evaluate", metrics["failures"], metrics["n_objects"] + len(metrics["failures"]), [split])
    return metrics


def model_prior(model, dataset, tau: float):
    """Set ``model``'s prior correction ``tau`` (:meth:`hbeo.model.inference.HBEO.set_prior_tau`): with its
    file's training class counts, or for a file without them (written before they were recorded) with
    ``dataset``'s training objects per class under the model's profile
    (:func:`hbeo.data.datasets.training_class_counts`; the source is named so). Returns the model."""
    if not tau or model.settings.class_counts is not None:
        return model.set_prior_tau(tau)
    from hbeo.data.datasets import training_class_counts
    counts = training_class_counts(dataset, model.settings.profile)
    order = [list(dataset.classes).index(c) for c in model.classes]
    return model.set_prior_tau(tau, counts[order], f"{dataset.name} training split, objects per class under "
                                                   f"profile {model.settings.profile} less validation (the model "
                                                   f"file records no class counts)")


def _val_split(model) -> str:
    """The validation split (``object`` or ``grouped@<twin_iou>``) of the model's profile; ``object``
    when the profile is unknown."""
    from hbeo import config
    try:
        prof = config.get_profile(model.settings.profile)
    except (ValueError, TypeError):
        return "object"
    return prof.data.val_split if prof.data.val_split == "object" else f"grouped@{prof.data.twin_iou}"


def record_validation(run, model_path, model, metrics: dict) -> dict:
    """Add one row to the run's ``validation.csv`` (:attr:`RunDir.validation_log`): when, which model
    file (name, sha256, rotation head, roll augmentation), how it was evaluated (views, seed, sampler, sensor
    noise and its scale, rolls, ...) and its validation scores; the file is rewritten atomically. Every
    configuration tried is meant to leave its row, so a choice made on validation can be checked against all
    the others. Returns the row."""
    import datetime
    run = RunDir.of(run)
    pe = metrics["pose_error_deg"]
    row = {"time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "model": os.path.basename(str(model_path)), "model_sha256": sha256_file(model_path)[:16],
           "rotation_head": model.net.cfg.rotation, "augment_roll": model.settings.augment_roll,
           "method": metrics["method"] + ("+verify" if metrics.get("verify") else ""), "pose": metrics["pose"],
           "ensemble": ";".join(str(f["file"]) for f in metrics.get("ensemble") or []),
           "rolls": metrics.get("rolls"), "mirror": metrics.get("mirror"), "prior_tau": metrics.get("prior_tau"), "verify": json.dumps(metrics.get("verify"), sort_keys=True),
           "views": metrics["views"], "seed": metrics["seed"], "sampler": metrics.get("sampler"),
           "noise": metrics.get("noise"), "noise_scale": metrics.get("noise_scale", 1 if metrics.get("noise") else None),
           "n_objects": metrics["n_objects"],
           "n_queries": metrics["n_queries"], "accuracy": metrics["accuracy"],
           "class_mean_accuracy": metrics.get("class_mean_accuracy"), "val_split": _val_split(model),
           "pose_median_deg": pe["median"],
           "pose_median_sym_deg": pe["median_sym"], "within_30": pe["within_30"],
           "iou": metrics["completion"]["iou"]}
    append_csv(run.validation_log, [row])
    return row
