"""Bessel functions for the compiled kernels, and the constants of their bounds.

The kernels call SciPy's own J0, J1 (Cephes) and the integral of J0
(specfun's ITJYA) through ``scipy.special.cython_special``. The function
pointers (and the table below) are passed to the kernels as arguments, never
read as globals, so numba can cache the compiled kernels on disk (a pointer
or a large array held in a global is a "dynamic global" that numba refuses
to cache): :func:`special_args` gives the tuple the kernels take.

SciPy's integral of J0 is off by up to 7e-10 between 5 and 60 (measured
against a compensated Gauss-Legendre sum), and good to 2e-14 beyond 60. Below
64 :func:`int_j0` interpolates a table instead: quintic Hermite on a 1/64
grid of the exact values, first and second derivatives (the integral by the
Neumann series ``2 sum J_{2k+1}``, the J_n by Miller's backward recurrence;
J0 and -J1), whose error is below h^6/46080 max|J0^(5)| < 4e-16. The table
holds each interval's interpolant as its six coefficients in t = 64 y - i
(exact from the node values, rounded once), evaluated in Horner form: the
rounding adds at most 12 u sum_k ``|c_k|`` < 2.2e-15 (u = 2^-53; sum_k ``|c_k|`` < 1.49).

Constants, each checked by ``tests/test_stackup.py``:

- :data:`I_MAX`: ``sup_{y >= 0} |int_0^y J0|`` = 1.4703000... at the first zero of J0
  (the integral rises to it, then oscillates about 1 with shrinking swings, never below 0.71).
- :data:`C_J1`: ``sup_{u > 0} sqrt(u) |J1(u)|`` = 0.82503... at u = 2.166; beyond u = 200 the
  modulus bound sqrt(u) (J1² + Y1²)^(1/2), decreasing for order 1 (Watson, 13.74), is below 0.79789.
"""

from __future__ import annotations

import ctypes
import functools

import math

import numpy as np
from numba import njit
from numba.extending import get_cython_function_address

__all__ = ["special_args", "int_j0", "int_j0_table", "TABLE_END", "I_MAX", "C_J1", "gauss_legendre_tables",
           "CF_ACCURACY"]

#: Bound of |int_0^y J0(t) dt| over y >= 0 (rounded up).
I_MAX = 1.470301
#: Bound of sqrt(u) |J1(u)| over u > 0 (rounded up).
C_J1 = 0.825031
#: Assumed absolute accuracy of one characteristic-function value of the pose error in float64
#: (products of up to a few dozen factors, each a few ulps; SciPy's integral of J0 is good to
#: 2e-13 up to 1e4, measured against Gauss-Legendre; tests/test_stackup.py checks every law's
#: CF to 1e-14 against an independent quadrature).
CF_ACCURACY = 1e-13

_DOUBLE = ctypes.c_double
_PTR = ctypes.POINTER(ctypes.c_double)


_TABLE_STEP = 1.0 / 64
#: Where :func:`int_j0`'s table ends (SciPy's ITJYA beyond).
TABLE_END = 64.0


@functools.cache
def special_args() -> tuple:
    """``(j0, j1, itj0y0, table)``: what the kernels take to evaluate Bessel functions.

    ``j0(x, 0)``, ``j1(x, 0)``: ctypes pointers to SciPy's compiled functions (the
    second argument is Cython's skip-dispatch flag); ``itj0y0(x, &i0, &i1)``
    writes int_0^x J0 and int_0^x Y0; ``table`` (N, 6): :func:`int_j0`'s quintic
    on each interval of its grid, its coefficients of t^0 ... t^5 (:func:`_hermite_coefficients`).
    """
    one = ctypes.CFUNCTYPE(_DOUBLE, _DOUBLE, ctypes.c_int)
    two = ctypes.CFUNCTYPE(None, _DOUBLE, _PTR, _PTR)
    addr = functools.partial(get_cython_function_address, "scipy.special.cython_special")
    from scipy import special
    y = np.arange(0.0, TABLE_END + 1.5 * _TABLE_STEP, _TABLE_STEP)
    table = _hermite_coefficients(np.array([_int_j0_neumann(v) for v in y]), special.j0(y), -special.j1(y),
                                  _TABLE_STEP)
    table.flags.writeable = False
    return one(addr("j0")), one(addr("j1")), two(addr("itj0y0")), table


