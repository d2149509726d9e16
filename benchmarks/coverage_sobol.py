"""Coverage and width of the Sobol and Shapley intervals over many seeds (issue 27).

For each case (a geometry, a pose and a budget) the analysis runs once per
seed; every interval is checked against a reference value:

- S1, ST of x, y, phi: the closed forms (:func:`~prp3mc.sobol.closed_form.analytic_indices`);
- Sh of x, y, phi: the closed form (:func:`~prp3mc.sobol.closed_form.analytic_shapley`),
  also for the correlated case, whose correlated inputs are normal (a joint normal law);
- every index of the position norm (no closed form): one run 16 times (S1, ST)
  8 times (S1, ST) or 128 times (Sh) larger than the runs checked, whose own
  error is then about an eighth (RQMC, rate about 1/N) or a tenth (Monte Carlo,
  1/sqrt(n)) of theirs.

Reported per case, statistic and output, pooled over the budget's names
(those whose estimate varies over the seeds): the coverage (share of seeds
whose interval holds the reference; its binomial standard error over S seeds
is about sqrt(0.95 x 0.05 / S), 1.5 % for 200), the smallest coverage of one
name, and the width ratio: the median reported half-width over 1.96 times the
standard deviation of the estimates across seeds (1 for an interval that is
exactly as wide as the estimates' spread calls for; about 1.07 for a t
interval over 16 replicates, t(0.975, 15) E[s] / 1.96 of the true sd).

Usage: ``python benchmarks/coverage_sobol.py [--seeds 200] [--samples 8192] [--permutations 2048]
[--json FILE]`` prints a Markdown table (about 6 minutes on one core for 200 seeds).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from prp3mc import Budget, Geometry, Normal
from prp3mc.sobol.shapley import shapley_effects
from prp3mc.sobol.indices import sobol_indices
from prp3mc.sobol.closed_form import analytic_indices, analytic_shapley

OUTPUTS = ("x", "y", "phi", "position")


def correlated_budget() -> Budget:
    """The paper budget with normal guide plays and encoder errors (the paper's sds), correlated: its
    correlated inputs are jointly normal, so x, y, phi have closed-form Shapley effects."""
    paper = Budget.from_preset("paper")
    normal = {f"theta_{i}": Normal(0.0, 0.04 / np.sqrt(3.0)) for i in (1, 2, 3)}
    normal |= {f"b_{i}": Normal(0.0125, 0.025 / np.sqrt(12.0)) for i in (1, 2, 3)}
    return Budget({**paper.inputs, **normal}, name="paper, correlated normal guide plays and encoders",
                  correlation={"theta_1,theta_2": 0.6, "theta_2,theta_3": -0.3, "theta_1,b_1": 0.4,
                               "b_1,b_2": 0.5})


#: (name, geometry preset, pose, budget)
CASES = (("u-shape", "u-shape", (0.0, 100.0, 0.0), Budget.from_preset("paper")),
         ("delta-shape", "delta-shape", (0.0, 160.0, 0.0), Budget.from_preset("paper")),
         ("u-shape correlated", "u-shape", (0.0, 100.0, 0.0), correlated_budget()))


def references(geometry: Geometry, budget: Budget, pose, n_samples: int, n_permutations: int) -> dict:
    """Reference value of every statistic, (O, K) per statistic: closed forms, or a run 16x / 128x larger."""
    ref = {}
    names = None
    if not budget.correlated:
        big = sobol_indices(geometry, budget, pose, 8 * n_samples, rng=2**40, shapley_permutations=0)
        names = big.names
        exact = analytic_indices(geometry, budget, pose)
        for stat in ("S1", "ST"):
            table = np.array(getattr(big, stat))
            for o, out in enumerate(OUTPUTS[:3]):
                rows = exact[exact["output"] == out].set_index("name")
                table[o] = rows.loc[list(names), stat].to_numpy()
            ref[stat] = table
    big = shapley_effects(geometry, budget, pose, 128 * n_permutations, rng=2**41)
    names = big.names
    exact = analytic_shapley(geometry, budget, pose)
    table = np.array(big.Sh)
    for o, out in enumerate(OUTPUTS[:3]):
        table[o] = exact[exact["output"] == out].set_index("name").loc[list(names), "Sh"].to_numpy()
    ref["Sh"] = table
    return ref


def run_seeds(geometry: Geometry, budget: Budget, pose, seeds, n_samples: int, n_permutations: int) -> dict:
    """Estimates and half-widths (S, O, K) of every statistic over the seeds."""
    est: dict = {}
    for seed in seeds:
        if budget.correlated:
            r = shapley_effects(geometry, budget, pose, n_permutations, rng=seed)
            stats = {"Sh": (r.Sh, r.Sh_conf)}
        else:
            r = sobol_indices(geometry, budget, pose, n_samples, rng=seed, shapley_permutations=n_permutations)
            stats = {s: (getattr(r, s), getattr(r, f"{s}_conf")) for s in ("S1", "ST", "Sh")}
        for s, (value, conf) in stats.items():
            est.setdefault(s, ([], []))
            est[s][0].append(value)
            est[s][1].append(conf)
    return {s: (np.array(v), np.array(c)) for s, (v, c) in est.items()}


def coverage_table(est: dict, ref: dict) -> list[dict]:
    """Rows (statistic, output, coverage, min_coverage, width_ratio, names) pooled over the names that vary."""
    rows = []
    for stat, (value, conf) in est.items():
        covered = np.abs(value - ref[stat]) <= conf                  # (S, O, K)
        sd = value.std(axis=0, ddof=1)
        for o, out in enumerate(OUTPUTS):
            varies = np.isfinite(sd[o]) & (sd[o] > 1e-12)
            if not varies.any():
                continue
            ratio = np.median(conf[:, o, varies], axis=0) / (1.96 * sd[o, varies])
            cov = covered[:, o, varies].mean(axis=0)
            rows.append({"statistic": stat, "output": out, "coverage": float(cov.mean()),
                         "min_coverage": float(cov.min()), "width_ratio": float(np.median(ratio)),
                         "width_ratio_range": [float(ratio.min()), float(ratio.max())],
                         "names": int(varies.sum())})
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=200)
    p.add_argument("--samples", type=int, default=8192, help="Sobol base sample size N (16 replicates)")
    p.add_argument("--permutations", type=int, default=2048, help="random orders of the Shapley effects")
    p.add_argument("--json", default=None, help="also write the rows to this file")
    args = p.parse_args(argv)
    out = []
    for name, preset, pose, budget in CASES:
        t0 = time.perf_counter()
        geometry = Geometry.from_preset(preset)
        ref = references(geometry, budget, pose, args.samples, args.permutations)
        est = run_seeds(geometry, budget, pose, range(args.seeds), args.samples, args.permutations)
        for row in coverage_table(est, ref):
            out.append({"case": name, **row})
        print(f"{name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    print(f"| case | statistic | output | coverage | min over names | width ratio (median; range) | names |\n"
          f"|---|---|---|---|---|---|---|")
    for r in out:
        lo, hi = r["width_ratio_range"]
        print(f"| {r['case']} | {r['statistic']} | {r['output']} | {r['coverage']:.3f} | {r['min_coverage']:.3f} "
              f"| {r['width_ratio']:.2f} ({lo:.2f}-{hi:.2f}) | {r['names']} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"seeds": args.seeds, "samples": args.samples, "permutations": args.permutations,
                       "rows": out}, fh, indent=1)


if __name__ == "__main__":
    main()
