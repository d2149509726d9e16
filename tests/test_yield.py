"""The exact yield (prp3mc.stackup, SPEC §9) against independent references.

Every comparison checks the *reported* bound: |exact - reference| <= error bound (+ the reference's own
error: exact arithmetic, OpenTURNS' precision, or the Monte Carlo standard error times N_SE).

- closed forms: a weighted sum of uniforms (the Irwin–Hall corner formula in exact rational arithmetic)
  and a single disc clearance (the marginal of a uniform point in a disc);
- OpenTURNS' LinearCombinationDistribution (ex RandomMixture) on budgets of uniform, normal and
  triangular laws (the dphi channel, a scalar linear combination);
- Monte Carlo: a sampler written here (numpy, the laws' quantile functions, the clearance through
  (rho cos zeta, rho sin zeta)), and the package's streamed Monte Carlo for the position.
"""

import math
from fractions import Fraction
from itertools import combinations

import numpy as np
import pytest
from numba import njit

from prp3mc import Geometry, Region, exact_yield, monte_carlo
from prp3mc.errors import BudgetError, SpecError
from prp3mc.model.budget import Budget
from prp3mc.model.effects import SystematicEffect
from prp3mc.model.laws import Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from prp3mc.model.linear import linear_model
from prp3mc.stackup import OUTPUTS, QUANTILE_LEVELS
from prp3mc.units import DEG2ARCSEC, DEG2RAD, MM2UM

from .realities import with_leads

N_SE = 5.0                      # Monte Carlo tolerance in standard errors (240 comparisons in the slow run)
ARCSEC = DEG2RAD / DEG2ARCSEC   # rad per arcsec


# ------------------------------------------------------------------ budgets

def uniform_budget() -> Budget:
    """Only uniform inputs off the clearances: dphi is a weighted sum of uniforms."""
    inputs = {f"theta_{i}": Uniform(-0.04, 0.04) for i in (1, 2, 3)}
    inputs.update({f"b_{i}": Uniform(0.0, 0.025) for i in (1, 2, 3)})
    inputs.update({"a_1": Uniform(-0.01, 0.02), "c_2": Uniform(-0.015, 0.015)})
    return Budget(inputs, name="uniforms")


def ot_budget() -> Budget:
    """Uniform, normal and triangular laws: what OpenTURNS' linear combination represents."""
    return Budget({"theta_1": Uniform(-0.04, 0.04), "theta_2": Normal(0.0, 0.012),
                   "theta_3": Triangular(-0.03, 0.01, 0.04),
                   "b_1": Normal(0.002, 0.006), "b_2": Uniform(0.0, 0.025), "b_3": Triangular(0.0, 0.02, 0.025),
                   "c_1": Uniform(-0.01, 0.01)}, name="ot")


def mixed_budget(geometry: Geometry) -> Budget:
    """Every law prp3mc has and every effect: clearances with uniform, disc and discrete radii, a truncated
    normal, a discrete class, a triangular and a normal law; an offset, a lead scale, a cyclic error, a
    backlash and the shared temperature."""
    inputs = {"rho_1": Uniform(0.0, 0.016), "zeta_1": Uniform(0.0, 360.0),
              "rho_2": Disc(0.012), "zeta_2": Uniform(0.0, 360.0),
              "rho_3": Discrete((0.004, 0.008, 0.012), (0.3, 0.5, 0.2)), "zeta_3": Uniform(0.0, 360.0),
              "theta_1": TruncNormal(0.0, 0.04, 1.0), "theta_2": Uniform(-0.04, 0.04),
              "theta_3": Triangular(-0.04, 0.0, 0.04),
              "b_1": Uniform(0.0, 0.025), "b_2": Discrete((-0.005, 0.0, 0.005), (0.25, 0.5, 0.25)),
              "b_3": Normal(0.0, 0.006)}
    effects = {"a_1": SystematicEffect("a_1", 0.01), "scale_2": SystematicEffect("scale_2", 1.5e-4),
               "cyclic_3": SystematicEffect("cyclic_3", 0.008, phase_deg=40.0),
               "backlash_1": SystematicEffect("backlash_1", 0.02),
               "thermal": SystematicEffect("thermal", 1.2e-5, temp_range_C=(15.0, 30.0))}
    return Budget(inputs, name="mixed").with_effects(effects, fitted_on=geometry)


def poses_of(preset: str, n: int, rng) -> np.ndarray:
    region = Region.from_preset(preset)
    return np.stack([rng.uniform(*region.x_mm, n), rng.uniform(*region.y_mm, n), rng.uniform(-5.0, 5.0, n)], axis=-1)


