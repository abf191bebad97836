"""Provenance of a run: the manifest (commit, tag, clean tree, notebooks at which commit, training from
scratch or resumed), fresh runs that retrain everything, the run's report, and a notebook run alone."""
import json
from pathlib import Path

import pytest

from hbeo.report import notebooks, provenance, reproduction_md as report
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]


def test_manifest_records_each_notebook_s_commit_and_training(tmp_path, monkeypatch):
    run = RunDir(tmp_path / "run").create()
    (run.path / "train_model").mkdir()
    (run.path / "train_model" / "provenance.json").write_text(json.dumps(
        {"model": "model.hbeo", "epochs": 3, "resumed_from_step": None, "n_params": 1234}))
    states = iter([{"git_commit": "a" * 40, "git_tag": "t1", "git_dirty": False},
                   {"git_commit": "b" * 40, "git_tag": None, "git_dirty": True}])
    monkeypatch.setattr(provenance, "git_state", lambda: next(states))
    m = provenance.write_manifest(run, "ci", "procedural", {"01_voxelize": 1.5}, fresh=True)
    assert m["notebooks"]["01_voxelize"]["commit"] == "a" * 40 and m["one_commit"] and m["git_tag"] == "t1"
    assert m["training"]["model.hbeo"]["resumed_from_step"] is None and m["code_version"]
    m = provenance.write_manifest(run, "ci", "procedural", {"02_subspace": 2.5})
    assert set(m["notebooks"]) == {"01_voxelize", "02_subspace"} and m["wall_time_total_s"] == 4.0
    assert not m["one_commit"]                          # a second commit, and a dirty tree
    text = report.reproduction_text(run, tmp_path / "R.md")
    assert "(notebooks at different commits)" in text and "uncommitted changes" in text
    assert "`model.hbeo`: 3 epochs, from scratch, 1,234 parameters" in text
    assert "## Deviations from the paper" in text and "HBEONet has 0.00 M parameters" in text


def test_the_manifest_hardware_is_the_training_machine_s(tmp_path, monkeypatch):
    """A later notebook run on another machine records its CPU with the notebook; the manifest's hardware stays
    the machine that trained the models until the training notebook runs again."""
    run = RunDir(tmp_path / "run").create()
    monkeypatch.setattr(provenance, "git_state", lambda: {"git_commit": "a" * 40, "git_tag": "t", "git_dirty": False})
    machines = iter([{"cpu": "A", "cpu_capability": "AVX2", "cores": 2}, {"cpu": "B", "cpu_capability": "AVX512"},
                     {"cpu": "C", "cpu_capability": "AVX512"}])
    monkeypatch.setattr(provenance, "hardware", lambda: next(machines))
    m = provenance.write_manifest(run, "ci", "procedural", {"04_train": 60.0}, fresh=True)
    assert m["hardware"]["cpu"] == "A"
    m = provenance.write_manifest(run, "ci", "procedural", {"08_your_depth_image": 1.0})
    assert m["hardware"]["cpu"] == "A" and m["notebooks"]["08_your_depth_image"]["cpu"] == "B"
    assert m["notebooks"]["04_train"]["cpu_capability"] == "AVX2"
    m = provenance.write_manifest(run, "ci", "procedural", {"04_train": 50.0})
    assert m["hardware"]["cpu"] == "C"


def test_git_state_ignores_the_run_s_own_outputs():
    state = provenance.git_state()
    assert len(state["git_commit"] or "") == 40 and state["git_dirty"] in (True, False)


def test_fresh_clears_what_a_run_trained_but_keeps_data(tmp_path):
    run = RunDir(tmp_path / "run").create()
    keep = [run.path / "grids_train.npz", run.path / "subspace.npz", run.path / "eval_so3_bins.json",
            run.path / "validation.csv"]
    # an earlier run's notebooks, tables, figures and report go too: a fresh run that stops midway leaves
    # nothing of the earlier one that looks like its own
    gone = [run.model, run.path / "model_opt_paper.hbeo", run.baseline("beo"), run.baseline("voxcnn"),
            run.evaluation("hbeo", "3dof"), run.evaluation("hbeo-verify", "3dof"), run.path / "05_table1.csv",
            run.path / "06_pose_completion.ipynb", run.path / "08_completion.ply", run.path / "REPRODUCTION.md"]
    for p in keep + gone:
        p.write_text("x")
    (run.path / "train_model").mkdir()
    (run.path / "train_model" / "checkpoint.pt").write_text("x")
    (run.path / "book").mkdir()
    removed = notebooks.clear_products(run)
    assert set(removed) == set(gone) | {run.path / "train_model", run.path / "book"}
    assert all(p.exists() for p in keep) and not any(p.exists() for p in gone)


def test_reports_go_to_the_run_and_only_the_reference_run_writes_paper(tmp_path, monkeypatch):
    written = []
    monkeypatch.setattr(report, "write_reproduction", lambda run, out=None: written.append(out) or out)
    run = RunDir(tmp_path / "run").create()
    report.write_reports(run, "cpu", "modelnet10-vox30")
    assert written == [run.path / "REPRODUCTION.md"]       # not the default place: paper/ untouched


