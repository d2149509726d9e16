"""P(position > S or ``|dphi|`` > Z) of a budget of independent legs, by conditioning on two legs.

When every random term belongs to one leg (no correlated directions; a
shared temperature is conditioned on, below), the pose error is ``d = s + sum_i a_i u_i`` with
a_i the columns of A^-1 and u_1, u_2, u_3 independent scalars, each the sum
of its leg's terms (``u_i = sum_t kappa_t X_t``). Write the joint exceedance
as ``P_pos + P_phi - J`` with ``J = P(position > S and |dphi| > Z)``; the two
channels come from their own series (:mod:`.series`), J from here.

For fixed (u_p, u_q), the set of u_L (L the third leg) where the position is
in spec is an interval ``[c_A - r_A, c_A + r_A]`` (``|e + m u_L| <= S``: c_A
linear in (u_p, u_q), r_A = sqrt(S² - e_perp²)/``|m|`` with e_perp linear), and
where ``|dphi| <= Z`` another, ``[c_B - w_B, c_B + w_B]`` (c_B linear, w_B
constant); so ``J = E[1 - P_L(A ∪ B) | u_p, u_q]``, a union of two
intervals through F_L, the CDF of u_L.

Each leg's CDF on a uniform grid (:func:`leg_cdfs`): its Fourier series on a
period that holds the leg's support, every grid point at once by one FFT,
truncated at K terms with the bound ``2 E(w_K) / (pi p)`` (E the product of
the terms' decreasing envelopes, p its decay power, :mod:`.characteristic`),
plus floating point (:data:`~._special.CF_ACCURACY` per coefficient) and the
normal laws' mass past their cut. Between grid points F is bracketed by
monotonicity.

J is bracketed on a partition of (u_p, u_q) into cells of grid intervals
(:func:`joint_exceedance`), each cell's share ``int g dmu`` (g = 1 - P_L(A ∪
B), mu the two legs' product measure) twice (:func:`_bracket`), and the
tighter end of each kept:

- first order: the cell's mass is the product of its two CDF differences;
  over the cell the ends of A and B lie in ranges (exact for the linear
  parts, monotone for the square root), so A and B contain a smallest and
  lie in a largest interval, which bound g from above and below. Its width
  falls as the cell's size.
- second order: ``int g dmu = m g(mean) + R`` (the first-order term of g's
  Taylor expansion about the cell's mean integrates to 0), the mean within a
  box a few grid steps wide (from the CDF bounds' prefix sums, by the
  trapezoid rule with its error ``h³ sup|f'| / 12``), g over that box as
  above, and ``|R| <= m (H_pp V_p + 2 H_pq sqrt(V_p V_q) + H_qq V_q) / 2``:
  V the legs' variances in the cell (bounded from the same sums), H bounds of
  g's second derivatives over the cell, ``sup|f_L'| G_i G_j + sup f_L K_ij``
  summed over the ends in use (G, K bounds of an end's first and second
  derivatives: the linear parts' exact, the square root's from
  ``|e_perp| <= amax < S``; an end whose range misses u_L's support adds
  none). ``sup f_L`` and ``sup |f_L'|`` are ``(1/pi) int t^k E(t) dt`` over the
  leg's envelope (:func:`_density_bounds`; finite where E falls faster than
  t^-2: the paper's legs, three uniform-envelope terms each, fall as t^-3);
  between grid points F_L is bracketed by the chord, off by at most
  ``h² sup|f_L'| / 8``. Only where g is twice differentiable on the whole
  cell: A empty throughout, or A non-empty throughout with A and B disjoint
  throughout, or overlapping with the same outer ends throughout (or the
  other ends off u_L's support); not where a shared term is conditioned on.
  Its width falls as the cell's size squared.

Cells where J's integrand is provably 0 (the smallest union covers u_L's
support) have no gap; the others are split where their gap is largest, until
the bracket's half-width meets the target or the cell budget is spent. The
reported bound is that half-width, plus the CDFs' errors, plus the two
channels' bounds.

A term of every leg with a uniform law (the shared temperature, T) is
conditioned on too: its range in :data:`_SHARED_INTERVALS` intervals of
equal probability, on each of which the constant vector ``s + c_T T`` ranges
over a segment; the linear forms carry T as a third variable taken as a
range (A's ends stay convex / concave in (u_p, u_q, T): their exact ends at
the cell's 8 corners, the tangent plane's deviation gains T's term). Each
interval is a replica of the pose with 1/K of its mass, its goal and its
cells.

Its reach (``benchmarks/bench_yield_either.py``, paper budget, both
geometries, 16 spec pairs, 5 poses each; benchmarks/README.md): the width
falls as N^-0.93 in the cells bracketed (median; N^-0.50 with the first
order alone), 6 to 51 times narrower than the first order at 20,000 open
cells a pose (0.085 s of CPU on average) and 6 to 240 times at 1,280,000
(4 s). 1e-9 is met at 48 of the 160 poses at 20,000 cells and 59 at
1,280,000 (46 and 48 with the first order): where J is 0 or below ~6e-8 at
the default budget, and in the ppm band (J from 1e-7 to 2e-5) at 11 of 19
poses with 1,280,000 cells (widths 4.6e-10 to 9.1e-9). A floor near 5e-10 to
1e-9 remains where the cells reach one step of the CDF grids.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from .._threads import check_stop, cores
from ..limits import CONDITIONED_THREAD_BYTES
from ._special import CF_ACCURACY, special_args
from .characteristic import envelope_power, term_cf

__all__ = ["CONDITIONAL_METHOD", "independent_legs", "leg_cdfs", "joint_exceedance", "chunk_bytes"]

CONDITIONAL_METHOD = (
    "; P(either) = P(position) + P(phi) - P(both out), the last by conditioning on two legs (and on the "
    "interval of a shared uniform temperature) and integrating the third through its CDF (each leg's CDF by its "
    "Fourier series on a grid with a rigorous truncation bound, bracketed between grid points by monotonicity; "
    "cells of the two legs bracketed by interval arithmetic and refined where the gap is largest); its bound is "
    "the bracket's half-width plus the CDFs' and the channels' bounds")
_GRID = 1 << 16                 # CDF grid points per leg (at least)
_K_MAX = 1 << 18                # Fourier terms per leg (at most)
_LEG_EPS = 1e-11                # truncation goal of a leg's CDF (its error enters J at most 4 times)
_INITIAL = 16                   # initial cells per leg
_MAX_CELLS = 20_000           # open cells per pose (at most): 0.02 to 0.22 s of CPU a pose (paper)
_MAX_ROUNDS = 60
_SHARED_INTERVALS = 8           # intervals of a shared (every-leg) uniform term: replicas of a pose (a power of 2)
_WIDEN = 1e-12                  # relative widening of every interval end (floating point)
_ROUND = 1e-300                 # absolute widening of sums that may round to 0
_SUMS_REL = 1e-14               # relative widening of differences of compensated prefix sums (their rounding)
_DENSITY_T0, _DENSITY_SPAN, _DENSITY_STEPS = 1e-3, 1e10, 4000   # the density bounds' grid: t0 sum|kappa|, span, steps
# memory (chunk_bytes): computing one pose's CDFs, per point of a leg's grid (its coefficients, FFT, CDF and
# bounds); a pose's cells at a round's peak, per cell (their ends and bounds, the round's copies and children)
_CDF_BYTES_PER_POINT = 64         # 51 traced (paper budget, 2^16 and 2^18 points)
_BYTES_PER_CELL = 200             # 56 held, ~180 with a round's copies and children


def independent_legs(C: np.ndarray, Ainv: np.ndarray, legs, table) -> tuple[np.ndarray, np.ndarray]:
    """Each random term's weight on its leg's direction, ``C[:, :, t] = kappa_t a_leg``, and whether the
    pose error is ``s + sum_i a_i u_i`` over independent legs.

    Returns (kappa (N, T), ok (N,)): ok is False where a random term is of all legs or off its leg's
    direction, or a leg has no random term."""
    legs = np.asarray(legs)
    N, _, T = C.shape
    kappa = np.zeros((N, T))
    if np.any(table.random & (legs < 0)):
        return kappa, np.zeros(N, dtype=bool)
    ok = np.ones(N, dtype=bool)
    for t in np.flatnonzero(table.random):
        a = Ainv[:, :, legs[t]]
        k = np.einsum("nj,nj->n", C[:, :, t], a) / np.einsum("nj,nj->n", a, a)
        resid = np.abs(C[:, :, t] - k[:, None] * a).max(axis=1)
        ok &= resid <= 1e-12 * np.abs(C[:, :, t]).max(axis=1) + 1e-300
        kappa[:, t] = k
    for i in range(3):
        ok &= (np.abs(kappa[:, legs == i]) > 0).any(axis=1) if np.any(legs == i) else False
    return kappa, ok


# ---------------------------------------------------------------------------------------------- the CDFs

@njit(cache=True, nogil=True)
def _sizes(env, kappa, legs, Q, eps, k_max, K, tail):
    """Terms K[n, i] of each leg's series and the bound ``tail`` of everything past them."""
    N, T = kappa.shape
    for n in range(N):
        for i in range(3):
            k = 64
            while True:
                w = 2.0 * math.pi * k / Q[n, i]
                e, p = 1.0, 0.0
                for t in range(T):
                    if legs[t] != i or kappa[n, t] == 0.0:
                        continue
                    x = abs(kappa[n, t]) * w
                    et, pt = envelope_power(env[t, 0], env[t, 1], env[t, 2], env[t, 3], env[t, 4], env[t, 5],
                                            env[t, 6], env[t, 7], x)
                    e *= et
                    p += pt
                bound = 2.0 * e / (math.pi * p) if p > 0.0 else math.inf
                if bound <= eps or k >= k_max:
                    break
                k *= 2
            K[n, i], tail[n, i] = k, bound


