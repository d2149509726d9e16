"""Benchmark of the Sobol pipeline over the reference test regions, against SALib's own analysis.

``bench_sobol(quick)`` times the whole pipeline a study runs: Sobol indices of
all four outputs on a 21 x 21 grid over each reference test region
(N = 8192 in 16 replicates, with the Shapley effects; N = 1024 with ``quick``), the exact worst
case, and the ranking tables of every output next to the worst-case
contributions. SALib's ``sobol.analyze`` (one call per pose, output and
problem) is timed on a few poses and scaled to the same grids.

At one pose (``bench_sobol_pose``) prp3mc's Sobol path (Saltelli design in 16
replicates, model, first and total indices of four outputs with their
intervals; no Shapley effects) is timed against OpenTURNS'
``SaltelliSensitivityAlgorithm`` on the same problem (the budget as
:func:`~prp3mc.model.interop.openturns_distribution`, the same linear
model, the same N, its intervals by a bootstrap of 100), when OpenTURNS is
installed. OpenTURNS estimates the 12 inputs only; prp3mc adds the three
clearance groups (15 columns of the design instead of 12). Wall and CPU
times are both reported (the machine may be shared).

Usage: ``python benchmarks/bench_sobol.py [--quick]`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from prp3mc import Budget, Geometry, Region, linear_model, worst_case
from prp3mc.sobol.ranking import ranking
from prp3mc.sobol.indices import sobol_indices

PRESETS = ("u-shape", "delta-shape")


def _pipeline(n_samples: int) -> tuple[float, float]:
    """Wall time of indices + worst case + rankings on both 21x21 grids, and the widest half-width."""
    budget = Budget.from_preset("paper")
    widest = 0.0
    t0 = time.perf_counter()
    for preset in PRESETS:
        geometry, grid = Geometry.from_preset(preset), Region.from_preset(preset).grid(21)
        result = sobol_indices(geometry, budget, grid, n_samples, rng=1, method="vectorised")
        wc = worst_case(geometry, budget, grid)
        for output in result.outputs:
            ranking(result, wc, output)
        widest = max(widest, float(result.ST_conf.max()), float(result.S1_conf.max()))
    return time.perf_counter() - t0, widest


def bench_sobol(quick: bool) -> dict:
    """Whole 21x21 Sobol ranking on both test regions; SALib's analysis scaled from a few poses."""
    n_samples = 1024 if quick else 8192
    seconds, widest = min(_pipeline(n_samples) for _ in range(1 if quick else 2))
    budget = Budget.from_preset("paper")
    geometry = Geometry.from_preset("u-shape")
    poses = Region.from_preset("u-shape").grid(21).reshape(-1, 3)[::220]
    timed = {}
    for method in ("salib", "vectorised"):
        t0 = time.perf_counter()
        sobol_indices(geometry, budget, poses, n_samples, rng=1, method=method)
        timed[method] = time.perf_counter() - t0
    n_grid = len(PRESETS) * 21 * 21
    salib = (timed["salib"] - timed["vectorised"]) / len(poses) * n_grid
    return {
        "sobol_n_samples": n_samples,
        "sobol_grid21_seconds": seconds,
        "sobol_grid21_poses_per_s": n_grid / seconds,
        "sobol_grid21_widest_halfwidth": widest,
        "sobol_salib_grid21_seconds_estimate": salib,
        "sobol_speedup_vs_salib": salib / seconds,
    }


def _timed(fn, repeat: int) -> tuple[float, float]:
    """Smallest wall and CPU times of ``repeat`` calls, s."""
    best = (np.inf, np.inf)
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = (min(best[0], time.perf_counter() - t0), min(best[1], time.process_time() - c0))
    return best


def bench_sobol_pose(quick: bool) -> dict:
    """Sobol at one pose, prp3mc's replicated design against OpenTURNS' Saltelli estimator with bootstrap."""
    n_samples, resamples = (1024 if quick else 8192), 100
    geometry, budget, pose = Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0.0, 100.0, 0.0]
    ours = lambda: sobol_indices(geometry, budget, pose, n_samples, rng=1, shapley_permutations=0)  # noqa: E731
    ours()
    result = {"sobol_pose_n_samples": n_samples}
    result["sobol_pose_seconds"], result["sobol_pose_cpu_seconds"] = _timed(ours, 2 if quick else 3)
    try:
        import openturns as ot
    except ImportError:
        return result
    from prp3mc.model.interop import openturns_distribution
    model, dist = linear_model(geometry, budget, pose), openturns_distribution(budget)

    def four_outputs(X):
        E = model.evaluate(np.asarray(X))
        return np.column_stack([E[:, 0], E[:, 1], E[:, 2], np.hypot(E[:, 0], E[:, 1])])

    function = ot.PythonFunction(dist.getDimension(), 4, func_sample=four_outputs)

    def theirs():
        ot.RandomGenerator.SetSeed(1)
        X = ot.SobolIndicesExperiment(dist, n_samples).generate()
        algo = ot.SaltelliSensitivityAlgorithm(X, function(X), n_samples)
        algo.setBootstrapSize(resamples)
        for o in range(4):
            algo.getFirstOrderIndices(o), algo.getTotalOrderIndices(o)
        algo.getFirstOrderIndicesInterval(), algo.getTotalOrderIndicesInterval()

    theirs()
    result["ot_sobol_pose_seconds"], result["ot_sobol_pose_cpu_seconds"] = _timed(theirs, 2 if quick else 3)
    result["sobol_pose_ratio_to_ot_wall"] = result["sobol_pose_seconds"] / result["ot_sobol_pose_seconds"]
    result["sobol_pose_ratio_to_ot_cpu"] = result["sobol_pose_cpu_seconds"] / result["ot_sobol_pose_cpu_seconds"]
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 1024 instead of 8192")
    args = parser.parse_args(argv)
    json.dump({**bench_sobol(args.quick), **bench_sobol_pose(args.quick)}, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
