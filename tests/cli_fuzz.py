"""Fuzzing the command line and the files it reads, in real ``python -m prp3mc`` processes (issue 25, point 5).

Each case is one command line drawn from a grammar of every command's
options: most values are legal (so that a run gets past the parser and into
the analysis), some are odd (empty, NaN, a number in the wrong unit, a
control character, a path to nowhere...), and most files are a good file
mutated once or twice (bytes flipped, cut short, a line dropped or doubled,
a number replaced or scaled by a unit factor, a string replaced, a BOM, a
CSV delimiter changed). Every run gets ``--max-hours`` (its own, or 72 s),
so one that outlives the timeout did not stop at its limit: a hang.

A case ends badly when the process hangs, dies of a signal, exits with
anything but 0, 1 or 2, prints a traceback (or ``Fatal Python error``,
``Exception ignored``), refuses in more than one line, or prints ``--json``
output that is not strict JSON (a NaN is silent nonsense). Run::

    PYTHONPATH=. python -m tests.cli_fuzz [--cases N] [--seed S] [--jobs J]

``tests/test_bad_input.py`` runs a few cases of a seed as a slow test.
"""

from __future__ import annotations

import json
import os
import random
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import bad_corpus

#: Odd values, tried in place of any option's value.
ODD = ["", " ", "nan", "NaN", "-inf", "inf", "1e309", "-1", "0", "-0", "2.5", "1e6", "1e-300", "0x10", "1_000",
       "+5", " 5", "1,5", "١٢", "True", "/", ".", "..", "\x01", "é", "\udce9", "a" * 300, "-", "--", "u-shape",
       "paper", "example", "quick", "tcp://h:1", "local:1", "g=theta_1", "geometry", "{tmp}", "{tmp}/x/y/z",
       "{missing}", "{dangling}", "{files}/c_good.csv", "{files}/s_ok.toml"]

#: Numbers in a file replaced by these, or scaled by a unit factor (inch, µm, rad, mm for m).
ODD_NUMBERS = ["nan", "inf", "-inf", "1e308", "-1e308", "0", "-0.0", "1e-320", "-1", "2.5", "1e6", "0.0025", "3"]
UNIT_FACTORS = [25.4, 1 / 25.4, 1000.0, 0.001, 57.29577951308232, 0.017453292519943295, -1.0]
ODD_STRINGS = ['"\\u0001"', '""', '"é☃"', '"' + "x" * 200 + '"', '"u-shape"', '"../x"', "[]", "{}", "1"]

#: A small study (seconds), the good base of the mutated ones.
STUDY = ('name = "fz"\nseed = 1\noutputs = ["montecarlo"]\n[worstcase]\ngrid = 3\n[montecarlo]\nsamples = 1024\n'
         'grid = 2\n[[configuration]]\ngeometry = "u-shape"\nregion = "u-shape"\n')
REGION = 'name = "r"\nx_mm = [-40.0, 40.0]\ny_mm = [60.0, 140.0]\nphi_deg = 0.0\n'
#: Two families of two classes (an allocation of seconds).
CLASSES = ('name = "c"\n[theta]\nclasses = [\n  { name = "fine", law = "uniform", lo = -0.02, hi = 0.02, cost = 3.0 },\n'
           '  { name = "coarse", law = "uniform", lo = -0.06, hi = 0.06, cost = 1.0 },\n]\n'
           '[b]\nclasses = [\n  { name = "fine", law = "uniform", lo = -0.003, hi = 0.003, cost = 2.0 },\n'
           '  { name = "coarse", law = "uniform", lo = -0.01, hi = 0.01, cost = 1.0 },\n]\n')


@dataclass
class FuzzCase:
    """One command line (placeholders as in :mod:`tests.bad_corpus`) and the files it mutated."""

    argv: list
    mutations: dict = field(default_factory=dict)   # file key -> (base key, [mutation names])


