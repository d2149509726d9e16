"""The Fourier series of a bounded stack-up and its certified truncation (compiled, one pose at a time).

Let Y (dimension d = 1, 2 or 3) be a channel of the pose error: dphi, (dx, dy)
or (dx, dy, dphi), ``Y = s + sum_t c_t X_t`` with independent X_t of bounded
support, and D the region whose probability is wanted: ``|dphi|`` <= z, a disc
``|(dx, dy)|`` <= z, or the cylinder of both. Periodising Y over a lattice L
whose shifts move Y's support off D (no aliasing) leaves the probability of
D unchanged, and the periodised density is a Fourier series whose
coefficients are Y's characteristic function on the dual lattice:

    P(Y in D) = (1 / ``|L|``) sum_{w in L*} phi_Y(w) T_D(w),

with T_D the Fourier transform of D's indicator (real and even):
2 sin(w z) / w, 2 pi z J1(z ``|w|``) / ``|w|``, and their product for the cylinder.
``phi_Y(w) = exp(i w.s) prod_t phi_t(c_t . w)`` (:mod:`.characteristic`).

**The lattice.** Every term of leg i acts along one direction m_i (the
channel's rows of column i of A^-1), so the legs' sums are independent
scalars. The dual lattice is taken rectangular in nu_j = m_j . w over a basis
of d legs (the 1-D channel has the single direction 1): nu_j = 2 pi n_j / Q_j,
so the characteristic function of a basis leg depends on n_j alone (computed
once per n_j) and the lattice's y-space shifts are Q_j m_j. The periods Q_j
are the smallest for which the support, shifted by any lattice vector, misses
D (their bounding boxes in the coordinates w of y = sum_j w_j m_j).

**The certified truncation.** Each term's ``|phi_t|`` is below a non-increasing
envelope (:func:`~.characteristic.envelope`), and ``|T_D(w)|`` below a bound
that falls with ``|w|`` (for every z up to the largest used, so one lattice
serves every quantile). :func:`~.truncation.select_points` walks the lattice
row by row with these envelopes and keeps the points that matter; what it
leaves out (rows left out or skipped whole, the tails of the rows walked,
the points dropped) is bounded from the envelopes. With floating point (an
assumed accuracy of each characteristic-function value,
:data:`~._special.CF_ACCURACY`) and the mass of normal laws beyond their cut
(mean ± k sd, which alone may alias) the parts make the reported bound.

**The sum** (:func:`_coefficients`). The basis legs' characteristic functions,
each times its share ``exp(i snu_j nu_j)`` of the known shift's phase, are
tabulated once per pose along their axes; at each kept point the series
multiplies their values (conjugated for n_j < 0) by the off-basis terms' (the
mixed leg, thermal) and the transform of D. An off-basis uniform's sine is
carried along a row by rotation (its argument is affine in n_1), restarted
every :data:`_RESTART` steps: within 2e-15 of the sine, inside
:data:`~._special.CF_ACCURACY`. The transform (a J1 in the plane: most of a
point's cost) is then taken only where it matters (:func:`_sum`): the points
whose terms are bounded (``|Re phi_Y|`` times the transform's bound) by a
total of at most :data:`_LEAVE_SHARE` of the target, within what the rest of
the bound leaves of it, are left out, and that total joins the bound.

Quantiles (d = 1, 2) solve ``P(z) = p`` by Newton's method with bisection
as a safeguard on the same series, and bracket the true quantile by solving
``P(z) = p -/+ bound``: the true quantile lies between (the true P is within
the bound of the series' and non-decreasing).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._special import CF_ACCURACY, TABLE_END
from .lattice import MIXED_LEG
from .characteristic import C_UNIFORM, NORMAL, UNIFORM, common_cf, gauss, int_j0_over, int_j0_over_near, sinc, term_cf
from .truncation import exponent_field, select_points, transform_bound

__all__ = ["pose_series", "STATUS"]

#: Status of a pose's series: ok; the bound is above the target; no bound (a basis leg's envelope does
#: not decay faster than 1/n: no density to speak of); too many terms (more than 2^23 lattice points).
STATUS = ("ok", "bound above target", "no bound", "too many terms")
_TWO_PI = 2.0 * math.pi
_RESTART = 16             # rotation steps at most between direct sines in the sum (see pose_series)
_LEAVE_SHARE = 0.05       # of the target: what the sum may leave out (see _sum), within what the bound leaves
_SUB_BITS = 6             # the mantissa's bits that split the sum's first bin not left out whole (see _sum)


# ------------------------------------------------------------------ the transform of D

@njit(cache=True, nogil=True)
def _transform(d, z1, z2, a, b, j1):
    """T_D at a point (a, b as in :func:`~.truncation.transform_bound`)."""
    if d == 1:
        return 2.0 * z1 if a == 0.0 else 2.0 * math.sin(a * z1) / a
    disc = math.pi * z1 * z1 if a == 0.0 else 2.0 * math.pi * z1 * j1(z1 * a, 0) / a
    if d == 2:
        return disc
    return disc * (2.0 * z2 if b == 0.0 else 2.0 * math.sin(b * z2) / b)


# ------------------------------------------------------------------ the series at one pose

@njit(cache=True, nogil=True)
def _prob(d, lam, re, a, b, n, z1, z2, j1):
    """The series' P(Y in D) at z1 (and z2 for the cylinder)."""
    s = 0.0
    for k in range(n):
        s += re[k] * _transform(d, z1, z2, a[k], b[k], j1)
    return (_transform(d, z1, z2, 0.0, 0.0, j1) + 2.0 * s) / lam


