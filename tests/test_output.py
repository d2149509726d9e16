"""Output folders under races and kills: claimed before any work, never replaced without force,
leftovers of killed runs cleaned by the next run (prp3mc.output)."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from prp3mc.cli import main
from prp3mc.errors import OutputBusyError, OutputExistsError, Prp3mcError
from prp3mc.output import (check_json, claim_output, output_folder, write_csv,
                           write_json)

# A run that writes its PID into the folder, holding it for HOLD seconds (HOLD < 0: until its stdin closes).
WRITER = textwrap.dedent("""
    import os, sys, time
    from prp3mc.output import output_folder
    from prp3mc.errors import Prp3mcError
    out, hold, force = sys.argv[1], float(sys.argv[2]), sys.argv[3] == "force"
    try:
        with output_folder(out, force=force) as tmp:
            print("claimed", flush=True)
            (tmp / "who").write_text(str(os.getpid()))
            sys.stdin.read() if hold < 0 else time.sleep(hold)
    except Prp3mcError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
""")


def writer(out: Path, hold: float, force: bool = False) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", WRITER, str(out), str(hold), "force" if force else "-"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def siblings(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


def test_two_racing_runs_one_wins(tmp_path):
    """Two processes started together on the same new folder: one writes it, the other stops in one line."""
    out = tmp_path / "out"
    runs = [writer(out, 1.0), writer(out, 1.0)]
    results = [(p.wait(30), *p.communicate()) for p in runs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 1]
    (_, _, err), = [r for r in results if r[0] == 1]
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "being written by another prp3mc run (pid" in err or "exists" in err
    winner = next(p for p, r in zip(runs, results) if r[0] == 0)
    assert (out / "who").read_text() == str(winner.pid)
    assert siblings(out) == []


def test_racing_force_runs_never_mix(tmp_path):
    """Even with --force, a run never replaces a folder another live run is writing."""
    out = tmp_path / "out"
    first = writer(out, -1, force=True)
    assert first.stdout.readline().strip() == "claimed"
    second = writer(out, 0.0, force=True)
    code, _, err = second.wait(30), *second.communicate()
    assert code == 1 and f"being written by another prp3mc run (pid {first.pid})" in err
    first.communicate("")
    assert first.returncode == 0
    assert (out / "who").read_text() == str(first.pid)


def test_killed_run_is_cleaned_by_the_next(tmp_path):
    """SIGKILL mid-run leaves a temp folder and the lock file; the next run removes both and succeeds."""
    out = tmp_path / "out"
    victim = writer(out, -1)
    assert victim.stdout.readline().strip() == "claimed"
    victim.send_signal(signal.SIGKILL)
    victim.wait(30)
    left = siblings(out)
    assert ".out.lock" in left and any(name.startswith(f".out.tmp-{victim.pid}-") for name in left)
    assert not out.exists()
    with output_folder(out) as tmp:   # the lock died with its holder: no wait, no error
        (tmp / "who").write_text("rerun")
    assert (out / "who").read_text() == "rerun"
    assert siblings(out) == []


def test_killed_force_swap_restores_the_old_folder(tmp_path):
    """A run killed after moving the old folder aside (no renameat2) loses nothing: it is put back."""
    out = tmp_path / "out"
    old = tmp_path / ".out.old-999999-abcd1234"
    old.mkdir()
    (old / "result").write_text("precious")
    (tmp_path / ".out.tmp-999999-zz9_xx12").mkdir()
    with pytest.raises(OutputExistsError, match="exists"):
        with output_folder(out):
            pass
    assert (out / "result").read_text() == "precious"
    assert siblings(out) == []


def test_leftovers_of_other_folders_are_left_alone(tmp_path):
    """Only this folder's own temp names are cleaned: run.v2's temp folder is not run's."""
    other = tmp_path / ".run.v2.tmp-1-abcdefgh"
    other.mkdir()
    with output_folder(tmp_path / "run") as tmp:
        (tmp / "x").write_text("1")
    assert other.exists()


