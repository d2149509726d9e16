"""The chain's formulas: one source for arrays and compiled scalars, checked against independent references."""

import math

import numpy as np
from numba import njit

from prp3mc.kinematics.formulas import (
    FAMILIES, a_row, adjugate3, cos_range, h_entry, h_row, leg_ik, offset_vector, turn,
)


@njit(cache=True)
def _compiled(v):
    """Every formula on the scalars of each row of ``v`` (N, 15), as the envelope kernel calls them."""
    out = np.empty((v.shape[0], 32))
    for n in range(v.shape[0]):
        a, c, e, ci, si, cj, sj, c0, s0 = v[n, 0], v[n, 1], v[n, 2], v[n, 3], v[n, 4], v[n, 5], v[n, 6], v[n, 7], v[n, 8]
        cp, sp, x, y, lo, w = v[n, 9], v[n, 10], v[n, 11], v[n, 12], v[n, 13], v[n, 14]
        ck, sk = turn(c0, s0, cp, sp)
        cl, sl = turn(s0, c0, cp, sp)
        cm, sm = turn(ci, si, cp, sp)
        ox, oy = offset_vector(a, c, e, ci, si, ck, sk, cm, sm)
        b, d = leg_ik(x - ox, y - oy, cj, sj, cl, sl)
        r = a_row(c, d, e, ck, sk, cl, sl, cm, sm)
        h = h_row(a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm)
        adj = adjugate3(r[0], r[1], r[2], a, b, c, d, e, x)
        cr = cos_range(lo, lo + w)
        row = (b, d) + r + h + adj + cr + (ck, sk, cm)
        for k in range(32):
            out[n, k] = row[k]
    return out


def _numpy(v):
    """The same on whole columns (numpy broadcasting)."""
    a, c, e, ci, si, cj, sj, c0, s0, cp, sp, x, y, lo, w = v.T
    ck, sk = turn(c0, s0, cp, sp)
    cl, sl = turn(s0, c0, cp, sp)
    cm, sm = turn(ci, si, cp, sp)
    ox, oy = offset_vector(a, c, e, ci, si, ck, sk, cm, sm)
    b, d = leg_ik(x - ox, y - oy, cj, sj, cl, sl)
    r = a_row(c, d, e, ck, sk, cl, sl, cm, sm)
    h = [np.broadcast_to(h_entry(q, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm), b.shape)
         for q in range(len(FAMILIES))]
    adj = adjugate3(*r, a, b, c, d, e, x)
    return np.column_stack([b, d, *r, *h, *adj, *cos_range(lo, lo + w), ck, sk, cm])


def _inputs(n=2000, seed=7):
    rng = np.random.default_rng(seed)
    t = rng.uniform(-np.pi, np.pi, (n, 4))
    v = np.column_stack([rng.uniform(-50, 50, (n, 3)), np.cos(t[:, 0]), np.sin(t[:, 0]), np.cos(t[:, 1]),
                         np.sin(t[:, 1]), np.cos(t[:, 2]), np.sin(t[:, 2]), np.cos(t[:, 3]), np.sin(t[:, 3]),
                         rng.uniform(-200, 200, (n, 2)), rng.uniform(-20, 20, n), rng.uniform(0, 6.2, n)])
    return v


def test_compiled_and_numpy_paths_agree_bit_for_bit():
    v = _inputs()
    np.testing.assert_array_equal(_compiled(v), _numpy(v))


def test_leg_ik_closes_the_leg():
    """T = a i + b j + c k + d l + e m with the b, d of leg_ik (eq. 1 without errors)."""
    v = _inputs()
    a, c, e, ci, si, cj, sj, c0, s0, cp, sp, x, y, _, _ = v.T
    ck, sk = turn(c0, s0, cp, sp)
    cl, sl = turn(s0, c0, cp, sp)
    cm, sm = turn(ci, si, cp, sp)
    ox, oy = offset_vector(a, c, e, ci, si, ck, sk, cm, sm)
    b, d = leg_ik(x - ox, y - oy, cj, sj, cl, sl)
    ok = np.abs(cj * sl - sj * cl) > 0.05          # away from l || j
    np.testing.assert_allclose((a * ci + b * cj + c * ck + d * cl + e * cm)[ok], x[ok], atol=1e-9)
    np.testing.assert_allclose((a * si + b * sj + c * sk + d * sl + e * sm)[ok], y[ok], atol=1e-9)


def test_turn_is_the_angle_sum():
    t0, phi = np.linspace(-4, 4, 9), np.linspace(3, -2, 9)
    c, s = turn(np.cos(t0), np.sin(t0), np.cos(phi), np.sin(phi))
    np.testing.assert_allclose(c, np.cos(t0 + phi), atol=1e-15)
    np.testing.assert_allclose(s, np.sin(t0 + phi), atol=1e-15)


def test_adjugate_is_det_times_inverse():
    M = np.random.default_rng(3).normal(size=(50, 3, 3))
    *adj, det = adjugate3(*np.moveaxis(M, 0, -1).reshape(9, -1))
    np.testing.assert_allclose(det, np.linalg.det(M), rtol=1e-12)
    inv = np.stack(adj).reshape(3, 3, -1) / det
    np.testing.assert_allclose(np.moveaxis(inv, -1, 0), np.linalg.inv(M), rtol=1e-9, atol=1e-12)


def test_cos_range_against_a_dense_scan():
    rng = np.random.default_rng(11)
    lo, w = rng.uniform(-20, 20, 300), rng.uniform(0, 2 * math.pi - 1e-6, 300)
    cmin, amin, cmax, amax = cos_range(lo, lo + w)
    scan = np.cos(lo[:, None] + w[:, None] * np.linspace(0.0, 1.0, 20001))
    assert np.all(cmin <= scan.min(axis=1) + 1e-12) and np.all(cmax >= scan.max(axis=1) - 1e-12)
    assert np.all(cmin >= scan.min(axis=1) - 1e-6) and np.all(cmax <= scan.max(axis=1) + 1e-6)
    assert np.all((amin >= lo) & (amin <= lo + w) & (amax >= lo) & (amax <= lo + w))
    np.testing.assert_array_equal(np.cos(amin), cmin)
