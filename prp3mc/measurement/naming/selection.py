"""Naming the effects the model misses, with selection that can change its mind.

Naming
------
Every model, null and alternative, holds the nuisances (registration,
drift) and the fitted repeatable fraction ``r``. At each step every
testable candidate is scored by its likelihood ratio (LR) at the current
covariance; the strongest few are refitted with ``r`` and the spread
factors re-profiled and the best is accepted only if that LR passes chi2(1)
at level ``alpha / K`` (Bonferroni over the K candidates tried). After each
acceptance:

- **exchange**: the systematic set is replaced by the best set of its size
  (every set of up to three effects is compared, larger sets by exchange
  moves, :mod:`~prp3mc.measurement.naming.subsets`), so an early wrong pick is
  replaced once a later effect explains what misled it;
- **backward**: an effect whose removal LR falls below the chi2(1) quantile
  at ``alpha`` is dropped.

Aliases are computed given the final model: another candidate is an alias
of a named effect when swapping it in leaves the fit within the chi2(1)
99 % quantile, and a whole set of the same size that fits as well makes the
members it replaces aliases too. An effect is ``identified`` only when no
set of the same size explains the data as well. Effects whose signature
vanishes over the campaign are invisible; effects whose signature lies in
the span of the nuisances are *confounded* (with registration or drift);
neither is ever named.

A cyclic screw error has two parameters (its phasor): its likelihood ratios
are put on the chi2(1) scale at their p-values
(:func:`~prp3mc.measurement.estimation.likelihood.chi2_equivalent`), so every threshold above
holds for it as it stands; its value is its amplitude, with the phase beside
it and an interval that covers near zero (:mod:`~prp3mc.measurement.estimation.cyclic`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..estimation.likelihood import chi2_equivalent
from ..forward.signatures import effect
from ..estimation.likelihood import Engine, Fit
from .named import NamedEffect
from .subsets import Gram

__all__ = ["select", "name_effects", "names_in", "effect_values", "STEP_COLUMNS"]

#: Most candidates refitted with r and the spreads re-profiled at each step.
_JOINT = 3
#: Columns of the selection's ``steps`` table.
STEP_COLUMNS = ["candidate", "lr", "estimate", "lr_joint", "step", "threshold", "accepted"]


def names_in(engine: Engine, fit: Fit) -> list[str]:
    """Names of the effects in ``fit``'s model: systematic ones, then spreads."""
    return [engine.systematic[j].name for j in fit.sys] + list(fit.factors)


def effect_values(engine: Engine, fit: Fit) -> dict:
    """Named effects of ``fit``: systematic values (a cyclic error's phasor) and spread bounds, name -> value in
    the effect's unit."""
    values = engine.values(fit)
    return {n: (fit.factors[n] * engine.spread_ref[n] if n in fit.factors else values[n])
            for n in names_in(engine, fit)}


def _lr(name: str, lr: float) -> float:
    """A likelihood ratio of adding or removing effect ``name`` on the chi2(1) scale (its p-value kept)."""
    return float(chi2_equivalent(max(lr, 0.0), effect(name).dof))


def _with(engine: Engine, fit: Fit, name: str, r: float | None = None) -> Fit:
    """Refit ``fit``'s model with effect ``name`` added (``r`` re-profiled unless given)."""
    if effect(name).systematic:
        return engine.refit(fit.sys + (engine.sys_index(name),), fit.factors, r, start_r=fit.r)
    return engine.refit(fit.sys, {**fit.factors, name: 1.0}, r, start_r=fit.r)


def _without(engine: Engine, fit: Fit, name: str) -> Fit:
    """Refit ``fit``'s model with effect ``name`` removed (``r`` re-profiled)."""
    if effect(name).systematic:
        j = engine.sys_index(name)
        return engine.refit(tuple(s for s in fit.sys if s != j), fit.factors, start_r=fit.r)
    return engine.refit(fit.sys, {k: v for k, v in fit.factors.items() if k != name}, start_r=fit.r)