@njit(cache=True, nogil=True)
def _coefficients(kind, par, tab, sp, kappa, legs, Q, lo, K, out):
    """out[n, i, k] = phi_i(w_k) exp(-i w_k lo) / (-2 pi i k), w_k = 2 pi k / Q, for k = 1..K[n, i]."""
    buf = np.empty(2)
    N, T = kappa.shape
    for n in range(N):
        for i in range(3):
            for k in range(1, K[n, i] + 1):
                w = 2.0 * math.pi * k / Q[n, i]
                phi = 1.0 + 0j
                for t in range(T):
                    if legs[t] == i and kappa[n, t] != 0.0:
                        phi *= term_cf(kind[t], par, t, tab, sp, buf, kappa[n, t] * w)
                out[n, i, k] = phi * np.exp(-1j * w * lo[n, i]) / (-2j * math.pi * k)


@njit(cache=True, nogil=True)
def _density_bounds(env, kappa, legs, out):
    """``out[n, i, k] >= sup |f_i^(k)|``, k = 0, 1, of leg i's density: ``(1/pi) int_0^inf t^k E(t) dt`` with E the
    product of its terms' envelopes (``|phi_i| <= E``, non-increasing), by a left sum on a geometric grid (an
    upper bound: E is non-increasing) and past its end E's power law; inf where the integral diverges."""
    N, T = kappa.shape
    for n in range(N):
        for i in range(3):
            scale = 0.0
            for t in range(T):
                if legs[t] == i:
                    scale += abs(kappa[n, t])
            if scale == 0.0:
                out[n, i, 0] = out[n, i, 1] = math.inf
                continue
            t0 = _DENSITY_T0 / scale
            r = math.exp(math.log(_DENSITY_SPAN) / _DENSITY_STEPS)
            s0, s1 = t0, 0.5 * t0 * t0                  # E <= 1 on [0, t0]
            t, e = t0, 1.0
            p = 0.0
            for k in range(_DENSITY_STEPS + 1):
                e, p = 1.0, 0.0
                for u in range(T):
                    if legs[u] != i or kappa[n, u] == 0.0:
                        continue
                    eu, pu = envelope_power(env[u, 0], env[u, 1], env[u, 2], env[u, 3], env[u, 4], env[u, 5],
                                            env[u, 6], env[u, 7], abs(kappa[n, u]) * t)
                    e *= eu
                    p += pu
                if k == _DENSITY_STEPS:
                    break
                dt = t * (r - 1.0)
                s0 += e * dt
                s1 += e * (t + dt) * dt
                t += dt
            out[n, i, 0] = (s0 + e * t / (p - 1.0)) / math.pi * (1.0 + 1e-12) if p > 1.0 else math.inf
            out[n, i, 1] = (s1 + e * t * t / (p - 2.0)) / math.pi * (1.0 + 1e-12) if p > 2.0 else math.inf


def _leg_sizes(kappa: np.ndarray, legs: np.ndarray, table) -> tuple:
    """Each leg's support (N, 3, 2), grid start and period (N, 3), its series' terms K and their truncation
    bound (N, 3), and the legs of the random terms (T,; -2 for a constant)."""
    N, T = kappa.shape
    random = table.random
    a, b = kappa * np.where(random, table.lo, 0.0), kappa * np.where(random, table.hi, 0.0)
    sup = np.zeros((N, 3, 2))
    for i in range(3):
        on = random & (legs == i)
        sup[:, i, 0] = np.minimum(a, b)[:, on].sum(axis=1)
        sup[:, i, 1] = np.maximum(a, b)[:, on].sum(axis=1)
    width = sup[..., 1] - sup[..., 0]
    pad = 0.01 * width
    lo, Q = sup[..., 0] - pad, width + 2.0 * pad
    K, tail = np.zeros((N, 3), np.int64), np.zeros((N, 3))
    leg_of = np.where(random, legs, -2).astype(np.int64)
    _sizes(table.env, kappa, leg_of, Q, _LEG_EPS, _K_MAX, K, tail)
    return sup, lo, Q, K, tail, leg_of


