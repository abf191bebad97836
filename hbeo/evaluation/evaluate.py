"""Evaluating a model on rendered views of a dataset: the metrics JSON.

:func:`evaluate_model` renders each test object from ``views`` random viewpoints with the
model's own camera and distances (its training render settings), predicts, and scores.
Keys of the returned dict (stable; the evaluation notebooks and outside checks read them):

``method`` (``hbeo``, ``beo``, ``icp``, ``voxcnn``), ``pose`` (``known``, ``1dof``, ``3dof``: what
the method had to estimate), ``given_class`` (the true class was given: accuracy is then 1 by
construction), ``precision`` (HBEO's network arithmetic, ``float32`` or ``bfloat16``; null for
the baselines), ``rolls`` (HBEO's test-time roll averaging, 1 = none; null for the baselines), ``mirror`` (HBEO's class
answer averaged with the mirrored image's, :meth:`hbeo.model.inference.HBEO.set_mirror`; null for the baselines),
``prior_tau`` (HBEO's prior correction, :meth:`hbeo.model.inference.HBEO.set_prior_tau`: 0 = none, the
paper's; null for the baselines), ``class_prior`` (``{tau, source, counts}`` of a correction, else null) and
``ensemble`` (the files, ``{file, sha256}``, of the models whose answers HBEO's were averaged with, else null),
``completion_rule`` (only when HBEO completed by another rule than the paper's, :mod:`hbeo.model.completion_rule`:
by default it does, never leaving a grid empty),
``hbeo_version``, ``dataset``, ``split``, ``views``, ``seed``, ``sampler``, ``noise``, ``noise_scale`` (only
where the noise was applied at a finer sensor, :attr:`hbeo.render.views.RenderSettings.noise_scale`), ``verify`` (HBEO's
verify settings, :class:`hbeo.model.verify.VerifyConfig`, or null),
``n_objects`` (objects scored), ``n_queries``, ``failures`` (objects that could not be rendered
or predicted, ``{file, reason, step, object, split}``: left out, the others still scored)

``accuracy``
    fraction of queries with the right class
``class_mean_accuracy``
    the mean over classes of each class's accuracy (the paper's Table I
    total; :func:`class_mean_accuracy`): the training split is 9:1
    between its largest and smallest class, the test split nearly balanced
``pose_error_deg``
    ``mean``, ``median`` (geodesic, raw: the paper's metric) and
    ``mean_sym``, ``median_sym`` (modulo each class's near-symmetry
    turns about the up axis, :data:`hbeo.conventions.UP_SYMMETRY`);
    ``within_30``, ``within_30_sym``: fraction of queries within 30
    degrees (Acc@pi/6; a median hides a bimodal error, e.g. flips)
``completion``
    ``edt``, ``naive``, ``iou`` (means; see :mod:`hbeo.subspace.metrics`),
    ``empty_fraction`` and ``empty`` (the share and the number of queries
    whose completed grid is empty; files written before the count lack it)
``completion_paper``
    HBEO under another completion rule than the paper's (``completion_rule``):
    the paper's rule (back-projection >= 0.5) on the same coefficients,
    scored like ``completion`` (``edt``, ``naive``, ``iou``, ``empty_fraction``,
    ``empty``) with its own ``per_query`` ``edt``, ``iou``, ``empty``
``completion_baseline``
    the trivial answer "the class's mean training shape" (the
    subspace's class mean thresholded at 0.5), scored like
    ``completion``: ``predicted_class`` (the model's class) and
    ``true_class`` ({``edt``, ``naive``, ``iou``} each), and
    ``true_class_iou_t03`` (threshold 0.3); absent when the method
    has no class means
``runtime_ms``
    ``mean_per_query``, ``median_per_query`` (preprocessing + network +
    back-projection, one view per call, after one warm-up call)
``hardware``
    the machine the times were measured on (:func:`hbeo.machine.hardware`: cpu, cores, memory, gpu, torch
    threads, CPU kernels, platform); files written before it was recorded lack it
``device``
    the network's device, only when HBEO ran on another than the CPU
    (:meth:`hbeo.model.inference.HBEO.to`; ``runtime_ms`` is then that device's)
``per_class``
    {class: {``n``, ``accuracy``, ``pose_mean_deg``,
    ``pose_median_deg``, ``pose_median_sym_deg``, ``pose_within_30``, ``edt``,
    ``naive``, ``iou``}}
``confusion``
    rows: true class, columns: predicted class (counts)
``per_query``
    columns over queries (for distributions and paired comparisons):
    ``object`` (the record's id), ``view`` (its view index: the same
    object, view and seed is the same image for every method),
    ``class``, ``pred``, ``pose_deg``, ``pose_sym_deg``, ``edt``,
    ``naive``, ``iou``, ``empty`` (the completed grid has no filled
    voxel), ``ms``
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from hbeo.progress import tqdm

from hbeo import __version__
from hbeo.baselines.methods import GIVEN_CLASS
from hbeo.conventions import UP_SYMMETRY, Intrinsics
from hbeo.data.gridset import record_grid
from hbeo.errors import BatchError, DataError
from hbeo.evaluation.method import HBEOMethod, Method, answer_label
from hbeo.limits import check_evaluation
from hbeo.machine import hardware
from hbeo.render.views import object_key
from hbeo.rotations import geodesic_deg, symmetric_pose_error_deg
from hbeo.rundir import failure
from hbeo.subspace.metrics import edt_error, iou, naive_error


@dataclass(frozen=True)
class EvaluationSetup:
    """What fixes an evaluation's queries and scoring, apart from the method answering them: the
    camera (``intrinsics``) and training render settings (``render``, a RenderSettings dict) the
    views are drawn with, the class names (``classes``, the order of a method's probabilities),
    the ``profile`` whose validation objects ``split="val"`` means, and optionally ``class_means``
    ({class: (30, 30, 30) float}: the trivial answer scored as ``completion_baseline``).
    :meth:`of_model` takes them from an HBEO model; a baseline needs no HBEO model."""

    intrinsics: Intrinsics
    render: dict
    classes: tuple
    profile: str | None = None
    class_means: dict | None = None

    @classmethod
    def of_model(cls, model, class_means: bool = True) -> "EvaluationSetup":
        """The setup an HBEO ``model`` was trained with (its camera, render settings, classes,
        profile and, with ``class_means``, its subspace's class means)."""
        means = class_mean_grids(model.subspace) if class_means and getattr(model, "subspace", None) is not None else None
        return cls(model.intrinsics, dict(model.settings.render), tuple(model.classes), model.settings.profile, means)


def evaluate_model(model, dataset, split: str = "test", views: int = 1, seed: int = 0, sampler: str | None = None,
                   noise: bool = False, per_class: int | None = None, progress: bool = True,
                   chunk: int = 64, method=None, pose: str | None = None, rolls: int = 1, verify=None,
                   batched: bool = False, noise_scale: int = 1) -> dict:
    """Render, predict and score; returns the metrics dict described in the module docstring.

    ``model`` (an HBEO model) fixes the evaluation's setup (:meth:`EvaluationSetup.of_model`).
    ``method``: None for the model itself (:class:`~hbeo.evaluation.method.HBEOMethod` with
    ``rolls`` and ``verify``), or any :class:`~hbeo.evaluation.method.Method` (a baseline,
    :mod:`hbeo.baselines.methods`) scored at pose setting ``pose`` (None: its first). See
    :func:`evaluate_method`, which needs no HBEO model. ``batched``: HBEO's one pass answers a chunk of views
    in one network call (:meth:`~hbeo.evaluation.method.HBEOMethod.predict_views`; not with ``verify``).
    ``noise_scale``: with ``noise``, where the noise is applied (:attr:`hbeo.render.views.RenderSettings.noise_scale`;
    the metrics carry it where it is not 1)."""
    if verify is not None and method is not None:
        raise ValueError("verify applies to HBEO itself, not to a baseline")
    own = method is None
    if own:
        method = HBEOMethod(model, rolls=rolls, verify=verify)
    m = evaluate_method(method, dataset, EvaluationSetup.of_model(model), split=split, views=views, seed=seed,
                        sampler=sampler, noise=noise, per_class=per_class, progress=progress, chunk=chunk, pose=pose,
                        batched=batched, noise_scale=noise_scale)
    device = getattr(model, "device", None)
    if own and device is not None and device.type != "cpu":      # runtimes are then that device's
        m["device"] = str(device)
    return m


def evaluate_method(method: Method, dataset, setup: EvaluationSetup, split: str = "test", views: int = 1,
                    seed: int = 0, sampler: str | None = None, noise: bool = False, per_class: int | None = None,
                    progress: bool = True, chunk: int = 64, pose: str | None = None, batched: bool = False,
                    noise_scale: int = 1) -> dict:
    """Render ``views`` query views of each ``split`` object, let ``method`` answer each, score: the
    metrics dict described in the module docstring (:func:`score_methods`, one method; ``batched``: its
    batched path where the method has one, recorded as ``batched`` in the metrics)."""
    pose = pose or method.poses[0]
    batched = bool(batched) and _batchable(method)
    rows, failures, records, rs = score_methods({method.name: (method, pose)}, dataset, setup, split, views, seed,
                                                sampler, noise, per_class, progress, chunk,
                                                desc=f"evaluate {method.name}/{pose} {dataset.name}/{split}",
                                                batched=batched, noise_scale=noise_scale)
    rows = rows[method.name]
    if not rows:
        raise BatchError(None, f"{dataset.name}/{split}: no view could be evaluated "
                               f"({len(failures)} of {len(records)} objects failed)", failures)
    out = summarize(rows, setup.classes, dataset.name, split, views, seed, rs.sampler, noise,
                    len(records) - len(failures), rs.noise_scale)
    out["failures"] = failures
    extra = {"precision": None, "rolls": None, "mirror": None, "verify": None, "prior_tau": None, "class_prior": None,
             "ensemble": None, **method.describe()}
    out["verify"] = extra["verify"]
    return {"method": method.name, "pose": pose, "given_class": (method.name, pose) in GIVEN_CLASS,
            "precision": extra["precision"], "rolls": extra["rolls"], "mirror": extra["mirror"], "prior_tau": extra["prior_tau"],
            "class_prior": extra["class_prior"], "ensemble": extra["ensemble"],
            **({"completion_rule": extra["completion"]} if extra.get("completion") else {}),
            **({"batched": True} if batched else {}), **out}


def score_methods(methods: dict, dataset, setup: EvaluationSetup, split: str = "test", views: int = 1, seed: int = 0,
                  sampler: str | None = None, noise: bool = False, per_class: int | None = None,
                  progress: bool = True, chunk: int = 64, desc: str = "evaluate", warm_up: bool = True,
                  batched: bool = False, noise_scale: int = 1):
    """The one evaluation loop: every method of ``methods`` ({key: (Method, pose setting)}) answers
    the same query views, each rendered once, in order.

    ``batched``: a method with a ``predict_views`` member (HBEO's one network pass,
    :meth:`hbeo.evaluation.method.HBEOMethod.predict_views`) answers a chunk's views in one call (the network
    on a batch, the views marched together on a GPU); its rows are those of the per-query loop, in the same
    order, each ``ms`` the batch's time shared equally. Methods without it answer one view at a time.

    Views come from :meth:`hbeo.render.views.ObjectViews.query_views` with the setup's render
    settings, ``views`` per object, ``seed``, ``noise`` (at ``noise_scale``) and (if given) ``sampler``: view j of an
    object is drawn from a stream keyed by ``seed``, the split, the object's class and id, and j
    (the paired protocol: every method, object subset and view count sees the same image for the
    same (object, view)). ``split``: ``train``, ``test`` or ``val`` (:func:`split_records`; its
    views have a stream of their own). Each method gets what the protocol gives its (name, pose)
    (:data:`~hbeo.baselines.methods.GIVEN_CLASS`) and ``rng`` seeded by (seed, object, view);
    ``warm_up``: one untimed call per method first (first-call set-up is not a per-query cost).

    Returns ({key: per-query rows for :func:`summarize`}, failures, records, render settings)."""
    from hbeo.render.views import RenderSettings
    if views < 1:
        raise ValueError(f"views must be >= 1, got {views}")
    for key, (m, pose) in methods.items():
        if not isinstance(m, Method):
            raise TypeError(f"{key}: {type(m).__name__} does not implement the Method protocol "
                            f"(name, poses, predict_view, describe; hbeo.evaluation.method)")
        if pose not in m.poses:
            raise ValueError(f"method {m.name!r} does not take pose {pose!r}; it takes {', '.join(m.poses)}")
    rs = RenderSettings.for_queries(setup.render, views, seed, sampler, noise, noise_scale)
    K, classes, means = setup.intrinsics, tuple(setup.classes), setup.class_means
    records = split_records(dataset, split, per_class, setup.profile)
    if not records:
        raise ValueError(f"{dataset.name}: no objects in split {split!r}")
    check_evaluation(len(records), views, len(methods), rs.image_size)   # before anything is rendered
    if unknown := sorted({r.cls for r in records} - set(classes)):
        raise ValueError(f"{dataset.name}: classes {', '.join(unknown)} are unknown to the model "
                         f"(it knows {', '.join(classes)})")
    rows, failures = {key: [] for key in methods}, []
    bar = tqdm(total=len(records), desc=desc, disable=not progress)
    warm = not warm_up
    many = {key for key, (m, _) in methods.items() if batched and _batchable(m)}
    for batch in rendered_chunks(rs, records, split, chunk, failures, bar):
        seen = []                           # a view with nothing visible is not scored (never as 0) ...
        for _, rec, v, truth in batch:
            visible = [j for j in range(views) if (v["depth"][j] > 0).any()]
            seen += [(rec, v, truth, j) for j in visible]
            if not visible:                 # ... and an object none of whose views shows a pixel is a failure
                failures.append(failure(_name(rec), f"no pixel visible in any of its {views} query views at "
                                                    f"{rs.image_size[0]}x{rs.image_size[1]} (its grid has "
                                                    f"{int(np.count_nonzero(truth))} voxels); not scored",
                                        "evaluate", object=_name(rec), split=split))
        answers = {}
        for key in many:
            m = methods[key][0]
            if not warm and seen:                     # the untimed first call
                m.predict_views(seen[0][1]["depth"][seen[0][3]][None].astype(np.float32), K)
            depths = np.stack([v["depth"][j] for _, v, _, j in seen]).astype(np.float32) if seen else None
            answers[key] = iter(m.predict_views(depths, K) if seen else [])
        for rec, v, truth, j in seen:
            depth = v["depth"][j].astype(np.float32)
            for key, (m, pose) in methods.items():
                query = dict(R_true=v["rotation"][j].astype(np.float64), t_true=v["translation"][j].astype(np.float64),
                             object_size=rs.object_size, pose=pose,
                             label_true=classes.index(rec.cls) if (m.name, pose) in GIVEN_CLASS else None)
                if key in answers:
                    out = next(answers[key])
                else:
                    if not warm:
                        m.predict_view(depth, K, rng=np.random.default_rng([seed, 1]), **query)
                    rng = np.random.default_rng([seed, 2, object_key(rec), j])
                    t0 = time.perf_counter()
                    out = m.predict_view(depth, K, rng=rng, **query)
                ms = out["ms"] if "ms" in out else (time.perf_counter() - t0) * 1e3
                pred = classes[answer_label(out)]
                row = {"object": rec.id, "view": j, "class": rec.cls, "pred": pred, "R_true": v["rotation"][j],
                       "R_pred": out["rotation"], "grid": out["grid"], "truth": truth, "ms": ms}
                if "grid_paper" in out:
                    row["grid_paper"] = out["grid_paper"]
                if means is not None:
                    row["mean_pred"], row["mean_true"] = means[pred], means[rec.cls]
                rows[key].append(row)
            warm = True
        bar.update(len(batch))
    bar.close()
    return rows, failures, records, rs


def _batchable(method) -> bool:
    """Whether ``method`` answers a batch of views in one call (:meth:`HBEOMethod.predict_views`)."""
    f = getattr(method, "predict_views", None)
    return callable(f) and getattr(method, "batchable", True)


def rendered_chunks(rs, records, split: str, chunk: int, failures: list, bar):
    """Render ``records`` with settings ``rs`` ``chunk`` objects at a time: yields lists of (index,
    record, views dict of :meth:`ObjectViews.query_views` (``rs.views_per_object`` views), true grid);
    the renderer is closed before each chunk is yielded (its threads would
    compete with the caller's and distort runtimes). A bad object is appended to ``failures`` and skipped."""
    from hbeo.render.views import ObjectViews
    for start in range(0, len(records), chunk):
        viewer, batch = ObjectViews(rs), []
        span = range(start, min(start + chunk, len(records)))
        try:
            if viewer.batched():      # a GPU: the chunk's objects ray-marched together, the same arrays
                try:
                    many = viewer.query_views_many([records[i] for i in span], split, rs.views_per_object)
                    batch = [(i, records[i], v, record_grid(records[i])) for i, v in zip(span, many)]
                    span = ()
                except DataError:     # a bad object: the chunk again one object at a time, which names it
                    batch = []
            for i in span:
                try:
                    batch.append((i, records[i], viewer.query_views(records[i], split, rs.views_per_object),
                                  record_grid(records[i])))
                except DataError as err:      # a bad object: named at the end, the others still scored
                    failures.append(failure(err.path or _name(records[i]), err.problem, "evaluate",
                                            object=_name(records[i]), split=split))
                    bar.update(1)
        finally:
            viewer.close()
        yield batch


def split_records(dataset, split: str, per_class: int | None = None, profile=None) -> list:
    """The objects an evaluation of ``split`` scores: the dataset's ``train`` or ``test`` records, or
    for ``val`` the training objects that training holds out (:func:`hbeo.data.datasets.validation_records`
    of the model's ``profile``), the first ``per_class`` of each class when given."""
    if split == "val":
        from hbeo.data.datasets import validation_records
        return validation_records(dataset, profile, per_class)
    return dataset.records(split=split, per_class=per_class)


def _name(record) -> str:
    return f"{record.split}/{record.cls}/{record.id}"


def class_mean_grids(subspace) -> dict[str, np.ndarray]:
    """{class: float (30, 30, 30) mean training grid} from a fitted :class:`~hbeo.subspace.basis.ObjectSubspace`."""
    return {c: subspace.eigen_object(c).astype(np.float32) for c in subspace.classes_}


def _completion(truth: np.ndarray, pred: np.ndarray) -> dict:
    return {"edt": float(edt_error(truth, pred).mean()), "naive": float(naive_error(truth, pred).mean()),
            "iou": float(iou(truth, pred).mean())}


def class_mean_accuracy(true, pred) -> float:
    """The mean over the classes present in ``true`` of each class's accuracy (share of its queries
    whose ``pred`` equals it): every class counts the same however many queries it has. NaN for no
    queries. ``true``, ``pred``: (n,) class names or indices.

    >>> class_mean_accuracy(["a", "a", "a", "b"], ["a", "a", "b", "a"])   # (2/3 + 0) / 2
    0.3333333333333333
    """
    true, pred = np.asarray(true), np.asarray(pred)
    if true.shape != pred.shape or true.ndim != 1:
        raise ValueError(f"class_mean_accuracy: true {true.shape} and pred {pred.shape} must be the same (n,)")
    if not len(true):
        return float("nan")
    return float(np.mean([(pred[true == c] == c).mean() for c in np.unique(true)]))


def summarize(rows: list[dict], classes, dataset: str, split: str, views: int, seed: int, sampler: str,
              noise: bool, n_objects: int, noise_scale: int = 1) -> dict:
    """Metrics dict from per-query rows (class, pred, R_true, R_pred, grid, truth, ms); ``noise_scale`` only
    where it is not 1."""
    cls = np.array([r["class"] for r in rows])
    correct = np.array([r["class"] == r["pred"] for r in rows])
    Rt, Rp = np.stack([r["R_true"] for r in rows]), np.stack([r["R_pred"] for r in rows])
    raw = geodesic_deg(Rp, Rt)
    sym = np.array([symmetric_pose_error_deg(p, t, UP_SYMMETRY.get(c, 1)) for p, t, c in zip(Rp, Rt, cls)])
    truth, pred = np.stack([r["truth"] for r in rows]), np.stack([r["grid"] for r in rows])
    edt, nai, io, empty = _scores(truth, pred)
    per = {}
    for c in classes:
        m = cls == c
        if m.any():
            per[c] = {"n": int(m.sum()), "accuracy": float(correct[m].mean()),
                      "pose_mean_deg": float(raw[m].mean()), "pose_median_deg": float(np.median(raw[m])),
                      "pose_median_sym_deg": float(np.median(sym[m])),
                      "pose_within_30": float((raw[m] < 30).mean()), "edt": float(edt[m].mean()),
                      "naive": float(nai[m].mean()), "iou": float(io[m].mean())}
    index = {c: i for i, c in enumerate(classes)}
    conf = np.zeros((len(classes), len(classes)), int)
    for r in rows:
        conf[index[r["class"]], index[r["pred"]]] += 1
    return {"hbeo_version": __version__, "dataset": dataset, "split": split, "views": views, "seed": seed,
            "sampler": sampler, "noise": bool(noise), **({"noise_scale": int(noise_scale)} if noise_scale != 1 else {}),
            "n_objects": n_objects, "n_queries": len(rows),
            "accuracy": float(correct.mean()), "class_mean_accuracy": class_mean_accuracy(cls, [r["pred"] for r in rows]),
            "pose_error_deg": {"mean": float(raw.mean()), "median": float(np.median(raw)),
                               "mean_sym": float(sym.mean()), "median_sym": float(np.median(sym)),
                               "within_30": float((raw < 30).mean()), "within_30_sym": float((sym < 30).mean())},
            "completion": _means(edt, nai, io, empty),
            "runtime_ms": {"mean_per_query": float(np.mean([r["ms"] for r in rows])),
                           "median_per_query": float(np.median([r["ms"] for r in rows]))},
            "hardware": hardware(), "per_class": per, "classes": list(classes), "confusion": conf.tolist(),
            "per_query": {**({"object": [r["object"] for r in rows], "view": [int(r["view"]) for r in rows]}
                             if all("object" in r for r in rows) else {}),
                          "class": cls.tolist(), "pred": [r["pred"] for r in rows], "pose_deg": raw.round(4).tolist(),
                          "pose_sym_deg": sym.round(4).tolist(), "edt": edt.round(6).tolist(),
                          "naive": nai.round(6).tolist(), "iou": io.round(6).tolist(), "empty": empty.tolist(),
                          "ms": [round(float(r["ms"]), 4) for r in rows]},
            **_baseline(rows, truth), **_paper_rule(rows, truth)}


def _paper_rule(rows: list[dict], truth: np.ndarray) -> dict:
    """``completion_paper`` and its per-query columns when every row also carries the paper's rule's grid (HBEO
    under another completion rule), else ``{}``."""
    if not rows or not all("grid_paper" in r for r in rows):
        return {}
    edt, nai, io, empty = _scores(truth, np.stack([r["grid_paper"] for r in rows]))
    return {"completion_paper": {**_means(edt, nai, io, empty),
                                 "per_query": {"edt": edt.round(6).tolist(), "iou": io.round(6).tolist(),
                                               "empty": empty.tolist()}}}


def _scores(truth: np.ndarray, pred: np.ndarray):
    """Per-query e', naive e, IoU and emptiness (n,) each of completions ``pred`` against ``truth``."""
    return edt_error(truth, pred), naive_error(truth, pred), iou(truth, pred), pred.reshape(len(pred), -1).sum(1) == 0


def _means(edt, nai, io, empty) -> dict:
    """A ``completion`` block: the means, the share and the count of empty completions."""
    return {"edt": float(edt.mean()), "naive": float(nai.mean()), "iou": float(io.mean()),
            "empty_fraction": float(empty.mean()), "empty": int(empty.sum())}


def _baseline(rows: list[dict], truth: np.ndarray) -> dict:
    if not rows or "mean_pred" not in rows[0]:
        return {}
    mp, mt = np.stack([r["mean_pred"] for r in rows]), np.stack([r["mean_true"] for r in rows])
    return {"completion_baseline": {"predicted_class": _completion(truth, mp >= 0.5),
                                    "true_class": _completion(truth, mt >= 0.5),
                                    "true_class_iou_t03": float(iou(truth, mt >= 0.3).mean())}}
