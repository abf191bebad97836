"""What the numbered notebooks show and explain: one module of teaching helpers per notebook topic.

- :mod:`~hbeo.lessons.voxelization` (01), :mod:`~hbeo.lessons.eigenobjects` (02),
  :mod:`~hbeo.lessons.renderings` (03), :mod:`~hbeo.lessons.training` (04): what the notebooks show about
  the run's grids, subspace, rendered sets and model;
- :mod:`~hbeo.lessons.yourdepth` (08): a user's depth image through the model, step by step;
- :mod:`~hbeo.lessons.viewer` (06, 08): rotatable offline 3-D views (plotly.js embedded).

May import: everything below it (up to :mod:`hbeo.evaluation` and :mod:`hbeo.report`, whose figure
helpers it uses); only the command line and the notebooks import it.
"""
