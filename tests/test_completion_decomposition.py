"""The completion rules (hbeo.model.completion_rule) and the completion decomposition
(hbeo.evaluation.decompose, hbeo.report.completion_gap), on tiny inputs."""
import numpy as np
import pandas as pd
import pytest

from hbeo.evaluation import decompose as D
from hbeo.model import completion_rule as C
from hbeo.subspace.metrics import edt_error, iou


class _Sub:
    """A stand-in subspace: identity basis on 4^3 grids, two classes' mean fields."""

    def __init__(self):
        self.means = {"a": np.full((4, 4, 4), 0.3), "b": np.zeros((4, 4, 4))}
        self.means["b"][0, 0, :2] = 0.9

    def eigen_object(self, c):
        return self.means[c]

    def reconstruct(self, coeffs, threshold=None):
        out = np.asarray(coeffs, np.float32).reshape(-1, 4, 4, 4)
        return out >= threshold if threshold is not None else out

    def project(self, grids):
        return np.asarray(grids, np.float32).reshape(len(grids), -1)


def test_paper_rule_is_the_threshold_and_may_be_empty():
    f = np.full((1, 4, 4, 4), 0.4)
    assert not C.PAPER.complete(f).any()
    assert C.rule("paper") is C.PAPER and C.rule("nonempty").fallback


def test_nonempty_rule_fills_a_backprojection_all_below_the_threshold():
    f = np.zeros((2, 4, 4, 4))
    f[0, 1, 2, 3], f[0, 0, 0, 0] = 0.3, 0.2          # all below 0.5: the paper's rule gives nothing
    f[1, 2, 2, 2] = 0.9                               # passes: kept as is
    g = C.CompletionRule("nonempty", 0.5, True).complete(f, k=[2, 5])
    assert g[0].sum() == 2 and g[0, 1, 2, 3] and g[0, 0, 0, 0]
    assert g[1].sum() == 1 and g[1, 2, 2, 2]
    with pytest.raises(ValueError):
        C.CompletionRule("nonempty", 0.5, True).complete(f)
    with pytest.raises(ValueError):
        C.rule("nonempty", 1.5)
    with pytest.raises(ValueError):
        C.rule("other")


def test_class_occupancy_and_top_k():
    assert C.class_occupancy(_Sub(), ["a", "b"]).tolist() == [round(0.3 * 64), 2]
    assert C.top_k(np.arange(8.0).reshape(2, 2, 2), 3).ravel().tolist() == [False] * 5 + [True] * 3


def test_hbeo_predict_never_empty_when_asked(monkeypatch):
    from hbeo.model.inference import HBEO
    m = HBEO.__new__(HBEO)                      # only the completion state
    m.subspace, m.classes = _Sub(), ("a", "b")
    m.set_completion("nonempty", threshold=0.5)
    assert m.completion.threshold == 0.5 and m._occupancy.tolist() == [19, 2]
    assert m.set_completion("paper").completion is C.PAPER and m._occupancy is None


def test_elevation_of_a_camera_looking_down_and_up():
    from hbeo.rotations import yaw_elevation_roll_to_matrix
    down = np.diag([1.0, -1.0, -1.0])       # the camera's z (forward) along the object's -z: looking straight down
    assert D.elevation_deg(down[None])[0] == pytest.approx(90)
    assert D.elevation_deg(np.eye(3)[None])[0] == pytest.approx(-90)
    side = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])   # forward along the object's +y: level
    assert D.elevation_deg(side[None])[0] == pytest.approx(0)
    e = np.array([-60.0, -10.0, 25.0, 80.0])                # the samplers' own angles come back, whatever yaw and roll
    R = yaw_elevation_roll_to_matrix(np.array([0.3, 2.0, 4.0, 5.5]), np.radians(e), np.array([1.0, 0.0, 2.5, 6.0]))
    assert D.elevation_deg(R) == pytest.approx(e)


