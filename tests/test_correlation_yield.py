"""The yield of a correlated budget (SPEC §9 and §10): exact when the correlated inputs are all normal, Monte
Carlo with the copula otherwise.

References, each independent of the series:

- closed forms: a budget of normal laws only is a 3-D Gaussian pose error, its covariance from the budget's
  own covariance (:meth:`Budget.covariance`, the copula's pair covariances) and the linear model's columns;
  P(|position| > S) by scipy's adaptive quadrature of the bivariate normal over the disc, P(``|dphi|`` > Z)
  by scipy.stats.norm, P(either) by nested quadrature over the disc of the conditional normal of dphi;
- Monte Carlo: the package's streamed sampler with the copula (tolerance from the binomial standard
  error, any seed), and a direct numpy count on the same draws (``budget.sample``) for its new
  |dphi| and either counters.
"""

import math

import numpy as np
import pytest
from scipy import integrate, stats

from prp3mc import Geometry, exact_yield, monte_carlo
from prp3mc.errors import BudgetError
from prp3mc.model.budget import Budget
from prp3mc.model.laws import Normal, Uniform
from prp3mc.model.linear import linear_model
from prp3mc.stackup.gaussian import GAUSSIAN_TERMS, exact_refusal, gaussian_terms
from prp3mc.units import DEG2ARCSEC, MM2UM

from .test_yield import poses_of

N_SE = 5.0
QUAD_ERR = 1e-11             # the quadratures' own error (absolute, in probability)


def normal_budget(rng=None) -> Budget:
    """Normal laws only, correlated within and across legs and families (a group and pairs)."""
    sd = {"theta": 0.015, "b": 0.006, "c": 0.004} if rng is None else \
        {k: v * rng.uniform(0.5, 1.5) for k, v in {"theta": 0.015, "b": 0.006, "c": 0.004}.items()}
    inputs = {f"{f}_{i}": Normal(0.002 if f == "b" else 0.0, sd[f]) for f in ("theta", "b") for i in (1, 2, 3)}
    inputs |= {"c_2": Normal(0.0, sd["c"])}
    return Budget(inputs, name="normals", groups={"screws": ("b_1", "b_2", "b_3")},
                  correlation={"screws": 0.6, "theta_1,theta_2": -0.5, "theta_3,c_2": 0.7, "b_1,theta_3": 0.3})


def mixed_budget() -> Budget:
    """Correlated normal inputs beside independent uniform ones and a clearance."""
    return Budget({"theta_1": Normal(0.0, 0.012), "theta_2": Normal(0.0, 0.012), "theta_3": Uniform(-0.04, 0.04),
                   "b_1": Uniform(0.0, 0.025), "b_2": Normal(0.0, 0.006), "b_3": Normal(0.001, 0.006),
                   "rho_2": Uniform(0.0, 0.016), "zeta_2": Uniform(0.0, 360.0)}, name="mixed",
                  correlation={"theta_1,theta_2": 0.8, "b_2,b_3": 0.6, "theta_1,b_3": -0.3})


def gaussian_pose(geometry, budget, pose):
    """Mean (3,) and covariance (3, 3) of (dx mm, dy mm, dphi rad) of an all-normal budget, from the budget's
    covariance (not from :mod:`prp3mc.stackup.gaussian`)."""
    m = linear_model(geometry, budget, pose)
    idx = [budget.factors.index(t) for t in m.terms]
    C = m.columns
    mean = C @ np.array([budget.factor_laws[t].mean for t in m.terms])
    return mean, C @ budget.covariance()[np.ix_(idx, idx)] @ C.T


def disc_inside(mean, cov, S, inner=None):
    """P(|(X, Y)| <= S) of a bivariate normal, by quadrature over x of the conditional normal of y; with ``inner``
    (a function of x, y) the integrand is weighted by it (nested quadrature over y)."""
    sx = math.sqrt(cov[0, 0])
    beta = cov[0, 1] / cov[0, 0]
    sc = math.sqrt(cov[1, 1] - beta * cov[0, 1])

    def over_x(x):
        h = math.sqrt(max(S * S - x * x, 0.0))
        my = mean[1] + beta * (x - mean[0])
        if inner is None:
            mass = stats.norm.cdf((h - my) / sc) - stats.norm.cdf((-h - my) / sc)
        else:
            mass = integrate.quad(lambda y: stats.norm.pdf(y, my, sc) * inner(x, y), -h, h, epsabs=1e-14,
                                  epsrel=1e-12, limit=200)[0]
        return stats.norm.pdf(x, mean[0], sx) * mass

    return integrate.quad(over_x, -S, S, epsabs=1e-14, epsrel=1e-12, limit=200)[0]


