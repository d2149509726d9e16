"""A study's accuracy spec: the ``[spec]`` table, the exact yield it adds to summary.json, tables/summary.csv and
the report's first screen.

The reader tests are fast (no analysis runs). The run tests (slow: the exact
yield engine's compiled kernels load in a few seconds) check that every
figure the summary carries equals :func:`prp3mc.exact_yield` on the same
grid, that the Monte Carlo points of the exceedance curve agree with the
exact curve within their sampling error, and that the report's first screen
shows the figures.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from prp3mc import exact_yield
from prp3mc.errors import StudyError
from prp3mc.reports.study_report import write_study
from prp3mc.stackup import ppk
from prp3mc.study.reader import Study
from prp3mc.study.runner import run_study

from .report_checks import figures_without_files, missing_files, read

BASE = """\
name = "spec"
seed = 5
budget = "paper"
outputs = ["montecarlo", "yield"]

[worstcase]
grid = 5

[montecarlo]
samples = 8192
grid = 2
percentiles = [50, 99.73]
{tolerance}
{spec}
[[configuration]]
geometry = "u-shape"
"""


def _text(spec: str = "", tolerance: str = "") -> str:
    return BASE.format(spec=spec, tolerance=tolerance)


# ----------------------------------------------------------------- the table
def test_spec_table_read():
    s = Study.from_text(_text("[spec]\nposition_um = 100\nphi_arcsec = 60\n"))
    assert (s.spec.position_um, s.spec.phi_arcsec, s.spec.source) == (100.0, 60.0, "[spec]")
    assert s.tolerance_mm == pytest.approx(0.1)            # the Monte Carlo run counts against the same spec
    assert Study.from_text(_text()).spec is None
    assert Study.from_text(_text("[spec]\nposition_um = 100\n").replace('outputs = ["montecarlo", "yield"]', "")).outputs \
        == ("montecarlo", "sobol", "yield")                  # the exact yield runs by default with a spec


def test_tolerance_is_the_same_position_spec():
    s = Study.from_text(_text(tolerance="tolerance_mm = 0.1"))
    assert (s.spec.position_um, s.spec.phi_arcsec) == (100.0, None)
    assert s.spec.source == "[montecarlo] tolerance_mm"
    both = Study.from_text(_text("[spec]\nposition_um = 100\n", "tolerance_mm = 0.1"))
    assert both.spec.source == "[spec]" and both.tolerance_mm == pytest.approx(0.1)


@pytest.mark.parametrize("spec, tolerance, line, reason", [
    ("[spec]\nposition_um = -5\n", "", 15, "must be a finite number > 0 µm"),
    ("[spec]\nposition_um = nan\n", "", 15, "must be a finite number"),
    ("[spec]\nposition_um = \"60\"\n", "", 15, "must be a finite number"),
    ("[spec]\nphi_arcsec = 60\n", "", 14, "[spec] needs position_um"),
    ("[spec]\nposition_um = 60\nposition_mm = 0.06\n", "", 16, "unknown key 'position_mm' in [spec]"),
    ("[spec]\nposition_um = 80\n", "tolerance_mm = 0.1", 13, "one spec with two values"),
    ("", "tolerance_mm = 0", 13, "tolerance_mm must be > 0 mm"),
])
def test_bad_spec_one_line_naming_line_and_unit(spec, tolerance, line, reason):
    with pytest.raises(StudyError) as err:
        Study.from_text(_text(spec, tolerance), source="s.toml")
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"s.toml:{line}: ") and reason in message, message


@pytest.mark.parametrize("spec, value, warning", [
    ("position_um = 0.06\n", (0.06, None), r"spec_position_um = 0.06 µm is below 1 µm: a spec in mm typed as µm\? "
                                          r"\(0.06 mm = 60 µm\)"),
    ("position_um = 60\nphi_arcsec = 0.01\n", (60.0, 0.01), r"spec_phi_arcsec = 0.01 arcsec is below 1 arcsec: "
                                                           r"a spec in deg typed as arcsec\? \(0.01 deg = 36 arcsec\)"),
])
def test_a_spec_below_one_unit_warns_as_every_entry_point_does(spec, value, warning):
    """Below 1 µm or 1 arcsec a study's spec is taken with the warning exact_yield, prp3mc yield and allocate
    give, worded the same (one rule); studies refused it before, the other entry points warned."""
    with pytest.warns(Warning, match=warning):
        s = Study.from_text(_text("[spec]\n" + spec), source="s.toml")
    assert (s.spec.position_um, s.spec.phi_arcsec) == value


# ----------------------------------------------------------------- the run
#: The engine warns where its joint (either) channel is bracketed or its bound misses the target; the study carries
#: that bound as it is (the report shows it).
LOOSE = pytest.mark.filterwarnings("ignore:exact yield:prp3mc.errors.Prp3mcWarning")


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A one-configuration study with a position and an orientation spec, run and written."""
    folder = tmp_path_factory.mktemp("spec")
    study = Study.from_text(_text("[spec]\nposition_um = 100\nphi_arcsec = 120\n"), source=str(folder / "s.toml"))
    result = run_study(study, progress=False)
    write_study(result, folder / "out")
    return study, result, folder / "out"