# ------------------------------------------------------------------ closed forms

def uniform_sum_cdf(weights_lo_hi, x: float) -> Fraction:
    """P(sum_t w_t U_t <= x), U_t uniform on [lo_t, hi_t]: the corner formula, exactly (rationals)."""
    base = Fraction(0)
    widths = []
    for w, lo, hi in weights_lo_hi:
        a, b = Fraction(w) * Fraction(lo), Fraction(w) * Fraction(hi)
        base += min(a, b)
        if a != b:
            widths.append(abs(b - a))
    n = len(widths)
    y = Fraction(x) - base
    total = Fraction(0)
    for k in range(n + 1):
        for subset in combinations(widths, k):
            r = y - sum(subset, Fraction(0))
            if r > 0:
                total += (-1) ** k * r ** n
    prod = Fraction(1)
    for w in widths:
        prod *= w
    return total / (math.factorial(n) * prod)


def test_dphi_of_a_sum_of_uniforms_matches_the_irwin_hall_corner_formula():
    geometry, budget = Geometry.from_preset("u-shape"), uniform_budget()
    poses = np.array([[-25.0, 130.0, 3.0], [30.0, 70.0, -4.0]])
    model = linear_model(geometry, budget, poses)
    for spec_as, quantiles in ((20.0, False), (60.0, True)):
        r = exact_yield(geometry, budget, poses, spec_position_um=60.0, spec_phi_arcsec=spec_as, quantiles=quantiles)
        for k in range(poses.shape[0]):
            terms = [(model.columns[k, 2, t], tl.law.lo, tl.law.hi) for t, tl in enumerate(model.term_laws)]
            z = spec_as * ARCSEC
            inside = float(uniform_sum_cdf(terms, z) - uniform_sum_cdf(terms, -z))
            assert abs(r.exceed_phi[k] - (1.0 - inside)) <= r.bound_phi[k] + 1e-15
            assert r.bound_phi[k] <= r.target
            # the quantiles: the closed form's P(|dphi| <= q -/+ err) brackets the level
            for q, level in enumerate(r.levels if quantiles else ()):
                zq, err = r.quantile_phi_deg[k, q] * DEG2RAD, r.quantile_phi_err_deg[k, q] * DEG2RAD
                below = float(uniform_sum_cdf(terms, zq - err) - uniform_sum_cdf(terms, -(zq - err)))
                above = float(uniform_sum_cdf(terms, zq + err) - uniform_sum_cdf(terms, -(zq + err)))
                assert below <= level / 100.0 + 1e-15 and above >= level / 100.0 - 1e-15


def disc_cdf(u):
    """P(X <= u) for X the x-coordinate of a point uniform in the unit disc."""
    u = np.clip(u, -1.0, 1.0)
    return 0.5 + (u * np.sqrt(1.0 - u * u) + np.arcsin(u)) / np.pi


def test_a_disc_clearance_matches_its_closed_form():
    """rho uniform over a disc of radius r: rho cos(zeta - omega) is the disc's marginal (closed CDF). On the
    u-shape at (0, 100, 0) leg 3 does not move phi (A^-1's entry is ~1e-19): with the disc and a uniform play
    theta_1 on leg 1 and normal laws on leg 3 (the position has a 2-D density), dphi = c_d X + c_t theta_1 and
    P(|dphi| <= z) is the disc's closed CDF averaged over theta_1 (one quadrature, to 1e-14)."""
    from scipy import integrate

    geometry = Geometry.from_preset("u-shape")
    r_mm, a = 0.012, 0.04
    budget = Budget({"rho_1": Disc(r_mm), "zeta_1": Uniform(0.0, 360.0), "theta_1": Uniform(-a, a),
                     "theta_3": Normal(0.0, 0.02), "b_3": Normal(0.0, 0.01)}, name="disc")
    pose = np.array([0.0, 100.0, 0.0])
    model = linear_model(geometry, budget, pose)
    c = model.columns[2, :]
    kd, kt = model.terms.index("rho_1"), model.terms.index("theta_1")
    assert np.all(np.abs(np.delete(c, [kd, kt])) < 1e-17)
    cd, ct = abs(c[kd]) * r_mm, c[kt]
    for spec_as in (20.0, 60.0, 90.0):
        z = spec_as * ARCSEC

        def inside(t):
            return disc_cdf((z - ct * t) / cd) - disc_cdf((-z - ct * t) / cd)

        kinks = sorted({float(np.clip(v, -a, a)) for v in ((z - cd) / ct, (z + cd) / ct, (-z - cd) / ct,
                                                            (-z + cd) / ct)})
        ref = 1.0 - integrate.quad(inside, -a, a, points=kinks, epsabs=1e-15, epsrel=1e-14, limit=200)[0] / (2 * a)
        r = exact_yield(geometry, budget, pose, spec_position_um=30.0, spec_phi_arcsec=spec_as, quantiles=False)
        assert abs(r.exceed_phi - ref) <= r.bound_phi + 1e-13
        assert r.bound_phi <= r.target
    # one leg alone moves the position along a line: no 2-D density, said in one line
    alone = Budget({"rho_1": Disc(r_mm), "zeta_1": Uniform(0.0, 360.0)}, name="disc alone")
    with pytest.raises(Exception, match="no density"):
        exact_yield(geometry, alone, pose, spec_position_um=10.0)


