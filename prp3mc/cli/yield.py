"""``prp3mc yield``: the exact yield of the linear model against a position (and orientation) spec (SPEC §9)."""

import argparse
import sys
import warnings

import numpy as np

from .._version import __version__
from ..errors import NoExactYieldError, Prp3mcWarning, SpecError
from ..kinematics.geometry import Geometry
from ..limits import DEFAULT_TARGET, TARGET_RANGE, montecarlo_estimate, yield_estimate
from ..units import DEG2ARCSEC, MM2UM, PPM, spec_value
from . import (add_budget, add_geometry, add_json, add_pose_or_region, add_seed, command, emit_json, emit_table,
               finite_float, grid_poses, positive_float, positive_int, provenance, within_limits)

#: A spec this many times below the error's RSS scale is refused (a value in mm typed as µm, or the like).
_SCALE = 1e-3
_MC_METHOD = ("Monte Carlo of the linear model with the budget's Gaussian copula, if any (the streamed sampler): "
              "every exceedance with its Wilson 95 % interval (ci95_ppm); error_bound = the largest distance from "
              "an exceedance to the farther end of its interval (a confidence statement, not a bound); quantiles "
              "are sample percentiles")


@command("yield", "exact yield of the linear model against a position (and orientation) spec, without sampling")
class YieldCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        add_pose_or_region(p)
        p.add_argument("--spec-position-um", type=positive_float, required=True, metavar="S",
                       help="the position error |(dx, dy)| must stay within S µm")
        p.add_argument("--spec-phi-arcsec", type=positive_float, default=None, metavar="Z",
                       help="|dphi| must stay within Z arcsec")
        p.add_argument("--target", type=_target, default=DEFAULT_TARGET, metavar="E",
                       help=f"bound of every probability's absolute error, in [{TARGET_RANGE[0]:g}, "
                            f"{TARGET_RANGE[1]:g}] (default {DEFAULT_TARGET:g})")
        p.add_argument("--samples", type=positive_int, default=10_000_000, metavar="N",
                       help="samples of the Monte Carlo fallback for a budget that correlates inputs not all normal "
                            "(default 1e7)")
        add_seed(p, help="seed of the Monte Carlo fallback (default: fresh, recorded in the output)")
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..kinematics.chain import check_poses
        from ..model.budget import Budget
        from ..model.validity import check_linearity
        from ..stackup import exact_yield
        from ..stackup.gaussian import exact_refusal

        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        why = exact_refusal(budget)

        def estimate(n):
            """Memory at ``n`` poses: the exact yield (conditioning on two legs with a phi spec) or the fallback."""
            if why is None:
                return yield_estimate(n, conditioned=args.spec_phi_arcsec is not None)
            return _fallback_estimate(args, budget, n)

        poses, where = grid_poses(args, estimate)
        if args.region is None:
            check_poses(geometry, poses)
            within_limits(args, estimate(1))
        check_linearity(geometry, budget, poses)
        specs = {"spec_position_um": args.spec_position_um, "spec_phi_arcsec": args.spec_phi_arcsec}
        if why is not None:
            _correlated(args, geometry, budget, poses, where, why)
            return
        with warnings.catch_warnings(record=True) as caught:    # a spec in the wrong unit: one line, not two
            warnings.simplefilter("always")
            try:
                over = exact_yield(geometry, budget, poses, quantiles=args.region is None, target=args.target,
                                   **specs)
            except NoExactYieldError as exc:                     # no density, too many classes or terms
                over = str(exc).removeprefix("exact yield: ")
        if isinstance(over, str):       # outside the block: the fallback's own warnings are said
            _correlated(args, geometry, budget, poses, where, over)
            return
        _check_scale(args, over)
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        inputs = dict(**specs, target=args.target, **where)
        if args.region is not None:
            region = over.region_summary()
            k = int(np.argmax(over.exceed_position))
            with warnings.catch_warnings():     # pose k is one of the grid's: its warnings were said, counted there
                warnings.simplefilter("ignore", Prp3mcWarning)
                at = exact_yield(geometry, budget, poses[k], target=args.target, **specs)
            doc = {**at.pose_record(), "region": region, "max_error_bound_ppm": PPM * float(over.error_bound.max()),
                   **provenance(args, geometry, budget, **inputs)}
            if not args.json:      # the summary on stderr, the table (one row per pose) on stdout or --out
                print("\n".join(_text(args, geometry, budget, poses[k], at, at.pose_record(), region)),
                      file=sys.stderr)
            emit_table(args, _pose_frame(over), doc)
            return
        record = over.pose_record(0)
        if args.json:
            emit_json({**record, **provenance(args, geometry, budget, **inputs)})
            return
        print("\n".join(_text(args, geometry, budget, poses[0], over, record, None)))


def _target(text: str) -> float:
    """``--target``: a probability in :data:`TARGET_RANGE` (below it floating point alone exceeds the target)."""
    value = finite_float(text)
    lo, hi = TARGET_RANGE
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"expected a target in [{lo:g}, {hi:g}] (below {lo:g} floating point "
                                         f"alone exceeds it), got {text!r}")
    return value


