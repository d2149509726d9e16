"""A budget's [effects] in the analyses: the linear model against the exact chain, the exact
worst case against brute force, Monte Carlo against the closed-form shift, and the geometry check."""

import itertools

import numpy as np
import pytest

from prp3mc import Budget, Geometry, Region, Uniform, exact_pose_error, linear_model, monte_carlo, worst_case
from prp3mc.cli import main
from prp3mc.errors import BudgetError
from prp3mc.kinematics.chain import inverse_kinematics
from prp3mc.kinematics.sensitivity import sensitivity
from prp3mc.model.effects import SystematicEffect, offset_errors, slider_error
from prp3mc.worstcase.envelope import worst_case_maxima
from prp3mc.units import DEG2RAD, RAD2DEG

from .conftest import random_poses

N_SE = 5.0
#: Effects of every kind: offsets of several families (b_3 is the encoder zero), scale, backlash, thermal.
VALUES = {"a_1": 0.02, "beta_2": -0.01, "psi_3": 0.015, "b_3": 0.005, "theta_1": 0.008,
          "scale_2": 2e-4, "backlash_1": 0.02, "backlash_3": 0.01, "thermal": 1.2e-5}
TEMPS = (10.0, 40.0)


def effects(values=VALUES, temps=TEMPS):
    return {k: SystematicEffect(k, v, temp_range_C=temps if k == "thermal" else None) for k, v in values.items()}


def small_budget(geometry, values=VALUES):
    """theta_i and b_i uniform (the paper's play and least count), with the effects."""
    inputs = {f"theta_{i}": Uniform(-0.04, 0.04) for i in (1, 2, 3)}
    inputs.update({f"b_{i}": Uniform(0.0, 0.025) for i in (1, 2, 3)})
    return Budget(inputs, name="small").with_effects(effects(values), fitted_on=geometry)


def _factors(budget, direction, temp):
    """Factor samples (n, D): inputs at 0, backlash_i = dir_i h_i / 2, thermal = temp."""
    n = direction.shape[0]
    X = np.zeros((n, len(budget.factors)))
    for k, name in enumerate(budget.factors):
        if name.startswith("backlash_"):
            X[:, k] = 0.5 * budget.effects[name].value * direction[:, int(name[-1]) - 1]
        elif name == "thermal":
            X[:, k] = temp
    return X


def test_linear_model_agrees_with_the_exact_chain_to_linear_order(geometry, region):
    """Known drivers (approach directions, temperatures) through slider_error and offset_errors, exactly."""
    rng = np.random.default_rng(3)
    poses = random_poses(region, 4, rng)
    direction = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))          # (8, 3)
    temp = np.linspace(*TEMPS, 8)
    departure = []
    for scale in (1.0, 0.5):
        values = {k: scale * v for k, v in VALUES.items()}
        budget = small_budget(geometry, values)
        model = linear_model(geometry, budget, poses)
        linear = model.evaluate(_factors(budget, direction, temp))                 # (4, 8, 3)
        linear[..., 2] *= RAD2DEG
        b, _ = inverse_kinematics(geometry, poses)
        errors = offset_errors(values)                  # slider_error holds b_3, the encoder zero offset
        errors["b"] = np.stack([slider_error(values, np.broadcast_to(bp, (8, 3)), direction, temp) for bp in b])
        exact = exact_pose_error(geometry, np.broadcast_to(poses[:, None], (4, 8, 3)), errors)
        size = np.abs(linear).max()
        assert np.abs(exact - linear).max() < 0.01 * size
        departure.append(np.abs(exact - linear).max())
    assert 3.0 < departure[0] / departure[1] < 5.0           # second order: half the effects, a quarter the gap


