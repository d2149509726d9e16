"""Rates of the discrepancy workflow on campaigns as a real instrument delivers them.

Over many seeds per case, on both reference geometries (49 poses x 8 visits,
phi in {-4, 0, 4} deg, both approach directions, 20 -> 28 degC, instrument
noise 2 µm / 0.0005 deg), it measures

- **false names**: campaigns that name an effect that was not hidden (nor is
  an alias of one that was), in null campaigns carrying a registration
  error alone or with a drift, errors that repeat, or gross outliers;
- **found**: campaigns in which every hidden effect is named or listed as an
  alias of a named one, and **exact**: named set = hidden set;
- **unexplained**: campaigns the workflow flags as unexplained; **ambiguous**:
  campaigns whose verdict says the cause is ambiguous (a named effect with
  aliases, or a drift an effect explains as well);
- **outliers found / false alarms**: share of the gross errors listed under
  ``outliers``, and listed rows that were not gross errors (per campaign),
  and the seconds per campaign (a campaign with gross errors also runs the
  comparison without setting them aside);
- **held-out gap after**: its mean (the null level is at most 1) and the
  share of campaigns where it exceeds the closing level;
- the **round trip** (issue 16): campaign 1 of a machine with hidden effects
  is analysed and its updated model (``result.model``: identified geometry
  and budget with ``[effects]``) checks campaign 2 of the same machine (seed
  + 10000); *found* is scored on campaign 1, everything else on campaign 2,
  where any name is a false one.

Usage: ``python benchmarks/bench_discrepancy.py [--seeds N] [--quick] [--json]
[--cases NAME ...] [--geometries u-shape delta-shape]``.

``--speed`` measures instead what one analysis costs a user
(:func:`bench_discrepancy_cli`): ``prp3mc discrepancy`` on a campaign of 392
rows (49 poses x 8 visits, registration error, U-shape), report included,
as wall time of the whole command in a fresh process, and split into import,
analysis and report in another fresh process; the target is 5 s on the
2-core machine. ``benchmarks/run.py`` reports it too.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import prp3mc
from prp3mc import Budget, Geometry, Region
from prp3mc.measurement.campaign.simulate import simulate_campaign
from prp3mc.measurement.discrepancy.workflow import discrepancy

SIGMA = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
#: The registration error of issue 10: 20 µm and 0.005 deg, carried by every case but the last.
REGISTRATION = (0.020, -0.020, 0.005)
#: The round-trip case: a second campaign checked against the model files of the first.
ROUND_TRIP = "round trip: scale_2 5e-4 + backlash_1 20 µm + beta_1 0.03 deg hidden, registration"
#: name -> (simulate_campaign keyword arguments, hidden effects)
CASES = {
    "null, registration": ({"registration": REGISTRATION}, ()),
    "null, registration + drift 15 µm in x": ({"registration": REGISTRATION, "drift": (0.015, 0.0, 0.0)}, ()),
    "null, registration + repeats r = 0.8": ({"registration": REGISTRATION, "repeatable_fraction": 0.8}, ()),
    "null, registration + outliers 1 % x 0.5 mm": ({"registration": REGISTRATION, "outliers": (0.01, 0.5)}, ()),
    "scale_2 hidden, registration": ({"effects": {"scale_2": 2e-4}, "registration": REGISTRATION}, ("scale_2",)),
    "scale_2 + beta_1 hidden, registration": ({"effects": {"scale_2": 5e-4, "beta_1": 0.03},
                                               "registration": REGISTRATION}, ("scale_2", "beta_1")),
    "scale_2 + beta_1 hidden, registered": ({"effects": {"scale_2": 2e-4, "beta_1": 0.03}},
                                            ("scale_2", "beta_1")),
    ROUND_TRIP: ({"effects": {"scale_2": 5e-4, "backlash_1": 0.02, "beta_1": 0.03}, "registration": REGISTRATION},
                 ("scale_2", "backlash_1", "beta_1")),
}


def campaign_poses(preset: str) -> np.ndarray:
    poses = Region.from_preset(preset).grid(7).reshape(-1, 3)
    poses[:, 2] = np.tile([-4.0, 0.0, 4.0], 17)[:49]
    return poses


def score(result, hidden: tuple, outlier_rows: list) -> dict:
    """One campaign's outcome: a named effect is false when neither it nor any of its aliases was hidden."""
    hidden = set(hidden)
    named = {e.name for e in result.named_effects}
    covered = named | {a for e in result.named_effects for a in e.aliases}
    row = {"false_name": any(e.name not in hidden and not set(e.aliases) & hidden for e in result.named_effects),
           "found": hidden <= covered if hidden else None,
           "exact": named == hidden if hidden else None,
           "unexplained": bool(result.unexplained), "ambiguous": result.verdict["state"] == "ambiguous"}
    rows = {int(o["row"]) for o in result.outliers}
    row["outliers_found"] = len(rows & set(outlier_rows)) / len(outlier_rows) if outlier_rows else None
    row["outlier_false_alarms"] = len(rows - set(outlier_rows))
    row["held_out_after"] = float(result.gap["held_out"]["after"])
    row["held_out_open"] = bool(result.gap["held_out"]["after"] > result.gap["closed_at"])
    return row


