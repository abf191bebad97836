"""The methods HBEO is compared with (Sec. IV): BEO, ICP and a 3-D CNN, behind one interface.

Owns BEO with known pose, 1-DOF and 3-DOF search (:mod:`~hbeo.baselines.beo`), the ICP pose
baseline (:mod:`~hbeo.baselines.icp`), the end-to-end 3-D CNN in the role of 3D ShapeNets
(:mod:`~hbeo.baselines.voxcnn`, trained by :mod:`hbeo.model.loop`), and the registry of methods and
pose settings (:mod:`~hbeo.baselines.methods`), and the check that a converted old-format model file
predicts as the old one did (:mod:`~hbeo.baselines.conversion_check`).

Adding a baseline: (1) a module here with a class that is prepared by ``fit`` (and ``save`` /
``load`` of one file in the run folder, :meth:`hbeo.rundir.RunDir.baseline`), never by attributes
set afterwards; (2) its name and pose settings in :data:`~hbeo.baselines.methods.METHODS` (and
:data:`~hbeo.baselines.methods.GIVEN_CLASS` where the protocol gives it the true class), its
preparation in :func:`~hbeo.baselines.methods.load_method`; (3) the
:class:`hbeo.evaluation.method.Method` contract: class attributes ``name`` and ``poses =
METHODS[name]``, ``describe()`` and ``predict_view(depth, intrinsics, R_true, t_true,
object_size, pose, label_true, rng)`` -> ``{"probabilities", "rotation", "grid"}``; (4) a
factory in ``tests/test_methods.py``'s ``FACTORIES``, whose conformance checks it must pass; (5)
its display label in :data:`hbeo.evaluation.method.LABELS`. The evaluation loop needs no change.

May import: the foundation modules, :mod:`hbeo.data`, :mod:`hbeo.subspace`, :mod:`hbeo.render`,
:mod:`hbeo.model`.
"""
