"""The completion error, taken apart: where HBEO's mean EDT error e' comes from, on the paired queries.

What this module owns: collecting HBEO's predicted coefficients on a split's paired query views
(:func:`collect`), each query's camera elevation recovered from the view protocol (:func:`query_elevations`),
scoring several completions of the same queries (:func:`score_grids`), the validation threshold scan and the
rule that chooses from it (:func:`threshold_scan`, :func:`choose_threshold`), the coefficients' R^2 split into
the class-mean direction and the within-class directions (:func:`coefficient_r2`), and the table of it all
(:func:`decomposition`). Grids are bool (n, 30, 30, 30) in the canonical frame; coefficients (n, k) subspace
coordinates; e' in voxel units (:mod:`hbeo.subspace.metrics`: an empty grid's distance field is the diagonal
R sqrt(3) everywhere, ~7,450 e' against a ModelNet10 test object); elevations in degrees.

The threshold rule (its second version, fixed on 2026-12-05 before its scan ran): the never-empty rule
(:mod:`hbeo.model.completion_rule`: back-projection >= t, and where nothing reaches t the predicted class's
mean-shape occupancy in top voxels) is scored at every t of :data:`THRESHOLDS` (0.1 to 0.5 by 0.05) on the
*validation* queries (``split="val"``: the training objects the model's training held out, with the test
protocol's views and seed); the chosen t is the one of lowest mean e' *of the never-empty rule*, the rule HBEO
answers by (ties: the one nearest 0.5). The paper's rule (>= t, no fallback) is scored beside at every t. The
first version of the rule chose on the paper's rule without its fallback over 0.2 to 0.5, so it ranked the
thresholds partly by how many completions each left empty, which the rule in use never returns; it chose 0.2, the
lowest value scanned. Test queries are then scored once at the chosen t; no test figure feeds back into it.

Elevation: query view j of an object is drawn from its own stream (:func:`hbeo.render.views.query_rng`) by the
model's training sampler (:meth:`hbeo.render.poses.ViewSampler.sample_each`); the elevation is that of the
optical axis above the object's horizon, asin(-R[2, 2]) (:mod:`hbeo.render.poses`). Bands: :data:`ELEVATIONS`.

May import: foundation, subspace, render, model and :mod:`hbeo.evaluation.evaluate` / ``intervals``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from hbeo.evaluation.intervals import cluster_bootstrap
from hbeo.subspace.metrics import distance_field, iou

#: the thresholds scanned on validation (the paper's 0.5 among them)
THRESHOLDS = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5)
#: the validation scan's row names, followed by the threshold: the paper's rule, the never-empty rule
SCAN_PAPER, SCAN_NONEMPTY = "HBEO, back-projection >= ", "HBEO never empty, back-projection >= "
#: camera elevation bands, degrees: (name, low, high], from above the object's horizon to below it
ELEVATIONS = (("from above (> 30°)", 30.0, 90.0), ("side (-30° to 30°)", -30.0, 30.0),
              ("from below (< -30°)", -90.0, -30.0))
#: the table's columns (a row fills those of its section)
COLUMNS = ("section", "row", "split", "threshold", "n", "mean_edt", "mean_edt_low", "mean_edt_high", "median_edt",
           "mean_iou", "empty", "accuracy", "error_share", "r2_global", "r2_class")


@dataclass
class Queries:
    """One split's queries, in the evaluation's order: ids (``cls``, ``object``, ``view``), HBEO's ``pred`` class,
    ``elevation`` (n,) degrees, ``truth`` (n, R, R, R) bool, ``coeffs`` (n, k) HBEO's, ``target`` (n, k) W^T o."""

    cls: np.ndarray
    object: np.ndarray
    view: np.ndarray
    pred: np.ndarray
    elevation: np.ndarray
    truth: np.ndarray
    coeffs: np.ndarray
    target: np.ndarray

    def keys(self) -> list[tuple]:
        return list(zip(self.cls.tolist(), self.object.tolist(), self.view.tolist()))


def elevation_deg(R: np.ndarray) -> np.ndarray:
    """Rotations (n, 3, 3) object -> camera -> (n,) elevation of the optical axis above the object's horizon."""
    return np.degrees(np.arcsin(np.clip(-np.asarray(R)[:, 2, 2], -1.0, 1.0)))


