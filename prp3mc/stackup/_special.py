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
J0 and -J1), whose error is below h^6/46080 max|J0^(5)| < 4e-16.

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

__all__ = ["special_args", "int_j0", "I_MAX", "C_J1", "gauss_legendre_tables", "CF_ACCURACY"]

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
_TABLE_END = 64.0


@functools.cache
def special_args() -> tuple:
    """``(j0, j1, itj0y0, table)``: what the kernels take to evaluate Bessel functions.

    ``j0(x, 0)``, ``j1(x, 0)``: ctypes pointers to SciPy's compiled functions (the
    second argument is Cython's skip-dispatch flag); ``itj0y0(x, &i0, &i1)``
    writes int_0^x J0 and int_0^x Y0; ``table`` (N, 3): int_0^y J0, J0 and -J1
    on the grid of :func:`int_j0`.
    """
    one = ctypes.CFUNCTYPE(_DOUBLE, _DOUBLE, ctypes.c_int)
    two = ctypes.CFUNCTYPE(None, _DOUBLE, _PTR, _PTR)
    addr = functools.partial(get_cython_function_address, "scipy.special.cython_special")
    from scipy import special
    y = np.arange(0.0, _TABLE_END + 1.5 * _TABLE_STEP, _TABLE_STEP)
    table = np.stack([[_int_j0_neumann(v) for v in y], special.j0(y), -special.j1(y)], axis=1)
    table.flags.writeable = False
    return one(addr("j0")), one(addr("j1")), two(addr("itj0y0")), table


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
def int_j0(sp, buf, y):
    """int_0^y J0(t) dt for y >= 0: the table below 64, SciPy's ITJYA beyond (``buf``: 2 doubles of scratch)."""
    if y < _TABLE_END:
        tab = sp[3]
        u = y * 64.0
        i = int(u)
        t = u - i
        h = _TABLE_STEP
        t2 = t * t
        t3 = t2 * t
        t4 = t3 * t
        t5 = t4 * t
        return (tab[i, 0] * (1 - 10 * t3 + 15 * t4 - 6 * t5) + h * tab[i, 1] * (t - 6 * t3 + 8 * t4 - 3 * t5)
                + h * h * tab[i, 2] * 0.5 * (t2 - 3 * t3 + 3 * t4 - t5)
                + tab[i + 1, 0] * (10 * t3 - 15 * t4 + 6 * t5) + h * tab[i + 1, 1] * (-4 * t3 + 7 * t4 - 3 * t5)
                + h * h * tab[i + 1, 2] * 0.5 * (t3 - 2 * t4 + t5))
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
