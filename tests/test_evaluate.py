import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hbeo.evaluation.evaluate import summarize
from hbeo.rotations import symmetric_pose_error_deg as symmetric_pose_error
from hbeo.rotations import uniform_so3


def test_symmetric_pose_error_forgives_only_the_class_turns():
    R = uniform_so3(20, np.random.default_rng(0))
    half = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    quarter = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    assert np.allclose(symmetric_pose_error(R @ half, R, 2), 0, atol=1e-5)
    assert np.allclose(symmetric_pose_error(R @ half, R, 1), 180, atol=1e-4)
    assert np.allclose(symmetric_pose_error(R @ quarter, R, 4), 0, atol=1e-5)
    assert np.allclose(symmetric_pose_error(R @ quarter, R, 2), 90, atol=1e-4)
    tilt = Rotation.from_euler("x", 30, degrees=True).as_matrix()
    assert np.allclose(symmetric_pose_error(R @ tilt, R, 4), 30, atol=1e-4)   # not an up-axis turn


def test_summary_keys_and_values():
    g = np.zeros((30, 30, 30), bool)
    g[10:20, 10:20, 10:20] = True
    R = np.eye(3)
    flip = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    rows = [{"class": "table", "pred": "table", "R_true": R, "R_pred": flip, "grid": g, "truth": g, "ms": 2.0},
            {"class": "chair", "pred": "table", "R_true": R, "R_pred": R, "grid": g, "truth": g, "ms": 4.0}]
    m = summarize(rows, ("chair", "table"), "procedural", "test", 1, 0, "so3", False, 2)
    assert m["accuracy"] == 0.5 and m["n_queries"] == 2
    assert m["pose_error_deg"]["mean"] == 90 and m["pose_error_deg"]["mean_sym"] == 0
    assert m["pose_error_deg"]["within_30"] == 0.5 and m["pose_error_deg"]["within_30_sym"] == 1.0
    assert m["per_class"]["table"]["pose_within_30"] == 0 and m["per_class"]["chair"]["pose_within_30"] == 1
    assert m["completion"]["iou"] == 1.0 and m["runtime_ms"]["mean_per_query"] == 3.0
    from hbeo.machine import hardware
    assert m["hardware"] == hardware() and m["hardware"]["cores"] >= 1       # the machine that timed it
    assert m["per_class"]["table"]["pose_median_deg"] == 180 and m["per_class"]["table"]["pose_median_sym_deg"] == 0
    assert m["confusion"] == [[0, 1], [0, 1]]


def test_evaluation_reads_its_cache_only_for_the_same_request(tmp_path, monkeypatch):
    """A cached eval_<method>_<pose>.json answers the same request (code version, dataset, model and
    baseline files, objects, views, seed) without loading anything; a change to any of them must
    evaluate again, here failing on the (fake) model file."""
    import json
    import pytest
    from hbeo.data import datasets
    from hbeo.errors import DataError
    from hbeo.evaluation import protocol
    from hbeo.rundir import RunDir
    from hbeo.run import Run
    run = RunDir(tmp_path).create()
    run.model.write_bytes(b"not a model")
    run.baseline("beo").write_bytes(b"not a baseline")
    ds = datasets.get_dataset("procedural", profile="ci")
    r = Run.open("ci", "procedural", run.path)
    req = protocol.request(r, "beo", "3dof")
    assert req["per_class"] == 1 and req["views"] == 1 and req["code"] == protocol.code_version()
    assert req["baseline_sha256"] and req["model_sha256"] and req["dataset_fingerprint"] == ds.fingerprint()
    run.evaluation("beo", "3dof").write_text(json.dumps({"accuracy": 0.5, "request": req}))
    assert protocol.evaluation(r, "beo", "3dof")["accuracy"] == 0.5   # ci: 1 per class
    assert protocol.evaluation(Run.open("ci", "procedural", str(tmp_path)), "beo", "3dof")["accuracy"] == 0.5
    run.baseline("beo").write_bytes(b"another baseline")                 # the baseline file changed
    with pytest.raises(DataError):
        protocol.evaluation(r, "beo", "3dof")
    run.baseline("beo").write_bytes(b"not a baseline")
    monkeypatch.setattr(protocol, "code_version", lambda: "other code")   # the code changed
    with pytest.raises(DataError):
        protocol.evaluation(r, "beo", "3dof")