def test_query_poses_are_the_evaluations_draws():
    from hbeo.render.views import RenderSettings, query_rng

    class R:
        cls, id = "chair", "chair_0001"
    render = RenderSettings().to_dict() if hasattr(RenderSettings(), "to_dict") else {}
    (Rm, t), = D.query_poses(render, [R()], "test", 2, 0)
    rs = RenderSettings.from_dict({**render, "views_per_object": 2, "seed": 0})
    R1, _ = rs.view_sampler.sample_each([query_rng(0, "test", R(), 1)])
    assert Rm.shape == (2, 3, 3) and np.allclose(Rm[1], R1[0])


def test_score_grids_matches_the_metrics():
    rng = np.random.default_rng(0)
    truth = rng.random((5, 6, 6, 6)) > 0.6
    pred = rng.random((5, 6, 6, 6)) > 0.6
    pred[2] = False
    s = D.score_grids(truth, {"p": lambda i: pred[i]}, chunk=2)["p"]
    assert np.allclose(s["edt"], edt_error(truth, pred)) and np.allclose(s["iou"], iou(truth, pred))
    assert s["empty"].tolist() == [False, False, True, False, False]


def test_threshold_choice_is_the_lowest_mean_with_ties_nearest_half():
    scan = pd.DataFrame({"threshold": [0.3, 0.4, 0.5], "nonempty_mean_edt": [5.0, 4.0, 4.0],
                         "mean_edt": [1.0, 9.0, 9.0]})
    assert D.choose_threshold(scan) == 0.5                  # the never-empty rule's mean, not the paper's rule's
    assert D.choose_threshold(scan.assign(nonempty_mean_edt=[3.0, 4.0, 4.0])) == 0.3
    assert D.choose_threshold(scan, "mean_edt") == 0.3      # the rule's first version


def test_coefficient_r2_splits_the_error():
    dirs = {"a": np.array([1.0, 0, 0]), "b": np.array([0, 1.0, 0])}
    target = np.array([[2, 0, 1], [3, 0, -1], [0, 2, 1], [0, 4, 0.0]])
    cls = np.array(["a", "a", "b", "b"])
    r = D.coefficient_r2(target, target, cls, dirs).set_index("row")
    assert np.allclose(r["r2_global"], 1) and np.allclose(r["r2_class"], 1)
    pred = target.copy()
    pred[:, 2] = 0                                          # within-class error only
    r = D.coefficient_r2(pred, target, cls, dirs).set_index("row")
    assert r.loc["class-mean direction", "error_share"] == 0 and r.loc["within-class directions", "error_share"] == 1
    means = np.array([[2.5, 0, 0], [2.5, 0, 0], [0, 3, 0.5], [0, 3, 0.5]])   # each class's average target
    assert D.coefficient_r2(means, target, cls, dirs).set_index("row").loc["all", "r2_class"] == pytest.approx(0)


def test_completions_and_scan_on_a_stand_in_subspace():
    sub = _Sub()
    truth = np.zeros((2, 4, 4, 4), bool)
    truth[:, 0, 0, :3] = True
    coeffs = np.zeros((2, 64), np.float32)
    coeffs[0, :3] = 0.45                                    # below 0.5, above 0.4
    q = D.Queries(np.array(["b", "b"]), np.array(["x", "y"]), np.array([0, 0]), np.array(["b", "b"]),
                  np.zeros(2), truth, coeffs, sub.project(truth))
    s = D.score_grids(truth, D.completions(q, sub, ("a", "b"), (0.4, 0.5)))
    scan = D.threshold_scan(s, (0.4, 0.5))
    assert scan["empty"].tolist() == [1, 2] and D.choose_threshold(scan, "mean_edt") == 0.4
    assert not s["nonempty t=0.5"]["empty"].any()


