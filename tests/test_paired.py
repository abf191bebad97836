"""Paired bootstrap over objects, the paper's claims judged by intervals, and the paired query views."""
import numpy as np
import pytest

from hbeo.evaluation import paired

CLS = ["chair", "desk", "sofa"]


def fake(method, pose, correct, pose_deg, edt, ms=5.0, objects=None, views=3, given=False):
    """Metrics with per-query columns over ``objects`` (default 10 per class) x ``views``."""
    objects = objects or [(c, f"{c}_{i:04d}") for c in CLS for i in range(10)]
    n = len(objects) * views
    q = {"object": [], "view": [], "class": [], "pred": [], "pose_deg": [], "pose_sym_deg": [], "edt": [],
         "naive": [], "iou": [], "empty": [], "ms": []}
    for k in range(n):
        c, o = objects[k // views]
        ok = correct(k) if callable(correct) else correct
        for col, v in (("object", o), ("view", k % views), ("class", c), ("pred", c if ok else "other"),
                       ("pose_deg", pose_deg(k) if callable(pose_deg) else pose_deg), ("pose_sym_deg", 0.0),
                       ("edt", edt(k) if callable(edt) else edt), ("naive", 0.0), ("iou", 0.5), ("empty", False),
                       ("ms", ms)):
            q[col].append(v)
    return {"method": method, "pose": pose, "given_class": given, "verify": None, "per_query": q}


def test_estimates_match_the_data_and_intervals_cover_them():
    rng = np.random.default_rng(0)
    errs = rng.exponential(30, 90)
    m = fake("hbeo", "3dof", lambda k: k % 4 != 0, lambda k: errs[k], 100.0)
    boot = paired.PairedBootstrap([m], n_boot=500)
    acc = boot.estimate(("hbeo", "3dof"), "accuracy")
    assert acc.value == pytest.approx(np.mean([k % 4 != 0 for k in range(90)]))
    assert acc.low < acc.value < acc.high and acc.n_objects == 30 and acc.n_queries == 90
    med = boot.estimate(("hbeo", "3dof"), "pose_median")
    assert med.value == pytest.approx(np.median(errs)) and med.low <= med.value <= med.high
    assert boot.estimate(("hbeo", "3dof"), "within_30").value == pytest.approx(np.mean(errs < 30))


def test_class_accuracy_is_the_mean_of_the_per_class_accuracies():
    # chair: all right (30 queries), desk: all wrong, sofa: half of its objects right
    objects = [(c, f"{c}_{i}") for c in CLS for i in range(10)]
    m = fake("hbeo", "3dof", lambda k: k < 30 or (60 <= k < 75), 0.0, 0.0, objects=objects)
    boot = paired.PairedBootstrap([m], n_boot=200)
    assert boot.estimate(("hbeo", "3dof"), "class_accuracy").value == pytest.approx((1 + 0 + 0.5) / 3)


def test_resamples_keep_class_counts_and_whole_objects():
    m = fake("hbeo", "3dof", True, 0.0, 0.0)
    boot = paired.PairedBootstrap([m], n_boot=50)
    assert boot.weights.shape == (50, 30)
    assert np.all(boot.weights.reshape(50, 3, 10).sum(axis=2) == 10)      # 10 objects per class, every resample


def test_a_constant_gap_gives_a_degenerate_paired_interval_and_unpaired_objects_are_left_out():
    # a: 10 objects per class x 3 views, errors that vary from query to query; b: view 0 of the first 4
    # objects of each class only, each with a's error on the same (object, view) plus 20
    a = fake("hbeo", "3dof", True, lambda k: 10.0 + k, 0.0)
    a_k = [3 * (10 * (j // 4) + j % 4) for j in range(12)]          # a's query index of b's j-th query
    b = fake("icp", "3dof", True, lambda j: 30.0 + a_k[j], 0.0, views=1,
             objects=[(c, f"{c}_{i:04d}") for c in CLS for i in range(4)])   # a subset: view 0 of 4 per class
    boot = paired.PairedBootstrap([a, b], n_boot=300)
    d = boot.contrast(("hbeo", "3dof"), ("icp", "3dof"), "pose_mean")
    assert d.n_queries == 12 and d.n_objects == 12                  # a's other 78 queries are left out
    hbeo_on_pairs = [10.0 + k for k in range(90) if k % 3 == 0 and (k // 3) % 10 < 4]
    assert hbeo_on_pairs == [10.0 + k for k in a_k]
    # on the shared pairs, HBEO's error is ICP's minus 20 everywhere -> the same in every resample
    assert d.value == pytest.approx(-20.0)
    assert d.low == pytest.approx(-20.0) and d.high == pytest.approx(-20.0)
    # ... although each method's own statistic does vary over the resamples
    own = boot.estimate(("hbeo", "3dof"), "pose_mean", on=[("icp", "3dof")])
    assert own.value == pytest.approx(np.mean(hbeo_on_pairs)) and own.high - own.low > 10
    assert own.n_queries == 12
    # unpaired, HBEO's mean is over all of its 90 queries
    assert boot.estimate(("hbeo", "3dof"), "pose_mean").value == pytest.approx(10.0 + np.mean(range(90)))


def test_verdicts_follow_the_interval():
    E = paired.Estimate
    assert paired.verdict(E(-5, -8, -1, 10, 10)) == "holds"
    assert paired.verdict(E(5, 1, 8, 10, 10)) == "fails"
    assert paired.verdict(E(1, -2, 3, 10, 10)) == "inconclusive"


def test_claims_judged_on_paired_statistics():
    hbeo = fake("hbeo", "3dof", lambda k: k % 10 != 0, 10.0, 100.0, ms=4.0)            # 90 % right
    beo_known = fake("beo", "known", lambda k: k % 2 == 0, 0.0, 100.0)                  # 50 % right, same EDT
    beo_3dof = fake("beo", "3dof", True, 50.0, 200.0, ms=10_000.0, views=1, given=True)
    vox = fake("voxcnn", "known", lambda k: k % 10 != 0, 0.0, 50.0)                    # as accurate as HBEO
    v = paired.judge(paired.PairedBootstrap([hbeo, beo_known, beo_3dof, vox], n_boot=300)).set_index("claim (paper)")
    verdict = v["verdict"]
    assert verdict["HBEO (unknown 3-DOF pose) classifies better than BEO with known pose"] == "holds"
    assert verdict["HBEO's mean 3-DOF pose error is less than half of BEO's (BEO given the class)"] == "holds"
    assert verdict["HBEO's completion is better than the end-to-end network's with known pose (mean EDT e')"] == "fails"
    assert verdict[[c for c in v.index if c.startswith("HBEO classifies better than the end-to-end")][0]] == "fails"
    assert verdict[[c for c in v.index if "competitive" in c][0]] == "holds"          # 100 <= 1.25 x 100
    assert verdict[[c for c in v.index if "faster" in c][0]] == "holds"               # 4 ms < 10 s / 100
    assert "ICP" not in " ".join(v.index)                                              # no ICP evaluation given
    assert v.loc["HBEO's mean 3-DOF pose error is less than half of BEO's (BEO given the class)", "pairs"] == 30



def test_a_claim_about_time_from_two_machines_is_not_comparable():
    xeon = {"cpu": "Intel Xeon", "cores": 2, "gpu": None, "torch_threads": 2}
    epyc = dict(xeon, cpu="AMD EPYC")

    def speed(h_hbeo, h_beo):
        hbeo = fake("hbeo", "3dof", True, 10.0, 100.0, ms=4.0)
        beo = fake("beo", "3dof", True, 50.0, 200.0, ms=10_000.0, views=1, given=True)
        for m, hw in ((hbeo, h_hbeo), (beo, h_beo)):
            if hw is not None:
                m["hardware"] = hw
        v = paired.judge(paired.PairedBootstrap([hbeo, beo], n_boot=100)).set_index("claim (paper)")["verdict"]
        return v[[c for c in v.index if "faster" in c][0]], v[[c for c in v.index if "pose error" in c][0]]

    assert speed(xeon, epyc) == (paired.NOT_COMPARABLE, "holds")      # only the claim about time is withheld
    assert speed(xeon, dict(xeon)) == ("holds", "holds")                # one machine: judged
    assert speed(xeon, None) == ("holds", "holds")                      # an older file: judged as before
    assert speed(xeon, dict(xeon, torch_threads=1)) == (paired.NOT_COMPARABLE, "holds")

def test_old_files_without_object_ids_are_refused():
    m = fake("hbeo", "3dof", True, 0.0, 0.0)
    del m["per_query"]["object"]
    with pytest.raises(ValueError, match="object ids"):
        paired.PairedBootstrap([m])


def test_query_views_are_paired_across_view_counts_and_object_lists():
    from hbeo.data.datasets import ObjectRecord
    from hbeo.render.views import object_key, query_rng
    a = ObjectRecord(cls="chair", split="test", id="chair_0890")
    b = ObjectRecord(cls="chair", split="test", id="chair_0891")
    assert object_key(a) == object_key(ObjectRecord(cls="chair", split="test", id="chair_0890"))
    assert object_key(a) != object_key(b)
    x = query_rng(0, "test", a, 1).random(4)
    assert np.array_equal(x, query_rng(0, "test", a, 1).random(4))
    assert not np.array_equal(x, query_rng(0, "test", a, 0).random(4))
    assert not np.array_equal(x, query_rng(0, "val", a, 1).random(4))


def test_two_models_of_the_same_method_are_contrasted_on_their_shared_queries(tmp_path):
    import json
    import subprocess
    import sys
    a = fake("hbeo", "3dof", True, 10.0, 0.0)                      # two HBEO models: the same method key
    b = fake("hbeo", "3dof", lambda k: k % 2 == 0, 40.0, 0.0)
    est = paired.contrast_pair(a, b, n_boot=300)
    assert list(est) == list(paired.CONTRASTS)
    assert est["class_accuracy"].value == pytest.approx(1 - 0.5) and est["accuracy"].value == pytest.approx(0.5)
    assert est["class_accuracy"].low <= 0.5 <= est["class_accuracy"].high < 1
    assert est["within_30"].value == pytest.approx(1.0) and est["pose_median"].value == pytest.approx(-30.0)
    assert est["accuracy"].n_queries == 90 and est["accuracy"].n_objects == 30
    other = fake("hbeo", "3dof", True, 10.0, 0.0, objects=[("chair", "elsewhere_0001")])
    with pytest.raises(ValueError, match="no queries"):
        paired.contrast_pair(a, other)
    for name, m in (("a.json", a), ("b.json", b)):
        (tmp_path / name).write_text(json.dumps(m))
    script = [sys.executable, "scripts/paired_contrast.py", str(tmp_path / "a.json"), str(tmp_path / "b.json"),
              "--out", str(tmp_path / "d.json")]
    done = subprocess.run(script, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "class_accuracy: 50.0 [" in done.stdout
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["contrasts"]["accuracy"]["value"] == pytest.approx(0.5) and "paired_contrast.py" in doc["made_by"]
    (tmp_path / "bad.json").write_text("{")
    done = subprocess.run(script[:2] + [str(tmp_path / "bad.json")] + script[3:], capture_output=True, text=True)
    assert done.returncode == 2 and "bad.json: not a readable metrics file" in done.stderr
    (tmp_path / "list.json").write_text("[1, 2]")             # JSON, but not what an evaluation writes
    done = subprocess.run(script[:2] + [str(tmp_path / "list.json")] + script[3:], capture_output=True, text=True)
    assert done.returncode == 2 and "list.json: not a metrics file" in done.stderr


def test_seed_means_are_contrasted_with_intervals_over_seeds_and_objects(tmp_path):
    import json
    import subprocess
    import sys
    a = [fake("hbeo", "3dof", lambda k, r=r: k % r != 0, 10.0, 0.0) for r in (2, 3, 4)]   # 45, 60, 67 of 90 right
    b = [fake("hbeo", "3dof", lambda k, r=r: k % r == 0, 40.0, 0.0) for r in (2, 3)]      # 1/2, 1/3 right
    est = paired.contrast_seeds(a, b, n_boot=300)
    acc = est["accuracy"]
    want = (45 + 60 + 67) / 90 / 3 - (45 + 30) / 90 / 2
    assert acc.a == pytest.approx([45 / 90, 60 / 90, 67 / 90]) and acc.b == pytest.approx([45 / 90, 30 / 90])
    assert acc.value == pytest.approx(want)
    assert acc.seeds_low < acc.value < acc.seeds_high and acc.objects_low <= acc.value <= acc.objects_high
    # Welch's interval from the per-seed figures themselves (scipy's t), not from the objects
    from scipy import stats
    va, vb = np.var(acc.a, ddof=1) / 3, np.var(acc.b, ddof=1) / 2
    df = (va + vb) ** 2 / (va ** 2 / 2 + vb ** 2 / 1)
    half = stats.t.ppf(0.975, df) * np.sqrt(va + vb)
    assert (acc.seeds_low, acc.seeds_high) == pytest.approx((acc.value - half, acc.value + half))
    assert est["within_30"].value == pytest.approx(1.0) and est["within_30"].seeds_low == pytest.approx(1.0)
    assert acc.n_queries == 90 and acc.n_objects == 30
    # only the queries every file answered count
    fewer = fake("hbeo", "3dof", True, 10.0, 0.0, objects=[(c, f"{c}_{i:04d}") for c in CLS for i in range(5)])
    est = paired.contrast_seeds(a[:2] + [fewer], b, n_boot=50)
    assert est["accuracy"].n_queries == 45 and est["accuracy"].n_objects == 15
    with pytest.raises(ValueError, match="at least two"):
        paired.contrast_seeds(a, b[:1])
    elsewhere = fake("hbeo", "3dof", True, 10.0, 0.0, objects=[("chair", "elsewhere_0001")])
    with pytest.raises(ValueError, match="share no"):
        paired.contrast_seeds(a, [b[0], elsewhere])
    files = []
    for i, m in enumerate(a + b):
        files.append(tmp_path / f"m{i}.json")
        files[-1].write_text(json.dumps(m))
    script = [sys.executable, "scripts/seed_contrast.py", "--a", *map(str, files[:3]), "--b", *map(str, files[3:]),
              "--out", str(tmp_path / "d.json")]
    done = subprocess.run(script, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "\naccuracy: a 50.0, 66.7, 74.4; b 50.0, 33.3; a - b 22.0 % [seeds " in done.stdout
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["contrasts"]["accuracy"]["value"] == pytest.approx(want) and doc["a"] == list(map(str, files[:3]))
    (tmp_path / "bad.json").write_text("{")
    done = subprocess.run(script[:3] + [str(tmp_path / "bad.json")] + script[4:], capture_output=True, text=True)
    assert done.returncode == 2 and "bad.json: not a readable metrics file" in done.stderr
    done = subprocess.run(script[:4] + ["--b", str(files[3])] + script[-2:], capture_output=True, text=True)
    assert done.returncode == 2 and "at least two" in done.stderr


def test_edt_nonempty_mean_leaves_out_the_empty_completions():
    """Queries whose completion is empty (``empty`` column, or for older files an IoU and naive error of 0)
    count in ``edt_mean`` but not in ``edt_nonempty_mean``."""
    m = fake("hbeo", "3dof", True, 0.0, lambda k: 10.0 + k % 5)
    q = m["per_query"]
    gone = [k for k in range(90) if k % 7 == 0]                     # 13 empty completions, far off
    for k in gone:
        q["empty"][k], q["edt"][k], q["iou"][k] = True, 5000.0, 0.0
    edt = np.array(q["edt"])
    kept = np.array([k not in gone for k in range(90)])
    boot = paired.PairedBootstrap([m], n_boot=200)
    key = ("hbeo", "3dof")
    e = boot.estimate(key, "edt_nonempty_mean")
    assert e.value == pytest.approx(edt[kept].mean()) and e.n_queries == 90 - len(gone)
    assert e.high < 100                                             # no resample sees an empty one
    assert boot.estimate(key, "edt_mean").value == pytest.approx(edt.mean())
    # a file without the empty column: emptiness read from IoU 0 with naive 0
    del q["empty"]
    old = paired.PairedBootstrap([m], n_boot=50).estimate(key, "edt_nonempty_mean")
    assert old.value == pytest.approx(edt[kept].mean()) and old.n_queries == 90 - len(gone)


def test_the_bootstrap_median_is_np_median_of_each_resample():
    """A resample's median (integer weights: how often each query was drawn) is ``np.median`` of the resample
    written out, the point value's own rule: for an even count the mean of the two middle values, not the lower
    one (the interval and its point value had used two rules)."""
    from hbeo.evaluation.paired import _weighted_median
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 8):
        v = rng.normal(size=n).round(1)                        # rounding makes ties
        w = rng.integers(0, 3, size=(40, n)).astype(float)
        w[w.sum(axis=1) == 0, 0] = 1
        got = _weighted_median(v, w)
        want = [np.median(np.repeat(v, row.astype(int))) for row in w]
        np.testing.assert_allclose(got, want)
    assert _weighted_median(np.array([1.0, 4.0]), np.ones((1, 2)))[0] == 2.5


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")   # a class of the subset undrawn
def test_resample_weights_and_statistics_are_their_definitions_written_out():
    """The resamples are the seeded draws within each class counted per object (``np.add.at`` over the draws,
    written out here), and a resample's mean, class mean and median are those of the queries it holds, each query
    repeated as often as its object was drawn, over a method that answered a subset of the objects with uneven
    views (the per-object sums the implementation uses give the same numbers)."""
    rng = np.random.default_rng(4)
    objects = [(c, f"{c}_{i:04d}") for c in CLS for i in range(10)]             # fake's own
    full = fake("hbeo", "3dof", lambda k: rng.random() < 0.6, lambda k: rng.exponential(20), lambda k: rng.random())
    keep = [k for k in range(90) if k % 7]                   # objects with 1, 2 or 3 views
    full["per_query"] = {col: [v[k] for k in keep] for col, v in full["per_query"].items()}
    boot = paired.PairedBootstrap([full, fake("beo", "known", True, 1.0, 1.0, objects=objects[::2], views=1)],
                                  n_boot=30, seed=7)
    want = np.zeros_like(boot.weights)
    draw = np.random.default_rng(7)
    for c in CLS:                                             # the objects sorted by class, then key
        members = np.arange(len(CLS) * 10)[CLS.index(c) * 10:(CLS.index(c) + 1) * 10]
        for b, row in enumerate(draw.integers(0, 10, (30, 10))):
            np.add.at(want[b], members[row], 1.0)
    np.testing.assert_array_equal(boot.weights, want)
    for key, on in ((("hbeo", "3dof"), None), (("hbeo", "3dof"), [("beo", "known")])):
        q = boot._table(key, on)
        reps = boot.weights[:, q["key"].map(boot.index).to_numpy()].astype(int)
        for what, rule in (("accuracy", lambda x, c: x.mean()), ("pose_mean", lambda x, c: x.mean()),
                           ("pose_median", lambda x, c: np.median(x)),
                           ("class_accuracy", lambda x, c: np.mean([x[c == k].mean() if (c == k).any() else np.nan
                                                                     for k in CLS]))):       # a class undrawn: NaN
            v, cls = paired.STATISTICS[what][0](q), q["class"].to_numpy()
            _, got, _ = boot.draws(key, what, on)
            expect = [rule(np.repeat(v, r), np.repeat(cls, r)) for r in reps]
            np.testing.assert_allclose(got, expect, rtol=1e-12, err_msg=f"{key} {what} on {on}")
