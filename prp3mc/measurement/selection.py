"""Naming the effects the model misses, their aliases, and the results of the workflow.

Naming
------
Forward selection over the library: at each step every testable candidate
is added in turn to the current model; the best by likelihood ratio (LR) is
accepted only if its LR passes chi2(1) at level ``alpha / K`` (Bonferroni
over the K candidates tried). Candidates whose LR is within the chi2(1) 99 %
quantile of the best are its *aliases*: the campaign cannot tell them apart,
the named effect is then reported with ``identified: false`` and each alias
with its own value and interval. After each acceptance all accepted values
are refitted jointly and any accepted effect that is no longer significant
(LR of removal below the chi2(1) quantile at ``alpha``) is dropped. Effects
whose signature vanishes over the campaign (e.g. ``c_i`` and ``e_i`` when
theta_i = 0) are reported as invisible and never named. When no candidate
passes, remaining disagreement (six global, per-pose, spatial and
lack-of-fit tests at family-wise level ``alpha_unexplained``) sets
``unexplained``.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import pandas as pd
from scipy import stats

from .._result import freeze, interval_frame
from .._version import __version__
from ..kinematics.geometry import Geometry
from ..uncertainty.budget import Budget
from ..units import z_value
from .campaign import Campaign
from .diagnostics import Diagnosis
from .effects import effect
from .likelihood import Engine, Fit
from .prediction import Prediction, noise_cov

__all__ = ["NamedEffect", "DiscrepancyResult", "select", "name_effects"]

_Q_ALIAS = float(stats.chi2.ppf(0.99, 1))
#: Level of the intervals the workflow computes (``ci95``).
_LEVEL = 0.95
_EFFECT_COLUMNS = ["name", "value", "unit", "ci_low", "ci_high", "level", "aliases", "identified", "lr"]


def _thawed(value):
    """A frozen value as plain JSON-ready Python: mappings to dicts, tuples to lists."""
    if isinstance(value, (dict, MappingProxyType)):
        return {k: _thawed(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_thawed(v) for v in value]
    return value


@dataclass(frozen=True, slots=True)
class NamedEffect:
    """An effect the workflow added to the model.

    Attributes
    ----------
    name : str
    value : float
        In ``unit`` (SPEC §5).
    unit : str
    ci95 : (float, float)
    aliases : tuple of str
        Effects the campaign cannot tell apart from this one; if any, the
        effect is *not* identified (one of the set is missing).
    evidence : mapping
        ``lr, threshold, p_bonferroni, n_candidates, step, delta_bic,
        identified``, ``alias_fits`` (value and ci95 of each alias) and, for
        spreads, ``budget_value`` and ``direction``.
    """

    name: str
    value: float
    unit: str
    ci95: tuple
    aliases: tuple
    evidence: dict

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        lo, hi = self.ci95
        return (f"NamedEffect(name={self.name!r}, value={self.value:.6g}, unit={self.unit!r}, "
                f"ci95=[{lo:.6g}, {hi:.6g}], identified={not self.aliases})")

    def _row(self) -> dict:
        return {"name": self.name, "value": self.value, "unit": self.unit, "ci_low": self.ci95[0],
                "ci_high": self.ci95[1], "level": _LEVEL, "aliases": ", ".join(self.aliases),
                "identified": self.evidence["identified"], "lr": self.evidence["lr"]}

    def to_frame(self) -> pd.DataFrame:
        """One row: ``name, value, unit, ci_low, ci_high, level, aliases, identified, lr``."""
        return pd.DataFrame([self._row()], columns=_EFFECT_COLUMNS)

    def to_dict(self) -> dict:
        """The effect's entry in ``discrepancy.json`` (SPEC §6)."""
        return {"name": self.name, "value": self.value, "unit": self.unit, "ci95": list(self.ci95),
                "aliases": list(self.aliases), "evidence": _thawed(self.evidence)}


