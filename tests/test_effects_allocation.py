"""Tolerance allocation with a budget's [effects] held fixed: exact against brute force, in every
bound and check, on the command line and in a study."""

import functools
import itertools
import json

import numpy as np
import pytest

from prp3mc import Budget, Geometry, allocate, linear_model, worst_case
from prp3mc.cli import main
from prp3mc.errors import BudgetError
from prp3mc.allocation.optimum import allocation_front, region_poses
from prp3mc.allocation.search import Problem
from prp3mc.model.effects import SystematicEffect

from .test_allocation import assert_pareto_front, random_menu

EFFECTS = {"backlash_1": 0.012, "backlash_3": 0.006, "thermal": 1.5e-5, "scale_2": 3e-4, "beta_1": 0.01}


def fixed_budget(geometry) -> Budget:
    effects = {k: SystematicEffect(k, v, temp_range_C=(15.0, 35.0) if k == "thermal" else None)
               for k, v in EFFECTS.items()}
    return Budget.from_preset("paper").with_effects(effects, name="machine", fitted_on=geometry)


@functools.lru_cache(maxsize=None)
def brute_force(preset, seed):
    """Every choice's cost and exact worst case (µm, arcsec) with the effects, by worst_case itself."""
    geometry = Geometry.from_preset(preset)
    menu, poses, fixed = random_menu(seed), region_poses(preset, grid=4), fixed_budget(geometry)
    choices = list(itertools.product(*[range(len(menu.classes_of(n))) for n in menu.inputs]))
    costs, pos, phi = [], [], []
    for ch in choices:
        choice = {n: menu.classes_of(n)[m].name for n, m in zip(menu.inputs, ch)}
        wc = worst_case(geometry, menu.budget(choice, fixed), poses)
        costs.append(sum(menu.classes_of(n)[m].cost for n, m in zip(menu.inputs, ch)))
        pos.append(1e3 * wc.position_mm.max())
        phi.append(3600 * wc.phi_deg.max())
    return choices, np.array(costs), np.array(pos), np.array(phi)


def test_envelope_and_screen_with_effects_match_worst_case_and_moments(geometry, preset):
    menu, poses, fixed = random_menu(1), region_poses(preset, grid=6), fixed_budget(geometry)
    problem = Problem(geometry, menu, poses, percentile=99.0, fixed=fixed)
    assert problem.fixed["ext"].shape == (len(poses), 1, 3)                  # thermal: one shared generator
    rng = np.random.default_rng(2)
    idx = np.stack([rng.integers(0, problem.n_classes) for _ in range(3)])
    env = problem.envelopes(idx)
    for k in range(idx.shape[0]):
        budget = menu.budget({n: problem.class_name(j, m) for j, (n, m) in enumerate(zip(problem.inputs, idx[k]))},
                             fixed)
        assert budget.effects == fixed.effects
        wc = worst_case(geometry, budget, poses)
        np.testing.assert_allclose(env["position"][k], wc.position_mm, rtol=1e-10)
        np.testing.assert_allclose(env["phi"][k], wc.phi_deg, rtol=1e-10)
        mean, cov = linear_model(geometry, budget, poses).moments()
        lam = np.linalg.eigvalsh(cov[:, :2, :2])[:, -1]
        normal = np.hypot(mean[:, 0], mean[:, 1]) + np.sqrt(lam * -2 * np.log(1 - 0.99))
        np.testing.assert_allclose(env["screen"][k], np.minimum(env["position"][k], normal), rtol=1e-9)


def test_least_cost_with_effects_equals_brute_force(geometry, preset):
    menu, poses, fixed = random_menu(5), region_poses(preset, grid=4), fixed_budget(geometry)
    choices, costs, pos, phi = brute_force(preset, 5)
    plain = allocate(geometry, menu, poses, spec_position_um=float(np.quantile(pos, 0.3)))
    for spec in np.quantile(pos, [0.05, 0.3, 0.6]):
        r = allocate(geometry, menu, poses, spec_position_um=float(spec), budget=fixed)
        ok = pos <= spec
        assert r.feasible and r.cost == pytest.approx(costs[ok].min(), rel=1e-12)
        assert 1e3 * r.worst_case_position_mm <= spec
        assert r.budget().effects == fixed.effects and r.to_dict()["fixed_effects"]["thermal"]["unit"] == "1/K"
    # the effects cost accuracy: the same spec needs dearer classes than without them
    spec = float(np.quantile(pos, 0.3))
    assert allocate(geometry, menu, poses, spec_position_um=spec, budget=fixed).cost >= plain.cost
    spec_phi = float(np.quantile(phi, 0.4))
    r = allocate(geometry, menu, poses, spec_phi_arcsec=spec_phi, budget=fixed)
    assert r.cost == pytest.approx(costs[phi <= spec_phi].min(), rel=1e-12)
    r = allocate(geometry, menu, poses, spec_position_um=0.5 * float(pos.min()), budget=fixed)
    assert not r.feasible and 1e3 * r.worst_case_position_mm == pytest.approx(pos.min(), rel=1e-9)


