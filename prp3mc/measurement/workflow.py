"""The discrepancy workflow: where model and measurement disagree, which effect is missing, the gap.

:func:`discrepancy` predicts every measurement
(:mod:`~prp3mc.measurement.prediction`), fits the model with the likelihood
engine (:mod:`~prp3mc.measurement.likelihood`), names missing effects by
forward selection (:mod:`~prp3mc.measurement.selection`), and diagnoses the
disagreement before and after and measures the gap
(:mod:`~prp3mc.measurement.diagnostics`). :func:`detectable_effect` plans a
campaign: how large an effect its layout can name.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import optimize, stats

from .._rng import resolve_rng
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from ..uncertainty.budget import Budget
from .campaign import Campaign, read_campaign, require_testable
from .diagnostics import diagnose, gap, is_unexplained
from .effects import effect
from .likelihood import Engine
from .prediction import noise_cov, predict
from .selection import DiscrepancyResult, name_effects, select

__all__ = ["discrepancy", "detectable_effect"]


def discrepancy(geometry: Geometry, budget: Budget, campaign, *, instrument_sigma_mm: float = 0.0,
                instrument_sigma_deg: float = 0.0, alpha: float = 0.01, alpha_unexplained: float = 0.05,
                max_effects: int = 6,
                n_bootstrap: int = 400,
                rng: "None | int | np.random.Generator" = None) -> DiscrepancyResult:
    """Find where model and campaign disagree, name the missing effects, close the gap.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        The model's random errors.
    campaign : Campaign, DataFrame or path
        SPEC §4 campaign; validated against ``geometry``.
    instrument_sigma_mm, instrument_sigma_deg : float
        Standard deviation of the measurement noise per coordinate.
    alpha : float
        Family-wise level of the naming steps (Bonferroni over candidates).
    alpha_unexplained : float
        Family-wise level (Bonferroni over its six tests) of the final test
        for disagreement that the named effects leave unexplained. It is
        looser than ``alpha`` because declaring a gap closed when structure
        remains is the costlier error: on simulated campaigns (30 seeds each)
        it flagged every local distortion outside the library, 1 of 30
        correct models and none of 30 correctly named hidden effects.
    max_effects : int
        Most effects named.
    n_bootstrap : int
        Parametric-bootstrap replicates for the null variances of the tests.
    rng : None, int or numpy.random.Generator
        Randomness of the bootstrap (Scientific Python SPEC 7); the integer
        seed used is recorded in the result.

    Returns
    -------
    DiscrepancyResult
    """
    t0 = time.perf_counter()
    seed, rng = resolve_rng(rng)
    if not (0 < alpha < 1 and 0 < alpha_unexplained < 1):
        raise BudgetError(f"alpha and alpha_unexplained must lie in (0, 1), got {alpha}, {alpha_unexplained}")
    campaign = require_testable(read_campaign(campaign, geometry))
    noise = noise_cov(instrument_sigma_mm, instrument_sigma_deg)
    engine = Engine(geometry, budget, campaign, noise)
    base = engine.fit((), {})
    fit, accepted, steps = select(engine, base, alpha, max_effects)
    named = name_effects(engine, fit, accepted)
    before = diagnose(engine, base, n_bootstrap, rng)
    after = diagnose(engine, fit, n_bootstrap, rng)
    unexplained = is_unexplained(after, alpha_unexplained)
    gap_doc = gap(engine, base, fit, before, after, unexplained)
    systematic = {engine.systematic[j].name: float(v) for j, v in zip(fit.sys, fit.theta)}
    effects_after = {**systematic, **{n: f * engine.spread_ref[n] for n, f in fit.factors.items()}}
    prediction = predict(geometry, budget, campaign, effects=effects_after,
                         instrument_sigma_mm=instrument_sigma_mm, instrument_sigma_deg=instrument_sigma_deg)
    return DiscrepancyResult(
        named_effects=named, unexplained=unexplained, gap=gap_doc, before=before, after=after, steps=steps,
        prediction_after=prediction, budget_after=prediction.budget, systematic=systematic,
        invisible=engine.invisible, structural_aliases=tuple(tuple(g) for g in engine.structural_aliases()),
        not_testable=engine.not_testable, campaign=campaign, geometry=geometry, budget=budget, seed=seed,
        n_bootstrap=n_bootstrap, alpha=alpha, alpha_unexplained=alpha_unexplained,
        instrument_sigma_mm=instrument_sigma_mm,
        instrument_sigma_deg=instrument_sigma_deg, wall_time_s=time.perf_counter() - t0)


def detectable_effect(geometry: Geometry, budget: Budget, campaign: Campaign, name: str, *,
                      power: float = 0.9, alpha: float = 0.01, instrument_sigma_mm: float = 0.0,
                      instrument_sigma_deg: float = 0.0) -> float:
    """Smallest |value| of a systematic effect that a campaign names with probability ``power``.

    For planning: simulate a campaign without effects (only its layout
    matters: poses, repeats, directions, temperatures) and ask how large an
    effect it would detect. Uses the non-central chi2(1) law of the LR at
    the Bonferroni threshold over the library's testable candidates;
    aliasing is not accounted for.

    Returns
    -------
    float
        In the effect's unit (SPEC §5); inf if the campaign cannot see it.
    """
    eff = effect(name)
    if not eff.systematic:
        raise BudgetError(f"{name}: detectable_effect handles systematic effects; simulate spreads instead")
    engine = Engine(geometry, budget, read_campaign(campaign, geometry),
                     noise_cov(instrument_sigma_mm, instrument_sigma_deg))
    if name not in [e.name for e in engine.systematic]:
        return float("inf")
    K = len(engine.systematic) + len(engine.spreads)
    threshold = stats.chi2.isf(alpha / K, 1)
    g = engine.fit((), {}).Gw[:, :, engine.sys_index(name)]
    info = float(np.sum(g * g))                                    # Fisher information per unit^2
    lam = optimize.brentq(lambda nc: stats.ncx2.sf(threshold, 1, nc) - power, 1e-6, 1e4)
    return float(np.sqrt(lam / info))
