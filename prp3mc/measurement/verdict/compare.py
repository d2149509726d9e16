"""The named model against the model without effects, and against the campaign's ISO 9283 figures.

:func:`diagnoses` runs the tests (:mod:`~prp3mc.measurement.verdict.diagnostics`)
on the model without effects (*before*: the budget and the nuisances) and on
the named model (*after*), each against null variances from its own
parametric bootstrap, and measures the gap between them, in sample and on
poses left out of the fit (:mod:`~prp3mc.measurement.verdict.holdout`).
:func:`predicted_iso9283` sets the campaign's ISO 9283 figures beside those
the named model predicts.
"""

from __future__ import annotations

import dataclasses

from ..campaign.iso9283 import iso9283_figures
from ..estimation.likelihood import Engine, Fit
from ..estimation.testable import ONE_VISIT
from .diagnostics import diagnose, gap, null_variances
from .holdout import held_out_gap

__all__ = ["diagnoses", "predicted_iso9283"]


def diagnoses(engine: Engine, base: Fit, fit: Fit, n_bootstrap: int, alpha_unexplained: float, rng,
              seed: int) -> tuple:
    """The diagnoses before and after the named effects, and the gap document with its held-out part.

    Parameters
    ----------
    engine : Engine
        The likelihood engine of the kept rows.
    base, fit : Fit
        The model without effects and the named model.
    n_bootstrap : int
        Bootstrap replicates of each null (:func:`~prp3mc.measurement.verdict.diagnostics.null_variances`).
    alpha_unexplained : float
        Level of the verdict (:func:`~prp3mc.measurement.verdict.diagnostics.gap`).
    rng : numpy.random.Generator
        The bootstrap's randomness (drawn before, then after).
    seed : int
        The analysis seed (the held-out folds' deal).

    Returns
    -------
    before, after : Diagnosis
    gap : dict
        :func:`~prp3mc.measurement.verdict.diagnostics.gap`'s document with ``held_out``, and
        ``not_tested`` (the dispersion channels) when no pose is measured twice.
    """
    null_before = null_variances(engine, base, n_bootstrap, rng)
    before = diagnose(engine, base, null=null_before)
    null_after = null_variances(engine, fit, n_bootstrap, rng)
    after = diagnose(engine, fit, null=null_after)
    gap_doc = gap(before, after, alpha_unexplained)
    gap_doc["held_out"] = held_out_gap(engine, {"before": (base, null_before), "after": (fit, null_after)}, seed)
    if not engine.repeats:
        gap_doc["not_tested"] = {ch: ONE_VISIT for ch in ("dispersion", "dispersion_pose")}
    return before, after, gap_doc


def predicted_iso9283(engine: Engine, fit: Fit, seed: int) -> tuple:
    """ISO 9283 figures of the kept rows in the machine frame (nuisances removed), measured and predicted.

    Predicted by the fitted model: its mean per pose, visit-to-visit
    covariance ``W`` and repeating covariance ``r Sigma``; the Monte Carlo
    of :func:`~prp3mc.measurement.campaign.iso9283.iso9283_figures` draws from ``seed``.

    Returns
    -------
    figures : dict
        ``measured`` and ``predicted`` figures.
    per_pose : DataFrame
        The figures per pose.
    """
    n = len(fit.nuis)
    corrected = engine.campaign.measured - engine.H[:, :, list(fit.nuis)] @ fit.theta[:n]
    campaign = dataclasses.replace(engine.campaign, measured=corrected)
    mean, W, R = engine.moments(fit.factors, fit.r)
    mean = mean + engine.pose_mean(engine.known + engine.columns(fit.sys, ()) @ fit.theta[n:])
    figures = iso9283_figures(campaign, mean, W, predicted_repeat_cov=R, rng=seed)
    return {"measured": dict(figures["measured"]), "predicted": dict(figures["predicted"])}, figures["per_pose"]
