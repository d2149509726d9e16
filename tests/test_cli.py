import json
import subprocess
import sys

import numpy as np
import pytest

from prp3mc import Geometry, sensitivity
from prp3mc.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_sensitivity_json(capsys):
    code, out, err = run(capsys, "sensitivity", "--geometry", "u-shape", "--pose", "10", "100", "0", "--json")
    assert code == 0 and err == ""
    doc = json.loads(out)
    s = sensitivity(Geometry.from_preset("u-shape"), [10.0, 100.0, 0.0])
    np.testing.assert_array_equal(doc["A"], s.A)
    assert set(doc["J"]) == {"a", "alpha", "b", "beta", "rho", "c", "gamma", "theta", "e", "psi"}
    np.testing.assert_array_equal(doc["J"]["theta"], s.J["theta"])


def test_sensitivity_table(capsys):
    code, out, _ = run(capsys, "sensitivity", "--geometry", "delta-shape", "--pose", "0", "160", "0")
    assert code == 0
    assert "J_theta" in out and "leg 3" in out


def test_geometry_file(capsys, tmp_path):
    path = tmp_path / "g.toml"
    Geometry.from_preset("delta-shape").to_toml(path)
    code, out, _ = run(capsys, "sensitivity", "--geometry", str(path), "--pose", "0", "160", "0", "--json")
    assert code == 0 and "J" in json.loads(out)


@pytest.mark.parametrize("argv, message, status", [
    (["--geometry", "u-shape", "--pose", "10", "300", "0"], "leaves leg 1's stroke", 1),
    (["--geometry", "w-shape", "--pose", "10", "100", "0"], "unknown geometry preset", 1),
    (["--geometry", "u-shape", "--pose", "nan", "100", "0"], "expected a finite number, got 'nan'", 2),
    (["--geometry", "missing.toml", "--pose", "0", "100", "0"], "no such file", 1),
])
def test_bad_input_one_line(capsys, argv, message, status):
    code, out, err = run(capsys, "sensitivity", *argv)
    assert code == status and out == ""
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize("text", ["[[leg]\n", "name = 'g'\n[[leg]]\na_mm = 1\n"])
def test_bad_geometry_file(capsys, tmp_path, text):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    code, _, err = run(capsys, "sensitivity", "--geometry", str(path), "--pose", "0", "100", "0")
    assert code == 1 and err.count("\n") == 1 and str(path) in err