def _check_scale(args, r) -> None:
    """Refuse a spec far below the error's scale (its RSS): a value in the wrong unit, said in one line."""
    for name, spec, rss, unit in (("--spec-position-um", args.spec_position_um, MM2UM * r.rss_position_mm, "µm"),
                                  ("--spec-phi-arcsec", args.spec_phi_arcsec, DEG2ARCSEC * r.rss_phi_deg, "arcsec")):
        if spec is None:
            continue
        scale = float(np.min(rss))
        if spec < _SCALE * scale:
            raise SpecError(f"{name} {spec:g} {unit} is below {_SCALE:g} x the error's RSS ({scale:.3g} {unit}): every "
                            f"pose is out of spec; a value in another unit (mm, deg)?")


def _pose_frame(r) -> "pd.DataFrame":
    """One row per pose: the exceedances (ppm) and their bound, the position's Ppk, worst case and RSS."""
    import pandas as pd

    from .._result import pose_columns

    frame = pd.DataFrame(pose_columns(r.poses))
    for output in ("position",) if r.exceed_phi is None else r.outputs:    # any = position alone
        frame[f"exceed_{output}_ppm"] = PPM * r.exceedance(output).reshape(-1)
    frame["error_bound_ppm"] = PPM * r.error_bound.reshape(-1)
    ppk_pos = r.ppk("position").reshape(-1)
    frame["ppk_position"] = pd.Series(ppk_pos, dtype=object).where(np.isfinite(ppk_pos), None)   # P = 0: none
    frame["worst_case_position_um"] = MM2UM * r.worst_position_mm.reshape(-1)
    frame["rss_position_um"] = MM2UM * r.rss_position_mm.reshape(-1)
    return frame


def _fallback_estimate(args, budget, n_poses: int):
    """Memory of the Monte Carlo fallback (:func:`_correlated`) at ``n_poses`` poses."""
    return montecarlo_estimate(args.samples, n_poses, len(budget.factors) + 1)


def _correlated(args, geometry, budget, poses, where, why: str) -> None:
    """A budget the exact yield cannot serve (correlated inputs not all normal; no density, too many classes
    or terms: ``why``): the streamed Monte Carlo with the copula, every
    exceedance with its Wilson 95 % interval; as the error, the distance to the interval's farther end (said
    in ``method``). Its memory is checked first: a budget that fails the exact series only when tried was
    sized for the exact yield."""
    import pandas as pd

    from .._result import pose_columns
    from ..montecarlo.propagation import monte_carlo
    from ..stackup.result import OUTPUTS, QUANTILE_LEVELS, ppk, region_summary

    within_limits(args, _fallback_estimate(args, budget, poses.shape[0]))
    for name, value in (("spec_position_um", args.spec_position_um), ("spec_phi_arcsec", args.spec_phi_arcsec)):
        if value is not None:   # below 1: a warning, as exact_yield gives on its own path
            spec_value(name, value)

    S = args.spec_position_um / MM2UM
    Z = None if args.spec_phi_arcsec is None else args.spec_phi_arcsec / DEG2ARCSEC
    mc = monte_carlo(geometry, budget, poses, args.samples, rng=args.seed, tolerance_mm=S, tolerance_phi_deg=Z,
                     percentiles=QUANTILE_LEVELS)
    names = [f"p{level:g}" for level in QUANTILE_LEVELS]
    position, phi = mc.position_pct.reshape(-1, len(names)), mc.phi_pct.reshape(-1, len(names))
    figures = {"position": (mc.exceed_prob, mc.exceed_ci), "phi": (mc.exceed_phi_prob, mc.exceed_phi_ci),
               "any": (mc.exceed_prob, mc.exceed_ci) if Z is None else (mc.exceed_any_prob, mc.exceed_any_ci)}
    figures = {o: (p.reshape(-1), ci.reshape(-1, 2)) for o, (p, ci) in figures.items() if p is not None}
    farther = {o: np.abs(ci - p[:, None]).max(axis=1) for o, (p, ci) in figures.items()}   # from P, (N,)
    half = np.max(list(farther.values()), axis=0)
    p = figures["position"][0]
    k = int(np.argmax(p))
    record = {f"exceed_{o}_ppm": PPM * float(figures[o][0][k]) if o in figures else None
              for o in OUTPUTS}
    record |= {"error_bound_ppm": PPM * float(half[k]),
               "ci95_ppm": {o: (PPM * ci[k]).tolist() for o, (_, ci) in figures.items()},
               "quantiles_position_um": dict(zip(names, (MM2UM * position[k]).tolist())),
               "quantiles_phi_arcsec": dict(zip(names, (DEG2ARCSEC * phi[k]).tolist())),
               "ppk_position": float(ppk(p[k])) if p[k] > 0 else None, "method": f"{_MC_METHOD} ({why})"}
    inputs = dict(spec_position_um=args.spec_position_um, spec_phi_arcsec=args.spec_phi_arcsec, seed=mc.seed,
                  samples=mc.n_samples, **where)
    doc = {**record, **provenance(args, geometry, budget, **inputs)}
    if args.region is not None:
        doc["region"] = region_summary(p, poses)
        frame = pd.DataFrame({**pose_columns(poses), **{f"exceed_{o}_ppm": PPM * v for o, (v, _) in figures.items()},
                              "ci95_farther_end_ppm": PPM * half})
        emit_table(args, frame, doc)
        return
    if args.json:
        emit_json(doc)
        return
    x, y, phi = poses[k]
    q = record["quantiles_position_um"]
    labels = {"position": f"position > {args.spec_position_um:g} µm", "any": "either"}
    if Z is not None:
        labels["phi"] = f"|dphi| > {args.spec_phi_arcsec:g} arcsec"
    print("\n".join([
        f"prp3mc {__version__}  geometry {geometry.name}  budget {budget.name}",
        f"pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
        f"Monte Carlo with {mc.n_samples:g} samples (seed {mc.seed}), not the exact series: {why}.",
        *(f"  {labels[o]:24s}{100 * v[k]:11.4g} %{PPM * v[k]:14.4f} ppm  95 % interval [{PPM * ci[k, 0]:.4g}, "
          f"{PPM * ci[k, 1]:.4g}] ppm" for o, (v, ci) in figures.items() if o != "any" or Z is not None),
        "  position quantiles (µm): " + "  ".join(f"{lv} {v:.3f}" for lv, v in q.items())]))


