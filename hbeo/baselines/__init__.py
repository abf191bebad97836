"""The methods HBEO is compared with (Sec. IV): BEO, ICP and a 3-D CNN, behind one interface.

Owns BEO with known pose, 1-DOF and 3-DOF search (:mod:`~hbeo.baselines.beo`), the ICP pose
baseline (:mod:`~hbeo.baselines.icp`), the end-to-end 3-D CNN in the role of 3D ShapeNets
(:mod:`~hbeo.baselines.voxcnn`, trained by :mod:`hbeo.model.loop`), and the registry of methods and
pose settings (:mod:`~hbeo.baselines.methods`), and the check that a converted old-format model file
predicts as the old one did (:mod:`~hbeo.baselines.conversion_check`). A new baseline goes here: a class with
``fit``/``save``/``load``/``predict_view`` registered in :mod:`~hbeo.baselines.methods`.

May import: the foundation modules, :mod:`hbeo.data`, :mod:`hbeo.subspace`, :mod:`hbeo.render`,
:mod:`hbeo.model`.
"""
