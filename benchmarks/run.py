"""Benchmarks of prp3mc, each reported as a rate and as a ratio against the
obvious alternative measured in the same run.

Usage: ``python benchmarks/run.py [--quick] [--json]``. With ``--json`` one JSON
object is printed on stdout; otherwise a readable table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from bench_sobol import bench_sobol

import prp3mc
from prp3mc import Budget, Geometry, Region, linear_model, monte_carlo, sensitivity, worst_case
from prp3mc.uncertainty.crosscheck import optimizer_worst_case


def best_of(fn, repeat: int) -> float:
    """Smallest wall time of ``repeat`` calls, s."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_sensitivity(quick: bool) -> dict:
    """All ten J_q on the U-shape 201x201 grid, against a per-pose loop."""
    g = Geometry.from_preset("u-shape")
    grid = Region.from_preset("u-shape").grid(201)
    t_batch = best_of(lambda: sensitivity(g, grid), 2 if quick else 5)
    flat = grid.reshape(-1, 3)[:: 50 if quick else 10]
    t_loop = best_of(lambda: [sensitivity(g, p) for p in flat], 1) / len(flat) * grid[..., 0].size
    return {
        "sensitivity_grid_201_seconds": t_batch,
        "sensitivity_poses_per_s": grid[..., 0].size / t_batch,
        "sensitivity_loop_seconds_estimate": t_loop,
        "sensitivity_speedup_vs_loop": t_loop / t_batch,
    }


def bench_worstcase(quick: bool) -> dict:
    """Exact envelope on the U-shape 201x201 grid, against differential evolution per pose."""
    g, budget = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    grid = Region.from_preset("u-shape").grid(201)
    worst_case(g, budget, grid)  # warm-up
    t = best_of(lambda: worst_case(g, budget, grid), 3 if quick else 10)
    rate = grid[..., 0].size / t
    region = Region.from_preset("u-shape")
    poses = region.grid(2 if quick else 3).reshape(-1, 3)[: 2 if quick else 5]
    runs = [optimizer_worst_case(g, budget, p, rng=k, maxiter=100 if quick else 300) for k, p in enumerate(poses)]
    exact = worst_case(g, budget, poses).position_mm
    found = np.array([r.position_mm for r in runs])
    de_s = float(np.mean([r.seconds for r in runs]))
    return {
        "worstcase_grid_201_seconds": t,
        "worstcase_poses_per_s": rate,
        "de_poses": len(poses),
        "de_seconds_per_pose": de_s,
        "de_evaluations_per_pose": float(np.mean([r.n_evaluations for r in runs])),
        "de_shortfall_max_rel": float(np.max((exact - found) / exact)),
        "de_shortfall_min_rel": float(np.min((exact - found) / exact)),
        "worstcase_speedup_vs_de": de_s * rate,
    }


def naive_monte_carlo(g, budget, poses, n):
    """The obvious implementation: a Python loop over samples, J_q products per sample, np.percentile."""
    J = sensitivity(g, poses).J
    X = budget.sample(n, 0)
    names = budget.names
    idx = {f: [names.index(f"{f}_{i}") for i in (1, 2, 3)] for f in ("rho", "zeta", "theta", "b")}
    omega = linear_model(g, budget, poses).omega
    out = np.empty((n,) + poses.shape[:-1] + (3,))
    for k in range(n):
        x = X[k]
        rho = x[idx["rho"]] * np.cos(np.deg2rad(x[idx["zeta"]]) - omega)
        out[k] = (np.einsum("...ij,...j->...i", J["rho"], rho)
                  + np.einsum("...ij,j->...i", J["theta"], np.deg2rad(x[idx["theta"]]))
                  + np.einsum("...ij,j->...i", J["b"], x[idx["b"]]))
    pos = np.hypot(out[..., 0], out[..., 1])
    phi = np.abs(out[..., 2])
    q = [50, 95, 99, 99.73]
    return out.mean(0), out.std(0), np.percentile(pos, q, axis=0), np.percentile(phi, q, axis=0)


def bench_montecarlo(quick: bool) -> dict:
    """Paper budget, U-shape 21x21 grid, full summaries, against the per-sample loop."""
    g, budget = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    grid = Region.from_preset("u-shape").grid(21)
    n = 200_000 if quick else 1_000_000
    monte_carlo(g, budget, grid, 20_000, rng=0)  # warm-up
    t = best_of(lambda: monte_carlo(g, budget, grid, n, rng=1), 1 if quick else 3)
    n_naive = 500 if quick else 2000
    t_naive = best_of(lambda: naive_monte_carlo(g, budget, grid, n_naive), 1)
    rate, naive = grid[..., 0].size * n / t, grid[..., 0].size * n_naive / t_naive
    return {
        "mc_poses": int(grid[..., 0].size), "mc_samples": n, "mc_seconds": t,
        "mc_pose_samples_per_s": rate, "mc_naive_pose_samples_per_s": naive,
        "mc_speedup_vs_naive": rate / naive,
    }


BENCHES = [bench_sensitivity, bench_worstcase, bench_montecarlo, bench_sobol]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller problems, fewer repeats")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    result = {"prp3mc_version": prp3mc.__version__, "quick": args.quick}
    for bench in BENCHES:
        result.update(bench(args.quick))
    if args.json:
        json.dump(result, sys.stdout, indent=2)
        print()
    else:
        for key, value in result.items():
            print(f"{key:45s} {value:.4g}" if isinstance(value, float) else f"{key:45s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
