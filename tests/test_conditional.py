"""P(either) by conditioning on two legs (prp3mc.stackup.conditional) against independent references.

- each leg's CDF against the closed form of a paper leg (the clearance rho cos(zeta - w), rho uniform, whose
  CDF is elementary, convolved with the trapezoid density of the guide's and the encoder's uniforms by
  SciPy's adaptive quadrature between the kinks);
- P(either) against the 3-D series where that converges (a normal law in every leg), within the sum of the
  two bounds;
- P(either) against Monte Carlo on the paper's budget, alone and with per-leg effects (a backlash, an offset,
  a lead scale), by the sampler of tests/test_yield.py, within the bound plus N_SE standard errors (2 poses;
  20 poses, both geometries, at 1e7 samples: slow).
"""

import math

import numpy as np
import pytest
from scipy import integrate, special

from prp3mc import Geometry, exact_yield
from prp3mc.model.budget import Budget
from prp3mc.model.effects import SystematicEffect
from prp3mc.model.laws import Normal, Uniform
from prp3mc.model.linear import linear_model
from prp3mc.stackup.characteristic import term_table
from prp3mc.stackup.conditional import CONDITIONAL_METHOD, independent_legs, joint_exceedance, leg_cdfs
from prp3mc.units import DEG2ARCSEC, MM2UM

from .realities import with_leads
from .test_yield import ARCSEC, N_SE, mixed_budget, poses_of, sample_exceedance


def _model(preset, budget, poses):
    m = linear_model(Geometry.from_preset(preset), budget, poses)
    T = len(m.terms)
    return m, m.columns.reshape(-1, 3, T), m.Ainv.reshape(-1, 3, 3)


def _clearance_cdf(x: float, R: float) -> float:
    """P(rho cos psi <= x), rho uniform on [0, R], psi uniform: for 0 <= x <= R, P(> x) =
    (R arccos(x/R) - x ln((R + sqrt(R² - x²))/x)) / (pi R); symmetric about 0."""
    a = abs(x)
    if a >= R:
        up = 0.0
    elif a == 0.0:
        up = 0.5
    else:
        up = (R * math.acos(a / R) - a * math.log((R + math.sqrt(R * R - a * a)) / a)) / (math.pi * R)
    return 1.0 - up if x >= 0 else up