@dataclass(frozen=True, slots=True)
class DiscrepancyResult:
    """Outcome of :func:`discrepancy`.

    Attributes
    ----------
    named_effects : tuple of NamedEffect
        Empty when the model misses nothing the campaign can see.
    unexplained : bool
        Disagreement remains that no candidate explains.
    gap : mapping
        ``metric, before, after, null_level, null_sd, closed`` and the two
        channels (see :mod:`~prp3mc.measurement.diagnostics`).
    before, after : Diagnosis
        Disagreement under the budget alone and with the named effects.
    steps : DataFrame
        Every candidate's LR at every selection step.
    prediction_after : Prediction
        The corrected model's prediction.
    budget_after : Budget
        The budget with named spreads applied.
    systematic : mapping
        Named systematic effects, name -> value: the model's new parameters.
    invisible : tuple of str
        Effects whose signature vanishes over the campaign (never named).
    structural_aliases : tuple of tuple of str
        Groups of effects with collinear signatures over the campaign.
    not_testable : mapping
        Effects the campaign cannot test, with the reason.
    campaign : Campaign
        The validated campaign.
    geometry, budget
        What the analysis ran on.
    seed, n_bootstrap : int
    alpha : float
    alpha_unexplained : float
    instrument_sigma_mm, instrument_sigma_deg : float
    version : str
    wall_time_s : float
    """

    named_effects: tuple
    unexplained: bool
    gap: dict
    before: Diagnosis
    after: Diagnosis
    steps: pd.DataFrame
    prediction_after: Prediction
    budget_after: Budget
    systematic: dict
    invisible: tuple
    structural_aliases: tuple
    not_testable: dict
    campaign: Campaign
    geometry: Geometry
    budget: Budget
    seed: int
    n_bootstrap: int
    alpha: float
    alpha_unexplained: float
    instrument_sigma_mm: float
    instrument_sigma_deg: float
    version: str = __version__
    wall_time_s: float = 0.0

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        g = self.gap
        return (f"DiscrepancyResult(named={tuple(e.name for e in self.named_effects)}, "
                f"unexplained={self.unexplained}, gap={g['before']:.4g}->{g['after']:.4g}, "
                f"closed={g['closed']}, seed={self.seed})")

    def to_frame(self) -> pd.DataFrame:
        """One row per named effect: ``name, value, unit, ci_low, ci_high, level, aliases, identified, lr``.

        The interval is the 95 % one (``ci95``); :meth:`conf_int` gives others.
        """
        return pd.DataFrame([e._row() for e in self.named_effects], columns=_EFFECT_COLUMNS)

    def conf_int(self, level: float = 0.95) -> pd.DataFrame:
        """Confidence intervals of the named effects at ``level``.

        At 0.95 these are the ``ci95`` intervals found by the workflow. At
        another level they are computed again the same way on the fitted
        model (Wald intervals of the systematic values, clipped at 0 for
        backlash; profile-likelihood intervals of spreads), which rebuilds
        the campaign's likelihood engine (a fraction of a second for 400
        measurements).

        Parameters
        ----------
        level : float
            Confidence level in (0, 1).

        Returns
        -------
        DataFrame
            ``name, value, unit, ci_low, ci_high, level``, one row per named
            effect, in the effect's unit (SPEC §5).

        Raises
        ------
        ValueError
            ``level`` is not in (0, 1).
        """
        z_value(level)                                    # validates the level
        effects = self.named_effects
        cis = [e.ci95 for e in effects] if level == _LEVEL or not effects else _intervals(self, level)
        frame = pd.DataFrame({"name": [e.name for e in effects], "value": [e.value for e in effects],
                              "unit": [e.unit for e in effects]}, columns=["name", "value", "unit"])
        return interval_frame(frame, [ci[0] for ci in cis], [ci[1] for ci in cis], level)

    def to_dict(self) -> dict:
        """The ``discrepancy.json`` document of SPEC §6 (plus diagnostics)."""
        return {
            "named_effects": [e.to_dict() for e in self.named_effects],
            "unexplained": bool(self.unexplained),
            "gap": _thawed(self.gap),
            "tests": {"before": _thawed(self.before.summary), "after": _thawed(self.after.summary)},
            "invisible": list(self.invisible),
            "structural_aliases": [list(g) for g in self.structural_aliases],
            "not_testable": _thawed(self.not_testable),
            "campaign": {"source": self.campaign.source, "n_measurements": self.campaign.n_measurements,
                         "n_poses": self.campaign.n_poses},
            "geometry": self.geometry.name, "budget": self.budget.name,
            "instrument_sigma_mm": self.instrument_sigma_mm, "instrument_sigma_deg": self.instrument_sigma_deg,
            "alpha": self.alpha, "alpha_unexplained": self.alpha_unexplained, "seed": self.seed,
            "n_bootstrap": self.n_bootstrap,
            "version": self.version, "wall_time_s": self.wall_time_s,
        }


def _intervals(result: DiscrepancyResult, level: float) -> list[tuple[float, float]]:
    """Intervals at ``level`` of ``result``'s named effects, from its fitted model state."""
    engine = Engine(result.geometry, result.budget, result.campaign,
                    noise_cov(result.instrument_sigma_mm, result.instrument_sigma_deg))
    sys = tuple(engine.sys_index(name) for name in result.systematic)
    factors = {e.name: e.value / e.evidence["budget_value"] for e in result.named_effects
               if "budget_value" in e.evidence}
    fit = engine.fit(sys, factors)
    return [engine.estimate(fit, e.name, level)[1] for e in result.named_effects]


def _with(engine: Engine, fit: Fit, name: str) -> Fit:
    """Refit ``fit``'s model with effect ``name`` added."""
    if effect(name).systematic:
        return engine.refit(fit.sys + (engine.sys_index(name),), fit.factors)
    return engine.refit(fit.sys, {**fit.factors, name: 1.0})