def test_budget_errors_match_the_library_slider_errors(geometry, region):
    poses = random_poses(region, 3, np.random.default_rng(4))
    budget = small_budget(geometry)
    direction = np.array([[1.0, -1.0, 1.0], [-1.0, -1.0, 1.0]])
    temp = np.array([12.0, 33.0])
    b, _ = inverse_kinematics(geometry, poses)
    errors = budget.errors(_factors(budget, direction, temp), b=b)
    for p in range(3):
        expect = slider_error(VALUES, np.broadcast_to(b[p], (2, 3)), direction, temp)
        np.testing.assert_allclose(errors["b"][p], expect, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(errors["beta"], np.broadcast_to([0.0, -0.01, 0.0], (2, 3)))


def brute_force(model, budget, n_dense=20_000):
    """Max over every corner of the factor box (linear in each factor), and over dense random samples."""
    bounds = budget.bounds()
    corners = np.array(list(itertools.product(*bounds)))
    E = model.evaluate(corners)
    rng = np.random.default_rng(0)
    dense = model.evaluate(bounds[:, 0] + (bounds[:, 1] - bounds[:, 0]) * rng.random((n_dense, len(bounds))))
    out = {}
    for q, f in (("position", lambda e: np.hypot(e[..., 0], e[..., 1])), ("phi", lambda e: np.abs(e[..., 2]) * RAD2DEG),
                 ("x", lambda e: np.abs(e[..., 0])), ("y", lambda e: np.abs(e[..., 1]))):
        out[q] = f(E).max(-1), f(dense).max(-1)
    return out


def check_worst_case(geometry, budget, poses):
    """The exact worst case of ``budget`` at ``poses`` (P,) against brute force, the fused kernel, its maximiser
    and its contributions; returns it."""
    P = len(poses)
    wc = worst_case(geometry, budget, poses)
    model = linear_model(geometry, budget, poses)
    for q, (corner_max, dense_max) in brute_force(model, budget).items():
        np.testing.assert_allclose(wc.value(q), corner_max, rtol=1e-12)
        assert np.all(dense_max <= wc.value(q) * (1 + 1e-12))
    # the fused kernel on large grids gives the same maxima and signs
    mx = worst_case_maxima(geometry, budget, poses)
    for q in ("position", "phi", "x", "y"):
        np.testing.assert_allclose(mx.value(q), wc.value(q), rtol=1e-12)
        np.testing.assert_array_equal(mx.leg_signs[q], wc.leg_signs[q])
        np.testing.assert_array_equal(mx.shared_signs[q], wc.shared_signs[q])
    # the maximiser's factors realise the maximum, and the contributions (shifts included) sum to it
    for q in ("position", "x"):
        X = wc.inputs_at[q]
        e = np.einsum("pof,pf->po", model.coef, np.stack([model.features(X[p:p + 1])[0] for p in range(P)]))
        got = np.hypot(e[:, 0], e[:, 1]) if q == "position" else np.abs(e[:, 0])
        np.testing.assert_allclose(got, wc.value(q), rtol=1e-12)
        np.testing.assert_allclose(wc.contribution[q].sum(-1), wc.value(q), rtol=1e-12)
    return wc


@pytest.mark.parametrize("keep", [("backlash_1", "thermal"), tuple(VALUES)])
def test_worst_case_with_effects_equals_brute_force(geometry, region, keep):
    budget = small_budget(geometry, {k: VALUES[k] for k in keep})
    wc = check_worst_case(geometry, budget, random_poses(region, 5, np.random.default_rng(5)))
    assert wc.shared_signs["position"].shape == (5, int("thermal" in keep))


def test_worst_case_shows_shifts_as_contributions(geometry, region):
    budget = small_budget(geometry)
    wc = worst_case(geometry, budget, random_poses(region, 2, np.random.default_rng(6)))
    frame = wc.contributions_frame("position")
    assert {"offset_beta_2", "offset_b_3", "scale_2", "backlash_1", "thermal", "b_3"} <= set(frame["term"])
    shift = frame[frame["term"] == "offset_beta_2"]
    np.testing.assert_allclose(shift["term_value"], -0.01)
    assert wc.maximizer("position", 0)["thermal"] in TEMPS


def _shift(geometry, poses, values, temps):
    """Mean pose error of the effects from J_q directly: offsets, scales and thermal at its mean temperature."""
    s = sensitivity(geometry, poses)
    b, _ = inverse_kinematics(geometry, poses)
    out = np.zeros(poses.shape)
    for name, v in values.items():
        if name.startswith(("scale", "backlash", "thermal")):
            continue
        q, leg = name.rsplit("_", 1)
        out += s.J[q][..., :, int(leg) - 1] * v * (DEG2RAD if q in ("alpha", "beta", "gamma", "theta", "psi") else 1)
    db = np.zeros(b.shape)
    db[..., 1] += values.get("scale_2", 0.0) * b[..., 1]
    db += values.get("thermal", 0.0) * (np.mean(temps) - 20.0) * b
    out += np.einsum("...ij,...j->...i", s.J["b"], db)
    return out * np.array([1.0, 1.0, RAD2DEG])


def test_monte_carlo_mean_is_shifted_by_the_effects(geometry, region, seed):
    poses = random_poses(region, 4, np.random.default_rng(7))
    budget = small_budget(geometry)
    r = monte_carlo(geometry, budget, poses, 100_000, rng=seed)
    base = linear_model(geometry, budget.without_effects(), poses).moments()[0]
    truth = base + _shift(geometry, poses, VALUES, TEMPS)
    np.testing.assert_allclose(linear_model(geometry, budget, poses).moments()[0], truth, rtol=1e-9, atol=1e-15)
    assert np.all(np.abs(r.mean - truth) < N_SE * r.mean_se)
    # backlash and thermal widen the spread: their variance adds to the inputs'
    cov = linear_model(geometry, budget, poses).moments()[1]
    cov0 = linear_model(geometry, budget.without_effects(), poses).moments()[1]
    assert np.all(np.diagonal(cov, axis1=-2, axis2=-1) > np.diagonal(cov0, axis1=-2, axis2=-1))
    assert np.all(np.abs(r.std - np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))) < N_SE * r.std_se)
    assert np.all(r.position_max <= worst_case(geometry, budget, poses).position_mm * (1 + 1e-6))


