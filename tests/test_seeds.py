"""Training-seed spread (issue 29, item 4): ``reproduce --seed S`` trains every model of a run with seed S in
its own folder, on the same test images; ``report --seeds`` sets such runs side by side (hbeo.report.seeds)."""
import json
import math

import pandas as pd
import pytest

from hbeo import cli, config
from hbeo.errors import DataError, HBEOError
from hbeo.evaluation.intervals import intervals
from hbeo.report import seeds as S
from hbeo.rundir import RunDir

OBJECTS = ["a1", "a2", "a3", "b1"]
CLASSES = ["a", "a", "a", "b"]
#: per training seed: the predicted classes, the raw and symmetric pose errors and the IoU of the 4 queries
ANSWERS = {0: (["a", "a", "a", "a"], [10, 40, 20, 100], [10, 20, 20, 100], 0.5),
           1: (["a", "a", "b", "b"], [10, 10, 10, 10], [10, 10, 10, 10], 0.6),
           2: (["a", "b", "b", "b"], [50, 50, 50, 10], [50, 20, 50, 10], 0.7)}


def _metrics(method, pose, seed, given_class=False, views=1, sampler="so3", objects=OBJECTS):
    pred, raw, sym, iou = ANSWERS[seed % 3]
    n = len(objects)
    return {"method": method, "pose": pose, "given_class": given_class, "verify": None, "dataset": "procedural",
            "split": "test", "views": views, "seed": 0, "sampler": sampler, "noise": False,
            "request": {"per_class": None, "dataset_fingerprint": "f00d", "views": views, "seed": 0},
            "per_query": {"object": objects, "view": [0] * n, "class": CLASSES[:n], "pred": pred[:n],
                          "pose_deg": raw[:n], "pose_sym_deg": sym[:n], "iou": [iou] * n, "edt": [1.0] * n,
                          "naive": [1.0] * n, "empty": [False] * n, "ms": [5.0] * n}}


def _run(folder, seed, profile="ci", dataset="procedural", evals=(("hbeo", "3dof"), ("beo", "known"),
                                                                   ("icp", "3dof")), **kw):
    run = RunDir(folder).create()
    run.manifest.write_text(json.dumps({"profile": profile, "dataset": dataset,
                                        "seeds": {"training": seed, "evaluation": 0, "rendering": 0}}))
    for method, pose in evals:
        run.evaluation(method, pose).write_text(json.dumps(_metrics(method, pose, seed, method == "icp", **kw)))
    return run


@pytest.fixture
def three(tmp_path):
    return [_run(tmp_path / name, seed).path for name, seed in (("r0", 0), ("r1", 1), ("r2", 2))]


def test_the_seed_table_gives_each_seed_its_interval_and_the_spread(three):
    t = S.seed_table(three[::-1], n_boot=200)             # any order: the runs are taken by seed
    row = t.set_index(["method", "statistic"])
    assert set(row.loc["hbeo"].index) == set(S.MEASURES)                         # every measure of HBEO
    assert set(row.loc["beo"].index) == {"class_mean", "accuracy", "lowest_class", "iou"}   # known pose
    assert set(row.loc["icp"].index) == {"within_30", "within_30_sym"}         # given the class, no completion
    cm = row.loc[("hbeo", "class_mean")]
    # class a: 3/3, 2/3, 1/3 right; class b: 0, 1, 1 -> class means 1/2, 5/6, 2/3
    assert [cm[f"seed {s}"] for s in (0, 1, 2)] == pytest.approx([1 / 2, 5 / 6, 2 / 3])
    assert cm["mean"] == pytest.approx(2 / 3) and cm["sd"] == pytest.approx(1 / 6)
    assert (cm["min"], cm["max"], cm["seeds"]) == (pytest.approx(1 / 2), pytest.approx(5 / 6), 3)
    acc = row.loc[("hbeo", "accuracy")]
    assert [acc[f"seed {s}"] for s in (0, 1, 2)] == pytest.approx([3 / 4, 3 / 4, 1 / 2])
    assert acc["mean"] == pytest.approx(2 / 3) and acc["sd"] == pytest.approx(math.sqrt(3) / 12)
    low = row.loc[("hbeo", "lowest_class")]
    assert [low[f"seed {s}"] for s in (0, 1, 2)] == pytest.approx([0, 2 / 3, 1 / 3])
    w30 = row.loc[("hbeo", "within_30")]
    assert [w30[f"seed {s}"] for s in (0, 1, 2)] == pytest.approx([1 / 2, 1, 1 / 4])
    assert w30["sd"] == pytest.approx(pd.Series([0.5, 1, 0.25]).std())            # pandas' std is n - 1
    sym = row.loc[("hbeo", "within_30_sym")]
    assert [sym[f"seed {s}"] for s in (0, 1, 2)] == pytest.approx([3 / 4, 1, 2 / 4])
    iou = row.loc[("hbeo", "iou")]
    assert (iou["mean"], iou["sd"], iou["min"], iou["max"]) == pytest.approx((0.6, 0.1, 0.5, 0.7))
    assert (iou["seed 1 low"], iou["seed 1 high"]) == pytest.approx((0.6, 0.6))   # no spread over objects
    for s in (0, 1, 2):                                   # each seed's interval is its own run's, over objects
        m = json.loads(RunDir(three[s]).evaluation("hbeo", "3dof").read_text())
        est, lo, hi = intervals(m, ["class_mean"], n_boot=200)["class_mean"]
        assert (cm[f"seed {s}"], cm[f"seed {s} low"], cm[f"seed {s} high"]) == (est, lo, hi) and lo <= est <= hi


