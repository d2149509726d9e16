"""The named model: gross errors set aside, effects named, the exact chain relinearised until stable.

One *pass* (:func:`name_pass`) works on the model linearised about one
point (:mod:`~prp3mc.measurement.estimation.relinearise`; the first is the nominal
geometry): it sets gross errors aside (:mod:`~prp3mc.measurement.estimation.outliers`),
names effects (:mod:`~prp3mc.measurement.naming.selection`) and tests every row
again under the named model.

:func:`identify` iterates passes (Gauss-Newton on the exact chain): after a
pass it evaluates the exact chain at the named values; when the pass's
linear model departs from it there by more than :data:`REMAINDER` (the
whitened energy of the difference, a log-likelihood ratio: it could move
no test), it linearises again about those values and runs a new pass from
scratch (gross errors and names found again), until the departure is below
:data:`REMAINDER` and the named model has not moved from the point's
(the exact chain at the named values and at the point's, the same within
:data:`REMAINDER`: an alias named instead of an effect with the same
signature, ``alpha_1`` for ``beta_1`` when ``a_1 = 0``, has not moved).
A large guide or base angle error is so named alone with its value, no
row set aside for the curvature the nominal model cannot follow, and the
registration fitted on the converged model.

Far from the nominal geometry Gauss-Newton can settle on a first-order alias
set instead of the effect (``alpha_1`` with a 30 deg ``psi_1`` for a 2 deg
``beta_1`` on the U-shape, once in 25 campaigns): when the passes named
several effects with aliases, the iteration restarts from each alias alone
and keeps the smallest model that fits as well (``_Passes.simpler``).

**The linearity guard.** The result is refused (nothing named, the verdict
says why and what to do) when the iteration does not settle in
:data:`MAX_PASSES` passes, when the exact chain cannot be solved at an
estimate (its closure does not converge, or passes a singularity), when
the effects named on every row still leave more than :data:`GROSS_SHARE`
of the rows standing out as gross errors, or when the chain is curved
across a named effect's interval (:data:`CURVATURE`: the Wald interval
needs the model linear there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..estimation import outliers as gross
from ...model.effects import amplitude_phase, components
from ..forward.signatures import effect
from ..estimation.likelihood import Engine, Fit
from ...errors import NonlinearityError
from ..estimation.relinearise import candidates, exact_errors, linearise
from .selection import STEP_COLUMNS, name_effects, select

__all__ = ["Named", "identify", "name_pass", "MAX_PASSES", "MAX_RESTARTS", "REMAINDER", "CURVATURE"]

#: Most passes of the iteration.
MAX_PASSES = 6
#: Most restarts from aliases (:meth:`_Passes.simpler`).
MAX_RESTARTS = 3
#: Largest share of the rows a start model may set aside as gross errors: beyond it the model misses an
#: effect (gross errors are a few rows), and the effects are named on every row before gross errors are sought.
GROSS_SHARE = 0.1
#: Whitened energy (a log-likelihood ratio) of the exact chain's departure from a pass's linear model at
#: the named values below which the pass stands.
REMAINDER = 0.1
#: Whitened energy of the chain's curvature across a named effect's interval (its value +- 2 standard
#: errors) above which the linearised interval is not trusted.
CURVATURE = 1.0


@dataclass(frozen=True)
class Named:
    """One pass: the engine of the kept rows, the null and named fits, and how they were found.

    Attributes
    ----------
    engine : Engine
        On the kept rows, linearised about the pass's point.
    base, fit : Fit
        The model without effects and with the named ones.
    accepted : dict
        Name -> evidence of the step that named it (:func:`~prp3mc.measurement.selection.select`).
    steps : DataFrame
        The selection's steps.
    keep : ndarray of bool, shape (M,)
        Rows kept (gross errors set aside).
    d2 : ndarray, shape (M,)
        Every row's squared standardised prediction error under ``fit``.
    limit : float
        The gross-error threshold of ``d2``.
    """

    engine: Engine
    base: Fit
    fit: Fit
    accepted: dict
    steps: pd.DataFrame
    keep: np.ndarray
    d2: np.ndarray
    limit: float

    @property
    def values(self) -> dict:
        """The named systematic effects' values, name -> value."""
        values = self.engine.values(self.fit)
        return {n: values[n] for n in (self.engine.systematic[j].name for j in self.fit.sys)}


