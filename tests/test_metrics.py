import numpy as np
import pytest

from hbeo.subspace import metrics


def cube(lo, hi, r=30):
    g = np.zeros((r, r, r), bool)
    g[lo:hi, lo:hi, lo:hi] = True
    return g


def test_identical_grids_are_perfect():
    g = cube(10, 20)
    assert metrics.edt_error(g, g) == 0 and metrics.naive_error(g, g) == 1.0
    assert metrics.iou(g, g) == 1.0 and metrics.chamfer(g, g) == 0.0


def test_known_values_for_a_shifted_and_a_shrunk_cube():
    a, b = cube(10, 20), cube(11, 21)
    mism = 2 * (1000 - 729)                         # 9^3 voxels overlap after the diagonal shift
    assert metrics.naive_error(a, b) == pytest.approx(1 - np.sqrt(mism) / np.sqrt(1000))
    assert metrics.iou(a, b) == pytest.approx(729 / (2000 - 729))
    small = cube(11, 19)            # one voxel thinner on every side: every outer voxel is 1 farther
    from scipy import ndimage
    expected = np.linalg.norm(ndimage.distance_transform_edt(~a) - ndimage.distance_transform_edt(~small))
    assert metrics.edt_error(a, small) == pytest.approx(expected)
    assert metrics.edt_error(a, small) < metrics.edt_error(a, cube(2, 8))   # near miss beats far miss
    assert metrics.chamfer(a, small) == pytest.approx(1.0, abs=0.3)


def test_edt_is_robust_to_small_shifts_unlike_naive():
    a, b = cube(10, 20), cube(11, 21)
    far = cube(5, 25)
    assert metrics.naive_error(a, b) < 0.3          # a one-voxel shift costs most of the naive score
    assert metrics.edt_error(a, b) < metrics.edt_error(a, far)


def test_empty_grids_have_documented_results():
    e, g = np.zeros((30, 30, 30), bool), cube(10, 20)
    diag = 30 * np.sqrt(3)
    assert metrics.edt_error(e, e) == 0 and metrics.iou(e, e) == 1.0 and metrics.chamfer(e, e) == 0
    assert np.isfinite(metrics.edt_error(g, e)) and metrics.edt_error(g, e) > metrics.edt_error(g, cube(2, 5))
    assert np.allclose(metrics.distance_field(e), diag)
    assert metrics.iou(g, e) == 0.0 and metrics.chamfer(g, e) == pytest.approx(diag)
    assert metrics.naive_error(g, e) == 0.0
    with pytest.raises(ValueError, match="empty target"):
        metrics.naive_error(e, g)


def test_batched_matches_single_and_float_predictions_threshold():
    rng = np.random.default_rng(0)
    t = rng.random((4, 30, 30, 30)) > 0.7
    p = rng.random((4, 30, 30, 30))
    out = metrics.completion_errors(t, p)
    for k, fn in [("edt", metrics.edt_error), ("naive", metrics.naive_error), ("iou", metrics.iou),
                  ("chamfer", metrics.chamfer)]:
        assert out[k].shape == (4,)
        assert out[k][2] == pytest.approx(fn(t[2], p[2] > 0.5))
    with pytest.raises(ValueError, match="differ in shape"):
        metrics.iou(t, p[:2])
    with pytest.raises(ValueError, match="expected a grid"):
        metrics.iou(np.zeros((3, 3)), np.zeros((3, 3)))


@pytest.mark.parametrize("block,threads", [(128, 1), (5, 1), (5, 3), (1, 2)])
def test_edt_of_repeated_grids_is_the_one_field_a_pair_figure(monkeypatch, block, threads):
    """Grids that repeat (an object's views, a class's mean shape, an empty completion) have their distance
    field computed once, blocks of fields on several threads: the same numbers as computing it for every pair."""
    monkeypatch.setattr(metrics, "EDT_BLOCK", block)
    from hbeo.subspace.metrics import distance_field
    rng = np.random.default_rng(3)
    objs = rng.random((4, 12, 12, 12)) < 0.15
    truth = np.repeat(objs, 3, axis=0)                          # three views of each object
    means = rng.random((2, 12, 12, 12)) < 0.2
    for pred in (rng.random((12, 12, 12, 12)) < 0.15, means[rng.integers(0, 2, 12)]):
        pred = pred.copy()
        pred[2] = False                                          # an empty completion
        pred[4] = truth[4]                                       # a perfect one: its field is the target's
        pred[9] = truth[0]                                       # another object's grid, used again after its last view
        want = np.array([np.linalg.norm(distance_field(a) - distance_field(b)) for a, b in zip(truth, pred)])
        got = metrics.edt_error(truth, pred, threads=threads)
        assert np.array_equal(got, want) and got[4] == 0 and got[2] > 0


