"""The alias-free lattice of each channel of the pose error, at a batch of poses (numpy).

A channel is dphi (d = 1), the position (dx, dy) (d = 2) or both (d = 3),
with the region D: ``|dphi|`` <= z, the disc ``|(dx, dy)|`` <= z, or their cylinder.
Its lattice (:mod:`.series`) is rectangular in ``nu_j = m_j . w`` over a
basis of d directions m_j: the single direction 1 for dphi; two legs'
directions (the position rows of A^-1's columns) for the position, the pair
closest to orthogonal among the legs whose terms' envelopes decay fast enough
(power above 1 with the transform's share); the three legs (the columns of
A^-1) for both. A term of a basis leg j has ``c_t . w = kappa_t nu_j``;
every other term (the third leg, thermal) is *mixed*: ``c_t . w = mu_t . nu``
with ``mu_t = V^-T c_t``.

The periods: in the coordinates w of ``y = sum_j w_j m_j`` (w = V^-T y), the
support of Y (the box of its terms' intervals, shifted by the known shift)
spans [lo_j, hi_j] and D spans [-e_j, e_j]; shifting by Q_j m_j misses D as
soon as ``Q_j >= e_j + max(-lo_j, hi_j)``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ["Channel", "channel", "leg_powers", "support_max", "LEVELS", "MIXED_LEG"]

#: Probabilities of the reported quantiles: p99.73 and p99.9937 (3 and 4 sd of a normal law, two-sided:
#: Cpk 1 and 1.33) and p99.9999 (1 ppm).
LEVELS = (0.9973, 0.999937, 0.999999)
_ROWS = {"phi": [2], "position": [0, 1], "both": [0, 1, 2]}
#: Group code of the position's third leg (off the basis: its terms' arguments mix nu_1 and nu_2). The other
#: codes: 0..d-1 a basis leg, -1 a term of all legs (thermal), -2 a term absent from the channel.
MIXED_LEG = 3
_MARGIN = 1.0 + 1e-12


@dataclass(frozen=True)
class Channel:
    """A channel's lattice at N poses, as :func:`~.series.batch_series` takes it (arrays padded to 3)."""

    d: int
    ok: np.ndarray          # (N,) a basis of legs with a density exists
    grp: np.ndarray         # (N, T) int
    mu: np.ndarray          # (N, T, 3)
    snu: np.ndarray         # (N, 3)
    Q: np.ndarray           # (N, 3)
    Vinv: np.ndarray        # (N, 3, 3)
    mnorm: np.ndarray       # (N, 3)
    ab: np.ndarray          # (N, 3) the position's third leg: m_3 = alpha m_1 + beta m_2, and |m_3|
    lam: np.ndarray         # (N,)
    zmax: np.ndarray        # (N,) largest |Y| over the (cut) support
    alias: np.ndarray       # (N,) mass of the normal laws beyond their cut that acts on the channel


def leg_powers(table, c, legs, share: float) -> np.ndarray:
    """Asymptotic decay power of each leg's envelope product with the transform's share, (N, 3)."""
    present = table.random[None, :] & (np.abs(c).max(axis=1) > 0)               # (N, T)
    out = np.zeros((c.shape[0], 3))
    for i in range(3):
        on = present & (legs == i)[None, :]
        out[:, i] = np.where(on, table.power[None, :], 0.0).sum(axis=1) + share
    return out


def _segments_max(s, dirs, lo, hi) -> np.ndarray:
    """Largest ``|s + sum_g dirs_g x_g|`` over x_g in [lo_g, hi_g]: at a corner. s (N, k), dirs (N, G, k), lo/hi (N, G)."""
    G = dirs.shape[1]
    best = np.zeros(s.shape[0])
    for corner in itertools.product((0, 1), repeat=G):
        x = np.where(np.array(corner, dtype=bool)[None, :], hi, lo)
        v = s + np.einsum("ngk,ng->nk", dirs, x)
        best = np.maximum(best, np.sqrt((v * v).sum(-1)))
    return best


