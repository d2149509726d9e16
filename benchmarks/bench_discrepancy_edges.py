"""Rates of the discrepancy workflow at its edges (issue 24): cyclic screw errors, effects outside the library,
one-visit sweeps, and the registration under aliases.

Over many seeds per case, on both reference geometries (instrument noise 2 µm / 0.0005 deg, a registration
error of 20 µm / -20 µm / 0.005 deg in every campaign), it measures per case

- **named**: campaigns naming anything; **found**: every hidden library effect named or in a named alias set;
- **wrong name**: a name that is neither hidden, nor an alias of a hidden effect, nor one of the case's declared
  first-order equivalents; **confident wrong name**: a wrong name with the gap closed (nothing flagged
  unexplained: the user would believe it);
- **unexplained**: the verdict says disagreement remains;
- for a hidden cyclic error, **amplitude covered**: the true amplitude inside the named amplitude's 95 %
  interval, and the median phase error; **registration covered**: registration components inside their
  (alias-union) 95 % intervals, counted per component (three per campaign).

Campaigns (makers in ``tests/realities.py``): 49 poses x 8 visits (phi -4, 0, 4 deg; both approach directions;
20 -> 28 degC), or, for the sweeps, 225 poses at phi = 0 visited once along a serpentine path. Cases outside
the library and their first-order equivalents (a library effect that the out-of-library effect's Taylor
expansion contains, which the workflow may rightly name):

- cyclic error of leg 2 (15 µm, 5 mm lead) on a geometry without ``lead_mm``: none;
- bowed rail of leg 2: delta b_2 = 20 µm (2 (b_2 - mid) / range)^2 over the campaign's range of b_2: ``b_2``
  (its mean) and ``scale_2`` (its slope);
- sagging passive guide of leg 1: delta theta_1 = 0.02 deg (d_1 / 100 mm)^2 through the exact chain: ``theta_1``;
- thermal expansion 4e-5 /K at the true temperature (20 -> 28 degC) read by a sensor saturating at 24 degC:
  ``thermal``.

Usage: ``python benchmarks/bench_discrepancy_edges.py [--seeds N] [--quick] [--json] [--cases NAME ...]
[--geometries u-shape delta-shape]``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # the campaign makers of tests/realities.py

from prp3mc import Budget, Geometry  # noqa: E402
from prp3mc.kinematics.chain import inverse_kinematics  # noqa: E402
from prp3mc.measurement.campaign.simulate import simulate_campaign  # noqa: E402
from prp3mc.measurement.discrepancy.workflow import discrepancy  # noqa: E402
from bench_discrepancy import rates_parser, run_cases, wilson  # noqa: E402
from tests.realities import (bowed_rail, campaign_poses, cyclic_error, sagging_guide, saturated,  # noqa: E402
                             sweep_poses, thermal_error, with_leads)

SIGMA = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
REGISTRATION = (0.020, -0.020, 0.005)
CYCLIC = (0.015, 30.0)                     # 15 µm, phase 30 deg, leg 2


def _grid(preset):
    return campaign_poses(preset, True)


def _b_range(geometry, poses, leg):
    b, _ = inverse_kinematics(geometry, poses, check=False)
    return float(b[:, leg - 1].min()), float(b[:, leg - 1].max())


#: name -> (layout, make(geometry, preset) -> (geometry, simulate kwargs, post-processing), hidden, equivalents)
CASES = {
    "cyclic_2 15 µm, lead_mm 5": (
        "grid", lambda g, p: (with_leads(g), {"effects": {"cyclic_2": CYCLIC}}, None), ("cyclic_2",), ()),
    "null, lead_mm 5 (cyclic candidates)": ("grid", lambda g, p: (with_leads(g), {}, None), (), ()),
    "cyclic 15 µm on leg 2, no lead_mm": (
        "grid", lambda g, p: (g, {"slider_error_fn": cyclic_error(2, CYCLIC[0], phase_deg=CYCLIC[1])}, None), (), ()),
    "bowed rail, leg 2, 20 µm": (
        "grid", lambda g, p: (g, {"slider_error_fn": bowed_rail(2, 0.020, *_b_range(g, _grid(p), 2))}, None),
        (), ("b_2", "scale_2")),
    "sagging guide, leg 1, 0.02 deg at d = 100 mm": (
        "grid", lambda g, p: (g, {"pose_error_fn": sagging_guide(g, 1, 0.02)}, None), (), ("theta_1",)),
    "thermal 4e-5 /K, sensor saturating at 24 degC": (
        "grid", lambda g, p: (g, {"slider_error_fn": thermal_error(4e-5)}, lambda c: saturated(c, 24.0)),
        (), ("thermal",)),
    "one visit: null sweep": ("sweep", lambda g, p: (g, {}, None), (), ()),
    "one visit: beta_1 0.06 deg": ("sweep", lambda g, p: (g, {"effects": {"beta_1": 0.06}}, None), ("beta_1",), ()),
    "aliases: alpha_1 0.05 deg at phi = 0": (
        "grid0", lambda g, p: (g, {"effects": {"alpha_1": 0.05}}, None), ("alpha_1",), ()),
    "aliases: spread_b_3 0.0625 mm": (
        "grid", lambda g, p: (g, {"effects": {"spread_b_3": 0.0625}}, None), ("spread_b_3",), ()),
}


def campaign(case: str, preset: str, seed: int):
    layout, make, hidden, equivalents = CASES[case]
    geometry, kwargs, post = make(Geometry.from_preset(preset), preset)
    budget = Budget.from_preset("paper")
    if layout == "sweep":
        c = simulate_campaign(geometry, budget, sweep_poses(preset), 1, rng=seed, visit_order="given",
                              registration=REGISTRATION, **SIGMA, **kwargs)
    else:
        poses = campaign_poses(preset, layout == "grid")
        c = simulate_campaign(geometry, budget, poses, 8, rng=seed, registration=REGISTRATION, **SIGMA, **kwargs)
    return geometry, budget, (post(c) if post else c)


def score(result, hidden: tuple, equivalents: tuple) -> dict:
    """One campaign's outcome (module notes)."""
    hidden, ok = set(hidden), set(hidden) | set(equivalents)
    named = {e.name for e in result.named_effects}
    covered = named | {a for e in result.named_effects for a in e.aliases}
    wrong = any(e.name not in ok and not set(e.aliases) & ok for e in result.named_effects)
    row = {"named": bool(named), "found": hidden <= covered if hidden else None, "wrong": wrong,
           "confident_wrong": wrong and not result.unexplained, "unexplained": bool(result.unexplained),
           "names": sorted(named)}
    cyc = next((e for e in result.named_effects if e.name == "cyclic_2" and "cyclic_2" in hidden), None)
    if cyc is not None:
        row["amplitude_covered"] = bool(cyc.ci95[0] <= CYCLIC[0] <= cyc.ci95[1])
        row["phase_error_deg"] = abs((cyc.phase_deg - CYCLIC[1] + 180.0) % 360.0 - 180.0)
        row["amplitude_ci_width_um"] = 1e3 * (cyc.ci95[1] - cyc.ci95[0])
    reg = [n for n in result.nuisance if n["name"].startswith("registration")]
    row["registration_covered"] = [bool(n["ci95"][0] <= REGISTRATION[k] <= n["ci95"][1]) for k, n in enumerate(reg)]
    row["registration_widened"] = any("by_alias" in n for n in reg)
    return row


