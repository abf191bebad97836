"""Depth images (Sec. IV, training data): cameras, viewpoints, renderers, sensor noise, render sets.

Owns sampling viewpoints (:mod:`~hbeo.render.poses`), rendering meshes and grids to depth
(:mod:`~hbeo.render.renderer`), ray-marching grids to depth in batches in torch
(:mod:`~hbeo.render.gridcast`) or in one fused Triton kernel (:mod:`~hbeo.render.fused`), sensor
noise (:mod:`~hbeo.render.noise`), the settings and labelled views of one object
(:mod:`~hbeo.render.views`), the rendered training sets on disk (:mod:`~hbeo.render.renderset`)
and as torch datasets (:mod:`~hbeo.render.torch_datasets`), whose streamed poses are drawn on the host,
ahead in worker processes on a GPU (:mod:`~hbeo.render.posedraws`).
Camera intrinsics and frames are defined once in :mod:`hbeo.conventions`.

May import: the foundation modules, :mod:`hbeo.data` and :mod:`hbeo.subspace`.
"""