def _query(cls, pred, R_pred, grid, truth, **extra):
    """One per-query row as hbeo.evaluation.evaluate.summarize reads it (true rotation: identity)."""
    return {"class": cls, "pred": pred, "R_true": np.eye(3), "R_pred": R_pred, "grid": grid, "truth": truth,
            "ms": 1.0, **extra}


def test_summary_median_symmetric_pose_error_uses_the_symmetry_adjusted_errors():
    """A table (4-fold symmetric about +z) turned by 180 degrees has a raw error of 180 and a symmetric
    error of 0; a chair (no symmetry) turned by 60 degrees has 60 for both. Three tables and one chair:
    raw median 180, symmetric median 0 (and symmetric mean 15)."""
    from scipy.spatial.transform import Rotation
    from hbeo.conventions import UP_SYMMETRY
    from hbeo.evaluation.evaluate import summarize
    assert UP_SYMMETRY["table"] == 4 and UP_SYMMETRY.get("chair", 1) == 1
    g = cube(10, 20)
    half = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    sixty = Rotation.from_euler("z", 60, degrees=True).as_matrix()
    rows = [_query("table", "table", half, g, g)] * 3 + [_query("chair", "chair", sixty, g, g)]
    m = summarize(rows, ("chair", "table"), "procedural", "test", 1, 0, "so3", False, 4)
    pe = m["pose_error_deg"]
    assert pe["median"] == pytest.approx(180) and pe["mean"] == pytest.approx(150)
    assert pe["median_sym"] == pytest.approx(0, abs=1e-4)
    assert pe["mean_sym"] == pytest.approx(15, abs=1e-4)
    assert pe["within_30"] == 0 and pe["within_30_sym"] == 0.75
    assert m["per_query"]["pose_sym_deg"] == pytest.approx([0, 0, 0, 60], abs=1e-3)
    assert m["per_class"]["chair"]["pose_median_sym_deg"] == pytest.approx(60, abs=1e-4)


def test_summary_completion_baseline_uses_the_predicted_and_the_true_class_mean_shapes():
    """The class-mean completion baseline: ``predicted_class`` thresholds the mean shape of the class the
    method *predicted*, ``true_class`` that of the true class. With a wrong prediction and two classes whose
    mean shapes differ, the two differ: here the true class's mean is the object itself (IoU 1, e' 0) and the
    predicted class's mean a disjoint box (IoU 0)."""
    from hbeo.evaluation.evaluate import summarize
    chair_mean = cube(10, 20).astype(np.float32) * 0.9             # >= 0.5 exactly on the object
    table_mean = cube(2, 8).astype(np.float32) * 0.7               # disjoint from it
    truth = cube(10, 20)
    rows = [_query("chair", "table", np.eye(3), truth, truth, mean_pred=table_mean, mean_true=chair_mean),
            _query("chair", "chair", np.eye(3), truth, truth, mean_pred=chair_mean, mean_true=chair_mean)]
    m = summarize(rows, ("chair", "table"), "procedural", "test", 1, 0, "so3", False, 1)
    b = m["completion_baseline"]
    assert b["true_class"]["iou"] == pytest.approx(1.0) and b["true_class"]["edt"] == pytest.approx(0.0)
    assert b["predicted_class"]["iou"] == pytest.approx(0.5)        # mean of 0 (wrong class) and 1
    wrong = metrics.edt_error(truth, table_mean >= 0.5)
    assert b["predicted_class"]["edt"] == pytest.approx(wrong / 2) and wrong > 0
    assert b["predicted_class"]["naive"] == pytest.approx((metrics.naive_error(truth, table_mean >= 0.5) + 1) / 2)
    assert b["true_class_iou_t03"] == pytest.approx(1.0)
    assert "completion_baseline" not in summarize([{k: v for k, v in r.items() if not k.startswith("mean_")}
                                                   for r in rows], ("chair", "table"), "procedural", "test",
                                                  1, 0, "so3", False, 1)
