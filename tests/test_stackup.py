"""The exact yield's building blocks against independent quadrature: every law's characteristic function
(``prp3mc.stackup.characteristic.term_cf``) and the constants of the Bessel bounds (``prp3mc.stackup._special``).

``CF_ACCURACY`` (1e-13 a coefficient) assumes each factor of a coefficient is good to about 1e-14; here each
law's phi_t(x) is checked to 1e-14 against SciPy's adaptive quadrature of its density (QAWO for the
oscillating factors, a Gauss-Kronrod rule split at the kinks for E J0(x rho)), from a few periods across
the support to about 150.
"""

import math

import numpy as np
import pytest
from scipy import integrate, special

from prp3mc import Geometry
from prp3mc.model.budget import Budget
from prp3mc.model.laws import Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from prp3mc.model.linear import linear_model
from prp3mc.stackup._special import C_J1, CF_ACCURACY, I_MAX, int_j0, special_args
from prp3mc.stackup.characteristic import int_j0_over, int_j0_over_near, term_cf, term_table

TOL = 1e-14


def density(law):
    """(pdf, lo, hi, kinks) of a continuous law, written here from its definition."""
    if isinstance(law, Uniform):
        return (lambda v: 1.0 / (law.hi - law.lo)), law.lo, law.hi, []
    if isinstance(law, Normal):
        return (lambda v: math.exp(-0.5 * ((v - law.mu) / law.sd) ** 2) / (law.sd * math.sqrt(2 * math.pi)),
                law.mu - 12 * law.sd, law.mu + 12 * law.sd, [law.mu])
    if isinstance(law, TruncNormal):
        sd = law.tol / (3.0 * law.cpk)
        lo, hi = law.center - law.tol, law.center + law.tol
        mass = special.ndtr(law.tol / sd) - special.ndtr(-law.tol / sd)
        return (lambda v: math.exp(-0.5 * ((v - law.center) / sd) ** 2) / (sd * math.sqrt(2 * math.pi) * mass),
                lo, hi, [law.center])
    if isinstance(law, Triangular):
        a, c, b = law.lo, law.mode, law.hi
        return ((lambda v: 2 * (v - a) / ((b - a) * (c - a)) if v < c else 2 * (b - v) / ((b - a) * (b - c))),
                a, b, [c])
    if isinstance(law, Disc):
        return (lambda v: 2 * v / law.radius ** 2), 0.0, law.radius, []
    raise TypeError(law)


def reference_cf(tl, x):
    """E exp(i x X) (a factor: X = value - reference) or E J0(x rho) (a clearance) by quadrature."""
    law = tl.law
    if isinstance(law, Discrete):
        v, w = np.array(law.values), np.array(law.weights)
        if tl.kind == "clearance":
            return complex(np.sum(w * special.j0(abs(x) * v)))
        return complex(np.sum(w * np.exp(1j * x * (v - tl.reference))))
    f, lo, hi, kinks = density(law)
    if tl.kind == "clearance":
        pts = sorted(set(kinks) | set(np.linspace(lo, hi, 33)[1:-1]))
        val = integrate.quad(lambda r: f(r) * special.j0(abs(x) * r), lo, hi, points=pts, limit=2000,
                             epsabs=1e-16, epsrel=1e-15)[0]
        return complex(val)
    ref = tl.reference
    parts = [lo, *[k for k in kinks if lo < k < hi], hi]
    re = im = 0.0
    for a, b in zip(parts[:-1], parts[1:]):
        if x == 0.0:
            re += integrate.quad(f, a, b, epsabs=1e-16, epsrel=1e-15)[0]
            continue
        re += integrate.quad(lambda v: f(v + ref), a - ref, b - ref, weight="cos", wvar=x, epsabs=1e-16,
                             limit=2000)[0]
        im += integrate.quad(lambda v: f(v + ref), a - ref, b - ref, weight="sin", wvar=x, epsabs=1e-16,
                             limit=2000)[0]
    return complex(re, im)


BUDGETS = {
    "factors": {"theta_1": TruncNormal(0.01, 0.04, 1.0), "theta_2": Triangular(-0.04, 0.01, 0.04),
                "theta_3": Triangular(-0.03, -0.03, 0.02), "b_1": Uniform(0.0, 0.025), "b_2": Normal(0.002, 0.006),
                "b_3": Discrete((-0.005, 0.0, 0.005), (0.25, 0.5, 0.25))},
    "clearances": {"rho_1": Uniform(0.002, 0.016), "zeta_1": Uniform(0.0, 360.0),
                   "rho_2": Disc(0.012), "zeta_2": Uniform(0.0, 360.0),
                   "rho_3": Triangular(0.0, 0.005, 0.016), "zeta_3": Uniform(0.0, 360.0)},
    "more clearances": {"rho_1": TruncNormal(0.008, 0.008, 1.0), "zeta_1": Uniform(0.0, 360.0),
                        "rho_2": Uniform(0.0, 0.016), "zeta_2": Uniform(0.0, 360.0),
                        "rho_3": Discrete((0.004, 0.008, 0.012), (0.3, 0.5, 0.2)), "zeta_3": Uniform(0.0, 360.0)},
}