def query_poses(render: dict, records, split: str, views: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(R (views, 3, 3), t (views, 3)) of each record's query views under render settings ``render`` (the model's),
    drawn as the evaluation draws them, without rendering."""
    from hbeo.render.views import RenderSettings, query_rng
    rs = RenderSettings.for_queries(render, views, seed)
    return [rs.view_sampler.sample_each([query_rng(rs.seed, split, r, j) for j in range(views)]) for r in records]


def query_elevations(render: dict, records, split: str, views: int, seed: int) -> dict[tuple, float]:
    """{(class, object id, view): elevation degrees} of each record's query views (:func:`query_poses`)."""
    return {(r.cls, r.id, j): float(e) for r, (R, _) in zip(records, query_poses(render, records, split, views, seed))
            for j, e in enumerate(elevation_deg(R))}


class _Recording:
    """HBEO as a :class:`~hbeo.evaluation.method.Method` that keeps each answer's coefficients."""

    name, poses = "hbeo", ("3dof",)

    def __init__(self, model):
        self.model, self.coeffs = model, []

    def describe(self) -> dict:
        return {}

    def predict_view(self, depth, intrinsics, R_true=None, t_true=None, object_size=1.0, pose="3dof",
                     label_true=None, rng=None) -> dict:
        p = self.model.predict(depth, intrinsics)
        self.coeffs.append(p.coeffs[0].astype(np.float32))
        return {"label": int(p.labels[0]), "probabilities": p.probabilities[0], "rotation": p.rotation[0],
                "grid": p.grids[0]}


def collect(model, dataset, split: str, views: int, seed: int, per_class=None, progress: bool = True) -> Queries:
    """HBEO's answers on ``split``'s paired query views (:func:`hbeo.evaluation.evaluate.score_methods`, the one
    evaluation loop), with their coefficients, the targets' W^T o and each view's elevation, which is checked
    against the rendered view's rotation (:func:`query_poses` draws what the loop drew)."""
    from hbeo.evaluation.evaluate import EvaluationSetup, score_methods
    setup = EvaluationSetup.of_model(model, class_means=False)
    m = _Recording(model)
    rows, failures, records, rs = score_methods({"hbeo": (m, "3dof")}, dataset, setup, split, views, seed,
                                                per_class=per_class, progress=progress, warm_up=False,
                                                desc=f"decompose {dataset.name}/{split}")
    rows = rows["hbeo"]
    poses = {(r.cls, r.id): R for r, (R, _) in zip(records, query_poses(setup.render, records, split, views, seed))}
    R_true = np.stack([r["R_true"] for r in rows])
    R_drawn = np.stack([poses[(r["class"], r["object"])][r["view"]] for r in rows])
    if not np.allclose(R_true, R_drawn, atol=1e-6):
        raise RuntimeError("the recovered query poses differ from the rendered views' (view protocol changed?)")
    truth = np.stack([r["truth"] for r in rows]).astype(bool)
    return Queries(np.array([r["class"] for r in rows]), np.array([r["object"] for r in rows]),
                   np.array([r["view"] for r in rows]), np.array([r["pred"] for r in rows]), elevation_deg(R_true),
                   truth, np.stack(m.coeffs), model.subspace.project(truth))


def score_grids(truth: np.ndarray, predictors: dict, chunk: int = 128) -> dict[str, dict[str, np.ndarray]]:
    """Score several completions of the same targets: ``predictors`` {name: f(index array) -> bool grids of those
    queries}; returns {name: {"edt", "iou", "empty"}} (n,) each. e' is :func:`hbeo.subspace.metrics.edt_error`'s,
    with each target's distance field computed once for all predictors."""
    n = len(truth)
    out = {k: {"edt": np.zeros(n), "iou": np.zeros(n), "empty": np.zeros(n, bool)} for k in predictors}
    for s in range(0, n, chunk):
        idx = np.arange(s, min(s + chunk, n))
        Dt = [distance_field(t) for t in truth[idx]]
        for name, f in predictors.items():
            g = np.asarray(f(idx)).astype(bool)
            o = out[name]
            o["edt"][idx] = [np.linalg.norm(d - distance_field(p)) for d, p in zip(Dt, g)]
            o["iou"][idx] = iou(truth[idx], g)
            o["empty"][idx] = ~g.reshape(len(g), -1).any(1)
    return out


