"""The exact worst case of the linear model over a budget's box.

- :mod:`~prp3mc.worstcase.envelope` — :func:`worst_case`, :class:`WorstCaseResult` and the batched maxima,
  the public entry.
- :mod:`~prp3mc.worstcase._kernel` — the fused compiled envelope kernel (numba).
- :mod:`~prp3mc.worstcase.crosscheck` — the paper's global optimiser on the exact chain, as a cross-check.

Imports the model, kinematics and the foundations.
"""
