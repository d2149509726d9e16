"""Benchmark of the exact tolerance allocation against differential evolution with sampling inside.

The problem: the bundled ``example`` classes (9 inputs, 3-4 classes each:
110 592 choices) on the u-shape test region, a 21 x 21 grid at phi = 0, and a
worst-case position spec of 40 µm. prp3mc's branch and bound
(:func:`prp3mc.allocate`) is timed against what published tolerance-synthesis
code does: scipy's ``differential_evolution`` over the class indices
(``integrality``), minimising cost plus a penalty on the spec violation, with
the worst case estimated by sampling inside every evaluation:

- ``de_montecarlo``: Monte Carlo draws of the inputs from their laws (the
  largest sampled position error over the grid);
- ``de_vertices``: random vertices of the box of term values (every term at
  an end of its interval, a clearance along its worst direction), a sampled
  worst case that approaches the exact one from below;
- ``de_exact``: prp3mc's exact worst case (:func:`prp3mc.worst_case`) inside
  every evaluation, the best DE can be given.

Sampled estimates can only miss the maximum, so a DE choice may look
feasible and is not: its exact worst case is reported beside its cost. The
linear model's columns are built once and shared, so DE pays only for sampling.

Usage: ``python benchmarks/bench_allocation.py [--quick]`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.optimize import differential_evolution

from prp3mc import Geometry, Region, allocate, linear_model, worst_case
from prp3mc.allocation.classes import ClassMenu

SPEC_UM = 40.0


def _problem(grid: int):
    geometry = Geometry.from_preset("u-shape")
    menu = ClassMenu.from_preset("example")
    poses = Region.from_preset("u-shape").grid(grid).reshape(-1, 3)
    return geometry, menu, poses


def _decode(menu, x) -> dict:
    return {name: menu.classes_of(name)[int(round(v))].name for name, v in zip(menu.inputs, x)}


def _de(geometry, menu, poses, n_samples: int, inner: str, maxiter: int, seed: int) -> dict:
    """Differential evolution with a worst case (``montecarlo``, ``vertices``, ``exact``) inside every evaluation."""
    first = menu.budget(_decode(menu, np.zeros(len(menu.inputs))))
    model = linear_model(geometry, first, poses)
    coef = [np.ascontiguousarray(model.coef[:, r, :]) for r in (0, 1)]         # (N, F): shared by every choice
    columns = [np.ascontiguousarray(model.columns[:, r, :]) for r in (0, 1)]   # (N, T) for the vertex variant
    rng = np.random.default_rng(seed)
    cost_of = {n: {c.name: c.cost for c in menu.classes_of(n)} for n in menu.inputs}
    evaluations = 0

    def sampled_worst_mm(choice) -> float:
        budget = menu.budget(choice)
        if inner == "exact":
            return float(worst_case(geometry, budget, poses).position_mm.max())
        if inner == "vertices":
            hi = np.array([budget.inputs[t].support[1] for t in model.terms])
            lo = np.array([-h if t.startswith("rho_") else budget.inputs[t].support[0]
                           for t, h in zip(model.terms, hi)])
            values = np.where(rng.integers(0, 2, size=(len(hi), n_samples)) == 1, hi[:, None], lo[:, None])
            x, y = columns[0] @ values, columns[1] @ values
        else:
            F = np.ascontiguousarray(model.features(budget.sample(n_samples, rng)).T)
            x, y = coef[0] @ F, coef[1] @ F
        return float(np.sqrt((x * x + y * y).max()))

    def objective(x) -> float:
        nonlocal evaluations
        evaluations += 1
        choice = _decode(menu, x)
        violation = max(0.0, 1e3 * sampled_worst_mm(choice) / SPEC_UM - 1.0)
        return sum(cost_of[n][c] for n, c in choice.items()) + 1e3 * violation

    bounds = [(0, len(menu.classes_of(n)) - 1) for n in menu.inputs]
    t0 = time.perf_counter()
    res = differential_evolution(objective, bounds, integrality=np.ones(len(bounds), bool), maxiter=maxiter,
                                 popsize=15, seed=seed, polish=False, tol=1e-8)
    seconds = time.perf_counter() - t0
    choice = _decode(menu, res.x)
    exact_um = 1e3 * float(worst_case(geometry, menu.budget(choice), poses).position_mm.max())
    return {"seconds": seconds, "cost": sum(cost_of[n][c] for n, c in choice.items()),
            "evaluations": evaluations, "exact_worst_case_um": exact_um, "meets_spec": exact_um <= SPEC_UM}


def bench_allocation(quick: bool = False, grid: int = 21, seed: int = 1) -> dict:
    """Time and cost of prp3mc's exact allocation and of DE with sampling inside, same run, same problem."""
    geometry, menu, poses = _problem(grid)
    allocate(geometry, menu, poses, spec_position_um=SPEC_UM)       # warm-up (imports, caches)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        r = allocate(geometry, menu, poses, spec_position_um=SPEC_UM)
        times.append(time.perf_counter() - t0)
    ours = {"seconds": min(times), "cost": r.cost, "nodes": r.nodes, "n_choices": r.n_choices,
            "exact_worst_case_um": 1e3 * r.worst_case_position_mm, "meets_spec": r.feasible}
    out = {"problem": {"geometry": "u-shape", "classes": "example", "grid": grid, "spec_position_um": SPEC_UM,
                       "n_choices": r.n_choices},
           "prp3mc": ours}
    maxiter = 10 if quick else 40
    variants = {"de_montecarlo": dict(n_samples=500 if quick else 2000, inner="montecarlo"),
                "de_vertices": dict(n_samples=256 if quick else 1024, inner="vertices"),
                "de_exact": dict(n_samples=None, inner="exact")}
    for name, kw in variants.items():
        de = _de(geometry, menu, poses, maxiter=maxiter, seed=seed, **kw)
        de.update(n_samples=kw["n_samples"], maxiter=maxiter,
                  speedup=de["seconds"] / ours["seconds"], cost_ratio=de["cost"] / ours["cost"])
        out[name] = de
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer DE generations and samples")
    args = parser.parse_args(argv)
    json.dump(bench_allocation(args.quick), sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
