"""Shapley effects: closed forms, the random-permutation estimator, a brute-force second reference, outputs."""

import itertools
import json
import math

import numpy as np
import pytest
from scipy import special

from prp3mc import Budget, Disc, Geometry, Normal, Triangular, Uniform, linear_model, worst_case
from prp3mc.cli import main
from prp3mc.errors import BudgetError, ParameterError, Prp3mcWarning
from prp3mc.sobol.ranking import ranking
from prp3mc.sobol.shapley import shapley_effects
from prp3mc.sobol.indices import DEPENDENT_NOTE, sobol_indices
from prp3mc.sobol.closed_form import analytic_indices, analytic_shapley

PAPER = Budget.from_preset("paper")
POSE = [5.0, 110.0, 1.0]
KEYS = ["x_mm", "y_mm", "phi_deg", "output", "name", "kind"]


def normal_budget(correlation=None) -> Budget:
    """Normal guide plays and encoders (the paper's sds), correlated: a joint normal law."""
    laws = {**{f"theta_{i}": Normal(0.0, 0.023) for i in (1, 2, 3)},
            **{f"b_{i}": Normal(0.0125, 0.0072) for i in (1, 2, 3)}}
    return Budget(laws, correlation=correlation if correlation is not None else
                  {"theta_1,theta_2": 0.6, "theta_2,theta_3": -0.3, "theta_1,b_1": 0.4, "b_1,b_2": 0.5})


def general_budget() -> Budget:
    return PAPER.replace(rho_1=Disc(0.016), zeta_1=Uniform(20.0, 110.0), zeta_2=Triangular(0.0, 90.0, 180.0),
                         theta_3=Normal(0.0, 0.015))


def within(est, se_est, ref, se_ref=0.0, k=6.0):
    """|est - ref| <= k combined standard errors (k = 6: a Student t with 15 df exceeds it with p ~ 2e-5)."""
    return np.abs(est - ref) <= k * np.sqrt(se_est**2 + se_ref**2) + 1e-12


# ------------------------------------------------------------------ closed forms
def test_closed_form_is_the_published_linear_gaussian_formula():
    """Y = b1 X1 + b2 X2 + b3 X3, X1 independent, corr(X2, X3) = r (Iooss and Prieur 2019, section 3.1):
    Sh2 V = b2^2 s2^2 (1 - r^2 / 2) + r b2 b3 s2 s3 + b3^2 s3^2 r^2 / 2, Sh3 likewise, Sh1 V = b1^2 s1^2."""
    g = Geometry.from_preset("u-shape")
    s1, s2, s3 = 0.02, 0.01, 0.03
    b = Budget({"theta_1": Normal(0.0, s1), "theta_2": Normal(0.0, s2), "b_3": Normal(0.0, s3)},
               correlation={"theta_2,b_3": 0.7})
    r = 2 * np.sin(np.pi * 0.7 / 6)
    c = linear_model(g, b, POSE).columns                                   # (3, 3): per deg, per deg, per mm
    exact = analytic_shapley(g, b, POSE)
    for o, out in enumerate(("x", "y", "phi")):
        b1, b2, b3 = c[o]
        V = b1**2 * s1**2 + b2**2 * s2**2 + b3**2 * s3**2 + 2 * r * b2 * b3 * s2 * s3
        want = np.array([b1**2 * s1**2,
                         b2**2 * s2**2 * (1 - r**2 / 2) + r * b2 * b3 * s2 * s3 + b3**2 * s3**2 * r**2 / 2,
                         b3**2 * s3**2 * (1 - r**2 / 2) + r * b2 * b3 * s2 * s3 + b2**2 * s2**2 * r**2 / 2]) / V
        got = exact[exact["output"] == out].set_index("name").loc[["theta_1", "theta_2", "b_3"], "Sh"]
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("budget", [PAPER, general_budget()], ids=["paper", "general"])
def test_closed_form_independent_is_the_sobol_split(budget):
    """Independent inputs: Sh = S1 = ST for an additive input, Sh = (S1 + ST) / 2 for rho_i, zeta_i (the
    clearance's two-input interaction); clearance_i = S1 = ST of the group; the inputs' effects sum to 1."""
    g = Geometry.from_preset("delta-shape")
    poses = [[0.0, 150.0, 0.0], [20.0, 180.0, -2.0]]
    sh = analytic_shapley(g, budget, poses)
    so = analytic_indices(g, budget, poses)
    df = sh.merge(so, on=KEYS, validate="one_to_one")
    inter = df["name"].str.match(r"(rho|zeta)_")
    np.testing.assert_allclose(df.loc[inter, "Sh"], (df.loc[inter, "S1"] + df.loc[inter, "ST"]) / 2, atol=1e-12)
    add = ~inter
    np.testing.assert_allclose(df.loc[add, "Sh"], df.loc[add, "S1"], atol=1e-12)
    np.testing.assert_allclose(df.loc[add, "Sh"], df.loc[add, "ST"], atol=1e-12)
    sums = df[df["kind"] == "input"].groupby(["x_mm", "output"])["Sh"].sum()
    np.testing.assert_allclose(sums, 1.0, atol=1e-12)


