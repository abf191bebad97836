"""hbeo.run.Run: the profile and dataset resolved once, stages that skip what the run folder already holds,
and one training path (the CLI's ``train`` and notebook 04) that always records its provenance."""
import json

import pytest

from hbeo import cli, config
from hbeo.config import Profile
from hbeo.data import datasets
from hbeo.model.fit import TrainOptions
from hbeo.model.inference import HBEO
from hbeo.model.trainingdata import ViewOptions
from hbeo.run import Run, Trained
from hbeo.rundir import DEFAULT_MODEL


def _count(monkeypatch):
    """Count resolutions of a profile from its name and loads of a dataset, wherever they happen."""
    calls = {"profile": 0, "dataset": 0}
    get_profile, get_dataset = config.get_profile, datasets.get_dataset

    def counted_profile(name, **kw):
        calls["profile"] += not isinstance(name, Profile)
        return get_profile(name, **kw)

    def counted_dataset(*a, **kw):
        calls["dataset"] += 1
        return get_dataset(*a, **kw)
    monkeypatch.setattr(config, "get_profile", counted_profile)
    monkeypatch.setattr(datasets, "get_dataset", counted_dataset)
    return calls


def test_the_train_command_resolves_the_profile_and_dataset_once_and_records_provenance(
        ci_render, ci_run, copy_run, tmp_path, monkeypatch):
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz",
                                                    "render_train"])      # no model or checkpoint of the ci run
    calls = _count(monkeypatch)
    assert cli.main(["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
                     "--max-steps", "1", "--rotation", "6d", "--fc", "12,10,8", "--quiet"]) == 0
    assert calls == {"profile": 1, "dataset": 1}
    info = json.loads((run.training(run.model) / "provenance.json").read_text())
    assert info["model"] == DEFAULT_MODEL and info["epochs"] == 1 and info["resumed_from_step"] is None
    assert info["recipe"]["rotation"] == "6d" and info["n_params"] > 0
    assert info["options"] == {"epochs": 1, "rotation": "6d", "max_steps": 1, "fc": [12, 10, 8]}
    assert HBEO.load(run.model).net.cfg.fc == (12, 10, 8)       # the widths asked for, not the profile's


def test_stages_skip_what_the_run_folder_holds(ci_render, ci_run, copy_run, tmp_path, monkeypatch):
    """Grids, subspace and rendered set are read, not built again; the model is trained only when missing."""
    import hbeo.run as run_module
    from hbeo.subspace.basis import ObjectSubspace
    folder = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz",
                                                       "render_train"])
    calls = _count(monkeypatch)
    run = Run.open("ci", "procedural", folder.path)
    assert calls == {"profile": 1, "dataset": 1} and run.profile.name == "ci" and run.path == folder.path

    def refuse(*a, **kw):
        raise AssertionError("built again")
    monkeypatch.setattr("hbeo.data.gridset.build_gridset", refuse)
    monkeypatch.setattr(ObjectSubspace, "fit", refuse)
    stamps = {p: p.stat().st_mtime_ns for p in folder.path.rglob("*") if p.is_file()}
    assert len(run.grids(progress=False)["train"]) == 60
    assert run.subspace(progress=False).dim_ == ObjectSubspace.load(folder.subspace).dim_
    m = run.renders("train", progress=False)
    assert m.n_images == ci_render.n_images and not m.images_per_s
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert calls == {"profile": 1, "dataset": 1}          # no stage resolved anything again
    trained = []
    monkeypatch.setattr(run_module.Run, "train",
                        lambda self, options=None, progress=True: trained.append(options) or Trained("m", None))
    assert run.model(progress=False) == "m" and trained == [None]     # missing: trained with the recipe


def test_train_options_fill_the_recipe_from_the_profile_and_report_what_changed():
    prof = config.get_profile("ci")
    assert TrainOptions().recipe(prof) == prof.recipe.fit_kwargs() and TrainOptions().changed() == {}
    opts = TrainOptions(rotation="bins", augment_roll=False, view=ViewOptions(True, 1.7), seed=3)
    assert opts.recipe(prof) == {**prof.recipe.fit_kwargs(), "rotation": "bins", "augment_roll": False}
    assert opts.changed() == {"rotation": "bins", "augment_roll": False, "seed": 3,
                              "view": {"recenter": True, "ref_distance": 1.7}}
    with pytest.raises(Exception):
        opts.seed = 4                                   # frozen: one set of options per training


def test_a_missing_baseline_is_fitted_in_a_folder_that_holds_only_the_committed_files(ci_grids, ci_run, copy_run,
                                                                                       tmp_path):
    """A committed run folder holds no grids or subspace (they are not committed): a later notebook asking for a
    baseline that is missing there makes what fitting it reads (here the training grids, then BEO's subspace)
    instead of failing on the absent grid file."""
    folder = copy_run(ci_run, tmp_path / "run", names=[])
    run = Run.open("ci", "procedural", folder.path)
    assert not folder.grids("train").exists() and not folder.subspace.exists()
    icp = run.baseline("icp", progress=False)
    assert folder.baseline("icp").is_file() and folder.grids("train").exists() and not folder.subspace.exists()
    assert icp is not None and (run.grids(progress=False)["train"].grids == ci_grids["train"].grids).all()
    run.baseline("beo", progress=False)
    assert folder.subspace.exists() and folder.baseline("beo").is_file()
    with pytest.raises(ValueError, match="unknown method"):
        run.baseline("nope")