def _scan(engine: Engine, fit: Fit) -> pd.DataFrame:
    """LR and estimate of adding every testable candidate to ``fit`` at its covariance (spreads: r fixed)."""
    lr, est = engine.score_systematic(fit)
    rows = [{"candidate": e.name, "lr": float(lr[j]), "estimate": float(est[j])}
            for j, e in enumerate(engine.systematic) if np.isfinite(lr[j])]
    for e in engine.spreads:
        if e.name in fit.factors:
            continue
        trial = engine.refit(fit.sys, {**fit.factors, e.name: 1.0}, fit.r, free=(e.name,))
        rows.append({"candidate": e.name, "lr": max(2.0 * (trial.loglik - fit.loglik), 0.0),
                     "estimate": float(trial.factors[e.name] * engine.spread_ref[e.name])})
    return pd.DataFrame(rows, columns=["candidate", "lr", "estimate"])


def _exchange(engine: Engine, fit: Fit) -> Fit:
    """Replace the systematic set by the best set of its size at the fit's covariance, until stable."""
    for _ in range(3):
        gram = Gram(engine, fit)
        S, g = gram.best(fit.sys)
        if set(S) == set(fit.sys) or g <= gram.gain(fit.sys) + 1e-9:
            break
        fit = engine.refit(tuple(S), fit.factors, start_r=fit.r)
    return fit


def select(engine: Engine, base: Fit, alpha: float, max_effects: int) -> tuple[Fit, dict, pd.DataFrame]:
    """Forward selection with exchange and backward moves from ``base`` (see the module notes).

    Returns
    -------
    fit : Fit
        The model with the accepted effects.
    accepted : dict
        Name -> ``step, threshold, n_candidates`` of the step that named it.
    steps : DataFrame
        Every candidate's ``lr`` (at the step's covariance) and ``estimate``
        at every ``step``, ``lr_joint`` (r and spreads re-profiled) for the
        strongest, the step's ``threshold`` and whether it was ``accepted``.
    """
    fit = base
    accepted: dict[str, dict] = {}
    step_rows = []
    from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
    drop_level = float(chi2.isf(alpha, 1))
    for step in range(1, max_effects + 1):
        scan = _scan(engine, fit)
        if scan.empty:
            break
        K = len(scan)
        threshold = float(chi2.isf(alpha / K, 1))
        scan = scan.sort_values("lr", ascending=False, ignore_index=True)
        # the LR with r and spreads re-profiled is at least the scan's: refit the strongest, and the next
        # ones only when it fails (a repeatable fraction fitted high may hide an effect's pose pattern)
        trials, joint = {}, {}
        for name in scan["candidate"].head(_JOINT):
            trials[name] = _with(engine, fit, name)
            joint[name] = _lr(name, 2.0 * (trials[name].loglik - fit.loglik))
            if joint[name] > threshold:
                break
        best = max(joint, key=joint.get)
        scan = scan.assign(lr_joint=scan["candidate"].map(joint), step=step, threshold=threshold,
                           accepted=scan["candidate"] == best)
        passed = joint[best] > threshold
        if not passed:
            step_rows.append(scan.assign(accepted=False))
            break
        step_rows.append(scan)
        evidence = {"step": step, "threshold": threshold, "n_candidates": K}
        before = set(names_in(engine, fit))
        fit = _exchange(engine, trials[best])
        for name in set(names_in(engine, fit)) - before:
            accepted[name] = dict(evidence)
        dropped = True
        while dropped:
            dropped = False
            for name in names_in(engine, fit):
                trial = _without(engine, fit, name)
                if _lr(name, 2.0 * (fit.loglik - trial.loglik)) < drop_level:
                    fit, dropped = trial, True
                    break
        accepted = {k: v for k, v in accepted.items() if k in names_in(engine, fit)}
    steps = pd.concat(step_rows, ignore_index=True) if step_rows else pd.DataFrame(columns=STEP_COLUMNS)
    return fit, accepted, steps[STEP_COLUMNS]


