"""``prp3mc worstcase``: exact maximum of the linear model over the budget's box."""

from .._version import __version__
from ..model.budget import Budget
from ..kinematics.geometry import Geometry
from ..model.validity import check_linearity
from ..worstcase.envelope import worst_case
from . import provenance, add_budget, add_geometry, add_json, add_pose, command, emit_json, positive_float


@command("worstcase", "exact worst-case pose error of the linear model at one pose")
class WorstCaseCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        add_pose(p)
        p.add_argument("--k-sigma", type=positive_float, default=None, metavar="K",
                       help="bound unbounded (normal) laws as mean ± K·sd")
        add_json(p)

    @staticmethod
    def run(args) -> None:
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        check_linearity(geometry, budget, args.pose)
        wc = worst_case(geometry, budget, args.pose, k_sigma=args.k_sigma)
        frame = wc.contributions_frame("position")
        if args.json:
            emit_json({
                "position_mm": float(wc.position_mm), "phi_deg": float(wc.phi_deg),
                "x_mm": float(wc.x_mm), "y_mm": float(wc.y_mm),
                "maximizer": {q: wc.maximizer(q) for q in ("position", "phi", "x", "y")},
                "position_contributions_mm": dict(zip(frame["term"], frame["contribution"].astype(float))),
                "k_sigma": args.k_sigma, "prp3mc_version": __version__,
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
        for _, row in frame.sort_values("contribution", ascending=False).iterrows():
            term = row["term"]
            if term.startswith("rho_"):
                value = f"rho={at[term]:.4g} mm at zeta={at['zeta_' + term[-1]]:.1f} deg"
            elif term == "thermal":
                value = f"T={at[term]:.4g} deg C"
            else:
                value = f"{at[term]:.4g}" if term in at else f"{row['term_value']:.4g} (known shift)"
            lines.append(f"  {term:15s} {value:34s} {1e3 * row['contribution']:9.3f} µm  "
                         f"({100 * row['share']:5.1f} %)")
        if args.k_sigma is not None:
            lines.append(f"Unbounded laws bounded at mean ± {args.k_sigma:g} sd.")
        if budget.effects:
            lines.append("Effects: backlash_i over ±h_i/2 and thermal over temp_range_C (their drivers are "
                         "unknown at a pose); offsets (offset_q_i) and lead scales (scale_i) are known shifts.")
        print("\n".join(lines))