@njit(cache=True, nogil=True)
def _density(d, lam, re, a, n, z, j0):
    """d/dz of the series' P(``|Y|`` <= z), d = 1 or 2."""
    s = 0.0
    if d == 1:
        for k in range(n):
            s += re[k] * 2.0 * math.cos(a[k] * z)
        return (2.0 + 2.0 * s) / lam
    for k in range(n):
        s += re[k] * j0(z * a[k], 0)
    return 2.0 * math.pi * z * (1.0 + 2.0 * s) / lam


@njit(cache=True, nogil=True)
def _solve(d, lam, re, a, b, n, target, z0, zmax, sp):
    """z in [0, zmax] with the series' P(z) = target: Newton's method, bisection where it strays."""
    lo, hi = 0.0, zmax
    z = min(max(z0, 1e-3 * zmax), 0.999 * zmax)
    for _ in range(100):
        f = _prob(d, lam, re, a, b, n, z, 0.0, sp[1]) - target
        if f < 0:
            lo = z
        else:
            hi = z
        if hi - lo <= 1e-13 * zmax:
            break
        dens = _density(d, lam, re, a, n, z, sp[0])
        step = z - f / dens if dens > 0 else -1.0
        if not (lo < step < hi):
            step = 0.5 * (lo + hi)
        if abs(step - z) <= 1e-14 * zmax:
            z = step
            break
        z = step
    return z


@njit(cache=True, nogil=True)
def _beyond(d, lam, re, a, b, n, target, z, zmax, side, sp):
    """A z' on ``side`` (-1: below, +1: above) of z where the series' P is <= target (below) or >= target
    (above): the root of P = target, then steps of doubling length until the inequality holds; 0 or
    zmax (where the true P is 0 or 1) when the target is out of (0, 1)."""
    if side < 0 and target <= 0.0:
        return 0.0
    if side > 0 and target >= 1.0:
        return zmax
    zt = _solve(d, lam, re, a, b, n, target, z, zmax, sp)
    step = 1e-12 * zmax
    for _ in range(200):
        p = _prob(d, lam, re, a, b, n, zt, 0.0, sp[1])
        if (side < 0 and p <= target) or (side > 0 and p >= target):
            return zt
        zt = min(max(zt + side * step, 0.0), zmax)
        if zt == 0.0 or zt == zmax:
            return zt
        step *= 2.0
    return 0.0 if side < 0 else zmax


