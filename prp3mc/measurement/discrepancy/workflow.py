"""The discrepancy workflow: where model and measurement disagree, which effect is missing, the gap.

:func:`discrepancy` is a pipeline of named steps, each in the package of its stage:

1. the campaign read and checked against the geometry and the budget;
2. the named model (:func:`~prp3mc.measurement.naming.identify.identify`): the instrument's
   registration and drift fitted as nuisances (:mod:`~prp3mc.measurement.estimation.nuisance`)
   and the repeatable fraction of the budget's errors in every model
   (:mod:`~prp3mc.measurement.estimation.likelihood`), gross errors set aside
   (:mod:`~prp3mc.measurement.estimation.outliers`) and missing effects named
   (:mod:`~prp3mc.measurement.naming.selection`), in passes relinearised on the exact chain;
3. the named effects (:func:`~prp3mc.measurement.naming.selection.name_effects`) and the
   updated model they make (:func:`~prp3mc.measurement.discrepancy.updated.updated_model`),
   whose predicted accuracy runs beside the rest;
4. the diagnoses before and after and the gap
   (:func:`~prp3mc.measurement.verdict.compare.diagnoses`);
5. what the analysis names with the gross errors kept (:func:`_with_outliers`);
6. the listed nuisances and the drift test
   (:func:`~prp3mc.measurement.estimation.nuisance.listed_nuisances`), what the campaign
   cannot tell apart (:mod:`~prp3mc.measurement.naming.confounds`), the prediction of the
   named model and its ISO 9283 figures
   (:func:`~prp3mc.measurement.verdict.compare.predicted_iso9283`);
7. the result, with the verdict (:func:`~prp3mc.measurement.verdict.diagnostics.verdict`).

:func:`detectable_effect` plans a campaign: how large an effect its layout can name.

Drift is fitted in every model and *listed* under ``nuisance`` only when a
likelihood-ratio test (chi2(3) at ``alpha``) shows it. When a named effect
has aliases, the nuisances fitted with each alias in its place differ (the
registration takes up what tells them apart); each listed nuisance's
interval is the union of its intervals over the named model and those
(``by_alias`` lists each), so that it covers whichever alias is true.

A campaign that visits every pose once (a laser tracker's sweep) is
analysed too: the systematic channels need no repeats; the dispersion
channels (spreads, the repeatable fraction, the repeat scatter) compare
repeats and are reported as not tested (``gap.not_tested``,
``repeatability.not_testable``, spreads under ``not_testable``). Fitting it always
(rather than adding it only when significant) keeps the null law of every
other test free of a pre-test, at a cost of three of the campaign's 3M
degrees of freedom.
"""

from __future__ import annotations

import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np
from scipy import optimize

from ..._rng import child_seed, resolve_rng
from ..._threads import single_threaded_blas
from ...errors import ParameterError, Prp3mcWarning
from ...kinematics.geometry import Geometry
from ...progress import Progress
from ...model.budget import Budget
from ...model.effects import amplitude_phase
from ...model.linear import linear_model
from ..campaign.data import Campaign, check_error_scale, read_campaign, require_testable
from ..forward.prediction import noise_cov, predict
from ..forward.signatures import effect
from ..estimation.likelihood import Engine
from ..estimation.nuisance import listed_nuisances
from ..estimation.outliers import outlier_rows, outlier_rule
from ..estimation.testable import not_testable, repeatability
from ..naming.confounds import ambiguities, design_confounds
from ..naming.identify import Named, identify
from ..naming.selection import effect_values, name_effects, select
from ..verdict.compare import diagnoses, predicted_iso9283
from ..verdict.diagnostics import diagnose, gap_value, verdict
from .accuracy import predicted_accuracy
from .results import DiscrepancyResult
from .updated import updated_model

__all__ = ["discrepancy", "detectable_effect", "detectable_in", "correlation_warning", "STAGES"]

#: The stages of :func:`discrepancy`, one progress step each.
STAGES = ("gross errors and names", "diagnoses", "with the gross errors", "ISO 9283")