def test_a_paper_leg_cdf_matches_its_closed_form():
    budget = Budget.load("paper")
    m, C, Ainv = _model("u-shape", budget, [10.0, 90.0, 2.0])
    table = term_table(m.term_laws, 8.0)
    kappa, ok = independent_legs(C, Ainv, m.legs, table)
    assert ok.all()
    cdf = leg_cdfs(kappa, m.legs, table, 0.0)
    assert cdf["eps"].max() < 2e-11
    leg = 1
    k_rho, k_theta, k_b = (kappa[0, m.terms.index(f"{f}_{leg + 1}")] for f in ("rho", "theta", "b"))
    th = sorted((k_theta * -0.04, k_theta * 0.04))
    bb = sorted((k_b * 0.0, k_b * 0.025))
    R = abs(k_rho) * 0.016

    lo, hi = th[0] + bb[0], th[1] + bb[1]
    short, long = sorted((th[1] - th[0], bb[1] - bb[0]))

    def trapezoid(v):                                  # density of the sum of the two uniforms
        return min(v - lo, hi - v, short) / (short * long) if lo < v < hi else 0.0

    def reference(x):                                  # quad between the kinks of both factors
        kinks = sorted({lo, lo + short, hi - short, hi, x - R, x, x + R})
        kinks = [k for k in kinks if lo <= k <= hi]
        parts = [integrate.quad(lambda v: _clearance_cdf(x - v, R) * trapezoid(v), a, b, epsabs=1e-15,
                                epsrel=1e-13, limit=200) for a, b in zip(kinks[:-1], kinks[1:])]
        return sum(p[0] for p in parts), sum(p[1] for p in parts)
    M = cdf["M"]
    for j in (M // 16, M // 2 + 123, 15 * M // 16):
        x = cdf["lo"][0, leg] + j * cdf["h"][0, leg]
        ref, err = reference(x)
        assert abs(cdf["F"][0, leg, j] - ref) <= cdf["eps"][0, leg] + err, (j, cdf["F"][0, leg, j], ref)


def _normal_legs() -> Budget:
    return Budget({"theta_1": Normal(0.0, 0.012), "b_1": Normal(0.002, 0.006), "theta_2": Normal(0.0, 0.015),
                   "b_2": Normal(0.0, 0.005), "theta_3": Normal(0.001, 0.01), "b_3": Normal(0.0, 0.008)}, name="nl")


def _paper_normal_encoders() -> Budget:
    """The paper's clearances and guide plays, its encoder errors normal (same mean and sd as its uniforms)."""
    inputs = dict(Budget.load("paper").factor_laws)
    inputs.update({f"b_{i}": Normal(0.0125, 0.025 / math.sqrt(12.0)) for i in (1, 2, 3)})
    return Budget(inputs, name="paper, normal encoders")


@pytest.mark.parametrize("which", ["normal legs", "paper, normal encoders"])
def test_conditioning_agrees_with_the_joint_series(which):
    """Where the 3-D series serves (a normal law in every leg) it is the reference: P_pos + P_phi - J by
    conditioning agrees with its P(either) within the sum of the bounds."""
    budget = _normal_legs() if which == "normal legs" else _paper_normal_encoders()
    poses = np.array([[0.0, 100.0, 0.0], [25.0, 75.0, -3.0]])
    geometry = Geometry.from_preset("u-shape")
    r0 = exact_yield(geometry, budget, poses, spec_position_um=1.0, quantiles=False)
    S_um = float(np.median(r0.rss_position_mm)) * MM2UM * 0.8
    Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC * 0.8
    r = exact_yield(geometry, budget, poses, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
    assert not r.bracketed_any.any() and CONDITIONAL_METHOD not in r.method and r.bound_any.max() <= 1e-9
    m, C, Ainv = _model("u-shape", budget, poses)
    share = 1e-13
    table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
    kappa, ok = independent_legs(C, Ainv, m.legs, table)
    assert ok.all()
    J_lo, J_hi = joint_exceedance(C, Ainv, m.legs, table, kappa, S_um / MM2UM, Z_as * ARCSEC, 1e-9, share)
    e = r.exceed_position + r.exceed_phi - 0.5 * (J_lo + J_hi)
    b = 0.5 * (J_hi - J_lo) + r.bound_position + r.bound_phi
    assert np.all(J_lo <= J_hi) and np.all(J_lo > 0)
    assert np.all(np.abs(e - r.exceed_any) <= b + r.bound_any), (e, r.exceed_any, b, r.bound_any)
    print(f"{which}: P(either) {r.exceed_any}, |cond - series| {np.abs(e - r.exceed_any)}, cond bound {b}")


def test_the_paper_budget_is_conditioned_not_bracketed():
    """The paper's budget: P(either) by conditioning, its bound below the Fréchet bracket's; so is a budget
    with a term of all legs (the temperature, conditioned on too)."""
    geometry = Geometry.from_preset("u-shape")
    pose = [5.0, 95.0, 1.0]
    with pytest.warns(Warning):
        br = exact_yield(geometry, "paper", pose, spec_position_um=80.0, spec_phi_arcsec=30.0, quantiles=False,
                         joint=False)
    r = exact_yield(geometry, "paper", pose, spec_position_um=80.0, spec_phi_arcsec=30.0, quantiles=False)
    assert bool(br.bracketed_any) and not bool(r.bracketed_any)
    assert CONDITIONAL_METHOD in r.method and CONDITIONAL_METHOD not in br.method
    assert float(r.bound_any) < float(br.bound_any)
    assert abs(float(r.exceed_any) - float(br.exceed_any)) <= float(r.bound_any + br.bound_any)
    geometry = with_leads(geometry)
    mixed = exact_yield(geometry, mixed_budget(geometry), pose, spec_position_um=60.0, spec_phi_arcsec=30.0,
                        quantiles=False)
    assert not bool(mixed.bracketed_any) and CONDITIONAL_METHOD in mixed.method


def _paper_with_effects(geometry) -> Budget:
    """The paper's budget with per-leg effects: a backlash (±h/2, a discrete law in leg 2), an offset and a
    lead scale (known shifts)."""
    effects = {"backlash_2": SystematicEffect("backlash_2", 0.01), "a_1": SystematicEffect("a_1", 0.01),
               "scale_3": SystematicEffect("scale_3", 1.5e-4)}
    return Budget.load("paper").with_effects(effects, fitted_on=geometry)


def _against_monte_carlo(preset, poses, n, seed, spec_um, spec_as, effects=False):
    geometry = with_leads(Geometry.from_preset(preset))
    budget = _paper_with_effects(geometry) if effects else Budget.load("paper")
    r = exact_yield(geometry, budget, poses, spec_position_um=spec_um, spec_phi_arcsec=spec_as, quantiles=False)
    assert (CONDITIONAL_METHOD in r.method) == bool((~r.bracketed_any).any())     # the series never serves here
    mc = sample_exceedance(linear_model(geometry, budget, poses), n, np.random.default_rng(seed), spec_um / MM2UM,
                           spec_as * ARCSEC)[2]
    se = np.sqrt(np.maximum(r.exceed_any, 1.0 / n) * (1.0 - r.exceed_any) / n)
    excess = np.abs(mc - r.exceed_any) - r.bound_any - N_SE * se
    assert np.all(excess <= 0.0), (mc, r.exceed_any, r.bound_any, se)
    z = np.abs(mc - r.exceed_any) / (r.bound_any + se)
    print(f"{preset} S={spec_um} µm Z={spec_as} arcsec n={n}: P(either) {r.exceed_any.min():.3g}.."
          f"{r.exceed_any.max():.3g}, bound {r.bound_any.min():.2g}..{r.bound_any.max():.2g}, largest "
          f"|exact - MC| / (bound + se) = {z.max():.2f}; {int(r.bracketed_any.sum())} pose(s) of {z.size} kept the "
          "bracket (its bound the smaller)")


@pytest.mark.parametrize("effects", [False, True])
def test_paper_budget_agrees_with_monte_carlo(effects, seed):
    poses = poses_of("u-shape", 2, np.random.default_rng(seed))
    _against_monte_carlo("u-shape", poses, 200_000, seed, 80.0, 30.0, effects)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
@pytest.mark.parametrize("specs", [(80.0, 30.0), (120.0, 60.0)])
def test_paper_budget_agrees_with_1e7_samples_at_20_poses(preset, specs, seed):
    poses = poses_of(preset, 20, np.random.default_rng(seed))
    _against_monte_carlo(preset, poses, 10_000_000, seed, *specs)


@pytest.mark.slow
def test_paper_budget_with_effects_agrees_with_1e7_samples_at_20_poses(seed):
    poses = poses_of("delta-shape", 20, np.random.default_rng(seed))
    _against_monte_carlo("delta-shape", poses, 10_000_000, seed, 90.0, 40.0, effects=True)


def paper_legs(poses, spec_um, spec_as):
    """The arguments of prp3mc.stackup.conditional.joint_exceedance for the paper's budget (U-shape) at ``poses``."""
    m = linear_model(Geometry.from_preset("u-shape"), Budget.load("paper"), poses)
    C, Ainv = m.columns.reshape(-1, 3, len(m.terms)), m.Ainv.reshape(-1, 3, 3)
    share = 1e-11
    table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
    kappa, ok = independent_legs(C, Ainv, m.legs, table)
    assert ok.all()
    return (C, Ainv, m.legs, table, kappa, spec_um / MM2UM, spec_as * ARCSEC, 1e-9, share)


def test_threads_and_chunks_leave_every_bit():
    """The poses run in chunks on threads: J's bracket at each pose is the same to the bit on one thread (one
    chunk) and on three (a pose a chunk), and the same as the pose alone."""
    poses = np.array([[-20.0, 80.0, 2.0], [15.0, 110.0, -3.0], [30.0, 95.0, 0.0]])
    args = paper_legs(poses, 100.0, 60.0)
    serial = joint_exceedance(*args, workers=1)
    threaded = joint_exceedance(*args, workers=3)
    alone = joint_exceedance(*(a[1:2] if k in (0, 1, 4) else a for k, a in enumerate(args)), workers=1)
    assert all(np.array_equal(a, b) for a, b in zip(serial, threaded))
    assert all(np.array_equal(a[1:2], b) for a, b in zip(serial, alone))
    assert np.all(serial[0] < serial[1])
