"""Running a study: every analysis of every configuration, batched over the poses.

:func:`run_study` takes a :class:`~prp3mc.study.reader.Study` (or a study
file, or the name of a bundled study) and returns a
:class:`~prp3mc.study.results.StudyResult`;
:func:`prp3mc.reports.study_report.write_study` writes its report, figures,
tables and ``summary.json`` (``prp3mc study FILE.toml --out DIR``).

Randomness: the study seed gives one Monte Carlo seed and one Sobol seed,
shared by all configurations, swept ones included (common random numbers, so
differences between configurations are not blurred by sampling noise), and the
seed of the allocation's Monte Carlo confirmation (stream 3, also shared). The
streams are keyed by the study seed alone, never by the process that runs a
configuration, so a study gives the same numbers serially or on a Dask
cluster (:mod:`prp3mc.study.distributed`).

Configurations are independent tasks, :func:`run_configuration`, run by an
executor: in this process by default, on Dask workers with ``scheduler=``.
A swept configuration that is infeasible or fails is reported
(:class:`~prp3mc.study.results.SkippedConfiguration`) and the others are kept.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
import warnings
from dataclasses import dataclass, replace
from typing import Any, Iterable, Iterator

import numpy as np

from .._rng import child_seed, resolve_rng
from .._threads import single_threaded_blas
from ..errors import GeometryError, InfeasiblePoseError, NoExactYieldError, Prp3mcWarning
from ..model.budget import Budget
from ..model.linear import linear_model
from ..montecarlo.propagation import monte_carlo
from ..sobol.ranking import ranking
from ..sobol.indices import sobol_indices
from ..worstcase.envelope import WorstCaseResult, worst_case
from ..stackup.gaussian import exact_refusal
from ..units import DEG2ARCSEC, RAD2DEG
from .allocation import ALLOCATION_STREAM, run_allocation
from .reader import Study, StudyConfiguration
from .spec import exceedance_curve, run_yield
from .results import ConfigurationResult, PoseSamples, SkippedConfiguration, StudyResult
from .sweep import Variant, expand

__all__ = ["run_study", "run_configuration", "Plan", "Outcome", "SerialExecutor"]


def _histogram_poses(config: StudyConfiguration, wc: WorstCaseResult) -> tuple[np.ndarray, tuple]:
    """Poses of the histograms: the configuration's, or centre, worst-case max and min."""
    if config.poses is not None:
        return np.asarray(config.poses), tuple(f"({x:g}, {y:g}, {p:g})" for x, y, p in config.poses)
    r = config.region
    flat = wc.poses.reshape(-1, 3)
    pos = wc.position_mm.ravel()
    centre = [0.5 * sum(r.x_mm), 0.5 * sum(r.y_mm), r.phi_deg]
    return (np.array([centre, flat[np.argmax(pos)], flat[np.argmin(pos)]]),
            ("centre", "worst-case max", "worst-case min"))


def _pose_samples(config: StudyConfiguration, budget: Budget, wc: WorstCaseResult, X: np.ndarray, seed: int,
                  k_sigma: float | None) -> PoseSamples:
    """The pose errors of the Monte Carlo run's draws ``X`` (n, inputs) (``budget.sample(n, seed)``) at the
    histograms' poses."""
    poses, labels = _histogram_poses(config, wc)
    n = X.shape[0]
    err = linear_model(config.geometry, budget, poses).evaluate(X)      # (P, n, 3) mm, mm, rad
    at = worst_case(config.geometry, budget, poses, k_sigma=k_sigma)
    return PoseSamples(poses=poses, labels=labels, position_mm=np.hypot(err[..., 0], err[..., 1]),
                       phi_deg=np.abs(err[..., 2]) * RAD2DEG, worst_position_mm=at.position_mm,
                       worst_phi_deg=at.phi_deg, seed=seed, n_samples=n)


