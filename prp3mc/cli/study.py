"""``prp3mc study``: run a study file and write its report, figures, tables and summary.json."""

import sys
import time

from ..output import check_output, figure_formats
from ..units import MM2UM
from ..reports.study_report import write_study
from ..study.reader import Study, bundled_studies
from ..study.runner import run_study
from . import add_progress, command


@command("study", "run a study (TOML file or bundled name) and write its report to a folder")
class StudyCommand:
    @staticmethod
    def add_arguments(p):
        p.add_argument("study", metavar="FILE.toml",
                       help=f"study file, or a bundled study: {', '.join(bundled_studies())}")
        p.add_argument("--out", required=True, metavar="DIR", help="output folder (must not exist)")
        p.add_argument("--force", action="store_true", help="replace DIR if it exists")
        p.add_argument("--seed", type=int, default=None, metavar="S", help="override the study's seed")
        p.add_argument("--quick", action="store_true",
                       help="reduced grids and sample sizes (a smoke test, as the golden regression files)")
        p.add_argument("--formats", default="png", metavar="LIST",
                       help="figure files to write, comma-separated among png, svg (default png; "
                            "the report embeds the PNG either way)")
        add_progress(p)

    @staticmethod
    def run(args) -> None:
        t0 = time.perf_counter()
        study = Study.load(args.study)
        if args.quick:
            study = study.reduced()
        formats = figure_formats(args.formats)
        check_output(args.out, args.force)
        result = run_study(study, rng=args.seed, progress=args.progress)
        report = write_study(result, args.out, force=args.force, formats=formats)
        worst = result.to_frame().query("output == 'position' and statistic == 'worst_case'")
        span = worst.pivot(index="configuration", columns="aggregate", values="value") * MM2UM
        ranges = ", ".join(f"{c.name} {span.at[c.name, 'min']:.1f}-{span.at[c.name, 'max']:.1f} µm"
                           for c in result.configurations)
        print(f"prp3mc study {study.name}: wrote {report} in {time.perf_counter() - t0:.1f} s "
              f"(analyses {result.wall_time_s:.1f} s, seed {result.seed}); worst-case position error: {ranges}",
              file=sys.stdout)
