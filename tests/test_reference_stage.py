"""maintainer/reference_stage.sh on toy git repositories: `save` stages only a run whose notebook 04 finished, and only
the run folder's new and changed files that git keeps (never the files --fresh deleted, never ignored ones such as
checkpoints); `finish` refuses a clone at another commit or with files of its own in the run folder. (The whole
save-then-finish path on a real run: the ci profile, checked by hand, see the script's commit.)"""
import hashlib
import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "maintainer" / "reference_stage.sh"
R = "results/cpu-toy"


def git(repo, *args):
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout


def stage(main, step, clone, seed=0, **env):
    return subprocess.run(["bash", str(main / "maintainer" / "reference_stage.sh"), step, str(clone)],
                          capture_output=True, text=True,
                          env={"PATH": "/usr/bin:/bin", "D": "toy", "SEED": str(seed), **env})


def new_run(run):
    """What notebooks 01-04 leave: the model rewritten, new tables, a training log, and files the stage never holds."""
    run.mkdir(parents=True, exist_ok=True)
    (run / "model.hbeo").write_text("new model")
    (run / "04_options.csv").write_text("new table")
    (run / "train_model").mkdir()
    (run / "train_model" / "train_log.csv").write_text("epoch\n1\n")
    (run / "train_model" / "checkpoint.pt").write_text("a checkpoint")
    (run / "model_opt_paper.hbeo").write_text("an option's model")
    (run / "render_train").mkdir()
    (run / "render_train" / "shard.npz").write_text("renderings")
    (run / "subspace.npz").write_text("basis")


@pytest.fixture
def repos(tmp_path):
    """A checkout holding the script and the project's .gitignore, and a clone whose run folder has a committed
    old reference."""
    main, clone = tmp_path / "main", tmp_path / "clone"
    (main / "maintainer").mkdir(parents=True)
    shutil.copy(SCRIPT, main / "maintainer")
    shutil.copy(ROOT / ".gitignore", main)
    git(main, "init", "-q")
    clone.mkdir()
    git(clone, "init", "-q")
    git(clone, "config", "user.email", "t@t")
    git(clone, "config", "user.name", "t")
    run = clone / R
    run.mkdir(parents=True)
    (clone / ".gitignore").write_text("results/*/train_*/checkpoint.pt\n")
    for name in ("model.hbeo", "old_ablation.json", "unchanged.csv"):
        (run / name).write_text("old " + name)
    git(clone, "add", ".")
    git(clone, "commit", "-qm", "old reference")
    (run / "old_ablation.json").unlink()     # --fresh removed an ablation's file
    new_run(run)
    return main, clone


def manifest(clone, notebooks, run=R, epochs=None):
    commit = git(clone, "rev-parse", "HEAD").strip()
    m = {"profile": "cpu", "dataset": "toy", "git_commit": commit, "git_tag": "t1", "git_dirty": False,
         "notebooks": {n: {"wall_s": 1.0, "finished_utc": "2026-12-01T00:00:00+00:00"} for n in notebooks}}
    if epochs is not None:
        m["profile_settings"] = {"epochs": epochs}
    (clone / run / "manifest.json").write_text(json.dumps(m))
    return commit


def test_save_refuses_a_run_whose_training_notebook_did_not_finish(repos):
    main, clone = repos
    manifest(clone, ["01_voxelize", "02_subspace", "03_render"])
    out = stage(main, "save", clone)
    assert out.returncode != 0 and "notebook 04 has not finished" in out.stderr
    assert not (main / f"{R}-stage").exists()


def test_save_stages_the_changed_files_git_keeps_and_nothing_else(repos):
    main, clone = repos
    commit = manifest(clone, ["01_voxelize", "02_subspace", "03_render", "04_train"])
    out = stage(main, "save", clone)
    assert out.returncode == 0, out.stderr
    st = main / f"{R}-stage"
    got = sorted(str(p.relative_to(st)) for p in st.rglob("*") if p.is_file())
    assert got == ["04_options.csv", "STAGE.md", "manifest.json", "model.hbeo", "train_model/train_log.csv"]
    assert (st / "model.hbeo").read_text() == "new model"
    assert commit in (st / "STAGE.md").read_text() and "| 04_train | 1.0 |" in (st / "STAGE.md").read_text()


def test_save_stages_a_seed_run_whose_folder_git_ignores(repos):
    main, clone = repos
    (clone / ".gitignore").write_text("results/*/\n!results/cpu-toy/\n")
    git(clone, "commit", "-qam", "seed runs ignored")
    new_run(clone / f"{R}-seed2")
    manifest(clone, ["01_voxelize", "02_subspace", "03_render", "04_train"], run=f"{R}-seed2")
    out = stage(main, "save", clone, seed=2)
    assert out.returncode == 0, out.stderr
    st = main / f"{R}-seed2-stage"
    got = sorted(str(p.relative_to(st)) for p in st.rglob("*") if p.is_file())
    assert got == ["04_options.csv", "STAGE.md", "manifest.json", "model.hbeo", "train_model/train_log.csv"]


def test_save_refuses_a_run_whose_notebook_05_started(repos):
    main, clone = repos
    manifest(clone, ["01_voxelize", "02_subspace", "03_render", "04_train"])
    (clone / R / "05_classification.ipynb").write_text("papermill's first write")
    out = stage(main, "save", clone)
    assert out.returncode != 0 and "notebooks after 04 started" in out.stderr


