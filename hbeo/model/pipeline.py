"""The run's steps in order, each skipped when its product is already in the run folder.

grids (notebook 01) -> subspace (02) -> rendered training set (03) -> model (04). The
notebooks call the same package functions; this module lets one command build whatever
is missing (``python -m hbeo train``).
"""
from __future__ import annotations

from pathlib import Path

from hbeo import config
from hbeo.data import datasets
from hbeo.data.gridset import run_gridsets
from hbeo.render.renderset import RenderSettings, render_set
from hbeo.subspace.basis import ObjectSubspace


def ensure_subspace(dataset: str, profile, run, progress: bool = True) -> ObjectSubspace:
    """``run/subspace.npz``, fitted on the run's training grids (60 % variance) if missing."""
    path = Path(run) / "subspace.npz"
    if path.exists():
        return ObjectSubspace.load(path)
    train = run_gridsets(dataset, profile, run, progress=progress)["train"]
    sub = ObjectSubspace(variance=0.6).fit(train.grids, train.labels, train.classes, progress=progress)
    sub.save(path)
    return sub


def ensure_render(dataset: str, profile, run, split: str = "train", settings: RenderSettings | None = None,
                  progress: bool = True):
    """``run/render_<split>`` with the run's subspace coefficients (rendered or resumed)."""
    prof = config.get_profile(profile)
    sub = ensure_subspace(dataset, prof, run, progress)
    ds = datasets.get_dataset(dataset, profile=prof)
    settings = settings or RenderSettings.from_profile(prof)
    return render_set(ds, datasets.select(ds, split, prof), split, Path(run) / f"render_{split}", settings,
                      subspace=sub, workers=prof.workers, progress=progress)
