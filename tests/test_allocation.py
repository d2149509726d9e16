"""Tolerance allocation: exactness against brute force, the statistical spec, the front, bad input."""

import functools
import itertools
import json

import numpy as np
import pytest

from prp3mc import Geometry, Region, allocate, linear_model, worst_case
from prp3mc.cli import main
from prp3mc.errors import AllocationError, Prp3mcError, Prp3mcWarning
from prp3mc.allocation.optimum import allocation_front, region_poses
from prp3mc.allocation.classes import ClassMenu
from prp3mc.allocation.search import Problem, least_cost

CATALOGUE_MENU = {
    "rho": {"classes": [{"name": "C2", "catalogue": "bearing_radial_clearance.bore_10_18.C2", "cost": 4.0},
                        {"name": "CN", "catalogue": "bearing_radial_clearance.bore_10_18.CN", "cost": 1.0}]},
    "theta": {"classes": [{"name": "fine", "law": "uniform", "lo": -0.01, "hi": 0.01, "cost": 6.0},
                          {"name": "paper", "catalogue": "guide_angular_play.paper", "cost": 1.0}]},
    "b": {"classes": [{"name": "1um", "law": "uniform", "lo": 0.0, "hi": 0.0005, "cost": 5.0},
                      {"name": "paper", "catalogue": "encoder_least_count.paper", "cost": 1.0}]},
}


def random_menu(seed: int, disjoint: bool = False) -> ClassMenu:
    """Three families with 2-3 classes and irregular costs (no ties: a unique optimum almost surely)."""
    rng = np.random.default_rng(seed)
    cost = lambda base: float(np.round(base * rng.uniform(0.7, 1.3), 3))  # noqa: E731
    b = ([{"name": "low", "law": "uniform", "lo": 0.0, "hi": 0.004, "cost": cost(3)},
          {"name": "high", "law": "uniform", "lo": 0.006, "hi": 0.012, "cost": cost(1)}] if disjoint else
         [{"name": "1um", "law": "uniform", "lo": 0.0, "hi": 0.0005, "cost": cost(6)},
          {"name": "5um", "law": "uniform", "lo": 0.0, "hi": 0.0025, "cost": cost(3)},
          {"name": "paper", "law": "uniform", "lo": 0.0, "hi": 0.025, "cost": cost(1)}])
    doc = {
        "rho": {"classes": [{"name": "C2", "catalogue": "bearing_radial_clearance.bore_10_18.C2", "cost": cost(4)},
                            {"name": "C3", "catalogue": "bearing_radial_clearance.bore_10_18.C3", "cost": cost(1)}]},
        "theta": {"classes": [{"name": "fine", "law": "uniform", "lo": -0.005, "hi": 0.005, "cost": cost(8)},
                              {"name": "mid", "law": "triangular", "lo": -0.03, "mode": 0.0, "hi": 0.03,
                               "cost": cost(2)}]},
        "b": {"classes": b},
    }
    return ClassMenu.from_dict(doc, source=f"random menu {seed}")


@functools.lru_cache(maxsize=None)
def _brute_force(preset, seed, disjoint=False):
    return brute_force(Geometry.from_preset(preset), random_menu(seed, disjoint), small_grid(preset))