@dataclass(frozen=True, slots=True)
class Plan:
    """What every configuration's task needs besides its own :class:`~prp3mc.study.sweep.Variant`.

    Attributes
    ----------
    study : Study
        Sizes, budget and analyses; its configurations are left out (each task
        carries its own), so a task's inputs do not grow with the sweep.
    montecarlo_seed, sobol_seed : int
        Shared by every configuration (common random numbers).
    allocation_seed : int or None
        Seed of the allocation's Monte Carlo confirmation (with an ``[allocation]`` table), shared too.
    n_tasks : int
        Number of configurations, for progress messages.
    progress : bool
        Report each analysis on stderr (serial runs).
    """

    study: Study
    montecarlo_seed: int
    sobol_seed: int
    allocation_seed: int | None = None
    n_tasks: int = 1
    progress: bool = False


@dataclass(frozen=True, slots=True)
class Outcome:
    """What one configuration's task returns: a result or the reason there is none, and its timings."""

    index: int
    result: ConfigurationResult | None
    skipped: SkippedConfiguration | None
    timings_s: dict


def _skip(variant: Variant, kind: str, exc: BaseException) -> Outcome:
    reason = str(exc) if kind == "infeasible" else f"{type(exc).__name__}: {exc}"
    return Outcome(variant.index, None, SkippedConfiguration(variant.name, variant.parameters, kind, reason), {})


def run_configuration(plan: Plan, variant: Variant) -> Outcome:
    """Every analysis of one configuration (a task: runs in this process or on a Dask worker).

    A swept configuration (one with parameters) that is infeasible or whose
    analyses raise is returned as skipped, with the reason; a configuration
    of the study file raises as it always did.
    """
    try:
        config = variant.build()
    except (GeometryError, InfeasiblePoseError) as exc:
        return _skip(variant, "infeasible", exc)
    try:
        with single_threaded_blas():   # the analyses spread over threads of their own (prp3mc._threads)
            result, timings = _analyses(plan, config, variant)
    except InfeasiblePoseError as exc:
        if not variant.parameters:
            raise
        return _skip(variant, "infeasible", exc)
    except Exception as exc:  # noqa: BLE001 -- one failing combination must not cost the sweep
        if not variant.parameters:
            raise
        return _skip(variant, "failed", exc)
    return Outcome(variant.index, result, None, timings)


def _fallback_phi_deg(study: Study) -> float | None:
    """The orientation spec (deg) the Monte Carlo run counts when it stands in for the exact yield."""
    return None if study.spec.phi_arcsec is None else study.spec.phi_arcsec / DEG2ARCSEC


def _timings(study: Study) -> dict[str, float]:
    """Zero time for every analysis the study runs."""
    return dict.fromkeys(("worstcase",) + tuple(o for o in study.outputs if o != "yield" or study.spec)
                         + (("allocation",) if study.allocation else ()), 0.0)


