"""The command line as a new user meets it: typos, grids, campaigns from the command line, readable numbers."""

import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from prp3mc import Budget, Geometry, Region, monte_carlo, worst_case
from prp3mc.cli import main
from prp3mc.units import probability_text, quantity_text

ROOT = Path(__file__).parent.parent


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("argv, hint", [
    (["worstcase", "--geometry", "u-shape", "--budgte", "paper", "--pose", "0", "100", "0"], "did you mean --budget?"),
    (["worstcas", "--geometry", "u-shape"], "did you mean worstcase?"),
    (["--versoin"], "did you mean --version?"),
    (["montecarlo", "--geometry", "u-shape", "--budget", "paper", "--pose", "0", "100", "0", "--sampels=9"],
     "did you mean --samples?"),
])
def test_typos_get_a_suggestion(capsys, argv, hint):
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == "" and hint in err and err.count("\n") == 1


def test_abbreviations_still_pass(capsys):
    code, out, _ = run(capsys, "worstcase", "--geometry", "u-shape", "--budg", "paper", "--pose", "0", "100", "0")
    assert code == 0 and "position error" in out


def test_help_lists_every_command_without_importing_them():
    """`prp3mc --help` reads the commands' help from their source: no numba, scipy or pandas import."""
    code = ("import sys, contextlib, io; from prp3mc.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()) as f: main(['--help'])\n"
            "print(sorted(m for m in ('numba', 'scipy', 'pandas', 'matplotlib') if m in sys.modules)); "
            "print(f.getvalue())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("[]")
    for name in ("allocate", "discrepancy", "init", "montecarlo", "sensitivity", "simulate", "sobol", "study",
                 "worstcase"):
        assert name in out


def test_readable_numbers():
    assert probability_text(0.000815) == "815 ppm"
    assert probability_text(0.0528, (0.05, 0.055)) == "5.28 % [5, 5.5]"
    assert probability_text(0.0) == "0 ppm"
    assert quantity_text(4.874e-4, "1") == "4.874e-04 (487.4 ppm)"
    assert quantity_text(0.5, "1") == "0.5" and quantity_text(0.012, "mm") == "0.012 mm"


def test_montecarlo_prints_a_probability_in_ppm(capsys):
    code, out, _ = run(capsys, "montecarlo", "--geometry", "u-shape", "--budget", "paper", "--pose", "10", "100",
                       "0", "--samples", "20000", "--seed", "1", "--tolerance-mm", "0.1")
    line = next(t for t in out.splitlines() if t.startswith("P(position error"))
    assert "ppm" in line and "0.000" not in line


@pytest.mark.parametrize("command", ["worstcase", "montecarlo", "sensitivity"])
def test_region_tables_equal_the_api(command, capsys, tmp_path):
    """--region R --grid N writes one row per pose (CSV on stdout, --out FILE.csv, --json rows) with the API's numbers."""
    budget = [] if command == "sensitivity" else ["--budget", "paper"]
    extra = ["--samples", "4000", "--seed", "3"] if command == "montecarlo" else []
    argv = [command, "--geometry", "u-shape", *budget, "--region", "u-shape", "--grid", "3", *extra]
    code, out, _ = run(capsys, *argv)
    assert code == 0
    table = pd.read_csv(pd.io.common.StringIO(out))
    poses = Region.from_preset("u-shape").grid(3).reshape(-1, 3)
    g, b = Geometry.load("u-shape"), Budget.load("paper")
    if command == "worstcase":
        assert np.allclose(table["position_mm"], worst_case(g, b, poses).position_mm, rtol=1e-12)
    elif command == "montecarlo":
        r = monte_carlo(g, b, poses, 4000, rng=3)
        assert np.allclose(table["position_p99_mm"], r.position_pct[:, 2], rtol=1e-12)
    else:
        assert len(table) == 9 * 12 * 9 and set(table["matrix"]) >= {"A", "B", "J_rho"}
    assert np.allclose(table[["x_mm", "y_mm", "phi_deg"]].drop_duplicates().to_numpy(), poses)
    assert main([*argv, "--out", str(tmp_path / "t.csv")]) == 0
    assert pd.read_csv(tmp_path / "t.csv").equals(table)
    assert main([*argv, "--out", str(tmp_path / "t.csv")]) == 1                # exists: refused
    code, out, _ = run(capsys, *argv, "--json")
    doc = json.loads(out)
    assert len(doc["rows"]) == len(table) and doc["inputs"]["grid"] == 3 and "versions" in doc


def test_grid_without_region_is_refused(capsys):
    code, _, err = run(capsys, "worstcase", "--geometry", "u-shape", "--budget", "paper", "--pose", "0", "100", "0",
                       "--grid", "5")
    assert code == 1 and "--region" in err


def test_region_file(capsys, tmp_path):
    path = tmp_path / "r.toml"
    path.write_text("x_mm = [-10, 10]\ny_mm = [90, 110]\nphi_deg = 2\n")
    code, out, _ = run(capsys, "worstcase", "--geometry", "u-shape", "--budget", "paper", "--region", str(path),
                       "--grid", "2")
    table = pd.read_csv(pd.io.common.StringIO(out))
    assert code == 0 and sorted(set(table["x_mm"])) == [-10, 10] and set(table["phi_deg"]) == {2}
    path.write_text("x_mm = [-10, 10]\ny = [90, 110]\n")
    code, _, err = run(capsys, "worstcase", "--geometry", "u-shape", "--budget", "paper", "--region", str(path))
    assert code == 1 and "unknown key(s) y" in err and err.count("\n") == 1


def test_simulate_writes_a_campaign_with_its_effects(capsys, tmp_path):
    from prp3mc import read_campaign
    out = tmp_path / "c.csv"
    code, text, _ = run(capsys, "simulate", "--geometry", "u-shape", "--budget", "paper", "--poses", "10",
                        "--visits", "3", "--effects", "scale_2=5e-4,backlash_1=0.02", "--registration",
                        "0.02,-0.02,0.005", "--outliers", "0.1", "--seed", "5", "--out", str(out), "--json")
    doc = json.loads(text)
    c = read_campaign(out, Geometry.load("u-shape"))
    assert code == 0 and c.n_measurements == 30 and c.n_poses == 10 and doc["inputs"]["seed"] == 5
    assert len(doc["outlier_rows"]) == 3 and doc["inputs"]["effects"] == {"scale_2": 5e-4, "backlash_1": 0.02}
    import prp3mc
    again = prp3mc.simulate_campaign(Geometry.load("u-shape"), Budget.load("paper"),
                                     _spread(Region.from_preset("u-shape"), 10), 3,
                                     effects={"scale_2": 5e-4, "backlash_1": 0.02}, registration=(0.02, -0.02, 0.005),
                                     outliers=(0.1, 0.5), rng=5)
    assert np.allclose(c.measured, again.measured, rtol=0, atol=1e-9)       # the CSV keeps 12 digits


def _spread(region, n):
    from prp3mc.cli.simulate import spread_poses
    return spread_poses(region, n)


def test_spread_poses():
    region = Region.from_preset("u-shape")
    assert np.allclose(_spread(region, 9), region.grid(3).reshape(-1, 3))
    p = _spread(region, 10)
    assert p.shape == (10, 3) and len(np.unique(p, axis=0)) == 10


def test_simulate_follows_a_plan(capsys, tmp_path):
    """--plan keeps the template's order, pose ids, directions and times; only the measured columns are drawn."""
    plan = pd.DataFrame({"pose_id": ["A", "B", "A", "C", "B", "C"],
                         "x_cmd": [0, 10, 0, -10, 10, -10], "y_cmd": [100, 90, 100, 120, 90, 120],
                         "phi_cmd": 0.0, "x_meas": np.nan, "y_meas": np.nan, "phi_meas": np.nan,
                         "dir_1": [1, -1, 1, 1, -1, -1], "dir_2": 1, "dir_3": -1,
                         "time_s": [0, 10, 20, 30, 45, 60]})
    plan.to_csv(tmp_path / "plan.csv", index=False)
    code, _, err = run(capsys, "simulate", "--geometry", "u-shape", "--budget", "paper", "--plan",
                       str(tmp_path / "plan.csv"), "--effects", "backlash_1=0.05", "--seed", "1",
                       "--out", str(tmp_path / "c.csv"))
    assert code == 0, err
    c = pd.read_csv(tmp_path / "c.csv", dtype={"pose_id": str})
    for col in ("pose_id", "x_cmd", "y_cmd", "dir_1", "dir_2", "dir_3", "time_s"):
        assert (c[col].to_numpy() == plan[col].to_numpy()).all(), col
    assert c["x_meas"].notna().all()
    plan.loc[2, "x_cmd"] = 5                                 # pose A commanded twice differently
    plan.to_csv(tmp_path / "bad.csv", index=False)
    code, _, err = run(capsys, "simulate", "--geometry", "u-shape", "--budget", "paper", "--plan",
                       str(tmp_path / "bad.csv"), "--out", str(tmp_path / "d.csv"))
    assert code == 1 and "pose_id 'A'" in err and err.count("\n") == 1


@pytest.mark.parametrize("argv, message", [
    (["--effects", "scale_2"], "NAME=VALUE"),
    (["--effects", "scale_9=1"], "unknown effect"),
    (["--registration", "1,2"], "DX,DY,DEG"),
    (["--temperature", "hot"], "START,END"),
])
def test_simulate_bad_input(capsys, tmp_path, argv, message):
    code, _, err = run(capsys, "simulate", "--geometry", "u-shape", "--budget", "paper", "--poses", "4",
                       "--out", str(tmp_path / "c.csv"), *argv)
    assert code in (1, 2) and message in err and err.count("\n") == 1
    assert not (tmp_path / "c.csv").exists()


def test_example_campaign_is_what_its_script_writes(tmp_path):
    """The bundled campaign is the output of the command line in the script beside it (same seed, same bytes)."""
    sys.path.insert(0, str(ROOT / "prp3mc" / "data" / "campaigns"))
    try:
        import make_example
    finally:
        sys.path.pop(0)
    assert main(make_example.command(tmp_path / "example.csv")) == 0
    bundled = ROOT / "prp3mc" / "data" / "campaigns" / "example.csv"
    assert (tmp_path / "example.csv").read_bytes() == bundled.read_bytes()


@pytest.mark.slow
def test_readme_example_campaign_line_works(tmp_path, monkeypatch, capsys):
    """The README's line runs `prp3mc discrepancy` on the bundled campaign and names the two hidden effects."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    line = next(t for t in readme.splitlines() if t.startswith("prp3mc discrepancy") and "--data example" in t)
    argv = shlex.split(line, comments=True)
    assert argv[:2] == ["prp3mc", "discrepancy"] and "example" in argv
    monkeypatch.chdir(tmp_path)
    assert main(argv[1:]) == 0
    doc = json.loads((tmp_path / argv[argv.index("--out") + 1] / "discrepancy.json").read_text())
    assert {e["name"] for e in doc["named_effects"]} == {"scale_2", "backlash_1"}
    assert not doc["unexplained"]


def test_xlsx_without_openpyxl_is_one_line_with_the_pip_line(capsys, tmp_path, monkeypatch):
    import importlib.util
    find = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "openpyxl" else find(name, *a))
    code, _, err = run(capsys, "study", "quick", "--quick", "--formats", "png,xlsx", "--out", str(tmp_path / "o"))
    assert code == 1 and "pip install 'prp3mc[xlsx]'" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()
