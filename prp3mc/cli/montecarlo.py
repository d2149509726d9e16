"""``prp3mc montecarlo``: Monte Carlo statistics of the pose error at one pose or over a grid."""

from __future__ import annotations


from .._version import __version__
from ..limits import montecarlo_estimate
from ..units import probability_text
from . import (EFFECTS_NOTE, provenance, add_budget, add_geometry, add_json, add_pose_or_region, add_progress,
               add_sampling, command, emit_json, emit_table, grid_poses, nonnegative_float, within_limits)


def _pkey(p: float) -> str:
    return f"p{p:g}"


@command("montecarlo", "Monte Carlo statistics of the pose error at one pose or over a region")
class MonteCarloCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        add_pose_or_region(p)
        add_sampling(p, default_samples=100_000)
        p.add_argument("--tolerance-mm", type=nonnegative_float, default=None, metavar="T",
                       help="also report P(position error > T)")
        p.add_argument("--exact-check", action="store_true",
                       help="compare 2000 samples with the exact nonlinear model")
        add_progress(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..model.validity import check_linearity
        from ..kinematics.chain import check_poses
        from ..montecarlo.propagation import monte_carlo
        from ..kinematics.geometry import Geometry
        from ..model.budget import Budget
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        poses, where = grid_poses(args)
        if args.region is None:   # a refused pose before any warning about the analysis
            check_poses(geometry, poses)
        within_limits(args, montecarlo_estimate(args.samples, poses.shape[0], len(budget.factors) + 1))
        check_linearity(geometry, budget, poses)
        if args.region is not None:
            r = monte_carlo(geometry, budget, poses, args.samples, rng=args.seed, tolerance_mm=args.tolerance_mm,
                            progress=args.progress)
            emit_table(args, _table(r, poses), provenance(args, geometry, budget, seed=r.seed,
                                                          n_samples=r.n_samples, **where))
            return
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
            lines.append(f"\nP(position error > {args.tolerance_mm:g} mm) = "
                         f"{probability_text(float(r.exceed_prob), r.exceed_ci)} (95% CI)")
        if budget.effects:
            lines.append("\n" + EFFECTS_NOTE)
        if r.linearization is not None:
            row = r.linearization.iloc[0]
            lines.append(f"\nExact vs linear model ({int(row['n_samples'])} samples): max "
                         f"{row['position_max_um']:.4f} µm, RMS {row['position_rms_um']:.4f} µm")
        print("\n".join(lines))


def _table(r, poses) -> pd.DataFrame:
    """One row per pose: mean and sd of dx, dy, dphi, the percentiles and maximum of the position error and
    |dphi| with their 95 % intervals, and P(position error > T) with its interval when asked (mm, deg)."""
    import pandas as pd
    cols = {"x_mm": poses[:, 0], "y_mm": poses[:, 1], "phi_deg": poses[:, 2]}
    for k, name in enumerate(("dx_mm", "dy_mm", "dphi_deg")):
        cols[f"mean_{name}"], cols[f"sd_{name}"] = r.mean[:, k], r.std[:, k]
    for what, pct, ci, unit in (("position", r.position_pct, r.position_pct_ci, "mm"),
                                ("phi_abs", r.phi_pct, r.phi_pct_ci, "deg")):
        for q, p in enumerate(r.percentiles):
            cols[f"{what}_{_pkey(p)}_{unit}"] = pct[:, q]
            cols[f"{what}_{_pkey(p)}_ci95_lo_{unit}"], cols[f"{what}_{_pkey(p)}_ci95_hi_{unit}"] = ci[:, q, 0], ci[:, q, 1]
    cols["position_max_mm"], cols["phi_abs_max_deg"] = r.position_max, r.phi_max
    if r.exceed_prob is not None:
        cols["exceed_probability"] = r.exceed_prob
        cols["exceed_ci95_lo"], cols["exceed_ci95_hi"] = r.exceed_ci[..., 0], r.exceed_ci[..., 1]
    return pd.DataFrame(cols)