def name_pass(full: Engine, alpha: float, max_effects: int, outlier_rate: float, start=()) -> Named:
    """Gross errors set aside, effects named, every row tested again under the named model (rows set aside
    only for a missing spread come back), on the model of ``full`` (the whole campaign).

    Gross errors are first looked for under the model with the systematic effects ``start`` (names; the
    effects the point was linearised about), then names are found from the model without effects.
    """
    visible = {e.name for e in full.systematic}
    start_model = {"sys": tuple(full.sys_index(n) for n in start if n in visible), "factors": {}}

    def start_fit(keep):
        engine = full.with_rows(keep)
        return engine, engine.refit(start_model["sys"], start_model["factors"])

    def named_model(keep):
        engine = full.with_rows(keep)
        base = engine.refit((), {})
        return (engine, base, *select(engine, base, alpha, max_effects))

    keep, _ = gross.flag(full, start_fit, outlier_rate)
    if (~keep).mean() > GROSS_SHARE:
        # not a few gross errors but a model that misses an effect: name on every row first
        fit = named_model(np.ones(full.M, bool))[2]
        start_model.update(sys=fit.sys, factors=fit.factors)
        keep, _ = gross.flag(full, start_fit, outlier_rate)
        if (~keep).mean() > GROSS_SHARE:
            raise NonlinearityError(f"{int((~keep).sum())} of {full.M} rows stand out as gross errors even under "
                                    "the effects named on every row: the model cannot follow this campaign")
    engine, base, fit, accepted, steps = named_model(keep)
    limit = gross.threshold(full.M, outlier_rate)
    d2 = gross.distances(full, keep, engine.values(fit), fit.factors, fit.r)
    if ((d2 <= limit) != keep).any() and (d2 <= limit).sum() > 3:
        keep = d2 <= limit
        engine, base, fit, accepted, steps = named_model(keep)
        d2 = gross.distances(full, keep, engine.values(fit), fit.factors, fit.r)
    return Named(engine, base, fit, accepted, steps, keep, d2, limit)


def _energy(named: Named, exact: np.ndarray, values: dict) -> float:
    """Whitened energy of ``exact`` (M, 3 of the whole campaign) less the pass's linear model at ``values``."""
    engine = named.engine
    cols = engine.cols_of(tuple(engine.sys_index(n) for n in values))
    linear = engine.known + engine.G[:, :, cols] @ components(list(values), list(values.values()))
    return _whitened_energy(named, exact[engine.keep] - linear)


def _whitened_energy(named: Named, difference: np.ndarray) -> float:
    """``|z|^2`` of a difference of pose errors (M_kept, 3) whitened by the pass's fit."""
    z = named.engine.whiten(difference, named.fit.Lw, named.fit.Lb)
    return float(z @ z)


def _curvature(geometry, budget, campaign, named: Named) -> dict:
    """Per named systematic effect: the largest whitened energy of the chain's departure from the pass's
    linear model at its value +- 2 standard errors (the others at theirs)."""
    values = named.values
    if not values:
        return {}
    engine, fit = named.engine, named.fit
    sets, labels = [], []
    se = np.sqrt(np.clip(np.diagonal(fit.theta_cov)[len(fit.nuis):], 0.0, None))       # per column
    k = 0
    for name in values:
        for unit in ((1.0, 1j) if effect(name).dof == 2 else (1.0,)):                 # a phasor's two parts
            for sign in (-2.0, 2.0):
                sets.append({**values, name: values[name] + sign * se[k] * unit})
                labels.append(name)
            k += 1
    exact = exact_errors(geometry, budget, campaign, sets)
    out: dict = {}
    for name, v, e in zip(labels, sets, exact):
        out[name] = max(out.get(name, 0.0), _energy(named, e, v))
    return out