# ------------------------------------------------------------------ the sum's rotated sines

@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_the_rotated_sines_of_the_sum_agree_with_direct_sines(preset):
    """The sum takes a centred uniform's sin(u) along a row by rotation (restart every 16 steps): its coefficients
    stay within 1e-14 of those with sin(u) afresh at every point (restart 0), far inside the 1e-13 a coefficient
    the bound allows (CF_ACCURACY), at poses of the paper budget (the mixed leg: two uniforms and a clearance)
    and of the budget mixing every law (a uniform in the mixed leg, the thermal term off every basis)."""
    from prp3mc.stackup.characteristic import term_table
    from prp3mc.stackup.lattice import channel
    from prp3mc.stackup.series import _RESTART, _coefficients
    from prp3mc.stackup.truncation import select_points
    from prp3mc.stackup._special import CF_ACCURACY, special_args

    geometry = with_leads(Geometry.from_preset(preset))
    poses = poses_of(preset, 3, np.random.default_rng(7))
    assert _RESTART == 16
    for budget in (Budget.from_preset("paper"), mixed_budget(geometry)):
        model = linear_model(geometry, budget, poses)
        C = model.columns.reshape(-1, 3, len(model.terms))
        table = term_table(model.term_laws, 8.0)
        ch = channel("position", C, model.Ainv.reshape(-1, 3, 3), np.array(model.legs), table, np.full(3, 0.1))
        tab, sp = table.arrays(), special_args()
        for i in range(3):
            pts = select_points(2, table.env, ch.grp[i], ch.mu[i], ch.Q[i], ch.Vinv[i], ch.mnorm[i], ch.ab[i],
                                ch.lam[i], 0.1, 0.0, 1e-9)[0]
            args = (2, table.kind, table.par, tab, sp, ch.grp[i], ch.mu[i], ch.snu[i], ch.Q[i], ch.Vinv[i], pts,
                    0.1, 0.0)
            direct, rotated = _coefficients(*args, 0), _coefficients(*args, _RESTART)
            assert np.any(direct[0] != rotated[0])                     # the rotation ran
            assert np.abs(direct[0] - rotated[0]).max() <= 1e-14 < CF_ACCURACY
            assert np.abs(direct[3] - rotated[3]).max() <= 1e-14 * direct[3].max()   # |re| times T_D's bound
            for a, b in zip((*direct[1:3], direct[4]), (*rotated[1:3], rotated[4])):   # T_D's arguments, bound
                assert np.array_equal(a, b)


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_the_points_the_sum_leaves_out_are_within_their_bound(preset):
    """The sum leaves out the points whose terms' bounds (``|Re phi|`` times T_D's bound) total at most its room,
    and reports that total: the series over the points kept stays within it of the series over every point, at
    every radius up to z1 (computed point by point, the quantiles' P(z)), at poses of both budgets and of the
    three channels; with no room it keeps every point and sums them in their order (to the bit)."""
    from prp3mc.stackup.characteristic import term_table
    from prp3mc.stackup.lattice import channel
    from prp3mc.stackup.series import _RESTART, _coefficients, _prob, _sum
    from prp3mc.stackup.truncation import select_points
    from prp3mc.stackup._special import special_args

    geometry = with_leads(Geometry.from_preset(preset))
    poses = poses_of(preset, 2, np.random.default_rng(11))
    sp = special_args()
    ran = set()
    normals = Budget({**{f"theta_{i}": Normal(0.0, 0.02) for i in (1, 2, 3)},
                      **{f"b_{i}": Uniform(0.0, 0.025) for i in (1, 2, 3)}}, name="normal legs")   # a 3-D series
    for budget in (Budget.from_preset("paper"), mixed_budget(geometry), normals):
        model = linear_model(geometry, budget, poses)
        C = model.columns.reshape(-1, 3, len(model.terms))
        table = term_table(model.term_laws, 8.0)
        tab = table.arrays()
        for which, z1, z2 in (("phi", 5e-5, 0.0), ("position", 0.1, 0.0), ("both", 0.1, 5e-5)):
            ch = channel(which, C, model.Ainv.reshape(-1, 3, 3), np.array(model.legs), table, np.full(2, z1),
                         None if which != "both" else np.full(2, z2))
            d = {"phi": 1, "position": 2, "both": 3}[which]
            for i in range(2):
                lam = ch.lam[i]
                pts, _, _, status = select_points(d, table.env, ch.grp[i], ch.mu[i], ch.Q[i], ch.Vinv[i],
                                                  ch.mnorm[i], ch.ab[i], lam, z1, z2, 1e-9 if d < 3 else 1e-7)
                if status >= 2:                                     # no 3-D series (legs without a normal law)
                    continue
                ran.add(d)
                re, ta, tb, cb, _ = _coefficients(d, table.kind, table.par, tab, sp, ch.grp[i], ch.mu[i], ch.snu[i],
                                                  ch.Q[i], ch.Vinv[i], pts, z1, z2, _RESTART)
                n = re.size
                every = [a.copy() for a in (re, ta, tb)]
                s_all, left0, n_all = _sum(d, lam, *(a.copy() for a in (re, ta, tb, cb)), z1, z2, sp[1], 0.0)
                assert (left0, n_all) == (0.0, n)
                s_seq = 0.0
                for k in range(n):                                  # the transform of D, point by point
                    a, b = ta[k], tb[k]
                    t = 2 * math.pi * z1 * sp[1](z1 * a, 0) / a if d > 1 else 2 * math.sin(a * z1) / a
                    if d == 3:
                        t *= 2 * math.sin(b * z2) / b if b > 0 else 2 * z2
                    s_seq += re[k] * t
                assert s_all == s_seq
                room = cb.sum() / lam                               # half the bound of every term
                s_kept, left, m = _sum(d, lam, re, ta, tb, cb, z1, z2, sp[1], room)
                assert 0 < m < n and 0 < left <= room                 # some points left out, within the room
                assert abs(2 * (s_all - s_kept) / lam) <= left
                for z in np.linspace(0.0, z1, 7)[1:]:
                    p_all = _prob(d, lam, every[0], every[1], every[2], n, z, z2, sp[1])
                    p_kept = _prob(d, lam, re, ta, tb, m, z, z2, sp[1])
                    assert abs(p_all - p_kept) <= left
    assert ran == {1, 2, 3}


