"""The same behaviour, measured: two source trees of prp3mc side by side, in one run.

Usage: ``python benchmarks/bench_before_after.py OLD_TREE NEW_TREE [--repeats N] [--bench-repeats M]
[--json FILE]``, each tree a checkout of prp3mc (``git archive COMMIT | tar -x -C DIR``). Every
figure runs each tree's own code in a fresh process (``PYTHONPATH=TREE``, cwd ``TREE``), the
two trees taking turns so that a change of the machine's load falls on both; the table gives
medians of the repeats and the 1-minute load average read around the runs:

- ``prp3mc --help`` and parsing the paper study (``Study.from_toml``): wall time of the process;
- ``prp3mc study paper_reproduction`` warm (compiled kernels cached) and cold (every numba
  cache of the tree deleted first, as after a fresh install): wall and CPU time;
- the paper study's ``summary.json``: every value that differs between the trees, by path;
- ``benchmarks/run.py --quick --json`` of each tree: its ratios (speed-ups against the
  alternative measured in the same run).

Written for issue 23 (the house by method); the figures are in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: The ratios of ``run.py --json`` compared between the trees (speed-ups against the alternative).
RATIOS = ("sensitivity_speedup_vs_loop", "worstcase_speedup_vs_de", "mc_grid_speedup_vs_numpy",
          "mc_pose_speedup_vs_numpy", "envelope_effects_cost_ratio", "sobol_pose_ratio_to_ot_wall",
          "sobol_pose_ratio_to_ot_cpu", "study_speedup_vs_before", "mc_grid_fraction_of_limit",
          "mc_pose_fraction_of_uniforms_limit")


#: What each figure of the table times.
LABELS = {"help": "`prp3mc --help`", "parse": "import and `Study.from_toml` of the paper study",
          "study_warm": "`prp3mc study paper_reproduction`, warm",
          "study_cold": "the same, cold (the tree's numba caches deleted)"}


def run(tree: Path, args: list[str], out: Path | None = None) -> dict:
    """Run ``python ARGS`` on ``tree``'s code; wall and CPU seconds, loads before and after."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    load0 = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], cwd=tree, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise RuntimeError(f"{tree}: {' '.join(args)} failed:\n{proc.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall": wall, "cpu": cpu, "load": 0.5 * (load0 + os.getloadavg()[0]), "stdout": proc.stdout}


def clear_numba(tree: Path) -> int:
    """Delete every numba cache file of ``tree``'s package; how many."""
    files = [p for pattern in ("*.nbi", "*.nbc") for p in (tree / "prp3mc").rglob(pattern)]
    for p in files:
        p.unlink()
    return len(files)


def flatten(doc, path: str = "") -> dict:
    """``{json path: leaf value}`` of a JSON document."""
    if isinstance(doc, dict):
        return {k: v for key, value in doc.items() for k, v in flatten(value, f"{path}/{key}").items()}
    if isinstance(doc, list):
        return {k: v for i, value in enumerate(doc) for k, v in flatten(value, f"{path}[{i}]").items()}
    return {path: doc}


