"""``prp3mc yield`` (SPEC §9): the JSON contract, the region table, the readable report and bad input."""

import json

import numpy as np
import pytest

from prp3mc import exact_yield
from prp3mc.cli import main
from prp3mc.model.budget import Budget

POSE = ("--pose", "10", "120", "0")
SPEC = ("--spec-position-um", "150", "--spec-phi-arcsec", "100")
LEVELS = {"p99.73", "p99.9937", "p99.9999"}


def run(capsys, *argv):
    code = main(["yield", "--geometry", "u-shape", "--budget", "paper", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_pose_json_is_the_spec_contract(capsys):
    code, out, err = run(capsys, *POSE, *SPEC, "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert {"exceed_position_ppm", "exceed_phi_ppm", "exceed_any_ppm", "error_bound_ppm", "quantiles_position_um",
            "quantiles_phi_arcsec", "method", "inputs", "versions"} <= set(doc)
    assert set(doc["quantiles_position_um"]) == LEVELS and set(doc["quantiles_phi_arcsec"]) == LEVELS
    r = exact_yield("u-shape", "paper", [10.0, 120.0, 0.0], spec_position_um=150.0, spec_phi_arcsec=100.0)
    assert doc["exceed_position_ppm"] == pytest.approx(1e6 * float(r.exceed_position), rel=1e-12)
    assert doc["exceed_phi_ppm"] == pytest.approx(1e6 * float(r.exceed_phi), rel=1e-12)
    assert doc["quantiles_position_um"]["p99.73"] == pytest.approx(1e3 * float(r.quantile_position_mm[0]))
    assert doc["inputs"]["spec_position_um"] == 150.0 and doc["inputs"]["pose"]["y_mm"] == 120.0
    assert "characteristic function" in doc["method"]


def test_without_a_phi_spec_exceed_phi_is_null(capsys):
    code, out, _ = run(capsys, *POSE, "--spec-position-um", "150", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["exceed_phi_ppm"] is None
    assert doc["exceed_any_ppm"] == doc["exceed_position_ppm"]


def test_region_json_carries_the_region_summary_and_one_row_per_pose(capsys):
    code, out, err = run(capsys, "--region", "u-shape", "--grid", "3", "--spec-position-um", "150", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert set(doc["region"]) == {"max_exceed_position_ppm", "mean_exceed_position_ppm", "area_fraction_above_1ppm",
                                  "argmax_pose"}
    rows = doc["rows"]
    assert len(rows) == 9
    values = np.array([row["exceed_position_ppm"] for row in rows])
    assert doc["region"]["max_exceed_position_ppm"] == pytest.approx(values.max())
    assert doc["region"]["mean_exceed_position_ppm"] == pytest.approx(values.mean())
    best = rows[int(values.argmax())]
    assert doc["region"]["argmax_pose"] == [best["x_mm"], best["y_mm"], best["phi_deg"]]
    # the pose again, with quantiles (another lattice): the same exceedance within both error bounds
    assert abs(doc["exceed_position_ppm"] - values.max()) <= doc["error_bound_ppm"] + best["error_bound_ppm"]
    assert doc["inputs"]["grid"] == 3


def test_region_json_says_each_warning_once(capsys):
    """The paper budget's P(either) bound is above the target (by conditioning on two legs): said once for the
    grid, not again for its worst pose."""
    code, out, err = run(capsys, "--region", "u-shape", "--grid", "2", *SPEC, "--json")
    assert code == 0, err
    said = json.loads(out)["warnings"]
    either = [w for w in said if "P(position or phi out of spec)" in w]
    assert len(either) == 1 and "of 4 pose(s)" in either[0] and len(set(said)) == len(said), said
    assert err.count("P(position or phi out of spec)") == 1, err


def test_region_table_goes_to_stdout_and_the_summary_to_stderr(capsys):
    code, out, err = run(capsys, "--region", "u-shape", "--grid", "2", "--spec-position-um", "150")
    assert code == 0
    assert out.splitlines()[0].startswith("x_mm,y_mm,phi_deg,exceed_position_ppm")
    assert len(out.splitlines()) == 5
    assert "The worst pose" in err


def test_readable_report_sets_worst_case_rss_and_quantiles_side_by_side(capsys):
    code, out, _ = run(capsys, *POSE, *SPEC)
    assert code == 0
    for text in ("ppm", " %", "Ppk", "worst case", "RSS", "p99.73", "p99.9999", "either"):
        assert text in out


@pytest.mark.parametrize("argv, message", [
    (("--spec-position-um", "0"), "> 0"),
    (("--spec-position-um", "0.0025"), "RSS"),
    (("--spec-position-um", "150", "--spec-phi-arcsec", "-3"), "> 0"),
])
def test_bad_specs_are_one_line(capsys, argv, message):
    code, out, err = run(capsys, *POSE, *argv)
    assert code != 0 and out == ""
    assert message in err and len(err.strip().splitlines()) == 1


def test_a_pose_out_of_reach_is_one_line(capsys):
    code, out, err = run(capsys, "--pose", "0", "900", "0", "--spec-position-um", "150")
    assert code != 0 and out == "" and len(err.strip().splitlines()) == 1


def test_a_correlated_budget_falls_back_on_monte_carlo_and_says_so(capsys, tmp_path):
    doc = Budget.load("paper").to_dict() | {"correlation": {"theta_1,theta_2": 0.6}}
    path = tmp_path / "corr.toml"
    Budget.from_dict(doc).to_toml(path)
    code = main(["yield", "--geometry", "u-shape", "--budget", str(path), *POSE, "--spec-position-um", "150",
                 "--samples", "200000", "--seed", "3", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    rec = json.loads(out)
    assert rec["method"].startswith("Monte Carlo")
    assert rec["inputs"]["seed"] == 3 and rec["inputs"]["samples"] == 200000
    assert rec["error_bound_ppm"] > 0 and rec["exceed_phi_ppm"] is None          # no --spec-phi-arcsec
    assert rec["exceed_any_ppm"] == rec["exceed_position_ppm"] and set(rec["ci95_ppm"]) == {"position", "any"}
    assert "theta_1 (uniform)" in rec["method"]
    with pytest.raises(Exception, match="correlates inputs whose law is not normal"):
        exact_yield("u-shape", Budget.from_dict(doc), [10.0, 120.0, 0.0], spec_position_um=150.0)


def correlated_budget(tmp_path, laws: str) -> str:
    """A budget file: theta_i and b_i of the paper's widths, normal (sd = half-width / 2) or uniform, with
    theta_1,theta_2 and b_2,b_3 correlated."""
    doc = Budget.load("paper").to_dict()
    if laws == "normal":
        doc["inputs"] = {k: {"law": "normal", "mu": 0.0, "sd": (0.02 if k.startswith("theta") else 0.006)}
                         for k in doc["inputs"] if k[:2] in ("th", "b_")}
    doc["correlation"] = {"theta_1,theta_2": 0.6, "b_2,b_3": -0.4}
    path = tmp_path / f"corr_{laws}.toml"
    Budget.from_dict(doc).to_toml(path)
    return str(path)


def test_the_fallback_reports_every_exceedance_with_its_interval(capsys, tmp_path):
    """SPEC §9 with a correlated budget the series cannot take: position, |dphi| and either as floats, each
    with its Wilson 95 % interval; the error is the farthest interval end; the region table has all three."""
    path = correlated_budget(tmp_path, "uniform")
    argv = ["yield", "--geometry", "u-shape", "--budget", path, "--spec-position-um", "60", "--spec-phi-arcsec", "30",
            "--samples", "100000", "--seed", "4", "--json"]
    assert main(argv[:5] + list(POSE) + argv[5:]) == 0
    rec = json.loads(capsys.readouterr().out)
    figures = {o: rec[f"exceed_{o}_ppm"] for o in ("position", "phi", "any")}
    assert all(isinstance(v, float) for v in figures.values())
    assert figures["any"] >= max(figures["position"], figures["phi"])
    assert rec["error_bound_ppm"] == pytest.approx(max(max(hi - figures[o], figures[o] - lo)
                                                       for o, (lo, hi) in rec["ci95_ppm"].items()))
    assert rec["method"].startswith("Monte Carlo") and rec["inputs"]["seed"] == 4
    assert main(argv[:5] + ["--region", "u-shape", "--grid", "2"] + argv[5:]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert len(rows) == 4 and {"exceed_position_ppm", "exceed_phi_ppm", "exceed_any_ppm",
                               "ci95_farther_end_ppm"} <= set(rows[0])


def test_an_all_normal_correlated_budget_is_exact(capsys, tmp_path):
    """Correlated inputs that are all normal: the exact series, its bound, and the method says how."""
    path = correlated_budget(tmp_path, "normal")
    code = main(["yield", "--geometry", "u-shape", "--budget", path, *POSE, "--spec-position-um", "60",
                 "--spec-phi-arcsec", "60", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    rec = json.loads(out)
    assert "jointly normal" in rec["method"] and "samples" not in rec["inputs"]
    assert isinstance(rec["exceed_phi_ppm"], float) and rec["error_bound_ppm"] <= 1e-3 + 1e-12
    r = exact_yield("u-shape", Budget.load(path), [10.0, 120.0, 0.0], spec_position_um=60.0, spec_phi_arcsec=60.0)
    assert rec["exceed_position_ppm"] == pytest.approx(1e6 * float(r.exceed_position), rel=1e-12)


def test_a_spec_beyond_the_worst_case_answers_zero(capsys):
    """1e4 µm against a worst case of 140 µm: P = 0 with bound 0 (it was refused: more than 2^23 terms)."""
    code, out, err = run(capsys, "--pose", "0", "100", "0", "--spec-position-um", "1e4", "--spec-phi-arcsec", "1e9",
                         "--json")
    assert code == 0, err
    rec = json.loads(out)
    assert rec["exceed_position_ppm"] == rec["exceed_phi_ppm"] == rec["exceed_any_ppm"] == 0.0
    assert rec["error_bound_ppm"] == 0.0


@pytest.mark.parametrize("target", ["1e-30", "0.5"])
def test_the_target_range_is_the_engine_s(capsys, target):
    try:
        code = main(["yield", "--geometry", "u-shape", "--budget", "paper", *POSE, "--spec-position-um", "100",
                     "--target", target])
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2 and "[1e-12, 0.01]" in err and target in err


def _without_density(capsys, tmp_path, *argv, before=()):
    """``prp3mc [before] yield`` at POSE with a budget of one random leg (a disc clearance: no 2-D density, no
    exact yield) and ``argv``; returns (exit status, stdout, stderr)."""
    from prp3mc.model.laws import Disc, Uniform

    path = tmp_path / "alone.toml"
    Budget({"rho_1": Disc(0.01), "zeta_1": Uniform(0.0, 360.0)}, name="disc alone").to_toml(path)
    code = main([*before, "yield", "--geometry", "u-shape", "--budget", str(path), *POSE, *argv, "--seed", "3"])
    return (code, *capsys.readouterr())


def test_a_budget_without_a_density_falls_back_on_monte_carlo(capsys, tmp_path):
    """One leg random (a disc clearance): no 2-D density, so no exact yield (NoExactYieldError); the command
    falls back on Monte Carlo as for correlated laws and says why (it used to exit 1, "use Monte Carlo")."""
    code, out, err = _without_density(capsys, tmp_path, "--spec-position-um", "8", "--samples", "20000", "--json")
    assert code == 0, err
    rec = json.loads(out)
    assert rec["method"].startswith("Monte Carlo") and "no density" in rec["method"]
    assert rec["inputs"]["samples"] == 20000 and 0.0 <= rec["exceed_position_ppm"] <= 1e6


def test_the_monte_carlo_fallback_of_a_budget_without_a_density_is_sized_first(capsys, tmp_path):
    """The exact series fails only when tried (NoExactYieldError): the Monte Carlo fallback that follows is
    sized too and refused in one line when it will not fit (here --max-gb, which the exact yield at one pose
    passes); it used to run unchecked."""
    code, out, err = _without_density(capsys, tmp_path, "--spec-position-um", "8", "--samples", "20000", "--json",
                                      before=("--max-gb", "0.01"))
    refusal = [line for line in err.splitlines() if ": warning: " not in line]   # the budget's own warning aside
    assert code == 1 and out == "" and len(refusal) == 1
    assert "Monte Carlo of 20000 samples at 1 pose(s) needs" in err and "more than --max-gb 0.01" in err


def test_a_spec_below_one_unit_warns_on_the_monte_carlo_fallback_too(capsys, tmp_path):
    """A spec below 1 µm warns on every path of the command: the Monte Carlo fallback (no exact yield) said
    nothing, the exact path's warning being dropped with its recorded warnings."""
    code, out, err = _without_density(capsys, tmp_path, "--spec-position-um", "0.5", "--samples", "2000", "--json")
    assert code == 0, err
    assert "spec_position_um = 0.5 µm is below 1 µm: a spec in mm typed as µm?" in err
    assert json.loads(out)["method"].startswith("Monte Carlo")



def test_the_monte_carlo_fallback_prints_its_text_without_an_orientation_spec(capsys, tmp_path):
    """The readable report of the fallback formatted --spec-phi-arcsec when none was given (a TypeError
    traceback, found by the corpus)."""
    code, out, err = _without_density(capsys, tmp_path, "--spec-position-um", "5", "--samples", "2000")
    assert code == 0, err
    assert "Monte Carlo with 2000 samples" in out and "position > 5 µm" in out and "dphi" not in out
