"""The run's steps in order, each skipped when its product is already in the run folder.

grids (notebook 01) -> subspace (02) -> rendered sets (03) -> model (04). The notebooks call the
same package functions; this module lets one command (``python -m hbeo train``) or any notebook run
alone (:func:`ensure_model`) build whatever is missing. Where each product lives is :class:`hbeo.rundir.RunDir`'s business; ``run`` is a RunDir
or a path.

May import: foundation, data, subspace, render, and the other model modules (lazily).
"""
from __future__ import annotations

import json

from hbeo import config
from hbeo.data import datasets
from hbeo.data.gridset import run_gridsets
from hbeo.render.renderset import Manifest, render_set
from hbeo.render.views import RenderSettings
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text
from hbeo.subspace.basis import ObjectSubspace

#: Fraction of each class's variance the run's subspace keeps (the paper's 60 %).
VARIANCE = 0.6


def ensure_subspace(dataset: str, profile, run, progress: bool = True) -> ObjectSubspace:
    """The run's subspace, fitted on its training grids (:data:`VARIANCE`) and saved if missing."""
    run = RunDir.of(run)
    if run.subspace.exists():
        return ObjectSubspace.load(run.subspace)
    return fit_subspace(dataset, profile, run, progress)


def fit_subspace(dataset: str, profile, run, progress: bool = True) -> ObjectSubspace:
    """Fit the run's subspace on its training grids (:data:`VARIANCE`; the grids are built if
    missing) and save it, replacing any earlier one (notebook 02)."""
    run = RunDir.of(run)
    train = run_gridsets(dataset, profile, run, progress=progress)["train"]
    sub = ObjectSubspace(variance=VARIANCE).fit(train.grids, train.labels, train.classes, progress=progress)
    sub.save(run.subspace)
    return sub


def ensure_render(dataset: str, profile, run, split: str = "train", settings: RenderSettings | None = None,
                  progress: bool = True) -> Manifest:
    """The run's rendered set of ``split`` with the run's subspace coefficients (rendered, resumed,
    or read when complete); ``settings`` default to the profile's."""
    prof = config.get_profile(profile)
    run = RunDir.of(run)
    sub = ensure_subspace(dataset, prof, run, progress)
    ds = datasets.get_dataset(dataset, profile=prof)
    settings = settings or RenderSettings.from_profile(prof)
    return render_set(ds, datasets.select(ds, split, prof), split, run.renders(split), settings,
                      subspace=sub, workers=prof.data.workers, progress=progress)


def train_run_model(dataset: str, profile, run, epochs: int | None = None, progress: bool = True):
    """Train the run's model with the profile's recipe (:meth:`hbeo.config.Profile.recipe`) on its
    rendered training set (rendered first if missing). Returns (model, path, resumed): ``resumed`` is
    the optimizer step of the checkpoint the training continued from (a run cut off earlier), or None
    when it trained from scratch; provenance records it."""
    from hbeo.model.fit import fit_model
    from hbeo.model.loop import CHECKPOINT, load_checkpoint
    prof = config.get_profile(profile)
    run = RunDir.of(run)
    ensure_render(dataset, prof, run, "train", progress=progress)
    ckpt = run.training(run.model) / CHECKPOINT
    resumed = None
    if ckpt.exists():
        resumed = int(load_checkpoint(ckpt)["step"])
    model, path = fit_model(run, prof, epochs=epochs, progress=progress, **prof.recipe.fit_kwargs())
    info = {"model": path.name, "recipe": prof.recipe.fit_kwargs(), "epochs": epochs or prof.recipe.epochs, "resumed_from_step": resumed,
            "n_params": model.net.n_params()}
    atomic_text(run.training(path) / "provenance.json", json.dumps(info, indent=1))
    return model, path, resumed


def ensure_model(dataset: str, profile, run, progress: bool = True):
    """The run's HBEO model (:attr:`hbeo.rundir.RunDir.model`): loaded, or trained with the profile's
    recipe first (:func:`train_run_model`) when missing, so a later notebook runs alone."""
    from hbeo.model.inference import HBEO
    run = RunDir.of(run)
    if run.model.exists():
        return HBEO.load(run.model)
    print(f"[hbeo] {run.model} missing: training it with profile {config.get_profile(profile).name}'s recipe "
          f"(notebook 04)", flush=True)
    return train_run_model(dataset, profile, run, progress=progress)[0]
