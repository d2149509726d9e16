"""Benchmark of ``prp3mc study paper_reproduction``: end to end, and where its time goes.

End to end: the command as a user runs it (a fresh process: imports, the
analyses, the report), wall and CPU time (the process and its children).
In this process, each part on its own, wall and CPU time (CPU time counts
every thread and worker process):

- the analyses (``run_study``), as shipped (BLAS on one thread inside them,
  :mod:`prp3mc._threads`) and as before (BLAS free to start its own threads
  inside prp3mc's worker threads);
- the report (``write_study``), the figures drawn on one worker process per
  core while the tables are written, and drawn one after the other in this
  process, as the command does.

The sample counts and grids are the study's own (``--quick``: its reduced
version). The same seed gives the same summary.json from the command and from
both ways of drawing the report (checked), and the same figures; with BLAS
threads free the numbers move in their last bits (the largest relative
difference is reported).

Usage: ``python benchmarks/bench_study.py [--quick]`` prints one JSON object;
``benchmarks/run.py`` shows it as two rows of its table.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from prp3mc.output import dumps_json
from prp3mc.reports.study_report import write_study
from prp3mc.study.summary import build_summary
from prp3mc.study import runner
from prp3mc.study.reader import Study
from prp3mc.sobol import indices as sobol

STUDY = "paper_reproduction"


def _cpu() -> float:
    """CPU time so far of this process and its waited-for children, s."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _timed(fn) -> tuple[object, float, float]:
    """``fn()``, its wall time and its CPU time (s)."""
    t0, c0 = time.perf_counter(), _cpu()
    value = fn()
    return value, time.perf_counter() - t0, _cpu() - c0


@contextlib.contextmanager
def _blas_threads_free():
    """The analyses as before this change: no BLAS thread limit inside them."""
    saved = runner.single_threaded_blas, sobol.single_threaded_blas
    runner.single_threaded_blas = sobol.single_threaded_blas = contextlib.nullcontext
    try:
        yield
    finally:
        runner.single_threaded_blas, sobol.single_threaded_blas = saved


def _numbers(path: Path) -> dict:
    """A summary.json without its timings (the only part that differs between runs)."""
    summary = json.loads(path.read_text())
    for key in ("wall_time_s", "timings_s"):
        summary["metadata"].pop(key, None)
    return summary


def _max_rel_diff(a, b) -> float:
    """Largest relative difference between the numbers of two summaries of the same structure."""
    if isinstance(a, dict):
        return max((_max_rel_diff(a[k], b[k]) for k in a if k != "metadata"), default=0.0)
    if isinstance(a, list):
        return max((_max_rel_diff(x, y) for x, y in zip(a, b)), default=0.0)
    if isinstance(a, float) and a != b:
        return abs(a - b) / max(abs(a), abs(b))
    return 0.0


def bench_study(quick: bool) -> dict:
    out: dict = {"study_quick": quick, "study_load_1min_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-m", "prp3mc", "study", STUDY, "--out", f"{tmp}/cli", "--no-progress"]
        argv += ["--quick"] if quick else []
        _, out["study_cli_seconds"], out["study_cli_cpu_seconds"] = _timed(
            lambda: subprocess.run(argv, check=True, capture_output=True))

        study = Study.load(STUDY)
        runner.run_study(study.reduced(), progress=False)     # warm-up: compiled kernels loaded, first calls
        study = study.reduced() if quick else study
        result, out["study_analyses_seconds"], out["study_analyses_cpu_seconds"] = _timed(
            lambda: runner.run_study(study, progress=False))
        out["study_analyses_timings_s"] = dict(result.timings_s)
        with _blas_threads_free():
            before, out["study_analyses_blas_free_seconds"], out["study_analyses_blas_free_cpu_seconds"] = _timed(
                lambda: runner.run_study(study, progress=False))

        workers = out["study_report_workers"] = len(os.sched_getaffinity(0))  # every core, whatever the load
        _, out["study_report_seconds"], out["study_report_cpu_seconds"] = _timed(
            lambda: write_study(result, f"{tmp}/parallel", workers=workers))
        _, out["study_report_serial_seconds"], out["study_report_serial_cpu_seconds"] = _timed(
            lambda: write_study(result, f"{tmp}/serial", workers=1))
        same = [_numbers(Path(tmp) / d / "summary.json") for d in ("cli", "parallel", "serial")]
        assert same[0] == same[1] == same[2], "summary.json differs between the ways of running the study"
        out["study_blas_free_max_rel_diff"] = _max_rel_diff(same[0], json.loads(dumps_json(build_summary(before))))
        figures = sorted(p.name for p in (Path(tmp) / "parallel" / "figures").iterdir())
        assert all((Path(tmp) / "parallel" / "figures" / f).read_bytes()
                   == (Path(tmp) / "serial" / "figures" / f).read_bytes() for f in figures)
    out["study_figures"] = len(figures)
    # in-process parts, as shipped and as before (the fresh process's imports come on top of both)
    out["study_parts_seconds"] = out["study_analyses_seconds"] + out["study_report_seconds"]
    out["study_parts_before_seconds"] = out["study_analyses_blas_free_seconds"] + out["study_report_serial_seconds"]
    out["study_speedup_vs_before"] = out["study_parts_before_seconds"] / out["study_parts_seconds"]
    out["study_load_1min_after"] = os.getloadavg()[0]
    return out


if __name__ == "__main__":
    json.dump(bench_study("--quick" in sys.argv[1:]), sys.stdout, indent=2)
    print()
