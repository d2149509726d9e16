"""``prp3mc yield``: the exact yield of the linear model against a position (and orientation) spec (SPEC §9)."""

import numpy as np

from .._version import __version__
from ..kinematics.geometry import Geometry, Region
from ..stackup import DEFAULT_TARGET, exact_yield
from ..stackup.result import PPM
from ..model.budget import Budget
from ..model.validity import check_linearity
from ..units import DEG2ARCSEC, MM2UM
from . import (add_budget, add_geometry, add_json, command, emit_json, finite_float, positive_float, positive_int,
               probability, provenance)


@command("yield", "exact yield of the linear model against a position (and orientation) spec, without sampling")
class YieldCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        where = p.add_mutually_exclusive_group(required=True)
        where.add_argument("--pose", nargs=3, type=finite_float, metavar=("X", "Y", "PHI"),
                           help="pose: x mm, y mm, phi deg")
        where.add_argument("--region", metavar="R", help="every pose of a grid over the test region R (a preset: "
                                                          "u-shape, delta-shape)")
        p.add_argument("--grid", type=positive_int, default=41, metavar="N",
                       help="with --region: an N x N grid (default 41)")
        p.add_argument("--spec-position-um", type=positive_float, required=True, metavar="S",
                       help="the position error |(dx, dy)| must stay within S µm")
        p.add_argument("--spec-phi-arcsec", type=positive_float, default=None, metavar="Z",
                       help="|dphi| must stay within Z arcsec")
        p.add_argument("--target", type=probability, default=DEFAULT_TARGET, metavar="E",
                       help=f"bound of every probability's absolute error (default {DEFAULT_TARGET:g})")
        add_json(p)

    @staticmethod
    def run(args) -> None:
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        specs = {"spec_position_um": args.spec_position_um, "spec_phi_arcsec": args.spec_phi_arcsec}
        region = None
        if args.region is not None:
            if args.grid < 2:
                from ..errors import GeometryError
                raise GeometryError(f"--grid must be at least 2 (an N x N grid of the region), got {args.grid}")
            grid = Region.from_preset(args.region).grid(args.grid)
            check_linearity(geometry, budget, grid)
            over = exact_yield(geometry, budget, grid, quantiles=False, target=args.target, **specs)
            region = over.region_summary()
            region["max_error_bound_ppm"] = PPM * float(over.error_bound.max())
            region["n_poses"] = int(over.exceed_position.size)
            pose = region["argmax_pose"]
        else:
            pose = list(args.pose)
            check_linearity(geometry, budget, pose)
        r = exact_yield(geometry, budget, pose, target=args.target, **specs)
        record = r.pose_record()
        if args.json:
            doc = {**record, "target": args.target}
            if region is not None:
                doc["region"] = region
                doc["at_pose"] = dict(zip(("x_mm", "y_mm", "phi_deg"), pose))
            extra = {"region": args.region, "grid": args.grid} if region is not None else {}
            emit_json({**doc, **provenance(args, geometry, budget, **specs, target=args.target, **extra)})
            return
        print("\n".join(_text(args, geometry, budget, pose, r, record, region)))


def _text(args, geometry, budget, pose, r, record, region) -> list[str]:
    """The readable report: the exceedances in % and ppm with their Ppk, then worst case, RSS and quantiles."""
    x, y, phi = pose
    lines = [f"prp3mc {__version__}  geometry {geometry.name}  budget {budget.name}"]
    if region is not None:
        lines += [f"Region {args.region}, {args.grid} x {args.grid} poses: P(position > {args.spec_position_um:g} µm) "
                  f"at most {region['max_exceed_position_ppm']:.4g} ppm, mean {region['mean_exceed_position_ppm']:.4g} ppm; "
                  f"{100 * region['area_fraction_above_1ppm']:.1f} % of the poses above 1 ppm.",
                  "The worst pose:"]
    lines += [f"pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
              f"Exact distribution of the linear model (no sampling): every probability within "
              f"{record['error_bound_ppm']:.2g} ppm.", "",
              f"{'':26s}{'P(exceed)':>12s}{'ppm':>14s}{'Ppk':>8s}"]
    rows = [(f"position > {args.spec_position_um:g} µm", r.exceed_position, "position")]
    if r.exceed_phi is not None:
        rows += [(f"|dphi| > {args.spec_phi_arcsec:g} arcsec", r.exceed_phi, "phi"), ("either", r.exceed_any, "any")]
    for label, value, output in rows:
        p = float(value)
        k = float(r.ppk(output))
        lines.append(f"  {label:24s}{100 * p:11.4g} %{PPM * p:14.4f}{k:8.2f}" if np.isfinite(k) else
                     f"  {label:24s}{100 * p:11.4g} %{PPM * p:14.4f}{'> 6':>8s}")
    lines += ["", f"{'':18s}{'worst case':>12s}{'RSS':>10s}" + "".join(f"{'p' + format(v, 'g'):>11s}" for v in r.levels)]
    for label, worst, rss, q, scale in (("position (µm)", r.worst_position_mm, r.rss_position_mm,
                                         r.quantile_position_mm, MM2UM),
                                        ("|dphi| (arcsec)", r.worst_phi_deg, r.rss_phi_deg, r.quantile_phi_deg,
                                         DEG2ARCSEC)):
        w = float(worst)
        lines.append(f"  {label:16s}{scale * w:12.3f}" if np.isfinite(w) else f"  {label:16s}{'unbounded':>12s}")
        lines[-1] += f"{scale * float(rss):10.3f}" + "".join(f"{scale * float(v):11.3f}" for v in np.ravel(q))
    qerr_pos = max(record["quantile_error_bounds_position_um"].values())
    qerr_phi = max(record["quantile_error_bounds_phi_arcsec"].values())
    lines += [f"Quantiles exact within {qerr_pos:.2g} µm and {qerr_phi:.2g} arcsec. RSS: |centre| + root sum of "
              "squares of the terms' half-widths (normal laws at 3 sd); worst case: the linear model's exact maximum."]
    if r.exceed_phi is not None and bool(np.asarray(r.bracketed_any)):
        lines.append("'either' lies between max and sum of the two (the joint series needs too many terms here): "
                     "its bound holds that bracket.")
    if budget.effects:
        lines.append("Effects: backlash_i ±h_i/2 with probability 1/2 each, one temperature uniform over "
                     "temp_range_C; offsets and lead scales are known shifts.")
    return lines
