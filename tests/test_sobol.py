"""Sobol indices: SALib's design and estimators, the vectorised path, closed forms, ranking, CLI."""

import json

import numpy as np
import pandas as pd
import pytest
from SALib.sample import sobol as sobol_sample

from prp3mc import Budget, Disc, Geometry, Normal, Region, Triangular, Uniform, linear_model, worst_case
from prp3mc.errors import BudgetError, InfeasiblePoseError, ParameterError
from prp3mc.cli import main
from prp3mc.sobol.ranking import ranking
from prp3mc.sobol.saltelli import design_factors as _factors, saltelli_design as _design
from prp3mc.sobol.indices import sobol_converge, sobol_indices
from prp3mc.sobol.closed_form import analytic_indices

from .conftest import random_poses

PAPER = Budget.from_preset("paper")
KEYS = ["x_mm", "y_mm", "phi_deg", "output", "name", "kind"]
LEG_GROUPS = {f"leg_{i}": [f"rho_{i}", f"zeta_{i}", f"theta_{i}", f"b_{i}"] for i in (1, 2, 3)}


def general_budget() -> Budget:
    """Non-uniform laws, a restricted contact angle and a group that splits a clearance."""
    return PAPER.replace(name="general", rho_1=Disc(0.016), zeta_1=Uniform(20.0, 110.0),
                         zeta_2=Triangular(0.0, 90.0, 180.0), theta_3=Normal(0.0, 0.015))


def with_exact(result, exact) -> pd.DataFrame:
    """The estimates of ``result`` beside the closed forms (columns S1_exact, ST_exact)."""
    return result.to_frame().merge(exact, on=KEYS, suffixes=("", "_exact"), validate="one_to_one")


# ------------------------------------------------------------------ design and estimators
def test_design_is_salibs_sampler_with_groups():
    """A, B and every AB of the shared design are the rows of SALib's sampler for each problem."""
    factors = _factors(PAPER, {"rhos": ["rho_1", "rho_2", "rho_3"]})
    U = _design(PAPER, factors, 64, seed=7)
    d, names = len(PAPER), list(PAPER.names)
    plain = sobol_sample.sample({"num_vars": d, "names": names, "bounds": [[0, 1]] * d}, 64,
                                calc_second_order=False, scramble=True, seed=7)
    np.testing.assert_array_equal(plain.reshape(64, d + 2, d).transpose(1, 0, 2),
                                  U[[0] + list(range(2, d + 2)) + [1]])
    for k in range(d, len(factors.names)):
        members = factors.groups[factors.names[k]]
        groups = ["g" if n in members else n for n in names]
        D = len(pd.unique(np.array(groups)))
        grouped = sobol_sample.sample({"num_vars": d, "names": names, "bounds": [[0, 1]] * d,
                                       "groups": groups}, 64, calc_second_order=False, scramble=True,
                                      seed=7).reshape(64, D + 2, d)
        np.testing.assert_array_equal(grouped[:, 0], U[0])
        np.testing.assert_array_equal(grouped[:, -1], U[1])
        np.testing.assert_array_equal(grouped[:, 1 + list(pd.unique(np.array(groups))).index("g")], U[2 + k])


@pytest.mark.parametrize("budget", [PAPER, general_budget()], ids=["paper", "general"])
def test_vectorised_equals_salib(geometry, region, budget):
    """Same replicated designs: the vectorised estimators reproduce SALib's numbers, replicate by replicate."""
    poses = random_poses(region, 2, np.random.default_rng(3))
    groups = {**LEG_GROUPS, "rho_and_theta_1": ["rho_1", "theta_1"]}
    kw = dict(rng=11, groups=groups, replicates=4, conf_level=0.9, shapley_permutations=0)
    salib = sobol_indices(geometry, budget, poses, 256, method="salib", **kw)
    vect = sobol_indices(geometry, budget, poses, 256, method="vectorised", workers=2, max_chunk_bytes=1, **kw)
    assert (salib.method, vect.method) == ("salib", "vectorised")
    for key in ("S1", "S1_conf", "ST", "ST_conf"):
        np.testing.assert_allclose(getattr(vect, key), getattr(salib, key), rtol=0, atol=1e-10, err_msg=key)


