"""The one-pose Monte Carlo and its numpy alternative, two source trees taking turns.

Usage: ``python benchmarks/bench_mc_pose_trees.py OLD_TREE NEW_TREE [--turns N] [--calls K]
[--log2-samples E] [--json FILE]``, each tree a checkout of prp3mc (``git archive COMMIT | tar -x
-C DIR``). Each turn runs each tree once, in a fresh process under ``nice -n 5`` (``PYTHONPATH=TREE``,
cwd ``TREE``, so every import is the tree's own, its ``benchmarks/bench_montecarlo.py`` included),
the trees' order alternating between turns. In that process, after the kernels are compiled (or
loaded from the tree's numba cache) by a small grid and a small one-pose run:

- ``monte_carlo`` at one pose (paper budget, U-shape, pose (0, 100, 0)) with 2^E samples
  (E = 22, ``run.py --quick``'s size), K calls;
- the tree's ``obvious_numpy`` on the same problem (its numpy alternative), K calls;
- the tree's ``uniform_rates`` (the d uniforms drawn alone, numpy's Generator and the compiled
  PCG64 lanes on all cores: the "uniforms limit"), and the compiled lanes' rate per CPU second
  on one thread.

Every call is timed by wall and process CPU time (all threads) with the 1-minute load after it;
the table gives medians over all calls of all turns, the spread (smallest-largest), and the
ratios ``run.py`` reports (``mc_pose_speedup_vs_numpy``, ``mc_pose_fraction_of_uniforms_limit``)
by wall time as ``run.py`` computes them and by CPU time, which a shared machine disturbs less.

Written for issue 23's unsettled one-pose ratio (session 25); the figures are in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _timed(fn) -> dict:
    """Wall and process CPU seconds of one call and the 1-minute load after it."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0, "load": os.getloadavg()[0]}


def child(log2_samples: int, calls: int) -> dict:
    """Run in the tree (cwd): compile, then time the one-pose Monte Carlo, numpy, and the uniforms."""
    import numpy as np
    sys.path.insert(0, str(Path.cwd() / "benchmarks"))
    import bench_montecarlo as bm

    g, budget = bm.Geometry.from_preset("u-shape"), bm.Budget.from_preset("paper")
    pose, n = np.array([0.0, 100.0, 0.0]), 1 << log2_samples
    out = {"compile": _timed(lambda: (bm.monte_carlo(g, budget, bm.Region.from_preset("u-shape").grid(21)[:2, :2],
                                                     10_000, rng=0),
                                      bm.monte_carlo(g, budget, pose, 10_000, rng=0)))}
    out["mc"] = [_timed(lambda: bm.monte_carlo(g, budget, pose, n, rng=1)) for _ in range(calls)]
    out["numpy"] = [_timed(lambda: bm.obvious_numpy(g, budget, pose, n, 1)) for _ in range(calls)]
    d = len(budget)
    numpy_rate, compiled_rate = bm.uniform_rates(d)
    out["uniforms"] = {"numpy_rate": numpy_rate, "limit_rate": compiled_rate, "load": os.getloadavg()[0]}
    lanes, tile = bm.pcg_lanes(0, 0, d), np.empty((d, bm.TILE))
    tiles = (1 << 22) // bm.TILE

    def draw():
        for _ in range(tiles):
            bm.draw_uniforms(*lanes, tile)
    draw()
    m = _timed(draw)
    out["uniforms"]["lane_rate_per_cpu"] = tiles * bm.TILE / m["cpu"]
    out["n"] = n
    return out


