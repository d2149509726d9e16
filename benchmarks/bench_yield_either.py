"""How far P(either) by conditioning on two legs reaches: its bound against the cell budget.

P(position > S or ``|dphi|`` > Z) = P_pos + P_phi - J on the paper's budget (its legs have no normal law, so
the 3-D series does not serve) is found by conditioning on two legs (:mod:`prp3mc.stackup.conditional`);
J = P(both out) is bracketed on cells of the two conditioned legs (to second order where its integrand is smooth on
a cell), at most ``_MAX_CELLS`` open cells a pose.
For each geometry, spec pair (S µm, Z arcsec) and pose (the default region's four corners and centre, phi = 0),
single thread (``workers=1``), it prints P_pos, P_phi, J's bracket (lo, hi, width), the bound of P(either)
(J's half-width plus both channels' bounds at the target; ``_tight``: at a quarter of it where J's bracket
closes to the target, as :func:`prp3mc.exact_yield` does), the cells evaluated, and the CPU seconds of the
conditioning (``time.process_time``; the two channels' series are timed apart), for each cell budget asked;
and the bound :func:`prp3mc.exact_yield` reports (its own cell budget) with its CPU seconds a pose.

Usage: ``python benchmarks/bench_yield_either.py [--cells 20000 80000 320000] [--specs 60x20 100x100 ...]
[--presets u-shape delta-shape]`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np
from scipy import special

from prp3mc import Budget, Geometry, Region, exact_yield, linear_model
from prp3mc.stackup import conditional
from prp3mc.stackup.characteristic import term_table
from prp3mc.units import DEG2ARCSEC, DEG2RAD, MM2UM

SPECS = [(s, z) for s in (60.0, 80.0, 100.0, 150.0) for z in (20.0, 30.0, 60.0, 100.0)]
TARGET = 1e-9


def region_poses(preset: str) -> np.ndarray:
    """The default region's four corners and its centre, phi = its phi (0)."""
    r = Region.from_preset(preset)
    (x0, x1), (y0, y1) = r.x_mm, r.y_mm
    return np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1], [0.5 * (x0 + x1), 0.5 * (y0 + y1)]]) @ \
        np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) + np.array([0.0, 0.0, r.phi_deg])


class Counter:
    """Counts the cells :meth:`conditional._Cells.evaluate` brackets."""

    def __init__(self):
        self.n = 0
        self._orig = conditional._Cells.evaluate
        counter = self

        def evaluate(cells_self, cells):
            counter.n += cells[0].size
            return counter._orig(cells_self, cells)
        conditional._Cells.evaluate = evaluate


def run(presets, specs, budgets) -> list[dict]:
    counter = Counter()
    default = conditional._MAX_CELLS
    budget = Budget.load("paper")
    share = 0.01 * TARGET                       # no normal law: share is the per-law cut (unused)
    out = []
    for preset in presets:
        g = Geometry.from_preset(preset)
        poses = region_poses(preset)
        m = linear_model(g, budget, poses)
        T = len(m.terms)
        C, Ainv = m.columns.reshape(-1, 3, T), m.Ainv.reshape(-1, 3, 3)
        table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
        kappa, ok = conditional.independent_legs(C, Ainv, m.legs, table)
        assert ok.all()
        for S_um, Z_as in specs:
            c0 = time.process_time()
            r = exact_yield(g, budget, poses, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False,
                            workers=1, joint=False)
            ch_cpu = (time.process_time() - c0) / len(poses)
            tight = exact_yield(g, budget, poses, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False,
                                workers=1, joint=False, target=0.25 * TARGET)
            c0 = time.process_time()
            reported = exact_yield(g, budget, poses, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False,
                                   workers=1, joint=True)
            reported_cpu = (time.process_time() - c0) / len(poses)
            for k, pose in enumerate(poses):
                row = {"preset": preset, "pose": pose.tolist(), "S_um": S_um, "Z_arcsec": Z_as,
                       "P_pos": float(r.exceed_position[k]), "P_phi": float(r.exceed_phi[k]),
                       "bound_pos": float(r.bound_position[k]), "bound_phi": float(r.bound_phi[k]),
                       "channels_cpu_s": ch_cpu, "bound_reported": float(reported.bound_any[k]),
                       "exact_yield_cpu_s": reported_cpu,
                       "bound_channels_tight": float(tight.bound_position[k] + tight.bound_phi[k]), "budgets": []}
                for cells in budgets:
                    conditional._MAX_CELLS = cells
                    counter.n = 0
                    c0 = time.process_time()
                    lo, hi = conditional.joint_exceedance(C[k:k + 1], Ainv[k:k + 1], m.legs, table, kappa[k:k + 1],
                                                          S_um / MM2UM, Z_as / DEG2ARCSEC * DEG2RAD, TARGET, share,
                                                          workers=1)
                    cpu = time.process_time() - c0
                    lo, hi = float(lo[0]), float(min(hi[0], row["P_pos"] + row["bound_pos"],
                                                     row["P_phi"] + row["bound_phi"]))
                    row["budgets"].append({
                        "max_cells": cells, "J_lo": lo, "J_hi": hi, "J_width": hi - lo,
                        "bound_either": 0.5 * (hi - lo) + row["bound_pos"] + row["bound_phi"],
                        "bound_either_tight": 0.5 * (hi - lo) + (row["bound_channels_tight"] if hi - lo <= TARGET
                                                                 else row["bound_pos"] + row["bound_phi"]),
                        "cells_evaluated": counter.n, "cpu_s": cpu})
                conditional._MAX_CELLS = default
                out.append(row)
                print(json.dumps(row), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, nargs="+", default=[conditional._MAX_CELLS])
    ap.add_argument("--specs", nargs="+", default=None, help="S x Z pairs, e.g. 60x20 (µm x arcsec)")
    ap.add_argument("--presets", nargs="+", default=["u-shape", "delta-shape"])
    a = ap.parse_args()
    specs = SPECS if a.specs is None else [tuple(float(v) for v in s.split("x")) for s in a.specs]
    t0 = time.perf_counter()
    rows = run(a.presets, specs, a.cells)
    print(json.dumps({"target": TARGET, "cells": a.cells, "rows": len(rows), "wall_s": time.perf_counter() - t0,
                      "load_1min": os.getloadavg()[0]}))


if __name__ == "__main__":
    main()
