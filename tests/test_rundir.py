"""RunDir: the one place that knows a run folder's file names."""
import pytest

from hbeo.rundir import RunDir


def test_layout_names(tmp_path):
    run = RunDir(tmp_path)
    assert run.grids("train") == tmp_path / "grids_train.npz"
    assert run.subspace == tmp_path / "subspace.npz"
    assert run.renders("test") == tmp_path / "render_test"
    assert run.render_manifest("train") == tmp_path / "render_train" / "manifest.json"
    assert run.model == run.model_file() == tmp_path / "model.hbeo"
    assert run.model_file("model_6d") == run.model_file("model_6d.hbeo") == tmp_path / "model_6d.hbeo"
    assert run.checkpoint(run.model) == tmp_path / "train_model" / "checkpoint.pt"
    assert run.train_log("model_6d.hbeo") == tmp_path / "train_model_6d" / "train_log.csv"
    assert run.baseline("voxcnn") == tmp_path / "voxcnn.hbeo"
    assert run.partial_train() == tmp_path / "partial_train.npz"
    assert run.partial_train(3) == tmp_path / "partial_train_v3.npz"
    assert run.evaluation("beo", "1dof") == tmp_path / "eval_beo_1dof.json"
    assert run.figure("05_confusion") == tmp_path / "05_confusion.png"
    assert run.table("05_table1", "md") == tmp_path / "05_table1.md"
    assert RunDir.of(run) is run and RunDir.of(str(tmp_path)) == run


@pytest.mark.parametrize("call", [
    lambda r: r.grids("../x"), lambda r: r.renders("a/b"), lambda r: r.model_file(""),
    lambda r: r.evaluation("hbeo", "3dof/../../x"), lambda r: r.baseline("nope"), lambda r: r.table("t", "xlsx"),
])
def test_names_that_would_leave_the_folder_or_are_unknown_are_refused(tmp_path, call):
    with pytest.raises(ValueError):
        call(RunDir(tmp_path))


def test_status_counts_a_rendered_set_only_once_its_manifest_exists(tmp_path):
    run = RunDir(tmp_path)
    assert not any(run.status().values())
    run.renders("train").mkdir()
    (run.renders("train") / "shard_00000.npz").write_bytes(b"half")
    run.subspace.write_bytes(b"x")
    s = run.status()
    assert s["subspace"] and not s["render_train"]
    run.render_manifest("train").write_text("{}")
    assert run.status()["render_train"]


def test_for_run_creates_the_default_folder_under_hbeo_results(tmp_path, monkeypatch):
    monkeypatch.setenv("HBEO_RESULTS", str(tmp_path))
    run = RunDir.for_run("ci", "procedural")
    assert run.path == tmp_path / "ci-procedural" and run.path.is_dir()
    assert RunDir.for_run("ci", "x", tmp_path / "elsewhere").path == tmp_path / "elsewhere"