# ------------------------------------------------------------------ OpenTURNS

def ot_law(law):
    import openturns as ot
    if isinstance(law, Uniform):
        return ot.Uniform(law.lo, law.hi)
    if isinstance(law, Normal):
        return ot.Normal(law.mu, law.sd)
    if isinstance(law, Triangular):
        return ot.Triangular(law.lo, law.mode, law.hi)
    raise TypeError(law)


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_dphi_matches_openturns_linear_combination_to_1e_10(preset):
    ot = pytest.importorskip("openturns")
    ot.Log.Show(ot.Log.NONE)
    geometry, budget = Geometry.from_preset(preset), ot_budget()
    y0 = 100.0 if preset == "u-shape" else 160.0
    poses = np.array([[0.0, y0, 0.0], [12.0, y0 - 20.0, 3.0], [-30.0, y0 + 25.0, -2.0]])
    model = linear_model(geometry, budget, poses)
    for spec_as in (40.0, 90.0):
        r = exact_yield(geometry, budget, poses, spec_position_um=60.0, spec_phi_arcsec=spec_as, target=1e-10,
                        quantiles=False)
        assert np.all(r.bound_phi <= 1e-10)
        for k in range(poses.shape[0]):
            mix = ot.LinearCombinationDistribution([ot_law(tl.law) for tl in model.term_laws],
                                                   [float(v) for v in model.columns[k, 2]], 0.0)
            z = spec_as * ARCSEC
            ref = mix.computeComplementaryCDF(z) + mix.computeCDF(-z)
            assert abs(r.exceed_phi[k] - ref) <= r.bound_phi[k] + 1e-12, (k, spec_as, r.exceed_phi[k] - ref)


# ------------------------------------------------------------------ Monte Carlo

