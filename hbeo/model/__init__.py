"""HBEONet and the HBEO model (Sec. III-B/C): network, the training loop, the model file, prediction.

Owns the network (:mod:`~hbeo.model.network`), the one training loop used by every network of the
project (:mod:`~hbeo.model.train`), fitting HBEO from a run folder (:mod:`~hbeo.model.fit`), the
exact camera-roll augmentation (:mod:`~hbeo.model.augment`), bringing a user's depth image into the
model's camera (:mod:`~hbeo.model.preprocess`), the safe model file and inference
(:mod:`~hbeo.model.inference`), and building a run's missing prerequisites
(:mod:`~hbeo.model.pipeline`).

May import: the foundation modules, :mod:`hbeo.data`, :mod:`hbeo.subspace`, :mod:`hbeo.render`.
"""