def test_constant_inputs_have_undefined_indices():
    """A zero-width input has no variance to share: its indices are NaN (undefined), not 0."""
    zero = Budget({name: Uniform(0.0, 0.0) for name in PAPER.names})
    g = Geometry.from_preset("u-shape")
    for method in ("salib", "vectorised"):
        r = sobol_indices(g, zero, [0, 100, 0], 64, rng=1, method=method)
        assert r.constant == r.names and np.all(np.isnan(r.S1)) and np.all(np.isnan(r.ST_conf))
    one = PAPER.replace(theta_2=Uniform(0.01, 0.01))
    r = sobol_indices(g, one, [0, 100, 0], 64, rng=1, groups={"theta": ["theta_1", "theta_2", "theta_3"]})
    k = r.names.index("theta_2")
    assert r.constant == ("theta_2",) and np.all(np.isnan(r.ST[..., k]))
    assert np.all(np.isfinite(np.delete(r.ST, k, axis=-1)))  # the group holding it is defined


# ------------------------------------------------------------------ closed forms
@pytest.mark.parametrize("budget", [PAPER, general_budget()], ids=["paper", "general"])
def test_salib_matches_closed_forms(geometry, region, budget):
    """x, y, phi at random poses: within the intervals (2.5 half-widths, about 5 SE) and 0.02.

    The vectorised path gives SALib's numbers (test_vectorised_equals_salib)
    at a fraction of the cost; the CLI test runs SALib itself.
    """
    poses = random_poses(region, 3, np.random.default_rng(12))
    r = sobol_indices(geometry, budget, poses, 8192, rng=2024, groups=LEG_GROUPS, outputs=("x", "y", "phi"),
                      method="vectorised")
    df = with_exact(r, analytic_indices(geometry, budget, poses, groups=LEG_GROUPS))
    assert len(df) == 3 * 3 * (len(budget) + len(r.groups))
    for key in ("S1", "ST"):
        err = (df[key] - df[f"{key}_exact"]).abs()
        assert err.max() < 0.02, df.loc[err.idxmax()]
        bad = df[err > 2.5 * df[f"{key}_conf"] + 1e-9]
        assert bad.empty, bad


def test_interval_coverage_over_seeds(geometry, region):
    """Coverage of the 95 % intervals over 24 seeds is not below nominal (mean over seeds - 4 SE).

    The Student t interval over 16 independent scramblings is exact for normal
    replicate estimates; benchmarks/coverage_sobol.py measures it over 200 seeds
    (and tests/test_coverage.py, slow, bounds it from both sides).
    """
    poses = random_poses(region, 4, np.random.default_rng(8))
    exact = analytic_indices(geometry, PAPER, poses)
    per_seed = []
    for seed in range(24):
        df = with_exact(sobol_indices(geometry, PAPER, poses, 512, rng=seed, outputs=("x", "y", "phi"),
                                      method="vectorised", shapley_permutations=0), exact)
        df = df[df["ST_exact"] > 1e-3]
        covered = [(df[k] - df[f"{k}_exact"]).abs() <= df[f"{k}_conf"] for k in ("S1", "ST")]
        per_seed.append(np.mean(np.concatenate(covered)))
    per_seed = np.array(per_seed)
    se = per_seed.std(ddof=1) / np.sqrt(len(per_seed))
    assert per_seed.mean() >= 0.95 - 4 * se, per_seed