def test_monte_carlo_draws_backlash_signs_and_temperatures_as_documented(geometry, seed):
    budget = small_budget(geometry)
    X = budget.sample(50_000, seed)
    k = budget.factors.index("backlash_1")
    assert set(np.unique(X[:, k])) == {-0.01, 0.01}
    assert abs(np.mean(X[:, k] > 0) - 0.5) < N_SE * 0.5 / np.sqrt(len(X))
    t = X[:, budget.factors.index("thermal")]
    assert TEMPS[0] <= t.min() and t.max() <= TEMPS[1]
    assert abs(t.mean() - 25.0) < N_SE * 30 / np.sqrt(12 * len(X))


def test_budgets_without_effects_draw_the_same_numbers(geometry):
    paper = Budget.from_preset("paper")
    assert paper.factors == paper.names
    r = monte_carlo(geometry, paper, [0.0, 100.0 if geometry.name == "u-shape" else 160.0, 0.0], 4096, rng=1)
    again = monte_carlo(geometry, paper.with_effects({}), r.poses, 4096, rng=1)
    np.testing.assert_array_equal(r.position_pct, again.position_pct)


# ------------------------------------------------------------ the geometry the effects were fitted on
def test_a_budget_refuses_another_geometry_in_one_line(tmp_path):
    u, delta = Geometry.from_preset("u-shape"), Geometry.from_preset("delta-shape")
    budget = small_budget(u)
    path = tmp_path / "b.toml"
    budget.to_toml(path)
    again = Budget.from_toml(path)
    assert again.fitted_on == budget.fitted_on and again.effects == budget.effects
    with pytest.raises(BudgetError) as info:
        worst_case(delta, again, [0.0, 160.0, 0.0])
    message = str(info.value)
    assert "'u-shape'" in message and "'delta-shape'" in message and "\n" not in message
    for fn in (lambda: linear_model(delta, again, [0.0, 160.0, 0.0]),
               lambda: worst_case_maxima(delta, again, [[0.0, 160.0, 0.0]])):
        with pytest.raises(BudgetError, match="fitted on geometry 'u-shape'"):
            fn()
    # a fitted geometry (offsets of a fraction of a mm or deg applied) is the same machine
    fitted = u.replace(a=np.add(u.a, [0.3, -0.2, 0.0]), beta=np.add(u.beta, [0.0, 0.4, 0.0]), name="u-shape fitted")
    worst_case(fitted, again, [0.0, 100.0, 0.0])
    # without effects a budget is geometry-agnostic
    worst_case(delta, again.without_effects(), [0.0, 160.0, 0.0])


