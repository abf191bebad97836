"""hbeo.progress: bars go to the progress file when a run asks for it, and the echo prints the latest one."""
import io
import os
import time

from hbeo import progress


def test_a_bar_writes_to_the_progress_file_when_asked(tmp_path, monkeypatch):
    path = tmp_path / "p.txt"
    monkeypatch.setenv(progress.PROGRESS_ENV, str(path))
    with progress.tqdm(range(7), desc="train epoch 3/15") as bar:
        for _ in bar:
            pass
    line = progress.latest_line(path)
    assert line.startswith("train epoch 3/15: 100%") and "7/7" in line


def test_a_bar_without_the_variable_writes_nothing_there(tmp_path, monkeypatch):
    monkeypatch.delenv(progress.PROGRESS_ENV, raising=False)
    bar = progress.tqdm(range(3), disable=True)
    list(bar)
    assert not list(tmp_path.iterdir())


def test_latest_line_takes_the_last_carriage_return_segment(tmp_path):
    p = tmp_path / "p.txt"
    p.write_text("a: 1/3\rb: 2/3\r\n  \r")
    assert progress.latest_line(p) == "b: 2/3"
    assert progress.latest_line(tmp_path / "missing.txt") == ""


def test_the_echo_prints_changes_with_the_notebook_and_restores_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(progress.PROGRESS_ENV, "before")
    out = io.StringIO()
    path = tmp_path / "echo.txt"
    with progress.ProgressEcho(path, "[hbeo 4/8] 04_train", out=out, interval_s=0.05):
        assert os.environ[progress.PROGRESS_ENV] == str(path)
        with open(path, "a") as f:
            f.write("\rhbeonet epoch 2/15:  40%| 250/625 [00:20<00:30]")
        time.sleep(0.3)
    assert os.environ[progress.PROGRESS_ENV] == "before" and not path.exists()
    lines = out.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith("[hbeo 4/8] 04_train 0:0")
    assert lines[0].endswith("hbeonet epoch 2/15:  40%| 250/625 [00:20<00:30]")


def test_in_a_notebook_papermill_runs_a_bar_is_text_on_stderr(monkeypatch, capsys):
    """Papermill run directly (no progress file): the executed notebook keeps text, not a widget's empty frame."""
    monkeypatch.delenv(progress.PROGRESS_ENV, raising=False)
    history = ["", 'profile = "ci"', '# Parameters\nprofile = "cpu"\n', "train()"]
    assert progress.run_by_papermill(history) and not progress.run_by_papermill(history[:2] + history[3:])
    monkeypatch.setattr(progress, "kernel_history", lambda: history)
    with progress.tqdm(range(5), desc="render") as bar:
        assert type(bar).__module__ == "tqdm.std"                     # not tqdm.notebook's widget
        list(bar)
    err = capsys.readouterr().err
    assert err.split("\r")[-1].strip().startswith("render: 100%") and "5/5" in err
    monkeypatch.setattr(progress, "kernel_history", lambda: history[:2])
    assert progress.run_by_papermill() is False                      # JupyterLab or nbval: tqdm.auto decides
