"""Fused compiled kernel of the exact envelope: one pass per pose, nothing per pose kept but the maxima.

Per pose it evaluates what :func:`~prp3mc.worstcase.envelope.worst_case`
computes through the numpy frame (:func:`~prp3mc.kinematics.chain.frame`,
:func:`~prp3mc.kinematics.sensitivity.h_entries`, the term intervals and the
corner maxima), with the same formulas (:mod:`~prp3mc.kinematics.formulas`,
called on scalars): the trigonometry of the chain from cos and sin of phi
alone (the per-leg angles enter as constants), the inverse kinematics, A and
A^-1 by cofactors (times 1/det here, divided by det in the numpy frame: they
differ in the last bit), the feasibility tests of
:func:`~prp3mc.kinematics.chain.validated_frame`, the h entries of the
budget's terms, the clearance intervals and the zonotope maxima. Poses go
through in blocks of :data:`BLOCK`, each step a loop over the block's poses
(it vectorises); larger batches go in chunks to a pool of threads.
Memory is the outputs only (42 bytes a pose: the four maxima, the ends of
their generators as one bit each, the refusal word) plus one scratch array per thread.

A budget's effects are terms too: known shifts are terms of zero width, a
backlash a term of its leg, a lead scale and thermal expansion are multiplied
by the nominal slider position b_i, a cyclic screw error by
sin(2 pi b_i / p_i + phi_i); thermal expansion acts on all legs at
once, so it adds a shared generator to the zonotope (16 corners).
"""

from __future__ import annotations

import functools
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import literal_unroll, njit

from .._threads import check_stop, cores
from ..kinematics.chain import DEFAULT_LIMITS, Limits
from ..kinematics.geometry import Geometry
from ..kinematics.formulas import (
    FAMILIES, LENGTH_FAMILIES, a_row, adjugate3, cos_range, h_row, leg_ik, offset_vector, turn,
)
from ..units import DEG2RAD, RAD2DEG
from ..model.budget import Budget, parse_input
from ..model.effects import WEIGHT_B, WEIGHT_WAVE, effect_terms

__all__ = ["REASONS", "NONFINITE", "leg_constants", "TERM_COLUMNS", "term_table", "kernel_tables", "envelope_kernel",
           "zonotope_maxima", "zonotope_scratch", "generator_signs"]

#: Refusal reasons in the order :func:`~prp3mc.kinematics.chain.validated_frame` tests them;
#: bit ``3 * reason + leg`` of the kernel's ``bad`` word.
REASONS = ("below", "above", "d", "transmission", "condition")
#: The bit of the ``bad`` word set for a pose holding NaN or infinity (refused whether or not limits are tested).
NONFINITE = 1 << 15

_RHO, _TRANSMISSION = FAMILIES.index("rho"), FAMILIES.index("b")
#: Rows of a pose block's scratch (each BLOCK values; see :func:`_range`): ``cs`` holds rows
#: _COS_PHI, _SIN_PHI, _X, _Y; ``legs`` per leg i the _LEG_ROWS rows from ``_LEG_ROWS * i``:
#: _B, _D (b and d, mm), the h entry of family q in row _H + q, _COS_OMEGA, _SIN_OMEGA.
_COS_PHI, _SIN_PHI, _X, _Y = range(4)
_B, _D, _H, _COS_OMEGA, _SIN_OMEGA = 0, 1, 2, 2 + len(FAMILIES), 3 + len(FAMILIES)
_LEG_ROWS = 4 + len(FAMILIES)


@njit(inline="always")
def _row(r):
    """Offset of row r of a block's scratch (BLOCK values a row)."""
    return r * BLOCK


@njit(inline="always")
def _leg_row(i, r):
    """Offset of row r of leg i in a block's ``legs`` scratch."""
    return (_LEG_ROWS * i + r) * BLOCK


