"""The exact yield of a budget of discrete classes only, by enumeration (numpy).

When every random term of the linear stack-up is a discrete law (classes),
the pose error ``s + sum_t c_t X_t`` takes finitely many values, one per
combination of the terms' atoms, with the product of their probabilities.
It has no density, so the Fourier series of :mod:`.series` does not apply;
but each exceedance is a finite sum, and each quantile an atom of the law.
The only error is floating point: the sum of M products of T weights is
within ``(M + T) eps`` of the true probability (eps the double's unit
roundoff; the weights sum to 1), which is the reported bound.
"""

from __future__ import annotations

import numpy as np

from ..errors import NoExactYieldError
from .characteristic import DISCRETE

__all__ = ["all_discrete", "discrete_yield", "MAX_COMBINATIONS", "ENUMERATION_METHOD"]

#: The most combinations of atoms enumerated (memory: 24 bytes each per pose, poses in chunks).
MAX_COMBINATIONS = 1 << 20
_CHUNK_VALUES = 1 << 22          # combinations x poses held at once
ENUMERATION_METHOD = ("exact enumeration: every random input is a discrete class, so the pose error takes finitely "
                      "many values (one per combination of the classes, with the product of their probabilities); "
                      "each exceedance is their finite sum and each quantile one of them; error bound = floating "
                      "point of that sum ((combinations + terms) x 1.1e-16)")


def all_discrete(table) -> bool:
    """True when the term table has random terms and every one is a discrete law (no density)."""
    random = table.random
    return bool(random.any()) and bool(np.all(table.kind[random] == DISCRETE))


def discrete_yield(C: np.ndarray, table, S: float, Z: float | None, levels: np.ndarray, budget: str) -> dict:
    """Exceedances, quantiles and worst cases of a budget of discrete classes, by enumeration.

    Parameters
    ----------
    C : ndarray (N, 3, T)
        Pose error (dx mm, dy mm, dphi rad) per unit of each term.
    table : TermTable
        Every random term a discrete law (:func:`all_discrete`).
    S : float
        Position spec, mm.
    Z : float or None
        ``|dphi|`` spec, rad.
    levels : ndarray (K,)
        Probabilities of the quantiles (may be empty).
    budget : str
        The budget's name, for the message.

    Returns
    -------
    dict
        ``e_pos, e_phi, e_any`` (N,) (``e_phi`` None without Z), ``bound`` (float), ``q_pos, qe_pos`` (N, K) mm,
        ``q_phi, qe_phi`` (N, K) rad, ``worst_pos`` mm, ``worst_phi`` rad (N,), ``combinations`` (int).

    Raises
    ------
    NoExactYieldError
        More than :data:`MAX_COMBINATIONS` combinations.
    """
    terms = np.flatnonzero(table.random)
    offsets, counts = table.par[terms, 0].astype(np.int64), table.par[terms, 1].astype(np.int64)
    M = int(np.prod(counts, dtype=np.float64))
    if M > MAX_COMBINATIONS:
        raise NoExactYieldError(f"exact yield: budget {budget!r} has only discrete classes (no density) and {M:.3g} "
                          f"combinations of them, more than the {MAX_COMBINATIONS:.3g} enumerated; use Monte Carlo")
    bound = (M + terms.size) * np.finfo(float).eps
    w = np.ones(1)
    for o, k in zip(offsets, counts):
        w = (w[:, None] * table.weights[o:o + k][None, :]).ravel()
    N, K = C.shape[0], levels.size
    out = {name: np.empty(N) for name in ("e_pos", "e_phi", "e_any", "worst_pos", "worst_phi")}
    out |= {name: np.empty((N, K)) for name in ("q_pos", "qe_pos", "q_phi", "qe_phi")}
    shift = C @ table.constant                                                   # (N, 3)
    chunk = max(1, _CHUNK_VALUES // M)
    for a in range(0, N, chunk):
        b = min(N, a + chunk)
        Y = shift[a:b, None, :]
        for t, o, k in zip(terms, offsets, counts):
            step = C[a:b, None, None, :, t] * table.atoms[o:o + k][None, None, :, None]
            Y = (Y[:, :, None, :] + step).reshape(b - a, -1, 3)
        r, az = np.hypot(Y[..., 0], Y[..., 1]), np.abs(Y[..., 2])
        out["e_pos"][a:b] = (r > S) @ w
        out["e_phi"][a:b] = (az > Z) @ w if Z is not None else np.nan
        out["e_any"][a:b] = ((r > S) | (az > Z)) @ w if Z is not None else out["e_pos"][a:b]
        out["worst_pos"][a:b], out["worst_phi"][a:b] = r.max(axis=1), az.max(axis=1)
        for y, q, qe in ((r, "q_pos", "qe_pos"), (az, "q_phi", "qe_phi")):
            out[q][a:b], out[qe][a:b] = _quantiles(y, w, levels, bound)
    out["e_phi"] = None if Z is None else out["e_phi"]
    return out | {"bound": float(bound), "combinations": M}


def _quantiles(y: np.ndarray, w: np.ndarray, levels: np.ndarray, bound: float) -> tuple[np.ndarray, np.ndarray]:
    """Each row's quantiles of the discrete law (values y (n, M), probabilities w (M,)): the least value whose
    cumulative probability reaches the level; their error, the distance to the values where it reaches
    level -/+ bound (the cumulative sums are exact within the bound)."""
    order = np.argsort(y, axis=1, kind="stable")
    ys = np.take_along_axis(y, order, axis=1)
    cw = np.cumsum(w[order], axis=1)
    last = y.shape[1] - 1

    def at(p):
        return np.take_along_axis(ys, np.minimum((cw[:, None, :] < p[None, :, None]).sum(axis=2), last), axis=1)

    q = at(levels)
    return q, np.maximum(q - at(levels - bound), at(levels + bound) - q)
