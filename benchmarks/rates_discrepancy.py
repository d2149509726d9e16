"""Rates of the discrepancy workflow over many seeds, on campaigns as a real instrument delivers them.

Every campaign (49 poses x 8 visits, instrument noise 2 µm / 0.0005 deg) is
seen through a registration error of 20 µm and 0.005 deg. Scenarios: null,
drift 15 µm, 1 % of rows off by 0.5 mm, errors that repeat (r = 0.8),
scale_2 = 5e-4 with beta_1 = 0.03 hidden together. Prints, per geometry and
scenario, the share of campaigns with a false name, found hidden effects,
"unexplained" verdicts, outliers found and false alarms.

    python benchmarks/rates_discrepancy.py [n_seeds]
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from prp3mc import Geometry  # noqa: E402
from prp3mc.measurement.simulate import simulate_campaign  # noqa: E402
from prp3mc.measurement.workflow import discrepancy  # noqa: E402
from tests.realities import (BUDGET, SIGMA, campaign_poses, drifted, registered, repeating,  # noqa: E402
                             with_outliers)

HIDDEN = {"scale_2": 5e-4, "beta_1": 0.03}


def found(r, name):
    return any(e.name == name or name in e.aliases for e in r.named_effects)


def main(n_seeds: int) -> None:
    t0 = time.perf_counter()
    for preset in ("u-shape", "delta-shape"):
        g = Geometry.from_preset(preset)
        poses = campaign_poses(preset, preset == "u-shape")
        tally: dict = {}
        for seed in range(n_seeds):
            base = simulate_campaign(g, BUDGET, poses, 8, rng=1000 + seed, **SIGMA)
            dirty, rows = with_outliers(base, 0.01, 0.5, seed)
            cases = {
                "null": registered(base, 0.02, -0.02, 0.005),
                "drift": registered(drifted(base, 0.015, 0.0, 0.0), 0.02, -0.02, 0.005),
                "outliers": registered(dirty, 0.02, -0.02, 0.005),
                "repeat 0.8": registered(repeating(g, poses, 8, 0.8, 2000 + seed), 0.02, -0.02, 0.005),
                "scale_2+beta_1": registered(simulate_campaign(g, BUDGET, poses, 8, effects=HIDDEN, rng=3000 + seed,
                                                               **SIGMA), 0.02, -0.02, 0.005),
            }
            for name, c in cases.items():
                r = discrepancy(g, BUDGET, c, rng=seed, **SIGMA)
                t = tally.setdefault(name, {"n": 0, "false_name": 0, "unexplained": 0, "found_all": 0,
                                            "outliers_found": 0, "outliers_true": 0, "false_alarms": 0,
                                            "seconds": 0.0})
                t["n"] += 1
                t["seconds"] += r.wall_time_s
                truth = set(HIDDEN) if name == "scale_2+beta_1" else set()
                named = {e.name for e in r.named_effects}
                t["false_name"] += bool(len(named) > len(truth) or (not truth and named))
                t["unexplained"] += r.unexplained
                t["found_all"] += bool(truth) and all(found(r, n) for n in truth)
                flagged = {o["row"] for o in r.outliers}
                true_rows = set(rows) if name == "outliers" else set()
                t["outliers_found"] += len(flagged & true_rows)
                t["outliers_true"] += len(true_rows)
                t["false_alarms"] += len(flagged - true_rows)
        for name, t in tally.items():
            n = t["n"]
            extra = f", hidden pair found {t['found_all']}/{n}" if name == "scale_2+beta_1" else ""
            outl = (f", outliers found {t['outliers_found']}/{t['outliers_true']}" if t["outliers_true"] else "")
            print(f"{preset:12s} {name:15s} false names {t['false_name']}/{n}, unexplained {t['unexplained']}/{n}"
                  f"{extra}{outl}, false outlier alarms {t['false_alarms']} in {n} campaigns, "
                  f"{t['seconds'] / n:.1f} s each", flush=True)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
