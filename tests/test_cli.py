import json
import subprocess
import sys

import pytest


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
    from hbeo.rundir import RunDir
    gs = GridSet.load(RunDir(tmp_path).grids("train"))
    assert len(gs) == 5
    assert RunDir(tmp_path).status()["grids_test"]


@pytest.mark.slow
def test_subspace_command_fits_and_reports(tmp_path):
    import json
    out = run("subspace", "--dataset", "procedural", "--profile", "ci", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "shared dimension:" in out.stdout and "naive" in out.stdout
    from hbeo.rundir import RunDir
    rd = RunDir(tmp_path)
    summary = json.loads(rd.subspace_summary.read_text())
    assert rd.table("subspace_completion_partial").is_file()
    assert summary["dim"] == sum(summary["n_components"].values()) + 10
    assert set(summary["errors"]) == {"full", "partial"}
    assert 0 < summary["errors"]["full"]["all"]["naive"] <= 1
    from hbeo.subspace.basis import ObjectSubspace
    assert ObjectSubspace.load(rd.subspace).dim_ == summary["dim"]


def finished_run(folder):
    """The least a finished run holds (issue 30: report refuses anything less): a manifest recording a
    profile and one executed notebook, and that notebook; the report marks every table as missing."""
    (folder / "manifest.json").write_text(json.dumps({"profile": "ci", "dataset": "procedural",
                                                       "notebooks": {"01_voxelize": {"wall_s": 1.0}}}))
    (folder / "01_voxelize.ipynb").write_text("{}")
    return folder


def test_report_writes_the_reproduction_from_a_run(tmp_path):
    finished_run(tmp_path)
    out = run("report", "--run", str(tmp_path), "--out", str(tmp_path / "R.md"))
    assert out.returncode == 0, out.stderr
    text = (tmp_path / "R.md").read_text()
    assert text.startswith("# Reproduction") and "*(missing: 05_table1.md" in text


@pytest.mark.slow
def test_reproduce_refuses_a_gpu_profile_without_cuda(tmp_path):
    import os
    import torch
    if torch.cuda.is_available():
        pytest.skip("a GPU is visible: the full profile would start")
    env = {k: v for k, v in os.environ.items() if k != "HBEO_ALLOW_CPU"}
    out = subprocess.run([sys.executable, "-m", "hbeo", "reproduce", "--profile", "full", "--out", str(tmp_path)],
                         capture_output=True, text=True, env=env)
    assert out.returncode == 2 and "needs a CUDA GPU" in out.stderr and "full profile" in out.stderr
    assert not list(tmp_path.iterdir())                                        # failed before writing anything


def test_report_writes_into_the_run_folder_unless_told_otherwise(tmp_path):
    from hbeo.report import reproduction_md
    paper = reproduction_md.PAPER / "REPRODUCTION.md"
    before = paper.stat().st_mtime_ns
    out = run("report", "--run", str(finished_run(tmp_path)))
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "REPRODUCTION.md").read_text().startswith("# Reproduction")
    assert paper.stat().st_mtime_ns == before                       # the committed report is written only when asked


def test_book_is_a_subcommand():
    out = run("book", "--help")
    assert out.returncode == 0 and "opens offline" in out.stdout and "RUN/book" in out.stdout


@pytest.mark.parametrize("command", ["render", "voxelize"])
def test_workers_0_means_one_process_per_usable_core(command, monkeypatch, tmp_path):
    from hbeo import cli, limits
    from hbeo.run import Run
    monkeypatch.setattr(limits, "usable_cores", lambda fallback=1: 3)
    parser = cli.build_parser()
    assert parser.parse_args([command]).workers is None                     # not given: the profile's count
    assert parser.parse_args([command, "--workers", "0"]).workers == 3
    assert parser.parse_args([command, "--workers", "5"]).workers == 5
    assert "0: one per core this process may use" in " ".join(run(command, "--help").stdout.split())
    seen = []
    monkeypatch.setattr(Run, "render", lambda self, splits, settings, subspace, workers, *a: seen.append(workers) or [])
    monkeypatch.setattr(Run, "voxelize", lambda self, workers=0: seen.append(workers) or [])
    assert cli.main([command, "--profile", "ci", "--workers", "0", "--out", str(tmp_path / "run")]) == 0
    assert seen == [3]


def test_train_image_size_is_two_pixel_counts_and_scales_the_camera():
    from hbeo.cli import _image_size
    from hbeo.render.views import RenderSettings
    assert _image_size("120,90") == (120, 90) and _image_size("160x120") == (160, 120)
    for bad in ("120", "a,b", "4,4", "120,90,1", "5000,90"):
        out = run("train", "--image-size", bad)
        assert out.returncode == 2 and "--image-size: expected" in out.stderr and bad in out.stderr, bad
    s = RenderSettings.from_profile("cpu", image_size=(160, 120))
    K, K0 = s.intrinsics, RenderSettings.from_profile("cpu").intrinsics
    assert (s.image_size, (K.width, K.height)) == ((160, 120), (160, 120))
    assert K.fx == 2 * K0.fx and K.fy == 2 * K0.fy               # the same field of view, twice the pixels