def sample_exceedance(model, n: int, rng, spec_mm: float, spec_rad: float, chunk: int = 250_000) -> np.ndarray:
    """Monte Carlo P(position > S), P(|dphi| > Z), P(either) at every pose of ``model``, (3, P).

    Written here from the laws' quantile functions: a clearance rho cos(zeta - omega) is sampled as
    rho cos(zeta) cos(omega) + rho sin(zeta) sin(omega), so every pose shares the samples.
    """
    P = model.columns.reshape(-1, 3, model.columns.shape[-1]).shape[0]
    cols = model.columns.reshape(P, 3, -1)
    cos_w, sin_w = model.cos_omega.reshape(P, 3), model.sin_omega.reshape(P, 3)
    draws, weights, shift = [], [], np.zeros((P, 3))
    for t, tl in enumerate(model.term_laws):
        if tl.kind == "shift":
            shift += cols[:, :, t] * tl.value
        elif tl.kind == "factor":
            draws.append(lambda u, law=tl.law, ref=tl.reference: law.ppf(u) - ref)
            weights.append(cols[:, :, t])
        else:
            leg = tl.leg
            draws.append(("rho", tl.law, tl.zeta))
            weights.append(cols[:, :, t] * cos_w[:, leg, None])
            weights.append(cols[:, :, t] * sin_w[:, leg, None])
    W = np.ascontiguousarray(np.stack(weights))
    counts = np.zeros((3, P))
    for start in range(0, n, chunk):
        m = min(chunk, n - start)
        X = []
        for draw in draws:
            if isinstance(draw, tuple):
                rho, zeta = draw[1].ppf(rng.random(m)), np.deg2rad(draw[2].ppf(rng.random(m)))
                X += [rho * np.cos(zeta), rho * np.sin(zeta)]
            else:
                X.append(draw(rng.random(m)))
        _count(np.stack(X, axis=1), W, shift, spec_mm, spec_rad, counts)
    return counts / n


@njit(cache=False)
def _count(X, W, shift, spec_mm, spec_rad, counts):
    """Add to ``counts`` (3, P) the samples X (m, F) beyond the spec at every pose (W: (F, P, 3))."""
    m, F = X.shape
    P = W.shape[1]
    for i in range(m):
        for p in range(P):
            ex, ey, ez = shift[p, 0], shift[p, 1], shift[p, 2]
            for f in range(F):
                x = X[i, f]
                ex += x * W[f, p, 0]
                ey += x * W[f, p, 1]
                ez += x * W[f, p, 2]
            out_pos = ex * ex + ey * ey > spec_mm * spec_mm
            out_phi = abs(ez) > spec_rad
            counts[0, p] += out_pos
            counts[1, p] += out_phi
            counts[2, p] += out_pos or out_phi


def check_against_monte_carlo(geometry, budget, poses, n, seed, spec_um=None, spec_as=None):
    """Exact vs the sampler here (all three channels) and the package's Monte Carlo (position): the
    difference within the bound plus N_SE standard errors."""
    r0 = exact_yield(geometry, budget, poses, spec_position_um=1.0, quantiles=False)
    spec_um = spec_um or float(np.median(r0.rss_position_mm)) * MM2UM
    spec_as = spec_as or float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC
    r = exact_yield(geometry, budget, poses, spec_position_um=spec_um, spec_phi_arcsec=spec_as, quantiles=False)
    model = linear_model(geometry, budget, poses)
    mc = sample_exceedance(model, n, np.random.default_rng(seed), spec_um / MM2UM, spec_as * ARCSEC)
    worst = 0.0
    for row, (e, b) in enumerate(((r.exceed_position, r.bound_position), (r.exceed_phi, r.bound_phi),
                                  (r.exceed_any, r.bound_any))):
        se = np.sqrt(np.maximum(e, 1.0 / n) * (1.0 - e) / n)
        excess = np.abs(mc[row] - e) - b - N_SE * se
        assert np.all(excess <= 0.0), (row, spec_um, spec_as, e, mc[row], b, se)
        worst = max(worst, float(np.max(np.abs(mc[row] - e) / np.maximum(b + se, 1e-300))))
    ref = monte_carlo(geometry, budget, poses, n, rng=seed + 1, tolerance_mm=spec_um / MM2UM, percentiles=(50.0,))
    p_mc = np.asarray(ref.exceed_prob).reshape(r.exceed_position.shape)
    se = np.sqrt(np.maximum(r.exceed_position, 1.0 / n) * (1.0 - r.exceed_position) / n)
    assert np.all(np.abs(p_mc - r.exceed_position) <= r.bound_position + N_SE * se)
    print(f"{geometry.name} {budget.name} n={n}: S={spec_um:.4g} µm Z={spec_as:.4g} arcsec; largest "
          f"|exact - MC| / (bound + se) = {worst:.2f} (here), "
          f"{float(np.max(np.abs(p_mc - r.exceed_position) / (r.bound_position + se))):.2f} (prp3mc.monte_carlo)")
    return r, mc


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_mixed_budget_agrees_with_monte_carlo(preset, seed):
    geometry = with_leads(Geometry.from_preset(preset))
    budget = mixed_budget(geometry)
    poses = poses_of(preset, 3, np.random.default_rng(seed))
    check_against_monte_carlo(geometry, budget, poses, 200_000, seed)


