"""Which lattice points the series keeps, and a rigorous bound of what it leaves out (compiled).

The summand at a lattice point n is ``phi_Y(w) T_D(w) / |L|`` (:mod:`.series`).
Its modulus is below the *envelope*

    F(n) = prod_t env_t(``|c_t . w|``) * Tb(w) / ``|L|``,

with env_t the terms' decreasing bounds (:func:`~.characteristic.envelope`)
and Tb a bound of ``|T_D|`` valid for every radius up to the largest served.
Both are symmetric under n -> -n, so half of the lattice is enumerated and
every point stands for two.

The lattice is cut into *rows*, lines along n_1 (the first basis leg), at
fixed (n_2, n_3). The target eps is shared out: 0.2 to the rows left out
whole, 0.15 to the rows skipped for their small whole sums, 0.15 to the tails
of the rows walked, 0.4 to the points dropped; the rest is left to floating
point and the normal laws' cut (:mod:`.series`).

**A row's tail.** Along a row every factor of F is an envelope of the modulus
of an affine function of n_1 (the transform's bound: of the norm of one), so
it is non-increasing past its peak c, and past a point U >= c it falls at
least as ((U - c) / (n_1 - c))^p, p its local power
(:func:`~.characteristic.envelope_power`). The factors whose peak lies beyond
U are bounded by their value at U divided out (they are <= 1 further on); the
others fall together at least as ((U - c_min) / (n_1 - c_min))^P, P the sum
of their powers, so ``sum_{n_1 > U} F <= F(U) (U - c_min) / (dropped (P - 1))``
(:func:`_walk_row`). Each row is walked outward from n_1 = 0 (F is taken
inline, point by point) and the tail tried at every 4th point until both
tails are within the row's share of the 0.15.

**Which rows.** In 1-D there is one row. For the position, a row's whole sum
is bounded two ways: by the separable majorant ``g_1(n_1) g_2(n_2) G_m(nu_m)``
(g_j: E_j, the product of basis leg j's envelopes, times the share
(tau / ``|L|``)^(1/d) of the radial transform bound tau; G_m: the third, "mixed",
leg's), which sums along a row to at most ``min(S_1, G_m(|beta nu_2| / 2) S_1
+ g_1(|beta nu_2| / (2 |alpha|)) C_m)`` (nu_m = alpha nu_1 + beta nu_2, so one of
``|nu_1|``, ``|nu_m|`` is large where ``|nu_2|`` is; S_1 = sum of g_1; C_m bounds the sum
of G_m along a row by its integral); and by E_2 times the transform's bound
at the row's closest approach to w = 0 times the same sum of E_1 G_m. That
bound is non-increasing in ``|n_2|``; the rows past K_2 are left out whole, K_2
the least leaving out at most 0.2 eps (past the first K_0 rows, bounded one by
one, they are bounded together: each factor of the bound falls at least as a
power of ``|n_2|``, :func:`_rb_tail`; K_0 from 128 up until that is within 0.05
eps). The 1-D arrays of the position end where g_j g(0) < 10 eps, past that
their entries come on demand and their sums' tails are analytic,
``sum_{n > N} g(n) <= g(N) N / (p - 1)``. For both channels (d = 3), rows
(n_2, n_3) are kept for ``|n_3|`` <= K_3, n_2 walked from its peak as n_1 is;
the rest is bounded from the 1-D sums of E_2, E_3 and the transform's bound
(:func:`_rows_3d`). Of the rows kept, those of smallest whole sums are skipped
while they add up to at most 0.15 eps.

Of the points walked, the smallest are dropped while their sum stays within
0.4 of the target (log2 bins of F; the sum dropped is counted exactly).
The bound is outer rows + skipped rows + row tails + dropped points.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._special import C_J1
from .lattice import MIXED_LEG
from .characteristic import envelope, envelope_power

__all__ = ["arrays_end", "exponent_field", "leg_envelope", "select_points", "transform_bound"]

_TWO_PI = 2.0 * math.pi
_SQRT2 = math.sqrt(2.0)
_N_CAP = 1 << 20            # longest 1-D envelope array of a basis leg
_RATIO = 1.25              # the geometric grid of the mixed leg's integral (:func:`_mixed_row_sum`)
_LOG_RATIO = math.log(_RATIO)
_K0 = 128                   # the position's rows bounded one by one, at least (past them: :func:`_rb_tail`)
_CHUNK = 64                 # points a row walk appends between checks of the arrays' room (:func:`_grown`)
_BINS = 1400                # log2 bins of the envelope, from 2^-1300 up
_WALK_CAP = 1 << 22         # farthest point of a row walk
_MAX_POINTS = (1 << 23, 1 << 23, 1 << 18)   # most points walked at one pose, per dimension (beyond: status 3)


# ------------------------------------------------------------------ bounds of the transform of D

@njit(cache=True, nogil=True)
def _disc_bound(S, u):
    """Bound of ``|2 pi S' J1(S' u) / u|`` over S' <= S (``|J1(v)|`` <= v / 2 and <= C_J1 / sqrt(v))."""
    if u <= 0.0:
        return math.pi * S * S
    return min(math.pi * S * S, 2.0 * math.pi * C_J1 * math.sqrt(S) / (u * math.sqrt(u)))


@njit(cache=True, nogil=True)
def _interval_bound(Z, u):
    """Bound of ``|2 sin(Z' u) / u|`` over Z' <= Z."""
    if u <= 0.0:
        return 2.0 * Z
    return min(2.0 * Z, 2.0 / u)


