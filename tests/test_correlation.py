"""Correlated budgets (SPEC §10): the [correlation] table, its Gaussian copula, and what respects it."""

import json

import numpy as np
import pytest
from scipy import special, stats

from prp3mc import (Budget, Disc, Discrete, Geometry, Normal, Triangular, TruncNormal, Uniform, linear_model,
                    monte_carlo, worst_case)
from prp3mc.cli import main
from prp3mc.errors import BudgetError
from prp3mc.model.copula import latent_from_spearman, pair_covariance, spearman_from_latent
from prp3mc.model.effects import SystematicEffect
from prp3mc.worstcase.envelope import CORRELATION_NOTE

PAPER = Budget.from_preset("paper")
GROUPS = {"bearings": ["rho_1", "rho_2", "rho_3"], "plays": ["theta_1", "theta_2"]}
TABLE = {"bearings": 0.8, "theta_1,theta_2": 0.5, "bearings,b_1": -0.2, "theta_3,b_3": 0.3}
POSE = [0.0, 100.0, 0.0]


def correlated(table=TABLE, groups=GROUPS, base=PAPER) -> Budget:
    doc = base.to_dict() | {"correlation": table, "groups": groups}
    return Budget.from_dict(doc)


def mixed() -> Budget:
    """Every law, correlated across law kinds."""
    laws = PAPER.replace(rho_1=Disc(0.016), theta_2=Triangular(-0.01, 0.03, 0.04),
                         b_3=Discrete((0.0, 0.01, 0.02), (0.6, 0.3, 0.1)), theta_3=TruncNormal(0.0, 0.04, 1.0),
                         b_1=Normal(0.01, 0.003))
    return correlated({"rho_1,theta_2": 0.7, "theta_2,b_3": -0.4, "b_3,theta_3": 0.5, "theta_3,b_1": 0.6,
                       "b_1,rho_2": -0.3}, {}, laws)


# ------------------------------------------------------------------ the table
def test_table_expands_groups_and_round_trips(tmp_path):
    b = correlated()
    s = b.copula.spearman
    at = {name: k for k, name in enumerate(b.copula.names)}
    assert s[at["rho_1"], at["rho_3"]] == 0.8 and s[at["rho_2"], at["b_1"]] == -0.2
    assert s[at["theta_1"], at["theta_2"]] == 0.5 and s[at["theta_3"], at["b_3"]] == 0.3
    assert s[at["rho_1"], at["theta_1"]] == 0.0 and b.correlated and not PAPER.correlated
    np.testing.assert_allclose(b.copula.latent, 2 * np.sin(np.pi * s / 6), rtol=0, atol=1e-15)
    path = tmp_path / "b.toml"
    b.to_toml(path)
    text = path.read_text()
    assert '"theta_1,theta_2" = 0.5' in text and "bearings = 0.8" in text
    again = Budget.from_toml(path)
    assert again == b and again.to_dict() == b.to_dict()
    np.testing.assert_array_equal(again.copula.latent, b.copula.latent)
    for copy in (b.replace(b_2=Uniform(0.0, 0.01)), b.scaled(2.0),
                 b.with_effects({"backlash_1": SystematicEffect("backlash_1", 0.01)})):
        assert copy.correlation == b.correlation
    effects = b.with_effects({"backlash_1": SystematicEffect("backlash_1", 0.01)})
    both = Budget.from_dict(effects.to_dict() | {"correlation": {**b.correlation, "backlash_1,b_2": 0.4}})
    assert "backlash_1,b_2" not in both.without_effects().correlation


def test_latent_conversion_is_openturns():
    ot = pytest.importorskip("openturns")
    rho = np.array([-0.95, -0.5, 0.0, 0.3, 0.8, 0.99])
    np.testing.assert_allclose(spearman_from_latent(latent_from_spearman(rho)), rho, rtol=0, atol=1e-14)
    for r in rho:
        S = ot.CorrelationMatrix(2)
        S[0, 1] = float(r)
        assert ot.NormalCopula.GetCorrelationFromSpearmanCorrelation(S)[0, 1] == pytest.approx(
            float(latent_from_spearman(r)), abs=1e-14)