def brute_force(geometry, menu, poses):
    """Every choice's cost and exact worst case by enumerating all 2^T corners of the input box.

    Independent of the 8-corner u-space algebra: the pose error at each corner
    of the box of term values is computed from the model's columns directly.
    """
    inputs = menu.inputs
    choices = list(itertools.product(*[range(len(menu.classes_of(n))) for n in inputs]))
    first = menu.budget({n: menu.classes_of(n)[0].name for n in inputs})
    cols = linear_model(geometry, first, poses).columns                  # (N, 3, T), terms == inputs
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=len(inputs))))   # (2^T, T)
    bounds = [[(-c.law.support[1], c.law.support[1]) if n.startswith("rho_") else c.law.support
               for c in menu.classes_of(n)] for n in inputs]
    lo_hi = np.array([[bounds[t][m] for t, m in enumerate(choice)] for choice in choices])   # (C, T, 2)
    mid, half = lo_hi.mean(-1), 0.5 * (lo_hi[..., 1] - lo_hi[..., 0])
    costs = np.array([sum(menu.classes_of(n)[m].cost for n, m in zip(inputs, ch)) for ch in choices])
    pos, phi = [], []
    for start in range(0, len(choices), 128):
        sl = slice(start, start + 128)
        corners = mid[sl, None, :] + signs[None] * half[sl, None, :]                   # (c, 2^T, T)
        err = np.einsum("not,cst->cnso", cols, corners, optimize=True)                  # (c, N, 2^T, 3)
        pos.append(np.hypot(err[..., 0], err[..., 1]).max(axis=(1, 2)))
        phi.append(np.degrees(np.abs(err[..., 2]).max(axis=(1, 2))))
    return choices, costs, 1e3 * np.concatenate(pos), 3600 * np.concatenate(phi)


def small_grid(preset):
    return region_poses(preset, grid=5)