def channel(which: str, columns: np.ndarray, Ainv: np.ndarray, legs, table, z1, z2=None, alias_one: float = 0.0
            ) -> Channel:
    """The lattice of channel ``which`` (``phi``, ``position``, ``both``) at N poses.

    Parameters
    ----------
    columns : ndarray (N, 3, T)
        Pose error (dx mm, dy mm, dphi rad) per unit of each term.
    Ainv : ndarray (N, 3, 3)
    legs : sequence of int (T,)
        Each term's leg (-1: all legs).
    table : TermTable
    z1 : ndarray (N,)
        Largest radius (mm) or half-width (rad) of D the series must serve.
    z2 : ndarray (N,), optional
        The cylinder's half-height (rad), ``both`` only.
    alias_one : float
        The mass beyond the cut of one normal law.
    """
    rows = _ROWS[which]
    d = len(rows)
    legs = np.asarray(legs)
    N, _, T = columns.shape
    c = columns[:, rows, :]                                          # (N, d, T)
    s = np.einsum("ndt,t->nd", c, table.constant)                   # known shift
    random = table.random
    nonzero = random[None, :] & (np.abs(c).max(axis=1) > 0)          # (N, T)
    alias = alias_one * (nonzero & table.normal[None, :]).sum(axis=1)
    V = np.zeros((N, 3, 3))
    grp = np.full((N, T), -2, dtype=np.int64)
    if d == 1:
        ok = nonzero.any(axis=1)
        V[:] = np.eye(3)
        grp[nonzero] = 0
    elif d == 2:
        m = np.moveaxis(Ainv[:, :2, :], 1, 2)                          # (N, leg, 2): each leg's direction
        valid = leg_powers(table, c, legs, 0.75) > 1.0 + 1e-9
        pairs = ((0, 1), (0, 2), (1, 2))
        score = np.zeros((N, 3))
        for k, (a, b) in enumerate(pairs):
            cross = np.abs(m[:, a, 0] * m[:, b, 1] - m[:, a, 1] * m[:, b, 0])
            sin = cross / (np.linalg.norm(m[:, a], axis=-1) * np.linalg.norm(m[:, b], axis=-1))
            score[:, k] = np.where(valid[:, a] & valid[:, b] & (sin > 1e-6), sin, 0.0)
        best = score.argmax(axis=1)
        ok = score.max(axis=1) > 0
        pair = np.array(pairs)[best]                                     # (N, 2)
        V[:, 0, :2] = m[np.arange(N), pair[:, 0]]
        V[:, 1, :2] = m[np.arange(N), pair[:, 1]]
        V[:, 2, 2] = 1.0
        third = 3 - pair.sum(axis=1)                                    # the leg off the basis
        grp[nonzero] = -1
        grp[nonzero & (legs[None, :] == third[:, None])] = MIXED_LEG
        for j in range(2):
            on = nonzero & (legs[None, :] == pair[:, j, None])
            grp[on] = j
    else:
        valid = leg_powers(table, c, legs, 1.0 / 3.0) > 1.0 + 1e-9
        ok = valid.all(axis=1)
        V[:] = np.swapaxes(Ainv, 1, 2)                                 # rows: the legs' directions
        grp[nonzero] = -1
        for j in range(3):
            grp[nonzero & (legs[None, :] == j)] = j
    V[~ok] = np.eye(3)
    R = np.swapaxes(np.linalg.inv(V), 1, 2)[:, :d, :d]                 # V^-T: w = R y, (c . w) = (R c) . nu
    Vinv = np.zeros((N, 3, 3))
    Vinv[:, :d, :d] = np.linalg.inv(V)[:, :d, :d]
    mu = np.zeros((N, T, 3))
    mu[:, :, :d] = np.einsum("nij,njt->nti", R, c)
    mu[grp == -2] = 0.0
    snu = np.zeros((N, 3))
    snu[:, :d] = np.einsum("nij,nj->ni", R, s)
    ab = np.ones((N, 3))
    if d == 2:
        m3 = m[np.arange(N), third]
        ab[:, :2] = np.einsum("nij,nj->ni", R, m3)
        ab[:, 2] = np.linalg.norm(m3, axis=-1)
    # the support's box and D's in w, and the periods
    lo, hi = np.where(random, table.lo, 0.0), np.where(random, table.hi, 0.0)
    a, b = mu[:, :, :d] * lo[None, :, None], mu[:, :, :d] * hi[None, :, None]
    wlo = snu[:, :d] + np.minimum(a, b).sum(axis=1)
    whi = snu[:, :d] + np.maximum(a, b).sum(axis=1)
    if d == 3:
        ext = z1[:, None] * np.linalg.norm(R[:, :, :2], axis=-1) + z2[:, None] * np.abs(R[:, :, 2])
    else:
        ext = z1[:, None] * np.linalg.norm(R, axis=-1)
    Q = np.ones((N, 3))
    Q[:, :d] = (ext + np.maximum(-wlo, whi)) * _MARGIN
    mnorm = np.ones((N, 3))
    mnorm[:, :d] = np.linalg.norm(V[:, :d, :d], axis=-1)
    lam = np.prod(Q[:, :d], axis=1) * np.abs(np.linalg.det(V[:, :d, :d]))
    zmax = support_max(d, c, s, legs, table)
    return Channel(d=d, ok=ok, grp=grp, mu=mu, snu=snu, Q=Q, Vinv=Vinv, mnorm=mnorm, ab=ab, lam=lam, zmax=zmax,
                   alias=alias)


def support_max(d: int, c: np.ndarray, s: np.ndarray, legs: np.ndarray, table) -> np.ndarray:
    """Largest ``|Y|`` over the support (normal laws cut), (N,), of the channel ``Y = s + c X`` (c (N, d, T),
    s (N, d); NaN for d = 3): the terms of a leg are parallel, so their sum is one segment; with the terms of
    all legs (thermal) the maximum is at one of a few corners."""
    random = table.random
    if d == 3:
        return np.full(c.shape[0], np.nan)
    lo, hi = np.where(random, table.lo, 0.0), np.where(random, table.hi, 0.0)
    if d == 1:
        a, b = c[:, 0, :] * lo, c[:, 0, :] * hi
        return np.maximum(np.abs(s[:, 0] + np.minimum(a, b).sum(-1)), np.abs(s[:, 0] + np.maximum(a, b).sum(-1)))
    dirs, seg_lo, seg_hi = [], [], []
    for i in range(3):
        on = random & (legs == i)
        if not on.any():
            continue
        ref = c[:, :, on]                                               # (N, 2, k), parallel columns
        axis = ref[:, :, np.argmax(np.abs(ref).max(axis=(0, 1)))]      # (N, 2)
        norm2 = np.maximum((axis * axis).sum(-1), 1e-300)
        w = np.einsum("njk,nj->nk", ref, axis) / norm2[:, None]          # c_t = w_t axis
        a, b = w * lo[on], w * hi[on]
        dirs.append(axis)
        seg_lo.append(np.minimum(a, b).sum(-1))
        seg_hi.append(np.maximum(a, b).sum(-1))
    for t in np.flatnonzero(random & (legs < 0)):
        dirs.append(c[:, :, t])
        seg_lo.append(np.full(c.shape[0], lo[t]))
        seg_hi.append(np.full(c.shape[0], hi[t]))
    if not dirs:
        return np.sqrt((s * s).sum(-1))
    return _segments_max(s, np.stack(dirs, axis=1), np.stack(seg_lo, axis=1), np.stack(seg_hi, axis=1))