def _points(K: np.ndarray) -> np.ndarray:
    """Grid points M of each pose's CDFs (N,), for the legs' series terms K (N, 3): a power of 2, at least
    :data:`_GRID` and above twice the most terms."""
    return np.maximum(_GRID, np.left_shift(1, np.ceil(np.log2(K.max(axis=-1) + 2)).astype(np.int64)))


def leg_cdfs(kappa: np.ndarray, legs, table, alias_one: float) -> dict:
    """Each leg's CDF on a uniform grid, with a bound of its error, at N poses.

    Parameters
    ----------
    kappa : ndarray (N, T)
        Each term's weight on its leg (:func:`independent_legs`).
    legs : sequence of int (T,)
    table : TermTable
    alias_one : float
        Mass of one normal law past its cut.

    Returns
    -------
    dict
        ``lo`` (N, 3) the grid's first point, ``h`` (N, 3) its step, ``F`` (N, 3, M) the CDF at the M points
        (M the largest of the poses' :func:`_points`), ``lo_b``/``hi_b`` (N, 3, M) bounds of F at the points
        (exact 0 / 1 off the support but for the normal laws' mass), ``eps`` (N, 3) the error bound,
        ``support`` (N, 3, 2), ``density`` (N, 3, 2) bounds of each leg's density and of its derivative
        (:func:`_density_bounds`; inf where its envelope does not fall fast enough).
    """
    legs = np.asarray(legs)
    sup, lo, Q, K, tail, leg_of = _leg_sizes(kappa, legs, table)
    alias = np.array([alias_one * np.count_nonzero(table.random & (legs == i) & table.normal) for i in range(3)],
                     dtype=float)
    M = int(_points(K).max())
    c = np.zeros(kappa.shape[:1] + (3, M), complex)
    _coefficients(table.kind, table.par, table.arrays(), special_args(), kappa, leg_of, Q, lo, K, c)
    f = np.fft.fft(c, axis=-1)
    f -= c.sum(axis=-1, keepdims=True)
    F = np.arange(M) / M + 2.0 * f.real
    del f
    terms = np.log(np.maximum(K, 1)) + 1.0
    fp = CF_ACCURACY * 2.0 * terms / math.pi + 4e-16 * np.log2(M) * (2.0 * np.abs(c).sum(axis=-1) + 1.0)
    del c
    eps = tail + fp + alias[None, :]
    h = Q / M
    g = lo[..., None] + h[..., None] * np.arange(M)
    below, above = g <= sup[..., 0, None], g >= sup[..., 1, None]
    del g
    lo_b = np.clip(np.where(below, 0.0, np.where(above, 1.0 - alias[None, :, None], F - eps[..., None])), 0.0, 1.0)
    hi_b = np.clip(np.where(below, alias[None, :, None], np.where(above, 1.0, F + eps[..., None])), 0.0, 1.0)
    dens = np.empty(kappa.shape[:1] + (3, 2))
    _density_bounds(table.env, kappa, leg_of, dens)
    return {"lo": lo, "h": h, "F": F, "lo_b": lo_b, "hi_b": hi_b, "eps": eps, "support": sup, "M": M,
            "alias": alias, "density": dens}


# ---------------------------------------------------------------------------------------------- the joint

def _legs_order(Ainv: np.ndarray) -> np.ndarray:
    """(N, 3) legs (p, q, L) per pose: L, the leg integrated through its CDF, is the one whose direction
    weighs most on both the position and dphi (both conditions then bound u_L)."""
    m = np.linalg.norm(Ainv[:, :2, :], axis=1)                          # (N, 3)
    g = np.abs(Ainv[:, 2, :])
    score = np.minimum(m / m.max(axis=1, keepdims=True), g / np.maximum(g.max(axis=1, keepdims=True), 1e-300))
    L = score.argmax(axis=1)
    order = np.array([[1, 2, 0], [0, 2, 1], [0, 1, 2]])
    return order[L]