@single_threaded_blas()  # the analysis's products are small: a second BLAS thread only spun (0.2 CPU-s a run)
def discrepancy(geometry: Geometry, budget: Budget, campaign, *, instrument_sigma_mm: float = 0.0,
                instrument_sigma_deg: float = 0.0, registration: bool = True, alpha: float = 0.01,
                alpha_unexplained: float = 0.05, outlier_rate: float = 0.01, max_effects: int = 6,
                n_bootstrap: int = 400, progress: "bool | None | Progress" = None,
                rng: "None | int | np.random.Generator" = None) -> DiscrepancyResult:
    """Find where model and campaign disagree, name the missing effects, close the gap.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        The model's random errors and, in its ``[effects]`` table, systematic
        errors already known (part of every model, null and alternative,
        driven by the campaign's ``dir_i``, ``temp_C`` and slider positions;
        one named again is a correction to it). A budget whose effects were
        fitted on another geometry is refused.
    campaign : Campaign, DataFrame or path
        A campaign (docs, *File formats*), measured in the instrument's frame; validated against ``geometry``.
    instrument_sigma_mm, instrument_sigma_deg : float
        Standard deviation of the measurement noise per coordinate.
    registration : bool
        Fit the instrument's planar registration (False when it is known to be registered).
    alpha : float
        Family-wise level of the naming steps (Bonferroni over candidates)
        and of the drift test.
    alpha_unexplained : float
        Family-wise level (Bonferroni over the seven channels of
        :mod:`~prp3mc.measurement.verdict.diagnostics`) of the verdict that
        disagreement remains unexplained; the gap closes at ``-ln`` of it.
    outlier_rate : float
        Family-wise false-alarm rate of the gross-error test over all rows.
    max_effects : int
        Most effects named.
    n_bootstrap : int
        Parametric-bootstrap replicates for the null variances of the tests.
    progress : bool, None or Progress
        Report the stages (:data:`STAGES`) on stderr: True, False, None
        (when stderr is a terminal), or a :class:`~prp3mc.progress.Progress`
        to advance by one per stage (left open, for a caller with more stages).
    rng : None, int or numpy.random.Generator
        Randomness of the bootstrap (Scientific Python SPEC 7); the integer
        seed used is recorded in the result.

    Returns
    -------
    DiscrepancyResult

    Warns
    -----
    Prp3mcWarning
        A budget with ``[correlation]``: the fit takes its inputs as
        independent (:func:`correlation_warning` says by how much that
        changes the budget's spread at the campaign's poses).
    """
    t0 = time.perf_counter()
    seed, rng = resolve_rng(rng)
    campaign = _checked_campaign(geometry, budget, campaign, instrument_sigma_mm,
                                 alpha=alpha, alpha_unexplained=alpha_unexplained, outlier_rate=outlier_rate)
    noise = noise_cov(instrument_sigma_mm, instrument_sigma_deg)
    # the predicted accuracy needs the named effects only: on a thread of its own (its kernels release the
    # GIL) while the rest is diagnosed
    with ThreadPoolExecutor(max_workers=1) as pool, _stages(progress) as stage_done:
        # registration and drift (nuisances), the repeatable fraction, gross errors set aside and effects named,
        # in passes relinearised on the exact chain until stable
        named, linearity = identify(
            geometry, budget, campaign,
            lambda point: Engine(geometry, budget, campaign, noise, registration=registration, point=point),
            alpha, max_effects, outlier_rate)
        engine, fit = named.engine, named.fit
        effects = name_effects(engine, fit, named.accepted)
        model = updated_model(geometry, budget, effects, campaign)
        accuracy = pool.submit(predicted_accuracy, geometry, budget, model, campaign, seed)
        stage_done()
        before, after, gap_doc = diagnoses(engine, named.base, fit, n_bootstrap, alpha_unexplained, rng, seed)
        stage_done()
        with_outliers = _with_outliers(named, alpha, max_effects, n_bootstrap, gap_doc["closed_at"], rng)
        stage_done()
        nuisance, drift_test = listed_nuisances(engine, fit, alpha, effects)
        shown, reasons = ambiguities(engine, fit, effects, drift_test, alpha)
        confounded = tuple(design_confounds(engine) + shown)
        values = effect_values(engine, fit)
        prediction = predict(geometry, budget, campaign, effects=values, instrument_sigma_mm=instrument_sigma_mm,
                             instrument_sigma_deg=instrument_sigma_deg, repeatable_fraction=fit.r)
        iso, iso_poses = predicted_iso9283(engine, fit, child_seed(seed, 9283))
        stage_done()
        return DiscrepancyResult(
            named_effects=effects, unexplained=not gap_doc["closed"] or linearity["guard"] != "ok", gap=gap_doc,
            verdict=verdict(gap_doc, effects, linearity, reasons, confounded), confounded=confounded,
            before=before, after=after, steps=named.steps, prediction_after=prediction,
            budget_after=prediction.budget, systematic={n: v for n, v in values.items() if effect(n).systematic},
            nuisance=nuisance, drift_test=drift_test, registration=registration,
            outliers=outlier_rows(campaign, named.keep, named.d2),
            outlier_rule=outlier_rule(named.keep.size, named.limit, outlier_rate), with_outliers=with_outliers,
            repeatability=repeatability(engine, fit), iso9283=iso, iso9283_poses=iso_poses,
            invisible=engine.invisible,
            confounded_with_registration=tuple(n for n, w in engine.confounded.items() if "registration" in w),
            structural_aliases=tuple(tuple(g) for g in engine.structural_aliases()),
            not_testable=not_testable(engine), linearity=linearity, model=model, accuracy=accuracy.result(),
            campaign=campaign, geometry=geometry, budget=budget, seed=seed, n_bootstrap=n_bootstrap, alpha=alpha,
            alpha_unexplained=alpha_unexplained, instrument_sigma_mm=instrument_sigma_mm,
            instrument_sigma_deg=instrument_sigma_deg, wall_time_s=time.perf_counter() - t0)


