"""Uncertainty: error budgets and how they propagate to the pose error.

- :mod:`~prp3mc.uncertainty.laws`, :mod:`~prp3mc.uncertainty.budget` — catalogue-style laws, budgets, the catalogue.
- :mod:`~prp3mc.uncertainty.model` — the linear model of a budget at a set of poses, and its exact moments.
- :mod:`~prp3mc.uncertainty.montecarlo` — Monte Carlo statistics with confidence intervals.
- :mod:`~prp3mc.uncertainty.worstcase` — the exact worst-case envelope.
- Sobol indices: :mod:`~prp3mc.uncertainty.sobol` (the public entry),
  :mod:`~prp3mc.uncertainty.saltelli` (design and estimators), :mod:`~prp3mc.uncertainty.sobol_closed_form`,
  :mod:`~prp3mc.uncertainty.ranking` (Sobol next to the worst case).
- :mod:`~prp3mc.uncertainty.crosscheck` — the paper's optimiser on the exact chain, as a cross-check.

Imports kinematics and the foundations, never measurement, study or reports.
"""