def test_the_table_is_written_as_csv_and_markdown(three, tmp_path):
    csv, md, claims_csv, claims_md = S.write_seed_table(three, n_boot=50)
    assert (csv, md) == (RunDir(three[0]).table("seeds_table"), RunDir(three[0]).table("seeds_table", "md"))
    assert (claims_csv, claims_md) == (RunDir(three[0]).table("seeds_claims"),
                                       RunDir(three[0]).table("seeds_claims", "md"))
    assert len(pd.read_csv(csv)) == 6 + 4 + 2
    text = md.read_text()
    assert "| HBEO (3-DOF) | class mean accuracy (%) | 50.0 [" in text and "| 66.7 ± 16.7 | 50.0 – 83.3 |" in text
    assert "| mean IoU | 0.500 [0.500, 0.500] | 0.600 [0.600, 0.600] | 0.700 [0.700, 0.700] | 0.600 ± 0.100 |" in text
    assert "`r1` (seed 1)" in text
    out = tmp_path / "elsewhere"
    assert S.write_seed_table(three[:2], out, n_boot=50)[0] == out / "seeds_table.csv"


@pytest.mark.parametrize("change, problem", [
    (dict(profile="cpu"), "profile cpu, dataset procedural"),
    (dict(dataset="modelnet10-vox30"), "a seed table compares runs of one profile and dataset"),
    (dict(seed=1), "training seed 1 again"),
    (dict(views=3), "views 3 here, 1 there"),
    (dict(sampler="upright"), "sampler 'upright' here, 'so3' there"),
    (dict(objects=["a1", "a2", "a4", "b1"]), "other (object, view) pairs"),
])
def test_runs_that_are_not_paired_seeds_are_refused(three, tmp_path, change, problem):
    change = dict(change)
    seed = change.pop("seed", 3)
    odd = _run(tmp_path / "odd", seed, **change)
    with pytest.raises(DataError) as err:
        S.seed_table([three[0], three[1], odd.path], n_boot=10)
    assert problem in str(err.value) and str(odd.path) in str(err.value)       # names the file and the problem


def test_a_folder_without_a_manifest_or_common_evaluations_is_refused(three, tmp_path):
    (tmp_path / "bare").mkdir()
    with pytest.raises(DataError, match="manifest.json: missing"):
        S.seed_table([three[0], tmp_path / "bare"])
    other = _run(tmp_path / "other", 5, evals=(("voxcnn", "known"),))
    with pytest.raises(DataError, match="no eval_<method>_<pose>.json that every run"):
        S.seed_table([three[0], other.path])
    with pytest.raises(HBEOError, match="at least 2 run folders"):
        S.seed_table([three[0]])


