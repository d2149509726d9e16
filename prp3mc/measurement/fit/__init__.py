"""The discrepancy workflow: which effects the measured campaign shows that the model lacks.

- :mod:`~prp3mc.measurement.fit.signatures` — the effect library's signatures at the campaign's poses.
- :mod:`~prp3mc.measurement.fit.prediction` — the predicted distribution of every measurement.
- :mod:`~prp3mc.measurement.fit.nuisance` — registration and drift of the instrument.
- :mod:`~prp3mc.measurement.fit.likelihood` — the likelihood engine (fits with and without effects,
  the repeatable fraction of the budget's errors).
- :mod:`~prp3mc.measurement.fit.outliers` — gross errors at a stated family-wise false-alarm rate.
- :mod:`~prp3mc.measurement.fit.subsets` — best subsets and alias sets of systematic effects.
- :mod:`~prp3mc.measurement.fit.selection` — naming effects with exchange moves, aliases.
- :mod:`~prp3mc.measurement.fit.relinearise` — the exact chain linearised about an estimate (Gauss-Newton).
- :mod:`~prp3mc.measurement.fit.identify` — gross errors and names, relinearised until stable; the linearity guard.
- :mod:`~prp3mc.measurement.fit.confounds` — what a campaign cannot tell apart (``confounded``).
- :mod:`~prp3mc.measurement.fit.cyclic` — a cyclic screw error's amplitude interval (covers near 0).
- :mod:`~prp3mc.measurement.fit.diagnostics` — the tests, the one verdict and the gap.
- :mod:`~prp3mc.measurement.fit.holdout` — the gap on poses left out of the fit.
- :mod:`~prp3mc.measurement.fit.updated` — the updated model and what a controller can compensate.
- :mod:`~prp3mc.measurement.fit.accuracy` — predicted accuracy: original, updated, compensated.
- :mod:`~prp3mc.measurement.fit.results` — :class:`DiscrepancyResult` and the named effects.
- :mod:`~prp3mc.measurement.fit.workflow` — :func:`discrepancy`, the whole pipeline.
"""
