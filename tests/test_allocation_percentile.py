"""The allocation's percentile spec: decided on the exact distribution, against brute force; correlated budgets."""

import itertools

import numpy as np
import pytest

from prp3mc import Budget, Geometry, allocate, exact_yield
from prp3mc._rng import child_seed
from prp3mc.allocation.classes import ClassMenu
from prp3mc.allocation.optimum import region_poses
from prp3mc.allocation.percentile import PercentileCheck
from prp3mc.allocation.search import Problem, least_cost
from prp3mc.errors import AllocationError
from prp3mc.model.laws import Uniform
from prp3mc.montecarlo.propagation import monte_carlo

Q = 99.73
ALPHA = 1 - Q / 100


def small_menu(normal: bool = False) -> ClassMenu:
    """Two families of two classes (64 choices). ``normal``: the cheap encoder class is a normal law, bounded
    at 2 sd for the worst case that caps the normal screen (which then accepts choices that fail)."""
    cheap_b = ({"name": "normal", "law": "normal", "mu": 0.0, "sd": 0.004, "cost": 1.1} if normal else
               {"name": "coarse", "law": "uniform", "lo": -0.008, "hi": 0.008, "cost": 1.1})
    return ClassMenu.from_dict({
        "theta": {"classes": [{"name": "fine", "law": "uniform", "lo": -0.005, "hi": 0.005, "cost": 7.0},
                              {"name": "coarse", "law": "uniform", "lo": -0.02, "hi": 0.02, "cost": 2.0}]},
        "b": {"classes": [{"name": "fine", "law": "uniform", "lo": -0.002, "hi": 0.002, "cost": 5.3}, cheap_b]}},
        source="small menu")


def brute_force(geometry, menu, poses, spec_um):
    """Every choice (C, J), its cost and whether it meets p{Q} <= spec at every pose, by the exact engine."""
    choices = np.array(list(itertools.product(*[range(len(menu.classes_of(n))) for n in menu.inputs])))
    costs, met = [], []
    for ch in choices:
        budget = menu.budget({n: menu.classes_of(n)[m].name for n, m in zip(menu.inputs, ch)})
        r = exact_yield(geometry, budget, poses, spec_position_um=spec_um, quantiles=False, target=1e-5)
        costs.append(sum(menu.classes_of(n)[m].cost for n, m in zip(menu.inputs, ch)))
        met.append(float(np.max(r.exceed_position + r.bound_position)) <= ALPHA)
    return choices, np.array(costs), np.array(met)


def _exact_against_brute_force(preset, normal, spec_um):
    """The allocation against the brute-force optimum; the old normal screen's choice as the brute force judges it."""
    geometry, menu = Geometry.from_preset(preset), small_menu(normal)
    poses = region_poses(preset, 2)
    k_sigma = 2.0 if normal else None
    choices, costs, met = brute_force(geometry, menu, poses, spec_um)
    r = allocate(geometry, menu, poses, spec_position_um=spec_um, spec_percentile=Q, n_samples=4000, rng=1,
                 k_sigma=k_sigma)
    assert r.feasible and r.statistical["method"] == "exact" and r.statistical["proven"]
    assert r.cost == pytest.approx(costs[met].min(), rel=1e-12)
    assert r.statistical["exceedance"] <= ALPHA
    problem = Problem(geometry, menu, poses, percentile=Q, k_sigma=k_sigma)
    old, _ = least_cost(problem, {"screen": spec_um / 1e3})
    k = int(np.flatnonzero((choices == old).all(axis=1))[0])
    return r, costs[k], bool(met[k])


def test_exact_screen_finds_the_brute_force_optimum_where_the_normal_screen_is_loose():
    r, old_cost, old_met = _exact_against_brute_force("u-shape", False, 40.1)
    assert old_met and old_cost > r.cost      # the normal screen rejected the optimum: its choice cost more


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
@pytest.mark.parametrize("normal", [False, True])
def test_exact_screen_equals_brute_force_over_specs(preset, normal):
    loose = 0
    for spec_um in (20.0, 30.0, 40.0, 50.0, 60.0):
        r, old_cost, old_met = _exact_against_brute_force(preset, normal, spec_um)
        loose += old_cost != r.cost
        assert old_cost >= r.cost or not old_met  # the screen's choice is never cheaper and feasible
    assert loose >= 1