# ------------------------------------------------------------------ the decomposition

def test_the_gaussian_terms_keep_the_joint_law(seed):
    """The independent terms that replace the correlated normal factors have the same mean and covariance of
    the pose error at every pose (a Gaussian law is its first two moments)."""
    rng = np.random.default_rng(seed)
    geometry = Geometry.from_preset(str(rng.choice(["u-shape", "delta-shape"])))
    budget = normal_budget(rng)
    poses = poses_of(geometry.name, 5, rng)
    m = linear_model(geometry, budget, poses)
    C = m.columns
    laws, legs, C2 = gaussian_terms(budget, m.term_laws, m.legs, C)
    assert len(laws) == len(legs) == C2.shape[-1] and 1 <= len(laws) - len(m.term_laws) <= 3
    assert [tl.name for tl in laws[len(m.term_laws):]] == list(GAUSSIAN_TERMS[:len(laws) - len(m.term_laws)])
    var = np.array([tl.law.var for tl in laws])
    mean = np.array([tl.law.mean for tl in laws])
    idx = [budget.factors.index(t) for t in m.terms]
    want = C @ budget.covariance()[np.ix_(idx, idx)] @ np.swapaxes(C, -1, -2)
    np.testing.assert_allclose(np.einsum("pit,t,pjt->pij", C2, var, C2), want, rtol=1e-10,
                               atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(np.einsum("pit,t->pi", C2, mean),
                               C @ np.array([budget.factor_laws[t].mean for t in m.terms]), atol=1e-15)
    lam = np.linalg.eigvalsh(budget.copula.latent)[0]
    for tl, old in zip(laws, m.term_laws):          # each correlated input keeps sqrt(lambda) of its sd
        assert tl.law.sd == pytest.approx(old.law.sd * math.sqrt(lam))
    independent = Budget({k: v for k, v in budget.factor_laws.items()}, name="independent")
    assert gaussian_terms(independent, m.term_laws, m.legs, C)[0] == m.term_laws


def test_only_all_normal_correlations_are_exact():
    assert exact_refusal(normal_budget()) is None and exact_refusal(mixed_budget()) is None
    assert exact_refusal(Budget.load("paper")) is None
    corr = Budget(Budget.load("paper").factor_laws, name="p", correlation={"theta_1,theta_2": 0.6, "rho_1,rho_2": 0.5})
    why = exact_refusal(corr)
    assert "rho_1 (uniform)" in why and "theta_1 (uniform)" in why
    with pytest.raises(BudgetError, match=r"not normal: .*tolerance_phi_deg=Z"):
        exact_yield("u-shape", corr, [10.0, 120.0, 0.0], spec_position_um=100.0)


# ------------------------------------------------------------------ closed forms

def closed_form_case(preset, seed):
    """An all-normal correlated budget at a random pose, specs near 1-2.5 sd: the exact result (with the joint
    series), the Gaussian's mean and covariance, S (mm) and Z (rad)."""
    rng = np.random.default_rng(seed)
    geometry, budget = Geometry.from_preset(preset), normal_budget(rng)
    pose = poses_of(preset, 1, rng)[0]
    mean, cov = gaussian_pose(geometry, budget, pose)
    S = float(rng.uniform(1.0, 2.5) * math.sqrt(np.trace(cov[:2, :2])))
    Z = float(rng.uniform(1.0, 2.5) * math.sqrt(cov[2, 2]))
    r = exact_yield(geometry, budget, pose, spec_position_um=MM2UM * S, spec_phi_arcsec=math.degrees(Z) * DEG2ARCSEC,
                    quantiles=False)
    assert "jointly normal" in r.method
    return r, mean, cov, S, Z


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_all_normal_correlated_budget_matches_the_gaussian_closed_forms(preset, seed):
    """Position: the bivariate normal over the disc; |dphi|: the normal law — within the reported bound (itself
    within the target) plus the quadrature's error."""
    r, mean, cov, S, Z = closed_form_case(preset, seed)
    sz = math.sqrt(cov[2, 2])
    refs = {"position": 1.0 - disc_inside(mean, cov, S),
            "phi": stats.norm.sf(Z, mean[2], sz) + stats.norm.cdf(-Z, mean[2], sz)}
    for o, bound in (("position", r.bound_position), ("phi", r.bound_phi)):
        assert abs(float(r.exceedance(o)) - refs[o]) <= float(bound) + QUAD_ERR, (o, float(r.exceedance(o)), refs[o])
        assert float(bound) <= r.target


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_either_matches_the_gaussian_over_the_cylinder(preset, seed):
    """P(either) of the all-normal correlated budget: nested quadrature over the disc of the conditional normal
    law of dphi given (dx, dy), within the reported bound (which may exceed the target: the joint series
    is the slow one) plus the quadrature's error."""
    r, mean, cov, S, Z = closed_form_case(preset, seed)
    gain = np.linalg.solve(cov[:2, :2], cov[:2, 2])
    sd_c = math.sqrt(cov[2, 2] - cov[2, :2] @ gain)

    def phi_in_given(x, y):
        mu = mean[2] + gain @ np.array([x - mean[0], y - mean[1]])
        return stats.norm.cdf((Z - mu) / sd_c) - stats.norm.cdf((-Z - mu) / sd_c)

    ref = 1.0 - disc_inside(mean, cov, S, phi_in_given)
    assert abs(float(r.exceed_any) - ref) <= float(r.bound_any) + QUAD_ERR, (float(r.exceed_any), ref)


# ------------------------------------------------------------------ Monte Carlo with the copula

def check_monte_carlo(geometry, budget, poses, n, seed):
    """Exact vs prp3mc.monte_carlo with the copula, all three channels: within the bound plus N_SE standard errors."""
    r0 = exact_yield(geometry, budget, poses, spec_position_um=1.0, quantiles=False)
    S = float(np.median(r0.rss_position_mm)) / 2.0
    Z = float(np.median(r0.rss_phi_deg)) / 2.0
    r = exact_yield(geometry, budget, poses, spec_position_um=MM2UM * S, spec_phi_arcsec=DEG2ARCSEC * Z,
                    quantiles=False)
    mc = monte_carlo(geometry, budget, poses, n, rng=seed, tolerance_mm=S, tolerance_phi_deg=Z, percentiles=(50.0,))
    for exact, bound, p in ((r.exceed_position, r.bound_position, mc.exceed_prob),
                            (r.exceed_phi, r.bound_phi, mc.exceed_phi_prob), (r.exceed_any, r.bound_any,
                                                                              mc.exceed_any_prob)):
        se = np.sqrt(np.maximum(exact, 1.0 / n) * (1.0 - exact) / n)
        assert np.all(np.abs(p - exact) <= bound + N_SE * se), (exact, p, bound, se)
    return r


def test_exact_agrees_with_monte_carlo_with_the_copula(seed):
    rng = np.random.default_rng(seed)
    geometry = Geometry.from_preset("delta-shape")
    check_monte_carlo(geometry, mixed_budget(), poses_of("delta-shape", 2, rng), 100_000, seed)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_exact_agrees_with_1e7_copula_samples(preset, seed):
    rng = np.random.default_rng(seed)
    geometry = Geometry.from_preset(preset)
    for budget in (mixed_budget(), normal_budget(rng)):
        check_monte_carlo(geometry, budget, poses_of(preset, 5, rng), 10_000_000, seed)


def test_monte_carlo_counts_phi_and_either_on_its_own_draws(seed):
    """The streamed sampler's new counters equal a direct count on the same draws (``budget.sample``), for a
    correlated budget the exact series cannot take (uniform laws)."""
    geometry = Geometry.from_preset("u-shape")
    budget = Budget(Budget.load("paper").factor_laws, name="p", correlation={"theta_1,theta_2": 0.6, "b_2,b_3": -0.4})
    pose = poses_of("u-shape", 1, np.random.default_rng(seed))
    n = 50_000
    S, Z = 0.03, 20.0 / DEG2ARCSEC
    mc = monte_carlo(geometry, budget, pose, n, rng=seed, tolerance_mm=S, tolerance_phi_deg=Z, percentiles=(50.0,))
    e = linear_model(geometry, budget, pose).evaluate(budget.sample(n, seed))[0]
    over_pos = np.hypot(e[:, 0], e[:, 1]) > S
    over_phi = np.abs(np.degrees(e[:, 2])) > Z
    for p, count in ((mc.exceed_prob, over_pos.sum()), (mc.exceed_phi_prob, over_phi.sum()),
                     (mc.exceed_any_prob, (over_pos | over_phi).sum())):
        assert abs(float(p[0]) * n - count) <= 2           # float32 in the kernel: a value at the threshold may flip
    frame = mc.conf_int(statistic="exceed")
    assert set(frame["output"]) == {"position", "phi", "any"} and set(frame["method"]) == {"wilson"}
    assert np.all((frame["ci_low"] <= frame["value"]) & (frame["value"] <= frame["ci_high"]))