def test_markdown_of_a_table():
    from hbeo.report.completion_gap import markdown
    rows = [D.summary("HBEO, back-projection >= 0.5", [1.0, 2.0], [0.5, 0.5], [0, 0], ["o", "p"], "validation",
                      "val", 0.5, n_boot=10),
            D.summary("HBEO, back-projection >= 0.3", [5.0, 7.0], [0.5, 0.5], [1, 1], ["o", "p"], "validation",
                      "val", 0.3, n_boot=10),
            D.summary("HBEO never empty, back-projection >= 0.5", [1.0, 2.0], [0.5, 0.5], [0, 0], ["o", "p"],
                      "validation", "val", 0.5, n_boot=10),
            D.summary("HBEO never empty, back-projection >= 0.3", [3.0, 3.0], [0.4, 0.4], [0, 0], ["o", "p"],
                      "validation", "val", 0.3, n_boot=10),
            D.summary("HBEO never empty", [1.0, 2.0], [0.5, 0.5], [0, 0], ["o", "p"], "validation", "val", 0.5,
                      n_boot=10),
            D.summary("HBEO (paper's rule, >= 0.5)", [1.0], [0.5], [1], ["o"], accuracy=1.0, n_boot=10),
            {"section": "coefficients", "row": "all", "n": 1, "error_share": 1.0, "r2_global": 0.5, "r2_class": 0.1},
            D.summary("HBEO, class right, pose within 30°", [1.0], [0.5], [1], ["o"], "hbeo_split", n_boot=10),
            D.summary("HBEO, side (-30° to 30°)", [1.0], [0.5], [1], ["o"], "elevation", accuracy=1.0, n_boot=10),
            {"section": "check", "row": "HBEO re-run here against the evaluation file", "n": 1, "accuracy": 1.0,
             "empty": 0},
            {"section": "empty", "row": "HBEO: all", "n": 1, "empty": 1},
            {"section": "empty", "row": "HBEO: chair", "n": 1, "empty": 1}]
    table = pd.DataFrame(rows, columns=list(D.COLUMNS))
    text = "\n".join(markdown(table))
    assert "chosen by lowest mean e' of the never-empty rule, the rule HBEO answers by: **0.5**" in text
    assert "| chair | 1 | 1 |" in text
    assert "| 0.3 | 2 | 6 [5, 7] | 6 | 0.500 | 2 | 3 [3, 3] | 3 | 0.400 |" in text   # both rules on one line
    assert "| 0.5 (chosen) | 2 |" in text
    first = "\n".join(markdown(table[~table["row"].str.startswith(D.SCAN_NONEMPTY)]))   # the rule's first version
    assert "the paper's rule (the rule's first version, no fallback): **0.5**" in first
    assert "| 0.3 | 2 | 6 [5, 7] | 6 | 0.500 | 2 | – | – | – |" in first
    assert "| HBEO (paper's rule, >= 0.5) | 1 | 1 [1, 1] | 1 | 0.500 | 1 | 100.0 % |" in text   # its one empty
    assert "class on 100.00 % of the 1 test queries" in text


def _queries(sub, n_obj=3, seed=0):
    rng = np.random.default_rng(seed)
    truth = np.zeros((2 * n_obj, 4, 4, 4), bool)
    truth[:, 0, 0, :2] = True
    cls = np.array(["b"] * (2 * n_obj))
    coeffs = (sub.project(truth) * rng.uniform(0.3, 0.7, (2 * n_obj, 1))).astype(np.float32)
    return D.Queries(cls, np.repeat([f"o{i}" for i in range(n_obj)], 2), np.tile([0, 1], n_obj), cls.copy(),
                     np.linspace(-80, 80, 2 * n_obj), truth, coeffs, sub.project(truth))