def _checked_campaign(geometry: Geometry, budget: Budget, campaign, instrument_sigma_mm: float,
                      **levels: float) -> Campaign:
    """The campaign read and validated against ``geometry``, once the levels (each in (0, 1)) and the budget's
    geometry are checked; warns when the budget correlates its inputs (:func:`correlation_warning`)."""
    for name, value in levels.items():
        if not 0 < value < 1:
            raise ParameterError(f"{name} must lie in (0, 1), got {value}")
    budget.check_geometry(geometry)
    campaign = require_testable(read_campaign(campaign, geometry))
    if budget.correlated:
        warnings.warn(Prp3mcWarning(correlation_warning(geometry, budget, campaign.poses)), stacklevel=4)
    check_error_scale(campaign, geometry, budget, instrument_sigma_mm)
    return campaign


@contextmanager
def _stages(progress):
    """``stage_done()``, advancing a progress bar by one of :data:`STAGES`; the bar is closed on leaving when it
    is :func:`discrepancy`'s own (``progress`` not a :class:`~prp3mc.progress.Progress`)."""
    bar = progress if isinstance(progress, Progress) else Progress(len(STAGES), "discrepancy", progress)
    stages = iter(STAGES)
    yield lambda: bar.update(label=f"discrepancy: {next(stages)}")
    if bar is not progress:
        bar.close()


def correlation_warning(geometry: Geometry, budget: Budget, poses: np.ndarray) -> str:
    """What the discrepancy fit's independent inputs make of a correlated budget, measured at the campaign's poses.

    The fit's likelihood sums each input's own covariance (it ignores
    ``[correlation]``; docs, *The discrepancy workflow*, Dependent inputs);
    the message says by how much the budget's standard deviation of the
    position error (the root of the x, y variances' sum) and of φ differ
    from the independent one's at some pose (the largest relative difference).

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        With ``[correlation]``.
    poses : ndarray, shape (P, 3)
        ``[x_mm, y_mm, phi_deg]``.

    Returns
    -------
    str
        The one-line warning :func:`discrepancy` gives.
    """
    budget = budget.without_effects()
    cov = [linear_model(geometry, b, poses, check=False).moments()[1] for b in (budget, Budget(budget.inputs))]
    sd = [(np.sqrt(c[..., 0, 0] + c[..., 1, 1]), np.sqrt(c[..., 2, 2])) for c in cov]
    change = [100 * float(np.max(np.abs(np.divide(a, b, out=np.ones_like(a), where=b > 0) - 1)))
              for a, b in zip(*sd)]
    return (f"budget {budget.name!r} correlates inputs ([correlation]); the discrepancy fit takes them as "
            f"independent: at the campaign's poses the correlation changes the budget's sd of the position error "
            f"by up to {change[0]:.0f} % and of phi by up to {change[1]:.0f} %, so the dispersion tests and the "
            "repeatable fraction are judged against the independent budget (the predicted accuracy respects the "
            "correlation; docs: The discrepancy workflow, Dependent inputs)")


