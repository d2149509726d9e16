"""Measurement: campaigns of measured poses and the discrepancy workflow.

- :mod:`~prp3mc.measurement.campaign` — reading and validating campaign CSV files.
- :mod:`~prp3mc.measurement.simulate` — simulated campaigns with hidden effects (exact chain).
- :mod:`~prp3mc.measurement.effects` — the effect library and its signatures.
- :mod:`~prp3mc.measurement.prediction` — the predicted distribution of every measurement.
- :mod:`~prp3mc.measurement.nuisance` — registration and drift of the instrument (nuisances).
- :mod:`~prp3mc.measurement.likelihood` — the likelihood engine (fits with and without effects,
  the repeatable fraction of the budget's errors).
- :mod:`~prp3mc.measurement.outliers` — gross errors at a stated family-wise false-alarm rate.
- :mod:`~prp3mc.measurement.subsets` — best subsets and alias sets of systematic effects.
- :mod:`~prp3mc.measurement.diagnostics` — the tests, the one verdict and the gap.
- :mod:`~prp3mc.measurement.selection` — naming effects with exchange moves, aliases.
- :mod:`~prp3mc.measurement.relinearise` — the exact chain linearised about an estimate (Gauss-Newton).
- :mod:`~prp3mc.measurement.identify` — gross errors and names, relinearised until stable; the linearity guard.
- :mod:`~prp3mc.measurement.confounds` — what a campaign cannot tell apart (``confounded``), the ambiguous verdict.
- :mod:`~prp3mc.measurement.plan` — planning a campaign: D-optimal poses, interleaved order, approach directions.
- :mod:`~prp3mc.measurement.holdout` — the gap on poses left out of the fit (cross-validation by pose).
- :mod:`~prp3mc.measurement.updated` — the updated model: identified geometry, budgets with ``[effects]``,
  what a controller can compensate.
- :mod:`~prp3mc.measurement.accuracy` — predicted accuracy over the region: original, updated, compensated.
- :mod:`~prp3mc.measurement.results` — :class:`DiscrepancyResult` and the named effects.
- :mod:`~prp3mc.measurement.workflow` — :func:`discrepancy`, the whole workflow.

Imports uncertainty, kinematics and the foundations; never study or reports.
"""