@pytest.mark.slow
def test_notebook_06_runs_alone_in_an_empty_run_folder(tmp_path):
    """Notebook 06 on a fresh folder builds what it needs (grids, subspace, renders, the model, baselines)."""
    import papermill as pm
    out = tmp_path / "run"
    pm.execute_notebook(str(ROOT / "notebooks" / "06_pose_completion.ipynb"), str(tmp_path / "06.ipynb"),
                        cwd=str(ROOT / "notebooks"), progress_bar=False,
                        parameters={"profile": "ci", "dataset": "procedural", "out_dir": str(out)})
    run = RunDir(out)
    assert run.model.exists() and run.table("06_claims").exists() and run.figure("06_pose_error").exists()


@pytest.mark.parametrize("ename, says", [("DataError", "fix what it names, then go on with `python -m hbeo reproduce "
                                                      "--profile ci --dataset procedural --out "),
                                         ("KeyError", "is a bug in hbeo")])
def test_a_failing_notebook_is_named_with_its_cell_error_copy_and_what_to_do(tmp_path, monkeypatch, capsys, ename,
                                                                            says):
    """The run stops on the first failing notebook with one line naming it, the cell, the error and its executed
    copy (no papermill traceback from deep inside), and says whether the input or hbeo is at fault."""
    import papermill as pm
    from hbeo import cli

    def fail(nb, target, **kw):
        raise pm.PapermillExecutionError(4, 4, "evals = ...", ename, "grids_train.npz: no such grid set file", [])
    monkeypatch.setattr(pm, "execute_notebook", fail)
    out = tmp_path / "run"
    with pytest.raises(notebooks.NotebookFailed) as err:
        notebooks.run_notebooks("ci", "procedural", out, only=["07"])
    msg = str(err.value)
    assert msg.startswith(f"notebook 07_runtime stopped in cell 4: {ename}: grids_train.npz: no such grid set file")
    assert str(RunDir(out).notebook("07_runtime")) in msg and says in msg
    assert cli.main(["reproduce", "--profile", "ci", "--dataset", "procedural", "--out", str(out), "--only", "07"]) == 2
    assert capsys.readouterr().err.startswith(f"error: notebook 07_runtime stopped in cell 4: {ename}")


def test_the_resume_command_is_the_one_for_the_run_folder(tmp_path, monkeypatch):
    import functools
    monkeypatch.setenv("HBEO_RESULTS", str(tmp_path))
    resume_command = functools.partial(provenance.reproduce_command, resume=True)
    assert resume_command(tmp_path / "ci-procedural", "ci", "procedural", 0) == \
        "make reproduce PROFILE=ci DATASET=procedural RESUME=1"
    assert resume_command(tmp_path / "ci-procedural-seed2", "ci", "procedural", 2) == \
        "make reproduce PROFILE=ci DATASET=procedural SEED=2 RESUME=1"
    assert resume_command(tmp_path / "x", "ci", "procedural", 2) == \
        f"python -m hbeo reproduce --profile ci --dataset procedural --seed 2 --out {tmp_path / 'x'}"


def test_an_interrupted_notebook_is_set_aside_and_the_way_on_is_printed(tmp_path, monkeypatch, capsys):
    """Ctrl-C in a notebook: its executed copy so far is renamed ``NN_name.partial.ipynb`` (not left looking
    finished under its own name), the manifest does not list it, and the command that goes on is printed."""
    import json
    import papermill as pm

    def interrupted(nb, target, **kw):
        Path(target).write_text("{}")                  # papermill writes the copy as it goes
        raise KeyboardInterrupt
    monkeypatch.setattr(pm, "execute_notebook", interrupted)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        notebooks.run_notebooks("ci", "procedural", out, only=["04"])
    run = RunDir(out)
    assert not run.notebook("04_train").exists() and (out / "04_train.partial.ipynb").exists()
    assert not run.manifest.exists() or "04_train" not in json.loads(run.manifest.read_text()).get("notebooks", {})
    err = capsys.readouterr().err
    assert "interrupted in 04_train" in err and f"--out {out}`" in err


def test_a_second_run_into_a_folder_in_use_is_refused(tmp_path, monkeypatch, capsys):
    """Two reproduce runs into one folder (make reproduce in two terminals): the second stops before it touches
    anything (its --fresh would remove the first one's models under it) and names the first's pid; once the first
    is done the folder is free again."""
    import papermill as pm
    from hbeo import cli
    from hbeo.errors import DataError
    from hbeo.storage import exclusive_lock
    ran = []
    monkeypatch.setattr(pm, "execute_notebook", lambda nb, target, **kw: ran.append(nb))
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.hbeo").write_text("the first run's model")
    with exclusive_lock(out / notebooks.LOCK_NAME, "a first run"):
        with pytest.raises(DataError, match=r"already running here \(pid \d+, since"):
            notebooks.run_notebooks("ci", "procedural", out, only=["07"], fresh=True)
        assert cli.main(["reproduce", "--profile", "ci", "--dataset", "procedural", "--out", str(out), "--only",
                         "07", "--fresh"]) == 2
        assert "make reproduce) is already running here" in capsys.readouterr().err
    assert ran == [] and (out / "model.hbeo").exists()
    notebooks.run_notebooks("ci", "procedural", out, only=["07"], fresh=True)
    assert len(ran) == 1 and not (out / "model.hbeo").exists()