def test_closed_form_refuses_correlated_non_normal_inputs():
    b = Budget.from_dict(PAPER.to_dict() | {"correlation": {"theta_1,theta_2": 0.5}})
    with pytest.raises(BudgetError, match="no closed form .* theta_1, theta_2"):
        analytic_shapley(Geometry.from_preset("u-shape"), b, POSE)


# ------------------------------------------------------------------ the estimator
@pytest.mark.parametrize("budget", [PAPER, normal_budget()], ids=["independent", "correlated"])
def test_estimator_matches_closed_forms(budget, seed):
    g = Geometry.from_preset("u-shape")
    r = shapley_effects(g, budget, POSE, 4096, rng=seed, outputs=("x", "y", "phi"))
    exact = analytic_shapley(g, budget, POSE)
    df = r.to_frame().merge(exact, on=KEYS, suffixes=("", "_exact"), validate="one_to_one")
    se = r.se().reshape(-1)
    ok = within(df["Sh"].to_numpy(), se, df["Sh_exact"].to_numpy())
    assert ok.all(), df[~ok]


def brute_force_shapley(budget: Budget, f, n_outer: int, n_inner: int, rng, batches: int = 8):
    """Shapley effects by the other game, v(S) = Var(E[Y | X_S]), over all 2^d sets, by a double loop.

    Conditional draws by the textbook formulas of the normal law (mean R_uS R_SS^-1 z_S, covariance
    R_uu - R_uS R_SS^-1 R_Su); the unbiased v(S) = var of inner means - mean inner variance / n_inner.
    Returns the effects (d,) and their batch-means standard errors.
    """
    d = len(budget.factors)
    R = np.eye(d)
    if budget.copula is not None:
        idx = list(budget.copula.index)
        R[np.ix_(idx, idx)] = budget.copula.latent
    L = np.linalg.cholesky(R)

    def values(z):
        return f(budget.marginal_ppf(np.clip(special.ndtr(z), 2**-53, 1 - 2**-53)))

    n = n_outer * batches
    v = np.zeros((1 << d, batches))
    full = values(rng.standard_normal((n * n_inner, d)) @ L.T).reshape(batches, -1)
    v[-1] = full.var(axis=1, ddof=1)
    for mask in range(1, (1 << d) - 1):
        S = [i for i in range(d) if mask >> i & 1]
        U = [i for i in range(d) if not mask >> i & 1]
        zS = rng.standard_normal((n, d)) @ L.T
        gain = R[np.ix_(U, S)] @ np.linalg.inv(R[np.ix_(S, S)])
        cov = R[np.ix_(U, U)] - gain @ R[np.ix_(S, U)]
        zU = (zS[:, S] @ gain.T)[:, None, :] + rng.standard_normal((n, n_inner, len(U))) @ \
            np.linalg.cholesky(cov + 1e-15 * np.eye(len(U))).T
        z = np.empty((n, n_inner, d))
        z[..., S] = zS[:, None, S]
        z[..., U] = zU
        Y = values(z.reshape(-1, d)).reshape(batches, n_outer, n_inner)
        v[mask] = Y.mean(-1).var(axis=1, ddof=1) - Y.var(-1, ddof=1).mean(-1) / n_inner
    sh = np.zeros((d, batches))
    for i in range(d):
        for mask in range(1 << d):
            if not mask >> i & 1:
                k = bin(mask).count("1")
                w = math.factorial(k) * math.factorial(d - k - 1) / math.factorial(d)
                sh[i] += w * (v[mask | 1 << i] - v[mask])
    est = sh.sum(axis=1) / v[-1].sum()
    lin = (sh - est[:, None] * v[-1]) / v[-1].mean()
    return est, lin.std(axis=1, ddof=1) / np.sqrt(batches)