def test_console_script_exit_status():
    proc = subprocess.run([sys.executable, "-m", "prp3mc", "sensitivity", "--geometry", "nope",
                           "--pose", "0", "100", "0"], capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == ["prp3mc sensitivity: error: unknown geometry preset 'nope' "
                                                "(known: u-shape, delta-shape)"]


@pytest.mark.parametrize("argv", [
    ["sensitivity", "--geometry", "GEOM", "--pose", "0", "100", "0"],
    ["worstcase", "--geometry", "GEOM", "--budget", "paper", "--pose", "0", "100", "0"],
    ["montecarlo", "--geometry", "GEOM", "--budget", "paper", "--pose", "0", "100", "0", "--samples", "500",
     "--seed", "4"],
    ["sobol", "--geometry", "GEOM", "--budget", "paper", "--pose", "0", "100", "0", "--samples", "64",
     "--seed", "4"],
], ids=lambda a: a[0])
def test_json_outputs_describe_themselves(argv, tmp_path, capsys):
    """Every --json output names its inputs (file hashes included) and the versions it ran on."""
    import hashlib
    geometry_file = tmp_path / "g.toml"
    Geometry.from_preset("u-shape").to_toml(geometry_file)
    argv = [str(geometry_file) if a == "GEOM" else a for a in argv] + ["--json"]
    assert main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["inputs"]["geometry"]["sha256"] == hashlib.sha256(geometry_file.read_bytes()).hexdigest()
    assert doc["inputs"]["pose"] == {"x_mm": 0.0, "y_mm": 100.0, "phi_deg": 0.0}
    if "--budget" in argv:
        assert doc["inputs"]["budget"] == {"name": "paper", "preset": "paper"}
    if "--seed" in argv:
        assert doc["inputs"]["seed"] == 4
    assert set(doc["versions"]) == {"prp3mc", "python", "numpy", "scipy", "pandas", "SALib", "numba", "matplotlib"}


def test_init_templates_run_as_written(tmp_path, capsys):
    """`prp3mc init` writes templates that every command reads as they are, and refuses to overwrite."""
    for kind in ("geometry", "budget", "study", "classes", "region"):
        assert main(["init", kind, str(tmp_path / f"{kind}.toml")]) == 0
    assert main(["init", "budget", str(tmp_path / "budget.toml")]) == 1
    assert "exists" in capsys.readouterr().err
    assert main(["worstcase", "--geometry", str(tmp_path / "geometry.toml"), "--budget",
                 str(tmp_path / "budget.toml"), "--pose", "0", "100", "0", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["inputs"]["geometry"]["name"] == "my-manipulator" and doc["position_mm"] > 0
    from prp3mc.study.reader import Study
    study = Study.load(tmp_path / "study.toml")
    assert [c.name for c in study.configurations] == ["u-shape", "delta-shape"]
    assert main(["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes",
                 str(tmp_path / "classes.toml"), "--spec-position-um", "150", "--grid", "11", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["feasible"] and set(doc["choice"]) == {f"{q}_{i}" for q in ("rho", "theta", "b") for i in (1, 2, 3)}
    assert main(["allocate", "--geometry", "u-shape", "--region", str(tmp_path / "region.toml"), "--classes",
                 "example", "--spec-position-um", "150", "--grid", "11", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["inputs"]["region"]["sha256"]


def test_discrepancy_json_describes_itself(tmp_path, capsys):
    """discrepancy.json and --json name the data file with its sha256, the seed and the versions."""
    import hashlib
    from prp3mc import Budget, Region, simulate_campaign
    g = Geometry.from_preset("u-shape")
    data = tmp_path / "campaign.csv"
    simulate_campaign(g, Budget.from_preset("paper"), Region.from_preset("u-shape").grid(4).reshape(-1, 3), 3,
                      rng=2).to_csv(data)
    argv = ["discrepancy", "--geometry", "u-shape", "--budget", "paper", "--data", str(data), "--out",
            str(tmp_path / "out"), "--instrument-sigma-mm", "0.002", "--instrument-sigma-deg", "0.0005",
            "--seed", "5", "--json"]
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    written = json.loads((tmp_path / "out" / "discrepancy.json").read_text())
    for doc in (printed, written):
        assert doc["inputs"]["data"]["sha256"] == hashlib.sha256(data.read_bytes()).hexdigest()
        assert doc["inputs"]["seed"] == 5 and doc["inputs"]["budget"] == {"name": "paper", "preset": "paper"}
        assert set(doc["versions"]) == {"prp3mc", "python", "numpy", "scipy", "pandas", "SALib", "numba", "matplotlib"}
    report = (tmp_path / "out" / "report.html").read_text()
    assert "<h2>Run</h2>" in report and written["inputs"]["data"]["sha256"] in report


def _cut_budget(path):
    """The paper budget cut before leg 3's theta and b, as a file ending at a table boundary would be."""
    from prp3mc import Budget
    Budget.from_preset("paper").to_toml(path)
    text = path.read_text()
    path.write_text(text[:text.index("[inputs.theta_3]")])
    return path


def _campaign(path, n: int = 4, visits: int = 3):
    from prp3mc import Budget, Region, simulate_campaign
    simulate_campaign(Geometry.from_preset("u-shape"), Budget.from_preset("paper"),
                      Region.from_preset("u-shape").grid(n).reshape(-1, 3), visits, rng=2).to_csv(path)
    return path


@pytest.mark.parametrize("argv", [
    ["worstcase", "--geometry", "u-shape", "--pose", "0", "100", "0"],
    ["montecarlo", "--geometry", "u-shape", "--pose", "0", "100", "0", "--samples", "2048", "--seed", "4"],
    ["sobol", "--geometry", "u-shape", "--pose", "0", "100", "0", "--samples", "64", "--seed", "4"],
], ids=lambda a: a[0])
def test_json_outputs_record_an_incomplete_budget(argv, tmp_path, capsys):
    """A budget with inputs missing for some legs: the warning is given once and the JSON records it."""
    budget = _cut_budget(tmp_path / "cut.toml")
    assert main(argv + ["--budget", str(budget), "--json"]) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert doc["inputs"]["budget"]["missing_inputs"] == ["b_3", "theta_3"]
    assert len(doc["warnings"]) == 1 and "no law for b_3, theta_3 (other legs have one)" in doc["warnings"][0]
    assert out.err.count("warning:") == 1


def test_discrepancy_records_an_incomplete_budget(tmp_path, capsys):
    """discrepancy.json, --json and the report say that the budget lacks inputs; so does a result made in Python."""
    import warnings
    from prp3mc import Budget, discrepancy
    from prp3mc.errors import IncompleteBudgetWarning
    from prp3mc.reports.discrepancy_report import report_document
    budget, data = _cut_budget(tmp_path / "cut.toml"), _campaign(tmp_path / "campaign.csv")
    assert main(["discrepancy", "--geometry", "u-shape", "--budget", str(budget), "--data", str(data),
                 "--out", str(tmp_path / "out"), "--seed", "5", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    written = json.loads((tmp_path / "out" / "discrepancy.json").read_text())
    for doc in (printed, written):
        assert doc["inputs"]["budget"]["missing_inputs"] == ["b_3", "theta_3"]
        assert len(doc["warnings"]) == 1 and doc["warnings"][0].startswith(f"{budget}: no law for b_3, theta_3")
    report = (tmp_path / "out" / "report.html").read_text()
    assert "<b>Warnings</b>" in report and "no law for b_3, theta_3" in report
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IncompleteBudgetWarning)
        cut = Budget.load(budget)
    doc = report_document(discrepancy(Geometry.from_preset("u-shape"), cut, data, rng=5))
    assert doc["warnings"] == ["budget 'paper': no law for b_3, theta_3 (other legs have one): taken as exact; "
                               "a budget cut short?"]
    assert doc["inputs"]["budget"]["missing_inputs"] == ["b_3", "theta_3"]
    assert "warnings" not in report_document(discrepancy(Geometry.from_preset("u-shape"), Budget.from_preset("paper"),
                                                         data, rng=5))


def test_discrepancy_refuses_what_cannot_finish(tmp_path, capsys, monkeypatch):
    """Stopped at its time limit, or refused by its memory before it starts: one line, exit 1, nothing written."""
    import prp3mc.limits as limits
    import prp3mc.measurement.campaign.data as command      # the command imports read_campaign from here when run
    data, out = _campaign(tmp_path / "campaign.csv"), tmp_path / "out"
    argv = ["discrepancy", "--geometry", "u-shape", "--budget", "paper", "--data", str(data), "--out", str(out)]
    assert main(["--max-hours", "2e-5", *argv]) == 1          # 72 ms: stopped while it runs
    err = capsys.readouterr().err.splitlines()
    assert err == ["prp3mc discrepancy: error: stopped at the --max-hours limit (0.072 s of wall time): "
                   "nothing was written"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["campaign.csv"]      # no folder, no lock, no leftovers
    # memory, from the row count alone: the file is not even read
    monkeypatch.setattr(limits, "available_memory", lambda: 1 << 20)
    monkeypatch.setattr(command, "read_campaign", lambda *a, **k: pytest.fail("read before it was sized"))
    assert main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "needs ~" in err[0] and "available (limit 819 KiB)" in err[0] and not out.exists()
    # memory, once the file is read: its poses and visits are counted too
    monkeypatch.undo()
    rows_only = limits.discrepancy_estimate(48).bytes
    full = limits.discrepancy_estimate(48, 16, 3).bytes
    assert rows_only < full
    monkeypatch.setattr(limits, "available_memory", lambda: (rows_only + full) / 2 / limits.MEMORY_MARGIN)
    assert main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "discrepancy analysis of 48 measurements of 16 poses needs ~" in err[0]
    assert not out.exists()
