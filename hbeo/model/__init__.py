"""HBEONet and the HBEO model (Sec. III-B/C): network, the training loop, the model file, prediction.

Owns the network (:mod:`~hbeo.model.network`), the one training loop used by every network of the
project (:mod:`~hbeo.model.loop`), fitting HBEO from a run folder (:mod:`~hbeo.model.fit`), training images as
torch datasets (:mod:`~hbeo.model.trainingdata`), the
exact camera-roll and mirror augmentation (:mod:`~hbeo.model.augment`, :mod:`~hbeo.model.mirror`), bringing a user's depth image into the
model's camera (:mod:`~hbeo.model.preprocess`) and whether the model can have understood it
(:mod:`~hbeo.model.viewcheck`), where ``--face-object`` turns the view (:mod:`~hbeo.model.facing`), the safe model file and inference
(:mod:`~hbeo.model.inference`, :mod:`~hbeo.model.modelfile`, whose ``meta.json`` :mod:`~hbeo.model.modelmeta`
checks), the completion rules that turn back-projected
coefficients into a grid (:mod:`~hbeo.model.completion_rule`), reading a user's depth image
(:mod:`~hbeo.model.depthfile`), checking an answer against the depth (:mod:`~hbeo.model.verify`), one
depth image's answer, predicted then verified (:mod:`~hbeo.model.answer`), data-parallel training
(:mod:`~hbeo.model.distributed`) and where a CUDA run's host waits for the device (:mod:`~hbeo.model.hostwaits`).

May import: the foundation modules, :mod:`hbeo.data`, :mod:`hbeo.subspace`, :mod:`hbeo.render`.
"""
