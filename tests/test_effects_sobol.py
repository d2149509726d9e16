"""Sobol indices and the ranking of a budget with [effects]: backlash_i and thermal are factors,
known shifts have no variance share but move the position error's indices."""

import itertools

import numpy as np
import pytest

from prp3mc import Budget, Geometry, Uniform, linear_model, worst_case
from prp3mc.errors import BudgetError
from prp3mc.sobol.ranking import ranking
from prp3mc.sobol.indices import sobol_indices
from prp3mc.sobol.closed_form import analytic_indices
from prp3mc.model.effects import SystematicEffect

from .conftest import random_poses

KEYS = ["x_mm", "y_mm", "phi_deg", "output", "name", "kind"]
TEMPS = (0.0, 40.0)


def effects_only(geometry, shifts=True):
    """One exact input (b_1 = 0), two backlashes and thermal; with ``shifts`` also an offset and a scale."""
    values = {"backlash_1": 0.02, "backlash_2": 0.01, "thermal": 1.2e-5}
    if shifts:
        values |= {"beta_3": 0.02, "scale_2": 3e-4}
    effects = {k: SystematicEffect(k, v, temp_range_C=TEMPS if k == "thermal" else None) for k, v in values.items()}
    return Budget({"b_1": Uniform(0.0, 0.0)}, name="effects").with_effects(effects, fitted_on=geometry)


def test_sobol_lists_backlash_and_thermal_and_matches_the_variance_shares(geometry, region):
    budget = effects_only(geometry)
    assert budget.factors == ("b_1", "backlash_1", "backlash_2", "thermal")
    poses = random_poses(region, 3, np.random.default_rng(1))
    groups = {"backlash": ["backlash_1", "backlash_2"]}
    r = sobol_indices(geometry, budget, poses, 8192, rng=5, groups=groups, outputs=("x", "y", "phi"))
    assert r.names == ("b_1", "backlash_1", "backlash_2", "thermal", "backlash")
    assert r.kinds == ("input", "effect", "effect", "effect", "group") and r.constant == ("b_1",)
    exact = analytic_indices(geometry, budget, poses, groups=groups)
    df = r.to_frame().merge(exact, on=KEYS, suffixes=("", "_exact"), validate="one_to_one")
    df = df[df["name"] != "b_1"]
    for key in ("S1", "ST"):
        err = (df[key] - df[f"{key}_exact"]).abs()
        assert err.max() < 0.02 and (err <= 2.5 * df[f"{key}_conf"] + 1e-9).all(), df.loc[err.idxmax()]
    # a linear output of independent factors: the first-order shares add up to 1
    sums = exact[exact["name"].isin(["backlash_1", "backlash_2", "thermal"])].groupby(KEYS[:4])["S1"].sum()
    np.testing.assert_allclose(sums, 1.0, rtol=1e-12)


def _position_indices(model, budget):
    """Exact S1 and ST of the position norm at every pose: signs enumerated, T by Gauss-Legendre."""
    names = ("backlash_1", "backlash_2", "thermal")
    h = [budget.effects[n].value / 2 for n in names[:2]]
    t, wt = np.polynomial.legendre.leggauss(200)
    temps, wt = TEMPS[0] + (t + 1) / 2 * (TEMPS[1] - TEMPS[0]), wt / 2
    grid = np.array([[0.0, s1 * h[0], s2 * h[1], T] for s1, s2 in itertools.product((-1, 1), repeat=2) for T in temps])
    E = model.evaluate(grid)                                             # (P, 4 * 200, 3)
    Y = np.hypot(E[..., 0], E[..., 1]).reshape(-1, 2, 2, len(temps))   # (P, s1, s2, T)
    w = np.full((2, 2, len(temps)), 0.25) * wt
    mean = (Y * w).sum((1, 2, 3))
    var = (Y**2 * w).sum((1, 2, 3)) - mean**2
    out = {}
    for k, ax in enumerate((1, 2, 3)):
        others = tuple(a for a in (1, 2, 3) if a != ax)
        w_ax = w.sum(tuple(a - 1 for a in others), keepdims=True)        # marginal law of factor k
        cond = (Y * w).sum(others, keepdims=True) / w_ax                  # E[Y | factor k]
        first = ((cond - mean[:, None, None, None]) ** 2 * w_ax).sum((1, 2, 3))
        rest = (Y * w).sum(ax, keepdims=True) / w.sum(ax - 1, keepdims=True)   # E[Y | all but factor k]
        total = ((Y - rest) ** 2 * w).sum((1, 2, 3))
        out[names[k]] = first / var, total / var
    return out


def test_position_indices_with_shifts_match_their_exact_values(geometry, region):
    """The norm is not linear: shifts move its indices; the estimates match exact integrals over the factors."""
    poses = random_poses(region, 2, np.random.default_rng(2))
    with_shift, without = effects_only(geometry), effects_only(geometry, shifts=False)
    estimates = {}
    for budget in (with_shift, without):
        r = sobol_indices(geometry, budget, poses, 8192, rng=9, outputs=("position",))
        exact = _position_indices(linear_model(geometry, budget, poses), budget)
        for name, (s1, st) in exact.items():
            k = r.names.index(name)
            for est, conf, truth in ((r.S1[:, 0, k], r.S1_conf[:, 0, k], s1), (r.ST[:, 0, k], r.ST_conf[:, 0, k], st)):
                assert np.all(np.abs(est - truth) <= 2.5 * conf + 0.01), (name, est, truth)
        estimates[budget is with_shift] = exact
    moved = max(abs(estimates[True][n][1] - estimates[False][n][1]).max() for n in estimates[True])
    assert moved > 0.05                                            # the shifts change the position indices


def test_ranking_shows_shifts_as_systematic_contributions(geometry, region):
    budget = effects_only(geometry)
    poses = random_poses(region, 3, np.random.default_rng(3))
    r = sobol_indices(geometry, budget, poses, 1024, rng=1)
    wc = worst_case(geometry, budget, poses)
    for index in (0, None):
        df = ranking(r, wc, "position", index=index)
        shifts = df[df["kind"] == "shift"]
        assert set(shifts["name"]) == {"offset_beta_3", "scale_2"}
        assert shifts[["S1", "ST"]].isna().all().all()
        assert set(df.loc[df["kind"] == "effect", "name"]) == {"backlash_1", "backlash_2", "thermal"}
    one = ranking(r, wc, "position", index=1).set_index("name")
    terms = wc.contributions_frame("position")
    terms = terms[(terms["x_mm"] == poses[1, 0]) & (terms["y_mm"] == poses[1, 1])].set_index("term")
    for name in ("offset_beta_3", "scale_2", "backlash_1", "thermal"):
        np.testing.assert_allclose(one.loc[name, "worst_case_contribution"], terms.loc[name, "contribution"])
    # every term's contribution is in exactly one row that is not a group: together they give the worst case
    rows = one[one["kind"].isin(["input", "effect", "shift"])]
    np.testing.assert_allclose(rows["worst_case_contribution"].fillna(0).sum(), wc.position_mm[1], rtol=1e-12)


def test_a_group_of_an_effect_the_budget_lacks_is_refused():
    g = Geometry.from_preset("u-shape")
    with pytest.raises(BudgetError, match="unknown input.*backlash_3"):
        sobol_indices(g, effects_only(g), [0, 100, 0], 64, rng=1, groups={"x": ["backlash_3"]})
