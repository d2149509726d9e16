"""Characteristic functions of the terms of the linear stack-up, and decreasing bounds of their moduli.

A term's scalar X_t (:class:`~prp3mc.model.linear.TermLaw`) enters the
pose error as ``columns[..., t] X_t``; its characteristic function
``phi_t(x) = E exp(i x X_t)`` (x in 1/mm, 1/deg or 1/K, as X_t's unit)
is evaluated by :func:`term_cf` in closed form where there is one:

========================= ===================================================================
law of X_t                phi_t(x)
========================= ===================================================================
uniform [m - h, m + h]    exp(i x m) sin(x h) / (x h)
normal (mu, sd)           exp(i x mu - sd² x² / 2)
triangular (a, c, b)      2/(b - a) [(c - a) e^{iax} h(ix(c - a)) + (b - c) e^{ibx} h(-ix(b - c))],
                          h(z) = (e^z (z - 1) + 1) / z² (a series near 0)
truncated normal          Gauss-Legendre on the support, its size from the Bernstein-ellipse bound
                          (Trefethen, ATAP, thm 19.3) so the rule's error is below 1e-16
discrete (classes)        sum_k w_k exp(i x v_k)
clearance, rho uniform    (I(x hi) - I(x lo)) / (x (hi - lo)), I(y) = int_0^y J0 (a 16-point rule
  [lo, hi]                on J0 when x (hi - lo) <= 4: no cancellation)
clearance, rho disc (r)   2 J1(x r) / (x r)
clearance, rho discrete   sum_k w_k J0(x v_k)
clearance, rho triangular sum over the two linear pieces (alpha + beta rho) of
                          alpha (I(x q) - I(x p)) / x + beta (q J1(x q) - p J1(x p)) / x
clearance, rho truncnorm  Gauss-Legendre on J0 (as the truncated normal)
========================= ===================================================================

A clearance term is ``rho cos(zeta - omega)`` with the contact angle zeta
uniform over whole turns, so that ``E exp(i x rho cos(zeta - omega)) =
E J0(x rho)`` whatever omega; other contact-angle laws are refused.

Every term also has an *envelope* (:func:`envelope`, its coefficients in
:attr:`TermTable.env`): a non-increasing function of ``|x|`` bounding ``|phi_t(x)|``,
from the total variation of the density (``|phi|`` <= V(f) / ``|x|``, and V(f') / x²
when f is continuous; for a clearance, integrating J0 by parts), from
``|J0(y)| <= min(1, sqrt(2 / (pi y)))``, ``|int_0^y J0| <= I_MAX`` and
``sqrt(u) |J1(u)| <= C_J1`` (:mod:`._special`); and a *power*
(:func:`envelope_power`, with the envelope's value): p such that ``env(x) <= env(x0) (x0 / x)^p`` for all
x >= x0, which bounds the truncation tails analytically (:mod:`.truncation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from numba import njit

from ..errors import BudgetError
from ..model.laws import Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from ._special import C_J1, I_MAX, TABLE_END, gauss_legendre_tables, int_j0, int_j0_table

__all__ = ["TermTable", "term_table", "term_cf", "common_cf", "int_j0_over", "int_j0_over_near", "sinc", "gauss",
           "envelope", "envelope_power", "KINDS", "NPAR"]

#: Kind codes of :class:`TermTable` (-1: a constant, folded into the known shift).
KINDS = ("uniform", "normal", "truncnormal", "triangular", "discrete",
         "clearance_uniform", "clearance_disc", "clearance_discrete", "clearance_triangular",
         "clearance_truncnormal")
(UNIFORM, NORMAL, TRUNCNORMAL, TRIANGULAR, DISCRETE,
 C_UNIFORM, C_DISC, C_DISCRETE, C_TRIANGULAR, C_TRUNCNORMAL) = range(len(KINDS))
NPAR = 8
#: Asymptotic decay power of each kind's envelope (normal: faster than any power).
_POWER = {UNIFORM: 1.0, NORMAL: math.inf, TRUNCNORMAL: 1.0, TRIANGULAR: 2.0, DISCRETE: 0.0, C_UNIFORM: 1.0,
          C_DISC: 1.5, C_DISCRETE: 0.5, C_TRIANGULAR: 1.0, C_TRUNCNORMAL: 1.0}
_TURN = 360.0


@dataclass(frozen=True)
class TermTable:
    """The terms of a linear model as the kernels take them (pose-independent).

    Attributes
    ----------
    kind : ndarray (T,) int64
        Index into :data:`KINDS`, or -1 for a constant term (a known shift, or a law of zero width).
    par : ndarray (T, NPAR)
        Each kind's parameters (see :func:`term_table`).
    atoms, weights : ndarray (A,)
        Values and probabilities of the discrete laws, one after the other (``par[t, :2]``:
        offset and count).
    constant : ndarray (T,)
        X_t of a constant term, 0 for the others.
    lo, hi : ndarray (T,)
        Support of X_t; a normal law's is cut at mean ± ``k_normal`` sd (the mass beyond
        is bounded separately).
    mean, var : ndarray (T,)
        Mean and variance of X_t.
    normal : ndarray (T,) bool
        Terms with a normal law (unbounded).
    env : ndarray (T, 8)
        The coefficients of each term's envelope (:func:`envelope`): a1, a2, a15, w0, bh, f2, w, sd.
    power : ndarray (T,)
        Asymptotic decay power of the term's envelope (inf for a normal law, 0 for a discrete one).
    """

    kind: np.ndarray
    par: np.ndarray
    atoms: np.ndarray
    weights: np.ndarray
    constant: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    mean: np.ndarray
    var: np.ndarray
    normal: np.ndarray
    env: np.ndarray
    power: np.ndarray

    @property
    def random(self) -> np.ndarray:
        """Terms with a random X_t, (T,) bool."""
        return self.kind >= 0

    def arrays(self) -> tuple:
        """``(atoms, weights, gl_sizes, gl_offsets, gl_nodes, gl_weights)``: the ``tab`` argument of the kernels."""
        return (self.atoms, self.weights, *gauss_legendre_tables())


def _full_turns(law) -> bool:
    if not isinstance(law, Uniform):
        return False
    turns = (law.hi - law.lo) / _TURN
    return turns >= 1 - 1e-12 and abs(turns - round(turns)) <= 1e-9 * turns


def _truncnormal_par(law: TruncNormal) -> list[float]:
    """center, half-width L, beta, normaliser N0 = int_{-1}^{1} exp(-beta² s²/2) ds, and the envelope's
    V = 2 f_max, 2 f(edge), W = 2 ``|f'(edge)|`` + TV(f') (densities in the law's unit)."""
    beta = 3.0 * law.cpk
    L = law.tol
    n0 = math.sqrt(2 * math.pi) / beta * math.erf(beta / math.sqrt(2))
    fmax = 1.0 / (L * n0)
    fe = fmax * math.exp(-0.5 * beta * beta)
    dfe = beta * beta / L * fe                              # |f'| at the edges
    dfmax = beta / L * fmax * math.exp(-0.5) if beta > 1 else dfe
    tv = 4 * dfmax - 2 * dfe if beta > 1 else 2 * dfe
    return [law.center, L, beta, n0, 2 * fmax, 2 * fe, 2 * dfe + tv]


def _triangle_tv(lo: float, mode: float, hi: float, at_zero_free: bool) -> float:
    """Total variation of a triangular density with its jumps at the ends; the jump at 0 is free
    when ``at_zero_free`` (an integral of J0 from 0 vanishes there)."""
    peak = 2.0 / (hi - lo)
    jump_lo = peak if mode == lo and not (at_zero_free and lo == 0.0) else 0.0
    jump_hi = peak if mode == hi else 0.0
    inner = (peak if mode > lo else 0.0) + (peak if mode < hi else 0.0)
    return jump_lo + jump_hi + inner


def term_table(term_laws, k_normal: float) -> TermTable:
    """Build the :class:`TermTable` of a model's :attr:`~prp3mc.model.linear.LinearModel.term_laws`.

    Parameters per kind (``par[t]``): uniform ``mid, hw``; normal ``mu, sd``;
    truncnormal ``center, L, beta, N0, V, 2f_e, W``; triangular ``a, c, b, V, V2``
    (V2 < 0 when the density jumps); discrete ``offset, count``; clearance uniform
    ``lo, hi, A``; disc ``r, A``; clearance discrete ``offset, count``; clearance
    triangular ``a, c, b, A``; clearance truncnormal as truncnormal with ``A`` last.
    A clearance's A bounds its envelope as ``min(1, A / |x|^p)``.
    """
    T = len(term_laws)
    kind = np.full(T, -1, dtype=np.int64)
    par = np.zeros((T, NPAR))
    constant, lo, hi, mean, var = (np.zeros(T) for _ in range(5))
    normal = np.zeros(T, dtype=bool)
    atoms, weights = [], []

    def add_atoms(t, values, probs):
        par[t, 0], par[t, 1] = len(atoms), len(values)
        atoms.extend(values)
        weights.extend(probs)

    for t, tl in enumerate(term_laws):
        law, ref = tl.law, tl.reference
        if tl.kind == "shift":
            constant[t] = lo[t] = hi[t] = mean[t] = tl.value
            continue
        if tl.kind == "clearance":
            if not _full_turns(tl.zeta):
                raise BudgetError(f"exact yield: the contact angle of {tl.name} is {tl.zeta}, not uniform over "
                                  "whole turns; the exact distribution needs it so (use Monte Carlo)")
            rmax = law.support[1]
            lo[t], hi[t] = -rmax, rmax
            var[t] = 0.5 * (law.var + law.mean**2)
            if isinstance(law, Uniform) and law.hi > law.lo:
                kind[t] = C_UNIFORM
                tv = (1.0 if law.lo > 0 else 0.0) / (law.hi - law.lo) + 1.0 / (law.hi - law.lo)
                par[t, :3] = law.lo, law.hi, I_MAX * tv
            elif isinstance(law, Disc) and law.radius > 0:
                kind[t] = C_DISC
                par[t, :2] = law.radius, 2 * C_J1 * law.radius**-1.5
            elif isinstance(law, Triangular):
                kind[t] = C_TRIANGULAR
                par[t, :4] = law.lo, law.mode, law.hi, I_MAX * _triangle_tv(law.lo, law.mode, law.hi, True)
            elif isinstance(law, TruncNormal):
                kind[t] = C_TRUNCNORMAL
                p = _truncnormal_par(law)
                fmax, fe = p[4] / 2, p[5] / 2
                tv = fe * ((1.0 if law.center - law.tol > 0 else 0.0) + 1.0) + 2 * (fmax - fe)
                par[t, :5] = *p[:4], I_MAX * tv
            else:                                                # a point or classes: sum of J0
                values, probs = ((law.values, law.weights) if isinstance(law, Discrete)
                                 else ((law.mean,), (1.0,)))
                if max(values) == 0.0:
                    continue                                     # rho = 0: no clearance at all
                kind[t] = C_DISCRETE
                add_atoms(t, values, probs)
            continue
        m, v = law.mean - ref, law.var
        mean[t], var[t] = m, v
        if law.support[0] == law.support[1]:                     # zero width: a known value
            constant[t] = lo[t] = hi[t] = law.support[0] - ref
            kind[t] = -1
            continue
        if isinstance(law, Uniform):
            kind[t] = UNIFORM
            par[t, :2] = 0.5 * (law.lo + law.hi) - ref, 0.5 * (law.hi - law.lo)
            lo[t], hi[t] = law.lo - ref, law.hi - ref
        elif isinstance(law, Normal):
            kind[t] = NORMAL
            normal[t] = True
            par[t, :2] = law.mu - ref, law.sd
            lo[t], hi[t] = law.mu - ref - k_normal * law.sd, law.mu - ref + k_normal * law.sd
        elif isinstance(law, TruncNormal):
            kind[t] = TRUNCNORMAL
            p = _truncnormal_par(law)
            p[0] -= ref
            par[t, :7] = p
            lo[t], hi[t] = law.center - law.tol - ref, law.center + law.tol - ref
        elif isinstance(law, Triangular):
            kind[t] = TRIANGULAR
            a, c, b = law.lo - ref, law.mode - ref, law.hi - ref
            s1 = 2.0 / ((b - a) * (c - a)) if c > a else 0.0
            s2 = 2.0 / ((b - a) * (b - c)) if b > c else 0.0
            v2 = 2.0 * (s1 + s2) if a < c < b else -1.0
            par[t, :5] = a, c, b, _triangle_tv(a, c, b, False), v2
            lo[t], hi[t] = a, b
        elif isinstance(law, Discrete):
            kept = [(x - ref, w) for x, w in zip(law.values, law.weights) if w > 0]
            lo[t], hi[t] = kept[0][0], kept[-1][0]
            if len(kept) == 1:
                constant[t] = kept[0][0]
                continue
            kind[t] = DISCRETE
            add_atoms(t, *zip(*kept))
        else:
            raise BudgetError(f"exact yield: term {tl.name} has a {law.kind} law, which has no characteristic "
                              "function here")
    power = np.array([_POWER[k] if k >= 0 else 0.0 for k in kind])
    for t in np.flatnonzero(kind == TRIANGULAR):
        power[t] = 2.0 if par[t, 4] > 0 else 1.0
    for t in np.flatnonzero(kind == C_DISCRETE):
        off, n = int(par[t, 0]), int(par[t, 1])
        power[t] = 0.5 if min(atoms[off:off + n]) > 0 else 0.0
    atoms, weights = np.array(atoms, dtype=float), np.array(weights, dtype=float)
    return TermTable(kind=kind, par=par, atoms=atoms, weights=weights, constant=constant, lo=lo, hi=hi, mean=mean,
                     var=var, normal=normal, env=_envelopes(kind, par, atoms, weights), power=power)


def _envelopes(kind, par, atoms, weights) -> np.ndarray:
    """The coefficients of :func:`envelope` of every term (T, 8); zeros (envelope 1) for constants."""
    env = np.zeros((kind.size, 8))
    A1, A2, A15, W0, BH, F2, W, SD = range(8)
    for t, k in enumerate(kind):
        p = par[t]
        if k == UNIFORM:
            env[t, A1] = 1.0 / p[1]
        elif k == NORMAL:
            env[t, SD] = p[1]
        elif k == TRUNCNORMAL:
            env[t, A1], env[t, F2], env[t, W] = p[4], p[5], p[6]
        elif k == TRIANGULAR:
            env[t, A1], env[t, A2] = p[3], max(p[4], 0.0)
        elif k in (C_UNIFORM, C_TRIANGULAR, C_TRUNCNORMAL):
            env[t, A1] = p[{C_UNIFORM: 2, C_TRIANGULAR: 3, C_TRUNCNORMAL: 4}[k]]
        elif k == C_DISC:
            env[t, A15] = p[1]
        elif k == C_DISCRETE:            # sum_k w_k min(1, sqrt(2/(pi x v_k))) <= w(v = 0) + x^-1/2 sum_{v > 0} ...
            off, n = int(p[0]), int(p[1])
            v, w = atoms[off:off + n], weights[off:off + n]
            env[t, W0] = w[v <= 0].sum()
            env[t, BH] = (w[v > 0] * np.sqrt(2.0 / (np.pi * v[v > 0]))).sum()
    return env


# ---------------------------------------------------------------------------------------------- compiled

@njit(cache=True, nogil=True)
def sinc(u):
    """sin(u) / u, the centred uniform's characteristic function (its series below 1e-4)."""
    if abs(u) < 1e-4:
        return 1.0 - u * u / 6.0
    return math.sin(u) / u


@njit(cache=True, nogil=True)
def gauss(sd, x):
    """exp(-(sd x)² / 2), the centred normal's characteristic function (and its envelope)."""
    return math.exp(-0.5 * (sd * x) ** 2)


@njit(cache=True, nogil=True)
def _h(z):
    """(e^z (z - 1) + 1) / z², entire: a series for ``|z|`` < 1 (24 terms: error below 1e-25)."""
    if abs(z) < 1.0:
        out = 0j
        fact = 2.0
        zk = 1.0 + 0j
        for k in range(24):
            out += (k + 1) * zk / fact
            zk *= z
            fact *= (k + 3)
        return out
    return (np.exp(z) * (z - 1.0) + 1.0) / (z * z)


#: The Bernstein ellipses :func:`_gl_size` tries: for rho = 1.2 ... 16, (b, log(rho² - 1), 2 log rho) with
#: b = (rho - 1/rho) / 2 (the logarithms once, not at every call: the same doubles).
_ELLIPSES = tuple((0.5 * (rho - 1.0 / rho), math.log(rho * rho - 1.0), 2.0 * math.log(rho))
                  for rho in (1.2, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0))
_LOG_64_15 = math.log(64.0 / 15.0)


@njit(cache=True, nogil=True)
def _gl_size(y, beta, n0, gl_sizes):
    """Index of the smallest Gauss-Legendre rule whose error on int_{-1}^{1} exp(-beta² s²/2) g(y s) ds,
    with ``|g(z)|`` <= exp(``|Im z|``) (cos, and J0 of a real affine argument), is below 1e-16 N0 by the
    Bernstein-ellipse bound (64/15) M rho^-2n / (rho² - 1), M = exp(beta² b²/2 + ``|y|`` b), b = (rho - 1/rho)/2;
    -1 if none is."""
    best = 1e300
    log_tol = math.log(1e-16 * n0)
    for b, log_r2, two_log_r in _ELLIPSES:
        logm = 0.5 * beta * beta * b * b + abs(y) * b
        n = (_LOG_64_15 + logm - log_r2 - log_tol) / two_log_r
        best = min(best, n)
    for i in range(gl_sizes.size):
        if gl_sizes[i] >= best:
            return i
    return -1


@njit(cache=True, nogil=True)
def _truncated_gauss(beta, n0, y, c, bessel, tab, sp):
    """int_{-1}^{1} exp(-beta² s²/2) g(s) ds / N0 with g = cos(y s) (bessel = 0) or J0(c + y s) (bessel = 1),
    by a composite Gauss-Legendre rule: K pieces of half-length 1/K, each with the rule that
    :func:`_gl_size` finds for it (frequency y / K, width beta / K), so the total error is below 1e-16."""
    gl_sizes, gl_off, gl_x, gl_w = tab[2], tab[3], tab[4], tab[5]
    K = 1
    while True:
        i = _gl_size(y / K, beta / K, n0, gl_sizes)
        if i >= 0:
            break
        K *= 2
    o, n = gl_off[i], gl_sizes[i]
    acc = 0.0
    for piece in range(K):
        centre = -1.0 + (2.0 * piece + 1.0) / K
        part = 0.0
        for q in range(n):
            s = centre + gl_x[o + q] / K
            g = math.cos(y * s) if bessel == 0.0 else sp[0](c + y * s, 0)
            part += gl_w[o + q] * math.exp(-0.5 * (beta * s) ** 2) * g
        acc += part / K
    return acc / n0


@njit(cache=True, nogil=True)
def common_cf(k, p0, p1, x, sp, buf):
    """phi_t(x) of the commonest kinds from their first two parameters (scalars, and the special functions
    ``sp`` with 2 doubles of scratch ``buf``, so that it inlines): uniform (mid, hw), normal (mu, sd) and a
    clearance uniform on [0, hi] (lo = 0, hi); NaN otherwise (then :func:`term_cf` applies)."""
    if k == UNIFORM:
        s = sinc(x * p1)
        return complex(s, 0.0) if p0 == 0.0 else complex(math.cos(x * p0) * s, math.sin(x * p0) * s)
    if k == NORMAL:
        a = gauss(p1, x)
        return complex(a, 0.0) if p0 == 0.0 else complex(math.cos(x * p0) * a, math.sin(x * p0) * a)
    if k == C_UNIFORM and p0 == 0.0:
        return complex(int_j0_over(sp, buf, abs(x) * p1), 0.0)
    return complex(np.nan, 0.0)


#: The series of I(y) / y in powers of y²: (-1/4)^m / (m!² (2m + 1)), m = 0 ... 11, each correctly rounded.
_INT_J0_SERIES = tuple(float(Fraction(-1, 4) ** m / (math.factorial(m) ** 2 * (2 * m + 1))) for m in range(12))


@njit(cache=True, nogil=True)
def int_j0_over_near(table, y):
    """I(y) / y, I(y) = int_0^y J0, for 0 <= y < :data:`~._special.TABLE_END`: below 1 the series (terms fall by
    y²/4 or faster: the first left out is below 1e-25) in Horner form, else :func:`~._special.int_j0_table`
    (``table``: ``sp[3]``; no special-function pointer, so that a kernel's loop inlines it without reference
    counting)."""
    if y < 1.0:
        s = y * y
        acc = 0.0
        for c in _INT_J0_SERIES[::-1]:
            acc = acc * s + c
        return acc
    return int_j0_table(table, y) / y


@njit(cache=True, nogil=True)
def int_j0_over(sp, buf, y):
    """I(y) / y, I(y) = int_0^y J0 (y >= 0): :func:`int_j0_over_near`, and :func:`~._special.int_j0` past its table."""
    if y < TABLE_END:
        return int_j0_over_near(sp[3], y)
    return int_j0(sp, buf, y) / y


@njit(cache=True, nogil=True)
def term_cf(k, par, t, tab, sp, buf, x):
    """phi_t(x) of term t, of kind ``k``, with parameters ``par[t]`` (:attr:`TermTable.par`), complex.

    ``tab``: :meth:`TermTable.arrays` and the Gauss-Legendre rules; ``sp``:
    :func:`~._special.special_args`; ``buf``: 2 doubles of scratch.
    """
    atoms, weights, gl_sizes, gl_off, gl_x, gl_w = tab
    j0, j1 = sp[0], sp[1]
    if k == UNIFORM:
        return np.exp(1j * x * par[t, 0]) * sinc(x * par[t, 1])
    if k == NORMAL:
        return np.exp(1j * x * par[t, 0] - 0.5 * (par[t, 1] * x) ** 2)
    if k == TRUNCNORMAL:
        return np.exp(1j * x * par[t, 0]) * (_truncated_gauss(par[t, 2], par[t, 3], x * par[t, 1], 0.0, 0.0, tab, sp) + 0j)
    if k == TRIANGULAR:
        a, c, b = par[t, 0], par[t, 1], par[t, 2]
        l1, l2 = c - a, b - c
        out = l1 * np.exp(1j * x * a) * _h(1j * x * l1) + l2 * np.exp(1j * x * b) * _h(-1j * x * l2)
        return 2.0 / (b - a) * out
    if k == DISCRETE:
        o, n = int(par[t, 0]), int(par[t, 1])
        out = 0j
        for q in range(n):
            out += weights[o + q] * np.exp(1j * x * atoms[o + q])
        return out
    ax = abs(x)
    if ax == 0.0:
        return 1.0 + 0j
    if k == C_UNIFORM:
        lo, hi = par[t, 0], par[t, 1]
        if lo == 0.0:
            return int_j0_over(sp, buf, ax * hi) + 0j
        if ax * (hi - lo) <= 4.0:             # average of J0 over [x lo, x hi] by a 16-point rule
            i = 2                             # gl_sizes[2] == 16
            o, n = gl_off[i], gl_sizes[i]
            mid, hw = 0.5 * (lo + hi), 0.5 * (hi - lo)
            acc = 0.0
            for q in range(n):
                acc += gl_w[o + q] * j0(ax * (mid + hw * gl_x[o + q]), 0)
            return 0.5 * acc + 0j
        return (int_j0(sp, buf, ax * hi) - int_j0(sp, buf, ax * lo)) / (ax * (hi - lo)) + 0j
    if k == C_DISC:
        u = ax * par[t, 0]
        return 2.0 * j1(u, 0) / u + 0j
    if k == C_DISCRETE:
        o, n = int(par[t, 0]), int(par[t, 1])
        acc = 0.0
        for q in range(n):
            acc += weights[o + q] * j0(ax * atoms[o + q], 0)
        return acc + 0j
    if k == C_TRIANGULAR:
        a, c, b = par[t, 0], par[t, 1], par[t, 2]
        acc = 0.0
        for piece in range(2):
            lo, hi = (a, c) if piece == 0 else (c, b)
            if hi <= lo:
                continue
            if piece == 0:                    # f = 2 (rho - a) / ((b - a)(c - a))
                beta = 2.0 / ((b - a) * (c - a))
                alpha = -beta * a
            else:                             # f = 2 (b - rho) / ((b - a)(b - c))
                beta = -2.0 / ((b - a) * (b - c))
                alpha = -beta * b
            acc += alpha * (int_j0(sp, buf, ax * hi) - int_j0(sp, buf, ax * lo)) / ax
            acc += beta * (hi * j1(ax * hi, 0) - lo * j1(ax * lo, 0)) / ax
        return acc + 0j
    return _truncated_gauss(par[t, 2], par[t, 3], ax * par[t, 1], ax * par[t, 0], 1.0, tab, sp) + 0j   # C_TRUNCNORMAL: E J0(x rho)


@njit(cache=True, nogil=True)
def envelope(a1, a2, a15, w0, bh, f2, w, sd, x):
    """A non-increasing bound of ``|phi_t|`` at ``|x|`` = x from a row of :attr:`TermTable.env` (scalars, so
    that it inlines): ``min(1, a1/x, a2/x², a15/x^1.5, w0 + bh/sqrt(x), f2/x + w/x²) exp(-sd² x²/2)``,
    each form present when its coefficients are."""
    if x <= 0.0:
        return 1.0
    e = 1.0
    if a1 > 0.0:
        e = min(e, a1 / x)
    if a2 > 0.0:
        e = min(e, a2 / (x * x))
    if a15 > 0.0:
        e = min(e, a15 / (x * math.sqrt(x)))
    if bh > 0.0:
        e = min(e, w0 + bh / math.sqrt(x))
    if f2 > 0.0 or w > 0.0:
        e = min(e, f2 / x + w / (x * x))
    if sd > 0.0:
        e *= gauss(sd, x)
    return e


@njit(cache=True, nogil=True)
def envelope_power(a1, a2, a15, w0, bh, f2, w, sd, x0):
    """:func:`envelope` at ``|x|`` = x0 and a power p >= 0 with ``envelope(x) <= envelope(x0) (x0 / x)^p`` for
    every x >= x0 (0 at x0 = 0), in one pass: ``(envelope, p)``.

    Past x0 the envelope is below the form that is smallest at x0, which falls
    as x^-q (q = 0 for the form 1, and for w0 + bh/sqrt(x) when w0 > 0), times
    the normal factor, which falls at least as fast as (x0/x)^(sd² x0²) past x0.
    The envelope is that smallest form times the normal factor (the forms and
    their order as in :func:`envelope`, so the value is the same to the bit).
    """
    if x0 <= 0.0:
        return 1.0, 0.0
    best, p = 1.0, 0.0
    if a1 > 0.0 and a1 / x0 < best:
        best, p = a1 / x0, 1.0
    if a2 > 0.0 and a2 / (x0 * x0) < best:
        best, p = a2 / (x0 * x0), 2.0
    if a15 > 0.0 and a15 / (x0 * math.sqrt(x0)) < best:
        best, p = a15 / (x0 * math.sqrt(x0)), 1.5
    if bh > 0.0 and w0 + bh / math.sqrt(x0) < best:
        best, p = w0 + bh / math.sqrt(x0), (0.5 if w0 == 0.0 else 0.0)
    if (f2 > 0.0 or w > 0.0) and f2 / x0 + w / (x0 * x0) < best:
        best, p = f2 / x0 + w / (x0 * x0), 1.0
    if sd > 0.0:
        best *= gauss(sd, x0)
    return best, p + (sd * x0) ** 2