def test_cli_refuses_a_budget_fitted_on_another_geometry(tmp_path, capsys):
    path = tmp_path / "b.toml"
    small_budget(Geometry.from_preset("u-shape")).to_toml(path)
    for command in ("worstcase", "montecarlo", "sobol"):
        code = main([command, "--geometry", "delta-shape", "--budget", str(path), "--pose", "0", "160", "0"]
                    + (["--samples", "64"] if command != "worstcase" else []))
        err = capsys.readouterr().err
        assert code == 1
        assert len(err.strip().splitlines()) == 1 and "fitted on geometry 'u-shape'" in err


# ------------------------------------------------------------ the exact chain behind the other checks
def test_linearity_guard_sees_the_effects(geometry, region):
    from prp3mc.errors import LinearityWarning
    from prp3mc.model.validity import check_linearity, linearity_departure
    poses = random_poses(region, 3, np.random.default_rng(8), phi_deg=(0.0, 0.0))
    small = small_budget(geometry)
    assert linearity_departure(geometry, small, poses) < 0.01
    large = small.with_effects(effects({"beta_2": 4.0, "thermal": 5e-4}, temps=(-50.0, 150.0)))
    assert linearity_departure(geometry, large, poses) > 10 * linearity_departure(geometry, small, poses)
    with pytest.warns(LinearityWarning, match="too large for the linear error model"):
        check_linearity(geometry, large, poses)


def test_an_output_the_budget_does_not_move_is_not_judged_on_round_off(geometry, region):
    """Equal slider offsets on every leg translate the platform: its linear |dphi| is round-off (1e-19 rad)
    and the exact chain's too (5e-16): their ratio is no departure (it was reported as 1.3e5 %)."""
    from prp3mc import Budget, Uniform
    from prp3mc.model.validity import linearity_departure
    offsets = Budget({f"b_{i}": Uniform(0.01, 0.01) for i in (1, 2, 3)})
    poses = random_poses(region, 3, np.random.default_rng(8), phi_deg=(0.0, 0.0))
    assert linearity_departure(geometry, offsets, poses) < 0.01


def test_monte_carlo_exact_check_includes_the_effects(geometry):
    pose = [10.0, 100.0, 1.0] if geometry.name == "u-shape" else [10.0, 160.0, 1.0]
    budget = small_budget(geometry)
    r = monte_carlo(geometry, budget, pose, 2048, rng=1, exact_check_poses=1, exact_check_samples=500)
    row = r.linearization.iloc[0]
    assert row["position_max_um"] < 0.01 * row["position_p99_linear_um"]


def test_optimizer_over_the_factors_does_not_beat_the_envelope(geometry):
    from prp3mc.worstcase.crosscheck import optimizer_worst_case
    pose = [5.0, 100.0, 0.0] if geometry.name == "u-shape" else [5.0, 160.0, 0.0]
    budget = small_budget(geometry)
    r = optimizer_worst_case(geometry, budget, pose, rng=3, maxiter=60)
    env = float(worst_case(geometry, budget, pose).position_mm)
    assert 0.95 * env <= r.position_mm <= env * (1 + 1e-3)
    assert set(r.inputs) == set(budget.factors)


