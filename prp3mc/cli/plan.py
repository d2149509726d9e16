"""``prp3mc plan``: a campaign template that makes the listed effects detectable (SPEC §11)."""

from pathlib import Path

from ..errors import ParameterError
from ..limits import plan_estimate
from ..errors import OutputExistsError
from . import (add_budget, add_geometry, add_instrument_noise, add_json, add_seed, command, emit_json, finite_float,
               positive_float, positive_int, probability, provenance, within_limits)
from ..provenance import spec_record


def effect_list(text: str) -> list[str]:
    """``E1,E2,...`` as a list of names (checked by the plan)."""
    return [name.strip() for name in text.split(",") if name.strip()]


@command("plan", "plan a campaign: poses, visit order and approach directions that make the listed effects "
                 "detectable")
class PlanCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        p.add_argument("--effects", required=True, type=effect_list, metavar="E1,E2,...",
                       help="candidate systematic effects to plan for (SPEC §5 names, comma separated)")
        p.add_argument("--poses", required=True, type=positive_int, metavar="N", help="distinct poses")
        p.add_argument("--visits", required=True, type=positive_int, metavar="V", help="visits of each pose")
        # dest template: the command line claims an --out *folder* (prp3mc.output); this is one file
        p.add_argument("--out", dest="template", required=True, type=Path, metavar="FILE.csv",
                       help="the campaign template to write")
        p.add_argument("--force", action="store_true", help="replace an existing file")
        p.add_argument("--minutes", type=positive_float, default=None, metavar="M",
                       help="spread the planned time_s evenly over M minutes (default: the moves at 20 mm/s and "
                            "4 s per measurement)")
        p.add_argument("--region", nargs="+", default=None, metavar="R",
                       help="where to choose poses: a preset (u-shape, delta-shape) or a region TOML file (prp3mc "
                            "init region), as other commands take it, or its bounds X0 X1 Y0 Y1 in mm (default: "
                            "the geometry's preset test region)")
        p.add_argument("--temperature", nargs=2, type=finite_float, default=(20.0, 28.0), metavar=("START", "END"),
                       help="temperature assumed for thermal expansion, rising steadily, deg C (not planned; "
                            "default 20 28)")
        add_instrument_noise(p, 0.002, 0.0005)
        p.add_argument("--no-registration", action="store_true",
                       help="the analysis will not fit the instrument's registration")
        p.add_argument("--power", type=probability, default=0.9, metavar="P",
                       help="probability of naming an effect at its detectable value (default 0.9)")
        p.add_argument("--alpha", type=probability, default=0.01, metavar="A",
                       help="family-wise level of the naming tests (default 0.01)")
        add_seed(p, help="seed of the directions and orders (default: fresh, recorded in the output)")
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..kinematics.geometry import Geometry
        from ..measurement.campaign.plan import MAX_CANDIDATES, plan_campaign
        from ..model.budget import Budget
        twice = sorted({name for name in args.effects if args.effects.count(name) > 1})
        if twice:
            raise ParameterError(f"--effects names {', '.join(twice)} twice: list each effect once")
        if args.template.suffix.lower() not in ("", ".csv"):
            raise ParameterError(f"--out {args.template}: the plan template is a CSV file; name it FILE.csv "
                                 "(--json prints the plan's summary on stdout)")
        if args.template.exists() and not args.force:
            raise OutputExistsError(f"{args.template} exists: choose another name or pass --force to replace it")
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        within_limits(args, plan_estimate(MAX_CANDIDATES, args.visits, len(args.effects)))
        region, where = _region(args.region)
        plan = plan_campaign(geometry, budget, args.effects, args.poses, args.visits, minutes=args.minutes,
                             region=region, temperature_C=tuple(args.temperature),
                             instrument_sigma_mm=args.instrument_sigma_mm,
                             instrument_sigma_deg=args.instrument_sigma_deg, registration=not args.no_registration,
                             power=args.power, alpha=args.alpha, rng=args.seed)
        args.template.parent.mkdir(parents=True, exist_ok=True)
        plan.write(args.template)
        if args.json:
            doc = plan.to_dict()
            doc["inputs"] = doc["inputs"] | provenance(args, geometry, budget)["inputs"] | {"out": str(args.template)}
            doc["inputs"]["region"] = where | doc["inputs"]["region"]      # a preset's or file's name, as grid_poses
            emit_json(doc)
            return
        print("\n".join(summary(plan) + [f"template: {args.template} (measured columns and temp_C to fill in)"]))


def _region(values: list[str] | None) -> tuple["Region | None", dict]:
    """``--region``: a preset or region file (one value), or its bounds X0 X1 Y0 Y1 in mm (four numbers, the
    older form); the region (None: the geometry's preset) and, for a preset or file, its record (name, and
    preset or file and sha256) for ``inputs.region``."""
    import argparse

    from ..kinematics.geometry import Region

    if values is None:
        return None, {}
    if len(values) == 1:
        region = Region.load(values[0])
        return region, spec_record(values[0], region)
    if len(values) != 4:
        raise ParameterError(f"--region takes a preset or region file (R), or four bounds X0 X1 Y0 Y1 in mm; got "
                             f"{len(values)} values: {' '.join(values)}")
    try:
        x0, x1, y0, y1 = (finite_float(v) for v in values)
    except argparse.ArgumentTypeError as exc:
        raise ParameterError(f"--region X0 X1 Y0 Y1: {exc}") from None
    return Region((x0, x1), (y0, y1)), {}


def summary(plan) -> list[str]:
    """The lines printed after planning: layout, smallest detectable values against the grid, confounds."""
    s = plan.settings
    lines = [f"{plan.poses.shape[0]} poses x {s['n_visits']} visits = {plan.n_measurements} measurements, "
             f"chosen from {s['candidates']} candidates (phi {min(s['phi_candidates_deg']):g} to "
             f"{max(s['phi_candidates_deg']):g} deg); seed {s['seed']}",
             f"smallest value named with probability {s['power']:g} (family-wise level {s['alpha']:g}), this plan "
             f"vs {plan.reference_layout}:"]
    for name, value in plan.detectable.items():
        lines.append(f"  {name}: not detectable: {plan.unseen[name]}" if name in plan.unseen else
                     f"  {name}: {value:.4g} vs {plan.reference[name]:.4g}")
    if "thermal" in plan.effects:
        t = s["temperature_C"]
        lines.append(f"thermal assumes the temperature rising steadily {t[0]:g} -> {t[1]:g} degC: the plan cannot "
                     "set it; it interleaves the visits so every pose is measured early and late. Cycle the "
                     "temperature to separate thermal expansion from drift")
    for c in plan.confounded:
        lines.append(f"confounded (the plan cannot break it): {', '.join(c['effects'])} with {', '.join(c['with'])}: "
                     f"{c['why']}")
    return lines