@pytest.mark.slow
@LOOSE
def test_summary_carries_exact_yield_on_the_same_grid(written):
    study, result, out = written
    doc = json.loads((out / "summary.json").read_text())["configurations"]["u-shape"]["yield"]
    c = study.configurations[0]
    ref = exact_yield(c.geometry, study.budget, c.region.grid(study.mc_grid), spec_position_um=100.0,
                      spec_phi_arcsec=120.0)
    assert doc["spec"] == {"position_um": 100.0, "phi_arcsec": 120.0, "source": "[spec]"}
    assert doc["grid"] == list(study.mc_grid)
    for o in ("position", "phi", "any"):
        p = ref.exceedance(o)
        assert doc[f"exceed_{o}_ppm"] == pytest.approx({"min": 1e6 * p.min(), "max": 1e6 * p.max(),
                                                       "mean": 1e6 * p.mean()}, rel=1e-12, abs=1e-12)
        assert doc[f"exceed_{o}_pct"]["max"] == pytest.approx(100 * p.max(), rel=1e-12, abs=1e-12)
        want = float(ppk(p.max()))
        assert doc["ppk_min"][o] == (pytest.approx(want) if np.isfinite(want) else None)
    assert doc["error_bound_ppm"] == pytest.approx(1e6 * ref.error_bound.max())
    assert doc["error_bounds_ppm"]["any"] == pytest.approx(1e6 * ref.bound_any.max())
    region = ref.region_summary()
    assert doc["region"]["argmax_pose"] == region.pop("argmax_pose")
    assert {k: v for k, v in doc["region"].items() if k != "argmax_pose"} == pytest.approx(region)
    for q, level in enumerate(ref.levels):
        assert doc["quantiles_position_um"][f"p{level:g}"]["max"] == pytest.approx(
            1e3 * ref.quantile_position_mm[..., q].max(), rel=1e-12)
        assert doc["quantiles_phi_arcsec"][f"p{level:g}"]["min"] == pytest.approx(
            3600 * ref.quantile_phi_deg[..., q].min(), rel=1e-12)
    assert doc["method"] == ref.method
    mc = json.loads((out / "summary.json").read_text())["configurations"]["u-shape"]["montecarlo"]
    assert mc["exceed"]["tolerance_mm"] == pytest.approx(0.1)        # the Monte Carlo counts against the same spec
    # tables/summary.csv: the same figures, a unit in every statistic's name or its unit column
    frame = pd.read_csv(out / "tables" / "summary.csv")
    rows = frame[frame["analysis"] == "exact_yield"].set_index(["output", "statistic", "aggregate"])
    assert rows.at[("position", "exceed_ppm", "max"), "value"] == pytest.approx(1e6 * ref.exceed_position.max())
    assert rows.at[("phi", "exceed_pct", "mean"), "value"] == pytest.approx(100 * ref.exceed_phi.mean())
    assert rows.at[("position", "above_1ppm", "mean"), "value"] == pytest.approx(
        ref.region_summary()["area_fraction_above_1ppm"])
    assert rows.at[("position", "error_bound_ppm", "max"), "unit"] == "ppm"
    assert list(rows.loc[("position", ["argmax_x", "argmax_y", "argmax_phi"], "max"), "value"]) == \
        ref.region_summary()["argmax_pose"]
    assert rows.at[("position", "p99.73", "max"), "unit"] == "mm"
    per_pose = pd.read_csv(out / "tables" / "yield_u-shape.csv")
    assert len(per_pose[(per_pose["output"] == "any") & (per_pose["statistic"] == "exceed")]) == ref.exceed_any.size


