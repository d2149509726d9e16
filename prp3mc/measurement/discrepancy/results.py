"""The results of the discrepancy workflow: named effects and the whole analysis."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ...provenance import file_record, versions
from ..._result import freeze, interval_frame, thawed
from ..._version import __version__
from ...kinematics.geometry import Geometry
from ...model.budget import Budget
from ...units import z_value
from ..campaign.data import Campaign
from ..verdict.diagnostics import Diagnosis
from ..estimation.likelihood import Engine
from ...model.effects import effect_value
from ..forward.prediction import Prediction, noise_cov
from ..estimation.relinearise import candidates, linearise
from .updated import UpdatedModel
from ..naming.named import EFFECT_COLUMNS, LEVEL, NamedEffect

__all__ = ["DiscrepancyResult"]

@dataclass(frozen=True, slots=True)
class DiscrepancyResult:
    """Outcome of :func:`~prp3mc.measurement.discrepancy.workflow.discrepancy`.

    Attributes
    ----------
    named_effects : tuple of NamedEffect
        Empty when the model misses nothing the campaign can see.
    unexplained : bool
        Disagreement remains that no candidate explains: ``not gap["closed"]``, or the linearity guard tripped.
    verdict : mapping
        ``state`` (one of :data:`~prp3mc.measurement.diagnostics.VERDICTS`:
        ``beyond the linear model``, ``unexplained``, ``ambiguous``,
        ``explained``, ``nothing missing``) and a one-line ``text``.
    confounded : tuple of mapping
        What the campaign cannot tell apart (:mod:`~prp3mc.measurement.naming.confounds`):
        ``{effects, with, why, advice, source}``, ``source`` ``design`` (from
        the signatures, with ``vif`` or ``r``) or ``data`` (an effect that
        explains the drift the data show as well).
    gap : mapping
        ``metric, before, after, null_level, closed_at, closed,
        deciding_channel`` and every channel's evidence (see
        :mod:`~prp3mc.measurement.verdict.diagnostics`), and ``held_out``: the gap
        before and after on poses left out of the fit
        (:mod:`~prp3mc.measurement.verdict.holdout`), the one to trust.
    before, after : Diagnosis
        Disagreement under the budget alone and with the named effects
        (nuisances in both, gross errors set aside).
    steps : DataFrame
        Every candidate's LR at every selection step.
    prediction_after : Prediction
        The corrected model's prediction (machine frame, no nuisances).
    budget_after : Budget
        The budget with named spreads applied.
    systematic : mapping
        Named systematic effects, name -> value: the model's new parameters.
    nuisance : tuple of mapping
        ``{name, value, unit, ci95}`` of the registration (when fitted) and
        of the drift (when its test rejects).
    drift_test : mapping
        ``lr, df, p, significant, time`` (``time_s`` or ``row order``) and
        the drift's fitted ``values``, listed or not.
    registration : bool
        Whether the registration was fitted.
    outliers : tuple of mapping
        ``{row, pose_id, z}`` of each measurement set aside (``z``: the
        square root of its squared standardised prediction error).
    outlier_rule : mapping
        ``family_wise_rate``, ``per_measurement_level``, ``z_threshold``.
    with_outliers : mapping or None
        When rows were set aside: what the workflow names and the gap it
        finds if they are kept (``named_effects, gap_before, gap_after,
        unexplained``).
    repeatability : mapping
        ``repeatable_fraction`` and its profile-likelihood ``ci95``; both
        None, with ``not_testable`` (the reason), when no pose is measured twice.
    iso9283 : mapping or None
        Largest ISO 9283 figures over the poses, ``measured`` and ``predicted``.
    iso9283_poses : DataFrame or None
        The ISO 9283 figures per pose.
    invisible : tuple of str
        Effects whose signature vanishes over the campaign (never named).
    confounded_with_registration : tuple of str
        Effects the campaign cannot tell apart from the registration (never named).
    structural_aliases : tuple of tuple of str
        Groups of effects with collinear signatures over the campaign.
    not_testable : mapping
        Effects the campaign cannot test, with the reason.
    linearity : mapping
        How the model was linearised (:func:`~prp3mc.measurement.identify.identify`):
        the ``passes`` of relinearisation on the exact chain, ``converged``,
        ``curvature`` per named effect and the linearity ``guard`` (``ok``,
        or ``tripped`` with ``why``, ``advice`` and ``last_estimate``: then
        nothing is named and the analysis is unexplained).
    model : UpdatedModel
        The updated model: identified geometry, updated and compensated
        budgets, the compensable and non-compensable effects.
    accuracy : mapping
        Predicted accuracy over the region, original, updated and
        compensated (:func:`~prp3mc.measurement.discrepancy.accuracy.predicted_accuracy`).
    campaign : Campaign
        The validated campaign (every row).
    geometry, budget
        What the analysis ran on.
    seed, n_bootstrap : int
    alpha, alpha_unexplained : float
    instrument_sigma_mm, instrument_sigma_deg : float
    version : str
    wall_time_s : float
    """

    named_effects: tuple
    unexplained: bool
    verdict: dict
    confounded: tuple
    gap: dict
    before: Diagnosis
    after: Diagnosis
    steps: pd.DataFrame
    prediction_after: Prediction
    budget_after: Budget
    systematic: dict
    nuisance: tuple
    drift_test: dict
    registration: bool
    outliers: tuple
    outlier_rule: dict
    with_outliers: dict | None
    repeatability: dict
    iso9283: dict | None
    iso9283_poses: pd.DataFrame | None
    invisible: tuple
    confounded_with_registration: tuple
    structural_aliases: tuple
    not_testable: dict
    linearity: dict
    model: UpdatedModel
    accuracy: dict
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
                f"outliers={len(self.outliers)}, seed={self.seed})")

    def effect_fit(self, name: str) -> tuple[float, tuple] | None:
        """Value and 95 % interval of effect ``name``: named, or an alias of a named effect (its alias fit);
        None when it is neither."""
        for e in self.named_effects:
            if e.name == name:
                return e.value, tuple(e.ci95)
            if name in e.aliases:
                f = e.evidence["alias_fits"][name]
                return f["value"], tuple(f["ci95"])
        return None

    @property
    def repeatable_fraction(self) -> float:
        """The fitted share of the budget's variance that repeats at every visit of a pose (NaN when the
        campaign measures no pose twice: not testable)."""
        r = self.repeatability["repeatable_fraction"]
        return float("nan") if r is None else float(r)

    def to_frame(self) -> pd.DataFrame:
        """One row per named effect: ``name, value, unit, ci_low, ci_high, level, aliases, identified, lr``.

        The interval is the 95 % one (``ci95``); :meth:`conf_int` gives others.
        """
        return pd.DataFrame([e.row() for e in self.named_effects], columns=EFFECT_COLUMNS)

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
            effect, in the effect's unit.

        Raises
        ------
        ValueError
            ``level`` is not in (0, 1).
        """
        z_value(level)                                    # validates the level
        effects = self.named_effects
        cis = [e.ci95 for e in effects] if level == LEVEL or not effects else _intervals(self, level)
        frame = pd.DataFrame({"name": [e.name for e in effects], "value": [e.value for e in effects],
                              "unit": [e.unit for e in effects]}, columns=["name", "value", "unit"])
        return interval_frame(frame, [ci[0] for ci in cis], [ci[1] for ci in cis], level)

    def inputs(self) -> dict:
        """What the analysis ran on: geometry and budget names, the data (file and sha256), seed, sizes."""
        source = self.campaign.source
        data = file_record(source) if Path(source).is_file() else {"source": source}
        budget = {"name": self.budget.name}
        if self.budget.missing_inputs:
            budget["missing_inputs"] = list(self.budget.missing_inputs)
        return {"geometry": {"name": self.geometry.name}, "budget": budget, "data": data,
                "n_measurements": int(self.campaign.n_measurements), "n_poses": int(self.campaign.n_poses),
                "seed": int(self.seed), "n_bootstrap": int(self.n_bootstrap)}

    def to_dict(self) -> dict:
        """The ``discrepancy.json`` document (plus diagnostics), with ``inputs`` and ``versions``.

        ``warnings`` (present when there are any) lists what needs care in the
        result, one line each: the budget's (:attr:`Budget.warnings`).
        """
        warnings = {"warnings": list(self.budget.warnings)} if self.budget.warnings else {}
        return {
            "inputs": self.inputs(), "versions": versions(), **warnings,
            "named_effects": [e.to_dict() for e in self.named_effects],
            "unexplained": bool(self.unexplained),
            "verdict": thawed(self.verdict),
            "confounded": thawed(self.confounded),
            "gap": thawed(self.gap),
            "nuisance": thawed(self.nuisance),
            "outliers": thawed(self.outliers),
            "repeatability": thawed(self.repeatability),
            "iso9283": thawed(self.iso9283),
            "confounded_with_registration": list(self.confounded_with_registration),
            "registration_fitted": bool(self.registration),
            "drift_test": thawed(self.drift_test),
            "outlier_rule": thawed(self.outlier_rule),
            "with_outliers": thawed(self.with_outliers),
            "tests": {"before": thawed(self.before.summary), "after": thawed(self.after.summary)},
            "invisible": list(self.invisible),
            "structural_aliases": [list(g) for g in self.structural_aliases],
            "not_testable": thawed(self.not_testable),
            "linearity": thawed(self.linearity),
            "model": thawed(self.model.to_dict()),
            "predicted_accuracy": thawed(self.accuracy),
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
    keep = np.ones(result.campaign.n_measurements, bool)
    keep[[o["row"] for o in result.outliers]] = False
    values = {n: effect_value(n, v) for n, v in result.linearity["passes"][-1]["point"].items()}
    point = None
    if values:                                       # the point the named effects were fitted about
        point = linearise(result.geometry, result.budget, result.campaign, values,
                          candidates(result.geometry, result.budget, result.campaign))
    engine = Engine(result.geometry, result.budget, result.campaign,
                    noise_cov(result.instrument_sigma_mm, result.instrument_sigma_deg),
                    registration=result.registration, keep=keep, point=point)
    sys = tuple(engine.sys_index(name) for name in result.systematic)
    factors = {e.name: e.value / e.evidence["budget_value"] for e in result.named_effects
               if "budget_value" in e.evidence}
    fit = engine.fit(sys, factors, 0.0 if np.isnan(result.repeatable_fraction) else result.repeatable_fraction)
    return [engine.estimate(fit, e.name, level)[1] for e in result.named_effects]
