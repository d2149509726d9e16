"""P(either) of the budget of every law and effect (a shared temperature among them): the Fréchet bracket
against the conditioning on two legs and the temperature's intervals.

The budget of ``tests/test_yield.py`` (clearances with uniform, disc and discrete radii, truncated normal,
discrete, triangular and normal laws; an offset, a lead scale, a cyclic error, a backlash, the temperature over
15-30 degC), both geometries (their leads set as ``tests/realities.py`` does), the default region's corners and
centre, three spec pairs; one thread. For each: P(either), the bound of the bracket (``exact_yield(joint=False)``)
and of the conditioning (the default), and the CPU seconds a pose of each call (``time.process_time``).

Usage: ``python benchmarks/bench_yield_either_mixed.py`` prints one JSON object a line.
"""

from __future__ import annotations

import json
import os
import sys
import time
import warnings

import numpy as np

from prp3mc import Geometry, exact_yield

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
from bench_yield_either import region_poses  # noqa: E402
from tests.realities import with_leads  # noqa: E402
from tests.test_yield import mixed_budget  # noqa: E402

SPECS = [(60.0, 30.0), (80.0, 40.0), (100.0, 60.0), (150.0, 100.0)]


def main() -> None:
    warnings.simplefilter("ignore")
    for preset in ("u-shape", "delta-shape"):
        g = with_leads(Geometry.from_preset(preset))
        budget = mixed_budget(g)
        poses = region_poses(preset)
        exact_yield(g, budget, poses[:1], spec_position_um=80.0, spec_phi_arcsec=40.0, quantiles=False, workers=1)
        for S, Z in SPECS:
            out = {"preset": preset, "S_um": S, "Z_arcsec": Z}
            for name, joint in (("bracket", False), ("conditioned", None)):
                c0 = time.process_time()
                r = exact_yield(g, budget, poses, spec_position_um=S, spec_phi_arcsec=Z, quantiles=False, workers=1,
                                joint=joint)
                out[name] = {"P_either": r.exceed_any.tolist(), "bound": r.bound_any.tolist(),
                             "bracketed": r.bracketed_any.tolist(),
                             "cpu_s_per_pose": (time.process_time() - c0) / len(poses)}
            print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