@pytest.mark.slow
@LOOSE
def test_exceedance_curve_agrees_with_monte_carlo(written):
    """The curve's Monte Carlo points (the study's draws) and the exact curve agree within 5 standard errors
    plus the exact error bound: an independent check of the engine at the poses the report shows."""
    _, result, _ = written
    for curve in result["u-shape"].curves:
        assert curve.mc_s is not None and len(curve.mc_s) >= 5
        exact = np.interp(curve.mc_s, curve.s, curve.exact)      # mc_s is a subset of s: exact values
        assert np.isin(curve.mc_s, curve.s).all()
        se = np.sqrt(np.maximum(exact * (1 - exact), 1 / curve.n_samples) / curve.n_samples)
        assert (np.abs(curve.mc_p - exact) <= 5 * se + curve.bound.max()).all(), (curve.output, curve.mc_p, exact)
        assert np.all(np.diff(curve.exact) <= curve.bound.max() * 2)          # P(> s) falls with s
        assert curve.spec in curve.s


def _section(html: str, title: str) -> str:
    match = re.search(r"<h2>\d+\. " + title + r"</h2>(.*?)<h2>", html, re.S)
    assert match, title
    return match.group(1)


@pytest.mark.slow
@LOOSE
def test_first_screen_answers_against_the_spec(written):
    study, result, out = written
    html = (out / "report.html").read_text(encoding="utf-8")
    summary = json.loads((out / "summary.json").read_text())["configurations"]["u-shape"]
    first = _section(html, "At a glance")
    assert html.index("At a glance") < html.index("Summary</h2>")        # the first section
    doc = summary["yield"]
    ppm = doc["exceed_position_ppm"]["max"]
    shown = f"{ppm:.0f}" if ppm >= 100 else f"{ppm:.3g}"
    bound = doc["error_bounds_ppm"]["position"]                           # the bound, with its unit
    assert f"P(position &gt; 100 µm), max" in first and f"{shown} ± {bound:.2g} ppm" in first
    assert "Ppk, min" in first and "region above 1 ppm" in first and "P(|δφ| &gt; 120 arcsec), max" in first
    assert "%.1f" % summary["worst_case_position_um"]["max"] in first                    # the worst case
    assert "Monte Carlo p99.73 position (µm)" in first
    assert "dominant by Sobol ST" in first and "dominant by worst-case share" in first
    # how conservative is each: worst case vs RSS vs Monte Carlo vs exact quantile, side by side
    for head in ("worst case (µm)", "RSS (µm)", "Monte Carlo p99.73 (µm)", "exact p99.73 (µm)"):
        assert f"<th>{head}</th>" in first
    assert "%.1f" % doc["quantiles_position_um"]["p99.73"]["max"] in first
    alts = read(first).alts
    assert "pareto_u-shape" in alts and "exceedance_u-shape_position" in alts and "exceedance_u-shape_phi" in alts
    # the contributions table: largest share first, units in the column names, no unitless value column
    contributions = pd.read_csv(out / "tables" / "contributions_u-shape.csv")
    assert "term_value" not in contributions and {"term_value_mm", "term_value_deg", "contribution_mm"} <= set(
        contributions)
    assert contributions["share"].is_monotonic_decreasing
    assert "<th>value (µm)</th>" in html and "<th>value (arcsec)</th>" in html and "<th>value</th>" not in html
    assert missing_files(html, out) == [] and figures_without_files(html, out, "png") == []