def completions(q: Queries, subspace, classes, thresholds=THRESHOLDS) -> dict:
    """Predictors for :func:`score_grids` of HBEO's coefficients: ``t=<t>`` (>= t) and ``nonempty t=<t>`` (the
    never-empty rule at t, k the predicted class's mean-shape occupancy) for each of ``thresholds``."""
    from hbeo.model.completion_rule import CompletionRule, class_occupancy
    k = class_occupancy(subspace, classes)[[list(classes).index(c) for c in q.pred]]
    preds = {}
    for t in thresholds:
        plain, never = CompletionRule("paper", t), CompletionRule("nonempty", t, True)
        preds[f"t={t:g}"] = lambda i, r=plain: r.complete(subspace.reconstruct(q.coeffs[i]))
        preds[f"nonempty t={t:g}"] = lambda i, r=never: r.complete(subspace.reconstruct(q.coeffs[i]), k[i])
    return preds


def _empty_at(q: Queries, subspace, t: float) -> np.ndarray:
    """(n,) bool: which of ``q``'s completions at threshold ``t`` are empty."""
    return np.concatenate([~subspace.reconstruct(q.coeffs[i:i + 256], threshold=t).reshape(len(q.coeffs[i:i + 256]), -1)
                           .any(1) for i in range(0, len(q.coeffs), 256)])


def threshold_scan(scores: dict, thresholds=THRESHOLDS) -> pd.DataFrame:
    """One row per threshold: mean and median e', mean IoU and empty count of the paper's rule at t, and the mean
    e' and IoU of the never-empty rule at t (``scores``: :func:`score_grids` of :func:`completions`)."""
    rows = []
    for t in thresholds:
        a, b = scores[f"t={t:g}"], scores[f"nonempty t={t:g}"]
        rows.append({"threshold": t, "mean_edt": a["edt"].mean(), "median_edt": float(np.median(a["edt"])),
                     "mean_iou": a["iou"].mean(), "empty": int(a["empty"].sum()),
                     "nonempty_mean_edt": b["edt"].mean(), "nonempty_mean_iou": b["iou"].mean()})
    return pd.DataFrame(rows)


def choose_threshold(scan: pd.DataFrame, column: str = "nonempty_mean_edt") -> float:
    """The module's rule: the threshold of lowest mean e' of the never-empty rule (``column``) in a validation
    scan; ties: nearest 0.5. ``column="mean_edt"`` gives the first version's choice (the paper's rule at t)."""
    best = scan[column].min()
    tied = scan[np.isclose(scan[column], best, rtol=0, atol=1e-9)]
    return float(tied.iloc[np.argmin(np.abs(tied["threshold"].to_numpy() - 0.5))]["threshold"])


def mean_directions(subspace, classes) -> dict[str, np.ndarray]:
    """{class: (k,) unit vector W^T mu_c}: each class mean's direction in coefficient space."""
    out = {}
    for c in classes:
        v = subspace.project(subspace.eigen_object(c)[None].astype(np.float32))[0].astype(np.float64)
        out[c] = v / np.linalg.norm(v)
    return out


def _r2(sse: float, ss: float) -> float:
    """1 - sse / ss; NaN when the targets do not vary (ss = 0: R² is undefined)."""
    return 1 - sse / ss if ss > 0 else float("nan")


def coefficient_r2(pred, target, cls, directions: dict) -> pd.DataFrame:
    """Predicted coefficients ``pred`` (n, k) against ``target`` (n, k), split for each query (true class ``cls``)
    into the component along its class mean's direction (``directions``: :func:`mean_directions`) and the rest
    (the within-class directions). Rows ``class-mean direction``, ``within-class directions``, ``all``:
    ``error_share`` (that part's share of the squared error; NaN for a perfect answer), ``r2_global`` (1 - SSE / the targets' sum of squares
    about their overall mean) and ``r2_class`` (1 - SSE / about each class's mean target: 0 is no better than
    answering each class's average coefficients)."""
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    cls = np.asarray(cls)
    U = np.stack([directions[c] for c in cls])
    ap, at = (pred * U).sum(1), (target * U).sum(1)
    parts = {"class-mean direction": (ap[:, None], at[:, None]),
             "within-class directions": (pred - ap[:, None] * U, target - at[:, None] * U), "all": (pred, target)}
    sse = {k: float(((p - t) ** 2).sum()) for k, (p, t) in parts.items()}
    rows = []
    for k, (p, t) in parts.items():
        centred = t.copy()
        for c in np.unique(cls):
            centred[cls == c] -= t[cls == c].mean(0)
        rows.append({"row": k, "n": len(cls), "error_share": sse[k] / sse["all"] if sse["all"] > 0 else np.nan,
                     "r2_global": _r2(sse[k], float(((t - t.mean(0)) ** 2).sum())),
                     "r2_class": _r2(sse[k], float((centred ** 2).sum()))})
    return pd.DataFrame(rows)


