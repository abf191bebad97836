"""Bootstrap intervals over objects (hbeo.evaluation.intervals)."""
import numpy as np
import pytest

from hbeo.evaluation.intervals import cluster_bootstrap, interval, intervals


def test_interval_covers_the_truth_and_narrows_with_more_objects():
    rng = np.random.default_rng(1)
    widths = []
    for n in (50, 800):
        x = rng.random(n) < 0.7
        est, lo, hi = cluster_bootstrap(x, np.arange(n), n_boot=500)
        assert lo <= 0.7 <= hi and lo <= est <= hi
        widths.append(hi - lo)
    assert widths[1] < widths[0] / 2.5                    # ~ 1 / sqrt(n)
    assert cluster_bootstrap(x, np.arange(800), n_boot=500) == cluster_bootstrap(x, np.arange(800), n_boot=500)


def test_views_of_one_object_are_resampled_together():
    """Three identical views per object carry the information of one: the object bootstrap's interval
    matches the one-view-per-object interval, the query bootstrap's is too narrow."""
    rng = np.random.default_rng(2)
    per_object = (rng.random(200) < 0.6).astype(float)
    views = np.repeat(per_object, 3)
    objects = np.repeat(np.arange(200), 3)
    _, lo1, hi1 = cluster_bootstrap(per_object, np.arange(200), n_boot=1000)
    _, lo3, hi3 = cluster_bootstrap(views, objects, n_boot=1000)
    _, lq, hq = cluster_bootstrap(views, np.arange(600), n_boot=1000)
    assert abs((hi3 - lo3) - (hi1 - lo1)) < 0.02 and (hq - lq) < 0.75 * (hi3 - lo3)


def test_interval_of_a_metrics_dict_and_bad_input():
    q = {"object": ["a", "a", "b", "c"], "class": ["x", "x", "y", "y"], "pred": ["x", "y", "y", "y"],
         "pose_deg": [10.0, 50.0, 20.0, 100.0], "iou": [0.5, 0.7, 0.2, 0.4]}
    m = {"per_query": q}
    assert interval(m, "accuracy")[0] == 0.75 and interval(m, "iou")[0] == pytest.approx(0.45)
    assert interval(m, "pose_median")[0] == 35.0 and interval(m, "within_30")[0] == 0.5
    with pytest.raises(ValueError, match="unknown statistic"):
        interval(m, "speed")
    with pytest.raises(ValueError, match="must be equal"):
        cluster_bootstrap(np.ones(3), np.ones(2))


def test_class_mean_weighs_every_class_alike_and_resamples_objects():
    """class_mean: the mean of the per-class accuracies (evaluate's class_mean_accuracy), not the share of
    right answers; its interval resamples objects, each keeping its class and views."""
    from hbeo.evaluation.evaluate import class_mean_accuracy
    from hbeo.evaluation.intervals import class_mean, estimate
    q = {"object": ["a", "a", "b", "c", "d"], "class": ["x", "x", "x", "x", "y"], "pred": ["x", "x", "y", "x", "x"],
         "pose_deg": [10.0, 50.0, 20.0, 100.0, 5.0], "pose_sym_deg": [10.0, 5.0, 20.0, 40.0, 5.0],
         "iou": [0.5, 0.7, 0.2, 0.4, 0.1]}
    m = {"per_query": q}
    assert estimate(m, "class_mean") == pytest.approx((3 / 4 + 0) / 2)           # accuracy would be 3/5
    assert estimate(m, "class_mean") == pytest.approx(class_mean_accuracy(q["class"], q["pred"]))
    assert estimate(m, "accuracy") == pytest.approx(0.6)
    est, lo, hi = interval(m, "class_mean", n_boot=300)
    assert est == estimate(m, "class_mean") and 0 <= lo <= est <= hi <= 1 and lo < hi
    # modulo symmetry reads pose_sym_deg: 4 of 5 within 30 degrees, raw 3 of 5
    assert estimate(m, "within_30_sym") == pytest.approx(0.8) and estimate(m, "within_30") == pytest.approx(0.6)
    assert class_mean([1, 0, 1], ["p", "q", "q"]) == pytest.approx(0.75) and np.isnan(class_mean([], []))
    with pytest.raises(ValueError, match="same"):
        class_mean([1, 0], ["p"])


def test_class_statistics_and_several_statistics_on_the_same_resamples():
    """class_mean (the paper's Table I total) and lowest_class weigh every class the same; intervals()
    gives each statistic exactly what interval() gives it alone."""
    q = {"object": ["a", "a", "b", "c", "d"], "class": ["x", "x", "y", "y", "y"], "pred": ["x", "y", "y", "y", "x"],
         "pose_deg": [10.0, 50.0, 40.0, 100.0, 5.0], "pose_sym_deg": [10.0, 20.0, 40.0, 10.0, 5.0],
         "iou": [0.5, 0.7, 0.2, 0.4, 0.1]}
    m = {"per_query": q}
    assert interval(m, "accuracy")[0] == pytest.approx(3 / 5)
    assert interval(m, "class_mean")[0] == pytest.approx((1 / 2 + 2 / 3) / 2)     # x: 1 of 2, y: 2 of 3
    assert interval(m, "lowest_class")[0] == pytest.approx(1 / 2)
    assert interval(m, "within_30_sym")[0] == pytest.approx(4 / 5) and interval(m, "within_30")[0] == 2 / 5
    both = intervals(m, ["accuracy", "class_mean", "lowest_class"], n_boot=300)
    for what, got in both.items():
        assert got == interval(m, what, n_boot=300)
    _, lo, hi = both["lowest_class"]
    assert lo <= both["class_mean"][1] and hi <= both["class_mean"][2]           # the lowest class is below the mean
    one = {"per_query": {**q, "class": ["x"] * 5, "pred": ["x", "y", "x", "x", "y"]}}   # one class: class mean = accuracy
    assert interval(one, "class_mean", n_boot=300) == pytest.approx(interval(one, "accuracy", n_boot=300))
    with pytest.raises(ValueError, match="unknown statistic 'speed'"):
        intervals(m, ["accuracy", "speed"])


def test_resamples_are_the_drawn_groups_queries_in_the_order_drawn():
    """The vectorized resampler gives, index for index, the drawn groups' queries concatenated (the
    definition, written out here), for groups of uneven sizes, unsorted and not contiguous."""
    from hbeo.evaluation.intervals import _resamples
    rng = np.random.default_rng(5)
    groups = rng.choice(np.array(["d", "a", "c", "b", "e"]), 37, p=[0.4, 0.3, 0.15, 0.1, 0.05])
    labels, idx = np.unique(groups, return_inverse=True)
    members = [np.flatnonzero(idx == g) for g in range(len(labels))]
    draw = np.random.default_rng(9)
    for got in _resamples(groups, 20, seed=9):
        pick = draw.integers(0, len(members), len(members))
        np.testing.assert_array_equal(got, np.concatenate([members[g] for g in pick]))
    single = list(_resamples(np.zeros(4), 3, seed=0))
    assert all(np.array_equal(s, np.arange(4)) for s in single)