def _analyses(plan: Plan, config: StudyConfiguration, variant: Variant) -> tuple[ConfigurationResult, dict]:
    study, progress, index = plan.study, plan.progress, variant.index
    mc_seed, sobol_seed = plan.montecarlo_seed, plan.sobol_seed
    timings = _timings(study)

    def stage(what: str) -> None:
        if progress:
            print(f"study {study.name} [{index + 1}/{plan.n_tasks}] {config.name}: {what}", file=sys.stderr,
                  flush=True)

    g, b = config.geometry, study.budget
    nx, ny = study.worstcase_grid
    stage(f"exact worst case on {nx} x {ny} poses")
    t = time.perf_counter()
    wc = worst_case(g, b, config.region.grid(study.worstcase_grid), k_sigma=study.k_sigma)
    timings["worstcase"] += time.perf_counter() - t
    kw: dict[str, Any] = {}
    wants_yield = study.spec is not None and "yield" in study.outputs
    no_exact = exact_refusal(b) if wants_yield else None       # correlated inputs not all normal: Monte Carlo
    if wants_yield and no_exact is None:       # before the Monte Carlo run: it counts every channel if this fails
        nx, ny = study.mc_grid
        stage(f"exact yield against the spec on {nx} x {ny} poses")
        t = time.perf_counter()
        try:
            kw["yield_"] = run_yield(config, b, study.spec, study.mc_grid)
        except NoExactYieldError as e:      # no density, too many classes, too many terms: known only by trying
            no_exact = e
        timings["yield"] += time.perf_counter() - t
    draws = None        # the Monte Carlo run's budget draws (its seed): the histograms' and the exceedance curves'
    if "montecarlo" in study.outputs:
        nx, ny = study.mc_grid
        stage(f"Monte Carlo, {study.mc_samples} samples on {nx} x {ny} poses")
        t = time.perf_counter()
        kw["montecarlo"] = monte_carlo(g, b, config.region.grid(study.mc_grid), study.mc_samples,
                                       rng=mc_seed, percentiles=study.percentiles,
                                       tolerance_mm=study.tolerance_mm, progress=progress,
                                       tolerance_phi_deg=_fallback_phi_deg(study) if no_exact is not None else None)
        draws = b.sample(study.mc_samples, mc_seed)
        kw["samples"] = _pose_samples(config, b, wc, draws, mc_seed, study.k_sigma)
        timings["montecarlo"] += time.perf_counter() - t
    if no_exact is not None:
        _no_exact_yield(study, config, no_exact, "P(position > spec)" + (
            ", P(|dphi| > spec) and P(either)" if study.spec.phi_arcsec is not None else "")
                        + " instead, with Wilson 95 % intervals")
    elif "yield_" in kw:
        t = time.perf_counter()
        kw["curves"] = tuple(exceedance_curve(config, b, kw["yield_"], o, draws)
                             for o in ("position",) + (("phi",) if study.spec.phi_arcsec is not None else ()))
        timings["yield"] += time.perf_counter() - t
    draws = None                                  # not held through the Sobol run
    if "sobol" in study.outputs:
        nx, ny = study.sobol_grid
        stage(f"Sobol indices, N = {study.sobol_samples} on {nx} x {ny} poses")
        t = time.perf_counter()
        poses = config.region.grid(study.sobol_grid)
        s = sobol_indices(g, b, poses, study.sobol_samples, rng=sobol_seed,
                          groups=study.sobol_groups or None, outputs=study.sobol_outputs,
                          progress=progress)
        wc_s = worst_case(g, b, poses, k_sigma=study.k_sigma)
        kw["sobol"] = s
        kw["ranking"] = {o: ranking(s, wc_s, output=o) for o in study.sobol_outputs}
        timings["sobol"] += time.perf_counter() - t
    allocation = study.allocation
    if allocation is not None and allocation.applies_to(variant.base.name):  # a swept one: by its base's name
        stage("tolerance allocation" + (" and its Pareto front" if allocation.front else ""))
        t = time.perf_counter()
        kw.update(run_allocation(config, allocation, study.worstcase_grid, study.k_sigma, plan.allocation_seed, b))
        timings["allocation"] += time.perf_counter() - t
    return ConfigurationResult(configuration=config, worst_case=wc, **kw), timings


def _no_exact_yield(study, config, reason, counted: str) -> None:
    """Warn that ``config`` has no exact yield (``reason``) and what the study reports instead: the Monte Carlo
    run's ``counted`` exceedances, or how to get them."""
    warnings.warn(Prp3mcWarning(
        f"study {study.name}: no exact yield for {config.name}: {reason}; "
        + (f"the Monte Carlo run counts {counted}" if "montecarlo" in study.outputs else
           "add montecarlo to the outputs for its Monte Carlo estimate")), stacklevel=3)


class SerialExecutor:
    """Runs the tasks one after the other in this process (the default)."""

    name = "serial"
    in_process = True

    def map(self, fn, tasks: Iterable[tuple]) -> Iterator[tuple[int, Any]]:
        """``(k, fn(*task_k))`` for every task, in order; errors propagate."""
        for k, task in enumerate(tasks):
            yield k, fn(*task)


