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

import prp3mc
from prp3mc import Geometry, Region, sensitivity


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


BENCHES = [bench_sensitivity]


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
