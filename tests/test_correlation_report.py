"""A correlated budget in a study's summary and report (issue 27 point 4): the correlation recorded with what each
analysis made of it, the ranking by Shapley effects, and the heat-map of the rank correlations."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from prp3mc.cli import main
from prp3mc.errors import Prp3mcWarning
from prp3mc.model.budget import Budget
from prp3mc.study.reader import Study
from prp3mc.study.runner import run_study
from prp3mc.study.summary import build_summary

EXAMPLE = Study.load("correlated_example")


def _tiny(outputs=()) -> Study:
    """The bundled correlated study on a 3 x 3 worst-case grid, with ``outputs`` at small sizes."""
    return dataclasses.replace(EXAMPLE, outputs=tuple(outputs), worstcase_grid=(3, 3), mc_grid=(2, 2),
                               mc_samples=4096, sobol_grid=(1, 1), sobol_samples=256)


def test_summary_records_the_table_and_the_pairs_it_realised(seed):
    """Every pair the table correlates (groups expanded) is listed; its realised rank correlation (the inputs are
    continuous) lies within 5 Fieller standard errors of the one asked, for any seed."""
    result = run_study(_tiny(["montecarlo"]), rng=seed, progress=False)
    doc = build_summary(result)
    c, budget = doc["correlation"], EXAMPLE.budget
    assert c["table"] == dict(budget.correlation) == doc["inputs"]["budget"]["correlation"]
    assert c["realised_from"] == {"samples": 4096}
    # bearings, guides, encoders: 3 pairs each, and "guides,b_1": every guide with b_1
    assert len(c["pairs"]) == 12
    z_se = np.sqrt(1.06 / (4096 - 3))
    for p in c["pairs"]:
        assert p["latent"] == pytest.approx(2 * np.sin(np.pi * p["spearman"] / 6))
        r = p["realised"]["value"]
        assert abs(np.arctanh(r) - np.arctanh(p["spearman"])) <= 5 * z_se, p
        assert p["realised"]["se"] == pytest.approx((1 - r * r) * z_se)
    assert {p["spearman"] for p in c["pairs"] if set(p["inputs"]) <= {"rho_1", "rho_2", "rho_3"}} == {0.8}


def test_summary_says_which_analyses_respected_it():
    wc_only = build_summary(run_study(_tiny(), rng=1, progress=False))["correlation"]["analyses"]
    assert list(wc_only) == ["worst_case"] and wc_only["worst_case"]["respects"] is False
    assert "box" in wc_only["worst_case"]["how"]
    with pytest.warns(Prp3mcWarning, match="correlates some inputs"):
        result = run_study(_tiny(["montecarlo", "sobol"]), rng=1, progress=False)
    every = build_summary(result)["correlation"]["analyses"]
    assert {k: v["respects"] for k, v in every.items()} == {"worst_case": False, "montecarlo": True, "shapley": True,
                                                            "sobol": False}
    assert every["sobol"]["how"].startswith("not defined")


def test_independent_budget_has_no_correlation_entry():
    study = dataclasses.replace(_tiny(), budget=Budget(EXAMPLE.budget.inputs))
    doc = build_summary(run_study(study, rng=1, progress=False))
    assert "correlation" not in doc and "correlation" not in doc["inputs"]["budget"]


def test_heatmap_order_keeps_groups_together_and_draws_every_correlation():
    from prp3mc.reports.canvas import agg_figure
    from prp3mc.reports.plots import correlation_heatmap
    from prp3mc.reports.study_report import correlation_order
    budget = EXAMPLE.budget
    order = correlation_order(budget)
    assert order == ["rho_1", "rho_2", "rho_3", "theta_1", "theta_2", "theta_3", "b_1", "b_2", "b_3"]
    at = [budget.copula.names.index(n) for n in order]
    matrix = budget.copula.spearman[np.ix_(at, at)]
    fig = correlation_heatmap(order, matrix, "t", fig=agg_figure())
    ax, bar = fig.axes
    image = ax.images[0]
    assert (image.norm.vmin, image.norm.vmax) == (-1.0, 1.0)             # centred at 0
    assert image.get_cmap().name == "RdBu_r"                                # diverging
    assert [t.get_text() for t in ax.get_yticklabels()] == order == [t.get_text() for t in ax.get_xticklabels()]
    labels = [t.get_text() for t in ax.texts]
    assert len(labels) == np.count_nonzero(matrix)                          # every correlation labelled, 0 left blank
    assert labels.count("−0.20") == 6 and labels.count("1") == len(order)
    assert "Spearman" in bar.get_ylabel()


@pytest.mark.slow
def test_correlated_study_report(tmp_path, capsys):
    """The report of the bundled correlated study: ranking by Shapley effects (and why), the heat-map with its
    caption, the table of analyses, the correlation in the Run section; the budget's warning once."""
    out = tmp_path / "corr"
    assert main(["study", "correlated_example", "--quick", "--seed", "1", "--no-progress", "--out", str(out)]) == 0
    assert capsys.readouterr().err.count("the budget correlates some inputs") == 1
    html = (out / "report.html").read_text(encoding="utf-8")
    doc = json.loads((out / "summary.json").read_text())
    assert len(doc["warnings"]) == 1
    assert "Sensitivity: Shapley effects</h2>" in html and "Sobol sensitivity</h2>" not in html
    assert "so Sobol indices are not defined" in html and "dominant by Shapley effect" in html
    assert "(Sh 0." in html                                                  # the dominant input's Shapley effect
    assert "Shapley effects (the budget correlates inputs): 512 random orders of the inputs on a 3 × 3 grid" in html
    assert 'alt="correlation"' in html and (out / "figures" / "correlation.png").is_file()
    assert "Spearman (rank) correlation" in html and "Gaussian copula realises it" in html
    assert html.index("Dependent inputs</h2>") < html.index('alt="correlation"') < html.index("Budget</h2>")
    assert "unchanged, a box. The worst case is the maximum over the box" in html
    assert "rank correlations\n<code>bearings</code> = 0.8" in html          # the Run section
    table = (out / "tables" / "correlation.csv").read_text().splitlines()
    assert table[0] == "input_a,input_b,spearman,latent,realised,realised_se" and len(table) == 13


