"""P(either) by conditioning on two legs at the target: the channels summed again where only their bounds keep
P(either)'s bound above it (prp3mc.stackup.exceedance._conditioned), against the 3-D series; a shared
temperature conditioned on too, against the 3-D series and Monte Carlo.

Where a normal law sits in every leg the 3-D series of the cylinder serves and is the independent reference:
P_pos + P_phi - J by conditioning (its channels tightened) must agree with its P(either) within the sum of both
bounds, at specs where J's bracket closes to below 1e-9 so that P(either)'s bound is the channels' (the 1e-9
scale is then what is checked).
"""

import math

import numpy as np
import pytest
from scipy import special

from prp3mc import Geometry, exact_yield
from prp3mc.model.effects import SystematicEffect
from prp3mc.model.linear import linear_model
from prp3mc.stackup import conditional, exceedance
from prp3mc.stackup.characteristic import term_table
from prp3mc.stackup.conditional import CONDITIONAL_METHOD, independent_legs, joint_exceedance
from prp3mc.units import DEG2ARCSEC, MM2UM

from .realities import with_leads
from .test_conditional import _normal_legs, _paper_normal_encoders
from .test_yield import ARCSEC, N_SE, mixed_budget, poses_of, sample_exceedance

POSES = np.array([[0.0, 100.0, 0.0], [25.0, 75.0, -3.0], [-30.0, 130.0, 2.0]])


def _conditioned(geometry, budget, S_um, Z_as, r, target=1e-9, workers=1):
    """_conditioned at every pose of ``r`` (all taken as still bracketed), with exact_yield's table and share."""
    m = linear_model(geometry, budget, r.poses)
    C, Ainv = m.columns.reshape(-1, 3, len(m.terms)), m.Ainv.reshape(-1, 3, 3)
    n_normal = sum(1 for tl in m.term_laws if tl.law is not None and tl.law.kind == "normal")
    share = 0.01 * target / max(n_normal, 1)
    table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
    N = C.shape[0]
    start = exceedance._Either(np.full(N, 0.5), np.ones(N), np.ones(N, bool), np.zeros(N, bool))
    return exceedance._conditioned(start, C=C, Ainv=Ainv, legs=np.array(m.legs), table=table, share=share,
                                   S=S_um / MM2UM, Z=Z_as * ARCSEC, target=target,
                                   position=(r.exceed_position, r.bound_position),
                                   phi=(r.exceed_phi, r.bound_phi), workers=workers)


