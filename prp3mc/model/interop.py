"""Hand a budget and results to other tools: SALib's other methods, OpenTURNS, xarray.

- :func:`salib_problem` and :func:`salib_model`: run any SALib method (Morris,
  FAST, RBD-FAST, delta moment-independent, PAWN...) on a prp3mc budget. The
  problem is the unit hypercube and the model maps unit samples through each
  law's inverse CDF, so every law of a budget (clearance discs, truncated
  normals, catalogue classes) is handled exactly; the indices of these
  methods do not change under such monotone input transforms (elementary
  effects are then per unit of probability).
- :func:`openturns_distribution`: the budget as an OpenTURNS joint
  distribution: its marginals, independent or joined by a ``NormalCopula``
  (needs ``pip install openturns``).
- :func:`to_xarray`: a result's tidy frame as an xarray Dataset over the
  poses (needs ``pip install xarray``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._result import POSE_COLUMNS
from ..errors import BudgetError, MissingDependencyError, ParameterError
from ..units import OUTPUTS, RAD2DEG
from .budget import Budget
from .laws import Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from .linear import linear_model

__all__ = ["salib_problem", "salib_model", "openturns_distribution", "to_xarray"]


def salib_problem(budget: Budget) -> dict:
    """A SALib problem for ``budget``: its factors (inputs, then backlash_i and thermal effects) on the unit hypercube.

    Returns
    -------
    dict
        ``{"num_vars": d, "names": [...], "bounds": [[0, 1]] * d}``; sample it
        with any SALib sampler and evaluate with :func:`salib_model`.
    """
    d = len(budget.factors)
    return {"num_vars": d, "names": list(budget.factors), "bounds": [[0.0, 1.0]] * d}


def salib_model(geometry, budget: Budget, poses, output: str = "position"):
    """The pose error of the linear model as a function of unit samples, for SALib.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    output : {"x", "y", "phi", "position"}
        dx (mm), dy (mm), dphi (deg) or the position-error norm (mm).

    Returns
    -------
    callable
        ``f(U)`` with ``U`` of shape (n, d) in [0, 1) (a SALib sample) returning
        the output, shape (..., n): (n,) for one pose.
    """
    if output not in OUTPUTS:
        raise ParameterError(f"unknown output {output!r} (choose from {', '.join(OUTPUTS)})")
    model = linear_model(geometry, budget, poses)

    def f(U: np.ndarray) -> np.ndarray:
        E = model.evaluate(budget.ppf(np.clip(U, 0.0, np.nextafter(1.0, 0.0))))       # (..., n, 3)
        if output == "position":
            return np.hypot(E[..., 0], E[..., 1])
        k = OUTPUTS.index(output)
        return E[..., k] * (RAD2DEG if output == "phi" else 1.0)

    return f


def _openturns_marginal(ot, law):
    if isinstance(law, Uniform):
        return ot.Uniform(law.lo, law.hi) if law.hi > law.lo else ot.Dirac(law.lo)
    if isinstance(law, Normal):
        return ot.Normal(law.mu, law.sd) if law.sd > 0 else ot.Dirac(law.mu)
    if isinstance(law, TruncNormal):
        lo, hi = law.support
        return ot.TruncatedNormal(law.center, law.sd_parent, lo, hi)
    if isinstance(law, Triangular):
        return ot.Triangular(law.lo, law.mode, law.hi)
    if isinstance(law, Disc):                        # pdf 2 r / R^2 on [0, R]: Beta(2, 1) on [0, R]
        return ot.Beta(2.0, 1.0, 0.0, law.radius) if law.radius > 0 else ot.Dirac(0.0)
    if isinstance(law, Discrete):
        return ot.UserDefined(ot.Sample([[v] for v in law.values]), ot.Point(law.weights))
    raise BudgetError(f"no OpenTURNS counterpart for a {type(law).__name__} law")  # pragma: no cover


def openturns_distribution(budget: Budget):
    """The budget as an OpenTURNS joint distribution, in factor order.

    Each marginal carries the factor's name as its description (the inputs,
    then the backlash_i and thermal effects). The marginals are independent,
    or, for a correlated budget, joined by OpenTURNS' ``NormalCopula`` of the
    budget's rank correlations (converted to the latent correlation by
    OpenTURNS' own ``GetCorrelationFromSpearmanCorrelation``). Requires the
    optional ``openturns`` package.
    """
    try:
        import openturns as ot
    except ImportError:
        raise MissingDependencyError("openturns", "pip install openturns") from None
    marginals = []
    for name, law in budget.factor_laws.items():
        m = _openturns_marginal(ot, law)
        m.setDescription([name])
        marginals.append(m)
    joint = getattr(ot, "JointDistribution", None) or ot.ComposedDistribution
    copula = budget.copula
    if copula is None:
        dist = joint(marginals)
    else:
        D = len(marginals)
        spearman = ot.CorrelationMatrix(D)
        for a, i in enumerate(copula.index):
            for b, j in enumerate(copula.index[:a]):
                spearman[i, j] = float(copula.spearman[a, b])
        dist = joint(marginals, ot.NormalCopula(ot.NormalCopula.GetCorrelationFromSpearmanCorrelation(spearman)))
    dist.setDescription(list(budget.factors))
    return dist


_LABELS = ("output", "statistic", "name", "term", "kind")


def to_xarray(result):
    """A result's :meth:`to_frame` as an ``xarray.Dataset`` indexed by pose and labels.

    Dimensions: the pose columns (``x_mm``, ``y_mm``, ``phi_deg``) and the
    label columns present (``output``, ``statistic``, ``name``...); data
    variables: the other columns (``value``, ``se``, ``ci_low``...). Requires
    the optional ``xarray`` package.
    """
    try:
        import xarray  # noqa: F401  (pandas' to_xarray needs it)
    except ImportError:
        raise MissingDependencyError("xarray", "pip install xarray") from None
    frame: pd.DataFrame = result.to_frame()
    index = [c for c in POSE_COLUMNS + _LABELS if c in frame.columns]
    return frame.set_index(index).to_xarray()