def summary(name: str, edt, iou_, empty, groups, section: str = "completion", split: str = "test",
            threshold=np.nan, accuracy=np.nan, n_boot: int = 2000) -> dict:
    """One row: mean e' with its 95 % bootstrap interval over ``groups`` (objects), median e', mean IoU, empties."""
    edt = np.asarray(edt, np.float64)
    m, lo, hi = cluster_bootstrap(edt, groups, n_boot=n_boot) if len(edt) else (np.nan,) * 3
    return {"section": section, "row": name, "split": split, "threshold": threshold, "n": len(edt), "mean_edt": m,
            "mean_edt_low": lo, "mean_edt_high": hi, "median_edt": float(np.median(edt)) if len(edt) else np.nan,
            "mean_iou": float(np.mean(iou_)) if len(edt) else np.nan, "empty": int(np.sum(empty)),
            "accuracy": accuracy}


def per_query(metrics: dict, keys: list[tuple]) -> pd.DataFrame:
    """A metrics dict's ``per_query`` columns in the order of ``keys`` ((class, object, view) each); KeyError
    names a query the file lacks."""
    q = pd.DataFrame(metrics["per_query"])
    q.index = pd.MultiIndex.from_arrays([q["class"], q["object"], q["view"]])
    missing = [k for k in keys if k not in q.index]
    if missing:
        raise KeyError(f"{len(missing)} of {len(keys)} queries are not in the {metrics.get('method')} metrics file "
                       f"({len(q)} queries), e.g. {missing[0]}: it was made on other objects or views")
    return q.loc[keys].reset_index(drop=True)


def paper_per_query(metrics: dict, keys: list[tuple]) -> pd.DataFrame:
    """:func:`per_query` with the completion columns (``edt``, ``iou``, ``empty``) under the paper's rule: the file's
    own where HBEO completed by it, its ``completion_paper`` columns where it completed by another rule."""
    paper = metrics.get("completion_paper")
    if paper is None:
        return per_query(metrics, keys)
    return per_query({"per_query": {**metrics["per_query"], **paper["per_query"]}}, keys)


