"""``prp3mc study``: run a study file and write its report, figures, tables and summary.json (optionally over a design sweep, on Dask)."""

import sys
import time

from ..errors import Prp3mcError
from ..limits import study_estimate
from ..output import figure_formats, table_formats
from ..units import MM2UM
from ..study.distributed import parse_scheduler
from ..study.bundled import bundled_studies
from . import WARNINGS, add_output, add_progress, add_seed, command, within_limits

#: Configurations named in the closing line; a sweep's best ones beyond that are in the report.
_NAMED = 4


@command("study", "run a study (TOML file or bundled name) and write its report to a folder")
class StudyCommand:
    @staticmethod
    def add_arguments(p):
        p.add_argument("study", metavar="FILE.toml",
                       help=f"study file, or a bundled study: {', '.join(bundled_studies())}")
        add_output(p)
        add_seed(p, help="override the study's seed")
        p.add_argument("--quick", action="store_true",
                       help="reduced grids and sample sizes (a smoke test, as the golden regression files)")
        p.add_argument("--scheduler", default=None, metavar="SPEC",
                       help="run the configurations on Dask: local:N (N local worker processes) or "
                            "tcp://HOST:PORT (an existing scheduler); needs pip install 'prp3mc[dask]'. "
                            "Default: in this process. The numbers do not depend on it")
        p.add_argument("--formats", default="png", metavar="LIST",
                       help="files to write, comma-separated: figures as png and/or svg (default png; the report "
                            "embeds the PNG either way), tables as CSV and with xlsx also one workbook "
                            "(needs pip install 'prp3mc[xlsx]')")
        add_progress(p)

    @staticmethod
    def run(args) -> None:
        from ..study.reader import Study
        from ..study.runner import run_study
        from ..reports.study_report import write_study
        t0 = time.perf_counter()
        if args.scheduler is not None:
            parse_scheduler(args.scheduler)  # a bad spec fails before the study runs
        study = Study.load(args.study)
        if args.quick:
            study = study.reduced()
        formats = figure_formats(args.formats) + table_formats(args.formats)[1:]   # refused before the run
        within_limits(args, study_estimate(study))     # its allocation too, with what the study holds by then
        result = run_study(study, rng=args.seed, progress=args.progress, scheduler=args.scheduler)
        if not result.configurations:
            first = result.skipped[0]
            raise Prp3mcError(f"study {study.name}: none of its {len(result.skipped)} configurations ran; "
                              f"{first.name}: {first.reason}")
        report = write_study(result, args.out, force=args.force, formats=formats, warnings=WARNINGS,
                             progress=args.progress)
        worst = result.to_frame().query("output == 'position' and statistic == 'worst_case'")
        span = worst.pivot(index="configuration", columns="aggregate", values="value") * MM2UM
        names = (list(span.sort_values("max").index[:_NAMED]) if study.sweep
                 else [c.name for c in result.configurations])
        ranges = ", ".join(f"{n} {span.at[n, 'min']:.1f}-{span.at[n, 'max']:.1f} µm" for n in names)
        if study.sweep:
            ranges = (f"{len(result.configurations)} of {len(result.configurations) + len(result.skipped)} "
                      f"configurations ran, best: {ranges}")
        print(f"prp3mc study {study.name}: wrote {report} in {time.perf_counter() - t0:.1f} s "
              f"(analyses {result.wall_time_s:.1f} s, seed {result.seed}); worst-case position error: {ranges}",
              file=sys.stdout)