def run_tree(tree: Path, log2_samples: int, calls: int) -> dict:
    """One fresh process on ``tree``'s code, under ``nice -n 5``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    proc = subprocess.run(["nice", "-n", "5", sys.executable, str(Path(__file__).resolve()), "--child",
                           "--log2-samples", str(log2_samples), "--calls", str(calls)],
                          cwd=tree, env=env, capture_output=True, text=True)
    if proc.returncode:
        raise RuntimeError(f"{tree} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout)


def summary(runs: list[dict]) -> dict:
    """Rates (samples/s by wall and per CPU-s) and the two ratios, as medians and spreads over calls."""
    n = runs[0]["n"]
    mc = [c for r in runs for c in r["mc"]]
    npy = [c for r in runs for c in r["numpy"]]
    lim = [r["uniforms"]["limit_rate"] for r in runs]
    lane = [r["uniforms"]["lane_rate_per_cpu"] for r in runs]
    s = {"mc_wall": [n / c["wall"] for c in mc], "mc_cpu": [n / c["cpu"] for c in mc],
         "numpy_wall": [n / c["wall"] for c in npy], "numpy_cpu": [n / c["cpu"] for c in npy],
         "limit_wall": lim, "lane_cpu": lane, "load": [c["load"] for c in mc + npy],
         "compile_cpu": [r["compile"]["cpu"] for r in runs]}
    # the ratios per process, as run.py computes them (its calls in one process) and by CPU time
    s["speedup_wall"] = [statistics.median(n / c["wall"] for c in r["mc"]) /
                         statistics.median(n / c["wall"] for c in r["numpy"]) for r in runs]
    s["speedup_cpu"] = [statistics.median(n / c["cpu"] for c in r["mc"]) /
                        statistics.median(n / c["cpu"] for c in r["numpy"]) for r in runs]
    s["fraction_wall"] = [statistics.median(n / c["wall"] for c in r["mc"]) / r["uniforms"]["limit_rate"]
                          for r in runs]
    # per CPU-s of the kernel (all threads) against per CPU-s of one lane drawing the uniforms alone
    s["fraction_cpu"] = [statistics.median(n / c["cpu"] for c in r["mc"]) / r["uniforms"]["lane_rate_per_cpu"]
                         for r in runs]
    return s


ROWS = (("mc_wall", "Monte Carlo, one pose (samples/s, wall)"),
        ("mc_cpu", "Monte Carlo, one pose (samples per CPU-s)"),
        ("numpy_wall", "numpy alternative (samples/s, wall)"),
        ("numpy_cpu", "numpy alternative (samples per CPU-s)"),
        ("limit_wall", "uniforms limit, compiled lanes on all cores (samples/s, wall)"),
        ("lane_cpu", "one compiled lane (samples per CPU-s)"),
        ("speedup_wall", "mc_pose_speedup_vs_numpy (wall, as run.py)"),
        ("speedup_cpu", "the same by CPU time"),
        ("fraction_wall", "mc_pose_fraction_of_uniforms_limit (wall, as run.py)"),
        ("fraction_cpu", "the same by CPU time (per CPU-s of the kernel / of one lane)"),
        ("compile_cpu", "first small calls (load or compile), CPU-s"),
        ("load", "1-minute load after each call"))


def table(old: dict, new: dict) -> str:
    """Markdown: median (smallest-largest) of each figure in both trees and the ratio of the medians."""
    g = lambda v: f"{v:.3g}"  # noqa: E731
    lines = ["| figure | before: median (range) | after: median (range) | after / before |", "|---|---|---|---|"]
    for key, label in ROWS:
        a, b = old[key], new[key]
        ma, mb = statistics.median(a), statistics.median(b)
        ratio = "" if key == "load" else f"{mb / ma:.2f}"
        lines.append(f"| {label} | {g(ma)} ({g(min(a))}-{g(max(a))}) | {g(mb)} ({g(min(b))}-{g(max(b))}) | {ratio} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path, nargs="?")
    parser.add_argument("new", type=Path, nargs="?")
    parser.add_argument("--turns", type=int, default=4)
    parser.add_argument("--calls", type=int, default=2, help="timed calls of each kind per process")
    parser.add_argument("--log2-samples", type=int, default=22)
    parser.add_argument("--json", type=Path, help="write every measurement here")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        json.dump(child(args.log2_samples, args.calls), sys.stdout)
        return 0
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    rec: dict = {"old": [], "new": []}
    for turn in range(args.turns):
        for label in (("old", "new") if turn % 2 == 0 else ("new", "old")):
            r = run_tree(trees[label], args.log2_samples, args.calls)
            rec[label].append(r)
            print(f"turn {turn} {label}: mc {[round(r['n'] / c['cpu'] / 1e6, 2) for c in r['mc']]} M/CPU-s, "
                  f"numpy {[round(r['n'] / c['cpu'] / 1e6, 3) for c in r['numpy']]} M/CPU-s, "
                  f"load {r['mc'][-1]['load']:.1f}", file=sys.stderr, flush=True)
            if args.json:
                args.json.write_text(json.dumps(rec, indent=1))
    print(table(summary(rec["old"]), summary(rec["new"])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
