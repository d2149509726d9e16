"""Compiled kernels of the streamed Monte Carlo (numba, cached on disk).

One call of :func:`scan_block` evaluates the position-error norm and |dphi|
of every pose of a chunk on one block of samples (float32, in cache-sized
tiles) and folds them into the streaming summaries: per-segment sums of the
norm, exceedance counts, maxima, and, for each selection window
``[lo, hi)``, the count below it, the values inside it (up to a capacity)
and a histogram of the values beyond the capacity over the window's sub-bin edges. Kernels
release the GIL so that sample blocks run in parallel threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pose_values", "scan_block", "feature_key", "SUB_BINS", "TILE"]

#: Sub-bins of a selection window, to narrow it when its values overflow the buffer.
SUB_BINS = 64
#: Samples per tile: a tile of features (F x TILE float32) stays in L2 while every pose reads it.
TILE = 4096


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


def feature_key(n_features: int) -> tuple:
    """The ``nf`` argument of the kernels for ``n_features`` features."""
    return (0,) * n_features


@njit(nogil=True, cache=True, fastmath=True)
def _sum64(v, a, b):
    """Sum of v[a:b] in float64 (vectorised; the order is fixed by the compiled code)."""
    acc = 0.0
    for s in range(a, b):
        acc += np.float64(v[s])
    return acc


@njit(nogil=True, cache=True, fastmath=True)
def _max32(v):
    m = np.float32(0.0)
    for s in range(v.size):
        x = v[s]
        m = x if x > m else m
    return m


@njit(nogil=True, cache=True)
def _mark_windows(v, lo, hi, nw, below, wid):
    """Count the values below each window; ``wid``: the window holding each value, or -1.

    Windows are disjoint, so a value lies in one window at most.
    """
    wid[:v.size] = -1
    for w in range(nw):
        a, h = lo[w], hi[w]
        k = 0
        for s in range(v.size):
            x = v[s]
            k += x < a
            wid[s] = w if (x >= a) & (x < h) else wid[s]
        below[w] += k


@njit(nogil=True, cache=True)
def _count_above(v, t):
    k = 0
    for s in range(v.size):
        k += v[s] > t
    return k


@njit(nogil=True, cache=True)
def scan_block(FT, b, C, nf, seg_lo, seg_hi, tol, main, lo, hi, nwin, edges, off, cap,
               below, inside, sub, buf, vmax, possum, exceed):
    """Fold one block of samples into the summaries of a chunk of poses.

    Parameters
    ----------
    FT : (nt, F, T) float32
        Features of the block's samples in tiles of T samples (the last one
        padded), so that a tile stays in cache while every pose reads it.
    b : int
        Samples in the block.
    C : (P, 3, F) float32
        Feature coefficients of the chunk's poses.
    nf : tuple
        :func:`feature_key` of F.
    seg_lo, seg_hi : (S,) int64
        Segments of the block (sample bounds within the block) for the sums.
    tol : float32
        Exceedance threshold of the norm (mm); negative: not counted.
    main : bool
        First pass: also sums, exceedances and maxima.
    lo, hi : (P, 2, W) float32
        Disjoint selection windows per pose and output (0 norm, 1 |dphi|), W < 128.
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
    exceed : (P,) int64, accumulated when ``main``
    """
    P, nt, T = C.shape[0], FT.shape[0], FT.shape[2]
    pos_t, phi_t = np.empty(T, np.float32), np.empty(T, np.float32)
    wid = np.empty(T, np.int8)
    idx = np.empty(T, np.int32)
    for t in range(nt):
        t0 = t * T
        m = min(T, b - t0)
        for p in range(P):
            pos, phi = pos_t[:m], phi_t[:m]
            pose_values(FT[t], C[p], pos, phi, nf)
            if main:
                for k in range(seg_lo.size):
                    a, z = max(seg_lo[k], t0) - t0, min(seg_hi[k], t0 + m) - t0
                    if a < z:
                        possum[p, k] += _sum64(pos, a, z)
                if tol >= 0:
                    exceed[p] += _count_above(pos, tol)
                vmax[p, 0] = max(vmax[p, 0], _max32(pos))
                vmax[p, 1] = max(vmax[p, 1], _max32(phi))
            for o in range(2):
                v, nw = pos if o == 0 else phi, nwin[p, o]
                _mark_windows(v, lo[p, o], hi[p, o], nw, below[p, o], wid)
                k = 0
                for s in range(m):  # indices of the values inside a window, without branches
                    idx[k] = s
                    k += wid[s] >= 0
                for i in range(k):
                    s = idx[i]
                    w, x = wid[s], v[s]
                    n_in = inside[p, o, w]
                    if n_in < cap[p, o, w]:
                        buf[off[p, o, w] + n_in] = x
                    else:  # overflow: histogram it (the kept values are histogrammed afterwards)
                        sub[p, o, w, np.searchsorted(edges[p, o, w], x, side="right") - 1] += 1
                    inside[p, o, w] = n_in + 1
