"""Report figures (issue 23): the time to draw and save the figures a user sees, two source trees in one run.

Each tree (``--before DIR``, a checkout of the commit before a change, and
``--after DIR``, default this one) is measured in a fresh process, the trees
taking turns ``--repeat`` times. A process runs the bundled ``quick`` study
and a discrepancy analysis of a simulated campaign (49 poses x 3 visits,
registration error; 50 bootstrap draws: the figures do not show them) untimed, then
draws every figure of their reports and saves it as PNG at the reports'
resolution (:func:`prp3mc.output.save_figure`) three times, timing each
figure by its quickest of the three.
Printed: per tree and report, the best and median total over the turns, and
the load average. ``--keep DIR`` keeps the last turn's PNGs of each tree in
``DIR/before`` and ``DIR/after``, to look at. Usage: ``python
benchmarks/bench_figures.py --before DIR [--after DIR] [--repeat N] [--keep DIR] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

_CHILD = r"""
import json, sys, tempfile, time
from pathlib import Path
from prp3mc import Budget, Geometry, Region
from prp3mc.measurement.campaign.simulate import simulate_campaign
from prp3mc.output import save_figure
from prp3mc.study.reader import Study
from prp3mc.study.runner import run_study
from prp3mc.reports.study_report import _figures
from prp3mc.reports import discrepancy_report
from prp3mc.reports.discrepancy_report import _REPORT_FIGURES, _report_figure

def timed(tasks, folder, dpi, renders=3):
    out = {}
    for name, draw in tasks:
        best = float("inf")
        for _ in range(renders):
            t0 = time.perf_counter()
            save_figure(draw(), folder, name, ("png",), dpi)
            best = min(best, time.perf_counter() - t0)
        out[name] = best
    return out

out = {}
with tempfile.TemporaryDirectory() as tmp:
    tmp = sys.argv[1] or tmp
    Path(tmp).mkdir(parents=True, exist_ok=True)
    figures = _figures(run_study(Study.load("quick"), progress=False))
    out["quick"] = timed([(name, draw) for name, _, draw in figures], tmp, 150)
    from prp3mc import discrepancy
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    poses = Region.from_preset("u-shape").grid(7).reshape(-1, 3)
    campaign = simulate_campaign(g, b, poses, 3, rng=1, registration=(0.020, -0.020, 0.005),
                                 instrument_sigma_mm=0.002, instrument_sigma_deg=0.0005)
    result = discrepancy(g, b, campaign, instrument_sigma_mm=0.002, instrument_sigma_deg=0.0005, n_bootstrap=50,
                         rng=1)
    tasks = [(n, (lambda n=n: _report_figure(n, result))) for n in _REPORT_FIGURES]
    out["discrepancy"] = timed([(n, d) for n, d in tasks if _report_figure(n, result) is not None], tmp,
                               discrepancy_report.DPI)
print(json.dumps(out))
"""


def _child(tree: Path, keep: str = "") -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    done = subprocess.run([sys.executable, "-c", _CHILD, keep], cwd=tree, env=env, check=True, capture_output=True,
                          text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def bench_figures(trees: dict, repeat: int = 3, keep: Path | None = None) -> dict:
    runs: dict = {label: [] for label in trees}
    loads = []
    for k in range(repeat):
        for label, tree in trees.items():
            runs[label].append(_child(tree, str(keep / label) if keep is not None and k == repeat - 1 else ""))
            loads.append(os.getloadavg()[0])
    out: dict = {"load": (min(loads), max(loads)), "repeat": repeat}
    for label, turns in runs.items():
        out[label] = {}
        for report in turns[0]:
            totals = [sum(t[report].values()) for t in turns]
            per = {name: statistics.median(t[report][name] for t in turns) for name in turns[0][report]}
            out[label][report] = {"figures": len(per), "best_s": min(totals), "median_s": statistics.median(totals),
                                  "median_per_figure_s": per}
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True)
    parser.add_argument("--after", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--keep", type=Path, help="keep the last turn's PNGs here")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    out = bench_figures({"before": args.before.resolve(), "after": args.after.resolve()}, args.repeat, args.keep)
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"load {out['load'][0]:.1f}-{out['load'][1]:.1f}, {out['repeat']} turns of each tree")
    for report in out["before"]:
        b, a = out["before"][report], out["after"][report]
        print(f"{report:14s} {b['figures']:2d} figures  before best {b['best_s']:.2f} s median {b['median_s']:.2f} s"
              f"  after best {a['best_s']:.2f} s median {a['median_s']:.2f} s"
              f"  after/before (medians) {a['median_s'] / b['median_s']:.2f}")


if __name__ == "__main__":
    main()