def test_batched_evaluation_gives_the_per_query_answers(ci_model):
    """HBEO's one pass on a chunk of views in one network call answers every query as the per-query loop does:
    the same classes and completions, poses within float32 rounding (the network's kernels may sum a batch in
    another order)."""
    from hbeo import config
    from hbeo.data.datasets import get_dataset
    from hbeo.evaluation.evaluate import evaluate_model
    from hbeo.model.inference import HBEO
    model = HBEO.load(ci_model)
    ds = get_dataset("procedural", profile=config.get_profile("ci"))
    one = evaluate_model(model, ds, split="test", views=2, seed=3, progress=False)
    many = evaluate_model(model, ds, split="test", views=2, seed=3, progress=False, batched=True, chunk=4)
    assert many["batched"] is True and "batched" not in one
    a, b = one["per_query"], many["per_query"]
    assert len(a["pred"]) == len(b["pred"]) == one["n_queries"] > 8
    for key in ("object", "view", "class", "pred", "empty"):
        assert a[key] == b[key], key
    np.testing.assert_allclose(a["pose_deg"], b["pose_deg"], atol=1e-3)
    np.testing.assert_allclose(a["edt"], b["edt"], rtol=1e-6)
    np.testing.assert_allclose(a["iou"], b["iou"], atol=1e-6)
    assert one["completion_paper"]["per_query"] == many["completion_paper"]["per_query"]
    # verify has no batched path: the per-query loop answers, and the file does not say batched
    from hbeo.model.verify import VerifyConfig
    v = evaluate_model(model, ds, split="test", views=1, seed=3, per_class=1, progress=False, batched=True,
                       verify=VerifyConfig())
    assert "batched" not in v


def test_an_object_with_no_visible_view_is_a_failure_not_a_silent_drop(ci_model, monkeypatch):
    """A query view with no pixel is not scored; an object none of whose views shows a pixel (a grid of a few
    voxels, as ModelNet10's bathtub_0070 at 80x60) is listed in ``failures`` and not counted in ``n_objects``."""
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.evaluation import evaluate as ev
    from hbeo.model.inference import HBEO
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    original = ev.rendered_chunks

    def blank_first(*args, **kw):
        for batch in original(*args, **kw):
            for i, rec, v, truth in batch:
                if i == 0:
                    v["depth"][:] = 0
            yield batch

    monkeypatch.setattr(ev, "rendered_chunks", blank_first)
    m = ev.evaluate_model(HBEO.load(ci_model), ds, split="test", views=2, seed=0, per_class=1, progress=False)
    first = ds.records(split="test", per_class=1)[0]
    assert [f["object"] for f in m["failures"]] == [ev._name(first)]
    assert "no pixel visible in any of its 2 query views at 80x60" in m["failures"][0]["reason"]
    n = len(ds.records(split="test", per_class=1))
    assert m["n_objects"] == n - 1 and m["n_queries"] == 2 * (n - 1)
    assert first.id not in m["per_query"]["object"]


def test_summary_class_mean_is_the_mean_of_per_class_accuracies_not_the_accuracy():
    """Three chairs (all right) and one table (wrong): accuracy 3/4, class mean (1 + 0) / 2; the symmetric
    median forgives the table's quarter turn (order 4), the plain one does not."""
    g = np.zeros((30, 30, 30), bool)
    g[10:20, 10:20, 10:20] = True
    R, quarter = np.eye(3), Rotation.from_euler("z", 90, degrees=True).as_matrix()
    rows = [{"class": "chair", "pred": "chair", "R_true": R, "R_pred": R, "grid": g, "truth": g, "ms": 1.0}] * 3 + \
           [{"class": "table", "pred": "chair", "R_true": R, "R_pred": quarter, "grid": g, "truth": g, "ms": 1.0}]
    m = summarize(rows, ("chair", "table"), "procedural", "test", 1, 0, "so3", False, 4)
    assert m["accuracy"] == 0.75 and m["class_mean_accuracy"] == 0.5
    assert m["per_class"]["table"]["pose_median_deg"] == pytest.approx(90)
    assert m["per_class"]["table"]["pose_median_sym_deg"] == pytest.approx(0, abs=1e-6)
