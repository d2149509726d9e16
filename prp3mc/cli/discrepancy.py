"""``prp3mc discrepancy``: name what the model misses in a measurement campaign."""

from ..kinematics.geometry import Geometry
from ..limits import discrepancy_estimate
from ..progress import Progress
from ..units import MM2UM, quantity_text
from . import (WARNINGS, add_budget, add_geometry, add_instrument_noise, add_json, add_output, add_progress, add_seed,
               command, emit_json, probability, provenance, within_limits)


@command("discrepancy", "find where model and measurements disagree and name the missing effect")
class DiscrepancyCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        p.add_argument("--data", required=True, metavar="CSV",
                       help="measurement campaign CSV (docs, File formats), or the bundled one: example")
        add_output(p, help="report folder (discrepancy.json, report.html)")
        add_instrument_noise(p)
        p.add_argument("--alpha", type=probability, default=0.01, metavar="A",
                       help="family-wise level of the naming tests (default 0.01)")
        p.add_argument("--alpha-unexplained", type=probability, default=0.05, metavar="A",
                       help="family-wise level of the final test for unexplained disagreement (default 0.05)")
        p.add_argument("--no-registration", action="store_true",
                       help="the instrument is known to be registered to the machine: do not fit its registration")
        p.add_argument("--outlier-rate", type=probability, default=0.01, metavar="A",
                       help="family-wise false-alarm rate of the gross-error test over all rows (default 0.01)")
        add_seed(p, help="seed of the bootstrap (default: fresh, recorded in the output)")
        add_progress(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..model.budget import Budget
        from ..reports.discrepancy_report import report_document, write_report
        from ..measurement.discrepancy.workflow import STAGES, discrepancy
        from ..measurement.campaign.data import check_instrument_noise, count_rows, read_campaign
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        d = len(budget)
        within_limits(args, discrepancy_estimate(count_rows(args.data), n_inputs=d))  # before reading the file
        campaign = read_campaign(args.data, geometry)
        check_instrument_noise(campaign, args.instrument_sigma_mm, args.instrument_sigma_deg)
        within_limits(args, discrepancy_estimate(campaign.n_measurements, campaign.n_poses,
                                                 int(campaign.repeats.max()), n_inputs=d))
        with Progress(len(STAGES) + 1, "discrepancy", args.progress) as bar:
            result = discrepancy(geometry, budget, campaign, instrument_sigma_mm=args.instrument_sigma_mm,
                                 instrument_sigma_deg=args.instrument_sigma_deg,
                                 registration=not args.no_registration, alpha=args.alpha,
                                 alpha_unexplained=args.alpha_unexplained, outlier_rate=args.outlier_rate,
                                 progress=bar, rng=args.seed)
            record = provenance(args, geometry, budget)["inputs"]
            folder = write_report(result, args.out, force=args.force, inputs=record, warnings=WARNINGS)
            bar.update(label="discrepancy: report")
        if args.json:
            emit_json(report_document(result, record, WARNINGS))
            return
        print("\n".join(headline(result) + [f"report: {folder / 'report.html'}",
                                             f"updated model: {folder / 'model'} (geometry.toml, budget.toml, "
                                             "budget_compensated.toml)"]))


def headline(result) -> list[str]:
    """The lines printed after an analysis: what was named, the nuisances, the gap and the one verdict."""
    from ..measurement.discrepancy.accuracy import MODELS
    g = result.gap
    lines = [f"{result.campaign.n_measurements} measurements of {result.campaign.n_poses} poses; "
             f"seed {result.seed}; {result.wall_time_s:.1f} s"]
    if result.outliers:
        rows = ", ".join(str(o["row"]) for o in result.outliers[:8]) + (" ..." if len(result.outliers) > 8 else "")
        lines.append(f"{len(result.outliers)} gross error(s) set aside (data rows {rows}; false-alarm rate "
                     f"{result.outlier_rule['family_wise_rate']:g} over all rows)")
    for n in result.nuisance:
        alias = " (union over the aliases of the named effects)" if "by_alias" in n else ""
        lines.append(f"nuisance {n['name']} = {n['value']:.4g} {n['unit']}  95% CI [{n['ci95'][0]:.4g}, "
                     f"{n['ci95'][1]:.4g}]{alias}")
    rep = result.repeatability
    if rep["repeatable_fraction"] is None:
        lines.append(f"repeatable fraction not testable: {rep['not_testable']}")
    else:
        lines.append(f"repeatable fraction {rep['repeatable_fraction']:.2f}  95% CI [{rep['ci95'][0]:.2f}, "
                     f"{rep['ci95'][1]:.2f}]")
    for e in result.named_effects:
        alias = f" (not separable from {', '.join(e.aliases)})" if e.aliases else ""
        phase = f", phase {e.phase_deg:.1f} deg" if e.phase_deg is not None else ""
        lines.append(f"named {e.name} = {quantity_text(e.value, e.unit)}  95% CI [{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]"
                     f"{phase}{alias}")
    if not result.named_effects:
        lines.append("named nothing: the model misses nothing this campaign can see")
    if result.confounded_with_registration:
        lines.append("not testable, confounded with registration: " + ", ".join(result.confounded_with_registration))
    for c in result.confounded:
        lines.append(f"confounded: {', '.join(c['effects'])} with {', '.join(c['with'])} ({c['source']}): {c['why']}")
    lin = result.linearity
    if len(lin["passes"]) > 1:
        lines.append(f"relinearised on the exact chain: {len(lin['passes'])} passes, "
                     f"{'converged' if lin['converged'] else 'NOT converged'}")
    verdict = ("closed" if g["closed"] else
               f"not closed: UNEXPLAINED disagreement remains ({g['deciding_channel'].replace('_', ' ')})")
    if g.get("not_tested"):
        verdict += "; the dispersion channels were not tested (one visit per pose: nothing to compare repeats with)"
    lines.append(f"gap {g['before']:.3g} -> {g['after']:.3g} (null level <= 1, closed at <= {g['closed_at']:.2g}): "
                 f"{verdict}")
    lines.append(f"verdict: {result.verdict['text']}")
    h = g["held_out"]
    lines.append(f"held-out gap (cross-validation by pose, {h['folds']} folds; trust this one) "
                 f"{h['before']:.3g} -> {h['after']:.3g}")
    acc = result.accuracy
    lines.append("predicted worst case / p99 of the position error over the region: " + ", ".join(
        f"{key} {MM2UM * acc[key]['worst_case_position_mm']:.1f} / {MM2UM * acc[key]['p99_position_mm']:.1f} µm"
        for key in MODELS))
    return lines