def test_percentile_check_decides_as_the_exact_engine_with_its_bound():
    geometry, menu = Geometry.from_preset("u-shape"), small_menu()
    poses = region_poses("u-shape", 2)
    problem = Problem(geometry, menu, poses, percentile=Q)
    check = PercentileCheck(geometry, problem, 0.040, Q, 2000, 0)
    idx = np.array([1, 1, 1, 0, 0, 0])
    rec = check.record(idx)
    budget = problem.budget({n: problem.class_name(j, m) for j, (n, m) in enumerate(zip(problem.inputs, idx))})
    r = exact_yield(geometry, budget, poses, spec_position_um=40.0, quantiles=False, target=1e-7)
    assert rec["met"] == bool(np.max(r.exceed_position) <= ALPHA)
    assert rec["value"] == pytest.approx(float(np.max(r.exceed_position)), abs=2 * ALPHA * 1e-3)
    assert check.record(idx) is rec and check.checks == 1                  # decided once


def test_a_choice_met_where_earlier_choices_failed_is_still_decided_at_every_pose():
    """The check tries first the poses that refused earlier choices (to refuse sooner): a choice that meets
    the spec there but fails at another pose of the grid is refused, at that pose."""
    geometry, menu = Geometry.from_preset("u-shape"), small_menu()
    poses = region_poses("u-shape", 2)
    problem = Problem(geometry, menu, poses, percentile=Q)
    check = PercentileCheck(geometry, problem, 0.030, Q, 2000, 0)
    first, second = np.array([1, 0, 0, 0, 0, 1]), np.array([0, 1, 0, 0, 0, 1])
    high = {}
    for idx in (first, second):
        budget = problem.budget({n: problem.class_name(j, m) for j, (n, m) in enumerate(zip(problem.inputs, idx))})
        r = exact_yield(geometry, budget, poses, spec_position_um=30.0, quantiles=False, target=1e-7)
        high[tuple(idx)] = r.exceedance("position") + r.bound("position")
    fails = {key: np.flatnonzero(h > ALPHA) for key, h in high.items()}
    assert fails[tuple(first)].tolist() == [1] and fails[tuple(second)].tolist() == [0]   # the menu's premise
    assert high[tuple(second)][1] <= ALPHA
    assert check.record(first) == {"met": False, "value": pytest.approx(high[tuple(first)][1], rel=1e-3),
                                   "pose": 1, "method": "exact"}
    rec = check.record(second)                      # met at pose 1, which is tried first; fails at pose 0
    assert not rec["met"] and rec["pose"] == 0
    assert rec["value"] == pytest.approx(high[tuple(second)].max(), rel=1e-3)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_exact_choice_holds_by_a_large_monte_carlo(preset):
    """Independently of the engine: with 2e6 samples the chosen classes' exceedance interval reaches down to
    1 - q at every pose, and every cheaper choice's interval lies above it at some pose where the margin allows."""
    geometry, menu = Geometry.from_preset(preset), small_menu()
    poses = region_poses(preset, 2)
    choices, costs, met = brute_force(geometry, menu, poses, 40.0)
    spec_um = 40.0
    r = allocate(geometry, menu, poses, spec_position_um=spec_um, spec_percentile=Q, n_samples=4000, rng=2)
    mc = monte_carlo(geometry, r.budget(), poses, 2_000_000, rng=5, tolerance_mm=spec_um / 1e3, percentiles=(50,))
    assert np.all(mc.exceed_ci[:, 0] <= ALPHA)
    for k in np.flatnonzero(costs < r.cost)[:8]:
        budget = menu.budget({n: menu.classes_of(n)[m].name for n, m in zip(menu.inputs, choices[k])})
        mc = monte_carlo(geometry, budget, poses, 2_000_000, rng=6, tolerance_mm=spec_um / 1e3, percentiles=(50,))
        assert not met[k] and np.any(mc.exceed_ci[:, 1] >= ALPHA)


