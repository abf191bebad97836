"""Shared fixtures: the real-data samples, and the ``ci`` run built once per session.

The ci run is what ``python -m hbeo train --profile ci --dataset procedural --epochs 1`` builds,
in one temporary :class:`~hbeo.rundir.RunDir`, stage by stage and only as far as a test asks:

    ci_run          the (empty) run folder, a RunDir
    ci_grids        {"train", "test"}: GridSets of both splits (60 + 30 objects; read-only arrays)
    ci_subspace     the run's ObjectSubspace (60 % of each class's variance)
    ci_render       the rendered training set (480 views, 80x60), its Manifest
    ci_render_test  the rendered test set (240 views), its Manifest
    ci_model        the model file trained by the CLI (one epoch, in a child process, so no
                    training threads stay in this one), its path

and ``tiny_model``, the one builder of a small untrained HBEO (32x24 camera, 4-channel network)
for the tests that need a valid model but no trained one (model files, prediction, fuzzing).

Each stage builds on the previous one, so a test that needs only grids does not train. The folder
is shared: tests read it and never write into it; a test that writes (evaluate fits baselines
beside the model, the 3-D CNN caches its partial grids) works on a ``copy_run`` copy. Whether
the folder is still as the stages left it is checked before each stage and at the end.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hbeo import config

CI = ("procedural", "ci")                 # dataset, profile of the shared run


@pytest.fixture(scope="session")
def sample_dir():
    """../shared/modelnet10_sample: five real ModelNet10 bathtub meshes."""
    d = config.modelnet10_sample_dir()
    if d is None or not d.is_dir():
        pytest.skip("shared/modelnet10_sample not found beside the repository")
    return d


@pytest.fixture(scope="session")
def vox30_file():
    p = config.vox30_path()
    if p is None:
        pytest.skip("shared/modelnet10_vox30 not found beside the repository")
    return p


@pytest.fixture(scope="session")
def vox30(vox30_file):
    with np.load(vox30_file) as z:
        return {k: z[k] for k in ("X_train", "names_train", "y_train", "classes")}


# ----------------------------------------------------------------------------- the shared ci run

class _SharedRun:
    """The shared run folder and what its stages wrote there (size and mtime of every file)."""

    def __init__(self, path: Path):
        from hbeo.rundir import RunDir
        self.run = RunDir(path).create()
        self.cache = path.parent / (path.name + "_cache")     # voxel cache of this session only
        self._files = self._state()

    def _state(self) -> dict:
        root = self.run.path
        return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
                for p in root.rglob("*") if p.is_file()}

    def check(self) -> None:
        now = self._state()
        changed = sorted(k for k in set(now) | set(self._files) if now.get(k) != self._files.get(k))
        assert not changed, (f"a test wrote into the shared ci run {self.run.path} (copy it with copy_run "
                             f"first): {', '.join(changed[:5])}")

    def build(self, step):
        """Run one stage (``step()``) after checking nothing else touched the folder."""
        self.check()
        out = step()
        self._files = self._state()
        return out


@pytest.fixture(scope="session")
def _ci(tmp_path_factory):
    shared = _SharedRun(tmp_path_factory.mktemp("ci_shared") / "ci-procedural")
    yield shared
    shared.check()                        # fails the session's last test's teardown if one wrote there


@pytest.fixture(scope="session")
def ci_run(_ci):
    """The shared ci run folder (a RunDir). Read only: copy it with ``copy_run`` to write."""
    return _ci.run


@pytest.fixture(scope="session")
def ci_grids(_ci):
    """{"train": GridSet, "test": GridSet} of the ci run (run_gridsets, as ``train`` does),
    voxelized into a cache of this session's own."""
    from hbeo.run import Run

    def step():
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("HBEO_CACHE", str(_ci.cache))
            sets = Run.open(CI[1], CI[0], _ci.run.path).grids(progress=False)
        for gs in sets.values():              # shared by every test: a test that writes into them fails
            for a in (gs.grids, gs.labels, gs.ids):
                a.setflags(write=False)
        return sets
    return _ci.build(step)


@pytest.fixture(scope="session")
def ci_subspace(_ci, ci_grids):
    """The ci run's ObjectSubspace, fitted on ``ci_grids["train"]`` and saved in the run."""
    from hbeo.run import Run
    return _ci.build(lambda: Run.open(CI[1], CI[0], _ci.run.path).subspace(progress=False))


