"""The run's steps in order, each skipped when its product is already in the run folder.

grids (notebook 01) -> subspace (02) -> rendered sets (03) -> model (04). The notebooks call the
same package functions; this module lets one command build whatever is missing (``python -m hbeo
train``). Where each product lives is :class:`hbeo.rundir.RunDir`'s business; ``run`` is a RunDir
or a path.

May import: foundation, data, subspace, render.
"""
from __future__ import annotations

from hbeo import config
from hbeo.data import datasets
from hbeo.data.gridset import run_gridsets
from hbeo.render.renderset import Manifest, render_set
from hbeo.render.views import RenderSettings
from hbeo.rundir import RunDir
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
                      subspace=sub, workers=prof.workers, progress=progress)