# ---------------------------------------------------------------- correlated budgets
def _correlated(r: float) -> Budget:
    inputs = {f"b_{i}": Uniform(-0.001, 0.001) for i in (1, 2, 3)}
    return Budget(inputs, name="batch", correlation={"b_1,b_2": r, "b_1,b_3": r, "b_2,b_3": r})


def test_a_correlated_budget_is_decided_by_monte_carlo_with_its_copula():
    geometry = Geometry.from_preset("u-shape")
    menu = ClassMenu.from_dict({"b": {"classes": [{"name": "coarse", "law": "uniform", "lo": -0.02, "hi": 0.02,
                                                   "cost": 1.0}]},
                                "theta": {"classes": [{"name": "fine", "law": "uniform", "lo": -0.002,
                                                       "hi": 0.002, "cost": 1.0}]}}, source="one choice")
    poses = np.array([[0.0, 140.0, 0.0]])
    independent = exact_yield(geometry, menu.budget({"b_1": "coarse", "b_2": "coarse", "b_3": "coarse",
                                                     "theta_1": "fine", "theta_2": "fine", "theta_3": "fine"}),
                              poses, spec_position_um=1.0, quantiles=True).quantile_position_mm[0, 0]
    fixed = _correlated(0.95)
    budget = menu.budget({n: menu.classes_of(n)[0].name for n in menu.inputs}, fixed)
    assert budget.correlated and dict(budget.correlation) == dict(fixed.correlation)
    correlated = monte_carlo(geometry, budget, poses, 200_000, rng=1, percentiles=(Q,)).position_pct[0, 0]
    assert abs(correlated / independent - 1) > 0.1                         # the copula matters here
    spec_um = 1e3 * 0.5 * (independent + correlated)                        # between the two
    r = allocate(geometry, menu, poses, spec_position_um=spec_um, spec_percentile=Q, n_samples=50_000, rng=3,
                 budget=fixed)
    ind = allocate(geometry, menu, poses, spec_position_um=spec_um, spec_percentile=Q, n_samples=50_000, rng=3)
    assert r.statistical["method"] == "monte_carlo" and ind.statistical["method"] == "exact"
    assert r.budget().correlated and r.to_dict()["statistical"]["method"].startswith("Monte Carlo")
    assert ind.feasible != r.feasible                                       # the copula, not ignored, decides
    assert r.feasible == (correlated <= independent) and r.statistical["confirmed"]


def test_a_correlation_naming_an_input_the_classes_lack_is_refused_in_one_line():
    fixed = Budget({"a_1": Uniform(-0.01, 0.01), "a_2": Uniform(-0.01, 0.01)}, name="frame",
                   correlation={"a_1,a_2": 0.5})
    with pytest.raises(AllocationError, match="cannot take budget 'frame'"):
        allocate("u-shape", "example", "u-shape", spec_position_um=40.0, spec_percentile=Q, grid=3, budget=fixed)


@pytest.mark.slow   # the engine takes ~1 min to find that its series would need more than 2^23 terms
def test_a_choice_the_exact_engine_cannot_serve_is_decided_by_monte_carlo():
    """A leg whose only laws are a narrow uniform and a discrete slip: the series cannot converge in budget."""
    menu = ClassMenu.from_dict({
        "theta": {"classes": [{"name": "fine", "law": "uniform", "lo": -0.005, "hi": 0.005, "cost": 7.0}]},
        "b": {"classes": [{"name": "slip", "law": "discrete", "values": [-0.012, 0.0, 0.012],
                           "weights": [0.004, 0.992, 0.004], "cost": 1.1}]}}, source="slip")
    geometry, poses = Geometry.from_preset("u-shape"), region_poses("u-shape", 2)
    problem = Problem(geometry, menu, poses, percentile=Q)
    rec = PercentileCheck(geometry, problem, 0.020, Q, 20_000, 1).record(np.zeros(6, dtype=int))
    mc = monte_carlo(geometry, problem.budget({n: menu.classes_of(n)[0].name for n in menu.inputs}), poses,
                     20_000, rng=child_seed(1, 1001), percentiles=(Q,))    # the check's first stream
    assert rec["method"] == "monte_carlo" and rec["value"] == float(mc.position_pct_ci[:, 0, 1].max())
    assert rec["met"] == (rec["value"] <= 0.020)