@pytest.mark.slow
def test_position_against_a_brute_force_double_loop(seed):
    """The position norm (nonlinear) with correlated normal and uniform inputs: two estimators of two games."""
    g = Geometry.from_preset("u-shape")
    b = Budget({"theta_1": Normal(0.0, 0.02), "theta_2": Normal(0.0, 0.02), "b_1": Uniform(0.0, 0.025),
                "b_3": Uniform(0.0, 0.025)}, correlation={"theta_1,theta_2": 0.7, "b_1,b_3": -0.5})
    model = linear_model(g, b, POSE)

    def f(X):
        E = model.evaluate(X)
        return np.hypot(E[..., 0], E[..., 1])

    rng = np.random.default_rng(seed)
    ref, ref_se = brute_force_shapley(b, f, 600, 48, rng)
    r = shapley_effects(g, b, POSE, 8192, rng=seed, outputs=("position",))
    est, se = r.Sh[0, :4], r.se()[0, :4]
    assert within(est, se, ref, ref_se).all(), (est, se, ref, ref_se)


def test_effects_sum_to_one_and_groups_sum_their_members(seed):
    g = Geometry.from_preset("delta-shape")
    b = Budget.from_dict(PAPER.to_dict() | {"correlation": {"rho_1,rho_2": 0.8, "theta_1,b_2": -0.4}})
    grid = np.array([[[0.0, 150.0, 0.0], [10.0, 160.0, 1.0]], [[-20.0, 170.0, 0.0], [5.0, 140.0, -1.0]]])
    groups = {"leg_1": ["rho_1", "zeta_1", "theta_1", "b_1"], "thetas": ["theta_1", "theta_2", "theta_3"]}
    r = shapley_effects(g, b, grid, 512, rng=seed, groups=groups)
    assert r.Sh.shape == (2, 2, 4, 17) and r.correlated and r.n_permutations == 512
    np.testing.assert_allclose(r.Sh[..., :12].sum(-1), 1.0, atol=1e-12)
    for name, members in {**groups, "clearance_2": ["rho_2", "zeta_2"]}.items():
        idx = [r.names.index(m) for m in members]
        np.testing.assert_allclose(r.Sh[..., r.names.index(name)], r.Sh[..., idx].sum(-1), atol=1e-12)
    again = shapley_effects(g, b, grid, 512, rng=r.seed, groups=groups, max_chunk_bytes=1)
    np.testing.assert_array_equal(again.Sh, r.Sh)                        # chunking changes nothing
    with pytest.raises(ValueError):
        r.Sh[0, 0, 0, 0] = 1.0
    assert "\n" not in repr(r)
    frame = r.to_frame()
    assert list(frame.columns) == KEYS + ["Sh", "Sh_conf"] and len(frame) == 4 * 4 * 17
    ci = r.conf_int(0.9)
    np.testing.assert_allclose(ci["ci_high"] - ci["value"], 1.7530503556925552 * ci["se"], rtol=1e-12)  # t(.95, 15)


def test_constant_inputs_have_no_effect():
    g = Geometry.from_preset("u-shape")
    r = shapley_effects(g, PAPER.replace(theta_2=Uniform(0.01, 0.01)), POSE, 64, rng=1)
    assert r.constant == ("theta_2",) and np.isnan(r.Sh[..., r.names.index("theta_2")]).all()
    np.testing.assert_allclose(np.nansum(r.Sh[..., :12], -1), 1.0, atol=1e-12)
    zero = shapley_effects(g, Budget({n: Uniform(0.0, 0.0) for n in PAPER.names}), POSE, 64, rng=1)
    assert np.isnan(zero.Sh).all()


@pytest.mark.parametrize("kwargs, message", [
    (dict(batches=1), "at least 2 batches"),
    (dict(n_permutations=20), "at least 2 orders per batch"),
    (dict(outputs=("z",)), "bad outputs"),
    (dict(conf_level=0.0), "conf_level"),
])
def test_bad_arguments(kwargs, message):
    args = dict(n_permutations=64, rng=1) | kwargs
    with pytest.raises(ParameterError, match=message):
        shapley_effects(Geometry.from_preset("u-shape"), PAPER, POSE, args.pop("n_permutations"), **args)


