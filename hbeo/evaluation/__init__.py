"""Computing the paper's numbers (Sec. IV): the evaluation protocol, metrics, sweeps and statistics.

- :mod:`~hbeo.evaluation.evaluate`: scoring one method on rendered views (the metrics dict);
- :mod:`~hbeo.evaluation.protocol`: which settings each notebook evaluates, on how many objects and
  views, the cache key of an evaluation and the one cached per-run evaluation the notebooks call;
- :mod:`~hbeo.evaluation.sweep`: scoring many settings of one model on the same validation queries;
- :mod:`~hbeo.evaluation.paired`: paired statistics over objects (bootstrap, contrasts, claim verdicts);
- :mod:`~hbeo.evaluation.intervals`: bootstrap intervals over objects;
- :mod:`~hbeo.evaluation.flips`: where large pose errors point (front/back flips about the up axis or not);
- :mod:`~hbeo.evaluation.decompose`: HBEO's completion error taken apart (threshold scan on validation, ceilings,
  coefficient R², class/pose and elevation splits, empty completions);
- :mod:`~hbeo.evaluation.method`: each method's display label.

Nothing here draws, formats or writes a report: that is :mod:`hbeo.report`, one layer up.

May import: everything below it (foundation, data, subspace, render, model, baselines, :mod:`hbeo.run`);
never :mod:`hbeo.report`, :mod:`hbeo.lessons` or the command line.
"""