def test_discrepancy_warning_measures_what_the_fit_leaves_out(seed):
    """The warning's figures (largest relative change of the sd of the position error and of phi at the poses) are
    those of Monte Carlo draws of the correlated and of the independent budget, within their sampling error."""
    import re

    from prp3mc.measurement.discrepancy.workflow import correlation_warning
    from prp3mc.kinematics.geometry import Geometry
    from prp3mc.model.linear import linear_model
    geometry, budget = Geometry.from_preset("u-shape"), EXAMPLE.budget
    poses = np.array([[-30.0, 70.0, 0.0], [0.0, 100.0, 2.0], [30.0, 130.0, -2.0]])
    message = correlation_warning(geometry, budget, poses)
    position, phi = map(float, re.findall(r"by up to (\d+) %", message))
    n = 40_000
    sds = []
    for b in (budget, Budget(budget.inputs)):
        err = linear_model(geometry, b, poses).evaluate(b.sample(n, seed))          # (P, n, 3)
        sds.append((np.sqrt(err[..., 0].var(1) + err[..., 1].var(1)), err[..., 2].std(1)))
    for k, shown in enumerate((position, phi)):
        change = 100 * np.max(np.abs(sds[0][k] / sds[1][k] - 1))
        assert abs(change - shown) <= 0.5 + 100 * 6 * np.sqrt(2 / n) * (1 + change / 100), (k, change, shown)
    assert "takes them as independent" in message and "one-batch" in message


def test_python_discrepancy_warns_of_a_correlated_budget(monkeypatch):
    """``prp3mc.discrepancy`` itself warns (not only the CLI), before the fit, and only for a correlated budget;
    the fit is stopped at its first step (the warning is what is tested)."""
    import warnings

    from prp3mc.kinematics.geometry import Geometry
    from prp3mc.measurement.discrepancy import workflow
    from prp3mc.study.reader import STUDIES_DIR

    class Stop(Exception):
        pass

    def stop(*args, **kwargs):
        raise Stop

    monkeypatch.setattr(workflow, "identify", stop)
    geometry = Geometry.from_preset("u-shape")
    correlated = Budget.load(str(STUDIES_DIR / "budgets" / "one_batch.toml"))
    with pytest.warns(Prp3mcWarning, match="one-batch.*the discrepancy fit takes them as independent"), \
            pytest.raises(Stop):
        workflow.discrepancy(geometry, correlated, "example", instrument_sigma_mm=0.002, instrument_sigma_deg=0.0005)
    with warnings.catch_warnings():
        warnings.simplefilter("error", Prp3mcWarning)
        with pytest.raises(Stop):
            workflow.discrepancy(geometry, Budget(correlated.inputs), "example", instrument_sigma_mm=0.002,
                                 instrument_sigma_deg=0.0005)


@pytest.mark.slow
def test_discrepancy_of_a_correlated_budget_warns_once(tmp_path, capsys):
    from prp3mc.study.reader import STUDIES_DIR
    out = tmp_path / "d"
    assert main(["discrepancy", "--geometry", "u-shape", "--budget", str(STUDIES_DIR / "budgets" / "one_batch.toml"),
                 "--data", "example", "--instrument-sigma-mm", "0.002", "--instrument-sigma-deg", "0.0005",
                 "--seed", "1", "--no-progress", "--out", str(out)]) == 0
    assert capsys.readouterr().err.count("the discrepancy fit takes them as independent") == 1
    doc = json.loads((out / "discrepancy.json").read_text())
    assert sum("takes them as independent" in w for w in doc["warnings"]) == 1
    assert "[correlation]" in (out / "model" / "budget.toml").read_text()