class _Cells:
    """Bracketing J at a chunk of poses: the geometry of A and B in (u_p, u_q) and the legs' CDF bounds.

    With a ``shared`` term (its pose error per unit cT (n, 3) and its uniform law's support (lo, hi)), each
    pose is ``K`` replicas, one per interval of equal probability of the term: the constant vector of replica
    r is ``s + cT tau`` with tau over the interval, its centre ``tau_r`` and half-width ``dt``; the linear forms
    carry cT's coefficient in a fourth column, taken over the interval as a range. The replicas share their
    pose's CDF bounds (``src``: each replica's pose)."""

    def __init__(self, s, Ainv, cdf, S, Z, shared=None):
        n = s.shape[0]
        K = 1 if shared is None else _SHARED_INTERVALS
        src = np.repeat(np.arange(n), K)
        cT = np.zeros((n, 3)) if shared is None else shared[0]
        if shared is None:
            tau, dt = np.zeros(1), 0.0
        else:
            t_lo, t_hi = shared[1], shared[2]
            dt = 0.5 * (t_hi - t_lo) / K
            tau = t_lo + dt * (2.0 * np.arange(K) + 1.0)
        s = s[src] + cT[src] * np.tile(tau, n)[:, None]
        Ainv, cT = Ainv[src], cT[src]
        self.src, self.K, self.dt = src, K, np.full(src.size, dt)
        rows = src
        m = src.size
        self.order = order = _legs_order(Ainv)
        p, q, L = order.T
        idx = np.arange(m)
        a_p, a_q, a_L = Ainv[idx, :, p], Ainv[idx, :, q], Ainv[idx, :, L]      # (m, 3)
        norm = np.linalg.norm(a_L[:, :2], axis=1)
        mh = a_L[:, :2] / norm[:, None]
        g3 = a_L[:, 2]
        self.ok = (norm > 0) & (g3 != 0)
        norm, g3 = np.where(self.ok, norm, 1.0), np.where(self.ok, g3, 1.0)
        dot = lambda v: (v[:, 0] * mh[:, 0] + v[:, 1] * mh[:, 1])              # noqa: E731
        cross = lambda v: (v[:, 0] * mh[:, 1] - v[:, 1] * mh[:, 0])            # noqa: E731
        # c_A = -e.m/|m|², e_perp = e x m/|m|, c_B = -(dphi without u_L)/g3: linear in (u_p, u_q, tau)
        self.cA = np.stack([-dot(s) / norm, -dot(a_p) / norm, -dot(a_q) / norm, -dot(cT) / norm], axis=1)
        self.ep = np.stack([cross(s), cross(a_p), cross(a_q), cross(cT)], axis=1)
        self.cB = np.stack([-s[:, 2] / g3, -a_p[:, 2] / g3, -a_q[:, 2] / g3, -cT[:, 2] / g3], axis=1)
        self.norm, self.wB, self.S = norm, Z / np.abs(g3), S
        self.lo = np.stack([cdf["lo"][rows, leg] for leg in (p, q, L)])                   # (3, m): p, q, L
        self.h = np.stack([cdf["h"][rows, leg] for leg in (p, q, L)])
        self.M = M = cdf["M"]
        self.lo_b, self.hi_b = np.empty((3, n, M)), np.empty((3, n, M))               # (3, n, M): per pose
        poses = np.arange(n)
        for k in range(3):
            leg = order[::K, k]
            self.lo_b[k], self.hi_b[k] = cdf["lo_b"][poses, leg], cdf["hi_b"][poses, leg]
        self.widthL = np.diff(cdf["support"][rows, L], axis=-1)[:, 0]
        self.rows = rows
        # second order (:func:`_bracket`): the conditioned legs' prefix sums, the densities' bounds and L's
        # support (F_L constant off it; unbounded where a normal law's mass lies past its cut)
        self.sums = np.empty((2, 3, n, M + 1))
        _prefix_sums(self.lo_b[:2], self.hi_b[:2], self.sums)
        f = cdf["density"][rows]
        self.dens = np.stack([f[idx, p, 1], f[idx, q, 1], f[idx, L, 0], f[idx, L, 1]], axis=1)
        self.supL = np.where((cdf["alias"][L] > 0.0)[:, None], np.array([-np.inf, np.inf]),
                             cdf["support"][rows, L])

    def initial(self, cdf) -> tuple:
        """_INITIAL x _INITIAL cells per pose over the two conditioned legs' supports."""
        n = self.norm.size
        rows = np.arange(n)
        edges = []
        for k in range(2):
            leg = self.order[:, k]
            sup = cdf["support"][self.rows, leg]
            a = np.floor((sup[:, 0] - self.lo[k]) / self.h[k]).astype(np.int64)
            b = np.minimum(np.ceil((sup[:, 1] - self.lo[k]) / self.h[k]).astype(np.int64), self.M - 1)
            edges.append(np.round(np.linspace(a, b, _INITIAL + 1)).astype(np.int64))
        ei, ej = edges
        P = np.repeat(rows, _INITIAL * _INITIAL)
        ii = np.tile(np.repeat(np.arange(_INITIAL), _INITIAL), n)
        jj = np.tile(np.arange(_INITIAL), n * _INITIAL)
        cells = (P, ei[ii, P], ei[ii + 1, P], ej[jj, P], ej[jj + 1, P])
        keep = (cells[2] > cells[1]) & (cells[4] > cells[3])
        return tuple(c[keep] for c in cells)

    def parts(self, cells) -> np.ndarray:
        """(5, cells) :func:`_bracket`'s first-order bracket (lo, hi) and second-order parts (m g lo, m g hi,
        remainder) of each cell's share of J, before a shared term's 1/K."""
        P, i0, i1, j0, j1 = cells
        out = np.empty((5, P.size))
        _bracket(P, i0, i1, j0, j1, self.lo, self.h, self.lo_b, self.hi_b, self.src, self.cA, self.ep, self.cB,
                 self.dt, self.norm, self.wB, float(self.S), self.widthL, self.sums, self.dens, self.supL, out)
        return out

    def evaluate(self, cells) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of each cell's share of J (its mass times 1 - P_L(A ∪ B)): the first-order
        bracket and the second-order one (:func:`_bracket`), whichever is tighter at each end."""
        first_lo, first_hi, mg_lo, mg_hi, rem = self.parts(cells)
        lo, hi = np.maximum(first_lo, mg_lo - rem), np.minimum(first_hi, mg_hi + rem)
        if self.K > 1:                       # a replica's mass is 1/K of its cells' (the term's interval)
            lo /= self.K
            hi /= self.K
        return lo, hi


@njit(cache=True, nogil=True, error_model="numpy")
def _cdf_bound(lo_b, hi_b, P, x, lo, h, M, upper, f1):
    """A lower (or upper) bound of F_L(x) at pose P from the bounds at the grid points: by monotonicity, and
    where ``|f_L'| <= f1`` (finite) by the chord between them, off F by at most ``t (1 - t) h² f1 / 2``."""
    v = (x - lo) / h
    j = int(math.floor(min(max(v, -2.0), M + 1.0)))
    if upper:
        if j < 0:
            return hi_b[P, 0]
        if j >= M - 1:
            return 1.0
        b = hi_b[P, j + 1]
        if f1 < math.inf:
            t = min(max(v - j, 0.0), 1.0)
            b = min(b, ((1.0 - t) * hi_b[P, j] + t * hi_b[P, j + 1] + 0.5 * t * (1.0 - t) * h * h * f1)
                    * (1.0 + _WIDEN) + _ROUND)
        return b
    if j < 0:
        return 0.0
    if j >= M - 1:
        return lo_b[P, M - 1]
    b = lo_b[P, j]
    if f1 < math.inf:
        t = min(max(v - j, 0.0), 1.0)
        b = max(b, ((1.0 - t) * lo_b[P, j] + t * lo_b[P, j + 1]) * (1.0 - _WIDEN)
                - 0.5 * t * (1.0 - t) * h * h * f1 * (1.0 + _WIDEN))
    return b