def test_clearance_group_is_rho_and_zeta_together(geometry, region):
    """clearance_i = c^2 E[rho^2] / 2 / V for a uniform contact angle; V from LinearModel.moments."""
    poses = random_poses(region, 3, np.random.default_rng(4))
    model = linear_model(geometry, PAPER, poses)
    var = np.diagonal(model.moments()[1], axis1=-2, axis2=-1).copy()   # (P, 3), dphi deg^2
    var[:, 2] *= (np.pi / 180) ** 2                                                 # rad^2, as the columns
    exact = analytic_indices(geometry, PAPER, poses)
    r = sobol_indices(geometry, PAPER, poses, 8192, rng=5, method="vectorised")
    df = with_exact(r, exact).set_index(["x_mm", "y_mm", "output", "name"])
    rho = PAPER.inputs["rho_1"]
    for i in (1, 2, 3):
        t = model.terms.index(f"rho_{i}")
        share = model.columns[..., t] ** 2 * (rho.var + rho.mean**2) / 2 / var          # (P, 3)
        for p, (x, y, _) in enumerate(poses):
            for o, out in enumerate(("x", "y", "phi")):
                row = df.loc[(x, y, out, f"clearance_{i}")]
                assert row["S1_exact"] == pytest.approx(share[p, o], abs=1e-12)
                assert row["ST_exact"] == pytest.approx(share[p, o], abs=1e-12)
                assert row["ST_exact"] == pytest.approx(df.loc[(x, y, out, f"zeta_{i}"), "ST_exact"], abs=1e-12)
                assert abs(row["S1"] - share[p, o]) <= 2.5 * row["S1_conf"] + 1e-9
                assert abs(row["ST"] - share[p, o]) <= 2.5 * row["ST_conf"] + 1e-9


def test_general_clearance_closed_form_by_monte_carlo():
    """Restricted contact angle, disc clearance: the group's variance share against plain sampling."""
    g, budget = Geometry.from_preset("delta-shape"), general_budget()
    pose = [5.0, 150.0, 1.0]
    model = linear_model(g, budget, pose)
    var = np.diagonal(model.moments()[1]).copy()
    var[2] *= (np.pi / 180) ** 2
    frame = analytic_indices(g, budget, pose)
    exact = frame.set_index(["output", "name"])
    X = budget.sample(1_000_000, 9)
    term = model.term_values(X)[:, model.terms.index("rho_1")]          # rho_1 cos(zeta_1 - omega_1)
    col2 = model.columns[:, model.terms.index("rho_1")] ** 2
    n = len(term)
    m2 = np.square(term - term.mean())
    se = np.sqrt(m2.var() / n)
    for o, out in enumerate(("x", "y", "phi")):
        assert exact.loc[(out, "clearance_1"), "S1"] * var[o] == pytest.approx(
            col2[o] * m2.mean(), abs=5 * col2[o] * se)
    total = frame[frame["kind"] == "input"].groupby("output")["S1"].sum()
    assert np.all(total < 1.0) and exact.loc[("x", "rho_1"), "S1"] > 0    # rho and zeta interact


# ------------------------------------------------------------------ result, ranking, convergence
def test_result_frame_and_seed():
    g = Geometry.from_preset("u-shape")
    grid = Region.from_preset("u-shape").grid((3, 2))
    r = sobol_indices(g, PAPER, grid, 128, outputs=("position", "x"))
    assert r.S1.shape == r.Sh.shape == (2, 3, 2, 15) and r.seed >= 0 and r.replicates == 16
    assert r.names[:12] == PAPER.names and r.kinds[12:] == ("group",) * 3
    df = r.to_frame()
    assert list(df.columns) == KEYS + ["S1", "S1_conf", "ST", "ST_conf", "Sh", "Sh_conf"] and len(df) == 6 * 2 * 15
    again = sobol_indices(g, PAPER, grid, 128, rng=r.seed, outputs=("position", "x"))
    np.testing.assert_array_equal(again.ST, r.ST)
    np.testing.assert_array_equal(again.Sh, r.Sh)
    none = sobol_indices(g, PAPER, grid, 128, rng=r.seed, outputs=("position", "x"), shapley_permutations=0)
    assert none.Sh is None and list(none.to_frame().columns) == KEYS + ["S1", "S1_conf", "ST", "ST_conf"]
    np.testing.assert_array_equal(none.ST, r.ST)