def leg_constants(geometry: Geometry, limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Per-leg constants and the limits of the feasibility tests, (16, 3).

    Rows: cos, sin of i, j and of the fixed parts of k, l, m; a, c, e (mm); the
    stroke's ends (mm) widened by the stroke tolerance; then (min transmission,
    max condition, stroke tolerance mm), the limits :func:`~prp3mc.kinematics.chain.validated_frame` tests.
    """
    al, be, ga, th, ps = (geometry.rad(k) for k in ("alpha", "beta", "gamma", "theta", "psi"))
    tj = al + be
    tk = tj + ga
    tl = tk + th
    tol = limits.stroke_tol_mm
    return np.array([np.cos(al), np.sin(al), np.cos(tj), np.sin(tj), np.cos(tk), np.sin(tk),
                     np.cos(tl), np.sin(tl), np.cos(ps), np.sin(ps),
                     *(geometry.rad(k) for k in ("a", "c", "e")),
                     geometry.stroke_mm[:, 0] - tol, geometry.stroke_mm[:, 1] + tol,
                     [limits.min_transmission, limits.max_condition, tol]])


@functools.lru_cache(maxsize=16)
def kernel_tables(geometry: Geometry, budget: Budget, k_sigma: float | None) -> tuple:
    """``(bounds, legc, terms)``: the budget's bounds, :func:`leg_constants` and :func:`term_table`, read-only.

    Kept for the last few (geometry, budget, k_sigma), so that a small batch does not pay for them again.
    """
    bounds = budget.bounds(k_sigma)
    out = (bounds, leg_constants(geometry), term_table(budget, bounds, geometry.lead_mm))
    for a in out:
        a.flags.writeable = False
    return out


#: Columns of :func:`term_table`.
TERM_COLUMNS = ("family", "leg", "unit", "mode", "lo", "hi", "zeta_lo", "zeta_hi")


def term_table(budget: Budget, bounds: np.ndarray, lead_mm: np.ndarray | None = None) -> np.ndarray:
    """The budget's terms for the kernel, one row each (T, 8), columns :data:`TERM_COLUMNS`.

    ``family``: index in FAMILIES; ``leg``: 0-2, or -1 for a term of every leg;
    ``unit``: 1 for lengths, rad per deg for angles, alpha_T for thermal;
    ``mode``: the term's :attr:`EffectTerm.weight <prp3mc.model.effects.EffectTerm.weight>`,
    ``WEIGHT_B`` when its u_i is also multiplied by the nominal slider
    position b_i, ``WEIGHT_WAVE`` when by ``sin(zeta_lo b_i + zeta_hi)`` (a cyclic screw
    error: ``zeta_lo`` = 2 pi / p_i, rad per mm, ``zeta_hi`` = phi_i, rad),
    else ``WEIGHT_ONE`` (0); ``lo``, ``hi``: the term's interval, or a clearance's
    rho interval with its contact angles ``zeta_lo``, ``zeta_hi`` (rad;
    zeta_hi = inf for a full circle, both 0 for other terms). ``bounds`` (D, 2)
    are the factors' intervals; ``lead_mm`` (3,) the screws' leads (cyclic errors need them).
    """
    names, factors = budget.names, budget.factors
    rows = []
    for k, name in enumerate(names):
        family, leg = parse_input(name)
        if family == "zeta":
            continue
        unit = 1.0 if family in LENGTH_FAMILIES else DEG2RAD
        zeta = (0.0, 0.0)
        if family == "rho":
            zlo, zhi = bounds[names.index(f"zeta_{leg + 1}")]
            zeta = (np.deg2rad(zlo), math.inf if zhi - zlo >= 360.0 else np.deg2rad(zhi))
        rows.append((FAMILIES.index(family), leg, unit, 0, *bounds[k], *zeta))
    for term in effect_terms(budget.effects, lead_mm):
        unit = term.coefficient * (1.0 if term.family in LENGTH_FAMILIES else DEG2RAD)
        if term.is_shift:
            lo = hi = term.value
        else:
            lo, hi = bounds[factors.index(term.effect.name)] - term.reference
        rows.append((FAMILIES.index(term.family), term.leg, unit, term.weight, lo, hi, term.wavenumber, term.phase))
    return np.array(rows, dtype=float).reshape(-1, len(TERM_COLUMNS))


@njit(cache=True)
def zonotope_scratch(n_gen, size):
    """Scratch arrays of :func:`zonotope_maxima` for ``n_gen`` generators and ``size`` poses (two allocations:
    its float rows are slices of one)."""
    G = n_gen - 3
    f = np.empty((3 + 2 * G) * size)
    return (f[:size], f[size:2 * size], f[2 * size:3 * size], np.empty(size, np.int64),
            f[3 * size:(3 + G) * size].reshape((G, size)), f[(3 + G) * size:].reshape((G, size)))


@njit(inline="always")
def _leg_corner(cx, cy, gens, k):
    """Corner k (bits 2, 1, 0: legs 1, 2, 3 at +1) about the point (cx, cy), the legs' generators added in order."""
    vx = cx + gens[0] if k & 4 else cx - gens[0]
    vy = cy + gens[1] if k & 4 else cy - gens[1]
    vx = vx + gens[2] if k & 2 else vx - gens[2]
    vy = vy + gens[3] if k & 2 else vy - gens[3]
    vx = vx + gens[4] if k & 1 else vx - gens[4]
    vy = vy + gens[5] if k & 1 else vy - gens[5]
    return vx, vy


