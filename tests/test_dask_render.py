"""Rendering on Dask (issue 15): a LocalCluster of 2 workers and a running scheduler given by its
address (``--scheduler``) write the same shard bytes as one worker; ``dask scheduler`` and
``dask worker`` started as programs, as a user would, serve ``python -m hbeo render --scheduler``."""
import logging
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from distributed import Client, LocalCluster

from hbeo import cli
from hbeo.data import datasets
from hbeo.errors import DataError
from hbeo.render import renderset
from hbeo.render.renderset import Manifest, render_set
from hbeo.render.views import RenderSettings

SMALL = RenderSettings(image_size=(32, 24), views_per_object=2)
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def ds():
    return datasets.ProceduralDataset(n_train=2, n_test=1, seed=3, classes=("bed", "chair", "table"))


@pytest.fixture(scope="module")
def single(ds, tmp_path_factory):
    """The reference: one worker process."""
    return render_set(ds, ds.records("train"), "train", tmp_path_factory.mktemp("one"), SMALL, workers=1,
                      objects_per_shard=2, progress=False)


def _hashes(m: Manifest) -> list[str]:
    m.verify()
    return [s["sha256"] for s in m.shards]


@pytest.fixture(scope="module")
def cluster():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as c:
        yield c


@pytest.mark.slow
def test_local_cluster_of_two_workers_writes_the_single_process_bytes(ds, single, tmp_path):
    two = render_set(ds, ds.records("train"), "train", tmp_path, SMALL, workers=2, objects_per_shard=2,
                     progress=False)
    assert two.rendered == single.rendered == 12 and len(two.shards) == 3
    assert _hashes(two) == _hashes(single)
    for s, p in zip(two.shards, two.shard_paths()):            # finished shards carry their sidecar
        assert p.with_name(p.name + ".sha256").read_text().split()[0] == s["sha256"]


@pytest.mark.slow
def test_scheduler_address_renders_the_same_bytes_and_resumes(ds, single, cluster, tmp_path):
    recs = ds.records("train")
    m = render_set(ds, recs, "train", tmp_path, SMALL, objects_per_shard=2, progress=False,
                   scheduler=cluster.scheduler_address)
    assert m.rendered == 12 and _hashes(m) == _hashes(single)
    with Client(cluster) as client:            # the cluster is still whole (rendering killed no worker)
        assert len(client.scheduler_info()["workers"]) == 2
    (tmp_path / "shard_00002.npz").unlink()
    with pytest.warns(UserWarning, match="shard_00002.npz: shard listed in the manifest is missing"):
        again = render_set(ds, recs, "train", tmp_path, SMALL, objects_per_shard=2, progress=False,
                           scheduler=cluster.scheduler_address)
    assert again.rendered == 4 and _hashes(again) == _hashes(single)
    # the CLI passes --scheduler through
    out = tmp_path / "cli"
    assert cli.main(["render", "--profile", "ci", "--dataset", "procedural", "--out", str(out), "--views", "1",
                     "--split", "test", "--quiet", "--scheduler", cluster.scheduler_address]) == 0
    assert Manifest.load(out / "render_test").n_images > 0


def test_unreachable_scheduler_is_a_one_line_error(ds, tmp_path, monkeypatch):
    monkeypatch.setattr(renderset, "CONNECT_TIMEOUT", "1s")
    with pytest.raises(DataError, match=r"tcp://127\.0\.0\.1:9: cannot reach the Dask scheduler"):
        render_set(ds, ds.records("test"), "test", tmp_path, SMALL, progress=False,
                   scheduler="tcp://127.0.0.1:9")
    with pytest.raises(ValueError, match="scheduler must be an address"):
        render_set(ds, ds.records("test"), "test", tmp_path, SMALL, progress=False, scheduler=" ")


@pytest.mark.slow
def test_dask_scheduler_and_worker_programs_serve_the_cli(tmp_path):
    """What a user runs: ``dask scheduler``, ``dask worker ADDRESS``, then ``hbeo render --scheduler``."""
    sched = subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                              "--no-dashboard", "--scheduler-file", str(tmp_path / "sched.json")],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    procs = [sched]
    try:
        deadline, address = time.time() + 60, None
        for line in sched.stderr:                       # "Scheduler at:   tcp://127.0.0.1:PORT"
            if m := re.search(r"Scheduler at:\s+(tcp://\S+)", line):
                address = m.group(1)
                break
            assert time.time() < deadline, "dask scheduler did not start"
        assert address, "dask scheduler exited"
        procs.append(subprocess.Popen([str(BIN / "dask"), "worker", address, "--nworkers", "2", "--nthreads", "1",
                                       "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        out = tmp_path / "run"
        r = subprocess.run([sys.executable, "-m", "hbeo", "render", "--profile", "ci", "--dataset", "procedural",
                            "--out", str(out), "--views", "2", "--split", "test", "--objects-per-shard", "2",
                            "--quiet", "--scheduler", address], capture_output=True, text=True, timeout=300,
                           env=dict(os.environ))
        assert r.returncode == 0, r.stderr[-2000:]
        assert "images/s" in r.stdout
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
    remote = Manifest.load(out / "render_test")
    ci = datasets.get_dataset("procedural", profile="ci")
    local = render_set(ci, datasets.select(ci, "test", "ci"), "test", tmp_path / "local",
                       RenderSettings.from_profile("ci", views_per_object=2), workers=1, objects_per_shard=2,
                       progress=False)
    assert _hashes(remote) == _hashes(local)
