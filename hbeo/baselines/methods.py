"""The registry of the methods compared in the paper (name -> pose settings), and the preparation of
a run's baselines; each implements :class:`hbeo.evaluation.method.Method` (HBEO through
:class:`hbeo.evaluation.method.HBEOMethod`), the one interface of :func:`hbeo.evaluation.evaluate.evaluate_method`.

==========  ==========================  =======================================================
method      pose settings               what it is
==========  ==========================  =======================================================
``hbeo``    ``3dof``                    HBEONet (:mod:`hbeo.model.inference`): depth -> class,
                                        pose, coefficients in one shot
``beo``     ``known``, ``1dof``,        BEO (:mod:`hbeo.baselines.beo`): partial grid, partial
            ``3dof``                    projection, class-pose posterior by search
``icp``     ``1dof``, ``3dof``          ICP against the true class's mean shape
                                        (:mod:`hbeo.baselines.icp`)
``voxcnn``  ``known``                   3-D CNN from the partial grid to class and
                                        completed grid (:mod:`hbeo.baselines.voxcnn`)
==========  ==========================  =======================================================

Each lives in one file of the run folder: :attr:`hbeo.rundir.RunDir.model` for ``hbeo``,
:meth:`hbeo.rundir.RunDir.baseline` for the others.

A baseline is a class with ``name`` and ``poses`` (class attributes, ``poses = METHODS[name]``),
``describe()`` and ``predict_view(depth, intrinsics, R_true, t_true, object_size, pose, label_true,
rng)`` -> ``{"probabilities": (C,), "rotation": (3, 3), "grid": (30, 30, 30) bool}``.
What each may use of the truth is the paper's protocol: BEO and the voxel network get the
object's translation and size (their input must be voxelized in the object's frame) and, for
``known``, its rotation; ``1dof`` gives the up axis and hides the yaw; the settings in
:data:`GIVEN_CLASS` get the true class (``label_true``), all others ``label_true=None``.
:func:`load_method` builds a baseline's file from the run's training grids (or rendered set)
when it is missing; BEO's 3-DOF search grid is the profile's ``beo_so3_grid``.

May import: foundation, data, subspace, render, model, and the other baseline modules.
"""
from __future__ import annotations

from hbeo import config
from hbeo.rundir import RunDir

METHODS: dict[str, tuple[str, ...]] = {
    "hbeo": ("3dof",),
    "beo": ("known", "1dof", "3dof"),
    "icp": ("1dof", "3dof"),
    "voxcnn": ("known",),
}
#: (method, pose) settings that are given the true class, as in the paper's pose experiment (BEO's
#: 3-DOF search over all classes was infeasible there; ICP aligns with the true class's mean shape).
GIVEN_CLASS = {("beo", "3dof"), ("icp", "1dof"), ("icp", "3dof")}


def check_method(method: str, pose: str | None) -> str:
    """The pose setting to use (the method's first one when ``pose`` is None); ValueError otherwise."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if pose is None:
        return METHODS[method][0]
    if pose not in METHODS[method]:
        raise ValueError(f"method {method!r} does not take pose {pose!r}; it takes {', '.join(METHODS[method])}")
    return pose


def load_method(method: str, run, profile="cpu", progress: bool = True, max_steps: int | None = None,
                seed: int = 0):
    """The baseline ``method`` of run folder ``run`` (a RunDir or a path): loaded from its file, or
    fitted on the run's training grids (``beo``, ``icp``) or trained on its rendered set (``voxcnn``,
    with training seed ``seed``; ``max_steps`` ends its training after that many optimizer steps) and
    saved first."""
    check_method(method, None)
    if method == "hbeo":
        raise ValueError("hbeo is the model itself: wrap it in hbeo.evaluation.method.HBEOMethod "
                         "(or pass method=None to evaluate_model)")
    run = RunDir.of(run)
    path = run.baseline(method)
    if method == "voxcnn":
        from hbeo.baselines.voxcnn import VoxCNNBaseline, train_voxcnn
        if path.exists():
            return VoxCNNBaseline.load(path)
        return train_voxcnn(run, profile, seed=seed, progress=progress, max_steps=max_steps)
    from hbeo.baselines.beo import BEO
    from hbeo.baselines.icp import ICPBaseline
    from hbeo.data.gridset import GridSet
    from hbeo.subspace.basis import ObjectSubspace
    cls = BEO if method == "beo" else ICPBaseline
    if path.exists():
        return cls.load(path)
    train = GridSet.load(run.grids("train"))
    if method == "beo":
        m = BEO(ObjectSubspace.load(run.subspace), so3_grid=config.get_profile(profile).baselines.beo_so3_grid)
        m = m.fit(train.grids, train.labels, train.classes, progress=progress)
    else:
        m = ICPBaseline().fit(train.grids, train.labels, train.classes)
    m.save(path)
    return m