@pytest.mark.parametrize("scale", [(1.0, 1.0), (1.2, 0.8)])
def test_tightened_channels_agree_with_the_joint_series_at_1e_9(scale):
    geometry, budget = Geometry.from_preset("u-shape"), _paper_normal_encoders()
    r0 = exact_yield(geometry, budget, POSES, spec_position_um=1.0, quantiles=False)
    S_um = float(np.median(r0.rss_position_mm)) * MM2UM * scale[0]
    Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC * scale[1]
    r = exact_yield(geometry, budget, POSES, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
    assert not r.bracketed_any.any() and r.bound_any.max() <= 1e-9            # the 3-D series served
    e = _conditioned(geometry, budget, S_um, Z_as, r)
    assert e.conditioned.all() and not e.bracketed.any()
    assert np.all(np.abs(e.exceed - r.exceed_any) <= e.bound + r.bound_any), (e.exceed, r.exceed_any, e.bound)
    reached = e.bound <= 1e-9
    assert (reached & (r.exceed_position > 0)).any()     # at the target where J closes, both channels at work
    # the channels alone, at exact_yield's target, would have kept every such pose above half of it
    assert np.all((r.bound_position + r.bound_phi)[reached] > 0.5e-9)
    print(f"scale {scale}: P(either) {r.exceed_any}, conditioned bound {e.bound}, |cond - series| / bounds "
          f"{np.abs(e.exceed - r.exceed_any) / (e.bound + r.bound_any)}")


def test_tightened_channels_leave_every_bit_on_two_threads():
    geometry, budget = Geometry.from_preset("u-shape"), _paper_normal_encoders()
    r0 = exact_yield(geometry, budget, POSES, spec_position_um=1.0, quantiles=False)
    S_um = float(np.median(r0.rss_position_mm)) * MM2UM * 1.5
    Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC * 0.6
    r = exact_yield(geometry, budget, POSES, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
    one, two = (_conditioned(geometry, budget, S_um, Z_as, r, workers=w) for w in (1, 2))
    assert all(np.array_equal(a, b) for a, b in zip(one, two))


@pytest.mark.parametrize("pose, Z_as", [([10.0, 120.0, 0.0], 100.0), ([-40.0, 140.0, 0.0], 60.0)])
def test_the_paper_budget_meets_1e_9_where_both_out_is_nearly_closed(pose, Z_as):
    """The paper's budget, U-shape, 100 µm: at benchmarks/bench_yield.py's pose (10, 120, 0) J's bracket closes
    to the target and P(either)'s bound was the channels' sum, 1.45e-9; at (-40, 140, 0) / 60 arcsec J's
    bracket spends its cells at 1.65e-9 wide (its half-width 8.3e-10 leaves 1.7e-10 of room: the channels go to
    target/16). Both now meet the target, inside the Fréchet bracket."""
    r = exact_yield("u-shape", "paper", pose, spec_position_um=100.0, spec_phi_arcsec=Z_as, quantiles=False)
    assert not bool(r.bracketed_any) and float(r.bound_any) <= 1e-9
    lo = max(float(r.exceed_position), float(r.exceed_phi))
    hi = float(r.exceed_position + r.exceed_phi)
    slack = float(r.bound_any + r.bound_position + r.bound_phi)
    assert lo - slack <= float(r.exceed_any) <= hi + slack


# ------------------------------------------------------------------ a shared temperature, conditioned on too

def _with_thermal(budget, geometry):
    return budget.with_effects({"thermal": SystematicEffect("thermal", 1.2e-5, temp_range_C=(15.0, 30.0))},
                               fitted_on=geometry)


@pytest.mark.parametrize("which", ["normal legs", "paper, normal encoders"])
def test_a_shared_temperature_is_conditioned_and_agrees_with_the_joint_series(which):
    """A temperature uniform over its range acts on every leg: J is conditioned on its intervals too (the
    cells' linear forms take it as a range). Where a normal law sits in every leg the 3-D series serves
    (bound ~5e-10) and is the reference: both agree within the sum of their bounds."""
    geometry = with_leads(Geometry.from_preset("u-shape"))
    budget = _with_thermal(_normal_legs() if which == "normal legs" else _paper_normal_encoders(), geometry)
    r0 = exact_yield(geometry, budget, POSES, spec_position_um=1.0, quantiles=False)
    for scale in ((0.8, 0.8), (1.2, 0.8)):
        S_um = float(np.median(r0.rss_position_mm)) * MM2UM * scale[0]
        Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC * scale[1]
        r = exact_yield(geometry, budget, POSES, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
        assert not r.bracketed_any.any() and r.bound_any.max() <= 1e-9
        e = _conditioned(geometry, budget, S_um, Z_as, r)
        assert e.conditioned.all()
        frechet = 0.5 * np.minimum(r.exceed_position, r.exceed_phi)          # the bracket's half-width at least
        assert np.all(e.bound < frechet)
        assert np.all(np.abs(e.exceed - r.exceed_any) <= e.bound + r.bound_any), (e.exceed, r.exceed_any, e.bound)
        print(f"{which} {scale}: P(either) {r.exceed_any}, conditioned bound {e.bound}, |cond - series| / bounds "
              f"{np.abs(e.exceed - r.exceed_any) / (e.bound + r.bound_any)}")


def test_the_every_law_budget_is_conditioned_and_agrees_with_monte_carlo(seed):
    """The budget of every law and effect (a shared temperature among them): conditioned, not bracketed, its
    bound below the Fréchet bracket's, and within bound + N_SE standard errors of Monte Carlo."""
    geometry = with_leads(Geometry.from_preset("u-shape"))
    budget = mixed_budget(geometry)
    poses = poses_of("u-shape", 2, np.random.default_rng(seed))
    kw = dict(spec_position_um=80.0, spec_phi_arcsec=40.0, quantiles=False)
    with pytest.warns(Warning):
        br = exact_yield(geometry, budget, poses, joint=False, **kw)
    r = exact_yield(geometry, budget, poses, **kw)
    assert br.bracketed_any.all() and not r.bracketed_any.any() and CONDITIONAL_METHOD in r.method
    assert np.all(r.bound_any < br.bound_any)
    n = 200_000
    mc = sample_exceedance(linear_model(geometry, budget, poses), n, np.random.default_rng(seed), 80.0 / MM2UM,
                           40.0 * ARCSEC)[2]
    se = np.sqrt(np.maximum(r.exceed_any, 1.0 / n) * (1.0 - r.exceed_any) / n)
    assert np.all(np.abs(mc - r.exceed_any) <= r.bound_any + N_SE * se), (mc, r.exceed_any, r.bound_any, se)
    print(f"P(either) {r.exceed_any}, bound {r.bound_any} (bracket {br.bound_any}), MC {mc} +- {se}")


def test_a_shared_term_leaves_every_bit_on_two_threads():
    geometry = with_leads(Geometry.from_preset("u-shape"))
    budget = mixed_budget(geometry)
    m = linear_model(geometry, budget, POSES)
    C, Ainv = m.columns.reshape(-1, 3, len(m.terms)), m.Ainv.reshape(-1, 3, 3)
    table = term_table(m.term_laws, 8.0)
    legs = np.array(m.legs)
    legs_table, t = exceedance._shared_term(table, legs)
    assert t is not None
    kappa, ok = independent_legs(C, Ainv, legs, legs_table)
    assert ok.all()
    args = (C, Ainv, legs, legs_table, kappa, 80.0 / MM2UM, 40.0 * ARCSEC, 1e-9, 1e-11)
    shared = (C[:, :, t], float(table.lo[t]), float(table.hi[t]))
    one = joint_exceedance(*args, workers=1, shared=shared)
    two = joint_exceedance(*args, workers=2, shared=shared)
    assert all(np.array_equal(a, b) for a, b in zip(one, two)) and np.all(one[0] < one[1])


@pytest.mark.parametrize("intervals", [1, 8])
def test_the_shared_terms_bracket_holds_the_joint_series_j(intervals, monkeypatch):
    """J = P_pos + P_phi - P(either) from the 3-D series (normal legs and a temperature; error below 2e-9)
    lies in the conditioned bracket, with the temperature's range in 8 intervals and in one (the whole range
    as one interval: a bracket that took the temperature at a point would miss it)."""
    from prp3mc.stackup import conditional

    monkeypatch.setattr(conditional, "_SHARED_INTERVALS", intervals)
    geometry = with_leads(Geometry.from_preset("u-shape"))
    budget = _with_thermal(_normal_legs(), geometry)
    r0 = exact_yield(geometry, budget, POSES, spec_position_um=1.0, quantiles=False)
    S_um = float(np.median(r0.rss_position_mm)) * MM2UM
    Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC
    r = exact_yield(geometry, budget, POSES, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
    J = r.exceed_position + r.exceed_phi - r.exceed_any
    err = r.bound_position + r.bound_phi + r.bound_any
    m = linear_model(geometry, budget, POSES)
    C, Ainv = m.columns.reshape(-1, 3, len(m.terms)), m.Ainv.reshape(-1, 3, 3)
    share = 1e-13
    table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
    legs = np.array(m.legs)
    legs_table, t = exceedance._shared_term(table, legs)
    kappa, ok = independent_legs(C, Ainv, legs, legs_table)
    assert ok.all()
    J_lo, J_hi = joint_exceedance(C, Ainv, legs, legs_table, kappa, S_um / MM2UM, Z_as * ARCSEC, 1e-9, share,
                                  shared=(C[:, :, t], float(table.lo[t]), float(table.hi[t])))
    assert np.all(J_lo - err <= J) and np.all(J <= J_hi + err), (J_lo, J, J_hi)
    print(f"{intervals} interval(s): J {J}, bracket {J_lo} .. {J_hi}")


# ------------------------------------------------------------------ the cells' second-order bracket

def _normal_cells(pose, scale, n):
    """Normal legs (U-shape): the cells' geometry at specs ``scale`` x the RSS, the legs' laws (mean, sd per
    leg, the truth the CDF grids approximate) and a uniform n x n partition of the conditioned legs' supports."""
    geometry, budget = Geometry.from_preset("u-shape"), _normal_legs()
    poses = np.array([pose])
    r0 = exact_yield(geometry, budget, poses, spec_position_um=1.0, quantiles=False)
    S, Z = float(r0.rss_position_mm[0]) * scale, float(r0.rss_phi_deg[0]) * DEG2ARCSEC * scale * ARCSEC
    m = linear_model(geometry, budget, poses)
    C, Ainv = m.columns.reshape(-1, 3, len(m.terms)), m.Ainv.reshape(-1, 3, 3)
    share = 1e-13
    table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
    legs = np.array(m.legs)
    kappa, ok = independent_legs(C, Ainv, legs, table)
    assert ok.all()
    s = np.einsum("ndt,t->nd", C, table.constant)
    cdf = conditional._cdf_bounds(kappa, legs, table, share)
    geo = conditional._Cells(s, Ainv, cdf, S, Z)
    on = [table.random & (legs == i) for i in range(3)]
    mu = np.array([(kappa[0] * table.mean)[o].sum() for o in on])
    sd = np.sqrt([(kappa[0] ** 2 * table.var)[o].sum() for o in on])
    edges = []
    for k in range(2):
        sup = cdf["support"][0, geo.order[0, k]]
        a = int(np.floor((sup[0] - geo.lo[k, 0]) / geo.h[k, 0]))
        b = min(int(np.ceil((sup[1] - geo.lo[k, 0]) / geo.h[k, 0])), geo.M - 1)
        edges.append(np.round(np.linspace(a, b, n + 1)).astype(np.int64))
    I, J = np.repeat(np.arange(n), n), np.tile(np.arange(n), n)
    cells = (np.zeros(n * n, np.int64), edges[0][I], edges[0][I + 1], edges[1][J], edges[1][J + 1])
    return geo, s[0], Ainv[0], S, Z, mu, sd, cells


def _g_direct(s, Ainv, order, S, Z, mu, sd, up, uq):
    """1 - P(u_L in A ∪ B) at (u_p, u_q), from the pose error directly: A the roots of ``|e + a_L u|² = S²``, B
    ``|dphi| <= Z``, u_L normal (exact CDF)."""
    p, q, L = order
    e = s[:, None] + Ainv[:, p, None] * up + Ainv[:, q, None] * uq
    m = Ainv[:2, L]
    a, b, c = m @ m, 2.0 * (m @ e[:2]), (e[:2] ** 2).sum(axis=0) - S * S
    disc = b * b - 4.0 * a * c
    rt = np.sqrt(np.maximum(disc, 0.0))
    A0, A1 = (-b - rt) / (2.0 * a), (-b + rt) / (2.0 * a)
    B = np.sort([(-Z - e[2]) / Ainv[2, L], (Z - e[2]) / Ainv[2, L]], axis=0)
    Phi = lambda x: special.ndtr((x - mu[L]) / sd[L])                          # noqa: E731
    over = (disc >= 0) & (np.maximum(A0, B[0]) <= np.minimum(A1, B[1]))
    apart = np.where(disc >= 0, Phi(A1) - Phi(A0), 0.0) + Phi(B[1]) - Phi(B[0])
    return 1.0 - np.where(over, Phi(np.maximum(A1, B[1])) - Phi(np.minimum(A0, B[0])), apart)


def _cell_reference(geo, s, Ainv, S, Z, mu, sd, cells, nodes):
    """Each cell's share of J, ``int g f_p f_q`` over it, by tensor Gauss-Legendre with ``nodes`` per leg."""
    t, w = np.polynomial.legendre.leggauss(nodes)
    P, i0, i1, j0, j1 = cells
    p, q, _ = geo.order[0]
    ends = [(geo.lo[k, 0] + a * geo.h[k, 0], geo.lo[k, 0] + b * geo.h[k, 0]) for k, (a, b) in enumerate(((i0, i1),
                                                                                                      (j0, j1)))]
    u, wt = [], []
    for k, leg in ((0, p), (1, q)):
        a, b = ends[k]
        x = 0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * t
        u.append(x)
        density = np.exp(-0.5 * ((x - mu[leg]) / sd[leg]) ** 2) / (sd[leg] * math.sqrt(2 * math.pi))
        wt.append(0.5 * (b - a)[:, None] * w * density)
    up = np.repeat(u[0], nodes, axis=1)
    uq = np.tile(u[1], nodes)
    g = _g_direct(s, Ainv, geo.order[0], S, Z, mu, sd, up.ravel(), uq.ravel()).reshape(P.size, nodes, nodes)
    return np.einsum("ci,cij,cj->c", wt[0], g, wt[1])


@pytest.mark.parametrize("pose, scale", [([0.0, 100.0, 0.0], 0.8), ([25.0, 75.0, -3.0], 1.2)])
def test_the_cells_second_order_bracket_holds_the_quadrature_and_needs_its_whole_remainder(pose, scale):
    """Normal legs: every cell's share of J by tensor Gauss-Legendre (g from the pose error directly, u_L's exact
    normal CDF; 48 nodes a leg, its error bounded by the difference to 24) lies in both of the cell's brackets
    (first order; second order ``m g(mean) ± R``) wherever the second order applies; with R scaled by 0.3 (or
    dropped) the second-order bracket misses it in some cells: the remainder bound is needed, within a factor
    of about 3 of the worst cell's."""
    geo, s, Ainv, S, Z, mu, sd, cells = _normal_cells(pose, scale, 32)
    f_lo, f_hi, mg_lo, mg_hi, rem = geo.parts(cells)
    smooth = np.isfinite(rem) & (f_hi - f_lo > 1e-14)
    assert smooth.sum() >= 50
    sub = tuple(c[smooth] for c in cells)
    ref = _cell_reference(geo, s, Ainv, S, Z, mu, sd, sub, 48)
    err = np.abs(ref - _cell_reference(geo, s, Ainv, S, Z, mu, sd, sub, 24)) + 1e-18
    f_lo, f_hi, mg_lo, mg_hi, rem = (a[smooth] for a in (f_lo, f_hi, mg_lo, mg_hi, rem))
    assert np.all((f_lo <= ref + err) & (ref - err <= f_hi))
    assert np.all((mg_lo - rem <= ref + err) & (ref - err <= mg_hi + rem))
    used = np.maximum(mg_lo - ref, ref - mg_hi) / rem                 # the share of R the truth needs
    for scale_R in (0.3, 0.0):
        missed = (mg_lo - scale_R * rem > ref + err) | (ref - err > mg_hi + scale_R * rem)
        assert missed.sum() >= 3, (scale_R, used.max())
    # the second order is the tighter bracket in most of these cells (the test is not of a bracket nobody uses)
    tighter = np.mean(mg_hi - mg_lo + 2.0 * rem < 0.5 * (f_hi - f_lo))
    assert tighter > 0.2, tighter
    print(f"{smooth.sum()} smooth cells of {cells[0].size} ({tighter:.2f} at half the first order's width or "
          f"less): the truth needs up to {used.max():.3f} of R; "
          f"reference error up to {err.max():.2g}")


def test_the_density_bounds_hold_and_are_close():
    """sup f and sup |f'| of each leg from its envelope: normal legs against the closed forms
    ``1 / (sd sqrt(2 pi))`` and ``1 / (sd² sqrt(2 pi e))`` (above them, within 1.5 times); the paper's legs
    (no closed form) above the largest slope of their CDF grids and within 2.5 times it (1.3 to 2.3 measured:
    the uniform terms' envelopes ``a / x`` lie well above ``|sin x / x|`` where it matters), and their f' bound
    finite (envelopes falling as t^-3)."""
    m = linear_model(Geometry.from_preset("u-shape"), _normal_legs(), POSES[:1])
    C = m.columns.reshape(-1, 3, len(m.terms))
    table = term_table(m.term_laws, 8.0)
    legs = np.array(m.legs)
    kappa, ok = independent_legs(C, m.Ainv.reshape(-1, 3, 3), legs, table)
    dens = conditional.leg_cdfs(kappa, legs, table, 0.0)["density"][0]
    sd = np.sqrt([(kappa[0] ** 2 * table.var)[table.random & (legs == i)].sum() for i in range(3)])
    want = np.stack([1.0 / (sd * math.sqrt(2.0 * math.pi)), 1.0 / (sd ** 2 * math.sqrt(2.0 * math.pi * math.e))], -1)
    assert np.all(want <= dens) and np.all(dens <= 1.5 * want), dens / want
    from .test_conditional import paper_legs
    C, Ainv, legs, table, kappa = paper_legs(POSES[:1], 80.0, 30.0)[:5]
    cdf = conditional.leg_cdfs(kappa, np.array(legs), table, 0.0)
    slope = (np.diff(cdf["F"], axis=-1) / cdf["h"][..., None]).max(axis=-1)
    assert np.all(np.isfinite(cdf["density"])) and np.all(slope <= cdf["density"][..., 0])
    assert np.all(cdf["density"][..., 0] <= 2.5 * slope), cdf["density"][..., 0] / slope