def _with_outliers(named: Named, alpha: float, max_effects: int, n_bootstrap: int, closed_at: float,
                   rng) -> dict | None:
    """What the analysis names, and its gap, with the gross errors kept (None when none was set aside)."""
    if named.keep.all():
        return None
    engine = named.engine.with_rows(np.ones(named.keep.size, bool))
    base = engine.refit((), {})
    fit, _, _ = select(engine, base, alpha, max_effects)
    n_boot = max(n_bootstrap // 4, 50)               # for the comparison only
    g_before, _ = gap_value(diagnose(engine, base, n_boot, rng))
    g_after, _ = gap_value(diagnose(engine, fit, n_boot, rng))
    return {"named_effects": [_value_entry(n, v) for n, v in effect_values(engine, fit).items()],
            "gap_before": g_before, "gap_after": g_after, "unexplained": bool(g_after > closed_at),
            "repeatable_fraction": fit.r}


def _value_entry(name: str, value) -> dict:
    """``{name, value}`` of an effect's value (a cyclic error's phasor as its amplitude, with ``phase_deg``)."""
    if isinstance(value, complex):
        amplitude, phase = amplitude_phase(value)
        return {"name": name, "value": amplitude, "phase_deg": phase}
    return {"name": name, "value": float(value)}


def detectable_effect(geometry: Geometry, budget: Budget, campaign: Campaign, name: str, *,
                      power: float = 0.9, alpha: float = 0.01, instrument_sigma_mm: float = 0.0,
                      instrument_sigma_deg: float = 0.0, registration: bool = True) -> float:
    """Smallest ``|value|`` of a systematic effect that a campaign names with probability ``power``.

    For planning: simulate a campaign without effects (only its layout
    matters: poses, repeats, directions, temperatures) and ask how large an
    effect it would detect, with the nuisances (registration unless
    ``registration`` is False, drift) profiled out and errors drawn afresh
    at every visit. Uses the non-central chi2(1) law of the LR at the
    Bonferroni threshold over the library's testable candidates; aliasing
    is not accounted for. A cyclic error's value is its amplitude, at its
    least detectable phase, with the non-central chi2(2) law.

    Returns
    -------
    float
        In the effect's unit; inf if the campaign cannot see it.
    """
    if not effect(name).systematic:
        raise ParameterError(f"{name}: detectable_effect handles systematic effects; simulate spreads instead")
    engine = Engine(geometry, budget, read_campaign(campaign, geometry),
                    noise_cov(instrument_sigma_mm, instrument_sigma_deg), registration=registration)
    return detectable_in(engine, name, power=power, alpha=alpha)


def detectable_in(engine: Engine, name: str, *, power: float = 0.9, alpha: float = 0.01) -> float:
    """:func:`detectable_effect` of systematic effect ``name`` on the campaign, noise and registration of an
    engine at the nominal geometry (one engine serves every effect of a plan).

    Returns
    -------
    float
        In the effect's unit; inf if the campaign cannot see it.
    """
    eff = effect(name)
    if name not in [e.name for e in engine.systematic] or name in engine.confounded:
        return float("inf")
    K = len(engine.systematic) - len(engine.confounded) + len(engine.spreads)
    from scipy.stats import chi2, ncx2  # imported when used: prp3mc --help imports this module
    threshold = chi2.isf(alpha / K, eff.dof)
    fit = engine.fit((), {}, 0.0)
    g = engine.whitened_candidates(fit)[:, engine.blocks[engine.sys_index(name)]]
    Q, _ = np.linalg.qr(engine.whitened(fit, (), engine.nuisance)[1])
    g = g - Q @ (Q.T @ g)
    info = float(np.linalg.eigvalsh(g.T @ g)[0])                   # Fisher information per unit^2 (least: phase)
    lam = optimize.brentq(lambda nc: ncx2.sf(threshold, eff.dof, nc) - power, 1e-6, 1e4)
    return float(np.sqrt(lam / info))