@njit(cache=True, nogil=True)
def _tau(d, z1, z2, r):
    """Bound of ``|T_D(w)|`` over ``|w|`` >= r (every radius up to z1; the cylinder's half-height z2), non-increasing."""
    if d == 1:
        return _interval_bound(z1, r)
    if d == 2:
        return _disc_bound(z1, r)
    u = r / _SQRT2          # either |w_xy| or |w_z| is at least |w| / sqrt 2
    return max(_disc_bound(z1, u) * 2.0 * z2, math.pi * z1 * z1 * _interval_bound(z2, u))


@njit(cache=True, nogil=True)
def _tau_pow(d, z1, z2, r0):
    """A power p with tau(r) <= tau(r0) (r0 / r)^p for r >= r0 > 0."""
    if d == 1:
        return 1.0 if 1.0 / r0 <= z1 else 0.0
    if d == 2:
        return 1.5 if 2.0 * C_J1 / (r0 * math.sqrt(r0 * z1)) <= z1 else 0.0
    u = r0 / _SQRT2
    pa = 1.5 if 2.0 * C_J1 / (u * math.sqrt(u * z1)) <= z1 else 0.0
    pb = 1.0 if 1.0 / u <= z2 else 0.0
    return min(pa, pb)


@njit(cache=True, nogil=True)
def transform_bound(d, z1, z2, a, b):
    """Bound of ``|T_D|`` at a point: a = ``|nu|`` (d = 1), ``|w|`` (d = 2), ``|w_xy|`` (d = 3); b = ``|w_z|`` (d = 3)."""
    if d == 1:
        return _interval_bound(z1, a)
    if d == 2:
        return _disc_bound(z1, a)
    return _disc_bound(z1, a) * _interval_bound(z2, b)


# ------------------------------------------------------------------ a basis leg's envelope along its axis

@njit(cache=True, nogil=True)
def _root(v, d):
    """v^(1/d) (a square root for d = 2: no call to pow)."""
    return v if d == 1 else (math.sqrt(v) if d == 2 else v ** (1.0 / 3.0))


@njit(cache=True, nogil=True)
def _leg_at(j, m, d, ev, grp, mu, Q, mnorm, lam, z1, z2):
    """Basis leg j at n_j = m: its envelope product E_j, its share g_j = E_j (tau(nu_j / ``|m_j|``) / ``|L|``)^(1/d),
    and the decay powers of g_j and of E_j there (0 at m = 0)."""
    nu = _TWO_PI * m / Q[j]
    e = 1.0
    pe = 0.0
    for t in range(ev.shape[0]):
        if grp[t] == j:
            v, pv = envelope_power(ev[t, 0], ev[t, 1], ev[t, 2], ev[t, 3], ev[t, 4], ev[t, 5], ev[t, 6], ev[t, 7],
                                   abs(mu[t, j]) * nu)
            e *= v
            pe += pv
    r = nu / mnorm[j]
    pg = pe + _tau_pow(d, z1, z2, r) / d if m > 0 else 0.0
    return e, e * _root(_tau(d, z1, z2, r) / lam, d), pg, pe


@njit(cache=True, nogil=True)
def arrays_end(d, eps):
    """Where :func:`select_points` ends the basis legs' 1-D arrays (:func:`leg_envelope`'s ``eta_lo``) for
    the target eps; past it E_j comes on demand (the same bits). The position's rows and its walk reach far
    less far than where g_j g(0) < 0.1 eps (~1/6 of it on the paper's budget): its arrays end at 10 eps, the
    sums past their end analytic (:func:`leg_envelope`), the rows past them bounded by ``_rb_tail``."""
    return (1e1 if d == 2 else 1e-1) * eps