@njit(cache=True, error_model="numpy")
def zonotope_maxima(Ai, um, uh, ext, values, codes, first, m, scratch):
    """Maxima over the zonotopes of ``m`` poses into ``values`` and ``codes`` from column ``first`` on.

    Ai : (3, 3, >= m) A^-1 of each pose (last axis the pose); um, uh : (3, >= m) centre
    and half-width of u along the legs' axes; ext : (G, 3, >= m) further generators of u
    (terms of all legs). values : (4, N) position mm, |dphi| rad, |dx| mm, |dy| mm.
    codes : (4, N) int16, the end of each generator at the maximum as bits: with the
    3 + G generators in the order legs 1-3, then ``ext``, bit 2 + G - k is set when
    generator k is at +1 (:func:`generator_signs` unpacks them). A corner is the centre
    moved by the further generators, then by the legs'; of equal maxima the smallest
    code is kept. Every step is a loop over the poses (they vectorise). ``scratch`` :
    :func:`zonotope_scratch` for 3 + G generators.
    """
    sx, sy, best, arg, ex, ey = scratch
    G = ext.shape[0]
    n_gen = 3 + G
    for g in range(G):
        for j in range(m):
            ex[g, j] = Ai[0, 0, j] * ext[g, 0, j] + Ai[0, 1, j] * ext[g, 1, j] + Ai[0, 2, j] * ext[g, 2, j]
            ey[g, j] = Ai[1, 0, j] * ext[g, 0, j] + Ai[1, 1, j] * ext[g, 1, j] + Ai[1, 2, j] * ext[g, 2, j]
    for j in range(m):
        best[j], arg[j] = -1.0, 0
    for e in range(1 << G):  # the further generators' ends: the centre they move the leg corners about
        for j in range(m):
            sx[j] = Ai[0, 0, j] * um[0, j] + Ai[0, 1, j] * um[1, j] + Ai[0, 2, j] * um[2, j]
            sy[j] = Ai[1, 0, j] * um[0, j] + Ai[1, 1, j] * um[1, j] + Ai[1, 2, j] * um[2, j]
        for g in range(G):
            exg, eyg = ex[g], ey[g]
            if (e >> (G - 1 - g)) & 1:
                for j in range(m):
                    sx[j], sy[j] = sx[j] + exg[j], sy[j] + eyg[j]
            else:
                for j in range(m):
                    sx[j], sy[j] = sx[j] - exg[j], sy[j] - eyg[j]
        for j in range(m):
            gens = (Ai[0, 0, j] * uh[0, j], Ai[1, 0, j] * uh[0, j], Ai[0, 1, j] * uh[1, j], Ai[1, 1, j] * uh[1, j],
                    Ai[0, 2, j] * uh[2, j], Ai[1, 2, j] * uh[2, j])
            top, at = best[j], arg[j]
            for k in range(8):
                vx, vy = _leg_corner(sx[j], sy[j], gens, k)
                q = vx * vx + vy * vy
                code = (k << G) | e
                better = (q > top) | ((q == top) & (code < at))
                at = code if better else at
                top = q if better else top
            best[j], arg[j] = top, at
    for j in range(m):
        values[0, first + j] = np.sqrt(best[j])
        codes[0, first + j] = arg[j]
    for o, r in ((1, 2), (2, 0), (3, 1)):  # |dphi|, |dx|, |dy|: every generator at its sign
        for j in range(m):
            c = Ai[r, 0, j] * um[0, j] + Ai[r, 1, j] * um[1, j] + Ai[r, 2, j] * um[2, j]
            g0, g1, g2 = Ai[r, 0, j] * uh[0, j], Ai[r, 1, j] * uh[1, j], Ai[r, 2, j] * uh[2, j]
            up = c >= 0
            best[j] = c
            sx[j] = ((abs(c) + abs(g0)) + abs(g1)) + abs(g2)
            arg[j] = ((np.int64(up == (g0 >= 0)) << (n_gen - 1)) | (np.int64(up == (g1 >= 0)) << (n_gen - 2))
                      | (np.int64(up == (g2 >= 0)) << (n_gen - 3)))
        for e in range(G):
            for j in range(m):
                g = Ai[r, 0, j] * ext[e, 0, j] + Ai[r, 1, j] * ext[e, 1, j] + Ai[r, 2, j] * ext[e, 2, j]
                sx[j] += abs(g)
                arg[j] |= np.int64((best[j] >= 0) == (g >= 0)) << (G - 1 - e)
        for j in range(m):
            values[o, first + j] = sx[j]
            codes[o, first + j] = arg[j]


