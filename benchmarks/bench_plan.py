"""A planned campaign against the 7 x 7 grid of the same size (issue 24, point 6), on the exact chain.

For each geometry, ``plan_campaign`` plans 49 poses x 8 visits for a few
candidate effects (``PLANNED``). For each effect:

- its **smallest detectable value** (named with probability 0.9 at the
  workflow's level, registration fitted) on the plan and on the grid of
  ``bench_discrepancy.py`` (49 poses, phi cycling -4, 0, 4 deg, 8 visits in
  random rounds, random approach directions);
- the **detection rate** over seeds: campaigns simulated with the exact
  chain on each layout (a registration error of 20 µm / 20 µm / 0.005
  deg, temperature 20 -> 28 degC), the effect hidden at the plan's
  detectable value, analysed by ``discrepancy``: the share in which it is
  named (or is an alias of the named effect).

Both layouts carry the ``dir_i`` columns of the legs with a backlash among
the planned effects only, as the plan's template does.

**Thermal against drift** (``--thermal``, issue 24 points 2 and 6): on the
delta-shape, lead screws expanding by ``THERMAL`` 1/K (the tests' machine,
``tests/realities.py``, made apart from the library's thermal effect), the
temperature rising steadily with time (a machine warming up) or cycled
three times, on the plan for thermal (planned with the temperature rising:
the plan cannot set it) and on the grid: thermal's smallest detectable
value, whether ``confounded`` lists it with the drift (its variance
inflation), and over seeds the share in which it is named (its value in
its interval), the verdict says the cause is ambiguous (because an effect
explains the data's drift as well, or aliases) or the disagreement
unexplained, or it is swallowed: not named while the verdict says
*explained* or *nothing missing*.

Usage: ``python benchmarks/bench_plan.py [--seeds N] [--geometries ...] [--thermal] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from pathlib import Path

from bench_discrepancy import REGISTRATION, SIGMA, campaign_poses, wilson

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.realities import cycled, rising, thermal_campaign  # noqa: E402  the tests' thermal machine

import prp3mc
from prp3mc import Budget, Geometry
from prp3mc.measurement.naming.confounds import design_confounds
from prp3mc.measurement.estimation.likelihood import Engine
from prp3mc.measurement.campaign.plan import plan_campaign
from prp3mc.measurement.forward.prediction import noise_cov
from prp3mc.measurement.campaign.simulate import simulate_campaign
from prp3mc.measurement.discrepancy.workflow import detectable_effect, discrepancy

#: The effects planned for on each geometry (each is then hidden alone).
PLANNED = {"u-shape": ("scale_2", "backlash_1", "beta_1", "thermal"),
           "delta-shape": ("scale_1", "backlash_3", "gamma_2", "thermal")}
#: Thermal expansion of the warming machine of the thermal case, 1/K.
THERMAL = 2e-5
_PLAN_SEED = 24


def layouts(preset: str, effects) -> dict:
    """The plan and the grid: name -> simulate_campaign keyword arguments, and the plan itself."""
    g, b = Geometry.from_preset(preset), Budget.from_preset("paper")
    plan = plan_campaign(g, b, effects, 49, 8, rng=_PLAN_SEED, **SIGMA)
    return plan, {"plan": {"poses": None, "plan": plan.to_frame()},
                  "grid": {"poses": campaign_poses(preset), "n_repeats": 8}}


def campaign(preset: str, layout: dict, dir_legs, seed: int, effects: dict):
    """One simulated campaign of ``layout`` as a frame with the ``dir_i`` columns of ``dir_legs`` only."""
    g, b = Geometry.from_preset(preset), Budget.from_preset("paper")
    kwargs = dict(layout)
    poses = kwargs.pop("poses")
    n = kwargs.pop("n_repeats", 8)
    c = simulate_campaign(g, b, poses, n, effects=effects, registration=REGISTRATION, rng=seed, **SIGMA, **kwargs)
    return c.to_frame().drop(columns=[f"dir_{i + 1}" for i in range(3) if i not in dir_legs])


def rate(values: list[bool]) -> dict:
    k = int(sum(values))
    return {"k": k, "n": len(values), "rate": k / len(values), "ci95": list(wilson(k, len(values)))}


def detection(preset: str, seeds: range) -> list[dict]:
    plan, lays = layouts(preset, PLANNED[preset])
    g, b = Geometry.from_preset(preset), Budget.from_preset("paper")
    out = []
    for name in PLANNED[preset]:
        value = plan.detectable[name]
        row = {"geometry": preset, "effect": name, "value": value, "detectable": {}, "detected": {}}
        for label, layout in lays.items():
            frames = [campaign(preset, layout, plan.dir_legs, s, {name: value}) for s in seeds]
            row["detectable"][label] = detectable_effect(g, b, prp3mc.read_campaign(frames[0], g), name,
                                                         **SIGMA)
            found = [discrepancy(g, b, f, rng=s, **SIGMA).effect_fit(name) is not None for s, f in zip(seeds, frames)]
            row["detected"][label] = rate(found)
        out.append(row)
        print(table([row]).splitlines()[-1], file=sys.stderr, flush=True)
    return out


def thermal(seeds: range) -> list[dict]:
    """Thermal expansion hidden on a warming and on a cycled machine, on the plan and on the grid (delta-shape)."""
    preset = "delta-shape"
    g, b = Geometry.from_preset(preset), Budget.from_preset("paper")
    plan, lays = layouts(preset, ("thermal",))
    noise = noise_cov(SIGMA["instrument_sigma_mm"], SIGMA["instrument_sigma_deg"])
    out = []
    for label, layout in lays.items():
        kwargs = dict(layout)
        poses, n = kwargs.pop("poses"), kwargs.pop("n_repeats", 8)
        for profile in (rising, cycled):
            frames = [thermal_campaign(g, poses, n, THERMAL, profile, s, registration=REGISTRATION, **kwargs)
                      .drop(columns=["dir_1", "dir_2", "dir_3"]) for s in seeds]
            engine = Engine(g, b, prp3mc.read_campaign(frames[0], g), noise)
            listed = [c["vif"]["thermal"] for c in design_confounds(engine, ("thermal",)) if "vif" in c]
            rows = []
            for s, f in zip(seeds, frames):
                r = discrepancy(g, b, f, rng=s, **SIGMA)
                fit = r.effect_fit("thermal")
                rows.append({"named": fit is not None, "in_ci": fit is not None and fit[1][0] <= THERMAL <= fit[1][1],
                             "ambiguous": r.verdict["state"] == "ambiguous",
                             "fine": r.verdict["state"] in ("explained", "nothing missing"),
                             "unexplained": r.verdict["state"] == "unexplained",
                             "drift": any(c["source"] == "data" and "thermal" in c["effects"] for c in r.confounded)})
            row = {"layout": label, "temperature": profile.__name__, "thermal": THERMAL,
                   "detectable": detectable_effect(g, b, prp3mc.read_campaign(frames[0], g), "thermal", **SIGMA),
                   "vif_listed": listed[0] if listed else None}
            for key in ("named", "in_ci", "ambiguous", "drift", "unexplained"):
                row[key] = rate([x[key] for x in rows])
            row["swallowed"] = rate([not x["named"] and x["fine"] for x in rows])
            out.append(row)
            print(thermal_table([row]).splitlines()[-1], file=sys.stderr, flush=True)
    return out


def thermal_table(rows: list[dict]) -> str:
    head = ["layout", "temperature", "detectable", "listed with drift (VIF)", "named", "value in CI",
            "ambiguous", "of which the data's drift", "unexplained", "swallowed"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        vif = "no" if r["vif_listed"] is None else f"yes ({r['vif_listed']:.3g})"
        lines.append(f"| {r['layout']} | {r['temperature']} | {r['detectable']:.3g} | {vif} | {_cell(r['named'])} | "
                     f"{_cell(r['in_ci'])} | {_cell(r['ambiguous'])} | {_cell(r['drift'])} | "
                     f"{_cell(r['unexplained'])} | {_cell(r['swallowed'])} |")
    return "\n".join(lines)


def _cell(r: dict) -> str:
    return f"{r['k']}/{r['n']}"


def table(rows: list[dict]) -> str:
    head = ["geometry", "effect", "hidden value (the plan's detectable)", "detectable: plan; grid",
            "detected: plan; grid"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        d, k = r["detectable"], r["detected"]
        lines.append(f"| {r['geometry']} | {r['effect']} | {r['value']:.3g} | {d['plan']:.3g}; {d['grid']:.3g} | "
                     f"{_cell(k['plan'])}; {_cell(k['grid'])} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=25, help="campaigns per effect and layout (default 25)")
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--geometries", nargs="+", default=list(PLANNED))
    p.add_argument("--thermal", action="store_true", help="the thermal-against-drift case instead")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = p.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    t0 = time.perf_counter()
    doc = {"prp3mc": prp3mc.__version__, "seeds": [seeds.start, seeds.stop], "plan_seed": _PLAN_SEED}
    if args.thermal:
        doc["thermal"] = thermal(seeds)
    else:
        doc["detection"] = [row for preset in args.geometries for row in detection(preset, seeds)]
    doc["wall_s"] = time.perf_counter() - t0
    print(json.dumps(doc, indent=2) if args.json else
          thermal_table(doc["thermal"]) if args.thermal else table(doc["detection"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