def _files(root: Path) -> dict:
    """The good files the grammar names (the corpus's, and a small study, region, classes and plan)."""
    paths = bad_corpus.prepare(root / "files")
    extra = {"s_small": STUDY, "region": REGION, "classes": CLASSES}
    for name, text in extra.items():
        (root / "files" / f"{name}.toml").write_text(text)
        paths[name] = str(root / "files" / f"{name}.toml")
    good = Path(paths["c_good"]).read_text().splitlines()
    columns = good[0].split(",")
    keep = [k for k, c in enumerate(columns) if c not in ("x_meas", "y_meas", "phi_meas")]
    plan = "\n".join(",".join(line.split(",")[k] for k in keep) for line in good[:13]) + "\n"
    (root / "files" / "plan.csv").write_text(plan)
    paths["plan"] = str(root / "files" / "plan.csv")
    paths["files"] = str(root / "files")
    paths["missing"] = str(root / "files" / "no_such_file.toml")
    return paths


_NUMBER = re.compile(rb"(?<![\w.])-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
_STRING = re.compile(rb'"[^"\n]*"')


def mutate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """``data`` changed once, and the name of the change."""
    kind = rng.choice(["flip", "cut", "drop line", "double line", "number", "unit", "string", "bom", "delimiter",
                       "empty cell", "swap header"])
    lines = data.split(b"\n")
    if kind == "flip" and data:
        out = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(len(out))] = rng.randrange(256)
        return bytes(out), kind
    if kind == "cut" and data:
        return data[:rng.randrange(len(data))], kind
    if kind in ("drop line", "double line") and len(lines) > 1:
        k = rng.randrange(len(lines))
        return b"\n".join(lines[:k] + ([] if kind == "drop line" else [lines[k], lines[k]]) + lines[k + 1:]), kind
    numbers = list(_NUMBER.finditer(data))
    if kind in ("number", "unit") and numbers:
        m = rng.choice(numbers)
        if kind == "number":
            new = rng.choice(ODD_NUMBERS).encode()
        else:
            new = repr(float(m.group()) * rng.choice(UNIT_FACTORS)).encode()
        return data[:m.start()] + new + data[m.end():], kind
    strings = list(_STRING.finditer(data))
    if kind == "string" and strings:
        m = rng.choice(strings)
        return data[:m.start()] + rng.choice(ODD_STRINGS).encode() + data[m.end():], kind
    if kind == "bom":
        return b"\xef\xbb\xbf" + data, kind
    if kind == "delimiter" and b"," in data:
        return data.replace(b",", rng.choice([b";", b"\t", b" ", b",,"])), kind
    if kind == "empty cell" and len(lines) > 2:
        k = rng.randrange(1, len(lines))
        cells = lines[k].split(b",")
        cells[rng.randrange(len(cells))] = rng.choice([b"", b"NA", b"-", b" "])
        lines[k] = b",".join(cells)
        return b"\n".join(lines), kind
    if kind == "swap header" and b"," in lines[0]:
        cells = lines[0].split(b",")
        i, j = rng.randrange(len(cells)), rng.randrange(len(cells))
        cells[i], cells[j] = cells[j], cells[i]
        return b"\n".join([b",".join(cells)] + lines[1:]), kind
    return data + b"\n\x00", "nul"