def name_effects(engine: Engine, fit: Fit, accepted: dict) -> tuple[NamedEffect, ...]:
    """The effects in ``fit``'s model with values, 95 % intervals and aliases given the final model."""
    from scipy.stats import chi2
    q_alias = float(chi2.ppf(0.99, 1))
    named = []
    gram = Gram(engine, fit)
    S = tuple(fit.sys)
    alternatives = gram.alternatives(S, q_alias) if S else []
    top = gram.gain(S)
    n_obs = 3 * engine.M
    for name in names_in(engine, fit):
        ev = dict(accepted[name])
        dof = effect(name).dof
        lr_raw = max(2.0 * (fit.loglik - _without(engine, fit, name).loglik), 0.0)
        lr = _lr(name, lr_raw)
        alias_sets = []
        if name in fit.factors:
            aliases = []
            for other in engine.spreads:
                if other.name in fit.factors:
                    continue
                factors = {k: v for k, v in fit.factors.items() if k != name}
                trial = engine.refit(fit.sys, {**factors, other.name: 1.0}, fit.r)
                if trial.loglik >= fit.loglik - q_alias / 2:
                    aliases.append(other.name)
        else:
            j = engine.sys_index(name)
            rest = [s for s in S if s != j]
            swaps = [c for c in gram.eligible if c not in S and gram.gain(rest + [c]) >= top - q_alias]
            alias_sets = [alt for alt in alternatives if j not in alt]
            aliases = [engine.systematic[c].name for c in swaps]
            for alt in alias_sets:
                aliases += [engine.systematic[c].name for c in alt if c not in S]
            aliases = list(dict.fromkeys(aliases))
        value, ci = engine.estimate(fit, name)
        phase = None
        alias_fits = {}
        for alias in aliases:
            trial = _with(engine, _without(engine, fit, name), alias, r=fit.r)
            a_value, a_ci = engine.estimate(trial, alias)
            alias_fits[alias] = {"value": a_value, "unit": effect(alias).unit, "ci95": list(a_ci),
                                 "nuisance": engine.nuisances(trial)}
        p = float(chi2.sf(lr, 1))
        ev.update(lr=float(lr), p_bonferroni=min(1.0, ev["n_candidates"] * p),
                  delta_bic=float(lr_raw - dof * np.log(n_obs)), identified=not aliases, alias_fits=alias_fits,
                  alternative_sets=[[engine.systematic[c].name for c in alt] for alt in alias_sets])
        if effect(name).dof == 2:                               # a cyclic error: its phasor
            cyc = engine.phasor(fit, name)
            phase = cyc["phase_deg"]
            ev.update(lr_df2=float(lr_raw), phasor_mm=[cyc["phasor"].real, cyc["phasor"].imag],
                      phasor_cov_mm2=cyc["cov"].tolist(),
                      amplitude_interval="profile likelihood ratio with Neyman critical values (covers near 0)")
        if name in fit.factors:
            ev.update(budget_value=engine.spread_ref[name],
                      direction="larger" if fit.factors[name] > 1 else "smaller")
        elif name in engine.budget.effects and phase is not None:   # a correction to the budget's cyclic error
            old = engine.budget.effects[name]
            total = engine.phasor(fit, name, offset=old.model_value)
            ev.update(budget_effect=old.value, budget_phase_deg=old.phase_deg, total=total["amplitude"],
                      total_phase_deg=total["phase_deg"], total_ci95=list(total["ci"]))
        elif name in engine.budget.effects:                # a correction to the budget's value
            ev.update(budget_effect=engine.budget.effects[name].value,
                      total=engine.budget.effects[name].value + float(value))
        named.append(NamedEffect(name, float(value), effect(name).unit, (float(ci[0]), float(ci[1])),
                                 tuple(aliases), ev, phase))
    return tuple(named)
