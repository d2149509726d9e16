"""Variance-based sensitivity: Sobol indices, Shapley effects and their ranking next to the worst case.

- :mod:`~prp3mc.sobol.indices` — :func:`sobol_indices` and :class:`SobolResult`, the public entry.
- :mod:`~prp3mc.sobol.saltelli` — Saltelli's design and SALib's estimators, vectorised over poses.
- :mod:`~prp3mc.sobol.shapley` — Shapley effects (defined for correlated inputs too).
- :mod:`~prp3mc.sobol.closed_form` — exact indices and Shapley effects of the linear outputs, the
  oracle of the estimates.
- :mod:`~prp3mc.sobol.ranking` — every input and group ranked next to its worst-case share.

Imports the worst case (for the ranking), the model, kinematics and the foundations.
"""