def _executor(scheduler) -> contextlib.AbstractContextManager:
    """A context giving the executor: serial, a Dask scheduler spec, or an executor object as it is."""
    if scheduler is None:
        return contextlib.nullcontext(SerialExecutor())
    if isinstance(scheduler, str):
        from .distributed import DaskExecutor  # imports dask only when entered
        return DaskExecutor(scheduler)
    return contextlib.nullcontext(scheduler)


def run_study(study: "Study | str | os.PathLike", *, rng: "None | int | np.random.Generator" = None,
              progress: bool | None = None, budget: Budget | None = None,
              scheduler: "str | Any | None" = None) -> StudyResult:
    """Run every analysis of every configuration of a study (every combination of its sweep).

    Parameters
    ----------
    study : Study, study file or bundled study name
    rng : None, int or numpy.random.Generator
        Overrides the study's seed (Scientific Python SPEC 7: a seed, or a
        Generator a seed is drawn from); with neither, a fresh seed. The
        study seed used is recorded, and the Monte Carlo and Sobol seeds are
        derived from it.
    progress : bool, optional
        Report each stage, and the progress of the long ones, on stderr
        (default: when stderr is a terminal).
    budget : Budget, optional
        Replace the study's budget (what-if runs).
    scheduler : str or executor, optional
        None: run in this process. ``"local:N"``: on a Dask LocalCluster of N
        worker processes; ``"tcp://HOST:PORT"``: on that Dask scheduler (see
        :mod:`prp3mc.study.distributed`; needs ``pip install 'prp3mc[dask]'``).
        Or an object with ``map(fn, tasks)`` yielding ``(k, result or
        exception)`` and a ``name``. The numbers do not depend on it.

    Returns
    -------
    StudyResult
        Swept configurations that are infeasible or fail are in ``skipped``.
    """
    t0 = time.perf_counter()
    study = Study.load(study)
    if budget is not None:
        study = study.with_budget(budget)
    seed, _ = resolve_rng(rng if rng is not None else study.seed)
    mc_seed, sobol_seed = child_seed(seed, 1), child_seed(seed, 2)
    show = sys.stderr.isatty() if progress is None else progress
    allocation_seed = child_seed(seed, ALLOCATION_STREAM) if study.allocation is not None else None
    variants = expand(study)
    outcomes: dict[int, Outcome] = {}
    with _executor(scheduler) as executor:
        in_process = getattr(executor, "in_process", False)
        plan = Plan(replace(study, configurations=()), mc_seed, sobol_seed, allocation_seed, len(variants),
                    progress=bool(show and in_process))
        for k, value in executor.map(run_configuration, [(plan, v) for v in variants]):
            if isinstance(value, BaseException):  # the task itself was lost (a worker died too often)
                if not variants[k].parameters:
                    raise value
                value = _skip(variants[k], "failed", value)
            outcomes[k] = value
            if show and not in_process:
                what = "done" if value.result is not None else f"{value.skipped.kind}: {value.skipped.reason}"
                print(f"study {study.name} [{len(outcomes)}/{len(variants)}] {variants[k].name}: {what}",
                      file=sys.stderr, flush=True)
        name = executor.name
    ordered = [outcomes[k] for k in range(len(variants))]
    timings = _timings(study)
    for o in ordered:
        for key, v in o.timings_s.items():
            timings[key] += v
    return StudyResult(study=study, seed=seed, montecarlo_seed=mc_seed, sobol_seed=sobol_seed,
                       configurations=tuple(o.result for o in ordered if o.result is not None),
                       timings_s=timings, wall_time_s=time.perf_counter() - t0,
                       skipped=tuple(o.skipped for o in ordered if o.skipped is not None), scheduler=name,
                       allocation_seed=allocation_seed)
