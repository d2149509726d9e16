"""Monte Carlo throughput and memory against the obvious numpy code and the machine's limits.

Figures (paper budget, U-shape), each timed with its wall and CPU time and the
1-minute load average right after it (the machine may be shared):
- 21 x 21 poses x 2^20 samples (2^18 with ``quick``): pose-samples/s of
  :func:`prp3mc.monte_carlo` (all summaries: moments with standard errors,
  exact percentiles with intervals, maxima, means) against the obvious numpy
  code on the same samples: per pose one small matrix product, a norm and
  ``np.percentile`` (no standard errors, no intervals: less work).
- one pose x 2^24 samples (2^22): samples/s, against the same numpy code.
- peak memory (the high-water mark of a fresh process) and rate of one pose at 1e8
  samples (and 1e9 with ``--huge``); the obvious code would hold the samples,
  their features and the errors: (d + F + 3) x 8 bytes a sample (not run).
- the limits, measured in the same run: a pose-sample costs ~72 flops (a 3 x 12
  by 12 product), so the float32 matrix-product rate (all cores) / 72; and, for
  one pose, the rate at which the d uniforms of a sample are drawn alone (the
  compiled PCG64 lanes, one per core), which a Monte Carlo on numpy's random
  numbers pays before it computes anything; numpy's own ``Generator.random``
  drawing them is reported beside it.

Usage: ``python benchmarks/bench_montecarlo.py [--quick] [--huge]`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from prp3mc import Budget, Geometry, Region, linear_model, monte_carlo
from prp3mc.montecarlo._kernel import TILE
from prp3mc.montecarlo._sampler import draw_uniforms, pcg_lanes

FLOPS_PER_POSE_SAMPLE = 72
PERCENTILES = (50.0, 95.0, 99.0, 99.73)


def timed(fn, repeat: int = 1) -> tuple[float, float, float]:
    """(wall s, CPU s, 1-minute load) of the fastest of ``repeat`` calls (all threads' CPU time)."""
    best = (np.inf, np.inf)
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = min(best, (time.perf_counter() - t0, time.process_time() - c0))
    return best[0], best[1], os.getloadavg()[0]


def peak_flops(dtype=np.float32, size: int = 4096, repeat: int = 3) -> float:
    """Best rate of a large square matrix product (flop/s, all cores via BLAS)."""
    a = np.random.default_rng(0).random((size, size)).astype(dtype)
    return 2.0 * size**3 / timed(lambda: a @ a, repeat)[0]


def _on_all_cores(work, repeat: int = 3) -> float:
    """Wall time of ``work(k)`` for k = 0 .. cores - 1 in as many threads."""
    workers = os.cpu_count() or 1
    with ThreadPoolExecutor(workers) as pool:
        return timed(lambda: list(pool.map(work, range(workers))), repeat)[0]


def uniform_rates(d: int, n: int = 1 << 23) -> tuple[float, float]:
    """Samples/s at which d uniforms a sample are drawn, on all cores: by numpy's Generator, and compiled.

    The compiled lanes (:func:`prp3mc.montecarlo._sampler.draw_uniforms`) draw
    the same numbers as numpy: their rate bounds a Monte Carlo on them.
    """
    workers = os.cpu_count() or 1
    per = n // workers // TILE * TILE
    gens = [np.random.default_rng(k) for k in range(workers)]
    bufs = [np.empty((per, d)) for _ in range(workers)]
    numpy_wall = _on_all_cores(lambda k: gens[k].random(out=bufs[k]))
    lanes = [pcg_lanes(k, 0, d) for k in range(workers)]
    tiles = [np.empty((d, TILE)) for _ in range(workers)]

    def compiled(k):
        for _ in range(per // TILE):
            draw_uniforms(*lanes[k], tiles[k])

    compiled(0)
    return workers * per / numpy_wall, workers * per / _on_all_cores(compiled)


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


def peak_memory(n: int) -> dict:
    """Peak resident memory (GB) and rate of a fresh process running one pose with ``n`` samples.

    The peak is the child's own high-water mark (``VmHWM``, Linux), not ``ru_maxrss``: a
    forked child's ``ru_maxrss`` keeps the parent's size at the fork, so it would report
    this benchmark's memory instead (the 4.4 GB once printed for 1e8 samples).
    """
    code = ("import resource, time, prp3mc; g = prp3mc.Geometry.from_preset('u-shape'); "
            "b = prp3mc.Budget.from_preset('paper'); t = time.perf_counter(); "
            f"prp3mc.monte_carlo(g, b, [0.0, 100.0, 0.0], {n}, rng=1); s = time.perf_counter() - t\n"
            "try:\n"
            "    kib = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM'))\n"
            "except OSError:\n"
            "    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            "print(s, kib)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    seconds, kib = out.stdout.split()[-2:]
    return {"peak_gb": int(kib) * 1024 / 1e9, "samples_per_s": n / float(seconds), "load": os.getloadavg()[0]}


def bench_montecarlo(quick: bool, huge: bool = False) -> dict:
    g, budget = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    grid = Region.from_preset("u-shape").grid(21)
    pose = np.array([0.0, 100.0, 0.0])
    monte_carlo(g, budget, grid[:2, :2], 10_000, rng=0)  # compile / load the kernels
    repeat = 1 if quick else 3
    n_grid = 1 << (18 if quick else 20)
    n_pose = 1 << (22 if quick else 24)
    P = grid[..., 0].size
    r = {"mc_grid_poses": P, "mc_grid_samples": n_grid, "mc_pose_samples": n_pose}
    for key, (poses, n, count) in {"mc_grid": (grid, n_grid, P * n_grid), "mc_pose": (pose, n_pose, n_pose)}.items():
        wall, cpu, load = timed(lambda: monte_carlo(g, budget, poses, n, rng=1), repeat)
        r[f"{key}_rate"], r[f"{key}_rate_cpu"], r[f"{key}_load"] = count / wall, count / cpu, load
        wall, cpu, load = timed(lambda: obvious_numpy(g, budget, poses, n, 1))
        r[f"{key}_numpy_rate"], r[f"{key}_numpy_rate_cpu"], r[f"{key}_numpy_load"] = count / wall, count / cpu, load
        r[f"{key}_speedup_vs_numpy"] = r[f"{key}_rate"] / r[f"{key}_numpy_rate"]
    flops = peak_flops()
    r["peak_float32_flops"] = flops
    r["mc_limit_pose_samples_per_s"] = flops / FLOPS_PER_POSE_SAMPLE
    r["mc_grid_fraction_of_limit"] = r["mc_grid_rate"] / r["mc_limit_pose_samples_per_s"]
    r["mc_uniforms_numpy_samples_per_s"], r["mc_uniforms_limit_samples_per_s"] = uniform_rates(len(budget))
    r["mc_pose_fraction_of_uniforms_limit"] = r["mc_pose_rate"] / r["mc_uniforms_limit_samples_per_s"]
    n_feat = linear_model(g, budget, pose).coef.shape[-1]
    for n in ([] if quick else [10**8]) + ([10**9] if huge else []):
        tag = f"mc_pose_1e{len(str(n)) - 1}"
        r.update({f"{tag}_{k}": v for k, v in peak_memory(n).items()})
        r[f"{tag}_numpy_gb"] = n * (len(budget) + n_feat + 3) * 8 / 1e9
    r["load_average_1min"] = os.getloadavg()[0]
    return r


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
