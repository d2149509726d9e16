"""``prp3mc allocate``: the least-cost tolerance classes that meet an accuracy spec over a region."""

from __future__ import annotations

from .._version import __version__
from ..kinematics.geometry import REGION_PRESETS, Region
from ..provenance import spec_record
from ..units import DEG2ARCSEC, MM2UM, quantity_text
from ..limits import allocate_estimate
from . import (add_geometry, add_json, add_progress, add_seed, command, emit_json, finite_float, positive_float, positive_int,
               provenance, within_limits)


@command("allocate", "least-cost tolerance classes meeting an accuracy spec over a region")
class AllocateCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        p.add_argument("--region", required=True, metavar="R",
                       help=f"test region: a preset ({', '.join(REGION_PRESETS)}) or a region TOML file "
                            "(prp3mc init region)")
        p.add_argument("--classes", required=True, metavar="FILE.toml",
                       help="classes file (docs, File formats), or the bundled example: example")
        p.add_argument("--budget", default=None, metavar="B",
                       help="a budget whose [effects] (fitted offsets, lead scales, backlash, thermal) stay fixed "
                            "in every bound and check; its inputs play no part (the classes choose them)")
        p.add_argument("--spec-position-um", type=finite_float, default=None, metavar="X",
                       help="worst-case position error bound, µm (with --spec-percentile: that percentile's bound)")
        p.add_argument("--spec-phi-arcsec", type=finite_float, default=None, metavar="Z",
                       help="worst-case |dphi| bound, arcsec")
        p.add_argument("--spec-percentile", type=finite_float, default=None, metavar="Q",
                       help="bound the Q-th percentile of the position error instead of its worst case "
                            "(decided on the exact distribution, confirmed by Monte Carlo)")
        p.add_argument("--phi-deg", type=finite_float, default=None, metavar="P",
                       help="platform orientation of the region, deg (default: the region's own, 0 for the presets)")
        p.add_argument("--grid", type=positive_int, default=41, metavar="N", help="N x N grid (default 41)")
        p.add_argument("--k-sigma", type=positive_float, default=None, metavar="K",
                       help="bound unbounded (normal) laws as mean ± K·sd")
        p.add_argument("--samples", type=positive_int, default=20_000, metavar="N",
                       help="Monte Carlo samples confirming a percentile spec (default 20000)")
        add_seed(p, help="random seed of the confirmation")
        p.add_argument("--front", action="store_true",
                       help="also sweep the cost-accuracy Pareto front of the worst-case position error "
                            "(of |dphi| with only a phi spec; the phi spec holds along a position front)")
        add_progress(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..model.budget import Budget
        from ..allocation.classes import ClassMenu
        from ..allocation.optimum import allocate, allocation_front, front_records
        budget = None if args.budget is None else Budget.load(args.budget)
        region, menu = Region.load(args.region), ClassMenu.load(args.classes)
        if args.phi_deg is None:
            args.phi_deg = region.phi_deg
        terms = len(menu.inputs) + (0 if budget is None else len(budget.factors))   # the menu's; at most the budget's
        within_limits(args, allocate_estimate(args.grid ** 2, terms,
                                              args.samples if args.spec_percentile is not None else 0))
        r = allocate(args.geometry, menu, region, spec_position_um=args.spec_position_um,
                     spec_phi_arcsec=args.spec_phi_arcsec, spec_percentile=args.spec_percentile,
                     grid=args.grid, phi_deg=args.phi_deg, k_sigma=args.k_sigma, n_samples=args.samples,
                     rng=args.seed, budget=budget)
        front = None
        if args.front:
            output = "position" if args.spec_position_um is not None else "phi"
            side = {"spec_phi_arcsec": args.spec_phi_arcsec} if output == "position" else {}
            front = allocation_front(r.geometry, r.menu, region, output=output, grid=args.grid,
                                     phi_deg=args.phi_deg, k_sigma=args.k_sigma, progress=args.progress,
                                     budget=budget, **side)
        if args.json:
            doc = r.to_dict()
            if front is not None:
                doc["front"] = front_records(front)
            doc.update(provenance(args, r.geometry, budget, classes=spec_record(args.classes, r.menu),
                                  region=args.region if args.region in REGION_PRESETS else spec_record(args.region, region),
                                  grid=args.grid, phi_deg=args.phi_deg, n_poses=int(r.poses.shape[0]),
                                  k_sigma=args.k_sigma, seed=r.seed,
                                  n_samples=args.samples if args.spec_percentile is not None else None))
            emit_json(doc)
            return
        print(_text(r, args, front))


def _text(r, args, front) -> str:
    status = "meets the spec" if r.feasible else "NO choice meets the spec; the closest one"
    spec = [f"{args.spec_position_um:g} µm" + (f" at p{args.spec_percentile:.10g}" if args.spec_percentile else "")
            if args.spec_position_um else None,
            f"{args.spec_phi_arcsec:g} arcsec" if args.spec_phi_arcsec else None]
    lines = [f"prp3mc {__version__}  geometry {args.geometry}  region {args.region} "
             f"({args.grid}x{args.grid}, phi={args.phi_deg:g} deg)  classes {r.menu.name}",
             f"spec: {', '.join(s for s in spec if s)}",
             f"least cost {r.cost:g}: {status}  (proven optimal: {r.nodes} of {r.n_choices} "
             f"choices evaluated, {r.wall_time_s:.2f} s)", ""]
    frame = r.choice_frame()
    for row in frame.itertuples():
        lines.append(f"  {row.input:9s} {row._2:16s} cost {row.cost:8g}   {row.source}")
    if r.fixed is not None:
        lines += ["", f"held fixed (budget {r.fixed.name}): " + ", ".join(
            f"{k} = {quantity_text(e.value, e.unit, 'g')}" for k, e in r.fixed.effects.items())]
    lines += ["", f"worst case over the region: position {MM2UM * r.worst_case_position_mm:.3f} µm, "
                  f"|dphi| {DEG2ARCSEC * r.worst_case_phi_deg:.3f} arcsec",
              f"binding: {r.binding} at " + "; ".join(
                  f"({x:g}, {y:g}, {p:g})" for x, y, p in r.binding_poses[:5])
              + (f" and {len(r.binding_poses) - 5} more" if len(r.binding_poses) > 5 else "")]
    if r.statistical is not None:
        st = r.statistical
        lines.append(f"p{st['percentile']:g} of the position error: screen {MM2UM * st['screen_mm']:.3f} µm; "
                     f"Monte Carlo {MM2UM * st['percentile_mm']:.3f} µm, 95 % upper bound "
                     f"{MM2UM * st['ci_high_mm']:.3f} µm ({st['n_samples']} samples, seed {st['seed']}): "
                     + ("confirmed" if st["confirmed"] else "NOT confirmed")
                     + f"; decided by {st['method']}" + (" (proven least cost)" if st["proven"] else ""))
    if front is not None:
        lines += ["", "Pareto front (cost, worst-case position µm, |dphi| arcsec):"]
        wide = front.pivot_table(index=["point", "cost"], columns="output", values="value").reset_index()
        for row in wide.itertuples():
            lines.append(f"  {row.cost:10g} {MM2UM * row.position:12.3f} {DEG2ARCSEC * row.phi:12.3f}")
    return "\n".join(lines)