@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")   # asked for 1e-15, it gets 1e-14
@pytest.mark.parametrize("name", list(BUDGETS))
def test_every_law_characteristic_function_matches_quadrature(name):
    model = linear_model(Geometry.from_preset("u-shape"), Budget(BUDGETS[name], name=name), [0.0, 100.0, 0.0])
    laws = [tl for tl in model.term_laws if tl.law is not None and tl.kind in ("factor", "clearance")]
    table = term_table(laws, 8.0)
    tab, sp, buf = table.arrays(), special_args(), np.empty(2)
    checked = 0
    for t, tl in enumerate(laws):
        if table.kind[t] < 0:
            continue
        lo, hi = table.lo[t], table.hi[t]
        width = max(hi - lo, 1e-12)
        for cycles in (0.0, 0.3, 2.0, 9.0, 40.0, 150.0):
            x = cycles / width
            got = term_cf(table.kind[t], table.par, t, tab, sp, buf, x)
            want = reference_cf(tl, x)
            assert abs(got - want) <= TOL, (tl.name, x, got, want)
            checked += 1
    assert checked >= 18 and TOL * 10 <= CF_ACCURACY


def test_the_bessel_bounds_constants():
    """I_MAX = sup |int_0^y J0| (at J0's first zero, 2.4048) and C_J1 = sup sqrt(u) |J1(u)| (at u = 2.166; past
    u = 200 the modulus sqrt(u) (J1² + Y1²)^(1/2), decreasing, bounds it), each rounded up by at most 1e-5."""
    y = np.linspace(0.0, 200.0, 400_001)
    i0 = np.array([special.itj0y0(v)[0] for v in y[::40]])
    fine = special.itj0y0(2.404825557695773)[0]
    assert np.abs(i0).max() <= I_MAX and I_MAX - 1e-5 <= fine <= I_MAX
    u = y[1:]
    assert (np.sqrt(u) * np.abs(special.j1(u))).max() <= C_J1 <= (np.sqrt(u) * np.abs(special.j1(u))).max() + 1e-5
    assert math.sqrt(200.0) * math.hypot(special.j1(200.0), special.y1(200.0)) <= C_J1


@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")
def test_integral_of_j0_table_and_series_match_quadrature():
    """int_j0's Horner table (0 <= y < 64) and int_j0_over_near's series (y < 1) against SciPy's adaptive
    quadrature of J0, each to 1e-15 (absolute, the integral; relative for I(y) / y below 1), at points across
    every table interval's position and on both sides of 1 and 64."""
    sp, buf = special_args(), np.empty(2)
    rng = np.random.default_rng(7)
    ys = np.concatenate([rng.uniform(0.0, 64.0, 300), [0.0, 1e-9, 0.5, 1.0 - 1e-12, 1.0, 63.999999, 64.0, 70.0]])
    for y in ys:
        want = integrate.quad(special.j0, 0.0, y, epsabs=1e-17, epsrel=1e-16, limit=500)[0] if y > 0 else 0.0
        assert abs(int_j0(sp, buf, y) - want) <= 1e-15 + 1e-14 * (y >= 8.0), y
        want_over = want / y if y > 0 else 1.0
        assert abs(int_j0_over(sp, buf, y) - want_over) <= 2e-15 * max(1.0, 1.0 / max(y, 1.0)), y
        if y < 64.0:
            assert int_j0_over_near(sp[3], y) == int_j0_over(sp, buf, y)


def test_the_sums_leave_out_is_within_its_room_on_bounds_of_every_magnitude():
    """series._sum on synthetic terms (d = 1, bounds cb from 1e-300 to 1 with ties, zeros and -0.0): what it
    leaves out, summed by brute force from the points it dropped, is within the bound it returns, which is within
    the room; with no room every point is kept (to the bit), with room for all of them none is."""
    from prp3mc.stackup.series import _sum

    rng = np.random.default_rng(5)
    n, lam, z = 4000, 3.0, 0.7
    cb = 10.0 ** rng.uniform(-300.0, 0.0, n)
    cb[:50] = cb[50]                                               # a bin with ties
    cb[60:70] = 0.0
    cb[70] = -0.0
    re = cb * rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 1.0, n)
    ta = rng.uniform(0.1, 50.0, n)
    tb = np.zeros(n)
    sp = special_args()
    term = np.array([2.0 * math.sin(a * z) / a for a in ta])        # as _sum takes it
    assert np.all(np.abs(term) <= 2.0 * z)
    total = 2.0 * np.abs(cb).sum() * 2.0 * z / lam
    for share in (0.0, 1e-9, 1e-3, 0.1, 0.5, 0.9, 2.0):
        room = share * total
        scale = 2.0 * z                                            # cb must bound |re T|: the transform's bound
        r, a, b, c = re.copy(), ta.copy(), tb.copy(), np.abs(cb) * scale
        s, left, m = _sum(1, lam, r, a, b, c, z, 0.0, sp[1], room)
        kept = np.isin(ta, a[:m])
        assert kept.sum() == m
        dropped = 2.0 * (np.abs(cb[~kept]) * scale).sum() / lam
        assert dropped <= left * (1 + 1e-12) and left <= max(room, 0.0)
        assert abs(2.0 * (np.sum(re * term) - s) / lam) <= left + 1e-15 * total
        if share == 0.0:
            assert m == n and left == 0.0 and s == sum(float(x) for x in re * term)
        if share >= 1.0:
            assert m <= 11                                          # all but (maybe) the zeros
        if 0.0 < share < 1.0:
            assert left >= 0.98 * room - 2.0 * c.max() / lam          # it leaves out about what the room allows