def round_trip(geometry, budget, poses, seed: int, kwargs: dict, hidden: tuple) -> dict:
    """Campaign 1 named, its updated model checks campaign 2 of the same machine: the row of campaign 2."""
    c1 = simulate_campaign(geometry, budget, poses, 8, rng=seed, **SIGMA, **kwargs)
    first = discrepancy(geometry, budget, c1, rng=seed, **SIGMA)
    c2 = simulate_campaign(geometry, budget, poses, 8, rng=seed + 10_000, **SIGMA, **kwargs)
    second = discrepancy(first.model.geometry, first.model.budget, c2, rng=seed, **SIGMA)
    row = score(second, (), list(c2.metadata["outlier_rows"]))
    row["false_name"] = bool(second.named_effects)
    row["found"] = score(first, hidden, [])["found"]
    return row


def wilson(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson interval of a proportion k / n."""
    if n == 0:
        return (math.nan, math.nan)
    z, p = 1.959963984540054, k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def run_case(preset: str, name: str, seeds: range) -> dict:
    kwargs, hidden = CASES[name]
    geometry, budget = Geometry.from_preset(preset), Budget.from_preset("paper")
    poses = campaign_poses(preset)
    rows, seconds = [], []
    for seed in seeds:
        t0 = time.perf_counter()
        if name == ROUND_TRIP:
            rows.append(round_trip(geometry, budget, poses, seed, kwargs, hidden))
        else:
            c = simulate_campaign(geometry, budget, poses, 8, rng=seed, **SIGMA, **kwargs)
            t0 = time.perf_counter()
            result = discrepancy(geometry, budget, c, rng=seed, **SIGMA)
            rows.append(score(result, hidden, list(c.metadata["outlier_rows"])))
        seconds.append(time.perf_counter() - t0)
    out = {"geometry": preset, "case": name, "hidden": list(hidden), "n": len(rows),
           "seconds_per_campaign": float(np.mean(seconds))}
    for key in ("false_name", "found", "exact", "unexplained", "ambiguous", "held_out_open"):
        values = [r[key] for r in rows if r.get(key) is not None]
        out[key] = None if not values else {"k": int(sum(values)), "n": len(values),
                                             "rate": sum(values) / len(values),
                                             "ci95": list(wilson(int(sum(values)), len(values)))}
    found = [r["outliers_found"] for r in rows if r.get("outliers_found") is not None]
    alarms = [r["outlier_false_alarms"] for r in rows]
    out["held_out_after_mean"] = float(np.mean([r["held_out_after"] for r in rows]))
    out["outliers_found"] = float(np.mean(found)) if found else None
    out["outlier_false_alarms_per_campaign"] = float(np.mean(alarms)) if alarms else None
    return out


def _cell(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, dict):
        return f"{v['k']}/{v['n']} ({100 * v['rate']:.0f} %)"
    return f"{v:.2f}"


def table(results: list[dict]) -> str:
    head = ["geometry", "case", "false names", "found", "exact", "unexplained", "ambiguous",
            "held-out gap after: mean; open",
            "outliers found", "false alarms/campaign", "s/campaign"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        cells = [r["geometry"], r["case"], _cell(r["false_name"]), _cell(r["found"]), _cell(r["exact"]),
                 _cell(r["unexplained"]), _cell(r["ambiguous"]),
                 f"{_cell(r['held_out_after_mean'])}; {_cell(r['held_out_open'])}",
                 _cell(r["outliers_found"]), _cell(r["outlier_false_alarms_per_campaign"]),
                 f"{r['seconds_per_campaign']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: What ``prp3mc discrepancy`` may take on a 400-row campaign, report included (issue 10), s.
SPEED_TARGET_S = 5.0

#: The command's work in one fresh process, timed part by part (argv: data, out).
_SPLIT = """
import sys, time, json
t0 = time.perf_counter()
from prp3mc.cli import build_parser
build_parser("discrepancy")                       # what the command line imports
from prp3mc import Budget, Geometry
from prp3mc.measurement.discrepancy.workflow import discrepancy
from prp3mc.reports.discrepancy_report import write_report
t1 = time.perf_counter()
r = discrepancy(Geometry.load("u-shape"), Budget.load("paper"), sys.argv[1], instrument_sigma_mm=0.002,
                instrument_sigma_deg=0.0005, rng=1)
t2 = time.perf_counter()
import matplotlib.figure, matplotlib.backends.backend_agg
t3 = time.perf_counter()
write_report(r, sys.argv[2])
t4 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "analysis": t2 - t1, "report": t4 - t2, "report_matplotlib_import": t3 - t2}))
"""


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def bench_discrepancy_cli(quick: bool = False, repeat: int = 5) -> dict:
    """``prp3mc discrepancy`` on 392 rows, report included: wall and CPU time, and where it goes.

    Each run is a fresh process (imports cold, as a user's); the best and the
    median of ``repeat`` runs (2 with ``quick``) are reported with the
    1-minute load average before and after, since the machine is shared.
    """
    repeat = 2 if quick else repeat
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    campaign = simulate_campaign(g, b, campaign_poses("u-shape"), 8, rng=1, registration=REGISTRATION, **SIGMA)
    out = {"discrepancy_cli_rows": campaign.n_measurements, "discrepancy_cli_target_s": SPEED_TARGET_S,
           "discrepancy_cli_load_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "campaign.csv"
        campaign.to_csv(data)
        argv = [sys.executable, "-m", "prp3mc", "discrepancy", "--geometry", "u-shape", "--budget", "paper",
                "--data", str(data), "--instrument-sigma-mm", "0.002", "--instrument-sigma-deg", "0.0005",
                "--seed", "1", "--no-progress", "--out"]
        walls, cpus = [], []
        for k in range(repeat):
            c0, t0 = _children_cpu(), time.perf_counter()
            subprocess.run(argv + [str(Path(tmp) / f"cli{k}")], check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
            cpus.append(_children_cpu() - c0)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        startup = time.perf_counter() - t0
        splits = [json.loads(subprocess.run([sys.executable, "-c", _SPLIT, str(data), str(Path(tmp) / f"s{k}")],
                                            check=True, capture_output=True, text=True).stdout)
                  for k in range(repeat)]
    out.update({"discrepancy_cli_wall_s_best": min(walls), "discrepancy_cli_wall_s_median": statistics.median(walls),
                "discrepancy_cli_cpu_s_median": statistics.median(cpus), "python_startup_s": startup,
                "discrepancy_cli_load_after": os.getloadavg()[0]})
    for part in splits[0]:
        out[f"discrepancy_{part}_s_median"] = statistics.median(s[part] for s in splits)
    return out


def speed_table(r: dict) -> str:
    """The speed figures as a few readable lines."""
    return "\n".join([
        f"prp3mc discrepancy, {r['discrepancy_cli_rows']} rows, report included: "
        f"{r['discrepancy_cli_wall_s_best']:.2f} s best, {r['discrepancy_cli_wall_s_median']:.2f} s median wall "
        f"({r['discrepancy_cli_cpu_s_median']:.2f} s CPU; target <= {r['discrepancy_cli_target_s']:g} s)",
        f"  split (median, fresh process): import {r['discrepancy_import_s_median']:.2f} s, analysis "
        f"{r['discrepancy_analysis_s_median']:.2f} s, report {r['discrepancy_report_s_median']:.2f} s (of which "
        f"importing matplotlib {r['discrepancy_report_matplotlib_import_s_median']:.2f} s); python start "
        f"{r['python_startup_s']:.2f} s",
        f"  1-minute load average {r['discrepancy_cli_load_before']:.1f} before, "
        f"{r['discrepancy_cli_load_after']:.1f} after (2 cores)"])


def rates_parser(description: str, cases, seeds: int, quick: int) -> argparse.ArgumentParser:
    """The options of a rates benchmark: ``--seeds`` (default ``seeds``), ``--quick`` (``quick`` seeds),
    ``--first-seed``, ``--cases`` (of ``cases``), ``--geometries``, ``--json``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--seeds", type=int, default=seeds, help=f"campaigns per case and geometry (default {seeds})")
    p.add_argument("--quick", action="store_true", help=f"{quick} seeds per case")
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--cases", nargs="+", choices=list(cases), default=list(cases), metavar="CASE")
    p.add_argument("--geometries", nargs="+", default=["u-shape", "delta-shape"])
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    return p


def main(argv=None) -> int:
    p = rates_parser(__doc__.splitlines()[0], CASES, 40, 8)
    p.add_argument("--speed", action="store_true", help="time prp3mc discrepancy on 392 rows instead of the rates")
    args = p.parse_args(argv)
    if args.speed:
        doc = bench_discrepancy_cli(args.quick)
        print(json.dumps(doc, indent=2) if args.json else speed_table(doc))
        return 0
    run_cases(run_case, table, args.geometries, args.cases,
              range(args.first_seed, args.first_seed + (8 if args.quick else args.seeds)), args.json)
    return 0


def run_cases(run_case, table, geometries, cases, seeds: range, as_json: bool) -> None:
    """Every case on every geometry over ``seeds``: a row per case on stderr as it ends (unless ``as_json``),
    then the table or one JSON object (seeds, results, wall time) on stdout."""
    t0 = time.perf_counter()
    results = []
    for preset in geometries:
        for name in cases:
            results.append(run_case(preset, name, seeds))
            if not as_json:
                print(table(results[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
    doc = {"prp3mc": prp3mc.__version__, "seeds": [seeds.start, seeds.stop], "results": results,
           "wall_s": time.perf_counter() - t0}
    print(json.dumps(doc, indent=2) if as_json else table(results))


if __name__ == "__main__":
    sys.exit(main())