def generator_signs(codes: np.ndarray, n_gen: int) -> np.ndarray:
    """The ends (-1, +1) of each generator, int8 of shape ``codes.shape + (n_gen,)``, from
    :func:`zonotope_maxima`'s codes (legs 1-3, then the terms of all legs)."""
    out = np.empty(codes.shape + (n_gen,), dtype=np.int8)
    _unpack(np.ascontiguousarray(codes).reshape(-1), out.reshape(-1, n_gen))
    return out


@njit(nogil=True, cache=True)
def _unpack(codes, out):
    n_gen = out.shape[1]
    for n in range(codes.size):
        for k in range(n_gen):
            out[n, k] = ((codes[n] >> (n_gen - 1 - k)) & 1) * 2 - 1


@njit(inline="always")
def _nonfinite(cs, j):
    """NONFINITE if pose ``j`` of a block held NaN or infinity, else 0, from its x, y and cos phi in
    ``cs`` (cos is NaN for an infinite phi; v - v is NaN for those only, and it vectorises)."""
    x, y, c = cs[_row(_X) + j], cs[_row(_Y) + j], cs[_row(_COS_PHI) + j]
    return np.int64(not (x - x) + (y - y) + (c - c) == 0.0) * NONFINITE


@njit(inline="always")
def _slider_factor(mode, b, wavenumber, phase):
    """What a term's u_i is multiplied by (:func:`term_table`'s ``mode``): 1, b_i, or sin(wavenumber b_i + phase)
    (compiled :func:`~prp3mc.model.effects.slider_factor`)."""
    if mode == WEIGHT_B:
        return b
    if mode == WEIGHT_WAVE:
        return math.sin(wavenumber * b + phase)
    return 1.0


#: Poses per block: the block's scratch rows (about 70 x BLOCK float64) stay in cache and every
#: step is a loop over the block's poses, which vectorises.
BLOCK = 128
#: Fewest poses for which threads pay (below, the calling thread runs them) and the most poses per chunk
#: of a thread: chunks are handed to whichever thread is free, so a core busy with other work slows its
#: share only.
THREADS_FROM = 1 << 16
CHUNK = 1 << 15


