"""Private re-implementations (issue 23): what they cost in lines and buy in time, before and after, in one run.

Two source trees of prp3mc, ``--before`` (a checkout of the commit before
the change) and ``--after`` (default: this one), are measured in the same
run, turn about, each command in a fresh process:

- **lines** of the private modules each tree holds;
- **imports**: ``prp3mc --help`` and parsing the paper study
  (``Study.load``) from a fresh interpreter, wall time;
- **study**: ``prp3mc study paper_reproduction --out X --force`` (``--quick``:
  its reduced grids), wall time, and whether both trees write the same
  ``summary.json`` but for timings (and the study file's path, each tree's own);
- **discrepancy**: ``prp3mc discrepancy`` on a simulated campaign of 392 rows
  (49 poses x 8 visits, registration error, as ``bench_discrepancy --speed``),
  report included, wall time, and whether ``discrepancy.json`` is the same
  but for its wall time;
- the report figures alone are timed by ``bench_figures.py`` (same ``--before``).

The 1-minute load average is printed with every row: the machine may be
shared. Usage: ``python benchmarks/bench_private.py --before DIR [--after DIR]
[--repeat N] [--quick] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PRIVATE = ["prp3mc/_distributions.py", "prp3mc/_fork.py", "prp3mc/_threads.py", "prp3mc/reports/_render.py",
           "prp3mc/reports/_layout.py", "prp3mc/limits.py", "prp3mc/montecarlo/_sampler.py",
           "prp3mc/montecarlo/_select.py", "prp3mc/montecarlo/_kernel.py"]

_CAMPAIGN = """
import sys
from prp3mc import Budget, Geometry
from prp3mc.measurement.campaign.simulate import simulate_campaign
sys.path.insert(0, sys.argv[2])
from bench_discrepancy import REGISTRATION, SIGMA, campaign_poses
g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
simulate_campaign(g, b, campaign_poses("u-shape"), 8, rng=1, registration=REGISTRATION, **SIGMA).to_csv(sys.argv[1])
"""


def _run(tree: Path, argv: list[str]) -> float:
    """Wall time (s) of ``python argv`` in a fresh process importing prp3mc from ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *argv], cwd=tree, env=env, check=True, capture_output=True)
    return time.perf_counter() - t0


def _lines(tree: Path) -> dict:
    return {name: sum(1 for _ in (tree / name).open()) if (tree / name).exists() else 0 for name in PRIVATE}


def _without(doc: dict, keys: tuple) -> dict:
    """``doc`` without the keys named (at any depth) whose values are timings."""
    if isinstance(doc, dict):
        return {k: _without(v, keys) for k, v in doc.items() if k not in keys}
    if isinstance(doc, list):
        return [_without(v, keys) for v in doc]
    return doc


def _turns(trees: dict, repeat: int, argv_of) -> dict:
    """Wall times per tree of ``argv_of(tree, label, k)``, the trees taking turns ``repeat`` times."""
    times = {label: [] for label in trees}
    for k in range(repeat):
        for label, tree in trees.items():
            times[label].append(_run(tree, argv_of(tree, label, k)))
    return {label: {"best_s": min(t), "median_s": statistics.median(t), "runs": len(t)} for label, t in times.items()}


def bench_private(before: Path, after: Path, repeat: int = 3, quick: bool = False) -> dict:
    trees = {"before": before, "after": after}
    out: dict = {"lines": {label: _lines(tree) for label, tree in trees.items()}, "load_start": os.getloadavg()[0]}
    out["help"] = _turns(trees, 2 * repeat, lambda tree, label, k: ["-m", "prp3mc", "--help"])
    out["study_parse"] = _turns(trees, 2 * repeat, lambda tree, label, k: [
        "-c", "from prp3mc.study.reader import Study; Study.load('paper_reproduction')"])
    out["load_after_imports"] = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        study = ["--quick"] if quick else []
        out["study"] = _turns(trees, max(1, repeat // 2) if not quick else repeat, lambda tree, label, k: [
            "-m", "prp3mc", "study", "paper_reproduction", "--out", str(tmp / f"study_{label}"), "--force",
            "--no-progress", *study])
        docs = [json.loads((tmp / f"study_{label}" / "summary.json").read_text()) for label in trees]
        skip = ("timings_s", "wall_time_s", "versions", "file", "source")    # timings, and the trees' own paths
        out["study_summary_same_but_timings"] = _without(docs[0], skip) == _without(docs[1], skip)
        out["load_after_study"] = os.getloadavg()[0]
        data = tmp / "campaign.csv"
        subprocess.run([sys.executable, "-c", _CAMPAIGN, str(data), str(after / "benchmarks")], cwd=after,
                       env=dict(os.environ, PYTHONPATH=str(after)), check=True)
        out["discrepancy"] = _turns(trees, repeat, lambda tree, label, k: [
            "-m", "prp3mc", "discrepancy", "--geometry", "u-shape", "--budget", "paper", "--data", str(data),
            "--instrument-sigma-mm", "0.002", "--instrument-sigma-deg", "0.0005", "--seed", "1", "--no-progress",
            "--out", str(tmp / f"disc_{label}"), "--force"])
        docs = [json.loads((tmp / f"disc_{label}" / "discrepancy.json").read_text()) for label in trees]
        out["discrepancy_json_same_but_timings"] = _without(docs[0], ("wall_time_s", "versions")) == \
            _without(docs[1], ("wall_time_s", "versions"))
        out["load_after_discrepancy"] = os.getloadavg()[0]
    return out


def table(r: dict) -> str:
    rows = [f"{'':34}{'before':>12}{'after':>12}{'after/before':>14}"]
    for name in PRIVATE:
        b, a = r["lines"]["before"][name], r["lines"]["after"][name]
        rows.append(f"{'lines ' + name.removeprefix('prp3mc/'):34}{b:>12}{a:>12}")
        b, a = sum(r["lines"]["before"].values()), sum(r["lines"]["after"].values())
    rows.append(f"{'lines, all of these':34}{b:>12}{a:>12}")
    for key, what in (("help", "prp3mc --help, s"), ("study_parse", "import + Study.load, s"),
                      ("study", "prp3mc study, s"), ("discrepancy", "prp3mc discrepancy, s")):
        for stat in ("best_s", "median_s"):
            b, a = r[key]["before"][stat], r[key]["after"][stat]
            rows.append(f"{what + ' (' + stat[:-2] + ')':34}{b:>12.2f}{a:>12.2f}{a / b:>14.2f}")
    rows.append(f"summary.json same but timings: {r['study_summary_same_but_timings']}; discrepancy.json same but "
                f"timings: {r['discrepancy_json_same_but_timings']}")
    rows.append("1-minute load: " + ", ".join(f"{k.removeprefix('load_')} {v:.1f}" for k, v in r.items()
                                              if k.startswith("load_")))
    return "\n".join(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", type=Path, required=True, help="source tree before the change")
    p.add_argument("--after", type=Path, default=Path(__file__).resolve().parents[1])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="the study's reduced grids")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    r = bench_private(args.before.resolve(), args.after.resolve(), args.repeat, args.quick)
    print(json.dumps(r, indent=2) if args.json else table(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