def summary_difference(old: Path, new: Path) -> dict:
    """Paths of summary.json only in one tree's output, and those whose values differ."""
    a, b = (flatten(json.loads(p.read_text())) for p in (old, new))
    return {"only_old": sorted(set(a) - set(b)), "only_new": sorted(set(b) - set(a)),
            "differ": {k: (a[k], b[k]) for k in sorted(set(a) & set(b)) if a[k] != b[k]},
            "bytes_identical": old.read_bytes() == new.read_bytes()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--repeats", type=int, default=5, help="of the short commands and the warm study")
    parser.add_argument("--cold", type=int, default=3, help="repeats of the cold study")
    parser.add_argument("--bench-repeats", type=int, default=2, help="repeats of run.py --quick (0: skip)")
    parser.add_argument("--json", type=Path, help="write every measurement here")
    args = parser.parse_args(argv)
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    work = Path(tempfile.mkdtemp(prefix="before_after_"))
    rec: dict = {"loads": [], "runs": {}}

    def measure(name: str, fn, repeats: int):
        for r in range(repeats):
            for label in (("old", "new") if r % 2 == 0 else ("new", "old")):    # taking turns
                m = fn(label, r)
                m.pop("stdout", None)
                rec["runs"].setdefault(name, {}).setdefault(label, []).append(m)
                print(f"{name:14s} {label} {m['wall']:7.2f} s wall {m['cpu']:7.2f} CPU-s load {m['load']:.1f}",
                      file=sys.stderr, flush=True)
                if args.json:                                  # what is measured so far survives an interruption
                    args.json.write_text(json.dumps(rec, indent=1, default=str))

    study = lambda label, r: run(trees[label], ["-m", "prp3mc", "study", "paper_reproduction", "--no-progress",  # noqa: E731
                                               "--force", "--out", str(work / f"{label}_{r}")])
    for label in trees:                                    # compile once (and warm the file cache)
        run(trees[label], ["-m", "prp3mc", "study", "paper_reproduction", "--no-progress", "--force",
                           "--out", str(work / f"{label}_first")])
    measure("help", lambda label, r: run(trees[label], ["-m", "prp3mc", "--help"]), args.repeats)
    measure("parse", lambda label, r: run(trees[label], ["-c", "from prp3mc.study.reader import Study; "
                                                          "Study.from_toml('studies/paper_reproduction.toml')"]),
            args.repeats)
    measure("study_warm", study, args.repeats)

    def cold(label, r):
        clear_numba(trees[label])
        return study(label, 100 + r)
    rec["summary"] = summary_difference(work / "old_0" / "summary.json", work / "new_0" / "summary.json")
    measure("study_cold", cold, args.cold)

    def bench(label, r):
        m = run(trees[label], ["benchmarks/run.py", "--quick", "--json"])
        m["ratios"] = {k: v for k, v in json.loads(m["stdout"]).items() if k in RATIOS}
        return m
    if args.bench_repeats:
        measure("bench_quick", bench, args.bench_repeats)
    shutil.rmtree(work, ignore_errors=True)
    print(table(rec))
    if args.json:
        args.json.write_text(json.dumps(rec, indent=1, default=str))
    return 0


def table(rec: dict) -> str:
    """Markdown tables: medians of wall and CPU time per figure, ratios of run.py, summary.json's differences."""
    med = lambda runs, key: statistics.median(m[key] for m in runs)  # noqa: E731
    lines = ["| figure | before (wall s; CPU s) | after (wall s; CPU s) | after / before (wall) | load |",
             "|---|---|---|---|---|"]
    for name, by in rec["runs"].items():
        if name == "bench_quick":
            continue
        old, new = by["old"], by["new"]
        loads = [m["load"] for m in old + new]
        lines.append(f"| {LABELS.get(name, name)} (median of {len(old)}) | {med(old, 'wall'):.2f}; {med(old, 'cpu'):.2f} | "
                     f"{med(new, 'wall'):.2f}; {med(new, 'cpu'):.2f} | {med(new, 'wall') / med(old, 'wall'):.2f} | "
                     f"{min(loads):.1f}-{max(loads):.1f} |")
    if "bench_quick" in rec["runs"]:
        by = rec["runs"]["bench_quick"]
        lines += ["", "| run.py --quick ratio | before (median) | after (median) | after / before |", "|---|---|---|---|"]
        for key in RATIOS:
            old = [m["ratios"][key] for m in by["old"] if key in m["ratios"]]
            new = [m["ratios"][key] for m in by["new"] if key in m["ratios"]]
            if old and new:
                a, b = statistics.median(old), statistics.median(new)
                lines.append(f"| {key} | {a:.3g} | {b:.3g} | {b / a:.2f} |")
    s = rec["summary"]
    lines += ["", f"summary.json byte-identical: {s['bytes_identical']}; values that differ: {len(s['differ'])}; "
              f"only before: {len(s['only_old'])}; only after: {len(s['only_new'])}", "",
              "| summary.json paths | count | what | largest difference |", "|---|---|---|---|"]
    groups: dict = {}
    for what, paths in (("only before", s["only_old"]), ("only after", s["only_new"]), ("differ", s["differ"])):
        for path in paths:
            groups.setdefault((pattern(path), what), []).append(path)
    for (pat, what), paths in groups.items():
        lines.append(f"| {pat} | {len(paths)} | {what} | {largest(s['differ'], paths) if what == 'differ' else ''} |")
    return "\n".join(lines)


def pattern(path: str) -> str:
    """A summary.json path with its configuration, output and input names as ``*``."""
    path = re.sub(r"^/configurations/[^/]+/", "/configurations/*/", path)
    return re.sub(r"/sobol/[^/]+/[^/]+/", "/sobol/*/*/", path)


def largest(differ: dict, paths: list) -> str:
    """The largest difference over ``paths``: in standard errors where the value has one beside it, else relative."""
    z, rel = [], []
    for path in paths:
        a, b = differ[path]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (a, b)):
            return f"{a!r} -> {b!r}" if len(paths) == 1 else "text"
        se = path.rsplit("/", 1)[0] + "/se"
        if path.endswith("/value") and se in differ:
            z.append(abs(a - b) / max((differ[se][0] ** 2 + differ[se][1] ** 2) ** 0.5, 1e-300))
        rel.append(abs(a - b) / max(abs(a), abs(b), 1e-300))
    return f"{max(z):.2f} combined se" if z else f"{max(rel):.3g} relative"


if __name__ == "__main__":
    sys.exit(main())