def _rate(rows, key):
    values = [v for r in rows if r.get(key) is not None for v in np.atleast_1d(r[key])]
    if not values:
        return None
    k = int(sum(values))
    return {"k": k, "n": len(values), "rate": k / len(values), "ci95": list(wilson(k, len(values)))}


def run_case(preset: str, case: str, seeds: range) -> dict:
    _, _, hidden, equivalents = CASES[case]
    rows, seconds = [], []
    for seed in seeds:
        geometry, budget, c = campaign(case, preset, seed)
        t0 = time.perf_counter()
        result = discrepancy(geometry, budget, c, rng=seed, **SIGMA)
        seconds.append(time.perf_counter() - t0)
        rows.append(score(result, hidden, equivalents) | {"seed": seed})
    out = {"geometry": preset, "case": case, "hidden": list(hidden), "equivalents": list(equivalents),
           "n": len(rows), "seconds_per_campaign": float(np.mean(seconds))}
    for key in ("named", "found", "wrong", "confident_wrong", "unexplained", "amplitude_covered",
                "registration_covered", "registration_widened"):
        out[key] = _rate(rows, key)
    phase = [r["phase_error_deg"] for r in rows if "phase_error_deg" in r]
    width = [r["amplitude_ci_width_um"] for r in rows if "amplitude_ci_width_um" in r]
    out["phase_error_deg_median"] = float(np.median(phase)) if phase else None
    out["amplitude_ci_width_um_median"] = float(np.median(width)) if width else None
    counts: dict = {}
    for r in rows:
        for n in r["names"]:
            counts[n] = counts.get(n, 0) + 1
    out["names"] = dict(sorted(counts.items(), key=lambda kv: -kv[1]))
    out["rows"] = rows
    return out


def _cell(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, dict) and "k" in v:
        return f"{v['k']}/{v['n']}"
    if isinstance(v, dict):
        return ", ".join(f"{k} {n}" for k, n in v.items()) or "-"
    return f"{v:.2g}"


def table(results: list[dict]) -> str:
    head = ["geometry", "case", "named", "found", "wrong name", "confident wrong name", "unexplained",
            "amplitude covered", "registration covered", "names (count)", "s/campaign"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        cells = [r["geometry"], r["case"], *(_cell(r[k]) for k in ("named", "found", "wrong", "confident_wrong",
                                                                    "unexplained", "amplitude_covered",
                                                                    "registration_covered", "names")),
                 f"{r['seconds_per_campaign']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = rates_parser(__doc__.splitlines()[0], CASES, 20, 4).parse_args(argv)
    run_cases(run_case, table, args.geometries, args.cases,
              range(args.first_seed, args.first_seed + (4 if args.quick else args.seeds)), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
