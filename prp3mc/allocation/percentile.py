"""The percentile spec of an allocation: decided on the exact distribution, searched along the screen.

A choice meets ``spec_percentile = q`` with position spec S when, at every
pose of the region, the q-quantile of the position error is at most S, that
is ``P(|(dx, dy)| > S) <= 1 - q/100``. :class:`PercentileCheck` decides it:

- ``exact`` (inputs independent): the exceedance from the exact distribution
  of the linear model (:func:`~prp3mc.stackup.exact_yield`), at the poses
  whose worst case passes S (elsewhere it is 0), with its guaranteed error
  bound: met when ``exceedance + bound <= 1 - q/100`` at every pose
  (the bound is asked for at a thousandth of ``1 - q/100``);
- ``monte_carlo`` (a budget with a ``[correlation]`` table, which the exact
  engine does not take, or a choice whose legs have too few continuous laws
  for the engine's series): Monte Carlo with the budget's Gaussian copula, met
  when the upper end of the percentile's 95 % interval is at most S at every
  pose (the check is then statistical, at that level).

:func:`percentile_least_cost` searches with it. The closed-form normal
screen of :mod:`~prp3mc.allocation.search` is no bound of the exact quantile
(it errs both ways: too high for sums of a few uniform terms, too low where a
law is cut at k·sd), so it only proposes: the least-cost choice within
``f * S`` on the screen, with the factor f bisected on the check's answers
(phase 1). With the exact method, where the menu is small enough, every
cheaper choice that valid bounds leave is then checked in cost order (phase
2): the first one met is the least-cost choice, *proven* (``proven``); the valid bounds are the
worst-case specs and, with bounded laws, the second moment: with W the worst
case and ``E = E|(dx, dy)|^2``, ``P(|(dx, dy)| > S) >= (E - S^2) / (W^2 - S^2)``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .._rng import child_seed
from ..errors import BudgetError, Prp3mcWarning
from ..montecarlo.propagation import monte_carlo
from ..stackup import exact_yield
from ..units import MM2UM
from .search import Problem, least_cost

__all__ = ["PercentileCheck", "percentile_least_cost", "METHODS"]

#: How a percentile spec is decided, by method.
METHODS = {"exact": "exact distribution of the linear model (prp3mc.stackup): exceedance + its error bound "
                    "<= 1 - q/100 at every pose",
           "monte_carlo": "Monte Carlo with the budget's Gaussian copula (its [correlation] table; the exact "
                          "engine assumes independent inputs): upper end of the percentile's 95 % interval <= S "
                          "at every pose"}
#: Screen factors tried by phase 1 (the least-cost choice within f * S on the normal screen, f bisected).
_PHASE1_CHECKS = 10
#: Phase 2 runs when the menu has at most this many choices times inputs, and checks at most _CERTIFY choices.
_ENUMERATE_ELEMENTS = 1 << 24
_CERTIFY = 400
_CHUNK_ELEMENTS = 1 << 18


class PercentileCheck:
    """Whether a choice meets the percentile spec at every pose of a :class:`Problem`.

    Parameters
    ----------
    geometry : Geometry
    problem : Problem
    spec_mm : float
        S, mm.
    percentile : float
        q, in %.
    n_samples, seed : int
        The Monte Carlo check's samples and root seed (method ``monte_carlo``).

    Attributes
    ----------
    method : str
        ``exact`` or ``monte_carlo`` (a correlated budget), see :data:`METHODS`.
    checks : int
        Choices decided (each once: answers are kept).
    """

    def __init__(self, geometry, problem: Problem, spec_mm: float, percentile: float, n_samples: int, seed: int):
        self.geometry, self.pb, self.S, self.q = geometry, problem, float(spec_mm), float(percentile)
        self.alpha = 1.0 - self.q / 100.0
        self.n_samples, self.seed = int(n_samples), int(seed)
        fixed = problem.fixed_budget
        self.method = "monte_carlo" if fixed is not None and fixed.correlated else "exact"
        self.bounded = not any(c.law.kind == "normal" for name in problem.inputs for c in problem.menu.classes_of(name))
        self.checks, self._answers, self._active = 0, {}, np.zeros(0, dtype=int)

    def __call__(self, idx) -> bool:
        """Whether class indices ``idx`` (J,) meet the spec (kept: each choice is decided once)."""
        return self.record(idx)["met"]

    def record(self, idx) -> dict:
        """The decision on ``idx``: ``met``, ``value`` (the largest exceedance + bound, or the largest upper
        end of the percentile's interval, mm), ``pose`` (its index) and ``method``."""
        key = tuple(int(v) for v in idx)
        if key not in self._answers:
            self.checks += 1
            self._answers[key] = self._exact(key) if self.method == "exact" else self._monte_carlo(key)
        return self._answers[key]

    def _budget(self, key):
        return self.pb.budget({n: self.pb.class_name(j, m) for j, (n, m) in enumerate(zip(self.pb.inputs, key))})

    def _exact(self, key) -> dict:
        """The exact decision on ``key``: met when exceedance + bound <= 1 - q/100 at every pose of the grid
        whose worst case passes S (with bounded laws, else at every pose; elsewhere the exceedance is 0). The
        poses that refused earlier choices are tried first, only to refuse sooner: a choice they do not refuse
        is then decided on all of them."""
        wc = self.pb.envelopes(np.array(key))["position"][0]
        at = np.flatnonzero(wc > self.S) if self.bounded else np.arange(wc.size)
        if at.size == 0:                       # the worst case is within S everywhere: nothing exceeds
            return {"met": True, "value": 0.0, "pose": int(np.argmax(wc)), "method": "exact"}
        budget = self._budget(key)
        first = np.intersect1d(self._active, at)
        for poses in ((first,) if first.size else ()) + (at,):   # the poses that failed before, then all
            try:
                with warnings.catch_warnings():   # a bound above the target is in the decision: no warning
                    warnings.simplefilter("ignore", Prp3mcWarning)
                    r = exact_yield(self.geometry, budget, self.pb.poses[poses], spec_position_um=self.S * MM2UM,
                                    quantiles=False, target=min(1e-2, 1e-3 * self.alpha))
            except BudgetError:                # too few continuous laws for the series: Monte Carlo decides
                return self._monte_carlo(key)
            high = np.asarray(r.exceedance("position") + r.bound("position")).reshape(-1)
            k = int(np.argmax(high))
            record = {"met": bool(high[k] <= self.alpha), "value": float(high[k]), "pose": int(poses[k]),
                      "method": "exact"}
            if not record["met"]:
                self._active = np.union1d(self._active, [record["pose"]])
                return record
        return record

    def _monte_carlo(self, key) -> dict:
        mc = monte_carlo(self.geometry, self._budget(key), self.pb.poses, self.n_samples,
                         rng=child_seed(self.seed, 1000 + self.checks), percentiles=(self.q,))
        high = mc.position_pct_ci[:, 0, 1]
        k = int(np.argmax(high))
        return {"met": bool(high[k] <= self.S), "value": float(high[k]), "pose": k, "method": "monte_carlo"}


def _cost(problem: Problem, idx) -> float:
    return float(problem.cost[np.arange(len(idx)), idx].sum())


def percentile_least_cost(problem: Problem, limits: dict, check: PercentileCheck) -> tuple:
    """The least-cost choice meeting ``check`` and the worst-case ``limits`` (``phi``, if given).

    Returns
    -------
    idx : ndarray (J,) or None
        Class indices of the choice (None: none was found that meets the spec).
    nodes : int
        Candidates the screen's searches evaluated.
    proven : bool
        Whether phase 2 checked every cheaper choice the valid bounds leave
        (the choice is then the least-cost one meeting the check).
    """
    S = check.S
    nodes, best, answers = 0, None, {}

    def attempt(f: float):
        nonlocal nodes, best
        idx, n = least_cost(problem, {**limits, "screen": S * f})
        nodes += n
        if idx is None:
            return None
        seen = tuple(idx) in {choice for _, choice in answers.values()}
        met = check(idx)
        if met and (best is None or _cost(problem, idx) < _cost(problem, best)):
            best = idx
        answers[f] = (met, tuple(idx))
        return met, seen

    # phase 1: bracket the screen factor (met at lo, not met at hi), then bisect it geometrically
    lo = hi = None
    f, repeats = 1.0, 0
    for _ in range(_PHASE1_CHECKS):
        answer = attempt(f)
        if answer is None:                    # no choice meets the screen (or the worst-case specs) this tight
            break
        met, seen = answer
        repeats = repeats + 1 if seen else 0
        if repeats == 2:                      # the bracket holds the same two choices: nothing new between
            break
        if met:
            lo = f if lo is None else max(lo, f)
        else:
            hi = f if hi is None else min(hi, f)
        if hi is None:                        # met so far: loosen until the screen binds no more
            if f > 1.0 and answers[f][1] == answers[f / 2][1]:
                break
            f *= 2.0
        elif lo is None:
            f /= 2.0
        elif hi / lo < 1.0 + 1e-3:
            break
        else:
            f = math.sqrt(lo * hi)
    # phase 2: every cheaper choice the valid bounds leave, in cost order
    proven = False
    if check.method == "exact":
        cheaper = _cheaper(problem, limits, check, None if best is None else _cost(problem, best))
        if cheaper is not None:
            for idx in cheaper:
                if check(idx):
                    best = idx
                    break
            proven = True
    return best, nodes, proven


def _cheaper(problem: Problem, limits: dict, check: PercentileCheck, cost: float | None):
    """The choices cheaper than ``cost`` that the worst-case limits and the second-moment bound leave,
    (m, J) in cost order, or None when the menu is too large to list or more than ``_CERTIFY`` are left."""
    N, J = problem.poses.shape[0], len(problem.inputs)
    shape = tuple(int(n) for n in problem.n_classes)
    j = np.arange(J)
    if math.prod(shape) * J > _ENUMERATE_ELEMENTS:
        return None
    every = np.stack(np.unravel_index(np.arange(math.prod(shape)), shape), axis=1)
    costs = problem.cost[j, every].sum(axis=1)
    if cost is not None:
        every, costs = every[costs < cost * (1 - 1e-12)], costs[costs < cost * (1 - 1e-12)]
    every = every[np.argsort(costs, kind="stable")]
    px, py = problem.P[..., 0], problem.P[..., 1]
    fixed, left = problem.fixed, []
    step = max(1, _CHUNK_ELEMENTS // N)
    for s in range(0, len(every), step):           # cheapest first: stop once more are left than can be checked
        idx = every[s:s + step]
        env = problem.envelopes(idx)
        ok = np.ones(len(idx), dtype=bool)
        if limits.get("phi") is not None:
            ok &= env["phi"].max(axis=1) <= limits["phi"]
        if check.bounded:
            mu = (problem.mean[j, idx] @ problem.P.reshape(J, -1)).reshape(len(idx), N, 3) + fixed["mean"]
            second = (mu[..., 0] ** 2 + mu[..., 1] ** 2 + problem.var[j, idx] @ (px * px + py * py)
                      + fixed["cov"][:, 0, 0] + fixed["cov"][:, 1, 1])
            W2, S2 = env["position"] ** 2, check.S ** 2
            low = np.where(W2 > S2, (second - S2) / np.where(W2 > S2, W2 - S2, 1.0), 0.0)
            ok &= low.max(axis=1) <= check.alpha
        left.append(idx[ok])
        if sum(len(x) for x in left) > _CERTIFY:
            return None
    return np.concatenate(left) if left else np.zeros((0, J), dtype=int)