def test_report_seeds_on_the_command_line(three, tmp_path, capsys):
    assert cli.main(["report", "--seeds", *map(str, three), "--out", str(tmp_path / "t")]) == 0
    assert (tmp_path / "t" / "seeds_table.md").is_file() and "seeds_table.csv" in capsys.readouterr().out
    assert cli.main(["report", "--seeds", str(three[0])]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: a seed table needs at least 2 run folders") and err.count("\n") == 1
    _run(tmp_path / "cpu", 7, profile="cpu")
    assert cli.main(["report", "--seeds", str(three[0]), str(tmp_path / "cpu")]) == 2
    err = capsys.readouterr().err
    assert "manifest.json: profile cpu" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as e:                  # one of --run, --seeds, --completion-decomposition
        cli.main(["report"])
    assert e.value.code == 2 and "one of the arguments --run --seeds --completion-decomposition is required" in \
        capsys.readouterr().err


def _claims_runs(tmp_path):
    """Three seeds' runs of HBEO, BEO with known pose and ICP whose answers make the paper's first claim (HBEO
    classifies better than BEO with known pose) hold for seed 0, fail for seed 1 and straddle zero for seed 2,
    and its pose claim against ICP (10 deg against 50) hold for every seed."""
    right = {0: ({"a1", "a2", "a3", "b1"}, set()), 1: (set(), {"a1", "a2", "a3", "b1"}), 2: ({"a1"}, {"a2"})}
    runs = []
    for seed, (hbeo_ok, beo_ok) in right.items():
        run = _run(tmp_path / f"c{seed}", seed, evals=())
        for (method, pose), ok, deg in ((("hbeo", "3dof"), hbeo_ok, 10.0), (("beo", "known"), beo_ok, 0.0),
                                        (("icp", "3dof"), set(), 50.0)):
            m = _metrics(method, pose, seed, method == "icp")
            q = m["per_query"]
            q["pred"] = [c if o in ok else ("b" if c == "a" else "a") for o, c in zip(q["object"], q["class"])]
            q["pose_deg"] = [deg] * len(q["object"])
            run.evaluation(method, pose).write_text(json.dumps(m))
        runs.append(run.path)
    return runs


def test_the_claims_are_judged_on_each_seed_s_own_run(tmp_path):
    runs = _claims_runs(tmp_path)
    t = S.seed_claims(runs[::-1]).set_index("claim (paper)")     # any order: the runs are taken by seed
    first = t.loc["HBEO (unknown 3-DOF pose) classifies better than BEO with known pose"]
    assert first["HBEO played by"] == "HBEO (3-DOF)"
    assert first["seed 0"] == "**holds**: -100.0 [-100.0, -100.0]"
    assert first["seed 1"] == "**fails**: 100.0 [100.0, 100.0]"
    assert first["seed 2"].startswith("**inconclusive**: 0.0 [-")
    assert first["verdicts"] == "holds 1 of 3, inconclusive 1 of 3, fails 1 of 3"
    icp = t.loc["HBEO's mean pose error is below the ICP baseline's (ICP given the class)"]
    assert [icp[f"seed {s}"] for s in (0, 1, 2)] == ["**holds**: -40.0 [-40.0, -40.0]"] * 3
    assert icp["verdicts"] == "holds 3 of 3"
    # only the claims whose two settings every run holds: none against the 3-D CNN or BEO 1-DOF or 3-DOF
    assert len(t) == 3 and not any("end-to-end" in c or "1-DOF" in c for c in t.index)
    one = _run(tmp_path / "odd", 3, objects=["a1", "a2", "a4", "b1"])     # refused as the seed table refuses
    with pytest.raises(DataError, match="other \\(object, view\\) pairs"):
        S.seed_claims([runs[0], one.path])


def test_reproduction_shows_the_seed_tables_only_while_they_describe_the_run(tmp_path):
    from hbeo.report import reproduction_md as report
    runs = _claims_runs(tmp_path)
    man = {"profile": "ci", "dataset": "procedural", "seeds": {"training": 0}}
    lines = "\n".join(S.section(runs[0], man))
    assert "has not been repeated with other training seeds" in lines and "SEED=S" in lines
    S.write_seed_table(runs, n_boot=20)
    assert S.stale(runs[0], 0) is None
    lines = "\n".join(S.section(runs[0], man))
    assert "| HBEO (3-DOF) | class mean accuracy (%) |" in lines and "holds 1 of 3, inconclusive 1 of 3" in lines
    assert lines in report.reproduction_text(runs[0], tmp_path / "R.md")
    assert S.stale(runs[0], 5) == "it has no column for this run's training seed 5"
    path = RunDir(runs[0]).evaluation("hbeo", "3dof")                 # the run evaluated again since: not shown
    m = json.loads(path.read_text())
    m["per_query"]["pred"][0] = "b"
    path.write_text(json.dumps(m))
    assert S.stale(runs[0], 0) == "its class_mean of hbeo (3dof) is not eval_hbeo_3dof.json's"
    lines = "\n".join(S.section(runs[0], man))
    assert "does not describe this run's evaluations" in lines and "| HBEO (3-DOF) |" not in lines
    path.unlink()
    assert S.stale(runs[0], 0) == "eval_hbeo_3dof.json is missing or unreadable"


def test_the_spread_is_given_only_while_the_tables_describe_the_run(tmp_path):
    runs = _claims_runs(tmp_path)
    man = {"profile": "ci", "dataset": "procedural", "seeds": {"training": 0}}
    assert S.spread(runs[0], man) == ([], [])                          # no seed tables yet
    S.write_seed_table(runs, n_boot=20)
    names, rows = S.spread(runs[0], man)
    assert names == ["0", "1", "2"]
    r = next(r for r in rows if r["label"] == "HBEO (3-DOF)")
    # HBEO's class means: seed 0 every answer right (100 %), seed 1 none (0 %), seed 2 a1 of class a (1/3, 0)
    cm = [1.0, 0.0, 1 / 6]
    mean, sd = sum(cm) / 3, math.sqrt(sum((x - sum(cm) / 3) ** 2 for x in cm) / 2)
    assert (r["mean"], r["sd"], r["min"], r["max"]) == (pytest.approx(mean), pytest.approx(sd), 0.0, 1.0)
    # the first claim differs between seeds; the pose claim against ICP and the completion claim hold on every seed
    assert (r["hold"], r["fail"], r["differ"], r["claims"]) == (2, 0, 1, 3)
    path = RunDir(runs[0]).evaluation("hbeo", "3dof")                  # evaluated again since: not shown
    m = json.loads(path.read_text())
    m["per_query"]["pred"][0] = "b"
    path.write_text(json.dumps(m))
    assert S.spread(runs[0], man) == ([], [])


# --------------------------------------------------------------------------- the seed of a run's trainings

def test_default_run_folder_per_training_seed(tmp_path, monkeypatch):
    monkeypatch.delenv("HBEO_RESULTS", raising=False)
    assert config.run_path("cpu", "modelnet10-vox30") == config.REPO_ROOT / "results" / "cpu-modelnet10-vox30"
    assert config.run_path("cpu", "modelnet10-vox30", training_seed=0) == config.run_path("cpu", "modelnet10-vox30")
    assert config.run_path("cpu", "modelnet10-vox30", training_seed=2).name == "cpu-modelnet10-vox30-seed2"
    assert config.run_path("cpu", "x", tmp_path / "mine", training_seed=2) == tmp_path / "mine"   # --out wins
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["reproduce", "--seed", "-1"])


