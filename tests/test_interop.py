"""Budgets handed to SALib's other methods and to OpenTURNS; results to xarray."""

import numpy as np
import pytest
from SALib.analyze import delta, fast, morris
from SALib.sample import fast_sampler, latin
from SALib.sample import morris as morris_sampler

from prp3mc import Budget, Disc, Discrete, Geometry, Region, Triangular, TruncNormal, linear_model, worst_case
from prp3mc.model.interop import openturns_distribution, salib_model, salib_problem, to_xarray

PAPER = Budget.from_preset("paper")
POSE = np.array([10.0, 100.0, 0.0])


def exact_first_order(geometry, budget, pose, output_row=0):
    """S1 of every non-clearance input of dx: c_k^2 var_k / V (the model is linear in them)."""
    model = linear_model(geometry, budget, pose)
    V = model.moments()[1][output_row, output_row]
    cols = model.columns[output_row] * (180 / np.pi if output_row == 2 else 1.0)
    return {t: cols[k] ** 2 * budget.inputs[t].var / V for k, t in enumerate(model.terms) if not t.startswith("rho")}


def test_fast_matches_the_closed_form(seed):
    """FAST runs on the budget and recovers the closed-form first-order shares."""
    g = Geometry.from_preset("u-shape")
    problem, f = salib_problem(PAPER), salib_model(g, PAPER, POSE, "x")
    truth = exact_first_order(g, PAPER, POSE)
    X = fast_sampler.sample(problem, 4000, seed=seed % 2**32)
    with pytest.warns(UserWarning):            # SALib warns that FAST's bootstrap intervals are indicative
        s1 = dict(zip(problem["names"], fast.analyze(problem, f(X), seed=seed % 2**32 + 1)["S1"]))
    for name, value in truth.items():
        assert abs(s1[name] - value) < 0.03, (name, s1[name], value)


@pytest.mark.slow
def test_delta_matches_the_closed_form(seed):
    """The delta moment-independent method's S1 on the budget agrees with the closed form (SALib's KDE: slow)."""
    g = Geometry.from_preset("u-shape")
    problem, f = salib_problem(PAPER), salib_model(g, PAPER, POSE, "x")
    truth = exact_first_order(g, PAPER, POSE)
    X = latin.sample(problem, 1000, seed=seed % 2**32)
    d = delta.analyze(problem, X, f(X), seed=seed % 2**32 + 1, num_resamples=10)
    s1 = dict(zip(problem["names"], d["S1"]))
    conf = dict(zip(problem["names"], d["S1_conf"]))
    for name, value in truth.items():
        assert abs(s1[name] - value) < 0.03 + 4 * conf[name], (name, s1[name], value)


def test_morris_ranks_the_dominant_input_first(seed):
    """For a linear output, mu* of a uniform input is |c_k| (hi - lo): its order is the closed form's."""
    g = Geometry.from_preset("delta-shape")
    problem, f = salib_problem(PAPER), salib_model(g, PAPER, [0.0, 160.0, 0.0], "x")
    X = morris_sampler.sample(problem, 100, num_levels=8, seed=seed % 2**32)
    mu_star = dict(zip(problem["names"], morris.analyze(problem, X, f(X), num_levels=8, seed=1)["mu_star"]))
    truth = exact_first_order(g, PAPER, [0.0, 160.0, 0.0])
    top, second = sorted(truth, key=truth.get, reverse=True)[:2]
    assert truth[top] > 2 * truth[second]
    assert max(mu_star, key=mu_star.get) == top


def test_openturns_marginals_are_the_laws():
    ot = pytest.importorskip("openturns")
    budget = PAPER.replace(rho_1=Disc(0.016), theta_2=Triangular(-0.01, 0.03, 0.04),
                           b_3=Discrete((0.0, 0.01, 0.02), (0.6, 0.3, 0.1)), theta_3=TruncNormal(0.0, 0.04, 1.0))
    dist = openturns_distribution(budget)
    assert list(dist.getDescription()) == list(budget.names)
    for k, (name, law) in enumerate(budget.inputs.items()):
        m = dist.getMarginal(k)
        assert m.getMean()[0] == pytest.approx(law.mean, rel=1e-9, abs=1e-12), name
        assert m.getStandardDeviation()[0] ** 2 == pytest.approx(law.var, rel=1e-6, abs=1e-15), name
        if not isinstance(law, Discrete):
            for u in (0.1, 0.5, 0.9):
                assert m.computeQuantile(u)[0] == pytest.approx(float(law.ppf(u)), rel=1e-6, abs=1e-12), name
    assert isinstance(dist, (getattr(ot, "JointDistribution", ot.Distribution), ot.Distribution))


def test_grid_results_convert_to_xarray():
    pytest.importorskip("xarray")
    grid = Region.from_preset("u-shape").grid(5)                     # (5, 5, 3)
    wc = worst_case(Geometry.from_preset("u-shape"), PAPER, grid)
    field = to_xarray(wc)["value"].sel(output="position", statistic="worst_case", phi_deg=0.0)
    assert field.shape == (5, 5)
    for pose, value in zip(grid.reshape(-1, 3), wc.position_mm.reshape(-1)):
        assert field.sel(x_mm=pose[0], y_mm=pose[1]).item() == value
