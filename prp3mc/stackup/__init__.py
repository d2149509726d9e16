"""The exact distribution of the linear stack-up: yields against a spec without sampling.

The linear model's pose error is a sum of independent scalar terms, each a
column times a budget input, an effect's factor or a clearance term
(:class:`~prp3mc.model.linear.TermLaw`). Its distribution follows from the
terms' characteristic functions, which are closed forms for every law prp3mc
has; this package inverts them with a guaranteed error bound:

- :mod:`~prp3mc.stackup.exceedance` — :func:`exact_yield`, the public entry:
  P(position > S), P(``|dphi|`` > Z), P(either) and the quantiles, per pose;
- :mod:`~prp3mc.stackup.result` — :class:`YieldResult`, the Ppk of an exceedance, the quantiles' levels
  (:data:`~prp3mc.stackup.result.QUANTILE_LEVELS`) and the outputs' names;
- :mod:`~prp3mc.stackup.enumeration` — a budget of discrete classes only (no density): its finitely many
  values enumerated;
- :mod:`~prp3mc.stackup.conditional` — P(either) of a budget of independent legs, by conditioning on two
  legs and integrating the third through its CDF (where the 3-D series does not converge);
- :mod:`~prp3mc.stackup.gaussian` — correlated normal inputs made independent terms of the same joint
  law (and why other correlated laws are refused);
- :mod:`~prp3mc.stackup.characteristic` — each law's characteristic function and
  a decreasing bound of its modulus;
- :mod:`~prp3mc.stackup.lattice` — the alias-free lattice of each channel (dphi,
  the position, both) at a batch of poses;
- :mod:`~prp3mc.stackup.truncation` — which lattice points to sum, and the bound
  of what is left out;
- :mod:`~prp3mc.stackup.series` — the sums, the quantiles and the per-pose driver (compiled);
- :mod:`~prp3mc.stackup._special` — the Bessel functions the kernels call.

Imports kinematics, model and the foundations, never study, measurement or reports.
"""

from .exceedance import DEFAULT_TARGET, exact_yield
from .result import OUTPUTS, QUANTILE_LEVELS, YieldResult, ppk

__all__ = ["exact_yield", "YieldResult", "ppk", "DEFAULT_TARGET", "QUANTILE_LEVELS", "OUTPUTS"]