@pytest.mark.parametrize("seed", [0, 3])
def test_reproduce_passes_the_training_seed_to_the_notebooks(seed, tmp_path, monkeypatch):
    import papermill
    calls = []
    monkeypatch.setenv("HBEO_RESULTS", str(tmp_path))
    monkeypatch.setattr(papermill, "execute_notebook", lambda nb, out, **kw: calls.append(kw["parameters"]))
    argv = ["reproduce", "--profile", "ci", "--dataset", "procedural", "--only", "04"]
    assert cli.main(argv + (["--seed", str(seed)] if seed else [])) == 0
    folder = tmp_path / ("ci-procedural" + (f"-seed{seed}" if seed else ""))
    expected = {"profile": "ci", "dataset": "procedural", "out_dir": str(folder)}
    assert calls == [{**expected, "training_seed": seed} if seed else expected]   # seed 0: the parameters as before
    assert json.loads(RunDir(folder).manifest.read_text())["seeds"] == {"training": seed, "evaluation": 0,
                                                                         "rendering": 0}


def test_reproduce_refuses_to_mix_two_training_seeds_in_one_folder(tmp_path, monkeypatch, capsys):
    import papermill
    monkeypatch.setattr(papermill, "execute_notebook", lambda nb, out, **kw: None)
    argv = ["reproduce", "--profile", "ci", "--dataset", "procedural", "--only", "04", "--out", str(tmp_path)]
    assert cli.main(argv + ["--seed", "1"]) == 0
    assert cli.main(argv) == 2                            # seed 0 into the seed-1 run: refused, one line
    err = capsys.readouterr().err
    assert "trained with training seed 1, not 0" in err and err.count("\n") == 1
    assert cli.main(argv + ["--fresh"]) == 0              # all trained again: the folder becomes seed 0's
    assert json.loads(RunDir(tmp_path).manifest.read_text())["seeds"]["training"] == 0