#: Each command's options: name -> legal values (a list) or None for a flag; FILE keys are in braces.
GRAMMAR = {
    "sensitivity": {"--geometry": ["u-shape", "delta-shape", "{geometry}"], "--pose": ["POSE"],
                    "--region": ["u-shape", "{region}"], "--grid": ["3"], "--json": None},
    "worstcase": {"--geometry": ["u-shape", "{geometry}"], "--budget": ["paper", "{budget}"], "--pose": ["POSE"],
                  "--region": ["u-shape", "{region}"], "--grid": ["3"], "--k-sigma": ["3"], "--json": None},
    "montecarlo": {"--geometry": ["u-shape", "{geometry}"], "--budget": ["paper", "{budget}"], "--pose": ["POSE"],
                   "--samples": ["256", "1024"], "--seed": ["1"], "--tolerance-mm": ["0.1"], "--json": None},
    "sobol": {"--geometry": ["u-shape", "{geometry}"], "--budget": ["paper", "{budget}"], "--pose": ["POSE"],
              "--samples": ["256"], "--seed": ["1"], "--group": ["g=theta_1,theta_2"], "--json": None},
    "allocate": {"--geometry": ["u-shape", "{geometry}"], "--region": ["u-shape", "{region}"],
                 "--classes": ["example", "{classes}"], "--spec-position-um": ["150", "60"], "--grid": ["3"],
                 "--spec-phi-arcsec": ["200"], "--json": None},
    "discrepancy": {"--geometry": ["u-shape", "{geometry}"], "--budget": ["paper", "{budget}"],
                    "--data": ["{campaign}"], "--out": ["{tmp}/d"], "--seed": ["1"],
                    "--instrument-sigma-mm": ["0.002"], "--no-registration": None, "--json": None},
    "simulate": {"--geometry": ["u-shape", "{geometry}"], "--budget": ["paper", "{budget}"],
                 "--poses": ["9", "4"], "--plan": ["{plan}"], "--region": ["u-shape", "{region}"],
                 "--visits": ["2"], "--effects": ["scale_2=5e-4", "backlash_1=0.02"], "--drift": ["0.01,0,0"],
                 "--temperature": ["20,28", "none"], "--seed": ["1"], "--out": ["{tmp}/c.csv", "-"],
                 "--json": None},
    "study": {"STUDY": ["{study}", "quick"], "--out": ["{tmp}/s"], "--seed": ["1"], "--quick": None,
              "--formats": ["png,csv", "svg", "xlsx", "csv"], "--scheduler": ["local:0", "tcp://"]},
    "init": {"KIND": ["geometry", "budget", "study", "classes", "region"], "FILE": ["{tmp}/t.toml"],
             "--force": None},
}
#: Options a run of the command needs (drawn first, then others at random).
REQUIRED = {"sensitivity": ["--geometry", "--pose"], "worstcase": ["--geometry", "--budget", "--pose"],
            "montecarlo": ["--geometry", "--budget", "--pose"], "sobol": ["--geometry", "--budget", "--pose"],
            "allocate": ["--geometry", "--region", "--classes", "--spec-position-um"],
            "discrepancy": ["--geometry", "--budget", "--data", "--out"],
            "simulate": ["--geometry", "--budget", "--poses", "--out"], "study": ["STUDY", "--out"],
            "init": ["KIND", "FILE"]}
#: The good file each placeholder stands for.
BASES = {"geometry": ["g_unicode_name", "g_bom"], "budget": ["b_bom", "b_unicode_group", "b_u_model"],
         "region": ["region"], "classes": ["classes"], "campaign": ["c_good", "c_drift"], "plan": ["plan"],
         "study": ["s_small"]}


def draw(rng: random.Random, odd_rate: float = 0.07, mutate_rate: float = 0.6) -> FuzzCase:
    """One case of the grammar."""
    command = rng.choice(sorted(GRAMMAR))
    options = GRAMMAR[command]
    chosen = list(REQUIRED[command])
    chosen = [o for o in chosen if rng.random() > 0.05]          # now and then a required one missing
    others = sorted(set(options) - set(chosen))
    chosen += rng.sample(others, rng.randint(0, min(3, len(others))))
    case = FuzzCase([command])
    for option in chosen:
        legal = options[option]
        if legal is None:
            case.argv.append(option)
            continue
        if not option.isupper():
            case.argv.append(option)
        value = rng.choice(legal)
        if value == "POSE":
            pose = [rng.choice(["0", "10", "-20"]), rng.choice(["100", "120"]), rng.choice(["0", "5"])]
            if rng.random() < odd_rate:
                pose[rng.randrange(3)] = rng.choice(ODD)
            if rng.random() < 0.05:
                pose = pose[:rng.randint(0, 2)]
            case.argv += pose
            continue
        if rng.random() < odd_rate:
            value = rng.choice(ODD)
        key = value[1:-1] if value.startswith("{") and value.endswith("}") else None
        if key in BASES:
            base = rng.choice(BASES[key])
            if rng.random() < mutate_rate:
                name = f"m_{key}"
                case.mutations[name] = (base, rng.randint(1, 2))
                value = "{" + name + "}"
            else:
                value = "{" + base + "}"
        case.argv.append(value)
    if rng.random() < 0.1:
        top = rng.choice(["--max-hours", "--max-gb"])
        case.argv[:0] = [top, rng.choice(ODD + ["0.5", "1", "100"])]
    if "--max-hours" not in case.argv:
        case.argv[:0] = ["--max-hours", "0.02"]
    return case


