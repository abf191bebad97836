"""Checkpoints every N steps and exact resume after a kill at any moment (single process), with
dropout and roll augmentation in play so every random generator the loop restores matters."""
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

import resume_job as job
from hbeo.model.distributed import weights_sha256
from hbeo.model.loop import load_checkpoint, train
from hbeo.rundir import CHECKPOINT, TRAIN_LOG

JOB = Path(__file__).with_name("resume_job.py")


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole")
    tr, va = job.data()
    net = train(job.TASK, tr, va, out, job.config())
    return weights_sha256(net), pd.read_csv(out / TRAIN_LOG)


@pytest.mark.parametrize("stop", [1, 3, 4, 8, 9, 14, 23])     # 8 steps an epoch, a checkpoint every 3
def test_a_run_killed_after_any_step_resumes_to_the_same_weights(tmp_path, uninterrupted, stop):
    tr, va = job.data()
    train(job.TASK, tr, va, tmp_path, job.config(), stop_after_step=stop)        # killed: nothing more written
    # killed after the step, before any checkpoint of that step: the last one is from an earlier step
    written = [s for s in (3, 6, 8, 9, 12, 15, 16, 18, 21) if s < stop]
    assert (tmp_path / CHECKPOINT).exists() == bool(written)
    if written:
        assert load_checkpoint(tmp_path / CHECKPOINT)["step"] == written[-1]
    tr, va = job.data()
    net = train(job.TASK, tr, va, tmp_path, job.config())
    sha, log = uninterrupted
    assert weights_sha256(net) == sha
    assert pd.read_csv(tmp_path / TRAIN_LOG).drop(columns="images_per_s").equals(log.drop(columns="images_per_s"))


def test_a_finished_checkpoint_brought_alone_gives_its_weights_and_its_log(tmp_path, uninterrupted):
    """A finished training's checkpoint copied into another folder (maintainer/seed_runs.sh's CKPT2): training
    there again trains nothing, returns the same weights and writes the log from the checkpoint's history."""
    tr, va = job.data()
    train(job.TASK, tr, va, tmp_path / "a", job.config())
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / CHECKPOINT).write_bytes((tmp_path / "a" / CHECKPOINT).read_bytes())
    tr, va = job.data()
    net = train(job.TASK, tr, va, tmp_path / "b", job.config())
    sha, log = uninterrupted
    assert weights_sha256(net) == sha
    assert (tmp_path / "b" / TRAIN_LOG).read_bytes() == (tmp_path / "a" / TRAIN_LOG).read_bytes()
    assert pd.read_csv(tmp_path / "b" / TRAIN_LOG).drop(columns="images_per_s").equals(log.drop(columns="images_per_s"))


def test_checkpoints_inside_an_epoch_say_where_the_epoch_stands(tmp_path):
    tr, va = job.data()
    train(job.TASK, tr, va, tmp_path, job.config(), stop_after_step=13)
    ck = load_checkpoint(tmp_path / CHECKPOINT)
    # step 12 is the 4th batch of the second epoch; the first epoch (8 steps) is done and logged
    assert (ck["epoch"], ck["step"], ck["in_epoch"]["batches"]) == (0, 12, 4)
    assert ck["in_epoch"]["seen"] == 4 * 8 and len(ck["history"]) == 1
    # epoch ends write checkpoints without in_epoch
    tr, va = job.data()
    train(job.TASK, tr, va, tmp_path / "e", job.config(checkpoint_every=None), stop_after_step=10)
    ck = load_checkpoint(tmp_path / "e" / CHECKPOINT)
    assert (ck["epoch"], ck["step"]) == (0, 8) and "in_epoch" not in ck


def _job(out, env, *extra):
    return subprocess.Popen([sys.executable, str(JOB), str(out), *map(str, extra)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=JOB.parent.parent)


def test_sigkill_at_random_moments_then_resume_matches_an_uninterrupted_run(tmp_path):
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(JOB.parent.parent))
    whole = _job(tmp_path / "whole", env)
    out, err = whole.communicate(timeout=300)
    assert whole.returncode == 0, err
    expected = out.split()[-1]
    rng, kills, run = random.Random(7), 0, tmp_path / "killed"
    for attempt in range(12):
        p = _job(run, env)
        assert p.stdout.readline().strip() == "started", p.stderr.read()
        if attempt < 4:
            time.sleep(rng.uniform(0.0, 0.3))
            p.kill()                                   # SIGKILL: no handler, no cleanup, nothing flushed
            p.wait()
            kills += p.returncode == -9
            continue
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        assert out.split()[-1] == expected
        break
    else:
        pytest.fail("the killed run never finished")
    assert kills >= 1
    assert not [f for f in run.rglob("*") if f.name.startswith(".") or f.suffix == ".tmp"], "a temporary file was left"