def _without(engine: Engine, fit: Fit, name: str) -> Fit:
    """Refit ``fit``'s model with effect ``name`` removed."""
    if effect(name).systematic:
        j = engine.sys_index(name)
        return engine.refit(tuple(s for s in fit.sys if s != j), fit.factors)
    return engine.refit(fit.sys, {k: v for k, v in fit.factors.items() if k != name})


def _names_in(engine: Engine, fit: Fit) -> list[str]:
    """Names of the effects in ``fit``'s model: systematic ones, then spreads."""
    return [engine.systematic[j].name for j in fit.sys] + list(fit.factors)


def _scan(engine: Engine, fit: Fit, excluded: set) -> pd.DataFrame:
    """LR and estimate of adding every testable candidate to ``fit``."""
    lr, est = engine.score_systematic(fit)
    rows = [{"candidate": e.name, "lr": float(lr[j]), "estimate": float(est[j])}
            for j, e in enumerate(engine.systematic) if np.isfinite(lr[j]) and e.name not in excluded]
    for e in engine.spreads:
        if e.name in fit.factors or e.name in excluded:
            continue
        value, trial = engine.score_spread(fit, e.name)
        rows.append({"candidate": e.name, "lr": max(value, 0.0),
                     "estimate": float(trial.factors[e.name] * engine.spread_ref[e.name])})
    return pd.DataFrame(rows, columns=["candidate", "lr", "estimate"])



def select(engine: Engine, base: Fit, alpha: float, max_effects: int) -> tuple[Fit, dict, pd.DataFrame]:
    """Forward selection from ``base`` (see the module notes).

    Returns
    -------
    fit : Fit
        The model with the accepted effects.
    accepted : dict
        Name -> evidence of its acceptance (including its ``aliases``).
    steps : DataFrame
        Every candidate's ``lr`` and ``estimate`` at every ``step``, with the
        step's ``threshold`` and whether it was ``accepted``.
    """
    n_obs = 3 * engine.M
    fit = base
    accepted: dict[str, dict] = {}        # name -> evidence of its acceptance
    excluded: set = set()
    step_rows = []
    for step in range(1, max_effects + 1):
        scan = _scan(engine, fit, excluded)
        if scan.empty:
            break
        K = len(scan)
        threshold = float(stats.chi2.isf(alpha / K, 1))
        scan = scan.assign(step=step, threshold=threshold, accepted=False).sort_values("lr", ascending=False)
        best = scan.iloc[0]
        passed = best["lr"] > threshold
        if passed:
            aliases = scan.loc[(scan["lr"] > best["lr"] - _Q_ALIAS) & (scan["candidate"] != best["candidate"]),
                               "candidate"].tolist()
            scan.loc[scan.index[0], "accepted"] = True
            p = float(stats.chi2.sf(best["lr"], 1))
            accepted[best["candidate"]] = {
                "lr": float(best["lr"]), "threshold": threshold, "p_bonferroni": min(1.0, K * p),
                "n_candidates": K, "step": step, "delta_bic": float(best["lr"] - np.log(n_obs)),
                "aliases": aliases,
            }
            excluded.update(aliases + [best["candidate"]])
            fit = _with(engine, fit, best["candidate"])
            for name in [n for n in _names_in(engine, fit) if n != best["candidate"]]:
                drop = 2.0 * (fit.loglik - _without(engine, fit, name).loglik)
                if drop < stats.chi2.isf(alpha, 1):
                    fit = _without(engine, fit, name)
                    accepted.pop(name)
        step_rows.append(scan)
        if not passed:
            break
    steps = pd.concat(step_rows, ignore_index=True) if step_rows else pd.DataFrame(
        columns=["candidate", "lr", "estimate", "step", "threshold", "accepted"])
    return fit, accepted, steps


def name_effects(engine: Engine, fit: Fit, accepted: dict) -> tuple[NamedEffect, ...]:
    """The effects in ``fit``'s model with their values, 95 % intervals, aliases and evidence."""
    named = []
    for name in _names_in(engine, fit):
        ev = dict(accepted[name])
        aliases = ev.pop("aliases")
        value, ci = engine.estimate(fit, name)
        alias_fits = {}
        for alias in aliases:
            trial = _with(engine, _without(engine, fit, name), alias)
            a_value, a_ci = engine.estimate(trial, alias)
            alias_fits[alias] = {"value": a_value, "unit": effect(alias).unit, "ci95": list(a_ci)}
        ev.update(identified=not aliases, alias_fits=alias_fits)
        if name in fit.factors:
            ev.update(budget_value=engine.spread_ref[name],
                      direction="larger" if fit.factors[name] > 1 else "smaller")
        named.append(NamedEffect(name, float(value), effect(name).unit, (float(ci[0]), float(ci[1])),
                                 tuple(aliases), ev))
    return tuple(named)