def test_save_with_checkpoint_stages_a_finished_training_of_a_stopped_notebook_04(repos):
    main, clone = repos
    run = clone / R
    manifest(clone, ["01_voxelize", "02_subspace", "03_render"], epochs=2)
    (run / "train_model" / "provenance.json").write_text("{}")
    (run / "train_model_opt_paper").mkdir()
    (run / "train_model_opt_paper" / "train_log.csv").write_text("epoch\n")    # an option's training, stopped
    env = {"CHECKPOINT": "1"}
    out = stage(main, "save", clone, **env)
    assert out.returncode != 0 and "training has not finished" in out.stderr      # the log stops at epoch 1 of 2
    (run / "train_model" / "train_log.csv").write_text("epoch\n1\n2\n")
    assert "CHECKPOINT=1" in stage(main, "save", clone).stderr                   # not without asking
    out = stage(main, "save", clone, **env)
    assert out.returncode == 0, out.stderr
    st = main / f"{R}-stage"
    got = sorted(str(p.relative_to(st)) for p in st.rglob("*") if p.is_file())
    assert got == ["STAGE.md", "manifest.json", "model.hbeo", "train_model/checkpoint.pt",
                   "train_model/provenance.json", "train_model/train_log.csv"]     # not 04_options.csv
    assert "notebooks 04-08 have not run" in (st / "STAGE.md").read_text()


def test_save_with_checkpoint_cut_stages_a_cut_training_and_the_subspace_hash(repos):
    main, clone = repos
    run = clone / R
    manifest(clone, ["01_voxelize", "02_subspace", "03_render"], epochs=60)
    (run / "train_model" / "train_log.csv").write_text("epoch,step\n1,10\n2,20\n")   # cut at epoch 2 of 60
    (run / "train_model" / "provenance.json").write_text("{}")
    out = stage(main, "save", clone, CHECKPOINT="1")
    assert out.returncode != 0 and "CHECKPOINT=cut" in out.stderr                  # 1 is for a finished training
    (run / "subspace.npz").unlink()
    out = stage(main, "save", clone, CHECKPOINT="cut")
    assert out.returncode != 0 and "no subspace.npz" in out.stderr
    (run / "subspace.npz").write_text("basis")
    out = stage(main, "save", clone, CHECKPOINT="cut")
    assert out.returncode == 0, out.stderr
    st = main / f"{R}-stage"
    got = sorted(str(p.relative_to(st)) for p in st.rglob("*") if p.is_file())
    assert got == ["STAGE.md", "manifest.json", "subspace.sha256", "train_model/checkpoint.pt",
                   "train_model/train_log.csv"]                      # no model.hbeo, nothing else of notebook 04
    assert (st / "subspace.sha256").read_text().split()[0] == hashlib.sha256(b"basis").hexdigest()
    text = (st / "STAGE.md").read_text()
    assert "after epoch 2 (step 20) of 60 epochs" in text and "notebooks 04-08 have not run" in text
    (run / "train_model" / "checkpoint.pt").unlink()
    out = stage(main, "save", clone, CHECKPOINT="cut")
    assert out.returncode != 0 and "no HBEONet checkpoint" in out.stderr


def test_finish_refuses_a_stage_without_a_model_or_a_cut_training(repos):
    main, clone = repos
    manifest(clone, ["01_voxelize", "02_subspace", "03_render", "04_train"])
    assert stage(main, "save", clone).returncode == 0
    (main / f"{R}-stage" / "model.hbeo").unlink()
    fresh = clone.parent / "fresh"
    git(clone.parent, "clone", "-q", str(clone), str(fresh))
    out = stage(main, "finish", fresh)
    assert out.returncode != 0 and "neither a model.hbeo nor a cut training" in out.stderr


def test_save_refuses_a_run_that_already_ran_its_last_notebooks(repos):
    main, clone = repos
    manifest(clone, ["01_voxelize", "02_subspace", "03_render", "04_train", "05_classification"])
    out = stage(main, "save", clone)
    assert out.returncode != 0 and "land the run instead" in out.stderr


def test_finish_refuses_a_clone_at_another_commit_or_with_files_in_the_run_folder(repos):
    main, clone = repos
    manifest(clone, ["01_voxelize", "02_subspace", "03_render", "04_train"])
    assert stage(main, "save", clone).returncode == 0
    fresh = clone.parent / "fresh"
    git(clone.parent, "clone", "-q", str(clone), str(fresh))
    (fresh / "x").write_text("a later commit")
    git(fresh, "add", "x")
    git(fresh, "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "later")
    out = stage(main, "finish", fresh)
    assert out.returncode != 0 and "is not at the run's commit" in out.stderr
    git(fresh, "checkout", "-q", "HEAD~1")
    (fresh / R / "stray.json").write_text("{}")
    out = stage(main, "finish", fresh)
    assert out.returncode != 0 and "not a clean clone" in out.stderr
    # a clean clone at the commit passes the checks and gets the manifest's tag back (tags do not survive a
    # session); the toy clone then stops at `make setup`, having no Makefile
    (fresh / R / "stray.json").unlink()
    assert "t1" not in git(fresh, "tag")
    out = stage(main, "finish", fresh)
    assert out.returncode != 0 and "reference_stage.sh:" not in out.stderr
    assert git(fresh, "tag").split() == ["t1"] and git(fresh, "rev-parse", "t1^{commit}") == git(fresh, "rev-parse", "HEAD")
