"""Presenting the numbers: the paper's tables and figures, the run's report, manifest and book.

- :mod:`~hbeo.report.tables`: the paper's tables and claims (on one reading's evaluations), and writing tables to a run;
- :mod:`~hbeo.report.figures`: voxel pictures, galleries, axis panels, writing figures;
- :mod:`~hbeo.report.paper_figures`: the figures of notebooks 05-07;
- :mod:`~hbeo.report.model_table`: the validation / test table of a run's models (a block of docs/experiments.md);
- :mod:`~hbeo.report.experiments`: the model table's rows as specs (``experiments/``): list, run, regenerate;
- :mod:`~hbeo.report.provenance`: the run's ``manifest.json``;
- :mod:`~hbeo.report.reproduction_md`: ``REPRODUCTION.md`` (reported vs. reproduced);
- :mod:`~hbeo.report.readme`: the README's verdict and command table, and the documentation's generated blocks;
- :mod:`~hbeo.report.readings`: ``REPRODUCTION.md``'s section on the paper's claims under each reading of the
  view protocol;
- :mod:`~hbeo.report.completion_gap`: ``REPRODUCTION.md``'s section on HBEO's completion error taken apart, its
  table and notebook 06's figure of it;
- :mod:`~hbeo.report.seeds`: the spread over training seeds of runs that differ only in that seed;
- :mod:`~hbeo.report.compare`: whether two run folders' tables agree, the measured timing columns aside;
- :mod:`~hbeo.report.notebooks`: running the numbered notebooks with papermill;
- :mod:`~hbeo.report.book`: the run's static, offline HTML book.

Nothing here changes a number: the evaluation's cache key leaves this layer out
(:data:`hbeo.evaluation.protocol.PRESENTATION_LAYERS`). Every file of a run is named by
:class:`hbeo.rundir.RunDir`.

May import: everything below it (foundation, data, subspace, render, model, baselines, :mod:`hbeo.run`,
:mod:`hbeo.evaluation`); never :mod:`hbeo.lessons` or the command line.
"""