def test_interop_hands_over_the_factors():
    from prp3mc.model.interop import openturns_distribution, salib_model, salib_problem
    g = Geometry.from_preset("u-shape")
    budget = small_budget(g)
    problem = salib_problem(budget)
    assert problem["names"] == list(budget.factors) and problem["num_vars"] == 9
    U = np.random.default_rng(0).random((64, 9))
    np.testing.assert_allclose(salib_model(g, budget, [0, 100, 0], "x")(U),
                               linear_model(g, budget, [0, 100, 0]).evaluate(budget.ppf(U))[:, 0])
    pytest.importorskip("openturns")
    dist = openturns_distribution(budget)
    assert list(dist.getDescription()) == list(budget.factors)
    assert dist.getMarginal(budget.factors.index("thermal")).getMean()[0] == pytest.approx(25.0)
    assert dist.getMarginal(budget.factors.index("backlash_1")).getStandardDeviation()[0] == pytest.approx(0.01)


@pytest.mark.parametrize("table, message", [
    ('[fitted_on]\nname = "u"\na_mm = [1, 2, 3]', "fitted_on needs a_mm, alpha_deg"),
    ('fitted_on = 3', "[fitted_on] must be a table"),
    ('[fitted_on]\nname = "u"\na_mm = [1, 2]\nalpha_deg = [0, 0, 0]\nbeta_deg = [0, 0, 0]\ngamma_deg = [0, 0, 0]\n'
     'theta_deg = [0, 0, 0]\nc_mm = [0, 0, 0]\ne_mm = [0, 0, 0]\npsi_deg = [0, 0, 0]', "a_mm must list three"),
    ('[fitted_on]\nname = "u"\na_mm = [1, 2, "x"]\nalpha_deg = [0, 0, 0]\nbeta_deg = [0, 0, 0]\ngamma_deg = [0, 0, 0]\n'
     'theta_deg = [0, 0, 0]\nc_mm = [0, 0, 0]\ne_mm = [0, 0, 0]\npsi_deg = [0, 0, 0]', "finite number"),
])
def test_bad_fitted_on_is_refused_in_one_line(tmp_path, table, message):
    path = tmp_path / "b.toml"
    top = table.startswith("fitted_on =")
    inputs = '[inputs]\nb_1 = {law = "uniform", lo = 0, hi = 0.01}\n'
    path.write_text(table + "\n" + inputs if top else inputs + table + "\n")
    with pytest.raises(BudgetError) as info:
        Budget.from_toml(path)
    assert message in str(info.value) and "\n" not in str(info.value) and str(info.value).startswith(str(path))