def test_correlated_uniform_budget_falls_back_on_monte_carlo_and_says_so(tmp_path):
    """Correlated inputs that are not all normal: no exact series; the Monte Carlo run counts every exceedance
    (position, |dphi|, either) with its Wilson interval, and the summary's correlation section says which."""
    from prp3mc.study.summary import build_summary

    (tmp_path / "corr.toml").write_text('name = "corr"\n[inputs]\n'
                                        + "".join(f'b_{i} = {{ law = "uniform", lo = 0, hi = 0.025 }}\n'
                                                  for i in (1, 2, 3))
                                        + '[correlation]\n"b_1,b_2" = 0.5\n')
    text = _text("[spec]\nposition_um = 30\nphi_arcsec = 20\n").replace('budget = "paper"', 'budget = "corr.toml"')
    study = Study.from_text(text, source=str(tmp_path / "s.toml"), base=tmp_path)
    with pytest.warns(Warning, match="no exact yield for u-shape: budget 'corr' correlates inputs whose law is not "
                                     "normal: b_1 .uniform., b_2 .uniform.; .* P.either. instead"):
        result = run_study(study, progress=False)
    c = result["u-shape"]
    mc = c.montecarlo
    assert c.yield_ is None and c.curves == () and mc.tolerance_mm == pytest.approx(0.03)
    assert mc.tolerance_phi_deg == pytest.approx(20 / 3600)
    assert np.all(mc.exceed_any_prob >= np.maximum(mc.exceed_prob, mc.exceed_phi_prob))
    doc = build_summary(result)
    exceed = doc["configurations"]["u-shape"]["montecarlo"]["exceed"]
    assert exceed["tolerance_phi_arcsec"] == pytest.approx(20.0)
    assert {"phi_probability", "any_probability"} <= set(exceed)
    how = doc["correlation"]["analyses"]["yield"]
    assert how["respects"] and "no exact series" in how["how"] and "Wilson" in how["how"]


def test_a_budget_without_a_density_counts_every_channel_of_its_spec(tmp_path):
    """One leg random (a disc clearance): the exact series has no density to invert (NoExactYieldError, known
    only by trying); the study warns and, with a phi spec, the Monte Carlo run counts P(position > S),
    P(|dphi| > Z) and P(either), as for a correlated budget: summary.json (montecarlo.exceed), the tables and the
    report carry them, and each equals the count over the run's own draws. The study used to stop with the
    one-line error, then counted position alone."""
    from prp3mc.model.budget import Budget
    from prp3mc.model.laws import Disc, Uniform
    from prp3mc.model.linear import linear_model
    from prp3mc.study.summary import build_summary
    from prp3mc.units import RAD2DEG

    Budget({"rho_1": Disc(0.01), "zeta_1": Uniform(0.0, 360.0)}, name="disc alone").to_toml(tmp_path / "alone.toml")
    text = _text("[spec]\nposition_um = 5\nphi_arcsec = 5\n").replace('budget = "paper"', 'budget = "alone.toml"')
    with pytest.warns(Warning, match="no law for rho_2"):
        study = Study.from_text(text, source=str(tmp_path / "s.toml"), base=tmp_path)
    with pytest.warns(Warning, match=r"no exact yield for u-shape: .*no density.*the Monte Carlo run counts "
                                     r"P\(position > spec\), P\(\|dphi\| > spec\) and P\(either\)"):
        result = run_study(study, progress=False)
    c = result["u-shape"]
    mc = c.montecarlo
    assert c.yield_ is None and c.curves == ()
    assert mc.tolerance_mm == pytest.approx(0.005) and mc.tolerance_phi_deg == pytest.approx(5 / 3600)
    err = linear_model(c.configuration.geometry, study.budget, mc.poses.reshape(-1, 3)).evaluate(
        study.budget.sample(mc.n_samples, result.montecarlo_seed))              # (P, n, 3) mm, mm, rad
    pos, phi = np.hypot(err[..., 0], err[..., 1]) > 0.005, np.abs(err[..., 2]) * RAD2DEG > 5 / 3600
    for p, counted in ((mc.exceed_prob, pos), (mc.exceed_phi_prob, phi), (mc.exceed_any_prob, pos | phi)):
        np.testing.assert_allclose(p.reshape(-1), counted.mean(axis=1))
    assert 0 < mc.exceed_phi_prob.min() and mc.exceed_phi_prob.max() < 1 and 0 < mc.exceed_prob.max()   # both bite
    assert np.any(mc.exceed_any_prob != mc.exceed_prob)          # either is not the position alone
    exceed = build_summary(result)["configurations"]["u-shape"]["montecarlo"]["exceed"]
    assert exceed["tolerance_phi_arcsec"] == pytest.approx(5.0)
    assert {"probability", "phi_probability", "any_probability"} <= set(exceed)
    assert "yield" not in build_summary(result)["configurations"]["u-shape"]
    write_study(result, tmp_path / "out")                  # the tables and the report carry every channel too
    table = pd.read_csv(tmp_path / "out" / "tables" / "summary.csv").query("analysis == 'montecarlo'")
    for output, statistic, p in (("position", "exceed_0.005mm", mc.exceed_prob),
                                 ("phi", "exceed_5arcsec", mc.exceed_phi_prob),
                                 ("any", "exceed_0.005mm_or_5arcsec", mc.exceed_any_prob)):
        row = table.query(f"output == '{output}' and statistic == '{statistic}' and aggregate == 'max'")
        assert row["value"].tolist() == pytest.approx([p.max()])
    html = (tmp_path / "out" / "report.html").read_text()
    assert "P(&gt; 5 arcsec)" in html and "P(&gt; 0.005 mm or 5 arcsec)" in html
    assert missing_files(html, tmp_path / "out") == [] and figures_without_files(html, tmp_path / "out", "png") == []


