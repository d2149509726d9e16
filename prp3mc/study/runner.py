"""Running a study: every analysis of every configuration, batched over the poses.

:func:`run_study` takes a :class:`~prp3mc.study.reader.Study` (or a study
file, or the name of a bundled study) and returns a
:class:`~prp3mc.study.results.StudyResult`;
:func:`prp3mc.reports.study_report.write_study` writes its report, figures,
tables and ``summary.json`` (``prp3mc study FILE.toml --out DIR``).

Randomness: the study seed gives one Monte Carlo seed and one Sobol seed,
shared by all configurations (common random numbers, so differences between
configurations are not blurred by sampling noise), and the seed of the
allocation's Monte Carlo confirmation (stream 3, also shared).
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

import numpy as np

from .._rng import child_seed, resolve_rng
from ..uncertainty.budget import Budget
from ..uncertainty.model import linear_model
from ..uncertainty.montecarlo import monte_carlo
from ..uncertainty.ranking import ranking
from ..uncertainty.sobol import sobol_indices
from ..uncertainty.worstcase import WorstCase, worst_case
from ..units import RAD2DEG
from .allocation import ALLOCATION_STREAM, run_allocation
from .reader import Study, StudyConfiguration
from .results import ConfigurationResult, PoseSamples, StudyResult

__all__ = ["run_study"]


def _histogram_poses(config: StudyConfiguration, wc: WorstCase) -> tuple[np.ndarray, tuple]:
    """Poses of the histograms: the configuration's, or centre, worst-case max and min."""
    if config.poses is not None:
        return np.asarray(config.poses), tuple(f"({x:g}, {y:g}, {p:g})" for x, y, p in config.poses)
    r = config.region
    flat = wc.poses.reshape(-1, 3)
    pos = wc.position_mm.ravel()
    centre = [0.5 * sum(r.x_mm), 0.5 * sum(r.y_mm), r.phi_deg]
    return (np.array([centre, flat[np.argmax(pos)], flat[np.argmin(pos)]]),
            ("centre", "worst-case max", "worst-case min"))


def _pose_samples(config: StudyConfiguration, budget: Budget, wc: WorstCase, n: int, seed: int,
                  k_sigma: float | None) -> PoseSamples:
    poses, labels = _histogram_poses(config, wc)
    X = budget.sample(n, seed)  # the Monte Carlo run's samples (same seed)
    err = linear_model(config.geometry, budget, poses).evaluate(X)      # (P, n, 3) mm, mm, rad
    at = worst_case(config.geometry, budget, poses, k_sigma=k_sigma)
    return PoseSamples(poses=poses, labels=labels, position_mm=np.hypot(err[..., 0], err[..., 1]),
                       phi_deg=np.abs(err[..., 2]) * RAD2DEG, worst_position_mm=at.position_mm,
                       worst_phi_deg=at.phi_deg, seed=seed, n_samples=n)


def run_study(study: "Study | str | os.PathLike", *, rng: "None | int | np.random.Generator" = None,
              progress: bool | None = None,
              budget: Budget | None = None) -> StudyResult:
    """Run every analysis of a study for every configuration.

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

    Returns
    -------
    StudyResult
    """
    t0 = time.perf_counter()
    study = Study.load(study)
    if budget is not None:
        study = study.with_budget(budget)
    seed, _ = resolve_rng(rng if rng is not None else study.seed)
    mc_seed, sobol_seed = child_seed(seed, 1), child_seed(seed, 2)
    timings = dict.fromkeys(("worstcase",) + study.outputs, 0.0)
    show = sys.stderr.isatty() if progress is None else progress
    steps = len(study.configurations) * len(timings)
    allocation, allocation_seed = study.allocation, None
    if allocation is not None:
        allocation_seed = child_seed(seed, ALLOCATION_STREAM)
        timings["allocation"] = 0.0
        steps += sum(allocation.applies_to(c.name) for c in study.configurations)
    done = 0

    def stage(config: StudyConfiguration, what: str) -> None:
        nonlocal done
        done += 1
        if show:
            print(f"study {study.name} [{done}/{steps}] {config.name}: {what}", file=sys.stderr, flush=True)

    results = []
    for config in study.configurations:  # a handful of configurations; each analysis is batched
        g, b = config.geometry, study.budget
        nx, ny = study.worstcase_grid
        stage(config, f"exact worst case on {nx} x {ny} poses")
        t = time.perf_counter()
        wc = worst_case(g, b, config.region.grid(study.worstcase_grid), k_sigma=study.k_sigma)
        timings["worstcase"] += time.perf_counter() - t
        kw: dict[str, Any] = {}
        if "montecarlo" in study.outputs:
            nx, ny = study.mc_grid
            stage(config, f"Monte Carlo, {study.mc_samples} samples on {nx} x {ny} poses")
            t = time.perf_counter()
            kw["montecarlo"] = monte_carlo(g, b, config.region.grid(study.mc_grid), study.mc_samples,
                                           rng=mc_seed, percentiles=study.percentiles,
                                           tolerance_mm=study.tolerance_mm, progress=progress)
            kw["samples"] = _pose_samples(config, b, wc, study.mc_samples, mc_seed, study.k_sigma)
            timings["montecarlo"] += time.perf_counter() - t
        if "sobol" in study.outputs:
            nx, ny = study.sobol_grid
            stage(config, f"Sobol indices, N = {study.sobol_samples} on {nx} x {ny} poses")
            t = time.perf_counter()
            poses = config.region.grid(study.sobol_grid)
            s = sobol_indices(g, b, poses, study.sobol_samples, rng=sobol_seed,
                              groups=study.sobol_groups or None, outputs=study.sobol_outputs,
                              progress=progress)
            wc_s = worst_case(g, b, poses, k_sigma=study.k_sigma)
            kw["sobol"] = s
            kw["ranking"] = {o: ranking(s, wc_s, output=o) for o in study.sobol_outputs}
            timings["sobol"] += time.perf_counter() - t
        if allocation is not None and allocation.applies_to(config.name):
            stage(config, "tolerance allocation" + (" and its Pareto front" if allocation.front else ""))
            t = time.perf_counter()
            kw.update(run_allocation(config, allocation, study.worstcase_grid, study.k_sigma, allocation_seed))
            timings["allocation"] += time.perf_counter() - t
        results.append(ConfigurationResult(configuration=config, worst_case=wc, **kw))
    return StudyResult(study=study, seed=seed, montecarlo_seed=mc_seed, sobol_seed=sobol_seed,
                       configurations=tuple(results), timings_s=timings,
                       wall_time_s=time.perf_counter() - t0, allocation_seed=allocation_seed)
