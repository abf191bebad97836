"""The paper's experiments (Sec. IV): evaluation protocol, tables, figures, notebooks, report.

- :mod:`~hbeo.reproduction.evaluate`: scoring one method on rendered test views (the metrics dict);
- :mod:`~hbeo.reproduction.protocol`: which settings each notebook evaluates, on how many objects,
  and the one cached per-run :func:`~hbeo.reproduction.protocol.evaluation` the notebooks call;
- :mod:`~hbeo.reproduction.tables`: the paper's tables and claims, and writing tables to a run;
- :mod:`~hbeo.reproduction.figures`: voxel pictures, galleries, axis panels, writing figures;
- :mod:`~hbeo.reproduction.voxelization`, :mod:`~hbeo.reproduction.eigenobjects`,
  :mod:`~hbeo.reproduction.renderings`, :mod:`~hbeo.reproduction.training`: what notebooks 01-04
  show about the run's grids, subspace, rendered sets and model;
- :mod:`~hbeo.reproduction.paper_figures`: the figures of notebooks 05-07;
- :mod:`~hbeo.reproduction.notebooks`: running the numbered notebooks with papermill;
- :mod:`~hbeo.reproduction.provenance`: the run's ``manifest.json``;
- :mod:`~hbeo.reproduction.report`: ``paper/REPRODUCTION.md``.

Every file of a run is named by :class:`hbeo.rundir.RunDir`.

May import: everything below it (foundation, data, subspace, render, model, baselines); only
:mod:`hbeo.cli` imports it.
"""
