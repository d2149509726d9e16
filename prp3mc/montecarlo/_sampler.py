"""Compiled sampling of a budget's features, tile by tile, with the uniforms numpy would draw.

:meth:`Budget.sample(n, seed) <prp3mc.model.budget.Budget.sample>` maps the
uniforms ``Generator(PCG64(seed)).random((n, D))`` through the inverse CDF of
each of the D factors (the inputs, then the effects' backlash and thermal).
This module draws the same uniforms in compiled code: a 128-bit PCG64 (XSL-RR
output, numpy's ``random`` = top 53 bits) in :data:`LANES` interleaved
streams. Lane l draws the D uniforms of samples l, l + L, l + 2L... of a tile
and then jumps the other lanes' draws in one affine step, so the lanes' steps
are independent (they overlap in the processor) and a tile's samples come out
in their natural order. The laws' inverse CDFs and the model's features
(values less their reference, rho cos zeta and rho sin zeta of a clearance,
the constant 1 of the known shifts) follow in the same tile, so no block of
samples is ever held in memory. A correlated budget's uniforms pass through
its Gaussian copula first (:meth:`GaussianCopula.correlate
<prp3mc.model.copula.GaussianCopula.correlate>`: normal quantiles, the
Cholesky factor, the normal CDF), as :meth:`Budget.ppf` does.

The uniforms are bit for bit numpy's; the values equal
:meth:`Law.ppf <prp3mc.model.laws.Law.ppf>`'s to round-off (exactly for
the uniform, triangular, disc and discrete laws; the normal quantile is
Wichura's AS 241, within about 1e-15 relative of scipy's ``ndtri``) and the
cosines and sines of zeta (degrees) come from a polynomial after an exact
reduction to [-45, 45] degrees, within one unit in the last place of numpy's.
A law without a compiled inverse CDF makes :func:`sampler_tables` return
``None``; the caller then samples through numpy.

Why kept rather than numpy's Generator: drawing inside the fused kernel
holds no samples, 1e8 samples at one pose peak at 0.28 GB where the numpy
code would hold 21.6 GB, and one pose runs 11.6x the numpy code
(``benchmarks/bench_montecarlo.py``, 2 shared cores; the uniforms alone are
only 1.2x numpy's ``Generator.random``).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic
from scipy import special

from ..model.budget import Budget
from ..model.copula import U_EDGE
from ..model.laws import Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from ..model.linear import FEATURE_COS, FEATURE_ONE, FEATURE_SIN, FEATURE_VALUE

__all__ = ["LANES", "sampler_tables", "pcg_lanes", "draw_uniforms", "draw_features"]

#: Interleaved PCG64 streams of a tile (a tile holds a multiple of LANES samples).
LANES = 16
_M128 = (1 << 128) - 1
_MULT = 0x2360ED051FC65DA44385DF649FCCF645  # PCG64's 128-bit multiplier
_MH, _ML = np.uint64(_MULT >> 64), np.uint64(_MULT & 0xFFFFFFFFFFFFFFFF)
_U64 = 0xFFFFFFFFFFFFFFFF

# law codes of the kernel; parameters in a row of `params`
_UNIFORM, _NORMAL, _TRUNCNORMAL, _TRIANGULAR, _DISC, _DISCRETE = range(6)


# ---------------------------------------------------------------- PCG64 in 64-bit halves
@intrinsic
def _mulhi(typingctx, a, b):
    """High 64 bits of the 128-bit product of two uint64."""
    sig = types.uint64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        i128 = ir.IntType(128)
        p = builder.mul(builder.zext(args[0], i128), builder.zext(args[1], i128))
        return builder.trunc(builder.lshr(p, ir.Constant(i128, 64)), ir.IntType(64))
    return sig, codegen


@njit(inline="always")
def _affine(ah, al, ch, cl, sh, sl):
    """(a * s + c) mod 2^128, each number as (high, low) uint64 halves."""
    lo = al * sl
    hi = _mulhi(al, sl) + al * sh + ah * sl
    out_lo = lo + cl
    return hi + ch + np.uint64(out_lo < lo), out_lo


@njit(inline="always")
def _uniform(sh, sl):
    """numpy's ``random()`` of a PCG64 state (already stepped): XSL-RR, top 53 bits."""
    rot = sh >> np.uint64(58)
    x = sh ^ sl
    x = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return np.float64(x >> np.uint64(11)) * (1.0 / 9007199254740992.0)


