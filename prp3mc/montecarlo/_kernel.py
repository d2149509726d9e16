"""Compiled kernels of the streamed Monte Carlo (numba, cached on disk).

One call of :func:`scan_blocks` is one pass of one thread over a range of
sample blocks for a chunk of poses, tile by tile (:data:`TILE` samples, so a
tile stays in cache while every pose reads it). A tile's features are drawn
in place (:func:`~prp3mc.montecarlo._sampler.draw_features`) or copied from
features the caller sampled through numpy. On the first pass their sums per
segment (about the exact mean) are added up. Then every pose's
position-error norm and |dphi| are evaluated in float32 and folded into the
streaming summaries: per-segment sums of the norm, exceedance counts,
maxima, and, for each selection window ``[lo, hi)``, the count below it, the
values inside it (up to a capacity) and a histogram over the window's
sub-bin edges of the values beyond the capacity. Kernels release the GIL so
that ranges of blocks run in parallel threads.

Why kept rather than numpy products and ``np.percentile``: 6.2-10.6x the numpy
code on 441 poses x 2^20 samples, 11.6x at one pose x 2^24, and 1e8 samples
in 0.28 GB instead of 21.6 GB (``benchmarks/bench_montecarlo.py``, 2 shared cores).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numba.cpython.unsafe.numbers import trailing_zeros

from ._sampler import draw_features
from ..model.budget import SAMPLE_BLOCK

__all__ = ["pose_values", "scan_blocks", "feature_key", "padded_features", "SUB_BINS", "TILE"]

#: Sub-bins of a selection window, to narrow it when its values overflow the buffer.
SUB_BINS = 64
#: Samples per tile: a tile of features (F x TILE float32) stays in L2 while every pose reads it.
TILE = 2048


@njit(nogil=True, cache=True, fastmath=True)
def pose_values(FT, c, pos, phi, nf):
    """Position-error norm and |dphi| (float32) of one pose on a block of features.

    FT : (F, >= b) float32 features; c : (3, F) float32 coefficients (dx mm, dy mm,
    dphi rad per feature); pos, phi : (b,) float32 outputs; nf : a tuple of F
    zeros (:func:`feature_key`): its length is a compile-time constant, so that
    the loop over the features unrolls and the loop over samples vectorises.
    """
    nf = len(nf)
    for s in range(pos.size):
        dx = np.float32(0.0)
        dy = np.float32(0.0)
        dz = np.float32(0.0)
        for f in range(nf):
            v = FT[f, s]
            dx += c[0, f] * v
            dy += c[1, f] * v
            dz += c[2, f] * v
        pos[s] = np.sqrt(dx * dx + dy * dy)
        phi[s] = abs(dz)


#: Feature counts are rounded up to a multiple of this in the compiled pose values: the added features
#: and their coefficients are zero (the same values, bit for bit), and budgets of 9 to 12 features share
#: one compilation of the kernels (a few seconds each) instead of one each.
FEATURE_GROUP = 4


def padded_features(n_features: int) -> int:
    """Rows of the features (and columns of the coefficients) the kernels read for ``n_features``."""
    return -(-n_features // FEATURE_GROUP) * FEATURE_GROUP


def feature_key(n_features: int) -> tuple:
    """The ``nf`` argument of the kernels for ``n_features`` features (:func:`padded_features` zeros)."""
    return (0,) * padded_features(n_features)


@njit(nogil=True, cache=True, fastmath=True)
def _sum64(v):
    """Sum of v in float64 (vectorised; the order is fixed by the compiled code)."""
    acc = 0.0
    for s in range(v.size):
        acc += np.float64(v[s])
    return acc


@njit(nogil=True, cache=True)
def _max32(v):
    """Largest of the float32 values v >= 0 (compared as integers, which vectorises)."""
    bits = v.view(np.int32)
    top = np.int32(0)
    for s in range(bits.size):
        x = bits[s]
        top = x if x > top else top
    return np.int32(top)


@njit(nogil=True, cache=True)
def _count_above(pos, phi, m, tols, out):
    """Add to ``out`` (3,) the samples with the norm above tols[0], |dphi| above tols[1], and either (a
    negative tolerance: that output is never above)."""
    tp, tf = tols[0], tols[1]
    a = b = c = 0
    for s in range(m):
        over_p = tp >= 0 and pos[s] > tp
        over_f = tf >= 0 and phi[s] > tf
        a += over_p
        b += over_f
        c += over_p or over_f
    out[0] += a
    out[1] += b
    out[2] += c


#: Samples per chunk of the feature sums: the chunk's centred features (F x 256 float64) stay in L1.
_SUM_CHUNK = 256


@njit(nogil=True, cache=True, fastmath=True)
def _pair_sums(x0, x1, y0, y1):
    """Sums of x0 y0, x0 y1, x1 y0, x1 y1 (four dot products sharing their loads)."""
    a00 = a01 = a10 = a11 = 0.0
    for s in range(x0.size):
        u0, u1, v0, v1 = x0[s], x1[s], y0[s], y1[s]
        a00 += u0 * v0
        a01 += u0 * v1
        a10 += u1 * v0
        a11 += u1 * v1
    return a00, a01, a10, a11


@njit(nogil=True, cache=True)
def _moment_sums(F, nF, m, first, shift, seg_start, seg_stop, s0, s1, S1, S2):
    """Add the tile's centred feature sums to the segments it meets.

    F : (nF rounded up to even, T) float64 features of samples ``first`` to
    ``first + m``, centred in place (a padding row is zero); segments ``s0:s1``
    of ``seg_start``/``seg_stop`` (global sample bounds); S1 (S, nF), S2 (S, nF, nF).
    Products are summed in chunks of :data:`_SUM_CHUNK` samples, read from L1,
    two rows by two rows.
    """
    for f in range(nF):
        row, c = F[f, :m], shift[f]
        for s in range(m):
            row[s] -= c
    for j in range(s0, s1):
        a, z = max(seg_start[j], first) - first, min(seg_stop[j], first + m) - first
        for c0 in range(a, z, _SUM_CHUNK):
            c1 = min(z, c0 + _SUM_CHUNK)
            for f in range(nF):
                S1[j, f] += _sum64(F[f, c0:c1])
            for f in range(0, nF, 2):
                for g in range(f, nF, 2):
                    a00, a01, a10, a11 = _pair_sums(F[f, c0:c1], F[f + 1, c0:c1], F[g, c0:c1], F[g + 1, c0:c1])
                    S2[j, f, g] += a00
                    if g + 1 < nF:
                        S2[j, f, g + 1] += a01
                    if f + 1 < nF:
                        S2[j, f + 1, g] += a10
                        if g + 1 < nF:
                            S2[j, f + 1, g + 1] += a11
        for f in range(nF):
            for g in range(f):
                S2[j, f, g] = S2[j, g, f]


@njit(nogil=True, cache=True)
def _windows(v, m, p, o, lo, hi, nwin, edges, off, cap, below, inside, sub, buf, flag):
    """Fold the values v[:m] of pose p, output o into its selection windows (disjoint, by increasing lo).

    ``flag[s]`` becomes 1 + the window holding v[s], or 0; the flagged values
    are then visited eight flags (one 64-bit word) at a time.
    """
    nw = nwin[p, o]
    if nw == 0:
        return
    for w in range(nw):
        a, h = lo[p, o, w], hi[p, o, w]
        k = 0
        tag = np.uint8(w + 1)
        if w == 0:
            for s in range(m):
                x = v[s]
                k += x < a
                flag[s] = tag if (x >= a) & (x < h) else np.uint8(0)
        else:
            for s in range(m):
                x = v[s]
                k += x < a
                flag[s] = tag if (x >= a) & (x < h) else flag[s]
        below[p, o, w] += k
    flag[m:] = 0
    words = flag.view(np.uint64)
    for q in range((m + 7) // 8):
        word = words[q]
        while word:  # the set bytes of the word, lowest first
            s = 8 * q + (trailing_zeros(word) >> 3)
            word &= ~(np.uint64(0xFF) << np.uint64(8 * (s - 8 * q)))
            w = flag[s] - 1
            x = v[s]
            n_in = inside[p, o, w]
            if n_in < cap[p, o, w]:
                buf[off[p, o, w] + n_in] = x
            else:  # overflow: histogram it (the kept values are histogrammed afterwards)
                sub[p, o, w, np.searchsorted(edges[p, o, w], x, side="right") - 1] += 1
            inside[p, o, w] = n_in + 1


@njit(nogil=True, cache=True)
def _scan_tile(FT, m, first, C, nf, seg_start, seg_stop, s0, s1, tols, main, lo, hi, nwin, edges, off, cap,
               below, inside, sub, buf, vmax, possum, exceed, pos_t, phi_t, flag):
    """Fold one tile (features FT[:, :m] of samples ``first`` to ``first + m``) into every pose's summaries."""
    for p in range(C.shape[0]):
        if not main and nwin[p, 0] == 0 and nwin[p, 1] == 0:
            continue
        pos, phi = pos_t[:m], phi_t[:m]
        pose_values(FT, C[p], pos, phi, nf)
        if main:
            for j in range(s0, s1):
                a, z = max(seg_start[j], first) - first, min(seg_stop[j], first + m) - first
                if a < z:
                    possum[p, j] += _sum64(pos[a:z])
            if tols[0] >= 0 or tols[1] >= 0:
                _count_above(pos, phi, m, tols, exceed[p])
            vmax_bits = vmax[p].view(np.int32)
            vmax_bits[0] = max(vmax_bits[0], _max32(pos))
            vmax_bits[1] = max(vmax_bits[1], _max32(phi))
        _windows(pos_t, m, p, 0, lo, hi, nwin, edges, off, cap, below, inside, sub, buf, flag)
        _windows(phi_t, m, p, 1, lo, hi, nwin, edges, off, cap, below, inside, sub, buf, flag)


