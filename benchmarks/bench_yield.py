"""The exact yield (:func:`prp3mc.exact_yield`) against Monte Carlo and OpenTURNS, measured in one run.

Figures (paper budget, U-shape, pose (10, 120, 0), spec 100 µm / 100 arcsec unless said), each with its wall
time, its CPU time (``time.process_time``: every thread of the process; less sensitive to a shared machine's
load than the wall time) and the 1-minute load average right after it:

- one pose: P(position > S) alone; with P(|dphi| > Z), P(either) and the quantiles;
- a grid of poses (21 x 21; 101 x 101 with ``--full``), P(position > S) at every pose, on every core and on
  one thread: CPU time, and the wall time two free cores would take (CPU time / 2, the pool's chunks
  keeping both busy), next to the wall time measured;
- Monte Carlo at 1 ppm: :func:`prp3mc.monte_carlo` with the exceedance, its rate measured at one pose on
  1e7 samples, extrapolated to the 1e8 samples that +-10 % (one standard error) at P = 1e-6 needs, and to
  the exact result's own precision (a standard error equal to its reported bound at the pose, ~1e12
  samples);
- OpenTURNS' LinearCombinationDistribution (ex RandomMixture) on P(|dphi| > Z) of a budget it can
  represent (uniform, normal, triangular), against the exact engine on the same pose (its two channels' series:
  P(either) left as its bracket, ``joint=False``);
- start-up: the first call in a fresh process with the numba cache (``--cold``: with an empty cache too).

Usage: ``python benchmarks/bench_yield.py [--full] [--cold]`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from prp3mc import Budget, Geometry, Region, exact_yield, linear_model, monte_carlo
from prp3mc.model.laws import Normal, Triangular, Uniform

POSE = [10.0, 120.0, 0.0]
S_UM, Z_AS = 100.0, 100.0
P_PPM, REL = 1e-6, 0.1          # Monte Carlo to +-10 % (one standard error) at 1 ppm


def timed(fn, repeat: int = 3) -> tuple[float, float, float]:
    """(best wall s, best CPU s of the process, 1-minute load after)."""
    best, best_cpu = np.inf, np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return best, best_cpu, os.getloadavg()[0]


def ot_budget() -> Budget:
    return Budget({"theta_1": Uniform(-0.04, 0.04), "theta_2": Normal(0.0, 0.012),
                   "theta_3": Triangular(-0.03, 0.01, 0.04), "b_1": Normal(0.002, 0.006), "b_2": Uniform(0.0, 0.025),
                   "b_3": Triangular(0.0, 0.02, 0.025), "c_1": Uniform(-0.01, 0.01)}, name="ot")


def bench_openturns(g: Geometry) -> dict:
    """P(|dphi| > Z) at one pose: OpenTURNS (distribution built and both CDF calls) against exact_yield."""
    import openturns as ot

    ot.Log.Show(ot.Log.NONE)
    budget = ot_budget()
    model = linear_model(g, budget, POSE)
    z = Z_AS / 3600.0 * np.pi / 180.0

    def with_ot():
        laws = []
        for tl in model.term_laws:
            law = tl.law
            laws.append(ot.Uniform(law.lo, law.hi) if isinstance(law, Uniform) else
                        ot.Normal(law.mu, law.sd) if isinstance(law, Normal) else
                        ot.Triangular(law.lo, law.mode, law.hi))
        mix = ot.LinearCombinationDistribution(laws, [float(v) for v in model.columns[2]], 0.0)
        return mix.computeComplementaryCDF(z) + mix.computeCDF(-z)

    def exact():    # P(either) left as its bracket (joint=False): the two channels' series alone
        return exact_yield(g, budget, POSE, spec_position_um=S_UM, spec_phi_arcsec=Z_AS, quantiles=False,
                           joint=False)

    p_ot = with_ot()
    r = exact()
    t_ot, c_ot, load_ot = timed(with_ot)
    t_ex, c_ex, load_ex = timed(exact)
    return {"openturns_s": t_ot, "exact_s": t_ex, "ratio_openturns_over_exact": t_ot / t_ex,
            "openturns_cpu_s": c_ot, "exact_cpu_s": c_ex,
            "difference": float(abs(float(r.exceed_phi) - p_ot)), "exact_bound": float(r.bound_phi),
            "note": "exact_yield computes the position channel too, P(either) not conditioned (OpenTURNS: dphi "
                    "alone)",
            "load": [load_ot, load_ex]}


def first_call(cold: bool) -> dict:
    """Wall time of the first exact_yield in a fresh process (numba cache as is; with ``cold`` also empty)."""
    code = ("import time; t0 = time.perf_counter(); import prp3mc; "
            f"prp3mc.exact_yield('u-shape', 'paper', {POSE}, spec_position_um={S_UM}, spec_phi_arcsec={Z_AS}); "
            "print(time.perf_counter() - t0)")
    out = {}
    runs = [("cached", None)] + ([("empty_cache", tempfile.mkdtemp())] if cold else [])
    for name, cache in runs:
        env = dict(os.environ) | ({"NUMBA_CACHE_DIR": cache} if cache else {})
        res = subprocess.run([sys.executable, "-W", "ignore", "-c", code], env=env, capture_output=True, text=True,
                             check=True)
        out[f"first_call_{name}_s"] = float(res.stdout.strip().splitlines()[-1])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the 101 x 101 grid (else 21 x 21)")
    ap.add_argument("--cold", action="store_true", help="also the first call with an empty numba cache (minutes)")
    args = ap.parse_args()
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    out = {"cores": os.cpu_count()}
    out |= first_call(args.cold)
    exact_yield(g, b, POSE, spec_position_um=S_UM, spec_phi_arcsec=Z_AS)          # warm
    t1, c1, l1 = timed(lambda: exact_yield(g, b, POSE, spec_position_um=S_UM, quantiles=False), 5)
    t2, c2, l2 = timed(lambda: exact_yield(g, b, POSE, spec_position_um=S_UM, spec_phi_arcsec=Z_AS), 3)
    r = exact_yield(g, b, POSE, spec_position_um=S_UM, spec_phi_arcsec=Z_AS)
    out["one_pose"] = {"position_s": t1, "all_s": t2, "position_cpu_s": c1, "all_cpu_s": c2, "load": [l1, l2],
                       "exceed_position": float(r.exceed_position), "bound_position": float(r.bound_position),
                       "bound_any": float(r.bound_any), "bracketed_any": bool(r.bracketed_any)}
    n = 101 if args.full else 21
    grid = Region.from_preset("u-shape").grid(n)
    out["grid"] = {"n": n, "poses": n * n}
    for name, workers in (("all_cores", None), ("one_thread", 1)):
        before = os.getloadavg()[0]
        tg, cg, lg = timed(lambda: exact_yield(g, b, grid, spec_position_um=S_UM, quantiles=False,
                                               workers=workers), 1)
        out["grid"][name] = {"workers": workers or os.cpu_count(), "position_s": tg, "cpu_s": cg,
                             "per_pose_ms": 1e3 * tg / (n * n), "cpu_per_pose_ms": 1e3 * cg / (n * n),
                             "load": [before, lg], "two_free_cores_s": cg / 2,
                             "extrapolated_101x101_two_free_cores_s": cg / (n * n) * 101 ** 2 / 2}
    # Monte Carlo at one pose: its rate, and the samples +-10 % at 1 ppm needs: (1 - p) / (p REL²)
    n_mc = 10_000_000
    monte_carlo(g, b, POSE, 10_000, rng=1, tolerance_mm=S_UM / 1e3, percentiles=(99.73,), progress=False)  # compile
    tm, cm, lm = timed(lambda: monte_carlo(g, b, POSE, n_mc, rng=1, tolerance_mm=S_UM / 1e3, percentiles=(99.73,),
                                           progress=False), 1)
    need = (1.0 - P_PPM) / (P_PPM * REL ** 2)
    out["monte_carlo"] = {"samples": n_mc, "s": tm, "cpu_s": cm, "rate_per_s": n_mc / tm, "load": lm,
                          "samples_needed": need, "extrapolated_s": need / (n_mc / tm),
                          "ratio_over_exact_one_pose": need / (n_mc / tm) / t1,
                          "ratio_over_exact_all_figures": need / (n_mc / tm) / t2,
                          "cpu_ratio_over_exact_one_pose": need * cm / n_mc / c1}
    # and to the exact result's own precision: a standard error equal to its bound at the pose, at 1 ppm
    same = P_PPM * (1.0 - P_PPM) / float(r.bound_position) ** 2
    out["monte_carlo"] |= {"samples_same_precision": same, "extrapolated_same_precision_s": same / (n_mc / tm),
                           "ratio_same_precision_one_pose": same / (n_mc / tm) / t1,
                           "cpu_ratio_same_precision_one_pose": same * cm / n_mc / c1}
    out["openturns"] = bench_openturns(g)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