def test_a_missing_subspace_is_the_one_the_run_s_model_was_trained_on(ci_model, ci_run, copy_run, tmp_path,
                                                                      monkeypatch):
    """A committed run keeps its model, not its subspace: the run's subspace is then the model file's (the one
    HBEO was trained on, byte for byte), not a new fit, which on another CPU kind differs in its last bits and
    changes BEO with it; a model whose subspace was fitted on other grids is not taken for the run's."""
    import zipfile
    from hbeo.model.modelfile import read_subspace
    from hbeo.subspace import basis
    folder = copy_run(ci_run, tmp_path / "run", names=[ci_model.name])
    run = Run.open("ci", "procedural", folder.path)
    monkeypatch.setattr(Run, "fit_subspace", lambda self, progress=True: pytest.fail("the subspace fitted again"))
    sub = run.subspace(progress=False)
    assert folder.subspace.read_bytes() == zipfile.ZipFile(folder.model).read("subspace.npz")
    assert sub.fingerprint_ == read_subspace(ci_model).fingerprint_ and run.baseline("beo", progress=False)
    other = copy_run(ci_run, tmp_path / "other", names=[ci_model.name])
    monkeypatch.setattr(basis, "data_fingerprint", lambda grids, labels: "other grids")
    fitted = []
    monkeypatch.setattr(Run, "fit_subspace", lambda self, progress=True: fitted.append(self) or sub)
    assert Run.open("ci", "procedural", other.path).subspace(progress=False) is sub and len(fitted) == 1
    assert not other.subspace.exists()


def test_read_subspace_takes_an_hbeo_file_s_subspace_and_refuses_other_files(ci_model, tmp_path):
    from hbeo.errors import DataError
    from hbeo.model.modelfile import read_subspace
    sub = read_subspace(ci_model)
    assert sub.basis_.shape[0] == HBEO.load(ci_model).subspace.basis_.shape[0]
    bad = tmp_path / "model.hbeo"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DataError, match="model.hbeo.*not a readable hbeo model file"):
        read_subspace(bad)
    import zipfile                                       # the members read_model wants, exactly
    with zipfile.ZipFile(ci_model) as z, zipfile.ZipFile(bad, "w") as out:
        for name in z.namelist():
            if name != "subspace.npz":
                out.writestr(z.getinfo(name), z.read(name))
    with pytest.raises(DataError, match="must hold exactly .*subspace.npz; it holds"):
        read_subspace(bad)


# ------------------------------------------------------------------ papermill parameters

PARAMS = 'profile = "ci"\ndataset = "procedural"\nepochs = None  # the profile\'s\nwidth, height = 80, 60\n'


def test_a_misspelt_papermill_parameter_is_refused_with_the_near_name():
    from hbeo.run import check_notebook_parameters
    history = ["", "%matplotlib inline", PARAMS, '# Parameters\nprofile = "cpu"\nepcohs = 3\n']
    with pytest.raises(ValueError, match=r"'epcohs' \(did you mean 'epochs'\?\).*dataset, epochs, height, profile, width\)"):
        check_notebook_parameters(history)
    check_notebook_parameters(history[:3] + ['# Parameters\nprofile = "cpu"\nepochs = 3\nheight = 90\n'])   # known
    check_notebook_parameters(history[:3])                          # not run by papermill: nothing to check
    check_notebook_parameters(["", '# Parameters\nx = 1\n'])         # nothing run before it: not judged
    check_notebook_parameters(history[:3] + ['# Parameters\nepochs = 3\n', "zz = 1",       # the last injection
                                             'from hbeo.run import Run'])


@pytest.mark.slow
def test_papermill_stops_a_notebook_run_with_a_misspelt_parameter(tmp_path):
    """Through papermill and a kernel, as a batch run meets it (the kernel's own cell history)."""
    import nbformat
    import papermill as pm
    nb = nbformat.v4.new_notebook(metadata={"kernelspec": {"name": "python3", "language": "python",
                                                          "display_name": "Python 3"}})
    params = nbformat.v4.new_code_cell(PARAMS, metadata={"tags": ["parameters"]})
    nb.cells = [params, nbformat.v4.new_code_cell("from hbeo.run import check_notebook_parameters\n"
                                                  "check_notebook_parameters()\nprint('trained', epochs)")]
    nbformat.write(nb, tmp_path / "in.ipynb")
    pm.execute_notebook(tmp_path / "in.ipynb", tmp_path / "ok.ipynb", parameters={"epochs": 3}, progress_bar=False)
    assert "trained 3" in (tmp_path / "ok.ipynb").read_text()
    with pytest.raises(pm.PapermillExecutionError, match="did you mean 'epochs'"):
        pm.execute_notebook(tmp_path / "in.ipynb", tmp_path / "bad.ipynb", parameters={"epcohs": 3},
                            progress_bar=False)
