"""Monte Carlo propagation of a budget through the linear model, streamed in bounded memory.

- :mod:`~prp3mc.montecarlo.propagation` — :func:`monte_carlo` and :class:`MonteCarloResult`
  (statistics with confidence intervals), the public entry.
- :mod:`~prp3mc.montecarlo._stream` — sample blocks, moments by segments, exact order statistics.
- :mod:`~prp3mc.montecarlo._sampler`, :mod:`~prp3mc.montecarlo._kernel`,
  :mod:`~prp3mc.montecarlo._select` — its compiled kernels (numba): sampling, pose values, selection.

Imports the model, kinematics and the foundations.
"""