def envelope_kernel(poses, legc, terms, check, values, codes, bad, workers=None) -> int:
    """Maxima of the linear model over the budget's box at every pose (compiled); returns the poses refused.

    poses : (N, 3) x mm, y mm, phi deg. legc : (16, 3) :func:`leg_constants` (with the
    limits); terms : (T, 8) :func:`term_table`. check : test the limits (else only
    non-finite poses are refused).
    values : (4, N) out, position mm, |dphi| deg, |dx| mm, |dy| mm.
    codes : (4, N) int16 out, the end of each generator at each maximum as the bits of
    :func:`zonotope_maxima` (legs 1-3, then the G terms of all legs, leg -1; see :func:`generator_signs`).
    bad : (N,) uint16 out, bit ``3 * reason + leg`` set for each refusal (see REASONS), or
    NONFINITE for a pose holding NaN or infinity (whatever ``check``).
    workers : threads for large batches (default: the cores); every pose's numbers are the same.
    """
    N = poses.shape[0]
    if N < THREADS_FROM or workers == 1:
        return _range(0, N, poses, legc, terms, check, values, codes, bad)
    args = (poses, legc, terms, check, values, codes, bad)
    workers = workers or cores()
    chunk = min(CHUNK, -(-N // workers))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return sum(pool.map(lambda a: check_stop() or _range(a, min(N, a + chunk), *args), range(0, N, chunk)))


@njit(nogil=True, cache=True, error_model="numpy")
def _range(start, stop, poses, legc, terms, check, values, codes, bad):
    """The envelope at poses ``start:stop``, block by block, with scratch rows allocated once; the poses refused.

    Each quantity of a block is a row of BLOCK values in one float array (few
    allocations: a small call pays for each), so every step is a loop over a row
    that vectorises.
    """
    G = 0
    for k in range(terms.shape[0]):
        G += terms[k, 1] < 0
    B = BLOCK
    n_legs = 3 * _LEG_ROWS
    f = np.empty((4 + 9 + n_legs + 9 + 6 + 3 * G) * B)
    cs = f[:4 * B]                          # rows _COS_PHI, _SIN_PHI, _X, _Y
    A = f[4 * B:13 * B]                     # A[leg, column] in row 3 leg + column
    legs = f[13 * B:(13 + n_legs) * B]      # per leg, rows _B, _D, _H + q, _COS_OMEGA, _SIN_OMEGA (_leg_row)
    k0 = 13 + n_legs
    Ai = f[k0 * B:(k0 + 9) * B]             # A^-1[row, column] in row 3 row + column
    um = f[(k0 + 9) * B:(k0 + 12) * B].reshape((3, B))    # centre and half-width of u on the legs
    uh = f[(k0 + 12) * B:(k0 + 15) * B].reshape((3, B))
    ext = f[(k0 + 15) * B:].reshape((G, 3, B))            # further generators: terms of all legs
    zs = zonotope_scratch(3 + G, B)
    refused = 0
    for b0 in range(start, stop, BLOCK):
        b1 = min(stop, b0 + BLOCK)
        _block(b0, b1, poses, legc, terms, check, values, codes, bad, cs, A, legs, Ai, um, uh, ext, zs)
        for j in range(b0, b1):
            refused += bad[j] != 0
            values[1, j] *= RAD2DEG
    return refused


@njit(cache=True, error_model="numpy")
def _block(start, stop, poses, legc, terms, check, values, codes, bad, cs, A, legs, Ai, um, uh, ext, zs):
    """The envelope at poses ``start:stop`` (at most BLOCK), one step at a time over all of them.

    The block's maxima (|dphi| in rad) and codes (:func:`zonotope_maxima`) go to columns
    ``start:stop`` of ``values`` and ``codes``; its refusals to ``bad[start:stop]``. The
    formulas are those of :mod:`~prp3mc.kinematics.formulas`, on scalars.
    """
    m, B = stop - start, BLOCK
    phi_deg, cp, sp = math.nan, 1.0, 0.0
    for j in range(m):
        if poses[start + j, 2] != phi_deg:  # a grid keeps phi: its cosine and sine once
            phi_deg = poses[start + j, 2]
            cp, sp = math.cos(phi_deg * (math.pi / 180.0)), math.sin(phi_deg * (math.pi / 180.0))
        cs[_row(_COS_PHI) + j], cs[_row(_SIN_PHI) + j] = cp, sp
        cs[_row(_X) + j], cs[_row(_Y) + j] = poses[start + j, 0], poses[start + j, 1]
    for i in literal_unroll((0, 1, 2)):  # constant offsets in every loop below
        ci, si, cj, sj = legc[0, i], legc[1, i], legc[2, i], legc[3, i]
        c4, c5, c6, c7, c8, c9 = legc[4, i], legc[5, i], legc[6, i], legc[7, i], legc[8, i], legc[9, i]
        a, c, e = legc[10, i], legc[11, i], legc[12, i]
        ra = _row(3 * i)
        for j in range(m):
            cp, sp = cs[_row(_COS_PHI) + j], cs[_row(_SIN_PHI) + j]
            ck, sk = turn(c4, c5, cp, sp)
            cl, sl = turn(c6, c7, cp, sp)
            cm, sm = turn(c8, c9, cp, sp)
            ox, oy = offset_vector(a, c, e, ci, si, ck, sk, cm, sm)
            b, d = leg_ik(cs[_row(_X) + j] - ox, cs[_row(_Y) + j] - oy, cj, sj, cl, sl)
            A[ra + j], A[ra + B + j], A[ra + 2 * B + j] = a_row(c, d, e, ck, sk, cl, sl, cm, sm)
            legs[_leg_row(i, _B) + j], legs[_leg_row(i, _D) + j] = b, d
            (legs[_leg_row(i, _H) + j], legs[_leg_row(i, _H + 1) + j], legs[_leg_row(i, _H + 2) + j],
             legs[_leg_row(i, _H + 3) + j], legs[_leg_row(i, _H + 4) + j], legs[_leg_row(i, _H + 5) + j],
             legs[_leg_row(i, _H + 6) + j], legs[_leg_row(i, _H + 7) + j], legs[_leg_row(i, _H + 8) + j],
             legs[_leg_row(i, _H + 9) + j]) = h_row(a, b, c, d, e, ci, si, cj, sj, ck, sk, cl, sl, cm, sm)
            legs[_leg_row(i, _COS_OMEGA) + j], legs[_leg_row(i, _SIN_OMEGA) + j] = -sl, cl
    for j in range(m):  # A^-1 by cofactors
        m00, m01, m02, m10, m11, m12, m20, m21, m22, det = adjugate3(
            A[j], A[B + j], A[2 * B + j], A[3 * B + j], A[4 * B + j], A[5 * B + j],
            A[6 * B + j], A[7 * B + j], A[8 * B + j])
        inv_det = 1.0 / det
        Ai[j], Ai[3 * B + j], Ai[6 * B + j] = m00 * inv_det, m10 * inv_det, m20 * inv_det
        Ai[B + j], Ai[4 * B + j], Ai[7 * B + j] = m01 * inv_det, m11 * inv_det, m21 * inv_det
        Ai[2 * B + j], Ai[5 * B + j], Ai[8 * B + j] = m02 * inv_det, m12 * inv_det, m22 * inv_det
    if check:
        for j in range(m):
            cond = 0.0
            for rr in literal_unroll((0, 1, 2)):
                col2 = A[rr * B + j] ** 2 + A[(3 + rr) * B + j] ** 2 + A[(6 + rr) * B + j] ** 2
                cond += col2 * (Ai[3 * rr * B + j] ** 2 + Ai[(3 * rr + 1) * B + j] ** 2 + Ai[(3 * rr + 2) * B + j] ** 2)
            cond = math.sqrt(3.0 * cond)
            word = 0
            for i in literal_unroll((0, 1, 2)):
                b, d = legs[_leg_row(i, _B) + j], legs[_leg_row(i, _D) + j]
                word |= (b < legc[13, i]) << i
                word |= (b > legc[14, i]) << (3 + i)
                word |= (not d > 0) << (6 + i)
                word |= (not abs(legs[_leg_row(i, _H + _TRANSMISSION) + j]) >= legc[15, 0]) << (9 + i)
                word |= (not cond <= legc[15, 1]) << (12 + i)
            bad[start + j] = word | _nonfinite(cs, j)
    else:
        for j in range(m):
            bad[start + j] = _nonfinite(cs, j)
    um[:] = 0.0
    uh[:] = 0.0
    g = 0
    for k in range(terms.shape[0]):
        fam, i, un, mode = int(terms[k, 0]), int(terms[k, 1]), terms[k, 2], terms[k, 3]
        lo, hi, zlo, zhi = terms[k, 4], terms[k, 5], terms[k, 6], terms[k, 7]
        if i < 0:  # a term of every leg: a further generator, w_l = h_l unit (b_l) on leg l
            mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            for l in range(3):
                hf = legs[_leg_row(l, _H + fam):_leg_row(l, _H + fam) + m]
                bl = legs[_leg_row(l, _B):_leg_row(l, _B) + m]
                mid_l, gen = um[l, :m], ext[g, l, :m]
                for j in range(m):
                    w = hf[j] * un * _slider_factor(mode, bl[j], zlo, zhi)
                    mid_l[j] += w * mid
                    gen[j] = w * half
            g += 1
            continue
        mid_i, half_i = um[i, :m], uh[i, :m]
        hf = legs[_leg_row(i, _H + fam):_leg_row(i, _H + fam) + m]
        bi = legs[_leg_row(i, _B):_leg_row(i, _B) + m]
        if fam == _RHO and zhi != math.inf:  # part of a circle: the interval depends on omega
            for j in range(m):
                omega = math.atan2(legs[_leg_row(i, _SIN_OMEGA) + j], legs[_leg_row(i, _COS_OMEGA) + j])
                cmin, _, cmax, _ = cos_range(zlo - omega, zhi - omega)
                c_lo = (hi if cmin <= 0 else lo) * cmin  # the term rho cos(zeta - omega)'s interval
                c_hi = (hi if cmax >= 0 else lo) * cmax
                scale = hf[j] * un
                mid_i[j] += scale * (0.5 * (c_lo + c_hi))
                half_i[j] += abs(scale) * (0.5 * (c_hi - c_lo))
            continue
        if fam == _RHO:
            lo, hi = -hi, hi
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        for j in range(m):
            scale = hf[j] * un * _slider_factor(mode, bi[j], zlo, zhi)
            mid_i[j] += scale * mid
            half_i[j] += abs(scale) * half
    zonotope_maxima(Ai.reshape((3, 3, B)), um, uh, ext, values, codes, start, m, zs)