# ---------------------------------------------------------------- the envelope
def test_envelope_matches_worst_case(preset, geometry):
    menu = random_menu(1)
    poses = region_poses(preset, grid=9)
    problem = Problem(geometry, menu, poses)
    rng = np.random.default_rng(2)
    idx = np.stack([rng.integers(0, problem.n_classes) for _ in range(4)])
    env = problem.envelopes(idx)
    for k in range(idx.shape[0]):
        choice = {n: problem.class_name(j, m) for j, (n, m) in enumerate(zip(problem.inputs, idx[k]))}
        wc = worst_case(geometry, menu.budget(choice), poses)
        np.testing.assert_allclose(env["position"][k], wc.position_mm, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(env["phi"][k], wc.phi_deg, rtol=1e-10, atol=1e-15)


def test_screen_uses_the_closed_form_moments(geometry, preset):
    menu = random_menu(3)
    poses = region_poses(preset, grid=5)
    problem = Problem(geometry, menu, poses, percentile=99.73)
    idx = np.array([0, 1, 1, 1, 0, 1, 1, 0, 2])
    choice = {n: problem.class_name(j, m) for j, (n, m) in enumerate(zip(problem.inputs, idx))}
    mean, cov = linear_model(geometry, menu.budget(choice), poses).moments()
    lam = np.linalg.eigvalsh(cov[:, :2, :2])[:, -1]
    normal = np.hypot(mean[:, 0], mean[:, 1]) + np.sqrt(lam * -2 * np.log(1 - 0.9973))  # chi2_2 ppf
    env = problem.envelopes(idx)
    np.testing.assert_allclose(env["screen"][0], np.minimum(env["position"][0], normal), rtol=1e-9)


# ---------------------------------------------------------------- exactness
@pytest.mark.parametrize("seed", [5, pytest.param(6, marks=pytest.mark.slow)])  # each seed ~10-20 s
def test_least_cost_equals_brute_force(geometry, preset, seed):
    menu, poses = random_menu(seed), small_grid(preset)
    choices, costs, pos, phi = _brute_force(preset, seed)
    cheapest, tightest = costs.argmin(), pos.argmin()
    unique_nontrivial = 0
    for spec in np.quantile(pos, np.linspace(0.02, 0.7, 8)):
        r = allocate(geometry, menu, poses, spec_position_um=float(spec))
        ok = pos <= spec
        best = costs[ok].min()
        assert r.feasible and r.cost == pytest.approx(best, rel=1e-12)
        assert r.worst_case_position_mm * 1e3 <= spec
        winners = np.flatnonzero(ok & np.isclose(costs, best, rtol=1e-12))
        if len(winners) == 1 and winners[0] not in (cheapest, tightest):
            unique_nontrivial += 1
            expected = {n: menu.classes_of(n)[m].name for n, m in zip(menu.inputs, choices[winners[0]])}
            assert r.choice == expected
            assert len(set(r.choice.values())) > 2      # legs and families take different classes
    assert unique_nontrivial >= 1     # legs 1 and 2 mirror each other: many optima come in pairs


def test_phi_and_both_specs_equal_brute_force(geometry, preset):
    menu, poses = random_menu(5), small_grid(preset)
    _, costs, pos, phi = _brute_force(preset, 5)
    spec_pos, spec_phi = float(np.quantile(pos, 0.5)), float(np.quantile(phi, 0.3))
    for kwargs, ok in (({"spec_phi_arcsec": spec_phi}, phi <= spec_phi),
                       ({"spec_position_um": spec_pos, "spec_phi_arcsec": spec_phi},
                        (phi <= spec_phi) & (pos <= spec_pos))):
        r = allocate(geometry, menu, poses, **kwargs)
        assert r.feasible and r.cost == pytest.approx(costs[ok].min(), rel=1e-12)
        assert r.worst_case_phi_deg * 3600 <= spec_phi


def test_classes_without_a_common_interval(geometry, preset):
    menu, poses = random_menu(8, disjoint=True), small_grid(preset)
    _, costs, pos, _ = _brute_force(preset, 8, True)
    for spec in np.quantile(pos, [0.1, 0.5]):
        r = allocate(geometry, menu, poses, spec_position_um=float(spec))
        assert r.cost == pytest.approx(costs[pos <= spec].min(), rel=1e-12)


def test_unreachable_spec_reports_the_closest_choice(geometry, preset):
    menu, poses = random_menu(6), small_grid(preset)
    choices, costs, pos, _ = _brute_force(preset, 6)
    r = allocate(geometry, menu, poses, spec_position_um=0.5 * float(pos.min()))
    assert not r.feasible
    assert r.worst_case_position_mm * 1e3 == pytest.approx(pos.min(), rel=1e-9)
    assert r.cost == pytest.approx(costs[np.isclose(pos, pos.min(), rtol=1e-9)].min())


def test_binding_poses_carry_the_maximum(geometry, preset):
    r = allocate(geometry, "example", preset, spec_position_um=60.0, grid=11)
    assert r.binding == "position" and len(r.binding_poses) >= 1
    at = worst_case(geometry, r.budget(), r.binding_poses).position_mm
    np.testing.assert_allclose(at, r.worst_case_position_mm, rtol=1e-3)


# ---------------------------------------------------------------- statistical spec
def test_percentile_spec_is_confirmed_and_no_dearer(geometry, preset):
    kwargs = dict(spec_position_um=40.0, grid=7)
    wc = allocate(geometry, "example", preset, **kwargs)
    st = allocate(geometry, "example", preset, spec_percentile=99.73, n_samples=20_000, rng=11, **kwargs)
    assert st.feasible and st.statistical["confirmed"] and st.seed == 11
    assert st.cost <= wc.cost
    assert st.statistical["method"] == "exact" and st.statistical["exceedance"] <= 1 - 0.9973
    problem = Problem(geometry, ClassMenu.from_preset("example"), region_poses(preset, grid=7), percentile=99.73)
    screen, _ = least_cost(problem, {"screen": 0.040})
    assert st.cost <= problem.cost[np.arange(9), screen].sum()       # no dearer than the normal screen's choice
    assert st.binding_poses.shape == (1, 3)
    again = allocate(geometry, "example", preset, spec_percentile=99.73, n_samples=20_000, rng=11, **kwargs)
    assert again.statistical == st.statistical


# ---------------------------------------------------------------- the front
def test_front_is_the_brute_force_pareto_set(geometry, preset):
    menu, poses = random_menu(5), small_grid(preset)
    _, costs, pos, _ = _brute_force(preset, 5)
    front = allocation_front(geometry, menu, poses)
    assert_pareto_front(front, costs, pos)
    assert set(front["unit"]) == {"mm", "deg"}


def assert_pareto_front(front, costs, pos):
    """The front's position points are the brute-force Pareto set: cost up, worst case (µm) strictly down."""
    rows = front[front["output"] == "position"].sort_values("point")
    expected, best = [], np.inf
    for k in np.lexsort((pos, costs)):
        if pos[k] < best * (1 - 1e-9):
            if expected and np.isclose(expected[-1][0], costs[k], rtol=1e-12):
                expected.pop()
            expected.append((costs[k], pos[k]))
            best = pos[k]
    np.testing.assert_allclose(rows["cost"], [c for c, _ in expected], rtol=1e-12)
    np.testing.assert_allclose(1e3 * rows["value"], [p for _, p in expected], rtol=1e-9)


def test_front_plot_returns_a_figure():
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure
    from prp3mc.reports.allocation_plots import allocation_front_plot
    front = allocation_front("u-shape", "example", "u-shape", grid=5, max_points=6)
    fig = allocation_front_plot(front, spec=80.0, chosen_cost=float(front["cost"].iloc[-1]))
    assert isinstance(fig, Figure) and len(fig.axes) == 1
    fig.clear()


# ---------------------------------------------------------------- input
@pytest.mark.parametrize("doc, message", [
    ({"rho": {"classes": [{"name": "X", "catalogue": "bearing_radial_clearance.nope", "cost": 1}]}},
     "no catalogue entry"),
    ({"theta": {"classes": [{"name": "X", "law": "uniform", "lo": -1, "hi": 1, "cost": -2}]}}, "cost"),
    ({"theta": {"classes": [{"name": "X", "law": "uniform", "lo": -1, "hi": 1}]}}, "missing cost"),
    ({"theta": {"classes": []}}, "empty class list"),
    ({"gears": {"classes": [{"name": "X", "law": "uniform", "lo": -1, "hi": 1, "cost": 1}]}}, "unknown family"),
    ({"zeta": {"classes": [{"name": "X", "law": "uniform", "lo": 0, "hi": 1, "cost": 1}]}}, "zeta"),
    ({"theta": {"classes": [{"name": "X", "law": "uniform", "lo": -1, "hi": float("nan"), "cost": 1}]}}, "finite"),
    ({"theta": {"classes": [{"name": "X", "law": "uniform", "lo": -1, "hi": 1, "cost": float("inf")}]}}, "finite"),
    ({"b": {"classes": [{"name": "X", "catalogue": "guide_angular_play.paper", "cost": 1}]}}, "applies to theta"),
    ({}, "no family"),
])
def test_bad_classes_are_one_line_errors(doc, message):
    with pytest.raises(AllocationError, match=message) as info:
        ClassMenu.from_dict(doc)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("kwargs, message", [
    ({}, "give a position spec"), ({"spec_position_um": -1.0}, "finite number > 0"),
    ({"spec_phi_arcsec": float("nan")}, "finite number > 0"),
    ({"spec_phi_arcsec": 10.0, "spec_percentile": 99.0}, "percentile spec bounds the position"),
    ({"spec_position_um": 10.0, "spec_percentile": 100.0}, "lie in"),
])
def test_bad_specs(kwargs, message):
    with pytest.raises(AllocationError, match=message):
        allocate("u-shape", "example", "u-shape", grid=3, **kwargs)


def test_cli_json_contract(tmp_path, capsys):
    path = tmp_path / "classes.toml"
    path.write_text("""
[rho]
classes = [
  { name = "C2", catalogue = "bearing_radial_clearance.bore_10_18.C2", cost = 4.0 },
  { name = "CN", catalogue = "bearing_radial_clearance.bore_10_18.CN", cost = 1.0 },
]
[theta]
classes = [
  { name = "fine",  law = "uniform", lo = -0.01, hi = 0.01, cost = 6.0 },
  { name = "paper", catalogue = "guide_angular_play.paper", cost = 1.0 },
]
[b]
classes = [{ name = "1um", law = "uniform", lo = 0.0, hi = 0.001, cost = 5.0 }]
""")
    code = main(["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", str(path),
                 "--spec-position-um", "60", "--spec-phi-arcsec", "200", "--grid", "9", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0
    assert {"cost", "choice", "worst_case_position_um", "worst_case_phi_arcsec", "feasible",
            "binding_poses", "inputs", "versions"} <= set(doc)
    assert doc["feasible"] and doc["worst_case_position_um"] <= 60 and set(doc["choice"]) == {
        f"{f}_{i}" for f in ("rho", "theta", "b") for i in (1, 2, 3)}
    assert doc["inputs"]["classes"]["file"] == str(path.resolve())
    code = main(["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", str(path),
                 "--spec-position-um", "1", "--grid", "5", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["feasible"] is False and doc["choice"]["theta_1"] == "fine"


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    path = tmp_path / "classes.toml"
    path.write_text('[rho]\nclasses = [{ name = "X", catalogue = "bearing_radial_clearance.nope", cost = 1 }]\n')
    code = main(["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", str(path),
                 "--spec-position-um", "60", "--json"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "no catalogue entry" in err


def test_result_protocol():
    r = allocate("delta-shape", "example", "delta-shape", spec_position_um=80.0, spec_phi_arcsec=120.0, grid=5)
    assert repr(r).count("\n") == 0 and "cost=" in repr(r)
    frame = r.to_frame()
    assert set(frame["output"]) == {"position", "phi"} and {"x_mm", "y_mm", "phi_deg"} <= set(frame.columns)
    assert not r.position_mm.flags.writeable
    with pytest.raises(TypeError):
        r.choice["rho_1"] = "C2"
    assert r.choice_frame()["cost"].sum() == pytest.approx(r.cost)
    assert json.dumps(r.to_dict(), allow_nan=False)
    assert isinstance(Region.from_preset("delta-shape"), Region) and isinstance(AllocationError("x"), Prp3mcError)
    assert Geometry.load("delta-shape").name == "delta-shape"


def test_init_classes_template_runs(tmp_path, capsys):
    path = tmp_path / "classes.toml"
    assert main(["init", "classes", str(path)]) == 0
    capsys.readouterr()
    assert main(["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", str(path),
                 "--spec-position-um", "150", "--grid", "5", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["feasible"] and doc["inputs"]["classes"]["sha256"]


@pytest.mark.parametrize("grid", [1, 0, 2.5])
def test_a_region_needs_a_grid_of_at_least_two(grid, capsys):
    """A 1 x 1 grid is the region's corner: a choice checked there alone broke the spec inside the region."""
    with pytest.raises(AllocationError, match="grid must be an integer >= 2"):
        region_poses("u-shape", grid)
    if grid == 1:
        argv = ["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", "example",
                "--spec-position-um", "40", "--grid", "1"]
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "grid must be an integer >= 2" in err


def test_a_percentile_spec_typed_as_a_fraction_is_refused_with_a_hint():
    with pytest.raises(AllocationError, match=r"a percent: 99.73, not 0.9973"):
        allocate("u-shape", "example", "u-shape", spec_position_um=40.0, spec_percentile=0.9973, grid=3)


def test_too_few_samples_to_confirm_a_percentile_are_refused():
    """With 2 samples the 'upper bound' of p99.73 was the sample maximum, far below the percentile, and a
    choice was called confirmed: the samples must bound the interval."""
    with pytest.raises(AllocationError, match="needs at least 1419 samples"):
        allocate("u-shape", "example", "u-shape", spec_position_um=40.0, spec_percentile=99.73, grid=3, n_samples=2)


@pytest.mark.parametrize("kwargs, unit", [({"spec_position_um": 0.08}, "µm"), ({"spec_phi_arcsec": 0.03}, "arcsec")])
def test_a_spec_below_one_unit_warns_naming_the_unit(kwargs, unit):
    """0.08 (80 µm typed in mm) ran silently to an infeasible allocation; ``prp3mc yield`` warns on the same,
    in the same words (one rule for every entry point)."""
    with pytest.warns(Prp3mcWarning, match=f"is below 1 {unit}: a spec in (mm|deg) typed as {unit}"):
        allocate("u-shape", "example", "u-shape", grid=2, **kwargs)


def test_a_percentile_of_many_nines_keeps_its_digits():
    """p99.99999 was printed as 'p100' (6 significant digits), a percentile the spec refuses."""
    with pytest.raises(AllocationError, match=r"confirming p99\.99999 needs"):
        allocate("u-shape", "example", "u-shape", spec_position_um=40.0, spec_percentile=99.99999, grid=3)