def test_result_is_read_only_with_labelled_intervals():
    """conf_int(level) is S +- t(level, R - 1) se with se = S_conf / t(conf_level, R - 1)."""
    g = Geometry.from_preset("u-shape")
    r = sobol_indices(g, PAPER, [[0, 100, 0], [10, 90, 2]], 64, rng=2, outputs=("x", "position"),
                      conf_level=0.9, replicates=8)
    with pytest.raises(ValueError):
        r.ST[0, 0, 0] = 1.0
    with pytest.raises(TypeError):
        r.groups["g"] = ("rho_1",)
    assert "\n" not in repr(r) and len(repr(r)) < 120
    ci = r.conf_int(0.9)
    assert list(ci.columns) == KEYS + ["statistic", "value", "unit", "se", "ci_low", "ci_high", "level"]
    assert set(ci["statistic"]) == {"S1", "ST", "Sh"}
    for key in ("S1", "ST", "Sh"):
        rows = ci[ci["statistic"] == key]
        np.testing.assert_allclose(rows["value"], getattr(r, key).reshape(-1), rtol=0, atol=0)
        np.testing.assert_allclose(rows["ci_high"] - rows["value"], getattr(r, f"{key}_conf").reshape(-1), rtol=1e-12)
        np.testing.assert_allclose(rows["value"] - rows["ci_low"], getattr(r, f"{key}_conf").reshape(-1), rtol=1e-12)
    wide = r.conf_int(0.99)
    assert (wide["level"] == 0.99).all()
    np.testing.assert_allclose(wide["se"], ci["se"], rtol=0, atol=0)
    ratio = 3.4994832973505026 / 1.894578605090005                    # t(0.99, 7) / t(0.9, 7)
    np.testing.assert_allclose(wide["ci_high"] - wide["ci_low"], ratio * (ci["ci_high"] - ci["ci_low"]),
                               rtol=1e-12, atol=1e-15)
    with pytest.raises(ParameterError, match="level"):
        r.conf_int(1.0)


@pytest.mark.parametrize("kwargs, error, message", [
    (dict(n_samples=1000), ParameterError, "power of two"),
    (dict(outputs=("z",)), ParameterError, "bad outputs"),
    (dict(method="fast"), ParameterError, "unknown method"),
    (dict(groups={"g": ["rho_9"]}), BudgetError, "unknown input"),
    (dict(groups={"g": "rho_1"}), BudgetError, "list of inputs"),
    (dict(conf_level=1.0), ParameterError, "conf_level"),
    (dict(replicates=12), ParameterError, "power of two"),
    (dict(replicates=64), ParameterError, "too small for 64 replicates"),
    (dict(shapley_permutations=-1), ParameterError, "shapley_permutations"),
])
def test_bad_arguments(kwargs, error, message):
    args = dict(n_samples=64, rng=1) | kwargs
    with pytest.raises(error, match=message):
        sobol_indices(Geometry.from_preset("u-shape"), PAPER, [0, 100, 0], args.pop("n_samples"), **args)


def test_ranking_per_pose_and_region(geometry, region):
    grid = region.grid(3)
    r = sobol_indices(geometry, PAPER, grid, 512, rng=3, groups=LEG_GROUPS)
    wc = worst_case(geometry, PAPER, grid)
    for output in ("position", "phi"):
        df = ranking(r, wc, output, index=(1, 2))
        assert df["ST"].is_monotonic_decreasing and len(df) == 12 + 6
        wc_of = df.set_index("name")["worst_case_contribution"]
        assert wc_of[["rho_1", "zeta_2", "leg_1"]].notna().tolist() == [False, False, True]
        parts = [n for n in r.names if n.startswith(("theta", "b_", "clearance"))]
        assert wc_of[parts].sum() == pytest.approx(float(wc.value(output)[1, 2]), rel=1e-9)
        assert wc_of[[f"leg_{i}" for i in (1, 2, 3)]].sum() == pytest.approx(float(wc.value(output)[1, 2]), rel=1e-9)
        o = r.outputs.index(output)
        assert df.set_index("name").loc["theta_1", "ST"] == r.ST[1, 2, o, r.names.index("theta_1")]
    area = ranking(r, wc, "position")
    worst = np.unravel_index(np.argmax(wc.position_mm), wc.position_mm.shape)
    assert area.attrs["worst_pose"] == grid[worst].tolist()
    row = area.set_index("name").loc["theta_2"]
    k = r.names.index("theta_2")
    assert row["ST"] == pytest.approx(r.ST[..., 3, k].mean()) and row["ST_max"] == r.ST[..., 3, k].max()
    with pytest.raises(ParameterError, match="same poses"):
        ranking(r, worst_case(geometry, PAPER, grid[:2]), "position")


