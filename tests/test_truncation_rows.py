"""The position's row bounds and the sums behind them (prp3mc.stackup.truncation): each bound against a brute
sum of what it bounds, at poses of the paper budget and of the budget mixing every law."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from prp3mc import Budget, Geometry
from prp3mc.model.linear import linear_model
from prp3mc.stackup.characteristic import term_table
from prp3mc.stackup.lattice import channel
from prp3mc.stackup.truncation import (_leg_at, _mixed, _mixed_row_sum, _mixed_scales, _rb, _rb_tail, _root, _tau,
                                       leg_envelope)

from .realities import with_leads
from .test_yield import mixed_budget, poses_of

EPS = 1e-9
TWO_PI = 2.0 * math.pi


def position_channels(preset: str, n: int = 1, z1: float = 0.1):
    """(table, channel) of the position at n poses, for the paper budget and the every-law budget."""
    geometry = with_leads(Geometry.from_preset(preset))
    poses = poses_of(preset, n, np.random.default_rng(11))
    for budget in (Budget.from_preset("paper"), mixed_budget(geometry)):
        model = linear_model(geometry, budget, poses)
        C = model.columns.reshape(-1, 3, len(model.terms))
        table = term_table(model.term_laws, 8.0)
        yield table, channel("position", C, model.Ainv.reshape(-1, 3, 3), np.array(model.legs), table,
                             np.full(n, z1))


@njit(cache=True)
def _mixed_sum(ev, grp, km, x0, delta, n):
    """sum_{|k| <= n} G_m(|x0 + k delta|)."""
    s = 0.0
    for k in range(-n, n + 1):
        s += _mixed(ev, grp, km, abs(x0 + k * delta))[0]
    return s


@njit(cache=True)
def _left_sum(ev, grp, km, x, ratio, n):
    """x G_m(x) + sum_i G_m(x_{i+1}) (x_{i+1} - x_i) on the grid x_i = x ratio^i, i < n: below int_0^inf G_m
    (G_m non-increasing)."""
    s = x * _mixed(ev, grp, km, x)[0]
    for _ in range(n):
        y = x * ratio
        s += _mixed(ev, grp, km, y)[0] * (y - x)
        x = y
    return s


@njit(cache=True)
def _leg_sums(j, d, ev, grp, mu, Q, mnorm, lam, z1, z2, n):
    """sum_{|m| <= n} g_j(|m|) and E_j(|m|)."""
    sg = se = 0.0
    for m in range(n + 1):
        e, g, _, _ = _leg_at(j, m, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
        w = 1.0 if m == 0 else 2.0
        sg += w * g
        se += w * e
    return sg, se


@njit(cache=True)
def _rows_sum(a, n, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km, ab):
    """sum_{a <= k < a + n} rb(k)."""
    s = 0.0
    for k in range(a, a + n):
        s += _rb(k, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km, ab)[0]
    return s


def _arrays(table, ch, i, eta):
    """What select_points builds for the position at pose i: both legs' arrays, S_1, S_1E, km, C_m, d_perp."""
    ev, d, z1, z2 = table.env, 2, 0.1, 0.0
    g0 = _root(_tau(d, z1, z2, 0.0) / ch.lam[i], d)
    legs = [leg_envelope(j, d, ev, ch.grp[i], ch.mu[i], ch.Q[i], ch.mnorm[i], ch.lam[i], z1, z2, g0, eta)
            for j in range(2)]
    km = _mixed_scales(ch.grp[i], ch.mu[i], ch.ab[i])
    cm = _mixed_row_sum(ev, ch.grp[i], km, abs(ch.ab[i, 0]) * TWO_PI / ch.Q[i, 0])
    V = ch.Vinv[i]
    along = (V[0, 1] * V[0, 0] + V[1, 1] * V[1, 0]) / (V[0, 0] ** 2 + V[1, 0] ** 2)
    d_perp = math.hypot(V[0, 1] - along * V[0, 0], V[1, 1] - along * V[1, 0])
    return legs, km, cm, d_perp


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_the_mixed_legs_row_sum_bounds_every_row(preset):
    """C_m (the mixed leg's G_m summed along a row, any offset: max G_m + (2 / delta) int_0^inf G_m) is above
    the brute sum over 4 x 10^4 + 1 points at 4 offsets, and within 30 % of it (max G_m = 1 is most of the
    gap), and its integral (by power-law segments, ratio 1.25) is within 3 % above a fine right sum (ratio
    1.001, below the integral)."""
    for table, ch in position_channels(preset):
        for i in range(ch.Q.shape[0]):
            km = _mixed_scales(ch.grp[i], ch.mu[i], ch.ab[i])
            delta = abs(ch.ab[i, 0]) * TWO_PI / ch.Q[i, 0]
            cm = _mixed_row_sum(table.env, ch.grp[i], km, delta)
            brute = max(_mixed_sum(table.env, ch.grp[i], km, x0, delta, 20_000)
                        for x0 in np.linspace(0.0, delta, 4, endpoint=False))
            assert brute <= cm <= 1.3 * brute, (preset, i, brute, cm)
            integral = _left_sum(table.env, ch.grp[i], km, 1e-6 / km.max(), 1.001, 40_000)
            assert integral <= 0.5 * delta * (cm - 1.0) <= 1.03 * integral, (preset, i, integral, cm)


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_the_legs_sums_bound_the_brute_sums_from_the_shorter_arrays(preset):
    """The position's 1-D arrays end where g_j g(0) < 10 eps: the whole sums of g_j and E_j (their tails past
    the end analytic) are still above the brute sums over |m| <= 2 x 10^5, and within 1e-5 of them."""
    for table, ch in position_channels(preset):
        for i in range(ch.Q.shape[0]):
            legs, *_ = _arrays(table, ch, i, 10 * EPS)
            for j, (g, E, PE, Rs, SE, ok) in enumerate(legs):
                assert ok and g.size < 1000
                sg, se = _leg_sums(j, 2, table.env, ch.grp[i], ch.mu[i], ch.Q[i], ch.mnorm[i], ch.lam[i], 0.1, 0.0,
                                   200_000)
                assert sg <= Rs[0] <= sg * (1 + 1e-5), (preset, i, j, Rs[0] / sg - 1)
                if np.isfinite(SE):
                    assert se <= SE <= se * (1 + 1e-5), (preset, i, j, SE / se - 1)


@pytest.mark.parametrize("preset", ["u-shape", "delta-shape"])
def test_the_rows_tail_bounds_the_rows_left_out(preset):
    """_rb_tail(a) bounds sum_{k >= a} rb(k): above the brute sum over 2 x 10^4 rows from a at a = 40, 100,
    160, 300, and within 50 % of it from a = 100 (2 to 10 % on the paper budget past K0 >= 128; looser near
    the knees)."""
    for table, ch in position_channels(preset):
        for i in range(ch.Q.shape[0]):
            legs, km, cm, d_perp = _arrays(table, ch, i, 10 * EPS)
            (g1, E1, _, R1, S1E, _), (g2, E2, *_) = legs
            args = (R1[0], S1E, cm, g1, E1, g2, E2, d_perp, 2, table.env, ch.grp[i], ch.mu[i], ch.Q[i],
                    ch.mnorm[i], ch.lam[i], 0.1, 0.0, km, ch.ab[i])
            for a in (40, 100, 160, 300):
                tail = _rb_tail(a, *args)
                brute = _rows_sum(a, 20_000, *args)
                assert brute <= tail, (preset, i, a, tail / brute)
                assert a < 100 or tail <= 1.5 * brute, (preset, i, a, tail / brute)
