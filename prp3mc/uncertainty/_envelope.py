"""Fused compiled kernel of the exact envelope: one pass per pose, nothing per pose kept but the maxima.

Per pose it evaluates what :func:`~prp3mc.uncertainty.worstcase.worst_case`
computes through the numpy frame (:func:`~prp3mc.kinematics.chain.frame`,
:func:`~prp3mc.kinematics.sensitivity.h_entries`, the term intervals and the
8-corner maxima), in scalars: the trigonometry of the chain from cos and sin
of phi alone (the per-leg angles enter as constants), the inverse kinematics,
A and A^-1 by cofactors, the feasibility tests of
:func:`~prp3mc.kinematics.chain.validated_frame`, the h entries of the
budget's terms, the clearance intervals and the zonotope maxima. Poses are
spread over threads (``prange``); memory is the outputs only.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..kinematics.geometry import Geometry
from ..kinematics.sensitivity import FAMILIES, LENGTH_FAMILIES
from ..units import DEG2RAD
from .budget import Budget, parse_input

__all__ = ["REASONS", "leg_constants", "term_table", "envelope_kernel", "zonotope_max"]

#: Refusal reasons in the order :func:`~prp3mc.kinematics.chain.validated_frame` tests them;
#: bit ``3 * reason + leg`` of the kernel's ``bad`` word.
REASONS = ("below", "above", "d", "transmission", "condition")

_RHO = FAMILIES.index("rho")


def leg_constants(geometry: Geometry) -> np.ndarray:
    """Per-leg constants (15, 3): cos, sin of i, j and of the fixed parts of k, l, m; a, c, e (mm); stroke."""
    al, be, ga, th, ps = (geometry.rad(k) for k in ("alpha", "beta", "gamma", "theta", "psi"))
    tj = al + be
    tk = tj + ga
    tl = tk + th
    return np.array([np.cos(al), np.sin(al), np.cos(tj), np.sin(tj), np.cos(tk), np.sin(tk),
                     np.cos(tl), np.sin(tl), np.cos(ps), np.sin(ps),
                     *(geometry.rad(k) for k in ("a", "c", "e"))] + [geometry.stroke_mm[:, 0],
                                                                      geometry.stroke_mm[:, 1]])


def term_table(budget: Budget, bounds: np.ndarray):
    """The budget's terms as arrays for the kernel.

    Returns ``family`` (T,) int (index in FAMILIES), ``leg`` (T,) int,
    ``unit`` (T,) (1 for lengths, rad per deg for angles) and ``box`` (T, 4):
    the term's interval, or for a clearance (rho_lo, rho_hi, zeta_lo rad,
    zeta_hi rad) with zeta_hi = inf for a full circle.
    """
    names = budget.names
    fam, legs, unit, box = [], [], [], []
    for k, name in enumerate(names):
        family, leg = parse_input(name)
        if family == "zeta":
            continue
        fam.append(FAMILIES.index(family))
        legs.append(leg)
        unit.append(1.0 if family in LENGTH_FAMILIES else DEG2RAD)
        if family == "rho":
            zlo, zhi = bounds[names.index(f"zeta_{leg + 1}")]
            full = zhi - zlo >= 360.0
            box.append((bounds[k][0], bounds[k][1], np.deg2rad(zlo), math.inf if full else np.deg2rad(zhi)))
        else:
            box.append((bounds[k][0], bounds[k][1], 0.0, 0.0))
    return (np.array(fam, dtype=np.int64), np.array(legs, dtype=np.int64), np.array(unit),
            np.array(box, dtype=float).reshape(-1, 4))


@njit(inline="always")
def zonotope_max(a, u_mid, u_half, values, signs, n):
    """Maxima over one pose's zonotope into ``values[:, n]`` and ``signs[:, n, :]``.

    a : (3, 3) A^-1; u_mid, u_half : (3,) centre and half-width of u.
    values : (4, N) position mm, |dphi| rad, |dx| mm, |dy| mm.
    signs : (4, N, 3) sign of each leg's u_i at the maximum. The corners are
    visited in the order sx, sy, sz in (-1, +1), the first of equal maxima kept.
    """
    c0 = a[0, 0] * u_mid[0] + a[0, 1] * u_mid[1] + a[0, 2] * u_mid[2]
    c1 = a[1, 0] * u_mid[0] + a[1, 1] * u_mid[1] + a[1, 2] * u_mid[2]
    best, arg = -1.0, 0
    for k in range(8):
        vx, vy = c0, c1
        for i in range(3):
            gx, gy = a[0, i] * u_half[i], a[1, i] * u_half[i]
            if (k >> (2 - i)) & 1:
                vx, vy = vx + gx, vy + gy
            else:
                vx, vy = vx - gx, vy - gy
        q = vx * vx + vy * vy
        if q > best:
            best, arg = q, k
    values[0, n] = np.sqrt(best)
    for i in range(3):
        signs[0, n, i] = 1 if (arg >> (2 - i)) & 1 else -1
    for j, r in ((1, 2), (2, 0), (3, 1)):
        c = a[r, 0] * u_mid[0] + a[r, 1] * u_mid[1] + a[r, 2] * u_mid[2]
        sc = 1 if c >= 0 else -1
        total = abs(c)
        for i in range(3):
            g = a[r, i] * u_half[i]
            total += abs(g)
            signs[j, n, i] = sc * (1 if g >= 0 else -1)
        values[j, n] = total


@njit(inline="always", error_model="numpy")
def _cos_range(lo, hi):
    """Min and max of cos over [lo, hi] (rad, hi - lo < 2 pi), as in worstcase._cos_range."""
    two_pi = 2 * math.pi
    top = math.ceil(lo / two_pi) * two_pi
    arg_max = top if top <= hi else (lo if math.cos(lo) >= math.cos(hi) else hi)
    bottom = math.ceil((lo - math.pi) / two_pi) * two_pi + math.pi
    arg_min = bottom if bottom <= hi else (lo if math.cos(lo) <= math.cos(hi) else hi)
    return math.cos(arg_min), math.cos(arg_max)


#: Poses per block of the threaded kernel (scratch arrays are allocated once per block).
BLOCK = 1024


def envelope_kernel(poses, legc, family, leg, unit, box, limits, check, values, signs, bad):
    """Maxima of the linear model over the budget's box at every pose (compiled).

    poses : (N, 3) x mm, y mm, phi deg. legc : (15, 3) :func:`leg_constants`.
    family, leg, unit, box : :func:`term_table`. limits : (3,) min transmission,
    max condition, stroke tolerance mm; check : test them.
    values : (4, N) out, as :func:`zonotope_max`; signs : (4, N, 3) out.
    bad : (N,) int64 out, bit ``3 * reason + leg`` set for each refusal (see REASONS).
    Small batches run on the calling thread, larger ones in blocks on all cores.
    """
    run = _blocks_threaded if poses.shape[0] > 16 * BLOCK else _blocks_serial   # threads pay from ~128^2
    run(poses, legc, family, leg, unit, box, limits, check, values, signs, bad)


@njit(parallel=True, cache=True, error_model="numpy")
def _blocks_threaded(poses, legc, family, leg, unit, box, limits, check, values, signs, bad):
    """:func:`_block` over blocks of :data:`BLOCK` poses on all cores."""
    N = poses.shape[0]
    for k in prange((N + BLOCK - 1) // BLOCK):
        _block(k * BLOCK, min(N, (k + 1) * BLOCK), poses, legc, family, leg, unit, box, limits, check,
               values, signs, bad)


@njit(cache=True, error_model="numpy")
def _blocks_serial(poses, legc, family, leg, unit, box, limits, check, values, signs, bad):
    """:func:`_block` over all poses on the calling thread."""
    _block(0, poses.shape[0], poses, legc, family, leg, unit, box, limits, check, values, signs, bad)


@njit(inline="always", error_model="numpy")
def _block(start, stop, poses, legc, family, leg, unit, box, limits, check, values, signs, bad):
    """The envelope at poses ``start:stop`` (see :func:`envelope_kernel`)."""
    T = family.shape[0]
    A = np.empty((3, 3))
    Ai = np.empty((3, 3))
    hb = np.empty((3, 14))          # per leg: b, d, the h entries of the ten families, cos, sin omega
    u_mid = np.empty(3)
    u_half = np.empty(3)
    phi_deg, cp, sp = math.nan, 1.0, 0.0
    for n in range(start, stop):
        if poses[n, 2] != phi_deg:  # a grid keeps phi: its cosine and sine once
            phi_deg = poses[n, 2]
            cp, sp = math.cos(phi_deg * (math.pi / 180.0)), math.sin(phi_deg * (math.pi / 180.0))
        for i in range(3):
            ci, si, cj, sj = legc[0, i], legc[1, i], legc[2, i], legc[3, i]
            ck, sk = legc[4, i] * cp - legc[5, i] * sp, legc[5, i] * cp + legc[4, i] * sp
            cl, sl = legc[6, i] * cp - legc[7, i] * sp, legc[7, i] * cp + legc[6, i] * sp
            cm, sm = legc[8, i] * cp - legc[9, i] * sp, legc[9, i] * cp + legc[8, i] * sp
            a, c, e = legc[10, i], legc[11, i], legc[12, i]
            rx = poses[n, 0] - (a * ci + c * ck + e * cm)
            ry = poses[n, 1] - (a * si + c * sk + e * sm)
            den = cj * sl - sj * cl
            b = (rx * sl - ry * cl) / den
            d = (rx * sj - ry * cj) / -den
            lk, lm = cl * ck + sl * sk, cl * cm + sl * sm
            A[i, 0], A[i, 1], A[i, 2] = -sl, cl, -(d + c * lk + e * lm)
            hb[i, 0], hb[i, 1] = b, d
            hb[i, 2] = cl * si - sl * ci                                         # a
            hb[i, 3] = a * (cl * ci + sl * si) + b * (cl * cj + sl * sj) + c * lk + d   # alpha
            hb[i, 4] = cl * sj - sl * cj                                         # b (transmission)
            hb[i, 5] = b * (cl * cj + sl * sj) + c * lk + d                      # beta
            hb[i, 6] = 1.0                                                       # rho
            hb[i, 7] = cl * sk - sl * ck                                         # c
            hb[i, 8] = c * lk + d                                                # gamma
            hb[i, 9] = d                                                         # theta
            hb[i, 10] = cl * sm - sl * cm                                        # e
            hb[i, 11] = e * lm                                                   # psi
            hb[i, 12], hb[i, 13] = -sl, cl
        (p, q, r), (s, t, u), (v, w, x) = (A[0, 0], A[0, 1], A[0, 2]), (A[1, 0], A[1, 1], A[1, 2]), \
            (A[2, 0], A[2, 1], A[2, 2])
        Ai[0, 0], Ai[1, 0], Ai[2, 0] = t * x - u * w, u * v - s * x, s * w - t * v
        Ai[0, 1], Ai[1, 1], Ai[2, 1] = r * w - q * x, p * x - r * v, q * v - p * w
        Ai[0, 2], Ai[1, 2], Ai[2, 2] = q * u - r * t, r * s - p * u, p * t - q * s
        det = p * Ai[0, 0] + q * Ai[1, 0] + r * Ai[2, 0]
        inv_det = 1.0 / det
        for rr in range(3):
            for cc in range(3):
                Ai[rr, cc] *= inv_det
        word = 0
        if check:
            cond = 0.0
            for rr in range(3):
                col2 = A[0, rr] ** 2 + A[1, rr] ** 2 + A[2, rr] ** 2
                cond += col2 * (Ai[rr, 0] ** 2 + Ai[rr, 1] ** 2 + Ai[rr, 2] ** 2)
            cond = math.sqrt(3.0 * cond)
            for i in range(3):
                b, d = hb[i, 0], hb[i, 1]
                if b < legc[13, i] - limits[2]:
                    word |= 1 << i
                if b > legc[14, i] + limits[2]:
                    word |= 1 << (3 + i)
                if not d > 0:
                    word |= 1 << (6 + i)
                if not abs(hb[i, 4]) >= limits[0]:
                    word |= 1 << (9 + i)
                if not cond <= limits[1]:
                    word |= 1 << (12 + i)
        bad[n] = word
        u_mid[:] = 0.0
        u_half[:] = 0.0
        for k in range(T):
            i = leg[k]
            scale = hb[i, 2 + family[k]] * unit[k]
            lo, hi = box[k, 0], box[k, 1]
            if family[k] == _RHO:
                if box[k, 3] == math.inf:
                    lo, hi = -box[k, 1], box[k, 1]
                else:
                    omega = math.atan2(hb[i, 13], hb[i, 12])
                    cmin, cmax = _cos_range(box[k, 2] - omega, box[k, 3] - omega)
                    lo = (box[k, 1] if cmin <= 0 else box[k, 0]) * cmin
                    hi = (box[k, 1] if cmax >= 0 else box[k, 0]) * cmax
            u_mid[i] += scale * (0.5 * (lo + hi))
            u_half[i] += abs(scale) * (0.5 * (hi - lo))
        zonotope_max(Ai, u_mid, u_half, values, signs, n)