class _Passes:
    """Passes from a starting point until the named model settles (module notes): the iteration's state."""

    def __init__(self, geometry, budget, campaign, make_engine, alpha, max_effects, outlier_rate):
        self.geometry, self.budget, self.campaign, self.make_engine = geometry, budget, campaign, make_engine
        self.alpha, self.max_effects, self.outlier_rate = alpha, max_effects, outlier_rate
        self.candidates = candidates(geometry, budget, campaign)

    def run(self, values: dict | None = None) -> tuple[Named, list, str | None]:
        """Passes from the model linearised about ``values`` (None: the nominal geometry): the last pass,
        the passes' records and why the iteration failed (None when it settled)."""
        passes, why = [], None
        try:
            point = None if values is None else linearise(self.geometry, self.budget, self.campaign, values,
                                                          self.candidates)
        except NonlinearityError as exc:
            return None, passes, f"linearising at {_text(values)}: {exc}"
        named = None
        for _ in range(MAX_PASSES):
            full = self.make_engine(point)
            try:
                named = name_pass(full, self.alpha, self.max_effects, self.outlier_rate,
                                  () if point is None else tuple(point.values))
            except NonlinearityError as exc:
                if named is None:                # nothing to fall back on: the model without effects, all rows
                    named = _unnamed(full, self.outlier_rate)
                return named, passes, str(exc)
            values = named.values
            record = {"point": _plain(point.values) if point is not None else {}, "named": _plain(values),
                      "gross_errors": int((~named.keep).sum())}
            passes.append(record)
            try:
                exact = exact_errors(self.geometry, self.budget, self.campaign, [values])[0]
            except NonlinearityError as exc:
                return named, passes, f"at the named values {_text(values)}: {exc}"
            record["remainder"] = _energy(named, exact, values)
            if point is not None:            # how far the named model moved from the point's (alias swaps: 0)
                record["moved"] = _whitened_energy(named, (exact - point.exact)[named.keep])
            if record["remainder"] <= REMAINDER and record.get("moved", 0.0) <= REMAINDER:
                return named, passes, None
            try:
                point = linearise(self.geometry, self.budget, self.campaign, values, self.candidates)
            except NonlinearityError as exc:
                return named, passes, f"linearising at the named values {_text(values)}: {exc}"
        return named, passes, (f"the named set and values did not settle in {MAX_PASSES} passes of "
                               f"relinearisation (last: {_text(passes[-1]['named'])})")

    def simpler(self, named: Named) -> tuple[Named, list, list]:
        """Restarts from each alias of the named effects alone, and the smallest model that fits as well.

        Far from the nominal geometry Gauss-Newton can settle on a first-order alias set (``alpha_1`` with
        a 30 deg ``psi_1``, for a guide angle error ``beta_1`` of 2 deg on the U-shape). Each alias of a
        named effect (from :func:`~prp3mc.measurement.naming.selection.name_effects`; those with the named
        effect's own signature left out, :data:`MAX_RESTARTS` at most) is a new start; a model
        with fewer effects on the same rows replaces the named one unless the named one beats it by the
        naming threshold for each effect more (a model of the same size, when it fits better).
        """
        same = {n: set(g) for g in named.engine.structural_aliases() for n in g}   # one signature: one model
        starts = {}
        for e in name_effects(named.engine, named.fit, named.accepted):
            for alias, fit in e.evidence["alias_fits"].items():
                if effect(alias).systematic and alias not in named.values and alias not in same.get(e.name, ()):
                    starts.setdefault(alias, fit["value"])
        starts = dict(list(starts.items())[:MAX_RESTARTS])       # the first named effect's aliases first
        from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
        threshold = float(chi2.isf(self.alpha / max(len(self.candidates), 1), 1))
        best, best_passes, tried = named, None, []
        for alias, value in starts.items():
            other, passes, why = self.run({alias: value})
            tried.append({"start": _plain({alias: value}), "named": _plain(other.values) if other else {},
                          "settled": why is None})
            if why is not None or other is None or not np.array_equal(other.keep, best.keep):
                continue
            extra = len(best.values) + len(best.fit.factors) - len(other.values) - len(other.fit.factors)
            gain = 2.0 * (best.fit.loglik - other.fit.loglik)
            if (extra > 0 and gain < extra * threshold) or (extra == 0 and gain < -1e-6):
                best, best_passes = other, passes
                tried[-1]["chosen"] = True
        return best, best_passes, tried