def test_existing_folder_needs_force_and_force_replaces(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old").write_text("old")
    (out / "summary.json").write_text("{}")          # an earlier output: --force may replace it
    with pytest.raises(OutputExistsError, match="pass --force"):
        with output_folder(out):
            pytest.fail("the block must not run")
    assert (out / "old").exists()
    with output_folder(out, force=True) as tmp:
        (tmp / "new").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["new"]
    assert siblings(out) == []


def test_failed_block_leaves_the_old_folder(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old").write_text("old")
    (out / "report.html").write_text("<p>an earlier report</p>")
    with pytest.raises(RuntimeError):
        with output_folder(out, force=True) as tmp:
            (tmp / "new").write_text("new")
            raise RuntimeError("analysis failed")
    assert sorted(p.name for p in out.iterdir()) == ["old", "report.html"]
    assert siblings(out) == []


@pytest.mark.parametrize("case", ["not an output", "the working folder", "holds an input", "empty name"])
def test_force_never_replaces_what_the_user_had(tmp_path, monkeypatch, capsys, case):
    """--force replaces an earlier output (or an empty folder), never the working folder, a folder
    holding the run's own input files, or any other folder: a mistyped --out loses nothing."""
    project = tmp_path / "project"
    project.mkdir()
    study = project / "my_study.toml"
    study.write_text("[study]\n")
    (project / "notes.txt").write_text("mine")
    if case != "not an output":
        (project / "summary.json").write_text("{}")        # even an output folder, in these cases
    monkeypatch.chdir(project if case == "the working folder" else tmp_path)
    out = {"not an output": str(project), "the working folder": ".", "holds an input": "project",
           "empty name": ""}[case]
    argv = ["study", str(study), "--out", out, "--force"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err
    assert sorted(p.name for p in project.iterdir()) == sorted(
        ["my_study.toml", "notes.txt"] + ([] if case == "not an output" else ["summary.json"]))


def test_folder_appearing_meanwhile_is_not_replaced(tmp_path):
    """A folder made by something else while the run computes is left as it is."""
    out = tmp_path / "out"
    with pytest.raises(OutputExistsError, match="appeared while this run was writing"):
        with output_folder(out) as tmp:
            (tmp / "new").write_text("new")
            out.mkdir()
            (out / "theirs").write_text("theirs")
    assert sorted(p.name for p in out.iterdir()) == ["theirs"]
    assert siblings(out) == []


def test_claim_is_reentrant_and_shared(tmp_path):
    """A command claims --out before computing; the report writer inside shares that claim."""
    out = tmp_path / "out"
    with claim_output(out) as claimed:
        assert claimed == out and (tmp_path / ".out.lock").exists()
        with output_folder(out) as tmp:
            (tmp / "x").write_text("1")
    assert (out / "x").exists() and siblings(out) == []


def test_busy_folder_is_refused_at_once(tmp_path):
    out = tmp_path / "out"
    holder = writer(out, -1)
    assert holder.stdout.readline().strip() == "claimed"
    with pytest.raises(OutputBusyError, match=f"pid {holder.pid}"):
        with claim_output(out):
            pass
    holder.communicate("")
    assert holder.returncode == 0


def test_unwritable_parent_is_one_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(Prp3mcError, match="cannot claim"):
        with claim_output(blocker / "out"):
            pass


def test_discrepancy_checks_its_folder_before_computing(tmp_path, capsys):
    """An existing --out is refused before the campaign is even read (the data file does not exist)."""
    out = tmp_path / "out"
    out.mkdir()
    code = main(["discrepancy", "--geometry", "u-shape", "--budget", "paper", "--data", str(tmp_path / "none.csv"),
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "exists" in err and "none.csv" not in err and err.count("\n") == 1


def test_study_checks_its_folder_before_computing(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    code = main(["study", str(tmp_path / "none.toml"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "exists" in err and err.count("\n") == 1


def test_no_json_carries_nan(tmp_path):
    with pytest.raises(Prp3mcError, match=r"not finite at outputs\.x\[1\]"):
        write_json(tmp_path / "a.json", {"outputs": {"x": [1.0, float("nan")]}})
    assert not (tmp_path / "a.json").exists()
    assert check_json({"a": [1, 2.0, None, "x"]}) == {"a": [1, 2.0, None, "x"]}
    write_json(tmp_path / "b.json", {"a": None})
    assert json.loads((tmp_path / "b.json").read_text()) == {"a": None}


def test_csv_has_the_bytes_pandas_writes(tmp_path, seed):
    """Float frames written from the values' reprs, any other frame by pandas: the same bytes as to_csv."""
    import numpy as np
    import pandas as pd
    rng = np.random.default_rng(seed)
    wild = rng.standard_normal(400) * 10.0 ** rng.uniform(-30, 30, 400)
    special = [0.0, -0.0, 1.0, 1e16, 1e15, 1e-5, 1e-4, 0.1 + 0.2, np.inf, -np.inf, 5e-324, 1.7976931348623157e308]
    floats = pd.DataFrame({"x_mm": np.resize(special, 400), "value": wild, "y": wild.round(3)})
    others = [floats.assign(value=np.where(wild > 0, np.nan, wild)),                   # NaN: written as nothing
              floats.assign(label=["a,b", 'say "x"'] * 200), floats.rename(columns={"y": "y,z"}),
              pd.DataFrame({"n": np.arange(3), "f": [0.5, 1.5, 2.5]})]
    for k, frame in enumerate([floats, *others]):
        write_csv(frame, tmp_path / f"{k}.csv")
        frame.to_csv(tmp_path / f"{k}_pandas.csv", index=False)
        assert (tmp_path / f"{k}.csv").read_bytes() == (tmp_path / f"{k}_pandas.csv").read_bytes(), k


@pytest.mark.slow  # two fresh interpreters running a study (the race itself is tested above without the CLI)
def test_cli_race_through_the_command_line(tmp_path):
    """Two real `prp3mc study` runs on one new --out: one report, one one-line refusal."""
    study = tmp_path / "s.toml"
    study.write_text('name = "race"\nseed = 1\noutputs = []\n[worstcase]\ngrid = 5\n'
                     '[[configuration]]\ngeometry = "u-shape"\nregion = "u-shape"\n')
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    runs = [subprocess.Popen([sys.executable, "-m", "prp3mc", "study", str(study), "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for _ in range(2)]
    results = [(p.wait(120), *p.communicate()) for p in runs]
    assert sorted(code for code, _, _ in results) == [0, 1]
    (_, _, err), = [r for r in results if r[0] == 1]
    assert err.count("\n") == 1 and "Traceback" not in err
    assert (out / "summary.json").exists() and siblings(out) == []


def test_every_json_output_goes_through_the_one_writer():
    """No NaN or infinity can leave prp3mc as JSON: every file and --json output is written by
    prp3mc.output.dumps_json, which refuses them (allow_nan=False) and names where they are."""
    package = Path(__file__).resolve().parent.parent / "prp3mc"
    writers = {str(p.relative_to(package)) for p in package.rglob("*.py")
               if any(call in p.read_text(encoding="utf-8") for call in ("json.dump", ".to_json("))}
    assert writers == {"output.py"}


@pytest.mark.skipif(not hasattr(signal, "SIGTERM") or os.name != "posix", reason="POSIX signals")
def test_sigterm_leaves_nothing_behind(tmp_path):
    """A run ended by SIGTERM (timeout, a batch system) unwinds as after Ctrl-C: no temporary folder, no lock."""
    proc = subprocess.Popen([sys.executable, "-m", "prp3mc", "study", "paper_reproduction", "--out",
                             str(tmp_path / "k"), "--no-progress"], stderr=subprocess.PIPE, text=True)
    lock, end = tmp_path / ".k.lock", time.monotonic() + 60
    while not lock.exists() and proc.poll() is None and time.monotonic() < end:   # the run holds its folder
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=60)[1]
    assert proc.returncode == 143 and err.strip().endswith("terminated")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