def test_cli_json_records_and_uses_the_effects(tmp_path, capsys):
    import json
    g = Geometry.from_preset("u-shape")
    budget = small_budget(g)
    path = tmp_path / "b.toml"
    budget.to_toml(path)
    pose = ["0", "100", "0"]
    assert main(["worstcase", "--geometry", "u-shape", "--budget", str(path), "--pose", *pose, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    wc = worst_case(g, budget, [0.0, 100.0, 0.0])
    assert doc["position_mm"] == float(wc.position_mm)
    assert doc["maximizer"]["position"]["thermal"] in TEMPS and "offset_beta_2" in doc["position_contributions_mm"]
    record = doc["inputs"]["budget"]
    assert record["fitted_on"] == "u-shape" and record["effects"]["backlash_1"] == {"value": 0.02, "unit": "mm"}
    assert main(["montecarlo", "--geometry", "u-shape", "--budget", str(path), "--pose", *pose, "--samples",
                 "20000", "--seed", "2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    mean = linear_model(g, budget, [0.0, 100.0, 0.0]).moments()[0]
    for k, key in enumerate(("x_mm", "y_mm", "phi_deg")):
        assert abs(doc["mean"][key] - mean[k]) < N_SE * doc["se"]["mean"][key]
    assert "effects" in doc["inputs"]["budget"]
    assert main(["sobol", "--geometry", "u-shape", "--budget", str(path), "--pose", *pose, "--samples", "256",
                 "--seed", "2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {"backlash_1", "backlash_3", "thermal"} <= set(doc["outputs"]["position"])
    shifts = [row for row in doc["ranking"]["position"] if row["kind"] == "shift"]
    assert {row["name"] for row in shifts} == {"offset_a_1", "offset_beta_2", "offset_psi_3", "offset_b_3",
                                                "offset_theta_1", "scale_2"}
    assert all(row["ST"] is None for row in shifts)


def test_the_registry_says_how_the_linear_model_takes_each_kind():
    """Every library effect parses to an ``EffectKind``; in the linear model a kind's effects are the terms its
    registry entry says (a known shift or a factor, of one leg or all), in its term unit, and the budget's
    effects table takes its words from the registry."""
    from prp3mc.model.effects import EFFECT_NAMES, ALL_LEGS, EffectKind, effect
    assert {effect(name).kind for name in EFFECT_NAMES} == set(EffectKind)
    g = Geometry.from_preset("u-shape").replace(lead=(5.0, 10.0, 4.0))
    effects = {"beta_2": SystematicEffect("beta_2", 0.01), "scale_1": SystematicEffect("scale_1", 1e-4),
               "backlash_3": SystematicEffect("backlash_3", 0.02),
               "thermal": SystematicEffect("thermal", 1.2e-5, temp_range_C=(15.0, 30.0)),
               "cyclic_2": SystematicEffect("cyclic_2", 0.01, phase_deg=30.0)}
    budget = Budget.from_preset("paper").with_effects(effects, fitted_on=g)
    model = linear_model(g, budget, Region.from_preset("u-shape").grid(1))
    terms = dict(zip(model.terms, zip(model.term_laws, model.term_units)))
    for name, eff in effects.items():
        kind = eff.effect.kind
        law, unit = terms[eff.effect.term]
        assert law.kind == kind.at_pose and (law.leg == ALL_LEGS) == (not kind.per_leg)
        assert unit == (kind.term_unit or eff.unit) and law.reference == kind.reference
    assert list(budget.effects_frame()["enters"]) == [effects[n].effect.kind.enters for n in budget.effects]
    assert EffectKind.THERMAL.term_unit == "K" and EffectKind.CYCLIC.dof == 2 and EffectKind.SPREAD.at_pose == "law"


def test_the_registry_says_what_a_campaign_needs_and_what_a_controller_compensates():
    """What a campaign needs to test an effect (:meth:`Effect.untestable`) and how a controller compensates a
    kind come from the registry: every systematic kind says how, every kind a controller may leave says why."""
    from prp3mc.model.effects import EFFECT_NAMES, EffectKind, effect
    for kind in EffectKind:
        assert (kind.compensation is None) == (not kind.systematic)
        assert (kind.uncompensated is None) == kind.is_shift
    everything = ({"dir_1", "dir_2", "dir_3", "temp_C"}, (True,) * 3, True, None)
    assert all(effect(n).untestable(*everything) is None for n in EFFECT_NAMES)
    why = {n: effect(n).untestable({"dir_1"}, (True, False, True), False, ("b_1",)) for n in EFFECT_NAMES}
    assert why["backlash_1"] is None and why["backlash_2"] == "needs dir_2" and why["thermal"] == "needs temp_C"
    assert "lead_mm of leg 2" in why["cyclic_2"] and why["cyclic_3"] is None
    assert "pose measured twice" in why["spread_b_1"] and why["beta_1"] is None and why["scale_3"] is None
    assert effect("spread_b_2").untestable(*everything[:3], ("b_1",)) == "needs its budget input"


def test_one_lead_check_behind_every_cyclic_path():
    """The budget's check, the slider error and the linear model's terms refuse a cyclic error without its leg's
    lead with the same one line."""
    from prp3mc.model.effects import check_leads, effect_terms
    g = Geometry.from_preset("u-shape").replace(lead=(5.0, None, 4.0))
    calls = (lambda: check_leads(["cyclic_2"], g),
             lambda: slider_error({"cyclic_2": 0.01}, np.zeros((1, 3)), lead_mm=g.lead_mm),
             lambda: effect_terms({"cyclic_2": SystematicEffect("cyclic_2", 0.01, phase_deg=0.0)}, g.lead_mm))
    for call in calls:
        with pytest.raises(BudgetError, match="cyclic_2: a cyclic screw error repeats with the lead of slider 2's "
                                              "screw, and .* has no lead_mm for leg 2"):
            call()
    check_leads(["cyclic_1", "cyclic_3", "backlash_2"], g)
