"""``prp3mc worstcase``: exact maximum of the linear model over the budget's box, at a pose or over a grid."""


from .._version import __version__
from ..limits import worstcase_estimate
from ..kinematics.geometry import Geometry
from . import (provenance, add_budget, add_geometry, add_json, add_pose_or_region, command, emit_json, emit_table,
               grid_poses, positive_float)


@command("worstcase", "exact worst-case pose error of the linear model at one pose or over a region")
class WorstCaseCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        add_pose_or_region(p)
        p.add_argument("--k-sigma", type=positive_float, default=None, metavar="K",
                       help="bound unbounded (normal) laws as mean ± K·sd")
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..worstcase.envelope import CORRELATION_NOTE, worst_case
        from ..model.validity import check_linearity
        from ..kinematics.chain import check_poses
        from ..model.budget import Budget
        from ..model.effects import EffectKind
        import pandas as pd
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        poses, where = grid_poses(args, lambda n: worstcase_estimate(n, len(budget)))
        if args.region is None:   # a refused pose before any warning about the analysis
            check_poses(geometry, poses)
        check_linearity(geometry, budget, poses)
        if args.region is not None:
            wc = worst_case(geometry, budget, poses, k_sigma=args.k_sigma)
            frame = pd.DataFrame({"x_mm": poses[:, 0], "y_mm": poses[:, 1], "phi_deg": poses[:, 2],
                                  "position_mm": wc.position_mm, "dx_abs_mm": wc.x_mm, "dy_abs_mm": wc.y_mm,
                                  "dphi_abs_deg": wc.phi_deg})
            emit_table(args, frame, provenance(args, geometry, budget, k_sigma=args.k_sigma, **where))
            return
        wc = worst_case(geometry, budget, args.pose, k_sigma=args.k_sigma)
        frame = wc.contributions_frame("position")
        if args.json:
            emit_json({
                "position_mm": float(wc.position_mm), "phi_deg": float(wc.phi_deg),
                "x_mm": float(wc.x_mm), "y_mm": float(wc.y_mm),
                "maximizer": {q: wc.maximizer(q) for q in ("position", "phi", "x", "y")},
                "position_contributions_mm": dict(zip(frame["term"], frame["contribution"].astype(float))),
                "k_sigma": args.k_sigma, "prp3mc_version": __version__,
                **({"correlation": CORRELATION_NOTE} if budget.correlated else {}),
                **provenance(args, geometry, budget, k_sigma=args.k_sigma),
            })
            return
        x, y, phi = args.pose
        lines = [f"prp3mc {__version__}  geometry {geometry.name}  budget {budget.name}  "
                 f"pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
                 "Exact maximum of the linear model over the budget's box:",
                 f"  position error  {1e3 * float(wc.position_mm):10.3f} µm",
                 f"  |dx|            {1e3 * float(wc.x_mm):10.3f} µm",
                 f"  |dy|            {1e3 * float(wc.y_mm):10.3f} µm",
                 f"  |dphi|          {3600 * float(wc.phi_deg):10.3f} arcsec ({float(wc.phi_deg):.6g} deg)",
                 "", "Inputs at the position maximum, and each term's contribution:"]
        at = wc.maximizer("position")
        laws = dict(zip(wc.model.terms, wc.model.term_laws))
        units = dict(zip(wc.model.terms, wc.model.term_units))
        for _, row in frame.sort_values("contribution", ascending=False).iterrows():
            term, tl = row["term"], laws[row["term"]]
            if tl.kind == "clearance":
                value = f"rho={at[term]:.4g} mm at zeta={at['zeta_' + term[-1]]:.1f} deg"
            elif tl.kind == "shift":
                value = f"{row['term_value']:.4g} {units[term]} (known shift)"
            elif term == EffectKind.THERMAL:                      # the factor is the temperature
                value = f"T={at[term]:.4g} deg C"
            else:
                value = f"{at[term]:.4g} {units[term]}"
            lines.append(f"  {term:15s} {value:34s} {1e3 * row['contribution']:9.3f} µm  "
                         f"({100 * row['share']:5.1f} %)")
        if args.k_sigma is not None:
            lines.append(f"Unbounded laws bounded at mean ± {args.k_sigma:g} sd.")
        if budget.correlated:
            lines.append(CORRELATION_NOTE)
        if budget.effects:
            lines.append("Effects: backlash_i over ±h_i/2 and thermal over temp_range_C (their drivers are "
                         "unknown at a pose); offsets (offset_q_i), lead scales (scale_i) and cyclic screw "
                         "errors (cyclic_i) are known shifts.")
        print("\n".join(lines))