@pytest.mark.slow
def test_correlated_normal_budget_gets_the_exact_yield(tmp_path):
    """Correlated inputs that are all normal: the exact series runs (no warning) and the summary says so."""
    import warnings

    from prp3mc.study.summary import build_summary

    (tmp_path / "corr.toml").write_text('name = "corr"\n[inputs]\n'
                                        + "".join(f'b_{i} = {{ law = "normal", mu = 0, sd = 0.006 }}\n'
                                                  for i in (1, 2, 3))
                                        + '[correlation]\n"b_1,b_2" = 0.5\n')
    text = (_text("[spec]\nposition_um = 20\n").replace('budget = "paper"', 'budget = "corr.toml"')
            .replace("grid = 5", "grid = 5\nk_sigma = 3"))           # normal laws: the worst case needs k_sigma
    study = Study.from_text(text, source=str(tmp_path / "s.toml"), base=tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = run_study(study, progress=False)
    c = result["u-shape"]
    assert c.yield_ is not None and "jointly normal" in c.yield_.method
    direct = exact_yield("u-shape", study.budget, c.yield_.poses, spec_position_um=20.0)
    np.testing.assert_array_equal(c.yield_.exceed_position, direct.exceed_position)
    how = build_summary(result)["correlation"]["analyses"]["yield"]
    assert how["respects"] and how["how"].startswith("exact")


def test_a_spec_beyond_the_worst_case_runs_and_yields_zero(tmp_path):
    """position_um = 1e5 (the worst case is ~150 µm): the study ran into "more than 2^23 terms"; now every
    pose's exceedance is 0 with bound 0, and the quantiles equal those of a spec inside the support."""
    study = Study.from_text(_text("[spec]\nposition_um = 1e5\nphi_arcsec = 1e5\n"), source=str(tmp_path / "s.toml"))
    c = run_study(study, progress=False)["u-shape"]
    for output in ("position", "phi", "any"):
        assert np.all(c.yield_.exceedance(output) == 0.0) and np.all(c.yield_.bound(output) == 0.0)
    inside = exact_yield("u-shape", study.budget, c.yield_.poses, spec_position_um=100.0,
                         quantiles=c.yield_.quantile_position_mm is not None)
    if inside.quantile_position_mm is not None:
        np.testing.assert_array_equal(c.yield_.quantile_position_mm, inside.quantile_position_mm)