@njit(cache=True, nogil=True)
def _coefficients(d, kind, par, tab, sp, grp, mu, snu, Q, Vinv, pts, z1, z2, restart):
    """The series' coefficients at the kept points ``pts`` (n, 3), and the bounds of their terms.

    Each basis leg's characteristic function, times its share ``exp(i snu_j nu_j)`` of the known shift's
    phase, is tabulated up to its extent among the points (n_j < 0: the conjugate). The off-basis terms
    (mixed leg, thermal) are taken point by point: a uniform or normal law's centre m_t is a known shift
    too, ``exp(i m_t mu_t . nu)``, separable in nu, so it joins the basis legs' phases and the term keeps its
    centred part, real: a normal law's Gaussian, a uniform's sin(u) / u. Along a row (n_1, the first basis
    leg's index, steps by one from a point to the next) u is affine in n_1, so (cos u, sin u) turns by the
    term's step from point to point (a rotation: four products, no sine); it is taken afresh at a row's
    start, after a gap, every ``restart`` steps (the rotation's rounding grows by a few ulps a step: after
    16 steps it is within 1.6e-15 of the exact sine, less than rounding the argument costs a direct sine at
    ``|u|`` ~ 100, and far inside :data:`~._special.CF_ACCURACY`) and where ``|u|`` < 1 (sin(u) / u would
    magnify its error there). ``restart`` = 0: sin(u) afresh at every point (the same to the bit as
    without the rotation).

    Returns
    -------
    re, ta, tb : ndarray (n,)
        Re phi_Y at each point, and the arguments a, b of T_D there (:func:`_transform`).
    cb : ndarray (n,)
        ``|re|`` times the transform's bound at each point (:func:`~.truncation.transform_bound`): the
        bound of the point's term (for every z up to z1) that :func:`_sum` leaves out by.
    tb_sum : float
        ``T_D(0) + 2 sum`` of the transform's bound over the points.
    """
    T = kind.size
    buf = np.empty(2)
    n = pts.shape[0]
    mix = np.flatnonzero((grp == -1) | (grp == MIXED_LEG))
    nm = mix.size
    shift = snu.copy()
    for q in range(nm):
        t = mix[q]
        if kind[t] == UNIFORM or kind[t] == NORMAL:
            shift += par[t, 0] * mu[t]
    e0 = e1 = e2 = 0                                # the extents, in scalars (no store a point)
    for k in range(n):
        e0 = max(e0, abs(pts[k, 0]))
        e1 = max(e1, abs(pts[k, 1]))
        e2 = max(e2, abs(pts[k, 2]))
    ext = np.array([e0, e1, e2])
    Phi = np.ones((3, ext.max() + 1), np.complex128)
    for j in range(d):
        for m in range(1, ext[j] + 1):
            nu_j = _TWO_PI * m / Q[j]
            c = complex(math.cos(shift[j] * nu_j), math.sin(shift[j] * nu_j))
            for t in range(T):
                if grp[t] == j:
                    x = mu[t, j] * nu_j
                    ct = common_cf(kind[t], par[t, 0], par[t, 1], x, sp, buf)
                    c *= ct if ct.real == ct.real else term_cf(kind[t], par, t, tab, sp, buf, x)
            Phi[j, m] = c
    # how each off-basis term is taken: 0 a centred uniform (by rotation), 1 a centred normal, 2 a clearance
    # uniform on [0, hi], 3 any other (term_cf); the uniforms' (cos, sin) of their step along n_0
    how = np.full(nm, 3, np.int64)
    rot_c, rot_s = np.ones(nm), np.zeros(nm)
    cos_u, sin_u = np.zeros(nm), np.zeros(nm)
    for q in range(nm):
        t = mix[q]
        if kind[t] == UNIFORM:
            how[q] = 0
            step = mu[t, 0] * (_TWO_PI / Q[0]) * par[t, 1]
            rot_c[q], rot_s[q] = math.cos(step), math.sin(step)
        elif kind[t] == NORMAL:
            how[q] = 1
        elif kind[t] == C_UNIFORM and par[t, 0] == 0.0:
            how[q] = 2
    table = sp[3]                                   # held here: int_j0_over_near inlines without reference counts
    re = np.empty(n)
    ta = np.empty(n)
    tb = np.empty(n)
    cb = np.empty(n)
    tb_sum = transform_bound(d, z1, z2, 0.0, 0.0)
    steps = restart
    for k in range(n):
        n0, n1, n2 = pts[k, 0], pts[k, 1], pts[k, 2]
        side = n0 - pts[k - 1, 0] if k > 0 and n1 == pts[k - 1, 1] and n2 == pts[k - 1, 2] else 0
        rotate = (side == 1 or side == -1) and steps < restart
        steps = steps + 1 if rotate else 0
        nu0 = _TWO_PI * n0 / Q[0]
        nu1 = _TWO_PI * n1 / Q[1]
        nu2 = _TWO_PI * n2 / Q[2] if d == 3 else 0.0
        phi = Phi[0, n0] if n0 >= 0 else np.conj(Phi[0, -n0])
        if d >= 2:                                  # the axes past d hold 1
            phi *= Phi[1, n1] if n1 >= 0 else np.conj(Phi[1, -n1])
        if d == 3:
            phi *= Phi[2, n2] if n2 >= 0 else np.conj(Phi[2, -n2])
        pr, pi = phi.real, phi.imag
        for q in range(nm):
            t = mix[q]
            x = mu[t, 0] * nu0 + mu[t, 1] * nu1 + mu[t, 2] * nu2
            h = how[q]
            if h == 0:
                u = x * par[t, 1]
                if rotate:
                    rs = side * rot_s[q]
                    cos_u[q], sin_u[q] = cos_u[q] * rot_c[q] - sin_u[q] * rs, sin_u[q] * rot_c[q] + cos_u[q] * rs
                else:
                    cos_u[q], sin_u[q] = math.cos(u), math.sin(u)
                v = sin_u[q] / u if abs(u) >= 1.0 else sinc(u)
            elif h == 1:
                v = gauss(par[t, 1], x)
            elif h == 2:
                y = abs(x) * par[t, 1]
                v = int_j0_over_near(table, y) if y < TABLE_END else int_j0_over(sp, buf, y)
            else:
                c = term_cf(kind[t], par, t, tab, sp, buf, x)
                pr, pi = pr * c.real - pi * c.imag, pr * c.imag + pi * c.real
                continue
            pr *= v
            pi *= v
        wx = Vinv[0, 0] * nu0 + Vinv[0, 1] * nu1 + Vinv[0, 2] * nu2
        wy = Vinv[1, 0] * nu0 + Vinv[1, 1] * nu1 + Vinv[1, 2] * nu2
        wz = Vinv[2, 0] * nu0 + Vinv[2, 1] * nu1 + Vinv[2, 2] * nu2
        if d == 1:
            pa, pb = abs(nu0), 0.0
        elif d == 2:
            pa, pb = math.sqrt(wx * wx + wy * wy), 0.0
        else:
            pa, pb = math.sqrt(wx * wx + wy * wy), abs(wz)
        re[k] = pr
        ta[k] = pa
        tb[k] = pb
        bt = transform_bound(d, z1, z2, pa, pb)
        tb_sum += 2.0 * bt
        cb[k] = abs(pr) * bt
    return re, ta, tb, cb, tb_sum


