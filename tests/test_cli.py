import subprocess
import sys


def run(*args):
    return subprocess.run([sys.executable, "-m", "hbeo", *args], capture_output=True, text=True)


def test_help_lists_subcommands():
    out = run("--help")
    assert out.returncode == 0
    for sub in ("data", "voxelize", "reproduce"):
        assert sub in out.stdout


def test_data_summary_vox30_prints_official_counts(vox30_file):
    out = run("data", "--dataset", "modelnet10-vox30", "--summary")
    assert out.returncode == 0, out.stderr
    lines = {ln.split()[0]: ln.split()[1:] for ln in out.stdout.splitlines()[2:]}
    assert lines["chair"][:2] == ["889", "100"] and lines["bathtub"][:2] == ["106", "50"]
    assert lines["total"][:3] == ["3991", "908", "4899"]
    assert "skipped 8 empty grids" in out.stderr


def test_bad_dataset_exits_2_with_one_line():
    out = run("data", "--dataset", "/no/such/folder")
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "unknown dataset" in out.stderr


def test_voxelize_writes_grids(tmp_path, sample_dir):
    out = run("voxelize", "--dataset", str(sample_dir), "--profile", "ci", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    from hbeo.data.gridset import GridSet
    gs = GridSet.load(tmp_path / "grids_train.npz")
    assert len(gs) == 5


def test_subspace_command_fits_and_reports(tmp_path):
    import json
    out = run("subspace", "--dataset", "procedural", "--profile", "ci", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "shared dimension:" in out.stdout and "naive" in out.stdout
    summary = json.loads((tmp_path / "subspace_summary.json").read_text())
    assert summary["dim"] == sum(summary["n_components"].values()) + 10
    assert set(summary["errors"]) == {"full", "partial"}
    assert 0 < summary["errors"]["full"]["all"]["naive"] <= 1
    from hbeo.subspace.basis import ObjectSubspace
    assert ObjectSubspace.load(tmp_path / "subspace.npz").dim_ == summary["dim"]
