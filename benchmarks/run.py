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
from bench_discrepancy import bench_discrepancy_cli, speed_table
from bench_montecarlo import bench_montecarlo, peak_flops, timed
from bench_sobol import bench_sobol, bench_sobol_pose
from bench_study import bench_study

import prp3mc
from prp3mc import Budget, Geometry, Region, sensitivity, worst_case
from prp3mc.worstcase.envelope import worst_case_maxima
from prp3mc.worstcase._kernel import envelope_kernel, kernel_tables
from prp3mc.worstcase.crosscheck import optimizer_worst_case


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


#: Flops of one pose in the envelope kernel, counted from its source: the chain and the h entries
#: (~230), A^-1 (~40), the feasibility tests (~45), the terms (~45), the zonotope maxima (~140).
ENVELOPE_FLOPS_PER_POSE = 500


def bench_envelope(quick: bool) -> dict:
    """The fused envelope kernel (maxima only) from 11x11 to 2001x2001: wall and CPU rates with the load.

    A grid of up to 101x101 poses is timed over a loop of calls (enough for 10 ms), the
    fastest loop of several: the sustained rate of a caller that evaluates many small
    grids (an allocation search, a sweep). ``envelope_{n}_ns_per_pose`` is the kernel
    alone on one thread (thread CPU time, the outputs allocated once): the per-pose
    cost, to compare across sizes. The whole call adds a fixed cost (``envelope_call_us``,
    one pose: checks, outputs, the result), which weighs most at 11x11. The alternative
    is worst_case's numpy frame path at 201x201 (it keeps the model); the limit is
    ENVELOPE_FLOPS_PER_POSE at the float64 matrix-product rate of all cores.
    """
    g, budget, region = Geometry.from_preset("u-shape"), Budget.from_preset("paper"), Region.from_preset("u-shape")
    worst_case_maxima(g, budget, region.grid(11))   # compile / load the kernels
    _, *tables = kernel_tables(g, budget, None)
    out = {}
    for n in (11, 101, 1001) if quick else (11, 101, 1001, 2001):
        grid = region.grid(n)
        calls = max(1, 10_000_000 // (n * n * 40))     # ~10 ms of calls at 40 ns a pose
        repeat = 7 if calls > 1 else 3
        wall, cpu, load = timed(lambda: _repeat(calls, worst_case_maxima, g, budget, grid), repeat)
        poses = calls * n * n
        out[f"envelope_{n}_poses_per_s"], out[f"envelope_{n}_poses_per_cpu_s"] = poses / wall, poses / cpu
        out[f"envelope_{n}_load"] = load
        flat = np.ascontiguousarray(grid.reshape(-1, 3))
        values, codes, bad = np.empty((4, n * n)), np.empty((4, n * n), np.int16), np.empty(n * n, np.uint16)
        kernel = lambda: _repeat(calls, envelope_kernel, flat, *tables, True, values, codes, bad, workers=1)  # noqa: E731
        kernel()
        out[f"envelope_{n}_ns_per_pose"] = 1e9 / poses * min(_thread_time(kernel) for _ in range(repeat))
    one = region.grid(1)
    out["envelope_call_us"] = 1e6 / 1000 * timed(lambda: _repeat(1000, worst_case_maxima, g, budget, one), 7)[0]
    grid = region.grid(201)
    worst_case(g, budget, grid)
    wall, cpu, load = timed(lambda: worst_case(g, budget, grid), 3)
    out["worstcase_numpy_poses_per_s"], out["worstcase_numpy_poses_per_cpu_s"] = grid[..., 0].size / wall, grid[..., 0].size / cpu
    out["worstcase_numpy_load"] = load
    out["envelope_limit_poses_per_s"] = peak_flops(np.float64) / ENVELOPE_FLOPS_PER_POSE
    # a machine's [effects]: thermal adds a shared generator (16 corners), backlash and a lead scale two terms
    from prp3mc.model.effects import SystematicEffect as Effect
    machine = budget.with_effects({"backlash_1": Effect("backlash_1", 0.02), "scale_2": Effect("scale_2", 1e-4),
                                   "thermal": Effect("thermal", 1.2e-5, temp_range_C=(15.0, 30.0))})
    grid = region.grid(1001)
    worst_case_maxima(g, machine, region.grid(11))
    cpu = {name: timed(lambda: worst_case_maxima(g, b, grid), 3)[1] for name, b in (("paper", budget), ("effects", machine))}
    out["envelope_1001_effects_poses_per_cpu_s"] = grid[..., 0].size / cpu["effects"]
    out["envelope_effects_cost_ratio"] = cpu["effects"] / cpu["paper"]
    return out


def _repeat(calls: int, fn, *args, **kwargs) -> None:
    """Call ``fn`` ``calls`` times, keeping no result (as a loop over many small grids would)."""
    for _ in range(calls):
        fn(*args, **kwargs)


def _thread_time(fn) -> float:
    t0 = time.thread_time()
    fn()
    return time.thread_time() - t0


BENCHES = [bench_sensitivity, bench_worstcase, bench_envelope, bench_montecarlo, bench_sobol, bench_sobol_pose,
           bench_study, bench_discrepancy_cli]


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
        print(table(result))
    return 0


def table(r: dict) -> str:
    """The table of benchmarks/README.md: each figure, the alternative, the ratio and the limit."""
    g = lambda v: f"{v:.3g}"  # noqa: E731
    rows = [
        ("Monte Carlo, 21x21 poses x %d samples (pose-samples/s)" % r["mc_grid_samples"],
         f"{g(r['mc_grid_rate'])} ({g(r['mc_grid_rate_cpu'])} per CPU-s; load {r['mc_grid_load']:.1f})",
         "numpy per pose: product, norm, np.percentile",
         f"{g(r['mc_grid_numpy_rate'])} (load {r['mc_grid_numpy_load']:.1f})", g(r["mc_grid_speedup_vs_numpy"]),
         "%s (float32 matmul / 72 flops): %s of it" % (g(r["mc_limit_pose_samples_per_s"]),
                                                      g(r["mc_grid_fraction_of_limit"]))),
        ("Monte Carlo, one pose x %d samples (samples/s)" % r["mc_pose_samples"],
         f"{g(r['mc_pose_rate'])} ({g(r['mc_pose_rate_cpu'])} per CPU-s; load {r['mc_pose_load']:.1f})",
         "the same numpy code", f"{g(r['mc_pose_numpy_rate'])} (load {r['mc_pose_numpy_load']:.1f})",
         g(r["mc_pose_speedup_vs_numpy"]),
         "%s (drawing the 12 uniforms of a sample alone, compiled, all cores; numpy's Generator: %s): %s of it"
         % (g(r["mc_uniforms_limit_samples_per_s"]), g(r["mc_uniforms_numpy_samples_per_s"]),
            g(r["mc_pose_fraction_of_uniforms_limit"]))),
        *[(f"Monte Carlo, one pose x 1e{e} samples: peak memory (GB); samples/s",
           f"{g(r[f'mc_pose_1e{e}_peak_gb'])}; {g(r[f'mc_pose_1e{e}_samples_per_s'])} (load {r[f'mc_pose_1e{e}_load']:.1f})",
           "numpy holding samples, features and errors (not run)", g(r[f"mc_pose_1e{e}_numpy_gb"]),
           g(r[f"mc_pose_1e{e}_numpy_gb"] / r[f"mc_pose_1e{e}_peak_gb"]), "target: <= 1 GB")
          for e in (8, 9) if f"mc_pose_1e{e}_peak_gb" in r],
        ("Exact envelope, 201x201 (poses/s)", g(r["worstcase_poses_per_s"]),
         "differential evolution per pose", g(1 / r["de_seconds_per_pose"]), g(r["worstcase_speedup_vs_de"]), "-"),
        *[(f"Exact envelope, fused kernel (maxima only), {n}x{n} (poses/s; per CPU-s; kernel ns a pose)",
           f"{g(r[f'envelope_{n}_poses_per_s'])}; {g(r[f'envelope_{n}_poses_per_cpu_s'])}; "
           f"{r[f'envelope_{n}_ns_per_pose']:.0f} ns (load {r[f'envelope_{n}_load']:.1f})",
           "worst_case (numpy frame, keeps the model), 201x201, per CPU-s",
           f"{g(r['worstcase_numpy_poses_per_cpu_s'])} (load {r['worstcase_numpy_load']:.1f})",
           g(r[f"envelope_{n}_poses_per_cpu_s"] / r["worstcase_numpy_poses_per_cpu_s"]) + " (CPU)",
           "%s (%d flops a pose at the float64 matmul rate); target 1e7 wall"
           % (g(r["envelope_limit_poses_per_s"]), ENVELOPE_FLOPS_PER_POSE))
          for n in (11, 101, 1001, 2001) if f"envelope_{n}_poses_per_s" in r],
        ("Exact envelope, fused kernel, 1001x1001, budget with [effects] (backlash, scale, thermal: 16 corners; "
         "per CPU-second)", g(r["envelope_1001_effects_poses_per_cpu_s"]), "the same without effects (8 corners)",
         g(r["envelope_1001_effects_poses_per_cpu_s"] * r["envelope_effects_cost_ratio"]),
         g(r["envelope_effects_cost_ratio"]) + " (CPU time)", "-"),
        *([("Sobol at one pose, N = %d in 16 scrambled replicates (s; CPU s)" % r["sobol_pose_n_samples"],
            f"{g(r['sobol_pose_seconds'])}; {g(r['sobol_pose_cpu_seconds'])}",
            "OpenTURNS SaltelliSensitivityAlgorithm, same problem, bootstrap of 100",
            f"{g(r['ot_sobol_pose_seconds'])}; {g(r['ot_sobol_pose_cpu_seconds'])}",
            f"{g(r['sobol_pose_ratio_to_ot_wall'])} (wall), {g(r['sobol_pose_ratio_to_ot_cpu'])} (CPU)",
            "target: ratio <= 1.5")] if "ot_sobol_pose_seconds" in r else []),
        ("prp3mc study paper_reproduction%s, end to end (s; CPU s)" % (" --quick" if r["study_quick"] else ""),
         f"{g(r['study_cli_seconds'])}; {g(r['study_cli_cpu_seconds'])}",
         "-", "-", "-", "10 s on 2 idle cores"),
        ("the study in process: analyses + report (s; CPU s)",
         f"{g(r['study_analyses_seconds'])} + {g(r['study_report_seconds'])}; "
         f"{g(r['study_analyses_cpu_seconds'])} + {g(r['study_report_cpu_seconds'])}",
         "BLAS threads free inside the analyses, figures drawn one after the other (the rest of this change kept)",
         f"{g(r['study_analyses_blas_free_seconds'])} + {g(r['study_report_serial_seconds'])}; "
         f"{g(r['study_analyses_blas_free_cpu_seconds'])} + {g(r['study_report_serial_cpu_seconds'])}",
         g(r["study_speedup_vs_before"]), "-"),
        ("J_q, 201x201 (poses/s)", g(r["sensitivity_poses_per_s"]), "per-pose loop",
         g(r["sensitivity_poses_per_s"] / r["sensitivity_speedup_vs_loop"]), g(r["sensitivity_speedup_vs_loop"]), "-"),
    ]
    lines = ["| figure | prp3mc | alternative | alternative's figure | ratio | limit |", "|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    lines.append(f"\n1-minute load average at the end of the Monte Carlo part: {r['load_average_1min']:.1f} (2 cores); "
                 f"a whole call of the envelope on one pose (its fixed cost): {r['envelope_call_us']:.1f} us")
    if "discrepancy_cli_wall_s_best" in r:
        lines.append("\n" + speed_table(r))
    extra = {k: v for k, v in r.items() if k.startswith(("sobol", "salib")) and not k.startswith("sobol_pose")}
    lines += [f"{k:45s} {v:.4g}" if isinstance(v, float) else f"{k:45s} {v}" for k, v in extra.items()]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
