"""The chain's formulas, written once for numpy arrays and for the compiled kernels.

Each function here is plain elementwise arithmetic on cosines and sines (a unit
vector u(t) is carried as ``cu, su``): called from Python with numpy arrays it
broadcasts (the numpy path of :mod:`~prp3mc.kinematics.chain` and
:mod:`~prp3mc.kinematics.sensitivity`); called from a numba-compiled function
with scalars it is compiled into the caller (each is registered with numba
through :func:`numba.extending.overload`), as in the envelope kernel
:mod:`~prp3mc.worstcase._kernel`. Both paths run the same floating-point
operations in the same order, so they agree bit for bit. The one choice that
differs between arrays and scalars is :func:`select` (``np.where``, or a
conditional expression).

A compiled kernel that calls these functions caches its machine code in
``__pycache__``; numba checks only the kernel's own file for changes, so after
editing this module clear the cache (``find prp3mc -name '*.nbi' -delete``).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba.extending import overload

__all__ = ["FAMILIES", "LENGTH_FAMILIES", "formula", "select", "turn", "dot", "perp_dot", "offset_vector",
           "leg_ik", "a_row", "h_entry", "h_row", "adjugate3", "cos_range"]

#: The ten error families of the paper's model, in the paper's order (:func:`h_entry`'s ``q`` indexes it).
FAMILIES = ("a", "alpha", "b", "beta", "rho", "c", "gamma", "theta", "e", "psi")
#: Families whose parameter is a length (mm); the others are angles (rad).
LENGTH_FAMILIES = frozenset({"a", "b", "rho", "c", "e"})


def formula(fn):
    """Register ``fn`` with numba so that compiled code calls the same source; returns ``fn``.

    Numba compiles it once per signature and LLVM inlines it into the caller (inlining
    at numba's level instead, ``inline="always"``, made cold compilation far slower for
    the same speed: benchmarks/README.md).
    """
    @functools.wraps(fn)
    def typer(*args):
        return fn
    overload(fn)(typer)
    return fn


def select(cond, a, b):
    """``a`` where ``cond`` holds, else ``b``: :func:`numpy.where` on arrays, a conditional in compiled code."""
    return np.where(cond, a, b)


@overload(select)
def _select_scalar(cond, a, b):
    def impl(cond, a, b):
        if cond:
            return a
        return b
    return impl


@formula
def turn(c0, s0, cp, sp):
    """Cosine and sine of t0 + phi from those of t0 and phi (addition formulas)."""
    return c0 * cp - s0 * sp, s0 * cp + c0 * sp


@formula
def dot(cu, su, cv, sv):
    """``u . v`` of the unit vectors u, v."""
    return cu * cv + su * sv


@formula
def perp_dot(cu, su, cv, sv):
    """``(E u) . v`` = sin(angle(v) - angle(u))."""
    return cu * sv - su * cv


@formula
def offset_vector(a, c, e, ci, si, ck, sk, cm, sm):
    """Components of ``a i + c k + e m`` (mm), the leg's fixed offsets from its base and platform point."""
    return a * ci + c * ck + e * cm, a * si + c * sk + e * sm


@formula
def leg_ik(rx, ry, cj, sj, cl, sl):
    """Eq. (2): slider position b and guide length d (mm) of a leg, from ``r = T - (a i + c k + e m)`` (mm)."""
    den = cj * sl - sj * cl
    return (rx * sl - ry * cl) / den, (rx * sj - ry * cj) / -den


@formula
def a_row(c, d, e, ck, sk, cl, sl, cm, sm):
    """A leg's row of A (eq. 3): the coefficients of dx, dy (mm/mm) and dphi (mm/rad)."""
    return -sl, cl, -(d + c * dot(cl, sl, ck, sk) + e * dot(cl, sl, cm, sm))


@formula
def h_entry(q, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm):
    """Diagonal entry h_q,i of H_q for family ``FAMILIES[q]`` (see :mod:`~prp3mc.kinematics.sensitivity`).

    ``a, c, e`` and the angles are the leg's constants, ``b, d`` its joint values
    (mm); mm per mm or per rad of the family's parameter. ``rho`` is the scalar 1.0.
    """
    if q == 0:    # a
        return perp_dot(cl, sl, ci, si)
    if q == 1:    # alpha
        return a * dot(cl, sl, ci, si) + b * dot(cl, sl, cj, sj) + c * dot(cl, sl, ck, sk) + d
    if q == 2:    # b: the transmission B_ii
        return perp_dot(cl, sl, cj, sj)
    if q == 3:    # beta
        return b * dot(cl, sl, cj, sj) + c * dot(cl, sl, ck, sk) + d
    if q == 4:    # rho
        return 1.0
    if q == 5:    # c
        return perp_dot(cl, sl, ck, sk)
    if q == 6:    # gamma
        return c * dot(cl, sl, ck, sk) + d
    if q == 7:    # theta
        return d
    if q == 8:    # e
        return perp_dot(cl, sl, cm, sm)
    return e * dot(cl, sl, cm, sm)  # psi


@formula
def h_row(a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm):
    """The ten :func:`h_entry` of a leg, in :data:`FAMILIES` order (for compiled code: each family a constant)."""
    return (h_entry(0, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(1, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(2, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(3, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(4, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(5, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(6, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(7, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(8, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm),
            h_entry(9, a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm))


@formula
def adjugate3(p, q, r, s, t, u, v, w, x):
    """Adjugate (cofactors, transposed) and determinant of ``[[p, q, r], [s, t, u], [v, w, x]]``.

    Returns ``(m00, m01, m02, m10, m11, m12, m20, m21, m22, det)``: the inverse is
    ``m / det``.
    """
    m00, m10, m20 = t * x - u * w, u * v - s * x, s * w - t * v
    m01, m11, m21 = r * w - q * x, p * x - r * v, q * v - p * w
    m02, m12, m22 = q * u - r * t, r * s - p * u, p * t - q * s
    return m00, m01, m02, m10, m11, m12, m20, m21, m22, p * m00 + q * m10 + r * m20


@formula
def cos_range(lo, hi):
    """Min and max of cos over [lo, hi] (rad, hi - lo < 2 pi) and the arguments attaining them.

    Returns ``(cos_min, arg_min, cos_max, arg_max)``.
    """
    two_pi = 2 * math.pi
    top = np.ceil(lo / two_pi) * two_pi
    arg_max = select(top <= hi, top, select(np.cos(lo) >= np.cos(hi), lo, hi))
    bottom = np.ceil((lo - math.pi) / two_pi) * two_pi + math.pi
    arg_min = select(bottom <= hi, bottom, select(np.cos(lo) <= np.cos(hi), lo, hi))
    return np.cos(arg_min), arg_min, np.cos(arg_max), arg_max