@pytest.mark.parametrize("table, groups, message", [
    ({"rho_1,foo": 0.3}, {}, "'foo' is neither an input"),
    ({"rho_1,rho_1": 0.3}, {}, "rho_1 is on both sides"),
    ({"rho_1,rho_2": 1.2}, {}, "strictly between -1 and 1"),
    ({"rho_1,rho_2": -1.0}, {}, "strictly between -1 and 1"),
    ({"rho_1,rho_2": "high"}, {}, "finite number"),
    ({"rho_1,rho_2": 0.3, "rho_2,rho_1": 0.2}, {}, "'rho_2,rho_1': the pair rho_2,rho_1 is given again"),
    ({"g": 0.3, "rho_1,rho_3": 0.2}, {"g": ["rho_1", "rho_3"]}, "already by 'g'"),
    ({"g,rho_2": 0.3}, {"g": ["rho_1", "rho_2"]}, "rho_2 is on both sides"),
    ({"zeta_1,rho_2": 0.2}, {}, "zeta_1 is a contact angle"),
    ({"clearance_1,theta_2": 0.2}, {}, "contact angle"),
    ({"rho_1": 0.3}, {}, "'rho_1' is an input"),
    ({"rho_1,rho_2,rho_3": 0.3}, {}, "a key is"),
    ({"rho_1,rho_2": 0.9, "rho_2,rho_3": 0.9, "rho_1,rho_3": -0.9}, {},
     "no joint law .* the pair rho_\\d,rho_\\d = .* is the one whose removal helps most"),
    ({"rho_1,rho_2": 0.9, "rho_2,rho_3": 0.9}, {}, "not positive definite.* pairs not given are uncorrelated"),
    ({"g": 0.9, "rho_1,b_1": 0.5, "rho_3,b_1": -0.5}, {"g": ["rho_1", "rho_2", "rho_3"]},
     "'rho_[13],b_1': .* the pair rho_[13],b_1 = -?0.5 is the one"),
])
def test_bad_tables_are_one_line(table, groups, message):
    with pytest.raises(BudgetError, match=message) as err:
        correlated(table, groups)
    assert "\n" not in str(err.value)


def test_a_loop_of_correlations_checked_as_a_whole():
    """Given one by one, 0.9, 0.8 then 0.9 pass through a matrix that is not positive definite; as a whole it is."""
    b = correlated({"rho_1,rho_2": 0.9, "rho_1,rho_3": 0.8, "rho_2,rho_3": 0.9}, {})
    assert np.linalg.eigvalsh(b.copula.latent)[0] > 0


def test_bad_table_from_the_command_line(tmp_path, capsys):
    path = tmp_path / "b.toml"
    correlated({"rho_1,rho_2": 0.5}).to_toml(path)
    path.write_text(path.read_text().replace("0.5", "1.5"))
    code = main(["worstcase", "--geometry", "u-shape", "--budget", str(path), "--pose", "0", "100", "0"])
    out, err = capsys.readouterr()
    assert code == 1 and out == "" and err.count("\n") == 1 and "strictly between -1 and 1" in err


# ------------------------------------------------------------------ the copula's laws
def test_marginals_are_the_laws(seed):
    """DKW: sup |F_n - F| <= sqrt(log(2 / 1e-6) / 2n) at the laws' quantiles; discrete classes within 5 SE."""
    b = mixed()
    n = 200_000
    X = b.sample(n, seed)
    eps = np.sqrt(np.log(2 / 1e-6) / (2 * n))
    q = np.linspace(0.001, 0.999, 199)
    for k, (name, law) in enumerate(b.factor_laws.items()):
        if isinstance(law, Discrete):
            freq = np.array([np.mean(X[:, k] == v) for v in law.values])
            se = np.sqrt(np.array(law.weights) * (1 - np.array(law.weights)) / n)
            assert np.all(np.abs(freq - law.weights) <= 5 * se), name
        else:
            ecdf = np.searchsorted(np.sort(X[:, k]), law.ppf(q), side="right") / n
            assert np.max(np.abs(ecdf - q)) <= eps, name


def test_realised_rank_correlations(seed):
    """Spearman's rho of every pair within 5 standard errors (Fieller's var(atanh rho_S) = 1.06 / (n - 3))."""
    b = mixed()
    n = 100_000
    X = b.sample(n, seed)
    se = np.sqrt(1.06 / (n - 3))
    cont = [k for k, law in enumerate(b.factor_laws.values()) if not isinstance(law, Discrete)]
    rho = stats.spearmanr(X[:, cont]).statistic
    names = [b.factors[k] for k in cont]
    for i, a in enumerate(names):
        for j, c in enumerate(names[:i]):
            want = 0.0
            if a in b.copula.names and c in b.copula.names:
                want = b.copula.spearman[b.copula.names.index(a), b.copula.names.index(c)]
            assert abs(np.arctanh(rho[i, j]) - np.arctanh(want)) <= 5 * se, (a, c, rho[i, j], want)


def test_pair_covariance_closed_forms_and_sampling(seed):
    u, n_, d = Uniform(0.0, 2.0), Normal(1.0, 0.5), Discrete((-0.1, 0.1), (0.5, 0.5))
    r = float(latent_from_spearman(0.6))
    assert pair_covariance(u, u, r) == pytest.approx(0.6 * u.var, rel=1e-9)                # Pearson = Spearman
    assert pair_covariance(n_, n_, r) == pytest.approx(r * n_.var, rel=1e-12)
    assert pair_covariance(n_, u, r) == pytest.approx(r * n_.sd * 2.0 / (2 * np.sqrt(np.pi)), rel=1e-9)
    assert pair_covariance(u, n_, r) == pytest.approx(pair_covariance(n_, u, r), rel=1e-9)
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((400_000, 2)) @ np.linalg.cholesky([[1, r], [r, 1]]).T
    for a, c in [(d, Triangular(0.0, 0.3, 1.0)), (Disc(0.016), TruncNormal(0.0, 1.0, 1.0)), (d, d)]:
        x, y = a.ppf(special.ndtr(z[:, 0])), c.ppf(special.ndtr(z[:, 1]))
        prod = (x - a.mean) * (y - c.mean)
        assert abs(pair_covariance(a, c, r) - prod.mean()) <= 5 * prod.std() / np.sqrt(len(prod))