def test_the_joint_series_agrees_with_monte_carlo(seed):
    """A normal law in every leg: P(either) comes from the 3-D series (not the bracket), within its bound."""
    geometry = Geometry.from_preset("u-shape")
    budget = Budget({f"theta_{i}": Normal(0.0, 0.012) for i in (1, 2, 3)}
                    | {f"b_{i}": Uniform(0.0, 0.025) for i in (1, 2, 3)} | {"rho_2": Uniform(0.0, 0.016),
                                                                           "zeta_2": Uniform(0.0, 360.0)}, name="n")
    poses = poses_of("u-shape", 3, np.random.default_rng(seed))
    r, _ = check_against_monte_carlo(geometry, budget, poses, 200_000, seed)
    assert not np.any(r.bracketed_any) and np.all(r.bound_any <= r.target)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
@pytest.mark.parametrize("which", ["paper", "mixed"])
def test_1e8_samples_at_20_poses(preset, which, seed):
    geometry = with_leads(Geometry.from_preset(preset))
    budget = Budget.load("paper") if which == "paper" else mixed_budget(geometry)
    poses = poses_of(preset, 20, np.random.default_rng(seed))
    check_against_monte_carlo(geometry, budget, poses, 100_000_000, seed)


# ------------------------------------------------------------------ the contract

def test_bad_specs_are_refused_in_one_line():
    with pytest.raises(SpecError, match="> 0"):
        exact_yield("u-shape", "paper", [0.0, 100.0, 0.0], spec_position_um=0.0)
    with pytest.raises(SpecError, match="> 0"):
        exact_yield("u-shape", "paper", [0.0, 100.0, 0.0], spec_position_um=60.0, spec_phi_arcsec=-1.0)
    with pytest.raises(SpecError, match="target"):
        exact_yield("u-shape", "paper", [0.0, 100.0, 0.0], spec_position_um=60.0, target=0.5)
    with pytest.raises(SpecError, match=r"target must be a probability in \[1e-12, 0.01\].*1e-30"):
        exact_yield("u-shape", "paper", [0.0, 100.0, 0.0], spec_position_um=60.0, target=1e-30)


def test_result_frame_and_record_carry_the_spec_figures():
    r = exact_yield("u-shape", "paper", [[0.0, 100.0, 0.0], [10.0, 120.0, 0.0]], spec_position_um=150.0,
                    spec_phi_arcsec=100.0)
    rec = r.pose_record(1)
    assert rec["exceed_position_ppm"] == pytest.approx(1e6 * r.exceed_position[1])
    assert set(rec["quantiles_position_um"]) == {"p99.73", "p99.9937", "p99.9999"}
    assert r.levels == QUANTILE_LEVELS == (99.73, 99.9937, 99.9999)         # in %, as the names say
    assert rec["error_bound_ppm"] >= 1e6 * r.bound_position[1]
    frame = r.to_frame()
    assert set(frame["statistic"]) >= {"exceed", "p99.73", "worst_case", "rss"}
    summary = r.region_summary()
    assert summary["argmax_pose"] == [float(v) for v in r.poses[int(np.argmax(r.exceed_position))]]
    # worst case >= every quantile (the paper's budget is bounded), and the exceedance of the worst case is 0
    assert np.all(r.quantile_position_mm[:, -1] <= r.worst_position_mm + r.quantile_position_err_mm[:, -1])


