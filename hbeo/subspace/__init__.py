"""The object subspace (Sec. III-A of HBEO, Sec. III of BEO): VBPCA, the shared basis, partial views.

Owns Variational Bayesian PCA (:mod:`~hbeo.subspace.vbpca`), the shared orthonormal basis
:class:`~hbeo.subspace.basis.ObjectSubspace` (:mod:`~hbeo.subspace.basis`: project, reconstruct, partial
projection), partial projection of many masks at once (:mod:`~hbeo.subspace.projection`), carving a
depth image at a pose hypothesis into known-filled / known-empty / unknown voxels
(:mod:`~hbeo.subspace.partial`), the completion metrics and protocol
(:mod:`~hbeo.subspace.metrics`, :mod:`~hbeo.subspace.completion`), and which reading of "60 % of the
variance" gives which basis size (:mod:`~hbeo.subspace.size`).

May import: the foundation modules and :mod:`hbeo.data`.
"""