@njit(cache=True, nogil=True)
def _sum(d, lam, re, ta, tb, cb, zs, z2, j1, room):
    """The series' ``sum re T_D(a, b)`` at zs (and z2) over the points but those it leaves out, which
    :func:`_coefficients`' bounds ``cb`` say add at most ``room`` to P (for every z up to z1: the quantiles).

    A point left out changes P by ``2 re T_D / |L|``, at most ``2 cb / |L|`` in modulus (``cb = |re|`` times
    the transform's bound; the error of re itself is in the floating-point part of the bound, for every
    point). The points are binned by the leading bits of cb (its binary exponent, then of the first bin
    not left out whole, the next :data:`_SUB_BITS` bits of its mantissa: bins a factor 2^(1/64) wide, in
    the order of cb); the whole bins from the smallest up whose total fits the room are left out, and of
    the next bin the points whose total still fits what the whole bins leave of it, in their order. The
    bound returned is the total of what was left out (summed in order: within n u < 1e-9 of the bins'
    totals, n <= 2^23 points), times 1 + 1e-8 (the rounding of the total and of each cb), and the budget
    is the room's share over 1 + 2e-8, so the bound stays below ``room``. ``room`` <= 0: every point
    summed, in order (the same to the bit as summing them all).

    Returns
    -------
    s : float
        ``sum re T_D(a, b)`` over the points kept, in their order.
    left : float
        Bound of what the points left out add to P (0 with ``room`` <= 0).
    n : int
        Points kept; ``re``, ``ta``, ``tb`` are compacted to them (the quantiles sum these).
    """
    n = re.size
    bits = cb.view(np.int64)                          # cb >= 0: its bits rise with it (the masks: -0.0 as 0)
    top = (1 << (11 + _SUB_BITS)) - 1
    budget = 0.5 * lam * room / (1.0 + 2e-8)
    key_lim = -1                                      # the bin left out in part: points below it left out whole
    rest = 0.0                                        # what the whole bins leave of the budget
    if budget > 0.0:
        hist = np.zeros(2048)
        for k in range(n):
            hist[exponent_field(cb[k])] += cb[k]
        acc = 0.0
        e = 0
        while e < 2047 and acc + hist[e] <= budget:
            acc += hist[e]
            e += 1
        sub = np.zeros(1 << _SUB_BITS)
        for k in range(n):
            key = (bits[k] >> (52 - _SUB_BITS)) & top
            if key >> _SUB_BITS == e:
                sub[key & ((1 << _SUB_BITS) - 1)] += cb[k]
        f = 0
        while f < (1 << _SUB_BITS) and acc + sub[f] <= budget:
            acc += sub[f]
            f += 1
        key_lim = (e << _SUB_BITS) + f
        rest = budget - acc
    out = 0.0
    part = 0.0
    kept = np.empty(n, np.int64)
    w = 0
    for k in range(n):                                # without branches (then the sum's J1 calls overlap)
        c = cb[k]
        key = (bits[k] >> (52 - _SUB_BITS)) & top
        some = (key == key_lim) & (part + c <= rest)
        drop = (key < key_lim) | some
        part += c if some else 0.0
        out += c if drop else 0.0
        kept[w] = k
        w += 0 if drop else 1
    s = 0.0
    for i in range(w):
        k = kept[i]
        s += re[k] * _transform(d, zs, z2, ta[k], tb[k], j1)
        re[i] = re[k]
        ta[i] = ta[k]
        tb[i] = tb[k]
    return s, 2.0 * out / lam * (1.0 + 1e-8), w