@pytest.fixture(scope="session")
def ci_render(_ci, ci_subspace):
    """The Manifest of the ci run's rendered training set (rendered in spawned workers)."""
    from hbeo.run import Run
    return _ci.build(lambda: Run.open(CI[1], CI[0], _ci.run.path).renders("train", progress=False))


@pytest.fixture(scope="session")
def ci_render_test(_ci, ci_subspace):
    """The Manifest of the ci run's rendered test set (``train`` does not render it)."""
    from hbeo.run import Run
    return _ci.build(lambda: Run.open(CI[1], CI[0], _ci.run.path).renders("test", progress=False))


@pytest.fixture(scope="session")
def ci_model(_ci, ci_render):
    """Path of the model trained by ``python -m hbeo train --dataset procedural --profile ci
    --epochs 1`` in the ci run (grids, subspace and rendering are already there and are reused)."""
    def step():
        out = subprocess.run([sys.executable, "-m", "hbeo", "train", "--dataset", CI[0], "--profile", CI[1],
                              "--out", str(_ci.run.path), "--epochs", "1", "--quiet"],
                             capture_output=True, text=True, env=dict(os.environ, HBEO_CACHE=str(_ci.cache)))
        assert out.returncode == 0, out.stderr
        assert "model:" in out.stdout and _ci.run.model.is_file()
        return _ci.run.model
    return _ci.build(step)


@pytest.fixture(scope="session")
def copy_run():
    """``copy_run(run, dest, names=None) -> RunDir``: a private copy of run folder ``run`` at
    ``dest`` (all of it, or the top-level entries ``names``), for tests that write into a run."""
    from hbeo.rundir import RunDir

    def copy(run, dest, names=None):
        src, dest = RunDir.of(run).path, Path(dest)
        dest.mkdir(parents=True, exist_ok=True)
        for p in sorted(src.iterdir()):
            if names is None or p.name in names:
                (shutil.copytree if p.is_dir() else shutil.copy2)(p, dest / p.name)
        return RunDir(dest)
    return copy


# ------------------------------------------------------------------ the tiny untrained model

def box_grids(n: int = 8) -> np.ndarray:
    """``n`` 30^3 boxes of varied size (the tiny model's training shapes; classes alternate)."""
    grids = np.zeros((n, 30, 30, 30), bool)
    for i, g in enumerate(grids):
        a = 8 + i % 4
        g[a:30 - a, 10:20, a:14 + i] = True
    return grids


def build_tiny_model(settings, classes=("chair", "table"), subspace=None, mean_grids=None):
    """An untrained HBEO with ``settings`` (a dict, or a function of the subspace giving one): a 2-component subspace of :func:`box_grids` (or ``subspace``), a 32x24
    Kinect-like camera, conv (4, 4, 4, 4) and FC (8, 8, 8) layers, weights from torch seed 0; with
    ``mean_grids`` the coefficient head's bias is their mean projection (a non-empty mean shape)."""
    import torch
    from hbeo.conventions import Intrinsics
    from hbeo.model.inference import HBEO
    from hbeo.model.network import HBEONet, NetConfig
    from hbeo.subspace.basis import ObjectSubspace
    if subspace is None:
        subspace = ObjectSubspace(n_components=2).fit(box_grids(), np.arange(8) % 2, tuple(classes), progress=False)
    torch.manual_seed(0)
    net = HBEONet(NetConfig(image_size=(32, 24), n_classes=len(classes), n_coeffs=subspace.dim_,
                            conv_channels=(4, 4, 4, 4), fc=(8, 8, 8)))
    if mean_grids is not None:
        with torch.no_grad():
            net.coeff_head.bias.copy_(torch.from_numpy(subspace.project(mean_grids).mean(0)))
    settings = settings(subspace) if callable(settings) else settings
    return HBEO(net, subspace, Intrinsics.kinect(32, 24), tuple(classes), settings)


@pytest.fixture(scope="session")
def tiny_model():
    """The builder of a small untrained HBEO, :func:`build_tiny_model` (call it with the settings,
    classes and subspace a test needs; every call gives a fresh model)."""
    return build_tiny_model