def test_openturns_normal_copula_cross_check(seed):
    """OpenTURNS' NormalCopula of the same rank correlations: its draws' covariance is the budget's."""
    ot = pytest.importorskip("openturns")
    from prp3mc.model.interop import openturns_distribution
    b = mixed()
    dist = openturns_distribution(b)
    np.testing.assert_allclose(np.array(dist.getSpearmanCorrelation()),
                               _full(b.copula.spearman, b.copula.index, len(b.factors)), atol=1e-12)
    ot.RandomGenerator.SetSeed(seed % 2**31)
    n = 200_000
    X = np.array(dist.getSample(n))
    cov = b.covariance()
    Xc = X - X.mean(axis=0)
    prod = Xc[:, :, None] * Xc[:, None, :]
    se = prod.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(prod.mean(axis=0) - cov) <= 5 * se + 1e-18)


def _full(block, index, D):
    out = np.eye(D)
    out[np.ix_(index, index)] = block
    return out


# ------------------------------------------------------------------ what respects it
def test_linear_model_covariance_closed_form():
    """Normal inputs: Pearson = latent r; uniform inputs: Pearson = Spearman. Cov = J Sigma J^T."""
    g = Geometry.from_preset("u-shape")
    laws = {"theta_1": Normal(0.0, 0.02), "theta_2": Normal(0.01, 0.01), "b_1": Uniform(0.0, 0.025),
            "b_2": Uniform(-0.01, 0.01)}
    b = Budget(laws, correlation={"theta_1,theta_2": 0.7, "b_1,b_2": -0.4})
    model = linear_model(g, b, POSE)
    sd = np.sqrt(b.variances())
    corr = np.eye(4)
    corr[0, 1] = corr[1, 0] = float(latent_from_spearman(0.7))
    corr[2, 3] = corr[3, 2] = -0.4
    sigma = corr * np.outer(sd, sd)
    J = model.columns                                                       # (3, 4): per mm, per deg
    deg = np.array([1.0, 1.0, 180 / np.pi])
    want = (J @ sigma @ J.T) * np.outer(deg, deg)
    np.testing.assert_allclose(model.moments()[1], want, rtol=1e-9, atol=0)


def test_montecarlo_respects_the_correlation(seed):
    """Compiled sampler = numpy's copula to round-off; the sample covariance matches the exact one."""
    from .test_montecarlo_sampler import compiled_features
    g = Geometry.from_preset("u-shape")
    b = mixed()
    model = linear_model(g, b, POSE)
    ref = model.features(b.sample(3000, seed))
    got = compiled_features(b, model, seed, 0, 3000)
    assert np.max(np.abs(got - ref) / np.abs(ref).max(axis=0)) <= 1e-13
    r = monte_carlo(g, b, POSE, 200_000, rng=seed)
    mean, cov = model.moments()
    assert np.all(np.abs(r.cov - cov) <= 5 * r.cov_se + 1e-30)
    assert np.all(np.abs(r.mean - mean) <= 5 * r.mean_se)
    again = monte_carlo(g, b.replace(), POSE, 200_000, rng=seed)
    assert np.array_equal(again.cov, r.cov)                               # replace keeps the correlation
    independent = monte_carlo(g, Budget(b.inputs), POSE, 200_000, rng=seed)
    assert not np.array_equal(independent.cov, r.cov)


def test_worst_case_is_the_box_and_says_so(capsys, tmp_path):
    g = Geometry.from_preset("delta-shape")
    b = correlated()
    a, c = worst_case(g, b, [0, 160, 0]), worst_case(g, PAPER, [0, 160, 0])
    assert a.position_mm == c.position_mm and a.phi_deg == c.phi_deg
    assert main(["worstcase", "--geometry", "u-shape", "--budget", "paper", "--pose", "0", "100", "0",
                 "--json"]) == 0
    assert "correlation" not in json.loads(capsys.readouterr().out)
    path = str(tmp_path / "b.toml")
    b.to_toml(path)
    assert main(["worstcase", "--geometry", "u-shape", "--budget", path, "--pose", "0", "100", "0", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["correlation"] == CORRELATION_NOTE
    assert doc["inputs"]["budget"]["correlation"] == dict(b.correlation)
    assert main(["worstcase", "--geometry", "u-shape", "--budget", path, "--pose", "0", "100", "0"]) == 0
    assert CORRELATION_NOTE in capsys.readouterr().out