@njit(cache=True, nogil=True)
def pose_series(d, kind, par, ev, tab, sp, grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, eps, alias, levels, z0,
                zmax, out_q, out_qerr):
    """The probability of D (radius zs; the cylinder's half-height z2) and the quantiles at one pose.

    Parameters
    ----------
    d : int
        The channel's dimension (1: ``|dphi|``, 2: position, 3: both).
    kind, par, tab, sp
        The term table (:class:`~.characteristic.TermTable`), its arrays and the special functions.
    grp : (T,) int
        Basis leg 0..d-1 of each term, -1 for a term off the basis (mixed), -2 for a term absent
        from the channel.
    mu : (T, 3)
        Each term's coefficients in nu (c_t . w = mu_t . nu); columns d.. are 0.
    snu : (3,)
        The known shift in nu (phase exp(i snu . nu)).
    Q, mnorm : (3,)
        Periods and ``|m_j|`` (1 past d).
    Vinv : (3, 3)
        w = Vinv nu (the channel's frequency from nu; zero past d).
    lam : float
        The lattice's cell volume ``|L|``.
    z1, z2 : float
        The largest radius (or half-width) of D the series serves (the periods and bounds hold
        up to it), and the cylinder's half-height.
    zs : float
        The radius (or half-width) of D at which the probability is wanted (<= z1).
    eps : float
        Target of the error bound (absolute, in probability).
    alias : float
        Mass of the normal laws beyond their cut (added to the bound).
    levels : (K,)
        Probabilities of the quantiles (d <= 2; empty for none); ``z0`` (K,) their starting guesses,
        ``zmax`` the largest value of ``|Y|`` (a quantile lies below).
    out_q, out_qerr : (K,)
        Written: the quantiles and bounds of their errors.

    Returns
    -------
    p_in : float
        The series' P(Y in D) at zs (and z2).
    bound : float
        Bound of its absolute error.
    n_terms : int
        Lattice points summed (half of them: the others are their conjugates).
    status : int
        Index into :data:`STATUS`.
    """
    pts, b_trunc, walked, status = select_points(d, ev, grp, mu, Q, Vinv, mnorm, ab, lam, z1, z2, eps)
    if status >= 2:
        out_q[:] = np.nan
        out_qerr[:] = np.nan
        return np.nan, np.inf, walked, status
    re, ta, tb, cb, tb_sum = _coefficients(d, kind, par, tab, sp, grp, mu, snu, Q, Vinv, pts, z1, z2, _RESTART)
    fp = CF_ACCURACY * tb_sum / lam + 1e-15
    room = min(_LEAVE_SHARE * eps, (1.0 - 1e-6) * (eps - b_trunc - fp - alias))
    s, left, n = _sum(d, lam, re, ta, tb, cb, zs, z2, sp[1], room)
    bound = b_trunc + fp + alias + left
    p_in = (_transform(d, zs, z2, 0.0, 0.0, sp[1]) + 2.0 * s) / lam         # = _prob(d, lam, re, ta, tb, n, zs, ...)
    # --- quantiles (d <= 2): the series' root, and where the series is below p - bound and above p + bound
    for q in range(levels.size):
        z = _solve(d, lam, re, ta, tb, n, levels[q], z0[q], zmax, sp)
        zl = _beyond(d, lam, re, ta, tb, n, levels[q] - bound, z, zmax, -1.0, sp)
        zh = _beyond(d, lam, re, ta, tb, n, levels[q] + bound, z, zmax, 1.0, sp)
        out_q[q] = z
        out_qerr[q] = max(z - zl, zh - z)
    if status == 0 and bound > eps:
        status = 1
    return p_in, bound, walked, status


@njit(cache=True, nogil=True)
def batch_series(start, stop, d, kind, par, ev, tab, sp, grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, eps, alias,
                 levels, z0, zmax, ok, out_p, out_b, out_n, out_s, out_q, out_qerr):
    """:func:`pose_series` at poses ``start`` to ``stop`` of a batch (per-pose arrays indexed first); a pose
    that is not ``ok`` (no basis of legs with a density) gets status 2 and NaN."""
    for i in range(start, stop):
        if not ok[i]:
            out_p[i], out_b[i], out_n[i], out_s[i] = np.nan, np.inf, 0, 2
            out_q[i, :] = np.nan
            out_qerr[i, :] = np.nan
            continue
        out_p[i], out_b[i], out_n[i], out_s[i] = pose_series(
            d, kind, par, ev, tab, sp, grp[i], mu[i], snu[i], Q[i], Vinv[i], mnorm[i], ab[i], lam[i], z1[i], z2[i], zs[i],
            eps, alias[i], levels, z0[i], zmax[i], out_q[i], out_qerr[i])