def test_reproduce_refuses_another_profile_or_dataset_in_a_run_folder(tmp_path, monkeypatch, capsys):
    """A run folder holds one run: another profile or dataset into it is refused in one line (its models,
    evaluations and tables would be the earlier run's, labelled as this one's), unless --fresh."""
    import papermill
    monkeypatch.setattr(papermill, "execute_notebook", lambda nb, out, **kw: None)
    out = ["--only", "05", "--out", str(tmp_path)]
    assert cli.main(["reproduce", "--profile", "ci", "--dataset", "procedural"] + out) == 0
    assert cli.main(["reproduce", "--profile", "quick", "--dataset", "procedural"] + out) == 2
    err = capsys.readouterr().err
    assert "holds a run of profile ci, not quick" in err and err.count("\n") == 1
    assert cli.main(["reproduce", "--profile", "quick", "--dataset", "procedural", "--fresh"] + out) == 0
    assert json.loads(RunDir(tmp_path).manifest.read_text())["profile"] == "quick"


def test_every_notebook_takes_the_training_seed_into_its_run():
    for nb in sorted((config.REPO_ROOT / "notebooks").glob("0*.ipynb")):
        cells = [c for c in json.loads(nb.read_text())["cells"] if c["cell_type"] == "code"]
        params = next("".join(c["source"]) for c in cells if "parameters" in c["metadata"].get("tags", []))
        assert "\ntraining_seed = 0 " in params, nb.name
        code = "".join("".join(c["source"]) for c in cells)
        assert code.count("Run.open(") == code.count("training_seed=training_seed)") == 1, nb.name


class _Stop(Exception):
    pass


class _Net:
    def n_params(self):
        return 1


class _Model:
    net = _Net()


@pytest.mark.parametrize("run_seed, option_seed, trained_with", [(0, None, 0), (5, None, 5), (5, 7, 7)])
def test_the_run_s_training_seed_reaches_hbeonet_s_training(run_seed, option_seed, trained_with, tmp_path,
                                                             monkeypatch):
    import hbeo.model.fit as fit
    from hbeo.model.fit import TrainOptions
    from hbeo.run import Run
    seen = []

    def fake_fit(run, prof, opts, **kw):
        seen.append(opts.seed)
        return _Model(), RunDir.of(run).model_file(opts.name)
    monkeypatch.setattr(fit, "fit_model", fake_fit)
    monkeypatch.setattr(Run, "renders", lambda self, *a, **k: None)             # no rendering
    run = Run.open("ci", "procedural", tmp_path / "run", training_seed=run_seed)
    assert run.training_seed == run_seed
    trained = run.train(TrainOptions(seed=option_seed), progress=False)
    assert seen == [trained_with]
    info = json.loads(run.dir.training_provenance(trained.path).read_text())
    assert info.get("seed", 0) == trained_with and ("seed" in info) == bool(trained_with)
    with pytest.raises(ValueError, match="training_seed"):
        Run.open("ci", "procedural", tmp_path / "run", training_seed=-1)


def test_the_run_s_training_seed_reaches_the_3d_cnn_and_not_its_validation_split(tmp_path, monkeypatch):
    import hbeo.baselines.voxcnn as V
    from hbeo.run import Run
    seen = {}

    class Data:
        classes, meta = ("a", "b"), {"views_per_object": 1}

        def split(self, val_fraction, seed):
            seen["split"] = seed
            return list(range(8)), [8, 9]

        def __len__(self):
            return 10

    def stop(task, train, val, folder, tc, **kw):
        seen["train"] = tc.seed
        raise _Stop                                       # before any training happens
    monkeypatch.setattr(V, "partial_training_set", lambda *a, **k: Data())
    monkeypatch.setattr(V, "train", stop)
    with pytest.raises(_Stop):
        Run.open("ci", "procedural", tmp_path / "run", training_seed=4).baseline("voxcnn", progress=False)
    assert seen == {"train": 4, "split": 0}