def _jump(delta: int, inc: int) -> tuple[int, int]:
    """(A, C) with state after ``delta`` draws = A * state + C mod 2^128."""
    acc_mult, acc_plus, mult, plus = 1, 0, _MULT, inc
    while delta:
        if delta & 1:
            acc_mult, acc_plus = acc_mult * mult & _M128, (acc_plus * mult + plus) & _M128
        plus, mult = (mult + 1) * plus & _M128, mult * mult & _M128
        delta >>= 1
    return acc_mult, acc_plus


def _halves(x: int) -> tuple[np.uint64, np.uint64]:
    return np.uint64(x >> 64), np.uint64(x & _U64)


def pcg_lanes(seed: int, first_sample: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Lane states and step constants for a tile starting at sample ``first_sample``.

    Returns
    -------
    lanes : (2, LANES) uint64
        High and low halves of lane l's state: before the draws of sample ``first_sample + l``.
    consts : (6,) uint64
        PCG64's increment and the affine jump over the other lanes' (LANES - 1) * d draws
        (d uniforms a sample).
    """
    st = np.random.PCG64(seed).state["state"]
    state, inc = st["state"], st["inc"]
    lanes = np.empty((2, LANES), np.uint64)
    for lane in range(LANES):
        a, c = _jump((first_sample + lane) * d, inc)
        lanes[:, lane] = _halves((a * state + c) & _M128)
    a, c = _jump((LANES - 1) * d, inc)
    return lanes, np.array([*_halves(inc), *_halves(a), *_halves(c)], np.uint64)


# ---------------------------------------------------------------- tables
def sampler_tables(budget: Budget, feature_ops: tuple) -> tuple | None:
    """The budget's laws and the model's features as arrays for :func:`draw_features`, or None.

    ``feature_ops`` is :meth:`LinearModel.feature_ops <prp3mc.model.linear.LinearModel.feature_ops>`.
    Returns ``(codes (D,) int64, params (D, 4) float64, cdf (K,), values (K,), ops (F, 3) int64,
    refs (F,), cidx (k,) int64, chol (k, k))`` over the budget's D factors (:attr:`Budget.factors`),
    with the correlated factors ``cidx`` and the Cholesky factor of their latent correlation
    (k = 0 for an independent budget), or None when a law has no compiled inverse CDF.
    """
    laws = list(budget.factor_laws.values())
    codes = np.empty(len(laws), np.int64)
    params = np.zeros((len(laws), 4))
    cdf, values = [], []
    for k, law in enumerate(laws):
        if type(law) is Uniform:
            codes[k], params[k, :2] = _UNIFORM, (law.lo, law.hi - law.lo)
        elif type(law) is Normal:
            codes[k], params[k, :2] = _NORMAL, (law.mu, law.sd)
        elif type(law) is TruncNormal:
            lo = float(special.ndtr(-3.0 * law.cpk))
            codes[k], params[k] = _TRUNCNORMAL, (law.center, law.sd_parent, lo, 1.0 - 2.0 * lo)
        elif type(law) is Triangular:
            codes[k], params[k] = _TRIANGULAR, (law.lo, law.mode, law.hi, (law.mode - law.lo) / (law.hi - law.lo))
        elif type(law) is Disc:
            codes[k], params[k, 0] = _DISC, law.radius
        elif type(law) is Discrete:
            c = np.cumsum(law.weights)
            c[-1] = 1.0
            codes[k], params[k, :2] = _DISCRETE, (len(cdf), len(c))
            cdf += list(c)
            values += list(law.values)
        else:
            return None
    ops, refs = feature_ops
    copula = budget.copula
    cidx = np.array(copula.index if copula else (), np.int64)
    chol = np.ascontiguousarray(copula.chol) if copula else np.zeros((0, 0))
    return codes, params, np.array(cdf, float), np.array(values, float), ops, refs, cidx, chol


# ---------------------------------------------------------------- inverse CDFs
_A = (3.387132872796366608, 133.14166789178437745, 1971.5909503065514427, 13731.693765509461125,
      45921.953931549871457, 67265.770927008700853, 33430.575583588128105, 2509.0809287301226727)
_B = (1.0, 42.313330701600911252, 687.1870074920579083, 5394.1960214247511077, 21213.794301586595867,
      39307.89580009271061, 28729.085735721942674, 5226.495278852545925)
_C = (1.42343711074968357734, 4.6303378461565452959, 5.7694972214606914055, 3.64784832476320460504,
      1.27045825245236838258, 0.24178072517745061177, 0.0227238449892691845833, 7.7454501427834140764e-4)
_D = (1.0, 2.05319162663775882187, 1.6763848301838038494, 0.68976733498510000455, 0.14810397642748007459,
      0.0151986665636164571966, 5.475938084995344946e-4, 1.05075007164441684324e-9)
_E = (6.6579046435011037772, 5.4637849111641143699, 1.7848265399172913358, 0.29656057182850489123,
      0.026532189526576123093, 0.0012426609473880784386, 2.71155556874348757815e-5, 2.01033439929228813265e-7)
_F = (1.0, 0.59983220655588793769, 0.13692988092273580531, 0.0148753612908506148525,
      7.868691311456132591e-4, 1.8463183175100546818e-5, 1.4215117583164458887e-7, 2.04426310338993978564e-15)


@njit(inline="always")
def _poly(c, x):
    return c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * (c[4] + x * (c[5] + x * (c[6] + x * c[7]))))))


@njit(inline="always")
def _ndtri(p):
    """Standard normal quantile (Wichura 1988, AS 241 PPND16, about 1e-16 relative)."""
    q = p - 0.5
    if abs(q) <= 0.425:
        r = 0.180625 - q * q
        return q * _poly(_A, r) / _poly(_B, r)
    r = p if q < 0 else 1.0 - p
    if r <= 0.0:
        return -math.inf if q < 0 else math.inf
    r = math.sqrt(-math.log(r))
    if r <= 5.0:
        r -= 1.6
        x = _poly(_C, r) / _poly(_D, r)
    else:
        r -= 5.0
        x = _poly(_E, r) / _poly(_F, r)
    return -x if q < 0 else x


@njit(nogil=True, cache=True)
def _ppf_row(code, prm, cdf, values, u, x, m):
    """x[:m] = inverse CDF of the law (code, prm) at u[:m] (as Law.ppf computes it)."""
    if code == _UNIFORM:
        for s in range(m):
            x[s] = prm[0] + prm[1] * u[s]
    elif code == _NORMAL:
        for s in range(m):
            x[s] = prm[0] + prm[1] * _ndtri(u[s])
    elif code == _TRUNCNORMAL:
        for s in range(m):
            x[s] = prm[0] + prm[1] * _ndtri(prm[2] + prm[3] * u[s])
    elif code == _TRIANGULAR:
        lo, mode, hi, fc = prm[0], prm[1], prm[2], prm[3]
        for s in range(m):
            v = u[s]
            a = lo + np.sqrt(v * (hi - lo) * (mode - lo))
            b = hi - np.sqrt((1.0 - v) * (hi - lo) * (hi - mode))
            x[s] = a if v < fc else b
    elif code == _DISC:
        for s in range(m):
            x[s] = prm[0] * np.sqrt(u[s])
    else:  # discrete: the first class whose cdf exceeds u (searchsorted side="right")
        start, k = int(prm[0]), int(prm[1])
        for s in range(m):
            i = 0
            for j in range(k):
                i += cdf[start + j] <= u[s]
            x[s] = values[start + min(i, k - 1)]


_SQRTH = 0.70710678118654752440  # sqrt(1/2)


@njit(inline="always")
def _ndtr(x):
    """Standard normal CDF, as scipy's ``ndtr`` (Cephes) computes it from erf and erfc."""
    t = x * _SQRTH
    z = abs(t)
    if z < _SQRTH:
        return 0.5 + 0.5 * math.erf(t)
    y = 0.5 * math.erfc(z)
    return 1.0 - y if t > 0 else y


@njit(nogil=True, cache=True)
def _correlate(cidx, chol, U, z, m):
    """Rows ``cidx`` of the uniforms U[:, :m] through the Gaussian copula: Phi(L Phi^-1(u)), kept in
    [U_EDGE, 1 - U_EDGE] (z: (k,) scratch)."""
    k = cidx.size
    for s in range(m):
        for a in range(k):
            u = min(max(U[cidx[a], s], U_EDGE), 1.0 - U_EDGE)
            z[a] = _ndtri(u)
        for a in range(k):
            acc = 0.0
            for b in range(a + 1):
                acc += chol[a, b] * z[b]
            U[cidx[a], s] = min(max(_ndtr(acc), U_EDGE), 1.0 - U_EDGE)


# fdlibm's kernels of sin and cos on [-pi/4, pi/4]
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


_ROUND = 6755399441055744.0  # 1.5 * 2^52: adding and subtracting it rounds to an integer


@njit(inline="always")
def _sincos_deg(t):
    """(sin, cos) of t degrees: t = 90 n + r exactly, |r| <= 45, then the kernels at r in radians."""
    n = (t * (1.0 / 90.0) + _ROUND) - _ROUND  # nearest integer (|t| < 2^51 degrees)
    x = (t - 90.0 * n) * (math.pi / 180.0)
    z = x * x
    w = z * z
    r = _S2 + z * (_S3 + z * _S4) + z * w * (_S5 + z * _S6)
    sn = x + z * x * (_S1 + z * r)
    r = z * (_C1 + z * (_C2 + z * _C3)) + w * w * (_C4 + z * (_C5 + z * _C6))
    hz = 0.5 * z
    w = 1.0 - hz
    cs = w + (((1.0 - w) - hz) + z * r)
    q = np.int64(n)  # quadrant: sin = (sn, cs, -sn, -cs)[q & 3], cos = (cs, -sn, -cs, sn)[q & 3]
    odd = (q & 1) == 1
    s_out = cs if odd else sn
    c_out = sn if odd else cs
    return s_out * np.float64(1 - (q & 2)), c_out * np.float64(1 - ((q + 1) & 2))


# ---------------------------------------------------------------- one tile
@njit(nogil=True, cache=True)
def draw_uniforms(lanes, consts, U):
    """The uniforms (d, T) of the next tile's T samples (T a multiple of LANES); the lanes move on.

    Lane l draws the d uniforms of samples l, l + LANES, ... and then jumps the
    other lanes' draws, so ``U[:, s]`` is sample s's row of numpy's ``random((n, d))``.
    """
    d, T = U.shape
    ih, il, ah, al, ch, cl = consts[0], consts[1], consts[2], consts[3], consts[4], consts[5]
    sh, sl = lanes[0], lanes[1]
    for i in range(T // LANES):
        base = i * LANES
        for j in range(d):
            for lane in range(LANES):
                h, lo = _affine(_MH, _ML, ih, il, sh[lane], sl[lane])
                sh[lane], sl[lane] = h, lo
                U[j, base + lane] = _uniform(h, lo)
        for lane in range(LANES):
            sh[lane], sl[lane] = _affine(ah, al, ch, cl, sh[lane], sl[lane])


@njit(nogil=True, cache=True)
def draw_features(lanes, consts, codes, params, cdf, values, ops, refs, cidx, chol, m, U, X, F):
    """Features of the next tile of samples; the lanes move on to the tile after it.

    Parameters
    ----------
    lanes : (2, LANES) uint64, updated
        :func:`pcg_lanes` states at the tile's first sample.
    consts : (6,) uint64
        :func:`pcg_lanes` constants.
    codes, params, cdf, values, ops, refs, cidx, chol
        :func:`sampler_tables`.
    m : int
        Samples of the tile that are used (the lanes draw the whole tile).
    U, X : (d, T) float64 scratch
        Uniforms and input values (mm / deg), T a multiple of LANES.
    F : (nF, T) float64 out
        Features of the tile's first ``m`` samples.
    """
    d = U.shape[0]
    draw_uniforms(lanes, consts, U)
    if cidx.size:
        _correlate(cidx, chol, U, np.empty(cidx.size), m)
    for j in range(d):
        _ppf_row(codes[j], params[j], cdf, values, U[j], X[j], m)
    f = 0
    while f < ops.shape[0]:
        op, a, b = ops[f, 0], ops[f, 1], ops[f, 2]
        xa, xb = X[a], X[b]
        if op == FEATURE_VALUE:
            out, ref = F[f], refs[f]
            for s in range(m):
                out[s] = xa[s] - ref
        elif op == FEATURE_ONE:
            F[f, :m] = 1.0
        elif op == FEATURE_COS and f + 1 < ops.shape[0] and ops[f + 1, 0] == FEATURE_SIN \
                and ops[f + 1, 1] == a and ops[f + 1, 2] == b:  # a clearance: both in one loop
            fc, fs = F[f], F[f + 1]
            for s in range(m):
                sn, cs = _sincos_deg(xb[s])
                fc[s] = xa[s] * cs
                fs[s] = xa[s] * sn
            f += 1
        else:
            out = F[f]
            for s in range(m):
                sn, cs = _sincos_deg(xb[s])
                out[s] = xa[s] * (cs if op == FEATURE_COS else sn)
        f += 1
