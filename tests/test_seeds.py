"""Training-seed spread (issue 29, item 4): ``reproduce --seed S`` trains every model of a run with seed S in
its own folder, on the same test images; ``report --seeds`` sets such runs side by side (hbeo.report.seeds)."""
import json

import pytest

from hbeo import cli, config
from hbeo.rundir import RunDir


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