def test_exceedance_and_bound_by_output_name():
    """One accessor per output name; ``phi`` only with an orientation spec (``any`` is then the position's)."""
    poses = [[0.0, 100.0, 0.0], [10.0, 120.0, 0.0]]
    r = exact_yield("u-shape", "paper", poses, spec_position_um=150.0, spec_phi_arcsec=100.0, quantiles=False)
    assert r.outputs == OUTPUTS == ("position", "phi", "any") and r.levels == ()
    for output in OUTPUTS:
        assert r.exceedance(output) is getattr(r, f"exceed_{output}")
        assert r.bound(output) is getattr(r, f"bound_{output}")
    assert np.array_equal(r.error_bound, np.maximum(np.maximum(r.bound_position, r.bound_any), r.bound_phi))
    frame = r.to_frame().query("statistic == 'exceed'")
    assert frame["output"].tolist() == ["position"] * 2 + ["phi"] * 2 + ["any"] * 2
    alone = exact_yield("u-shape", "paper", poses, spec_position_um=150.0, quantiles=False)
    assert alone.outputs == ("position", "any") and np.array_equal(alone.bound("any"), alone.bound_position)
    with pytest.raises(KeyError, match="no orientation spec"):
        alone.bound("phi")
    with pytest.raises(KeyError, match="choose from position, phi, any"):
        r.exceedance("x")


def test_quantiles_agree_with_monte_carlo(seed):
    """P(position > q) and P(|dphi| > q) at the exact quantiles q are 1 - level, within N_SE standard errors."""
    geometry, budget = Geometry.from_preset("u-shape"), Budget.load("paper")
    poses = poses_of("u-shape", 2, np.random.default_rng(seed))
    r = exact_yield(geometry, budget, poses, spec_position_um=100.0)
    n = 200_000
    rng = np.random.default_rng(seed)
    for k in range(poses.shape[0]):
        model = linear_model(geometry, budget, poses[k:k + 1])
        for q, level in enumerate(r.levels[:2]):
            p = 1.0 - level / 100.0
            qp, qf = r.quantile_position_mm[k, q], r.quantile_phi_deg[k, q] * DEG2RAD
            assert r.quantile_position_err_mm[k, q] < 1e-5 * qp and r.quantile_phi_err_deg[k, q] * DEG2RAD < 1e-5 * qf
            mc = sample_exceedance(model, n, rng, qp, qf)
            se = math.sqrt(p * (1.0 - p) / n)
            assert abs(mc[0, 0] - p) <= N_SE * se and abs(mc[1, 0] - p) <= N_SE * se, (k, level, mc[:2, 0], p)


@pytest.mark.parametrize("index", [(), 4, (3, 0)])
def test_pose_record_of_a_batch_needs_the_index_of_one_pose(index):
    """pose_record() of a 3 x 3 grid raised numpy's TypeError ('only 0-dimensional arrays...'), pose_record(4)
    an IndexError: a one-line ParameterError names the batch's shape instead."""
    from prp3mc.errors import ParameterError
    from prp3mc.kinematics.geometry import Region
    r = exact_yield("u-shape", "paper", Region.from_preset("u-shape").grid(3), spec_position_um=100.0,
                    quantiles=False)
    with pytest.raises(ParameterError, match=r"one pose of the batch \(3, 3\)"):
        r.pose_record(index)
    assert r.pose_record((1, 1))["exceed_position_ppm"] == pytest.approx(1e6 * float(r.exceed_position[1, 1]))


# ------------------------------------------------------------------ specs beyond the support

@pytest.mark.parametrize("which", ["paper", "ot"])
def test_a_spec_beyond_the_worst_case_is_zero_and_leaves_the_quantiles_alone(which):
    """S and Z from 1e3 to 1e9 (µm, arcsec): no series sized by the spec (it used to need more than 2^23 terms
    or find "no density"); P = 0 with bound 0 on bounded laws, 0 within the normal laws' cut mass (<= the
    target) otherwise; the quantiles bit-identical to a run with a spec inside the support."""
    budget = Budget.load("paper") if which == "paper" else ot_budget()
    pose = [0.0, 100.0, 0.0]
    inside = exact_yield("u-shape", budget, pose, spec_position_um=50.0, spec_phi_arcsec=50.0)
    for spec in (1e3, 1e4, 1e6, 1e9):
        r = exact_yield("u-shape", budget, pose, spec_position_um=spec, spec_phi_arcsec=spec)
        for output in OUTPUTS:
            assert float(r.exceedance(output)) == 0.0
            assert 0.0 <= float(r.bound(output)) <= (0.0 if which == "paper" else 2e-2 * r.target)   # any: both cuts
        assert not bool(r.bracketed_any)
        np.testing.assert_array_equal(r.quantile_position_mm, inside.quantile_position_mm)
        np.testing.assert_array_equal(r.quantile_phi_deg, inside.quantile_phi_deg)
        np.testing.assert_array_equal(r.quantile_position_err_mm, inside.quantile_position_err_mm)
        assert int(r.lattice_points["position"]) == int(inside.lattice_points["position"])