#: The quintic Hermite interpolant on [0, 1] in powers of t: row k holds the coefficients of t^k on
#: (f0, h f0', h² f0'' / 2, f1, h f1', h² f1'' / 2), the values and scaled derivatives at t = 0 and t = 1.
_HERMITE = ((1, 0, 0, 0, 0, 0), (0, 1, 0, 0, 0, 0), (0, 0, 1, 0, 0, 0),
            (-10, -6, -3, 10, -4, 1), (15, 8, 3, -15, 7, -2), (-6, -3, -1, 6, -3, 1))


def _hermite_coefficients(f: np.ndarray, df: np.ndarray, ddf: np.ndarray, h: float) -> np.ndarray:
    """(N - 1, 6): on each interval [y_i, y_i + h] of a grid with values f, first and second derivatives
    df, ddf (N,), the coefficients c_0 ... c_5 of the quintic Hermite interpolant in t = (y - y_i) / h, each
    the exact integer combination of the node data correctly rounded (``math.fsum`` of its terms repeated;
    h a power of 2, so the scaled derivatives are exact)."""
    data = np.stack([f[:-1], h * df[:-1], 0.5 * h * h * ddf[:-1], f[1:], h * df[1:], 0.5 * h * h * ddf[1:]], axis=1)
    out = np.empty((f.size - 1, 6))
    for i, row in enumerate(data.tolist()):
        out[i] = [math.fsum(v if c > 0 else -v for c, v in zip(k, row) for _ in range(abs(c)))
                  for k in _HERMITE]
    return out


@njit(cache=True, nogil=True)
def _int_j0_neumann(y):
    """int_0^y J0 = 2 sum_k J_{2k+1}(y), the J_n by Miller's backward recurrence normalised by
    J0 + 2 sum_k J_{2k} = 1 (about 1 µs at y = 20: the table's builder)."""
    if y == 0.0:
        return 0.0
    n_start = 2 * ((int(y) + 20 + int(math.sqrt(60.0 * y))) // 2)
    j_next, j, norm, odd = 0.0, 1e-30, 0.0, 0.0
    for n in range(n_start, 0, -1):
        j_prev = (2.0 * n / y) * j - j_next
        if n % 2 == 0:
            norm += 2.0 * j
        else:
            odd += 2.0 * j
        j_next, j = j, j_prev
        if abs(j) > 1e250:
            j_next, j, norm, odd = j_next * 1e-250, j * 1e-250, norm * 1e-250, odd * 1e-250
    return odd / (norm + j)


@njit(cache=True, nogil=True)
def int_j0_table(table, y):
    """int_0^y J0(t) dt for 0 <= y < 64 from the table of :func:`special_args` (``sp[3]``), in Horner form. An
    array and a scalar, no branch: inlined in a loop, it costs no reference counting (a kernel hoists the
    table out of its loop)."""
    u = y * 64.0
    i = int(u)
    t = u - i
    c = table
    return c[i, 0] + t * (c[i, 1] + t * (c[i, 2] + t * (c[i, 3] + t * (c[i, 4] + t * c[i, 5]))))


@njit(cache=True, nogil=True)
def int_j0(sp, buf, y):
    """int_0^y J0(t) dt for y >= 0: the table below 64, SciPy's ITJYA beyond (``buf``: 2 doubles of scratch)."""
    if y < TABLE_END:
        return int_j0_table(sp[3], y)
    sp[2](y, buf[0:].ctypes, buf[1:].ctypes)
    return buf[0]


#: Gauss-Legendre rule sizes available to the kernels (smooth laws' characteristic functions).
GL_SIZES = (8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)


@functools.cache
def gauss_legendre_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(sizes, offsets, nodes, weights)``: every rule of :data:`GL_SIZES` on [-1, 1], flat, read-only."""
    nodes, weights = zip(*(np.polynomial.legendre.leggauss(n) for n in GL_SIZES))
    sizes = np.array(GL_SIZES, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    out = (sizes, offsets, np.concatenate(nodes), np.concatenate(weights))
    for a in out:
        a.flags.writeable = False
    return out
