"""Monte Carlo throughput and memory against the obvious numpy code and the machine's flop limit.

Figures (paper budget, U-shape):
- 21 x 21 poses x 2^20 samples (2^18 with ``quick``): pose-samples/s of
  :func:`prp3mc.monte_carlo` (all summaries: moments with standard errors,
  exact percentiles with intervals, maxima, means) against the obvious numpy
  code on the same samples: per pose one small matrix product, a norm and
  ``np.percentile`` (no standard errors, no intervals: less work).
- one pose x 2^24 samples (2^22): samples/s, against the same numpy code.
- peak memory of one pose at 1e8 samples (and 1e9 with ``--huge``), each in
  a fresh process (``ru_maxrss``).
- the limit: a pose-sample costs ~72 flops (a 3 x 12 by 12 product), so the
  machine's float32 matrix-product rate (measured here, all cores) / 72.

Usage: ``python benchmarks/bench_montecarlo.py [--quick] [--huge]`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

from prp3mc import Budget, Geometry, Region, linear_model, monte_carlo

FLOPS_PER_POSE_SAMPLE = 72
PERCENTILES = (50.0, 95.0, 99.0, 99.73)


def peak_flops(dtype=np.float32, size: int = 4096, repeat: int = 3) -> float:
    """Best rate of a large square matrix product (flop/s, all cores via BLAS)."""
    a = np.random.default_rng(0).random((size, size)).astype(dtype)
    best = min(_timed(lambda: a @ a) for _ in range(repeat))
    return 2.0 * size**3 / best


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def obvious_numpy(geometry, budget, poses, n: int, seed: int):
    """The obvious code: features once, then per pose a (3, F) @ (F, n) product, a norm, np.percentile."""
    model = linear_model(geometry, budget, poses)
    F = model.features(budget.sample(n, seed)).T
    out = []
    for c in model.coef.reshape(-1, 3, F.shape[0]):
        D = c @ F
        pos = np.hypot(D[0], D[1])
        out.append((D.mean(1), np.cov(D), np.percentile(pos, PERCENTILES), np.percentile(np.abs(D[2]), PERCENTILES)))
    return out


def _best(fn, repeat: int) -> float:
    return min(_timed(fn) for _ in range(repeat))


def peak_memory_gb(n: int) -> float:
    """Peak resident memory (GB) of a fresh process running one pose with ``n`` samples."""
    code = ("import resource, prp3mc; g = prp3mc.Geometry.from_preset('u-shape'); "
            "b = prp3mc.Budget.from_preset('paper'); "
            f"prp3mc.monte_carlo(g, b, [0.0, 100.0, 0.0], {n}, rng=1); "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1]) / 1e6, time.perf_counter() - t0


def bench_montecarlo(quick: bool, huge: bool = False) -> dict:
    g, budget = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    grid = Region.from_preset("u-shape").grid(21)
    pose = np.array([0.0, 100.0, 0.0])
    monte_carlo(g, budget, grid[:2, :2], 10_000, rng=0)  # compile / load the kernels
    repeat = 1 if quick else 2
    n_grid = 1 << (18 if quick else 20)
    n_pose = 1 << (22 if quick else 24)
    P = grid[..., 0].size
    t_grid = _best(lambda: monte_carlo(g, budget, grid, n_grid, rng=1), repeat)
    t_grid_np = _best(lambda: obvious_numpy(g, budget, grid, n_grid, 1), 1)
    t_pose = _best(lambda: monte_carlo(g, budget, pose, n_pose, rng=1), repeat)
    t_pose_np = _best(lambda: obvious_numpy(g, budget, pose, n_pose, 1), 1)
    flops = peak_flops()
    result = {
        "mc_grid_poses": P, "mc_grid_samples": n_grid,
        "mc_grid_pose_samples_per_s": P * n_grid / t_grid,
        "mc_grid_numpy_pose_samples_per_s": P * n_grid / t_grid_np,
        "mc_grid_speedup_vs_numpy": t_grid_np / t_grid,
        "mc_pose_samples": n_pose,
        "mc_pose_samples_per_s": n_pose / t_pose,
        "mc_pose_numpy_samples_per_s": n_pose / t_pose_np,
        "mc_pose_speedup_vs_numpy": t_pose_np / t_pose,
        "peak_float32_flops": flops,
        "mc_limit_pose_samples_per_s": flops / FLOPS_PER_POSE_SAMPLE,
        "mc_grid_fraction_of_limit": P * n_grid / t_grid / (flops / FLOPS_PER_POSE_SAMPLE),
    }
    for n in ([] if quick else [10**8]) + ([10**9] if huge else []):
        gb, seconds = peak_memory_gb(n)
        result[f"mc_pose_1e{len(str(n)) - 1}_peak_gb"] = gb
        result[f"mc_pose_1e{len(str(n)) - 1}_samples_per_s"] = n / seconds
    result["load_average_1min"] = os.getloadavg()[0]
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--huge", action="store_true", help="also 1e9 samples at one pose")
    args = parser.parse_args(argv)
    json.dump(bench_montecarlo(args.quick, args.huge), sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
