"""Data-parallel training with torchrun (2 processes, gloo): the issue's command, identical
weights on both ranks, a normal model file, and a killed run that resumes and finishes."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hbeo.model.distributed import World, rank_slice, weights_sha256
from hbeo.model.inference import HBEO
from hbeo.rundir import CHECKPOINT, RANKS, RunDir

TORCHRUN = Path(sys.executable).with_name("torchrun")


def test_rank_slices_cover_the_epoch_in_equal_contiguous_parts():
    order = np.array([5, 3, 9, 1, 7, 0, 2])
    parts = [rank_slice(order, World(r, 3)) for r in range(3)]
    assert [len(p) for p in parts] == [3, 3, 3]
    assert list(np.concatenate(parts)) == [5, 3, 9, 1, 7, 0, 2, 5, 3]        # padded by wrapping round
    assert rank_slice(order, World()) is not None and list(rank_slice(order, World())) == list(order)


def _torchrun(run, cache, *extra, wait=True):
    cmd = [str(TORCHRUN), "--standalone", "--nproc_per_node", "2", "-m", "hbeo", "train", "--profile", "ci",
           "--dataset", "procedural", "--out", str(run), *extra]
    env = dict(os.environ, HBEO_CACHE=str(cache), OMP_NUM_THREADS="1")
    if not wait:
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                                start_new_session=True)
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)


@pytest.fixture
def run_with_renders(tmp_path, ci_render, ci_run, copy_run, _ci):
    """A private copy of the ci run with its grids, subspace and rendered training set."""
    rd = RunDir(ci_run.path)
    keep = [p.name for p in rd.path.iterdir() if p.name in {rd.subspace.name, rd.renders("train").name}
            or p.name.startswith("grids")]
    return copy_run(ci_run, tmp_path / "run", keep), _ci.cache


@pytest.mark.slow
def test_torchrun_two_processes_train_the_ci_profile(run_with_renders):
    run, cache = run_with_renders
    out = _torchrun(run.path, cache)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.count("model:") == 1 and "2 processes" in out.stdout        # rank 0 alone reports
    ranks = json.loads((run.training(run.model) / RANKS).read_text())
    assert ranks["world_size"] == 2 and ranks["backend"] == "gloo"
    assert len(ranks["weights_sha256"]) == 2 and len(set(ranks["weights_sha256"])) == 1
    model = HBEO.load(run.model)                              # a normal, safe model file
    assert weights_sha256(model.net) == ranks["weights_sha256"][0]
    log = pd.read_csv(run.train_log(run.model))
    assert len(log) == 8 and log.step.is_monotonic_increasing     # the ci profile's 8 epochs


@pytest.mark.slow
def test_torchrun_killed_run_resumes_and_continues_the_schedule(run_with_renders):
    run, cache = run_with_renders
    p = _torchrun(run.path, cache, "--checkpoint-every", "5", wait=False)
    ck = run.checkpoint(run.model)
    deadline = time.time() + 300
    while not ck.exists() and time.time() < deadline and p.poll() is None:
        time.sleep(0.2)
    assert ck.exists(), p.communicate()[1][-3000:]
    os.killpg(p.pid, signal.SIGKILL)                          # torchrun and both ranks, at once
    p.wait()
    assert not run.model.exists()
    from hbeo.model.loop import load_checkpoint
    step_at_kill = load_checkpoint(ck)["step"]
    out = _torchrun(run.path, cache, "--checkpoint-every", "5")
    assert out.returncode == 0, out.stderr[-3000:]
    log = pd.read_csv(run.train_log(run.model))
    assert list(log.epoch) == list(range(1, 9)) and log.step.iloc[-1] > step_at_kill
    assert log.step.diff().dropna().nunique() == 1              # the same steps in every epoch, none lost
    ranks = json.loads((run.training(run.model) / RANKS).read_text())
    assert len(set(ranks["weights_sha256"])) == 1 and ranks["step"] == log.step.iloc[-1]
    HBEO.load(run.model)