def decomposition(model, test: Queries, val: Queries, evals: dict, n_boot: int = 2000) -> tuple[pd.DataFrame, float]:
    """The table (:data:`COLUMNS`) and the threshold chosen on ``val``. ``evals``: the run's metrics dicts of the
    same test queries, {"hbeo": HBEO 3-DOF, "beo": BEO known pose, "voxcnn": the 3-D CNN} (the last optional).

    Sections: ``validation`` (the scan at each threshold, the paper's rule then the never-empty one, and last the
    never-empty rule at the chosen threshold again, named as the test rows name it),
    ``completion`` (test: class mean shape of the true class, the full-grid projection ceiling W W^T o, BEO,
    HBEO as evaluated, HBEO at the chosen threshold, HBEO never empty), ``coefficients`` (:func:`coefficient_r2`),
    ``hbeo_split`` (class right / wrong x pose within / outside 30°), ``elevation`` (:data:`ELEVATIONS`: accuracy,
    IoU and e' of HBEO and BEO), ``empty`` (empty completions per class and method), ``check`` (one row: the share
    of test queries where this run of the model gives the evaluation file's class, as ``accuracy``, and the number
    whose emptiness at 0.5 differs from the file's, as ``empty``: the rows mix the file's and this run's answers)."""
    sub, classes = model.subspace, tuple(model.classes)
    vs = score_grids(val.truth, completions(val, sub, classes))
    scan = threshold_scan(vs)
    t = choose_threshold(scan)
    vkey = np.char.add(np.char.add(val.cls.astype(str), "/"), val.object.astype(str))
    rows = [summary(f"{label}{x:g}", vs[f"{key}{x:g}"]["edt"], vs[f"{key}{x:g}"]["iou"], vs[f"{key}{x:g}"]["empty"],
                    vkey, "validation", "val", x, n_boot=n_boot)
            for label, key in ((SCAN_PAPER, "t="), (SCAN_NONEMPTY, "nonempty t=")) for x in scan["threshold"]]
    rows.append(summary(f"HBEO never empty (>= {t:g}, else class-mean occupancy)", vs[f"nonempty t={t:g}"]["edt"],
                        vs[f"nonempty t={t:g}"]["iou"], vs[f"nonempty t={t:g}"]["empty"], vkey, "validation", "val",
                        t, n_boot=n_boot))
    keys = test.keys()
    h, b = paper_per_query(evals["hbeo"], keys), per_query(evals["beo"], keys)
    means = {c: sub.eigen_object(c) >= 0.5 for c in classes}
    preds = {**completions(test, sub, classes, (t,)),
             "mean": lambda i: np.stack([means[c] for c in test.cls[i]]),
             "ceiling": lambda i: sub.reconstruct(sub.project(test.truth[i]), threshold=0.5)}
    s = score_grids(test.truth, preds)
    key = np.char.add(np.char.add(test.cls.astype(str), "/"), test.object.astype(str))
    acc = {"hbeo": (h["class"] == h["pred"]).to_numpy(), "beo": (b["class"] == b["pred"]).to_numpy()}
    he, be = h["empty"].to_numpy(bool), b["empty"].to_numpy(bool)
    tt, nt = s[f"t={t:g}"], s[f"nonempty t={t:g}"]
    rows += [summary("class mean shape (true class, >= 0.5)", s["mean"]["edt"], s["mean"]["iou"], s["mean"]["empty"],
                     key, threshold=0.5, n_boot=n_boot),
             summary("full-grid projection ceiling (W W^T o, >= 0.5)", s["ceiling"]["edt"], s["ceiling"]["iou"],
                     s["ceiling"]["empty"], key, threshold=0.5, n_boot=n_boot),
             summary("BEO, partial projection, known pose", b["edt"], b["iou"], be, key, threshold=0.5,
                     accuracy=acc["beo"].mean(), n_boot=n_boot),
             summary("HBEO (paper's rule, >= 0.5)", h["edt"], h["iou"], he, key, threshold=0.5,
                     accuracy=acc["hbeo"].mean(), n_boot=n_boot),
             summary(f"HBEO, threshold chosen on validation (>= {t:g})", tt["edt"], tt["iou"], tt["empty"], key,
                     threshold=t, accuracy=acc["hbeo"].mean(), n_boot=n_boot),
             summary(f"HBEO never empty (>= {t:g}, else class-mean occupancy)", nt["edt"], nt["iou"], nt["empty"],
                     key, threshold=t, accuracy=acc["hbeo"].mean(), n_boot=n_boot)]
    same = (test.pred == h["pred"].to_numpy()).mean()      # the coefficients come from this run of the model
    differ = int(((s[f"t={t:g}"]["empty"] if t == 0.5 else _empty_at(test, sub, 0.5)) != he).sum())
    rows.append({"section": "check", "row": "HBEO re-run here against the evaluation file", "split": "test",
                 "n": len(he), "accuracy": float(same), "empty": differ})
    r2 = coefficient_r2(test.coeffs, test.target, test.cls, mean_directions(sub, classes))
    rows += [{"section": "coefficients", "split": "test", **r} for r in r2.to_dict("records")]
    right, within = acc["hbeo"], (h["pose_deg"] < 30).to_numpy()
    for cm, cv in ((True, "class right"), (False, "class wrong")):
        for pm, pv in ((True, "pose within 30°"), (False, "pose outside 30°")):
            m = (right == cm) & (within == pm)
            rows.append(summary(f"HBEO, {cv}, {pv}", h["edt"][m], h["iou"][m], he[m], key[m], "hbeo_split",
                                threshold=0.5, n_boot=n_boot))
    for name, lo, hi in ELEVATIONS:
        m = (test.elevation > lo) & (test.elevation <= hi) if lo > -90 else (test.elevation <= hi)
        for who, q, e, a in (("HBEO", h, he, acc["hbeo"]), ("BEO, known pose", b, be, acc["beo"])):
            rows.append(summary(f"{who}, {name}", q["edt"][m], q["iou"][m], e[m], key[m], "elevation",
                                threshold=0.5, accuracy=float(a[m].mean()), n_boot=n_boot))
    counts = {"HBEO": he, "BEO, known pose": be, f"HBEO never empty (>= {t:g})": nt["empty"]}
    if evals.get("voxcnn") is not None:
        counts["3-D CNN, known pose"] = per_query(evals["voxcnn"], keys)["empty"].to_numpy(bool)
    for c in ("all", *classes):
        m = np.ones(len(key), bool) if c == "all" else test.cls == c
        for who, e in counts.items():
            rows.append({"section": "empty", "row": f"{who}: {c}", "split": "test", "n": int(m.sum()),
                         "empty": int(e[m].sum())})
    return pd.DataFrame(rows, columns=list(COLUMNS)), t