def identify(geometry, budget, campaign, make_engine, alpha: float, max_effects: int,
             outlier_rate: float) -> tuple[Named, dict]:
    """The named model, relinearised on the exact chain until stable (module notes), and its record.

    Parameters
    ----------
    geometry, budget, campaign
        What the analysis runs on (the whole campaign).
    make_engine : callable
        ``make_engine(point) -> Engine`` on the whole campaign, linearised about ``point`` (None: nominal).
    alpha, max_effects, outlier_rate
        As :func:`~prp3mc.measurement.discrepancy.workflow.discrepancy`.

    Returns
    -------
    named : Named
        The last pass; when the linearity guard trips, its fit is the model without effects.
    linearity : dict
        ``passes`` (per pass: the point's values, the named values, gross errors set aside, the
        departure ``remainder`` and, from the second, how far the named model ``moved``),
        ``restarts`` (from the named effects' aliases, when relinearised: their start, what they
        named, whether they settled and were ``chosen``), ``converged``, ``curvature`` (per named
        effect), ``guard`` (``"ok"`` or ``"tripped"``) and, when tripped, ``why``, ``advice`` and
        ``last_estimate``.
    """
    iteration = _Passes(geometry, budget, campaign, make_engine, alpha, max_effects, outlier_rate)
    named, passes, why = iteration.run()
    doc = {"passes": passes, "restarts": []}
    if why is None and len(passes) > 1 and len(named.values) > 1:
        named, chosen, doc["restarts"] = iteration.simpler(named)
        if chosen is not None:
            doc["passes"] = passes = passes + chosen
    doc.update(converged=why is None, max_passes=MAX_PASSES, remainder_tolerance=REMAINDER,
               curvature_tolerance=CURVATURE)
    if why is None:
        try:
            doc["curvature"] = _curvature(geometry, budget, campaign, named)
        except NonlinearityError as exc:
            why = f"across the named effects' intervals: {exc}"
        else:
            curved = {n: c for n, c in doc["curvature"].items() if c > CURVATURE}
            if curved:
                why = ("the exact chain is curved across the interval of " + ", ".join(curved)
                       + f" (whitened departure {max(curved.values()):.3g} > {CURVATURE:g})")
    doc["guard"] = "ok" if why is None else "tripped"
    if why is not None:
        doc.update(why=why, last_estimate=passes[-1]["named"] if passes else {},
                   advice="nothing is named: the errors are too large for the model linearised about this "
                          "geometry; apply the last estimate's geometric offsets to the geometry (a geometry closer "
                          "to the machine) and analyse again")
        named = Named(named.engine, named.base, named.base, {}, named.steps, named.keep, named.d2, named.limit)
    return named, doc


def _unnamed(full: Engine, outlier_rate: float) -> Named:
    """The model without effects on every row (what a pass falls back on when it cannot name)."""
    base = full.refit((), {})
    keep = np.ones(full.M, bool)
    return Named(full, base, base, {}, pd.DataFrame(columns=STEP_COLUMNS), keep,
                 gross.distances(full, keep, full.values(base), base.factors, base.r),
                 gross.threshold(full.M, outlier_rate))


def _plain(values: dict) -> dict:
    """Effect values as JSON holds them: a cyclic error's phasor as ``[amplitude_mm, phase_deg]``
    (:func:`~prp3mc.model.effects.effect_value` reads it back)."""
    return {n: list(amplitude_phase(v)) if isinstance(v, complex) else v if isinstance(v, list) else float(v)
            for n, v in values.items()}


def _text(values: dict) -> str:
    return ", ".join(f"{n} = {v[0]:.4g} {effect(n).unit} at {v[1]:.4g} deg" if isinstance(v, list) else
                     f"{n} = {v:.4g} {effect(n).unit}" for n, v in _plain(values).items()) or "nothing"