@njit(cache=True, nogil=True, error_model="numpy")
def _union(lo_b, hi_b, P, lo, h, M, a1, b1, e1, a2, b2, e2, upper, f1):
    """A lower (upper) bound of P_L(A ∪ B), A = [a1, b1] (empty if e1) and B = [a2, b2]."""
    if not e1 and not e2 and max(a1, a2) <= min(b1, b2):
        v = max(_cdf_bound(lo_b, hi_b, P, max(b1, b2), lo, h, M, upper, f1)
                - _cdf_bound(lo_b, hi_b, P, min(a1, a2), lo, h, M, not upper, f1), 0.0)
    else:
        v1 = 0.0 if e1 else max(_cdf_bound(lo_b, hi_b, P, b1, lo, h, M, upper, f1)
                                - _cdf_bound(lo_b, hi_b, P, a1, lo, h, M, not upper, f1), 0.0)
        v2 = 0.0 if e2 else max(_cdf_bound(lo_b, hi_b, P, b2, lo, h, M, upper, f1)
                                - _cdf_bound(lo_b, hi_b, P, a2, lo, h, M, not upper, f1), 0.0)
        v = v1 + v2
    return min(max(v, 0.0), 1.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _ends(p, x0, x1, y0, y1, cA, ep, cB, d3, norm, S, widthL, w):
    """The ranges of A's and B's ends over the box [x0, x1] x [y0, y1] of replica p (and its shared term over
    [-d3, d3]), each widened by the floating-point tolerance: (amin, amax) of ``|e_perp|``, A's lower end
    within (lo_min, lo_max) and upper within (hi_min, hi_max), c_B within (cB_lo, cB_hi), and the tolerance.
    A's ends ``c_A -/+ sqrt(S² - e_perp²)/|m|`` are convex / concave in (u_p, u_q): the largest lower end and
    the smallest upper end are at corners (exact); the others by intervals and by the tangent plane at the
    centre, whichever is tighter."""
    a, b, d, e = cA[p, 1] * x0, cA[p, 1] * x1, cA[p, 2] * y0, cA[p, 2] * y1
    cA_lo, cA_hi = cA[p, 0] + min(a, b) + min(d, e), cA[p, 0] + max(a, b) + max(d, e)
    a, b, d, e = ep[p, 1] * x0, ep[p, 1] * x1, ep[p, 2] * y0, ep[p, 2] * y1
    ep_lo, ep_hi = ep[p, 0] + min(a, b) + min(d, e), ep[p, 0] + max(a, b) + max(d, e)
    a, b, d, e = cB[p, 1] * x0, cB[p, 1] * x1, cB[p, 2] * y0, cB[p, 2] * y1
    cB_lo, cB_hi = cB[p, 0] + min(a, b) + min(d, e), cB[p, 0] + max(a, b) + max(d, e)
    if d3 > 0.0:                                     # the shared term over its interval
        a, d, e = abs(cA[p, 3]) * d3, abs(ep[p, 3]) * d3, abs(cB[p, 3]) * d3
        cA_lo, cA_hi, ep_lo, ep_hi, cB_lo, cB_hi = cA_lo - a, cA_hi + a, ep_lo - d, ep_hi + d, cB_lo - e, cB_hi + e
    nrm = norm[p]
    amin = 0.0 if ep_lo * ep_hi <= 0.0 else min(abs(ep_lo), abs(ep_hi))
    amax = max(abs(ep_lo), abs(ep_hi))
    r_big = math.sqrt(max(S * S - amin * amin, 0.0)) / nrm
    tol = _WIDEN * (abs(cA_lo) + abs(cA_hi) + abs(cB_lo) + abs(cB_hi) + S / nrm + w + widthL[p])
    lo_max, hi_min = -np.inf, np.inf
    for x in (x0, x1):
        for y in (y0, y1):
            for it in range(2 if d3 > 0.0 else 1):
                cc = cA[p, 0] + cA[p, 1] * x + cA[p, 2] * y
                ee = ep[p, 0] + ep[p, 1] * x + ep[p, 2] * y
                if d3 > 0.0:
                    cc += cA[p, 3] * (2 * it - 1) * d3
                    ee += ep[p, 3] * (2 * it - 1) * d3
                r = math.sqrt(max(S * S - ee * ee, 0.0)) / nrm
                lo_max, hi_min = max(lo_max, cc - r), min(hi_min, cc + r)
    xm, ym, dx, dy = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (x1 - x0), 0.5 * (y1 - y0)
    ee = ep[p, 0] + ep[p, 1] * xm + ep[p, 2] * ym
    root = math.sqrt(max(S * S - ee * ee, 0.0))
    if amax < S:                                     # d r / d e_perp = -e / (root |m|)
        r_c = root / nrm
        slope = ee / (root * nrm)
        c_m = cA[p, 0] + cA[p, 1] * xm + cA[p, 2] * ym
        dev = abs(cA[p, 1] + slope * ep[p, 1]) * dx + abs(cA[p, 2] + slope * ep[p, 2]) * dy
        if d3 > 0.0:
            dev += abs(cA[p, 3] + slope * ep[p, 3]) * d3
        lo_min = max(cA_lo - r_big, c_m - r_c - dev)
        dev = abs(cA[p, 1] - slope * ep[p, 1]) * dx + abs(cA[p, 2] - slope * ep[p, 2]) * dy
        if d3 > 0.0:
            dev += abs(cA[p, 3] - slope * ep[p, 3]) * d3
        hi_max = min(cA_hi + r_big, c_m + r_c + dev)
    else:
        lo_min, hi_max = cA_lo - r_big, cA_hi + r_big
    return amin, amax, lo_min - tol, lo_max + tol, hi_min - tol, hi_max + tol, cB_lo - tol, cB_hi + tol, tol


@njit(cache=True, nogil=True, error_model="numpy")
def _g_bounds(bL_lo, bL_hi, o, loL, hL, M, ends, S, w, f1):
    """Bounds (lo, hi) of ``g = 1 - P_L(A ∪ B)`` over a box, its :func:`_ends`: over it A and B contain a
    smallest and lie in a largest interval."""
    amin, amax, lo_min, lo_max, hi_min, hi_max, cB_lo, cB_hi, tol = ends
    lo_s, hi_s = lo_max, hi_min
    lo_Bs, hi_Bs = cB_hi - w, cB_lo + w
    g_hi = 1.0 - _union(bL_lo, bL_hi, o, loL, hL, M, lo_s, hi_s, (amax > S) or (lo_s > hi_s),
                        lo_Bs, hi_Bs, lo_Bs > hi_Bs, False, f1)
    g_lo = 1.0 - _union(bL_lo, bL_hi, o, loL, hL, M, lo_min, hi_max, amin > S,
                        cB_lo - w, cB_hi + w, False, True, f1)
    return g_lo, g_hi


@njit(cache=True, nogil=True)
def _prefix_sums(lo_b, hi_b, out):
    """out[k, 0 | 1 | 2, P, j] = sum over i < j of lo_b[k, P, i], hi_b[k, P, i], i lo_b[k, P, i]
    (compensated sums: each off by at most ~2.2e-16 of itself, :data:`_SUMS_REL` covers it)."""
    for k in range(lo_b.shape[0]):
        for P in range(lo_b.shape[1]):
            for a in range(3):
                acc, comp = 0.0, 0.0
                out[k, a, P, 0] = 0.0
                for i in range(lo_b.shape[2]):
                    x = lo_b[k, P, i] if a == 0 else (hi_b[k, P, i] if a == 1 else i * lo_b[k, P, i])
                    t = acc + x
                    if abs(acc) >= abs(x):
                        comp += (acc - t) + x
                    else:
                        comp += (x - t) + acc
                    acc = t
                    out[k, a, P, i + 1] = acc + comp


@njit(cache=True, nogil=True, error_model="numpy")
def _moments(lo_b, hi_b, sums, k, o, a, b, h, f1):
    """Bounds of a conditioned leg's mass over grid interval [a, b] (m_lo, m_hi), of its mean's offset from
    the interval's start (d_lo, d_hi) and of its variance (v_hi), from the CDF bounds and their prefix sums:
    ``m (mean - x_a) = int (F(x_b) - F(u)) du`` (grid sums of F's bounds by monotonicity and, where
    ``|f'| <= f1``, by the trapezoid rule, off by ``h³ f1 / 12`` a step) and ``m E(u - x_a)² =
    int 2 (u - x_a) (F(x_b) - F(u)) du``."""
    n = b - a
    w = n * h
    m_lo = max(lo_b[k, o, b] - hi_b[k, o, a], 0.0)
    m_hi = min(hi_b[k, o, b] - lo_b[k, o, a], 1.0)
    L0, L1, H0, H1 = sums[k, 0, o, a], sums[k, 0, o, b], sums[k, 1, o, a + 1], sums[k, 1, o, b + 1]
    err = _SUMS_REL * (L1 + sums[k, 0, o, b + 1] + H1 + sums[k, 1, o, b] + n * hi_b[k, o, b]) + _ROUND
    s_lo = n * lo_b[k, o, b] - (H1 - H0)                 # F(u) <= F(x_{j+1}) on a step
    s_hi = n * hi_b[k, o, b] - (L1 - L0)                 # F(u) >= F(x_j)
    if f1 < math.inf:
        tr = n * h * h * f1 / 12.0
        s_lo = max(s_lo, n * lo_b[k, o, b] - 0.5 * (H1 - H0 + sums[k, 1, o, b] - sums[k, 1, o, a]) - tr)
        s_hi = min(s_hi, n * hi_b[k, o, b] - 0.5 * (L1 - L0 + sums[k, 0, o, b + 1] - sums[k, 0, o, a + 1]) + tr)
    s_lo, s_hi = max(s_lo - err, 0.0) * h, (s_hi + err) * h
    if m_lo <= 0.0:
        return m_lo, m_hi, 0.0, w, 0.25 * w * w
    d_lo, d_hi = min(s_lo / m_hi, w), min(s_hi / m_lo, w)
    J0, J1 = sums[k, 2, o, a], sums[k, 2, o, b]
    s2 = n * n * hi_b[k, o, b] - 2.0 * (J1 - J0) + (2.0 * a - 1.0) * (L1 - L0)
    s2 += _SUMS_REL * (n * n * hi_b[k, o, b] + J1 + J0 + abs(2.0 * a - 1.0) * (L1 + L0)) + _ROUND
    v_hi = min(h * h * s2 / m_lo - d_lo * d_lo, 0.25 * w * w)
    return m_lo, m_hi, d_lo, d_hi, max(v_hi, 0.0) * (1.0 + _WIDEN)


@njit(cache=True, nogil=True, error_model="numpy")
def _end_hessian(r0, r1, L0, L1, G1, G2, K, e1, e2, f0, f1, H0, H1, H2):
    """(H0, H1, H2) plus bounds of ``|d²F_L(e)|`` (pp, pq, qq) of an end ranging over (r0, r1) with ``|de/du_i| <=
    G_i`` and ``|d²e/du_i du_j| <= K |e_i e_j|``: ``f1 G_i G_j + f0 K |e_i e_j|``; none where the range misses L's
    support [L0, L1] (F_L constant there). Scalars in and out: no array a cell."""
    if r1 <= L0 or r0 >= L1:
        return H0, H1, H2
    return (H0 + (f1 * G1 * G1 + f0 * K * e1 * e1), H1 + (f1 * G1 * G2 + f0 * K * e1 * e2),
            H2 + (f1 * G2 * G2 + f0 * K * e2 * e2))


@njit(cache=True, nogil=True, error_model="numpy")
def _remainder(p, ends, cA, ep, cB, norm, S, w, L0, L1, f0, f1, vx, vy):
    """A bound of ``|int (g - g(mean) - grad g(mean) (u - mean)) dmu| / m`` over the cell (its :func:`_ends`):
    half of ``H_pp V_p + 2 H_pq sqrt(V_p V_q) + H_qq V_q`` (H bounds of g's second derivatives over the cell, V
    of the legs' variances in it), inf where g is not twice differentiable on the cell (A appears, or the
    union's pattern changes); [L0, L1] u_L's support."""
    amin, amax, lo_min, lo_max, hi_min, hi_max, cB_lo, cB_hi, tol = ends
    aB0, aB1, bB0, bB1 = cB_lo - w, cB_hi - w, cB_lo + w, cB_hi + w
    H0 = H1 = H2 = 0.0
    GB1, GB2 = abs(cB[p, 1]), abs(cB[p, 2])
    if amin > S:                                          # A empty on the cell: g = 1 - F(b_B) + F(a_B)
        H0, H1, H2 = _end_hessian(aB0, aB1, L0, L1, GB1, GB2, 0.0, 0.0, 0.0, f0, f1, H0, H1, H2)
        H0, H1, H2 = _end_hessian(bB0, bB1, L0, L1, GB1, GB2, 0.0, 0.0, 0.0, f0, f1, H0, H1, H2)
    elif amax + _WIDEN * (amax + S) < S:
        amax += _WIDEN * (amax + S)
        root = math.sqrt(S * S - amax * amax) * (1.0 - _WIDEN)
        nrm = norm[p]
        e1, e2 = abs(ep[p, 1]), abs(ep[p, 2])
        GA1 = abs(cA[p, 1]) + amax / (nrm * root) * e1
        GA2 = abs(cA[p, 2]) + amax / (nrm * root) * e2
        KA = S * S / (nrm * root * root * root)
        if hi_max < aB0 or bB1 < lo_min:                  # disjoint on the cell: every end
            H0, H1, H2 = _end_hessian(lo_min, lo_max, L0, L1, GA1, GA2, KA, e1, e2, f0, f1, H0, H1, H2)
            H0, H1, H2 = _end_hessian(hi_min, hi_max, L0, L1, GA1, GA2, KA, e1, e2, f0, f1, H0, H1, H2)
            H0, H1, H2 = _end_hessian(aB0, aB1, L0, L1, GB1, GB2, 0.0, 0.0, 0.0, f0, f1, H0, H1, H2)
            H0, H1, H2 = _end_hessian(bB0, bB1, L0, L1, GB1, GB2, 0.0, 0.0, 0.0, f0, f1, H0, H1, H2)
        elif lo_max <= bB0 and aB1 <= hi_min:             # overlapping on the cell: F(max b) - F(min a)
            if min(hi_min, bB0) >= L1:
                pass
            elif hi_min >= bB1:
                H0, H1, H2 = _end_hessian(hi_min, hi_max, L0, L1, GA1, GA2, KA, e1, e2, f0, f1, H0, H1, H2)
            elif bB0 >= hi_max:
                H0, H1, H2 = _end_hessian(bB0, bB1, L0, L1, GB1, GB2, 0.0, 0.0, 0.0, f0, f1, H0, H1, H2)
            else:
                return math.inf
            if max(lo_max, aB1) <= L0:
                pass
            elif lo_max <= aB0:
                H0, H1, H2 = _end_hessian(lo_min, lo_max, L0, L1, GA1, GA2, KA, e1, e2, f0, f1, H0, H1, H2)
            elif aB1 <= lo_min:
                H0, H1, H2 = _end_hessian(aB0, aB1, L0, L1, GB1, GB2, 0.0, 0.0, 0.0, f0, f1, H0, H1, H2)
            else:
                return math.inf
        else:
            return math.inf
    else:
        return math.inf
    return 0.5 * (H0 * vx + 2.0 * H1 * math.sqrt(vx * vy) + H2 * vy) * (1.0 + 1e-9)


@njit(cache=True, nogil=True, error_model="numpy")
def _bracket(P, i0, i1, j0, j1, lo, h, lo_b, hi_b, src, cA, ep, cB, dt, norm, wB, S, widthL, sums, dens, supL,
             out):
    """Two brackets of each cell's share of J, ``int g dmu`` over the cell (g = 1 - P_L(A ∪ B), mu the two
    legs' product measure). Cell c is replica P[c]'s grid intervals [i0, i1] x [j0, j1] of legs p, q; lo, h
    (3, n) the legs' (p, q, L) grids, lo_b, hi_b (3, poses, M) their CDF bounds at replica p's pose src[p];
    cA, ep, cB (n, 4) the linear forms (constant, u_p, u_q, tau) of c_A, e_perp and c_B, tau (a shared term)
    over [-dt, dt] (dt (n,), 0: none); norm, wB, widthL (n,); sums (2, 3, poses, M + 1)
    (:func:`_prefix_sums` of legs p and q), dens (n, 4) bounds of f_p', f_q', f_L and f_L', supL (n, 2).

    out[0], out[1]: first order, the cell's mass (the product of its two legs' CDF differences, bracketed)
    times the bounds of g over the cell (:func:`_g_bounds`).

    out[2], out[3], out[4]: second order, ``int g dmu = m g(mean) + R``: the mass's bounds times those of g
    over the box the mean lies in (:func:`_moments`; a few grid steps wide), and ``m_hi`` times the bound of
    ``|R| / m`` (:func:`_remainder`; inf where g is not smooth on the cell or a shared term is conditioned on,
    where f_L' or the legs' f' have no bound, or where a leg's mass in the cell has no positive lower bound):
    the share lies in [out[2] - out[4], out[3] + out[4]]."""
    M = lo_b.shape[2]
    bL_lo, bL_hi = lo_b[2], hi_b[2]
    for c in range(P.size):
        p = P[c]
        o = src[p]
        d3 = dt[p]
        w = wB[p]
        x0, x1 = lo[0, p] + i0[c] * h[0, p], lo[0, p] + i1[c] * h[0, p]
        y0, y1 = lo[1, p] + j0[c] * h[1, p], lo[1, p] + j1[c] * h[1, p]
        ends = _ends(p, x0, x1, y0, y1, cA, ep, cB, d3, norm, S, widthL, w)
        h_lo, h_up = _g_bounds(bL_lo, bL_hi, o, lo[2, p], h[2, p], M, ends, S, w, math.inf)
        m0_lo, m0_hi, dx_lo, dx_hi, vx = _moments(lo_b, hi_b, sums, 0, o, i0[c], i1[c], h[0, p], dens[p, 0])
        m1_lo, m1_hi, dy_lo, dy_hi, vy = _moments(lo_b, hi_b, sums, 1, o, j0[c], j1[c], h[1, p], dens[p, 1])
        out[0, c] = m0_lo * m1_lo * h_lo
        out[1, c] = m0_hi * m1_hi * h_up
        out[2, c], out[3, c], out[4, c] = 0.0, math.inf, math.inf
        if d3 > 0.0 or m0_lo <= 0.0 or m1_lo <= 0.0 or dens[p, 3] == math.inf or h_up <= 0.0:
            continue
        R = _remainder(p, ends, cA, ep, cB, norm, S, w, supL[p, 0], supL[p, 1], dens[p, 2], dens[p, 3], vx, vy)
        if R == math.inf:
            continue
        box = _ends(p, x0 + dx_lo, x0 + dx_hi, y0 + dy_lo, y0 + dy_hi, cA, ep, cB, 0.0, norm, S, widthL, w)
        g_lo, g_hi = _g_bounds(bL_lo, bL_hi, o, lo[2, p], h[2, p], M, box, S, w, dens[p, 3])
        out[2, c], out[3, c], out[4, c] = m0_lo * m1_lo * g_lo, m0_hi * m1_hi * g_hi, m0_hi * m1_hi * R


def _split(cells):
    """Each cell cut in halves along each leg wider than one grid step (2 or 4 children)."""
    P, i0, i1, j0, j1 = cells
    mi = np.where(i1 - i0 >= 2, (i0 + i1) // 2, i1)
    mj = np.where(j1 - j0 >= 2, (j0 + j1) // 2, j1)
    kids = [(P, i0, mi, j0, mj), (P, mi, i1, j0, mj), (P, i0, mi, mj, j1), (P, mi, i1, mj, j1)]
    out = tuple(np.concatenate([k[f] for k in kids]) for f in range(5))
    keep = (out[2] > out[1]) & (out[4] > out[3])
    return tuple(c[keep] for c in out)


_KEPT = ("lo", "h", "lo_b", "hi_b", "support", "density")


def _cdf_bounds(kappa, legs, table, alias_one) -> dict:
    """The legs' CDF bounds at a chunk of poses whose grids have the same points, one pose at a time: a
    pose's coefficients, FFT and CDF are freed before the next; only the bounds (``lo_b``, ``hi_b``), grids,
    supports and density bounds are kept (:func:`leg_cdfs` for the keys)."""
    n = kappa.shape[0]
    keep = {}
    for j in range(n):          # a pose's CDFs are 3 x M >= 196,608 points: vectorised within, memory bound
        check_stop()
        one = leg_cdfs(kappa[j:j + 1], legs, table, alias_one)
        if j == 0:
            keep = {"M": one["M"], "alias": one["alias"]}
            keep.update({key: np.empty((n,) + one[key].shape[1:]) for key in _KEPT})
        for key in _KEPT:
            keep[key][j] = one[key][0]
        del one
    return keep


def _chunk_joint(s, Ainv, kappa, legs, table, alias_one, S, Z, goal, shared=None):
    """J's bracket (lo, hi) at a chunk of poses; NaN where the legs' directions do not bound u_L. With a
    ``shared`` term (:class:`_Cells`) each pose is refined as its replicas, each to 1/K of the goal and of the
    cell budget, and their brackets summed."""
    cdf = _cdf_bounds(kappa, legs, table, alias_one)
    geo = _Cells(s, Ainv, cdf, S, Z, shared)
    order, K = geo.order, geo.K
    n = geo.src.size
    goal, most = goal / K, _MAX_CELLS // K
    # every CDF error is already in the cells' bounds; the mass past the normal laws' cuts is off the cells
    outside = cdf["alias"][order[:, 0]] + cdf["alias"][order[:, 1]]
    if K > 1:
        outside = outside / K
    J_lo, J_hi = np.zeros(n), outside.copy()
    cells = geo.initial(cdf)
    del cdf
    vals = geo.evaluate(cells)
    for rnd in range(_MAX_ROUNDS + 1):
        check_stop()
        lo_c, hi_c = vals
        gap = hi_c - lo_c
        P, i0, i1, j0, j1 = cells
        splittable = (i1 - i0 >= 2) | (j1 - j0 >= 2)
        closed = (gap <= 0.0) | ~splittable
        J_lo += np.bincount(P[closed], lo_c[closed], minlength=n)
        J_hi += np.bincount(P[closed], hi_c[closed], minlength=n)
        op = ~closed
        G = np.bincount(P[op], gap[op], minlength=n)
        count = np.bincount(P[op], minlength=n)
        done = (J_hi - J_lo + G <= goal) | (count > most) | (rnd == _MAX_ROUNDS)
        finish = op & done[P]
        J_lo += np.bincount(P[finish], lo_c[finish], minlength=n)
        J_hi += np.bincount(P[finish], hi_c[finish], minlength=n)
        op &= ~done[P]
        if not op.any():
            break
        cut = op & (gap >= 0.5 * G[P] / np.maximum(count[P], 1))
        stay = op & ~cut
        kids = _split(tuple(c[cut] for c in cells))
        new = geo.evaluate(kids)
        cells = tuple(np.concatenate([c[stay], k]) for c, k in zip(cells, kids))
        vals = tuple(np.concatenate([v[stay], w]) for v, w in zip(vals, new))
        del kids, new
    if K > 1:
        J_lo, J_hi = J_lo.reshape(-1, K).sum(axis=1), J_hi.reshape(-1, K).sum(axis=1)
    ok = geo.ok.reshape(-1, K).all(axis=1)
    J_lo, J_hi = np.where(ok, J_lo, np.nan), np.where(ok, np.minimum(J_hi, 1.0), np.nan)
    return J_lo, J_hi


def chunk_bytes(n: int, M: int) -> float:
    """Peak bytes of one thread of :func:`joint_exceedance` on its chunk of ``n`` poses whose CDF grids have ``M`` points: the
    memory model its chunks are sized by (:data:`~prp3mc.limits.CONDITIONED_THREAD_BYTES` each).

    Every pose holds its three legs' CDF bounds (two float64 a point, twice while the cells copy them in
    their legs' order), the two conditioned legs' three prefix sums (:func:`_prefix_sums`, 16 bytes a point of
    each of the three legs on average) and at most ``4 x _MAX_CELLS`` cells (a round splits at most
    ``_MAX_CELLS`` open cells in four); one pose at a time computes its CDFs."""
    return 3.0 * M * (_CDF_BYTES_PER_POINT + n * 48) + n * 4.0 * _MAX_CELLS * _BYTES_PER_CELL


def _chunks(M: np.ndarray, workers: int) -> list[np.ndarray]:
    """The poses (indices) in chunks of equal grid points M, each as many as fit in
    :data:`~prp3mc.limits.CONDITIONED_THREAD_BYTES` by :func:`chunk_bytes` (one at least) and no more than
    each of the ``workers``' equal share of them; the largest grids first (the slowest chunks start first)."""
    out = []
    for m in np.unique(M)[::-1]:
        idx = np.flatnonzero(M == m)
        most = -(-idx.size // workers)
        n = 1
        while n < most and chunk_bytes(n + 1, int(m)) <= CONDITIONED_THREAD_BYTES:
            n += 1
        out += [idx[a:a + n] for a in range(0, idx.size, n)]
    return out


def joint_exceedance(C: np.ndarray, Ainv: np.ndarray, legs, table, kappa: np.ndarray, S: float, Z: float,
                     target: float, alias_one: float, workers: int | None = None,
                     shared: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of J = P(``|(dx, dy)|`` > S and ``|dphi|`` > Z) at N poses of a budget of independent legs.

    The poses are independent: they run in chunks (:func:`chunk_bytes`; each pose's results do not depend on
    its chunk) on a pool of threads, each holding at most
    :data:`~prp3mc.limits.CONDITIONED_THREAD_BYTES` (:func:`~prp3mc.limits.yield_estimate` counts them). The
    time goes to compiled kernels that release the GIL (the CDFs' coefficients, their FFT, the cells'
    brackets, :func:`_bracket`), so the threads run on every core.

    Parameters
    ----------
    C : ndarray (N, 3, T)
        Pose error (dx mm, dy mm, dphi rad) per unit of each term.
    Ainv : ndarray (N, 3, 3)
    legs : sequence of int (T,)
    table : TermTable
    kappa : ndarray (N, T)
        :func:`independent_legs`.
    S, Z : float
        The specs, mm and rad.
    target : float
        Goal of the bracket's width.
    alias_one : float
        Mass of one normal law past its cut.
    workers : int, optional
        Threads (default: the CPU count).
    shared : (ndarray (N, 3), float, float), optional
        A term of every leg with a uniform law (the temperature): its pose error per unit (mm, mm, rad) and its
        support; ``table`` and ``kappa`` leave it out. J is conditioned on its :data:`_SHARED_INTERVALS`
        intervals of equal probability too (:class:`_Cells`).

    Returns
    -------
    (J_lo, J_hi) : ndarray (N,) each
        J lies between them; NaN where no leg's direction bounds u_L under both specs.
    """
    legs = np.asarray(legs)
    N = C.shape[0]
    s = np.einsum("ndt,t->nd", C, table.constant)
    J_lo, J_hi = np.empty(N), np.empty(N)
    workers = workers or cores()
    chunks = _chunks(_points(_leg_sizes(kappa, legs, table)[3]), workers)

    def run(idx):
        sh = None if shared is None else (shared[0][idx], shared[1], shared[2])
        J_lo[idx], J_hi[idx] = _chunk_joint(s[idx], Ainv[idx], kappa[idx], legs, table, alias_one, S, Z, target, sh)

    if workers == 1 or len(chunks) == 1:
        for idx in chunks:
            run(idx)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(run, chunks))
    return J_lo, J_hi