@njit(nogil=True, cache=True)
def scan_blocks(k0, k1, n, lanes, consts, codes, params, cdf, values, ops, refs, cidx, chol, Fext, C, nf, shift,
                block_segs,
                seg_start, seg_stop, sums, S1, S2, tols, main, lo, hi, nwin, edges, off, cap,
                below, inside, sub, buf, vmax, possum, exceed):
    """Fold sample blocks ``k0:k1`` into the summaries of a chunk of poses (one pass of one thread).

    Parameters
    ----------
    k0, k1, n : int
        Blocks (of SAMPLE_BLOCK samples) and the run's sample count.
    lanes, consts, codes, params, cdf, values, ops, refs, cidx, chol
        The compiled sampler (:mod:`._sampler`): lane states at sample ``k0 * SAMPLE_BLOCK`` (updated).
    Fext : (b, F) float64
        Features of block k0 sampled by the caller (then k1 = k0 + 1), or an empty array: draw them.
    C : (P, 3, Fp) float32
        Feature coefficients of the chunk's poses, zero beyond the F features
        (Fp = :func:`padded_features` of F).
    nf : tuple
        :func:`feature_key` of F.
    shift : (F,) float64
        Exact feature means: the sums are about them (its size is F).
    block_segs, seg_start, seg_stop : int64
        Segments of block k: ``block_segs[k]:block_segs[k + 1]``, with global sample bounds.
    sums : bool
        Add the feature sums S1 (S, F) and S2 (S, F, F) per segment.
    tols : (2,) float32
        Exceedance thresholds of the norm (mm) and of |dphi| (rad); negative: not counted.
    main : bool
        First pass: also sums of the norm, exceedances and maxima.
    lo, hi : (P, 2, W) float32
        Disjoint selection windows per pose and output (0 norm, 1 |dphi|), by increasing lo.
    nwin : (P, 2) int64
        Windows in use per pose and output.
    edges : (P, 2, W, SUB_BINS + 1) float32
        Sub-bin edges of each window.
    off, cap : (P, 2, W) int64
        Offset and capacity of each window in ``buf``.
    below, inside : (P, 2, W) int64, accumulated
        Values below the window and inside it.
    sub : (P, 2, W, SUB_BINS) int64, accumulated
        Values inside the window but beyond its capacity, per sub-bin.
    buf : (N,) float32
        Collected values (the first ``cap`` of each window).
    vmax : (P, 2) float32, accumulated
    possum : (P, S) float64, accumulated when ``main``
    exceed : (P, 3) int64, accumulated when ``main``
        Samples above tols[0] (norm), tols[1] (|dphi|), and above either.
    """
    nF, nP, T = shift.size, C.shape[2], TILE
    fused = Fext.shape[0] == 0
    d = codes.size
    U, X = np.empty((d, T)), np.empty((d, T))
    F, FT = np.zeros((nP, T)), np.zeros((nP, T), np.float32)  # rows from nF on stay zero (nP is even)
    pos_t, phi_t = np.empty(T, np.float32), np.empty(T, np.float32)
    flag = np.zeros(T, np.uint8)
    for k in range(k0, k1):
        start = k * SAMPLE_BLOCK
        b = min(n - start, SAMPLE_BLOCK)
        s0, s1 = block_segs[k], block_segs[k + 1]
        for t0 in range(0, b, T):
            m = min(T, b - t0)
            if fused:
                draw_features(lanes, consts, codes, params, cdf, values, ops, refs, cidx, chol, m, U, X, F)
            else:
                for f in range(nF):
                    for s in range(m):
                        F[f, s] = Fext[t0 + s, f]
            for f in range(nF):
                for s in range(m):
                    FT[f, s] = F[f, s]
            if sums:
                _moment_sums(F, nF, m, start + t0, shift, seg_start, seg_stop, s0, s1, S1, S2)
            _scan_tile(FT, m, start + t0, C, nf, seg_start, seg_stop, s0, s1, tols, main, lo, hi, nwin, edges, off,
                       cap, below, inside, sub, buf, vmax, possum, exceed, pos_t, phi_t, flag)
