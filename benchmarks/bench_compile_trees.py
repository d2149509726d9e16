"""Cold and warm runs of two source trees on equal work, taking turns: what compilation costs each.

Usage: ``nice -n 5 python benchmarks/bench_compile_trees.py OLD_TREE NEW_TREE STUDY_TOML [--turns N]
[--json FILE]``, each tree a checkout of prp3mc (``git archive COMMIT | tar -x -C DIR``) and
STUDY_TOML a study both trees accept with the same analyses (``benchmarks/compile_equal_work.toml``:
``outputs = ["montecarlo"]``, the exact worst case and the Monte Carlo; no Sobol, whose Shapley effects
only the newer tree computes; no exact yield). Each turn, for each tree (the order alternating between
turns), in fresh processes (``PYTHONPATH=TREE``, cwd ``TREE``; run the driver under ``nice`` and its
children inherit it):

- cold: every numba cache and ``__pycache__`` of the tree deleted (as after a fresh install), then
  the first call of each compiled entry point the study uses, timed one by one in one process:
  ``sensitivity`` (201 x 201 poses; numpy in both trees, a control), ``worst_case`` (201 x 201, the
  envelope kernel) and ``monte_carlo`` (21 x 21 poses, 2^16 samples, the fused kernels); then the
  same process again, warm (its caches now written);
- cold: the caches deleted again, ``prp3mc study STUDY_TOML``; then the same study warm.

Cold less warm CPU seconds is the compilation (and the writing of its caches). The table gives
medians and ranges of wall and CPU seconds, of the cold-warm differences per turn, and the load.

``python benchmarks/bench_compile_trees.py TREE --events`` (cwd anywhere) deletes the tree's caches and
prints, as JSON, the CPU seconds numba spends compiling each function at the first ``worst_case`` and
``monte_carlo`` calls (its ``numba:compile`` events, each function's own time without its callees').

Written for issue 23's "cold first study after a fresh install no slower" (session 25); the
figures are in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench_before_after import run

ENTRY_POINTS = ("sensitivity", "worst_case", "monte_carlo")


def entry_points() -> dict:
    """Wall and CPU seconds of importing prp3mc and of the first call of each entry point (run in the tree)."""
    def timed(fn) -> dict:
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}
    out = {"import": timed(lambda: __import__("prp3mc"))}
    import prp3mc
    g, b = prp3mc.Geometry.from_preset("u-shape"), prp3mc.Budget.from_preset("paper")
    region = prp3mc.Region.from_preset("u-shape")
    calls = {"sensitivity": lambda: prp3mc.sensitivity(g, region.grid(201)),
             "worst_case": lambda: prp3mc.worst_case(g, b, region.grid(201)),
             "monte_carlo": lambda: prp3mc.monte_carlo(g, b, region.grid(21), 1 << 16, rng=1,
                                                       percentiles=(50, 95, 99, 99.73))}
    out.update({name: timed(calls[name]) for name in ENTRY_POINTS})
    return out


def compile_events() -> dict:
    """CPU seconds of numba's compile events per function (its callees' compilation excluded), run in the tree."""
    from numba.core import event

    stack, own = [], {}

    class Listener(event.Listener):
        def on_start(self, ev):
            stack.append([time.process_time(), 0.0])

        def on_end(self, ev):
            t0, callees = stack.pop()
            total = time.process_time() - t0
            fn = ev.data["dispatcher"].py_func
            name = f"{fn.__module__}.{fn.__name__}"
            own[name] = own.get(name, 0.0) + total - callees
            if stack:
                stack[-1][1] += total

    event.register("numba:compile", Listener())
    calls = entry_points()
    return {"calls": {k: v["cpu"] for k, v in calls.items()}, "compile_events": own}


def clear_caches(tree: Path) -> int:
    """Delete every numba cache file and ``__pycache__`` folder under ``tree``; how many numba files."""
    files = [p for pattern in ("*.nbi", "*.nbc") for p in tree.rglob(pattern)]
    for p in files:
        p.unlink()
    for folder in [p for p in tree.rglob("__pycache__") if p.is_dir()]:
        shutil.rmtree(folder)
    return len(files)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path, nargs="?")
    parser.add_argument("new", type=Path, nargs="?")
    parser.add_argument("study", type=Path, nargs="?")
    parser.add_argument("--turns", type=int, default=3)
    parser.add_argument("--json", type=Path, help="write every measurement here")
    parser.add_argument("--events", action="store_true", help="per-function compile CPU-s of OLD, cold")
    parser.add_argument("--child", choices=("calls", "events"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        json.dump(entry_points() if args.child == "calls" else compile_events(), sys.stdout)
        return 0
    if args.events:
        clear_caches(args.old.resolve())
        print(run(args.old.resolve(), [str(Path(__file__).resolve()), "--child", "events"])["stdout"])
        return 0
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    study, work = args.study.resolve(), Path(tempfile.mkdtemp(prefix="compile_trees_"))
    me = str(Path(__file__).resolve())
    rec: dict = {"old": [], "new": []}
    for turn in range(args.turns):
        for label in (("old", "new") if turn % 2 == 0 else ("new", "old")):
            tree, r = trees[label], {}
            r["deleted"] = clear_caches(tree)
            for state in ("cold", "warm"):
                m = run(tree, [me, "--child", "calls"])
                r[f"entry_{state}"] = {**json.loads(m.pop("stdout")), "process": m}
            clear_caches(tree)
            for state in ("cold", "warm"):
                m = run(tree, ["-m", "prp3mc", "study", str(study), "--no-progress", "--force",
                               "--out", str(work / f"{label}_{turn}_{state}")])
                m.pop("stdout")
                r[f"study_{state}"] = m
            rec[label].append(r)
            print(f"turn {turn} {label}: study cold {r['study_cold']['cpu']:.1f} warm {r['study_warm']['cpu']:.1f} "
                  f"CPU-s; entry points cold {r['entry_cold']['process']['cpu']:.1f} warm "
                  f"{r['entry_warm']['process']['cpu']:.1f} CPU-s; load {r['study_cold']['load']:.1f}",
                  file=sys.stderr, flush=True)
            if args.json:
                args.json.write_text(json.dumps(rec, indent=1))
    shutil.rmtree(work, ignore_errors=True)
    print(table(rec))
    return 0


def table(rec: dict) -> str:
    """Markdown: median (range) over turns of each figure in both trees, and after - before of the medians."""
    rows = [("study, cold", lambda r: r["study_cold"]), ("study, warm", lambda r: r["study_warm"]),
            ("entry points' process, cold", lambda r: r["entry_cold"]["process"]),
            ("entry points' process, warm", lambda r: r["entry_warm"]["process"])]
    rows += [(f"`{name}` first call, {state}", lambda r, n=name, s=state: r[f"entry_{s}"][n])
             for name in ("import",) + ENTRY_POINTS for state in ("cold", "warm")]
    lines = ["| figure (s) | before: wall; CPU, median (CPU range) | after: wall; CPU, median (CPU range) "
             "| after - before (CPU) |", "|---|---|---|---|"]

    def cell(runs):
        cpu = [m["cpu"] for m in runs]
        return f"{statistics.median(m['wall'] for m in runs):.1f}; {statistics.median(cpu):.2f} " \
               f"({min(cpu):.2f}-{max(cpu):.2f})", statistics.median(cpu)
    for label, get in rows:
        (a, ma), (b, mb) = cell([get(r) for r in rec["old"]]), cell([get(r) for r in rec["new"]])
        lines.append(f"| {label} | {a} | {b} | {mb - ma:+.2f} |")
    diffs = [("compilation in the study (cold - warm CPU-s, per turn)", "study")]
    diffs += [(f"compilation at `{n}`'s first call (cold - warm CPU-s)", n) for n in ENTRY_POINTS]
    for label, key in diffs:
        cells = []
        for tree in ("old", "new"):
            if key == "study":
                d = [r["study_cold"]["cpu"] - r["study_warm"]["cpu"] for r in rec[tree]]
            else:
                d = [r["entry_cold"][key]["cpu"] - r["entry_warm"][key]["cpu"] for r in rec[tree]]
            cells.append(d)
        ma, mb = statistics.median(cells[0]), statistics.median(cells[1])
        fmt = lambda d: ", ".join(f"{v:.1f}" for v in d)  # noqa: E731
        lines.append(f"| {label} | {ma:.2f} ({fmt(cells[0])}) | {mb:.2f} ({fmt(cells[1])}) | {mb - ma:+.2f} |")
    loads = [m["load"] for tree in ("old", "new") for r in rec[tree] for m in (r["study_cold"], r["study_warm"])]
    lines += ["", f"1-minute load around the studies: {min(loads):.1f}-{max(loads):.1f}"]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
