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