def materialise(case: FuzzCase, paths: dict, tmp: Path, rng: random.Random) -> tuple[list, list]:
    """Write the case's mutated files into ``tmp``; return its argv (filled) and the mutations made."""
    local = dict(paths)
    made = []
    for name, (base, count) in case.mutations.items():
        data = Path(paths[base]).read_bytes()
        for _ in range(count):
            data, kind = mutate(data, rng)
            made.append(f"{base}:{kind}")
        target = tmp / f"{name}{Path(paths[base]).suffix}"
        target.write_bytes(data)
        local[name] = str(target)
    return bad_corpus.expand(case.argv, local, str(tmp)), made


def judge(argv: list, code, out: str, err: str) -> str | None:
    """What went wrong (None: nothing); see the module docstring."""
    if code is None:
        return "hang"
    for marker in ("Traceback", "Fatal Python error", "Exception ignored"):
        if marker in err:
            return f"traceback: {err.strip().splitlines()[-1][:200]}"
    if code not in (0, 1, 2):
        return f"exit {code}: {err.strip()[-200:]}"
    if code:
        errors = [line for line in err.splitlines() if ": warning: " not in line]
        if len(errors) != 1:
            return f"{len(errors)} error lines: {err.strip()[:300]}"
    elif "--json" in argv and out.strip():
        def refuse(constant):
            raise ValueError(f"{constant} in the JSON output")
        try:
            json.loads(out, parse_constant=refuse)
        except ValueError as exc:
            return f"bad JSON: {str(exc)[:200]}"
    return None


def run_case(case: FuzzCase, paths: dict, tmp: Path, rng: random.Random, timeout: float) -> dict:
    tmp.mkdir(parents=True, exist_ok=True)
    argv, made = materialise(case, paths, tmp, rng)
    t0 = time.time()
    try:
        r = subprocess.run([sys.executable, "-m", "prp3mc", *argv], capture_output=True, timeout=timeout, cwd=tmp)
        code, out, err = r.returncode, r.stdout.decode(errors="replace"), r.stderr.decode(errors="replace")
    except subprocess.TimeoutExpired:
        code, out, err = None, "", ""
    return {"argv": [os.fsdecode(a) if isinstance(a, bytes) else a for a in argv], "mutations": made,
            "exit": code, "seconds": round(time.time() - t0, 1), "problem": judge(argv, code, out, err),
            "stderr": err.strip()[-300:]}


def fuzz(root: Path, cases: int, seed: int = 0, jobs: int = 1, timeout: float = 150.0, log=print) -> dict:
    """Run ``cases`` drawn cases of ``seed``; return counts by exit status and the problems found."""
    from concurrent.futures import ThreadPoolExecutor
    paths = _files(root)
    rng = random.Random(seed)
    drawn = [(k, draw(rng), random.Random(rng.random())) for k in range(cases)]

    def one(item):
        k, case, case_rng = item
        return run_case(case, paths, root / f"f{k}", case_rng, timeout)

    result = {"cases": 0, "exits": {}, "problems": [], "hangs": 0, "tracebacks": 0, "seconds": 0.0}
    with ThreadPoolExecutor(jobs) as pool:
        for r in pool.map(one, drawn):
            result["cases"] += 1
            result["seconds"] += r["seconds"]
            result["exits"][str(r["exit"])] = result["exits"].get(str(r["exit"]), 0) + 1
            if r["problem"]:
                result["problems"].append(r)
                result["hangs"] += r["problem"] == "hang"
                result["tracebacks"] += r["problem"].startswith("traceback")
            log(f"{'BAD ' if r['problem'] else 'ok  '}{r['seconds']:6.1f}s exit {r['exit']} {r['argv']}"
                f" {r['mutations']}" + (f"\n      {r['problem']}" if r["problem"] else ""))
    return result


if __name__ == "__main__":
    import argparse
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=150.0)
    parser.add_argument("--root", type=Path, default=None)
    a = parser.parse_args()
    root = a.root or Path(os.environ.get("TMPDIR", "/tmp")) / f"prp3mc_fuzz_{os.getpid()}"
    res = fuzz(root, a.cases, a.seed, a.jobs, a.timeout, log=lambda s: print(s, flush=True))
    print(json.dumps({k: v for k, v in res.items() if k != "problems"}))
    print(json.dumps(res["problems"], indent=1))