def _text(args, geometry, budget, pose, r, record, region) -> list[str]:
    """The readable report: the exceedances in % and ppm with their Ppk, then worst case, RSS and quantiles."""
    x, y, phi = pose
    lines = [f"prp3mc {__version__}  geometry {geometry.name}  budget {budget.name}"]
    if region is not None:
        lines += [f"Region {args.region}, {args.grid or 21} x {args.grid or 21} poses: P(position > "
                  f"{args.spec_position_um:g} µm) at most {region['max_exceed_position_ppm']:.4g} ppm, mean "
                  f"{region['mean_exceed_position_ppm']:.4g} ppm; {100 * region['area_fraction_above_1ppm']:.1f} % "
                  "of the poses above 1 ppm.", "The worst pose:"]
    lines += [f"pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
              f"Exact distribution of the linear model (no sampling): every probability within "
              f"{record['error_bound_ppm']:.2g} ppm.", "",
              f"{'':26s}{'P(exceed)':>12s}{'ppm':>14s}{'Ppk':>8s}"]
    rows = [(f"position > {args.spec_position_um:g} µm", "position")]
    if r.exceed_phi is not None:
        rows += [(f"|dphi| > {args.spec_phi_arcsec:g} arcsec", "phi"), ("either", "any")]
    for label, output in rows:
        p = float(np.ravel(r.exceedance(output))[0])
        k = float(np.ravel(r.ppk(output))[0])
        lines.append(f"  {label:24s}{100 * p:11.4g} %{PPM * p:14.4f}{k:8.2f}" if np.isfinite(k) else
                     f"  {label:24s}{100 * p:11.4g} %{PPM * p:14.4f}{'> 6':>8s}")
    lines += ["", f"{'':18s}{'worst case':>12s}{'RSS':>10s}"
              + "".join(f"{'p' + format(v, 'g'):>11s}" for v in r.levels)]
    for label, worst, rss, q, scale in (("position (µm)", r.worst_position_mm, r.rss_position_mm,
                                         r.quantile_position_mm, MM2UM),
                                        ("|dphi| (arcsec)", r.worst_phi_deg, r.rss_phi_deg, r.quantile_phi_deg,
                                         DEG2ARCSEC)):
        w = float(np.ravel(worst)[0])
        lines.append(f"  {label:16s}{scale * w:12.3f}" if np.isfinite(w) else f"  {label:16s}{'unbounded':>12s}")
        lines[-1] += (f"{scale * float(np.ravel(rss)[0]):10.3f}"
                      + "".join(f"{scale * float(v):11.3f}" for v in np.ravel(q)))
    qerr_pos = max(record["quantile_error_bounds_position_um"].values())
    qerr_phi = max(record["quantile_error_bounds_phi_arcsec"].values())
    lines += [f"Quantiles exact within {qerr_pos:.2g} µm and {qerr_phi:.2g} arcsec. RSS: |centre| + root sum of "
              "squares of the terms' half-widths (normal laws at 3 sd); worst case: the linear model's exact maximum.",
              "Ppk = Phi^-1(1 - P) / 3 (one-sided)."]
    if r.exceed_phi is not None and bool(np.ravel(r.bracketed_any)[0]):
        lines.append("'either' lies between the larger and the sum of the two (the joint series does not converge "
                     "in time for this budget): its bound covers that bracket.")
    if budget.correlated:
        lines.append("Correlated inputs, all normal (so jointly normal): exact, as independent normal terms with the "
                     "same joint law.")
    if budget.effects:
        lines.append("Effects: backlash_i ±h_i/2 with probability 1/2 each, one temperature uniform over "
                     "temp_range_C; offsets, lead scales and cyclic errors are known shifts.")
    return lines
