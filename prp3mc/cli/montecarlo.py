"""``prp3mc montecarlo``: Monte Carlo statistics of the pose error at one pose."""

from .._version import __version__
from ..model.budget import Budget
from ..kinematics.geometry import Geometry
from ..limits import montecarlo_estimate
from ..montecarlo.propagation import monte_carlo
from ..model.validity import check_linearity
from . import (EFFECTS_NOTE, provenance, add_budget, add_geometry, add_json, add_pose, add_progress, add_sampling, command,
               emit_json, nonnegative_float, within_limits)


def _pkey(p: float) -> str:
    return f"p{p:g}"


@command("montecarlo", "Monte Carlo statistics of the pose error at one pose")
class MonteCarloCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        add_pose(p)
        add_sampling(p, default_samples=100_000)
        p.add_argument("--tolerance-mm", type=nonnegative_float, default=None, metavar="T",
                       help="also report P(position error > T)")
        p.add_argument("--exact-check", action="store_true",
                       help="compare 2000 samples with the exact nonlinear model")
        add_progress(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        within_limits(args, montecarlo_estimate(args.samples, 1, len(budget.factors) + 1))
        check_linearity(geometry, budget, args.pose)
        r = monte_carlo(geometry, budget, args.pose, args.samples, rng=args.seed,
                        tolerance_mm=args.tolerance_mm, exact_check_poses=1 if args.exact_check else 0,
                        progress=args.progress)
        keys = ("x_mm", "y_mm", "phi_deg")
        position = {_pkey(p): float(v) for p, v in zip(r.percentiles, r.position_pct)}
        position["max"] = float(r.position_max)
        position["mean"] = float(r.position_mean)
        phi = {_pkey(p): float(v) for p, v in zip(r.percentiles, r.phi_pct)}
        phi["max"] = float(r.phi_max)
        doc = {
            "mean": dict(zip(keys, r.mean.astype(float).tolist())),
            "std": dict(zip(keys, r.std.astype(float).tolist())),
            "position_mm": position,
            "phi_abs_deg": phi,
            "se": {"mean": dict(zip(keys, r.mean_se.tolist())), "std": dict(zip(keys, r.std_se.tolist())),
                   "position_mean": float(r.position_mean_se)},
            "ci95": {"position_mm": {_pkey(p): ci.tolist() for p, ci in zip(r.percentiles, r.position_pct_ci)},
                     "phi_abs_deg": {_pkey(p): ci.tolist() for p, ci in zip(r.percentiles, r.phi_pct_ci)}},
            "cov": r.cov.tolist(),
            "seed": r.seed, "n_samples": r.n_samples, "prp3mc_version": __version__,
            **provenance(args, geometry, budget, seed=r.seed, n_samples=r.n_samples),
        }
        if r.exceed_prob is not None:
            doc["exceed"] = {"tolerance_mm": args.tolerance_mm, "probability": float(r.exceed_prob),
                             "ci95": r.exceed_ci.tolist()}
        if r.linearization is not None:
            doc["linearization"] = r.linearization.drop(columns=["x_mm", "y_mm", "phi_deg"]).iloc[0].to_dict()
        if args.json:
            emit_json(doc)
            return
        x, y, phi_ = args.pose
        lines = [f"prp3mc {__version__}  geometry {geometry.name}  budget {budget.name}  "
                 f"pose x={x:g} mm  y={y:g} mm  phi={phi_:g} deg",
                 f"{r.n_samples} samples, seed {r.seed}", "",
                 f"{'':14s}{'mean':>12s}{'± se':>10s}{'std':>12s}{'± se':>10s}"]
        for k, name in enumerate(("dx µm", "dy µm", "dphi arcsec")):
            f = 1e3 if k < 2 else 3600.0
            lines.append(f"{name:14s}{f * r.mean[k]:12.3f}{f * r.mean_se[k]:10.3f}"
                         f"{f * r.std[k]:12.3f}{f * r.std_se[k]:10.3f}")
        lines += ["", f"{'percentile':14s}{'position µm':>14s}{'95% CI':>22s}{'|dphi| arcsec':>16s}"]
        for q, p in enumerate(r.percentiles):
            lo, hi = 1e3 * r.position_pct_ci[q]
            lines.append(f"{_pkey(p):14s}{1e3 * r.position_pct[q]:14.3f}   [{lo:8.3f}, {hi:8.3f}]"
                         f"{3600 * r.phi_pct[q]:16.3f}")
        lines.append(f"{'max':14s}{1e3 * r.position_max:14.3f}{'':25s}{3600 * r.phi_max:13.3f}")
        if r.exceed_prob is not None:
            lo, hi = r.exceed_ci
            lines.append(f"\nP(position error > {args.tolerance_mm:g} mm) = {float(r.exceed_prob):.4g} "
                         f"[{lo:.4g}, {hi:.4g}]")
        if budget.effects:
            lines.append("\n" + EFFECTS_NOTE)
        if r.linearization is not None:
            row = r.linearization.iloc[0]
            lines.append(f"\nExact vs linear model ({int(row['n_samples'])} samples): max "
                         f"{row['position_max_um']:.4f} µm, RMS {row['position_rms_um']:.4f} µm")
        print("\n".join(lines))