def test_the_exceedance_falls_to_zero_across_the_support_edge():
    """Monotone in S through the worst case W: P(> S) within its bound non-increasing, 0 from W on, and one
    channel beyond its support makes P(either) the other channel's exceedance."""
    pose = [0.0, 100.0, 0.0]
    W = MM2UM * float(exact_yield("u-shape", "paper", pose, spec_position_um=100.0,
                                  quantiles=False).worst_position_mm)
    specs = [0.9 * W, 0.97 * W, 0.995 * W, W * (1 - 1e-9), W * (1 + 1e-9), 1.01 * W, 10 * W]
    r = [exact_yield("u-shape", "paper", pose, spec_position_um=s, spec_phi_arcsec=40.0, quantiles=False)
         for s in specs]
    p = np.array([float(x.exceed_position) for x in r])
    b = np.array([float(x.bound_position) for x in r])
    assert np.all(np.diff(p) <= b[:-1] + b[1:]) and p[0] > 0
    assert np.all(p[4:] == 0.0) and np.all(b[4:] == 0.0)
    for x in r[4:]:
        assert float(x.exceed_any) == float(x.exceed_phi) and float(x.bound_any) == float(x.bound_phi)
        assert not bool(x.bracketed_any)


# ------------------------------------------------------------------ discrete classes only: enumeration

def classes_budget() -> Budget:
    return Budget({f"theta_{i}": Discrete((-0.04, 0.0, 0.04), (0.25, 0.5, 0.25)) for i in (1, 2, 3)}
                  | {f"b_{i}": Discrete((0.0, 0.01, 0.025), (0.3, 0.4, 0.3)) for i in (1, 2, 3)}
                  | {"a_1": Discrete((-0.01, 0.02), (0.5, 0.5))}, name="classes")


def test_a_budget_of_discrete_classes_is_exact_by_enumeration():
    """Every input a class: no density (it was refused "use Monte Carlo"); the pose error takes 3^6 x 2 values,
    and the exceedances, quantiles and worst cases equal a brute-force sum over them (itertools, from the
    linear model's columns and laws), bound ~1e-13."""
    from itertools import product
    budget = classes_budget()
    poses = np.array([[0.0, 100.0, 0.0], [10.0, 120.0, 2.0]])
    S, Z = 0.06, 60.0 * ARCSEC
    r = exact_yield("u-shape", budget, poses, spec_position_um=MM2UM * S, spec_phi_arcsec=60.0)
    assert r.error_bound.max() < 1e-12 and not np.any(r.bracketed_any)
    model = linear_model(Geometry.from_preset("u-shape"), budget, poses)
    laws = [(t, tl) for t, tl in enumerate(model.term_laws) if tl.law is not None and tl.kind == "factor"]
    assert all(isinstance(tl.law, Discrete) for _, tl in laws)
    for n in range(2):
        c = model.columns.reshape(-1, 3, len(model.terms))[n]
        ys, ws = [], []
        for combo in product(*[list(zip(tl.law.values, tl.law.weights)) for _, tl in laws]):
            ys.append(sum(c[:, t] * (v - tl.reference) for (t, tl), (v, _) in zip(laws, combo)))
            ws.append(math.prod(w for _, w in combo))
        ys, ws = np.array(ys), np.array(ws)
        pos, phi = np.hypot(ys[:, 0], ys[:, 1]), np.abs(ys[:, 2])
        assert abs(r.exceed_position[n] - ws[pos > S].sum()) <= r.bound_position[n]
        assert abs(r.exceed_phi[n] - ws[phi > Z].sum()) <= r.bound_phi[n]
        assert abs(r.exceed_any[n] - ws[(pos > S) | (phi > Z)].sum()) <= r.bound_any[n]
        assert r.worst_position_mm[n] == pytest.approx(pos.max(), rel=1e-12)
        order = np.argsort(pos)
        for level, q in zip(QUANTILE_LEVELS, r.quantile_position_mm[n]):
            k = np.searchsorted(np.cumsum(ws[order]), level / 100 - 1e-12)
            assert q == pytest.approx(pos[order][k], rel=1e-12)


def test_too_many_classes_are_refused_in_one_line():
    budget = Budget({f"{p}_{i}": Discrete(tuple(np.linspace(-0.01, 0.01, 11)), (1 / 11,) * 11)
                     for p in ("theta", "b") for i in (1, 2, 3)}, name="many")
    with pytest.raises(BudgetError, match="combinations.*Monte Carlo"):
        exact_yield("u-shape", budget, [0.0, 100.0, 0.0], spec_position_um=60.0)