@njit(cache=True, nogil=True)
def leg_envelope(j, d, ev, grp, mu, Q, mnorm, lam, z1, z2, g0, eta_lo):
    """Leg j's E_j and g_j (:func:`_leg_at`) at n = 0..N, and ``Rs[m + 1] = sum_{|n| > m} g_j(|n|)``
    (Rs[0]: the whole sum), the tail past N analytic: ``2 g(N) N / (p - 1)``. N: where g_j times the other
    legs' g(0) is below ``eta_lo`` with a decay power above 1 (past it, :func:`_leg_at` gives E_j on demand).
    Returns (g, E, PE, Rs, SE, ok): PE the decay power of E_j at each n (the sum of its terms'); SE =
    sum_{n in Z} E_j(``|n|``) (inf when E_j's power stays at or below 1); not ok when g_j's does (no finite
    sum)."""
    cap = 256
    g = np.empty(cap)
    E = np.empty(cap)
    PE = np.empty(cap)
    m = 0
    p = 0.0
    while True:
        e, gm, p, pe = _leg_at(j, m, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
        if m == cap:
            cap *= 2
            g2 = np.empty(cap)
            E2 = np.empty(cap)
            P2 = np.empty(cap)
            g2[:m] = g[:m]
            E2[:m] = E[:m]
            P2[:m] = PE[:m]
            g, E, PE = g2, E2, P2
        g[m] = gm
        E[m] = e
        PE[m] = pe
        if m >= 1 and p > 1.0 and gm * g0 ** (d - 1) < eta_lo:
            break
        if m >= _N_CAP:
            if p <= 1.0:
                return g[:m + 1], E[:m + 1], PE[:m + 1], np.full(m + 2, np.inf), np.inf, False
            break
        m += 1
    N = m
    Rs = np.empty(N + 2)
    Rs[N + 1] = 2.0 * g[N] * N / (p - 1.0)
    for k in range(N, 0, -1):
        Rs[k] = Rs[k + 1] + 2.0 * g[k]
    Rs[0] = Rs[1] + g[0]
    SE = np.inf
    if pe > 1.0:
        SE = E[0] + 2.0 * (E[1:N + 1].sum() + E[N] * N / (pe - 1.0))
    return g[:N + 1], E[:N + 1], PE[:N + 1], Rs, SE, True


@njit(cache=True, nogil=True)
def _leg_pair(g, E, j, m, d, ev, grp, mu, Q, mnorm, lam, z1, z2):
    """Basis leg j's (E_j, g_j) at n_j = m >= 0: from its arrays (:func:`leg_envelope`), or on demand past
    their end (:func:`_leg_at`: the same bits)."""
    if m < g.size:
        return E[m], g[m]
    e, gm, _, _ = _leg_at(j, m, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
    return e, gm


# ------------------------------------------------------------------ the position's third (mixed) leg

@njit(cache=True, nogil=True)
def _mixed_scales(grp, mu, ab):
    """``|c_t . w|`` per unit of ``|nu_m|`` of each term of the mixed leg (0 for the others), (T,)."""
    km = np.zeros(grp.size)
    norm = math.sqrt(ab[0] * ab[0] + ab[1] * ab[1])
    for t in range(grp.size):
        if grp[t] == MIXED_LEG:
            km[t] = math.sqrt(mu[t, 0] ** 2 + mu[t, 1] ** 2) / norm
    return km


@njit(cache=True, nogil=True)
def _mixed(ev, grp, km, ax3):
    """The mixed leg's envelope product G_m at ``|nu_m|`` = ax3 and its decay power there (0 at ax3 = 0); km:
    :func:`_mixed_scales`."""
    e = 1.0
    p = 0.0
    for t in range(ev.shape[0]):
        if grp[t] == MIXED_LEG:
            v, pv = envelope_power(ev[t, 0], ev[t, 1], ev[t, 2], ev[t, 3], ev[t, 4], ev[t, 5], ev[t, 6], ev[t, 7],
                                   km[t] * ax3)
            e *= v
            p += pv
    return e, p


@njit(cache=True, nogil=True)
def _mixed_row_sum(ev, grp, km, delta):
    """Bound of sum_k G_m(x0 + k delta) over k in Z, any x0: max G_m + (2 / delta) int_0^inf G_m
    (G_m even and non-increasing in ``|x|``). inf when there is no mixed leg or G_m does not decay faster
    than 1/x.

    The integral: G_m is 1 up to ``flat`` (found by doubling from 1e-6 / max km; G_m <= 1 below the
    first probe), which adds that much. Past it, on a geometric grid x_i (ratio r = 1.25), G_m falls at
    least as its decay power p at x_i (:func:`_mixed`: G_m(y) <= G_m(x_i) (x_i / y)^p for y >= x_i), so

        int_{x_i}^{r x_i} G_m <= G_m(x_i) x_i int_1^r s^-p ds = G_m(x_i) x_i ln r (e^{(1 - p) ln r} - 1) / ((1 - p) ln r)

    (``ln r`` at p = 1), and the rest past x_i is at most ``G_m(x_i) x_i / (p - 1)`` (p > 1), added when it
    is within 1e-6 of the integral so far."""
    kmax = km.max()
    if kmax == 0.0 or delta <= 0.0:
        return np.inf
    x = 1e-6 / kmax
    flat = 0.0
    probe = x
    for _ in range(64):
        if _mixed(ev, grp, km, probe)[0] < 1.0:
            break
        flat = probe
        probe *= 2.0
    x = max(x, flat)
    acc = x
    for _ in range(2000):
        e, p = _mixed(ev, grp, km, x)
        if p > 1.0 and e * x / (p - 1.0) <= 1e-6 * acc:
            return 1.0 + 2.0 * (acc + e * x / (p - 1.0)) / delta
        q = (1.0 - p) * _LOG_RATIO
        acc += e * x * _LOG_RATIO * (math.expm1(q) / q if q != 0.0 else 1.0)
        x *= _RATIO
    return np.inf


@njit(cache=True, nogil=True)
def _rb(k, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km, ab):
    """Bound of the whole sum of the position's row n_2 = k >= 1 (``|nu_2|`` = nu2), two ways.

    Form A: g_2(k) times a bound of the row's sum of g_1(n_1) G_m(nu_m) (the transform shared); form B
    (when S1E, the sum of E_1, is finite): E_2(k) times the transform's bound at the row's closest approach
    to w = 0 (``|nu_2|`` d_perp) times a bound of the row's sum of E_1(n_1) G_m(nu_m). With h = g_1 or E_1
    (non-increasing) and S_h its sum over the row, that sum is at most S_h (G_m <= 1), and, as one of
    ``|nu_1|`` >= ``|beta|`` nu2 / (2 ``|alpha|``), ``|nu_m|`` >= ``|beta|`` nu2 / 2 holds at every point (nu_m =
    alpha nu_1 + beta nu_2), at most G_m(``|beta|`` nu2 / 2) S_h + h(``|beta|`` nu2 / (2 ``|alpha|``)) C_m (h at
    the integer below; C_m: :func:`_mixed_row_sum`). Both forms are non-increasing in k (so are g_2, E_2,
    the transform's bound, G_m and h). Returns (min of the two, form A, form B, nu2)."""
    nu2 = _TWO_PI * k / Q[1]
    e2, g2k = _leg_pair(g2, E2, 1, k, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
    alpha, beta = ab[0], ab[1]
    ha, hb = S1, S1E
    if beta != 0.0 and cm < np.inf:
        gmv, _ = _mixed(ev, grp, km, 0.5 * abs(beta) * nu2)
        e1v = g1v = 0.0
        if alpha != 0.0:
            e1v, g1v = _leg_pair(g1, E1, 0, int(abs(beta) * nu2 / (2.0 * abs(alpha)) * Q[0] / _TWO_PI), d, ev, grp,
                                 mu, Q, mnorm, lam, z1, z2)
        ha = min(ha, gmv * S1 + g1v * cm)
        if S1E < np.inf:
            hb = min(hb, gmv * S1E + e1v * cm)
    fa = g2k * ha
    fb = e2 * _disc_bound(z1, nu2 * d_perp) / lam * hb if S1E < np.inf else np.inf
    return min(fa, fb), fa, fb, nu2


@njit(cache=True, nogil=True)
def _rb_tail(a, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km, ab):
    """Bound of ``sum_{k >= a} rb(k)`` (a >= 1; :func:`_rb`): each form f of :func:`_rb` falls at least as
    f(a) (a / k)^P past a, so ``sum_{k >= a} rb(k) <= f(a) (1 + int_a^inf (a / x)^P dx) = f(a) (1 + a / (P - 1))``
    when P > 1; the smaller of the two (inf when neither power is above 1).

    The powers, for k >= a (every argument below is proportional to k):

    - g_2 and E_2 fall as their powers at a (:func:`_leg_at`), the transform's bound at the closest
      approach ``|nu_2|`` d_perp as its power there (:func:`_tau_pow`);
    - the bound of the row's sum of h, ``min(S_h, G_m(|beta| nu_2 / 2) S_h + h(floor(c k)) C_m)`` (c = ``|beta|
      Q_1 / (2 |alpha| Q_2)``): G_m falls as its power p_m at a (:func:`_mixed`); with x = c a > 1 and
      i = floor(x), floor(c k) > c k - 1 >= (x - 1) k / a, so ``h(floor(c k)) <= h(i) (i / floor(c k))^p_h
      <= h(i) (i / (x - 1))^p_h (a / k)^p_h`` (p_h h's power at i; p_h = 0 when x <= 1); the sum falls as
      ``(G_m S_h + h(i) (i / (x - 1))^p_h C_m) (a / k)^min(p_m, p_h)`` (its value at a times that, and
      S_h with power 0 when that value is larger)."""
    nu2 = _TWO_PI * a / Q[1]
    e2, g2a, pg, pe = _leg_at(1, a, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
    alpha, beta = ab[0], ab[1]
    ha, qa, hb, qb = S1, 0.0, S1E, 0.0
    if beta != 0.0 and cm < np.inf:
        gmv, pm = _mixed(ev, grp, km, 0.5 * abs(beta) * nu2)
        e1v = g1v = 0.0
        ra = rb = 1.0
        pa1 = pb1 = np.inf
        if alpha != 0.0:
            x = abs(beta) * nu2 / (2.0 * abs(alpha)) * Q[0] / _TWO_PI
            i = int(x)
            e1v, g1v, pa1, pb1 = _leg_at(0, i, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
            if x > 1.0:
                ra, rb = (i / (x - 1.0)) ** pa1, (i / (x - 1.0)) ** pb1
            else:
                pa1 = pb1 = 0.0
        ta = gmv * S1 + g1v * ra * cm
        if ta < S1:
            ha, qa = ta, min(pm, pa1)
        tb = gmv * S1E + e1v * rb * cm
        if tb < S1E:
            hb, qb = tb, min(pm, pb1)
    t = g2a * ha * (1.0 + a / (pg + qa - 1.0)) if pg + qa > 1.0 else np.inf
    r = nu2 * d_perp
    pt = pe + (_tau_pow(2, z1, z2, r) if r > 0.0 else 0.0) + qb
    if S1E < np.inf and pt > 1.0:
        t = min(t, e2 * _disc_bound(z1, r) / lam * hb * (1.0 + a / (pt - 1.0)))
    return t


# ------------------------------------------------------------------ the rows

@njit(cache=True, nogil=True)
def exponent_field(f):
    """The biased binary exponent of a float64 (its bits 52-62): ``floor(log2 |f|) + 1023`` for a normal f, 0
    for a subnormal or 0, 2047 for inf and NaN. The log2 bins of the walk's drop (:func:`_bin`) and of the
    sum's left-out points (:func:`~.series._sum`)."""
    return (np.float64(f).view(np.int64) >> 52) & 0x7FF


@njit(cache=True, nogil=True)
def _bin(f):
    """The drop's log2 bin of f > 0: ``floor(log2 f) + 1300`` within [0, _BINS): from f's exponent field
    (f normal), else (subnormal) ``math.frexp``'s exponent."""
    e = exponent_field(f)
    k = e - 1023 + 1300 if e > 0 else math.frexp(f)[1] - 1 + 1300
    return min(_BINS - 1, max(0, k))


@njit(cache=True, nogil=True)
def _only_inverse(row):
    """Whether a row of :attr:`~.characteristic.TermTable.env` has a1 / x as its one form (a1 > 0, no other
    coefficient, no normal factor): then :func:`_inverse_envelope` is its envelope, to the bit."""
    return row[0] > 0.0 and not (row[1:3] > 0.0).any() and not (row[4:8] > 0.0).any()


@njit(cache=True, nogil=True)
def _inverse_envelope(a1, x):
    """:func:`~.characteristic.envelope` of a row with a1 / x alone (:func:`_only_inverse`), its operations in
    its order (``min(1, a1 / x)``; 1 at x = 0) without the tests of the absent forms: the same bits."""
    return min(1.0, a1 / x) if x > 0.0 else 1.0


@njit(cache=True, nogil=True)
def _factor_tail(value, c, U, p, dropped, power, cmin):
    """Fold a factor of the row (its value at U, its peak c along the row, its decay power p at U) into
    ``(dropped, power, cmin)`` = (product of dropped factors, total power, smallest peak), returned: past
    U >= c the factor falls at least as ((U - c) / (n - c))^p, and (U - c) / (x - c) only grows as c falls,
    so the product of the factors kept falls at least as ((U - c_min) / (x - c_min))^P; a factor whose peak
    lies beyond U may still rise: it is dropped (bounded by 1)."""
    if c > U:
        return dropped * value, power, cmin
    if p > 0.0:
        return dropped, power + p, min(cmin, c)
    return dropped, power, cmin


@njit(cache=True, nogil=True)
def _grown(F, pts, count):
    """F (n,) and pts (n, 3) grown to n = max(2 F.size, count + _CHUNK) entries, their first count copied."""
    n = max(2 * F.size, count + _CHUNK)
    F2 = np.empty(n)
    F2[:count] = F[:count]
    P2 = np.empty((n, 3), np.int64)
    P2[:count] = pts[:count]
    return F2, P2


@njit(cache=True, nogil=True)
def _walk_row(d, n2, n3, origin, budget, E1, P1, NU1, e2, e3, mix, ev, grp, mu, Q, Vinv, mnorm, lam, z1, z2,
              rowc, inv1, pts, F, count):
    """Walk the row (n2, n3) outward from n_1 = 0, appending its points (n, F) from ``count`` on, until each
    side's tail is within half the budget. ``E1``, ``P1``: the first basis leg's envelope product and its
    power along its axis (:func:`leg_envelope`); ``NU1``: nu_1 at n_1 = 0, 1, ... (``2 pi n_1 / Q_1``, as the
    walk would compute it; past its end the walk does); ``e2``, ``e3``: the row's E_2 and E_3; ``mix``: the
    terms off the basis legs (mixed, thermal), whose envelopes F takes point by point (``inv1``: those with
    a1 / x alone, :func:`_inverse_envelope`); ``rowc``: (mix.size, 2)
    scratch for their row constants ``mu_t2 nu_2``, ``mu_t3 nu_3`` (the sums keep their order: same bits).
    The arrays grow (:func:`_grown`) only between chunks of _CHUNK points: no array is rebound inside the
    walk's inner loop, which then runs without reference counting (atomic NRT increfs/decrefs of F and pts
    at every point when they could be rebound there). With the drop's bins filled after the walk (not point
    by point) the points' computations overlap: select_points -0.2 to -0.3 ms a pose on the paper's grid.

    The tail is tried at every 4th point U, from F's value f there: every factor of F is an envelope of
    ``|an affine function of n_1|`` (the transform's of the norm of one), non-increasing past its peak (see
    :func:`_factor_tail`; the basis leg's peak at n_1 = 0), so
    ``sum_{n > U} F <= int_U^inf f / dropped ((U - c_min) / (x - c_min))^P dx = f / dropped (U - c_min) / (P - 1)``.
    Returns (count, tails, pts, F, ok)."""
    nu2 = _TWO_PI * n2 / Q[1]
    nu3 = _TWO_PI * n3 / Q[2]
    e23 = e2 * e3
    for k in range(mix.size):
        rowc[k, 0] = mu[mix[k], 1] * nu2
        rowc[k, 1] = mu[mix[k], 2] * nu3
    cx = (Vinv[0, 1] * nu2, Vinv[1, 1] * nu2, Vinv[2, 1] * nu2)
    cz = (Vinv[0, 2] * nu3, Vinv[1, 2] * nu3, Vinv[2, 2] * nu3)
    v00, v10, v20 = Vinv[0, 0], Vinv[1, 0], Vinv[2, 0]
    tails = 0.0
    ok = True
    for side in range(2):
        if origin and side == 1:
            break
        s = 1 if side == 0 else -1
        U = 1 if (origin or side == 1) else 0             # side 0 holds n1 = 0 (origin row: n1 >= 1)
        step = _TWO_PI * s / Q[0]                         # nu_1 per step along the side
        vx, vy, vz = Vinv[0, 0] * step, Vinv[1, 0] * step, Vinv[2, 0] * step
        done = False
        while not done:
            if count + _CHUNK > F.size:
                F, pts = _grown(F, pts, count)
            stop = count + _CHUNK
            while count < stop:
                if U > _WALK_CAP:
                    ok = False
                    done = True
                    break
                tail_here = U >= 1 and U % 4 == 0
                # F at (s U, n2, n3): the basis legs' envelopes, the others', the transform's bound; at a tail
                # point also each factor's decay power and peak (dropped, power, cmin: see _factor_tail)
                if U < NU1.size:
                    nu1 = NU1[U] if s > 0 else -NU1[U]        # 2 pi (-U) / Q_1 = -(2 pi U / Q_1) exactly
                else:
                    nu1 = _TWO_PI * (s * U) / Q[0]
                if U < E1.size:
                    e1, p1 = E1[U], P1[U]
                else:
                    e1, _, _, p1 = _leg_at(0, U, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
                f = e1 * e23
                dropped, power, cmin = 1.0, p1, (min(float(U), 0.0) if p1 > 0.0 else float(U))
                for k in range(mix.size):
                    t = mix[k]
                    x = mu[t, 0] * nu1 + rowc[k, 0] + rowc[k, 1]
                    if tail_here:
                        v, pv = envelope_power(ev[t, 0], ev[t, 1], ev[t, 2], ev[t, 3], ev[t, 4], ev[t, 5], ev[t, 6],
                                               ev[t, 7], abs(x))
                        slope = mu[t, 0] * step
                        if slope != 0.0:                      # else constant along the row
                            dropped, power, cmin = _factor_tail(v, U - x / slope, U, pv, dropped, power, cmin)
                    elif inv1[k]:
                        v = _inverse_envelope(ev[t, 0], abs(x))
                    else:
                        v = envelope(ev[t, 0], ev[t, 1], ev[t, 2], ev[t, 3], ev[t, 4], ev[t, 5], ev[t, 6], ev[t, 7],
                                     abs(x))
                    f *= v
                # the transform: |nu_1| and |w_z| are affine in n_1, |w_xy| the norm of an affine function
                if d == 1:
                    a = abs(nu1)
                    tb = _interval_bound(z1, a)
                    if tail_here:
                        dropped, power, cmin = _factor_tail(tb, 0.0, U, _tau_pow(1, z1, z2, a), dropped, power, cmin)
                else:
                    wx = v00 * nu1 + cx[0] + cz[0]
                    wy = v10 * nu1 + cx[1] + cz[1]
                    a = math.sqrt(wx * wx + wy * wy)
                    tb = _disc_bound(z1, a)
                    if tail_here:
                        vv = vx * vx + vy * vy
                        if vv > 0.0:
                            dropped, power, cmin = _factor_tail(tb, U - (wx * vx + wy * vy) / vv, U,
                                                                _tau_pow(2, z1, z2, a) if a > 0 else 0.0,
                                                                dropped, power, cmin)
                    if d == 3:
                        wz = v20 * nu1 + cx[2] + cz[2]
                        tz = _interval_bound(z2, abs(wz))
                        tb *= tz
                        if tail_here and vz != 0.0:
                            dropped, power, cmin = _factor_tail(tz, U - wz / vz, U,
                                                                _tau_pow(1, z2, z2, abs(wz)) if wz != 0 else 0.0,
                                                                dropped, power, cmin)
                f = f * tb / lam
                pts[count, 0], pts[count, 1], pts[count, 2] = s * U, n2, n3
                F[count] = f
                count += 1
                if tail_here and power > 1.0 and dropped > 0.0:
                    tail = f / dropped * (U - cmin) / (power - 1.0)
                    if tail <= 0.5 * budget:
                        tails += tail
                        done = True
                        break
                U += 1
        if not ok:
            tails += np.inf
    return count, tails, pts, F, ok


@njit(cache=True, nogil=True)
def _leg_value(j, m, E, d, ev, grp, mu, Q, mnorm, lam, z1, z2):
    """E_j at ``|n_j|`` = m: from the array, or on demand past its end."""
    if m < E.size:
        return E[m]
    return _leg_at(j, m, d, ev, grp, mu, Q, mnorm, lam, z1, z2)[0]


@njit(cache=True, nogil=True)
def _first_within(suffix, e):
    """The fewest rows to keep: the least K with ``suffix[K + 1]`` <= e, or N when none is. ``suffix[k]`` bounds
    the rows ``|n|`` >= k (k = 1..N), ``suffix[N + 1]`` their analytic tail past N."""
    N = suffix.size - 2
    for k in range(N + 1):
        if suffix[k + 1] <= e:
            return k
    return N


@njit(cache=True, nogil=True)
def _rows_3d(E2, E3, SE, ev, grp, mu, Q, Vinv, mnorm, lam, z1, z2, e_part):
    """The rows (n2, n3) of the 3-D channel (half-plane, the origin's first), each with a bound of its whole
    sum, and the bound of what they leave out (outer rows, tails of the row walks). A row's points lie on
    a line in w, w(n_1) = n_1 v + w_0: ``|T_D|`` <= D(d_xy) 2Z along it, d_xy = ``|a_2 nu_2 + a_3 nu_3|`` its closest
    approach to 0 in xy; so the row sums to at most E_2 E_3 D(d_xy) S_1 2Z / ``|L|`` (S_j: sum of E_j). For
    ``|n_3|`` > K_3 the sum over n_2 of E_2 D(``|a_2 nu_2 + a_3 nu_3|``) is at most S_2 D(``|a_3 nu_3|`` / 2)
    + E_2(``|a_3 nu_3|`` / (2 ``|a_2|``)) C_D (one of the two arguments is that large; C_D bounds D's sum along
    n_2 by its integral); for each ``|n_3|`` <= K_3, n_2 is walked from its peaks until the tail is within budget.
    Returns (rows, row_sum, outer, tails, status)."""
    d = 3
    S1E, S2E = SE[0], SE[1]
    head = S1E * 2.0 * z2 / lam
    vx, vy = Vinv[0, 0], Vinv[1, 0]
    vn = math.sqrt(vx * vx + vy * vy)
    ux, uy = vx / vn, vy / vn
    a2 = ux * Vinv[1, 1] - uy * Vinv[0, 1]
    a3 = ux * Vinv[1, 2] - uy * Vinv[0, 2]
    cj = 2.0 * math.pi * C_J1 * math.sqrt(z1)        # D(u) = min(pi S², cj u^-1.5)
    knee = (cj / (math.pi * z1 * z1)) ** (2.0 / 3.0)
    int_d = knee * math.pi * z1 * z1 + 2.0 * cj / math.sqrt(knee)
    cd = math.pi * z1 * z1 + 2.0 * int_d / (abs(a2) * _TWO_PI / Q[1]) if a2 != 0.0 else np.inf
    N3 = E3.size - 1

    def b3(k):
        nu3 = _TWO_PI * k / Q[2]
        b = S2E * math.pi * z1 * z1
        if a2 != 0.0 and a3 != 0.0:
            e2 = _leg_value(1, int(abs(a3) * nu3 / (2.0 * abs(a2)) * Q[1] / _TWO_PI), E2, d, ev, grp, mu, Q, mnorm,
                            lam, z1, z2)
            b = min(b, e2 * cd + _disc_bound(z1, 0.5 * abs(a3) * nu3) * S2E)
        return b

    pe3 = _leg_at(2, N3, d, ev, grp, mu, Q, mnorm, lam, z1, z2)[3]
    suffix = np.empty(N3 + 2)
    suffix[N3 + 1] = 2.0 * E3[N3] * N3 / (pe3 - 1.0) * b3(N3) * head if pe3 > 1.0 else np.inf
    for k in range(N3, 0, -1):
        suffix[k] = suffix[k + 1] + 2.0 * E3[k] * b3(k) * head
    K3 = _first_within(suffix, e_part)
    outer = suffix[K3 + 1]
    status = 1 if outer > e_part else 0
    budget = e_part / (2.0 * (K3 + 1))
    rows = np.zeros((256, 2), np.int64)
    row_sum = np.empty(256)
    row_sum[0] = np.inf                   # the origin's row
    count = 1
    tails = 0.0
    for n3 in range(K3 + 1):
        nu3 = _TWO_PI * n3 / Q[2]
        e3 = E3[n3]
        for side in range(2):
            if n3 == 0 and side == 1:
                break
            s = 1 if side == 0 else -1
            U = 1 if (n3 == 0 or side == 1) else 0
            while True:
                nu2 = _TWO_PI * s * U / Q[1]
                x = a2 * nu2 + a3 * nu3
                e2 = _leg_value(1, U, E2, d, ev, grp, mu, Q, mnorm, lam, z1, z2)
                rb = e2 * e3 * head * _disc_bound(z1, abs(x))
                if count == rows.shape[0]:
                    r2 = np.zeros((2 * count, 2), np.int64)
                    s2 = np.empty(2 * count)
                    r2[:count] = rows
                    s2[:count] = row_sum
                    rows, row_sum = r2, s2
                rows[count, 0], rows[count, 1] = s * U, n3
                row_sum[count] = rb
                count += 1
                if U >= 1 and U % 4 == 0:
                    dropped, power, cmin = _factor_tail(e2, 0.0, U,
                                                        _leg_at(1, U, d, ev, grp, mu, Q, mnorm, lam, z1, z2)[3],
                                                        1.0, 0.0, float(U))
                    slope = a2 * _TWO_PI * s / Q[1]
                    if slope != 0.0:
                        ax = abs(x)
                        dropped, power, cmin = _factor_tail(
                            _disc_bound(z1, ax), U - x / slope, U,
                            1.5 if ax > 0 and cj / (ax * math.sqrt(ax)) <= math.pi * z1 * z1 else 0.0,
                            dropped, power, cmin)
                    tail = np.inf if power <= 1.0 or dropped <= 0.0 else rb / dropped * (U - cmin) / (power - 1.0)
                    if tail <= 0.5 * budget:
                        tails += tail
                        break
                if U > _WALK_CAP or count > _MAX_POINTS[2]:
                    return rows[:count], row_sum[:count], np.inf, np.inf, 3
                U += 1
    return rows[:count], row_sum[:count], outer, 2.0 * tails, status


@njit(cache=True, nogil=True)
def select_points(d, ev, grp, mu, Q, Vinv, mnorm, ab, lam, z1, z2, eps):
    """The lattice points the series keeps (half of the lattice; n -> -n gives the rest) and the bound.

    Returns
    -------
    pts : ndarray (n, 3) int64
        The kept points.
    bound : float
        Outer rows + row tails + dropped points (the series' truncation error is below it).
    lattice_points : int
        Points walked (before dropping).
    status : int
        0; 1 when the bound could not be brought within 0.9 eps; 2 when there is none (a basis leg's
        envelope sums to infinity); 3 when the points needed exceed 2^23 (2^18 for d = 3, whose caller
        then falls back on a bracket).
    """
    empty = np.zeros((0, 3), np.int64)
    g_origin = _root(_tau(d, z1, z2, 0.0) / lam, d)
    eta_lo = arrays_end(d, eps)
    one = np.ones(1)
    zero_tail = np.array([1.0, 0.0])
    gs = [one, one, one]
    Es = [one, one, one]
    PEs = [one, one, one]
    Rs = [zero_tail, zero_tail, zero_tail]
    SEs = np.ones(3)
    for j in range(d):
        g, E, PE, R, SEs[j], ok = leg_envelope(j, d, ev, grp, mu, Q, mnorm, lam, z1, z2, g_origin, eta_lo)
        if not ok:
            return empty, np.inf, 0, 2
        gs[j], Es[j], PEs[j], Rs[j] = g, E, PE, R
    status = 0
    e_outer, e_skip, e_rows, e_drop = 0.2 * eps, 0.15 * eps, 0.15 * eps, 0.4 * eps
    # --- the rows: (n2, n3) pairs of the half-plane, the origin's row first
    rows = np.zeros((1, 2), np.int64)
    row_sum = np.full(1, np.inf)         # a bound of each row's whole sum (the origin's row is never skipped)
    outer = 0.0
    if d == 2:
        S1, S1E = Rs[0][0], SEs[0]
        km = _mixed_scales(grp, mu, ab)
        cm = _mixed_row_sum(ev, grp, km, abs(ab[0]) * _TWO_PI / Q[0])
        g1, g2, E1, E2 = gs[0], gs[1], Es[0], Es[1]
        # a row's whole sum (_rb), two ways: g_1 g_2 G_m (the transform shared) summed along the row, or
        # E_1 E_2 G_m times the transform's bound at the row's closest approach to w = 0 (|nu_2| d_perp)
        v0x, v0y, v1x, v1y = Vinv[0, 0], Vinv[1, 0], Vinv[0, 1], Vinv[1, 1]
        along = (v1x * v0x + v1y * v0y) / (v0x * v0x + v0y * v0y)
        d_perp = math.sqrt((v1x - along * v0x) ** 2 + (v1y - along * v0y) ** 2)
        # rows |n2| > K0 bounded together by _rb_tail (within a few % of their sum); K0 from _K0 up by 1/4
        # while that is above 1/4 of the part (the rows that matter for K2 are then all one by one)
        K0 = _K0
        far = _rb_tail(K0 + 1, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km, ab)
        while far > 0.25 * e_outer and K0 < _N_CAP:
            K0 += K0 // 4
            far = _rb_tail(K0 + 1, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km,
                           ab)
        RB = np.zeros(K0 + 1)
        suffix = np.empty(K0 + 2)
        suffix[K0 + 1] = 2.0 * far
        for k in range(K0, 0, -1):
            RB[k] = _rb(k, S1, S1E, cm, g1, E1, g2, E2, d_perp, d, ev, grp, mu, Q, mnorm, lam, z1, z2, km, ab)[0]
            suffix[k] = suffix[k + 1] + 2.0 * RB[k]
        K2 = _first_within(suffix, e_outer)
        outer = suffix[K2 + 1]
        if outer > e_outer:
            status = 1
        rows = np.zeros((K2 + 1, 2), np.int64)
        row_sum = np.full(K2 + 1, np.inf)
        for k in range(K2 + 1):
            rows[k, 0] = k
            if k > 0:
                row_sum[k] = RB[k]
    elif d == 3:
        if not (SEs[0] < np.inf and SEs[1] < np.inf and SEs[2] < np.inf):
            return empty, np.inf, 0, 2
        rows, row_sum, outer, tails2, st = _rows_3d(Es[1], Es[2], SEs, ev, grp, mu, Q, Vinv, mnorm, lam, z1, z2,
                                                    0.5 * e_outer)
        outer += tails2
        status = max(status, st)
    # --- skip the rows of smallest whole sums while they add up to at most e_skip; walk the others
    order = np.argsort(row_sum)
    skipped = 0.0
    walk = np.ones(rows.shape[0], np.bool_)
    for k in order:
        if skipped + 2.0 * row_sum[k] > e_skip:
            break
        skipped += 2.0 * row_sum[k]
        walk[k] = False
    n_rows = max(1, int(walk.sum()))
    budget = e_rows / (2.0 * n_rows)
    pts = np.empty((4096, 3), np.int64)
    F = np.empty(4096)
    count = 0
    tails = 0.0
    mix = np.flatnonzero((grp == MIXED_LEG) | (grp == -1))
    rowc = np.empty((mix.size, 2))
    inv1 = np.empty(mix.size, np.bool_)
    for k in range(mix.size):
        inv1[k] = _only_inverse(ev[mix[k]])
    NU1 = np.empty(Es[0].size)
    for u in range(NU1.size):
        NU1[u] = _TWO_PI * u / Q[0]
    for k in range(rows.shape[0]):
        if count > _MAX_POINTS[d - 1]:
            return empty, np.inf, count, 3
        if not walk[k]:
            continue
        n2, n3 = rows[k, 0], rows[k, 1]
        e2 = _leg_value(1, abs(n2), Es[1], d, ev, grp, mu, Q, mnorm, lam, z1, z2)
        e3 = _leg_value(2, abs(n3), Es[2], d, ev, grp, mu, Q, mnorm, lam, z1, z2)
        count, t, pts, F, ok = _walk_row(d, n2, n3, k == 0, budget, Es[0], PEs[0], NU1, e2, e3, mix, ev, grp, mu,
                                         Q, Vinv, mnorm, lam, z1, z2, rowc, inv1, pts, F, count)
        tails += 2.0 * t
        if not ok:
            status = max(status, 1)
    # --- drop the smallest points while their sum stays within e_drop (log2 bins, filled here in the walk's
    # order: the same sums as filled point by point during the walk, whose latency they lengthened)
    bins = np.zeros(_BINS)
    for i in range(count):
        if F[i] > 0.0:
            bins[_bin(F[i])] += 2.0 * F[i]
    cut = 0
    acc = 0.0
    for k in range(_BINS):
        if acc + bins[k] > e_drop:
            break
        acc += bins[k]
        cut = k + 1
    threshold = 2.0 ** (cut - 1300)
    kept = 0
    dropped = 0.0
    for i in range(count):
        if F[i] >= threshold:
            pts[kept, 0], pts[kept, 1], pts[kept, 2] = pts[i, 0], pts[i, 1], pts[i, 2]
            kept += 1
        else:
            dropped += 2.0 * F[i]
    bound = outer + skipped + tails + dropped
    if status == 0 and bound > 0.9 * eps:
        status = 1
    return pts[:kept].copy(), bound, count, status