# ------------------------------------------------------------------ Sobol of a correlated budget
def test_sobol_of_a_correlated_budget_reports_shapley(capsys, tmp_path):
    g = Geometry.from_preset("u-shape")
    b = Budget.from_dict(PAPER.to_dict() | {"groups": {"bearings": ["rho_1", "rho_2", "rho_3"]},
                                            "correlation": {"bearings": 0.8, "theta_1,theta_2": 0.5}})
    with pytest.warns(Prp3mcWarning, match="Sobol indices split the variance only for independent inputs"):
        r = sobol_indices(g, b, POSE, 256, rng=3)
    assert r.correlated and np.isnan(r.S1).all() and np.isnan(r.ST_conf).all()
    assert np.isfinite(r.Sh).all() and np.allclose(r.Sh[..., :12].sum(-1), 1.0)
    df = ranking(r, worst_case(g, b, POSE), "position")
    assert df.attrs["sorted_by"] == "Sh" and df["Sh"].dropna().is_monotonic_decreasing
    from matplotlib.figure import Figure
    from prp3mc.reports import plots
    left = plots.ranking_figure(df, fig=Figure()).axes[0]                # the report draws Sh, not empty S1/ST
    assert left.get_xlabel() == "Shapley effect (95 % CI)" and "correlated inputs" in " ".join(left.get_title().split())
    assert left.get_yticklabels()[0].get_text().removesuffix(" (group)") == df["name"].iloc[0]
    path = tmp_path / "b.toml"
    b.to_toml(path)
    code = main(["sobol", "--geometry", "u-shape", "--budget", str(path), "--pose", *map(str, POSE),
                 "--samples", "256", "--seed", "2", "--json"])
    out, err = capsys.readouterr()
    doc = json.loads(out)
    assert code == 0 and "Sobol indices split the variance" in err
    entry = doc["outputs"]["position"]
    assert entry["theta_1"]["S1"] is None and entry["theta_1"]["reason"] == DEPENDENT_NOTE
    assert sum(entry[n]["Sh"] for n in PAPER.names) == pytest.approx(1.0, abs=1e-9)
    assert [row["Sh"] for row in doc["ranking"]["position"]] == sorted(
        (row["Sh"] for row in doc["ranking"]["position"]), reverse=True)
    assert doc["inputs"]["budget"]["correlation"] == {"bearings": 0.8, "theta_1,theta_2": 0.5}
    assert main(["sobol", "--geometry", "u-shape", "--budget", str(path), "--pose", *map(str, POSE),
                 "--samples", "256", "--seed", "2"]) == 0
    text = capsys.readouterr().out
    assert "sorted by Shapley effect Sh" in text and DEPENDENT_NOTE in text


def test_exact_shapley_by_enumeration_matches_permutation_average():
    """The closed form's 2^g subset sum equals the average over all g! orders (g = 4), for a random covariance."""
    from prp3mc.sobol.closed_form import _gaussian_shapley
    rng = np.random.default_rng(0)
    A = rng.standard_normal((4, 4))
    cov = A @ A.T + 0.1 * np.eye(4)
    c = rng.standard_normal(4)

    def v(S):
        S = list(S)
        if not S:
            return 0.0
        return c @ cov[:, S] @ np.linalg.solve(cov[np.ix_(S, S)], cov[S, :]) @ c

    want = np.zeros(4)
    for order in itertools.permutations(range(4)):
        for j, i in enumerate(order):
            want[i] += v(order[:j + 1]) - v(order[:j])
    want /= math.factorial(4)
    got = np.einsum("f,ifg,g->i", c, _gaussian_shapley(cov), c)
    np.testing.assert_allclose(got, want, rtol=1e-10)
    assert got.sum() == pytest.approx(c @ cov @ c, rel=1e-12)


def test_converge_on_shapley_for_a_correlated_budget():
    from prp3mc.sobol.indices import sobol_converge
    g = Geometry.from_preset("u-shape")
    b = normal_budget()
    with pytest.warns(Prp3mcWarning):
        result, history = sobol_converge(g, b, POSE, target_width=0.08, n_start=256, rng=1, outputs=("x",))
    assert history["converged"].iloc[-1] and 2 * result.Sh_conf[result.Sh > 0.05].max() < 0.08
    with pytest.raises(BudgetError, match="no Sobol indices to converge"):
        sobol_converge(g, b, POSE, which="ST", rng=1)