def _metrics(q, empty, edt=10.0):
    n = len(q.cls)
    return {"per_query": {"class": q.cls.tolist(), "object": q.object.tolist(), "view": q.view.tolist(),
                          "pred": q.pred.tolist(), "edt": [edt] * n, "iou": [0.5] * n, "empty": list(empty),
                          "pose_deg": [10.0, 50.0] * (n // 2)}}


def test_the_whole_decomposition_on_a_stand_in_model():
    class Model:
        subspace, classes = _Sub(), ("a", "b")
    test, val = _queries(Model.subspace), _queries(Model.subspace, seed=1)
    empty = (test.coeffs.max(1) < 0.5).tolist()             # what the paper's rule gives these coefficients
    evals = {"hbeo": _metrics(test, empty, 100.0), "beo": _metrics(test, [False] * len(empty))}
    table, t = D.decomposition(Model(), test, val, evals, n_boot=20)
    assert set(table["section"]) == {"validation", "completion", "check", "coefficients", "hbeo_split", "elevation",
                                     "empty"}
    check = table[table["section"] == "check"].iloc[0]
    assert check["accuracy"] == 1.0 and check["empty"] == 0
    comp = table[table["section"] == "completion"].set_index("row")
    assert comp.loc["HBEO (paper's rule, >= 0.5)", "empty"] == sum(empty) > 0
    assert comp.filter(like="never empty", axis=0)["empty"].tolist() == [0]
    # a file made under the never-empty rule: the paper's columns come from its completion_paper
    never = _metrics(test, [False] * len(empty), 50.0)
    never["completion_paper"] = {"per_query": {"edt": [100.0] * len(empty), "iou": [0.5] * len(empty),
                                               "empty": empty}}
    again, _ = D.decomposition(Model(), test, val, {**evals, "hbeo": never}, n_boot=20)
    cols = ["n", "mean_edt", "empty"]
    assert again[again["section"] == "completion"][cols].equals(table[table["section"] == "completion"][cols])


def test_default_threshold_is_the_reference_runs_validation_choice():
    """HBEO's default never-empty threshold is the one the ModelNet10 reference run's own validation scan chose
    (its decomposition table: the last validation row), so the constant cannot drift from its evidence."""
    from hbeo import config
    csv = config.REPO_ROOT / "results" / "cpu-modelnet10-vox30" / "06_completion_decomposition.csv"
    val = pd.read_csv(csv).query("section == 'validation'")
    assert float(val.iloc[-1]["threshold"]) == C.NONEMPTY_THRESHOLD
    scan = val[val["row"].str.startswith(D.SCAN_NONEMPTY)]
    if len(scan):                                           # the rule's second version: its choice is the minimum
        best = scan.loc[scan["mean_edt"].idxmin(), "threshold"]
        assert float(best) == C.NONEMPTY_THRESHOLD


def test_a_metrics_file_of_other_queries_is_named_in_a_short_error():
    """A decomposition over more queries than the evaluation file scored says so in one line, not with every
    missing key."""
    sub = _Sub()
    test = _queries(sub, n_obj=300)
    fewer = {"method": "hbeo", "per_query": {"class": test.cls[:6].tolist(), "object": test.object[:6].tolist(),
                                             "view": test.view[:6].tolist()}}
    keys = list(zip(test.cls, test.object, test.view))
    with pytest.raises(KeyError, match=r"594 of 600 queries are not in the hbeo metrics file \(6 queries\)") as err:
        D.per_query(fewer, keys)
    assert len(str(err.value)) < 300


@pytest.mark.slow
def test_the_completion_gap_decomposes_the_queries_the_evaluation_scored(ci_model, copy_run, tmp_path, monkeypatch):
    """Notebook 06's decomposition on a profile whose evaluation scores the first objects of each class (``quick``
    and ``ci`` on ModelNet10; here the ci run with 1 object per class): it scores the evaluation file's queries
    (it used to take every test object and stop on a KeyError)."""
    from hbeo.evaluation import protocol
    from hbeo.report import completion_gap
    from hbeo.run import Run
    run = copy_run(ci_model.parent, tmp_path / "run", ["model.hbeo", "subspace.npz", "grids_train.npz",
                                                     "grids_test.npz", "render_train"])
    monkeypatch.setattr(protocol, "eval_plan", lambda profile, method, pose: (1, 1))
    r = Run.open("ci", "procedural", run.path)
    h = protocol.evaluation(r, "hbeo", "3dof", progress=False)
    protocol.evaluation(r, "beo", "known", progress=False)
    assert h["n_objects"] == len(h["classes"])                   # one per class: fewer than the ci test split
    completion_gap.write_decomposition(r, progress=False)
    table = pd.read_csv(run.table(completion_gap.NAME))
    check = table[table["section"] == "check"].iloc[0]
    assert check["n"] == h["n_queries"]