def test_front_with_effects_is_the_brute_force_pareto_set(geometry, preset):
    menu, poses, fixed = random_menu(5), region_poses(preset, grid=4), fixed_budget(geometry)
    _, costs, pos, _ = brute_force(preset, 5)
    assert_pareto_front(allocation_front(geometry, menu, poses, budget=fixed), costs, pos)


def test_percentile_spec_is_confirmed_with_the_effects(geometry, preset):
    fixed = fixed_budget(geometry)
    r = allocate(geometry, "example", preset, spec_position_um=120.0, spec_percentile=99.0, grid=5,
                 n_samples=8192, rng=3, budget=fixed)
    assert r.feasible and r.statistical["confirmed"] and r.statistical["ci_high_mm"] <= r.worst_case_position_mm
    assert r.worst_case_position_mm == pytest.approx(worst_case(geometry, r.budget(), r.poses).position_mm.max())


def test_allocate_refuses_effects_of_another_geometry():
    with pytest.raises(BudgetError, match="fitted on geometry 'u-shape'"):
        allocate("delta-shape", "example", "delta-shape", spec_position_um=60.0, grid=3,
                 budget=fixed_budget(Geometry.from_preset("u-shape")))


def test_cli_allocate_with_a_budget(tmp_path, capsys):
    path = tmp_path / "machine.toml"
    fixed_budget(Geometry.from_preset("u-shape")).to_toml(path)
    argv = ["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", "example",
            "--spec-position-um", "60", "--grid", "5", "--json"]
    assert main(argv + ["--budget", str(path)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["fixed_effects"]) == set(EFFECTS) and doc["inputs"]["budget"]["sha256"]
    assert main(argv) == 0
    plain = json.loads(capsys.readouterr().out)
    assert "fixed_effects" not in plain and doc["worst_case_position_um"] != plain["worst_case_position_um"]
    code = main(["allocate", "--geometry", "delta-shape", "--region", "delta-shape", "--classes", "example",
                 "--spec-position-um", "60", "--grid", "3", "--budget", str(path)])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and "fitted on geometry 'u-shape'" in err


# ---------------------------------------------------------------- a study with a budget's effects
STUDY = """\
name = "machine"
seed = 4
budget = "machine.toml"

[worstcase]
grid = 5

[montecarlo]
samples = 4096
grid = 2
percentiles = [50, 99]

[sobol]
samples = 256
grid = 2
outputs = ["position"]

[allocation]
classes = "example"
spec_position_um = 140.0
front = false

[[configuration]]
geometry = "u-shape"
"""


def test_study_runs_every_analysis_with_the_effects(tmp_path, capsys):
    u = Geometry.from_preset("u-shape")
    fixed = fixed_budget(u)
    fixed.to_toml(tmp_path / "machine.toml")
    (tmp_path / "machine_study.toml").write_text(STUDY)
    out = tmp_path / "out"
    assert main(["study", str(tmp_path / "machine_study.toml"), "--out", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    record = summary["inputs"]["budget"]
    assert record["fitted_on"] == "u-shape" and record["effects"]["thermal"]["temp_range_C"] == [15.0, 35.0]
    grid = __import__("prp3mc").Region.from_preset("u-shape").grid(5)
    wc = worst_case(u, fixed, grid)
    got = summary["configurations"]["u-shape"]
    assert got["worst_case_position_um"]["max"] == pytest.approx(1e3 * wc.position_mm.max(), rel=1e-12)
    assert {"backlash_1", "thermal", "offset_beta_1", "scale_2"} <= set(got["sobol"]["position"])
    alloc = allocate(u, "example", grid.reshape(-1, 3), spec_position_um=140.0, budget=fixed)
    assert got["allocation"]["cost"] == alloc.cost and got["allocation"]["choice"] == alloc.choice
    html = (out / "report.html").read_text()
    assert "Systematic effects of the machine" in html and (out / "tables" / "effects.csv").is_file()


def test_study_refuses_effects_of_another_machine_in_one_line(tmp_path, capsys):
    fixed_budget(Geometry.from_preset("u-shape")).to_toml(tmp_path / "machine.toml")
    (tmp_path / "s.toml").write_text(STUDY + '\n[[configuration]]\ngeometry = "delta-shape"\n')
    assert main(["study", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "s.toml:27: geometry 'delta-shape': budget 'machine'" in err


def test_a_sweep_over_a_machine_fitted_budget_is_refused(tmp_path):
    """Fitted effects belong to the machine they were measured on: sweeping its geometry is refused up front."""
    from prp3mc.errors import StudyError
    from prp3mc.study.runner import run_study
    fixed_budget(Geometry.from_preset("u-shape")).to_toml(tmp_path / "machine.toml")
    text = STUDY.replace("[allocation]", "[x]").split("[x]")[0] + '[[configuration]]\ngeometry = "u-shape"\n'
    (tmp_path / "s.toml").write_text(text + '\n[sweep]\n"leg.3.a_mm" = [180.4, 200]\n')
    with pytest.raises(StudyError, match="fitted on geometry 'u-shape': a sweep changes that geometry"):
        run_study(tmp_path / "s.toml")