def test_converge_doubles_until_target():
    g = Geometry.from_preset("u-shape")
    result, history = sobol_converge(g, PAPER, [0, 100, 0], target_width=0.03, n_start=256, rng=1,
                                     outputs=("x", "position"), method="vectorised", shapley_permutations=0)
    assert history["converged"].iloc[-1] and not history["converged"].iloc[:-1].any()
    assert list(history["n_samples"]) == [256 * 2**k for k in range(len(history))]
    assert result.n_samples == history["n_samples"].iloc[-1]
    matters = result.ST > 0.05
    assert 2 * result.ST_conf[matters].max() < 0.03
    _, short = sobol_converge(g, PAPER, [0, 100, 0], target_width=1e-4, n_start=64, n_max=128, rng=1,
                              method="vectorised", shapley_permutations=0)
    assert list(short["n_samples"]) == [64, 128] and not short["converged"].any()


# ------------------------------------------------------------------ command line
def run(capsys, *argv):
    code = main(["sobol", *argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_cli_json_matches_closed_forms(capsys):
    """SPEC §6: every input and clearance group for the four outputs; x, y, phi against closed forms."""
    pose = [12.0, 90.0, 3.0]
    code, out, err = run(capsys, "--geometry", "u-shape", "--budget", "paper", "--pose", *map(str, pose),
                         "--samples", "8192", "--seed", "1", "--json")
    assert code == 0 and err == ""
    doc = json.loads(out)
    assert doc["method"] == "vectorised" and doc["seed"] == 1 and doc["n_samples"] == 8192
    names = set(PAPER.names) | {"clearance_1", "clearance_2", "clearance_3"}
    assert set(doc["outputs"]) == {"x", "y", "phi", "position"}
    for entry in doc["outputs"].values():
        assert set(entry) == names
        assert all(set(v) == {"S1", "S1_conf", "ST", "ST_conf", "Sh", "Sh_conf"} for v in entry.values())
        assert sum(v["Sh"] for k, v in entry.items() if k in PAPER.names) == pytest.approx(1.0, abs=1e-9)
    exact = analytic_indices(Geometry.from_preset("u-shape"), PAPER, pose)
    for row in exact.itertuples():
        got = doc["outputs"][row.output][row.name]
        assert abs(got["S1"] - row.S1) < min(0.02, 2.5 * got["S1_conf"] + 1e-9)
        assert abs(got["ST"] - row.ST) < min(0.02, 2.5 * got["ST_conf"] + 1e-9)


def test_cli_json_shape_and_groups(capsys):
    code, out, _ = run(capsys, "--geometry", "delta-shape", "--budget", "paper", "--pose", "0", "160", "0",
                       "--samples", "256", "--seed", "3", "--method", "vectorised", "--group",
                       "leg_1=rho_1,zeta_1,theta_1,b_1", "--json")
    doc = json.loads(out)
    assert code == 0 and "leg_1" in doc["outputs"]["position"]
    rows = doc["ranking"]["position"]
    assert [r["ST"] for r in rows] == sorted((r["ST"] for r in rows), reverse=True)
    assert {r["name"]: r["worst_case_contribution"] for r in rows}["rho_2"] is None


def test_cli_table(capsys):
    code, out, _ = run(capsys, "--geometry", "u-shape", "--budget", "paper", "--pose", "0", "100", "0",
                       "--samples", "256", "--seed", "3", "--method", "vectorised")
    assert code == 0
    assert "position: worst case" in out and "clearance_3" in out and "arcsec" in out


@pytest.mark.parametrize("argv, message", [
    (["--samples", "1000"], "power of two"),
    (["--budget", "lavish"], "unknown budget preset"),
    (["--pose", "10", "300", "0"], "leaves leg 1's stroke"),
    (["--group", "leg_1"], "NAME=input"),
])
def test_cli_bad_input_one_line(capsys, argv, message):
    args = {"--geometry": ["u-shape"], "--budget": ["paper"], "--pose": ["0", "100", "0"], "--samples": ["64"]}
    args[argv[0]] = argv[1:]
    code, out, err = run(capsys, *[a for k, v in args.items() for a in (k, *v)])
    assert code == 1 and out == ""
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_bad_pose_refused():
    with pytest.raises(InfeasiblePoseError):
        sobol_indices(Geometry.from_preset("u-shape"), PAPER, [0, 400, 0], 64, rng=1)
