"""Least squares of every set of systematic effects at one covariance state: best subsets and alias sets.

At fixed spread factors and repeatable fraction the systematic values are
linear least squares in whitened coordinates. Projecting the nuisances out
and forming the Gram matrix ``K = A'A`` and ``b = A'z`` of the candidates
once, the log-likelihood gain of any set ``S`` over the nuisance-only model
is ``b_S' K_SS^-1 b_S / 2``, so whole families of sets are compared without
refitting: every set of up to :data:`EXHAUSTIVE` effects exhaustively, larger
sets by exchange moves (swap one member for one outsider while that
improves the fit). A cyclic screw error has two columns: a set's gain has as
many degrees of freedom as it has columns, and is put on the scale of one
per effect (:func:`~prp3mc.measurement.estimation.likelihood.chi2_equivalent`), so sets of as
many effects compare at their p-values.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from ..estimation.likelihood import Engine, Fit, chi2_equivalent

__all__ = ["Gram", "EXHAUSTIVE"]

#: Largest set size searched exhaustively.
EXHAUSTIVE = 3
_SINGULAR = 1e-8       # determinant of a set's signature correlations below which it is degenerate


class Gram:
    """Gains of sets of systematic candidates at the covariance of ``fit`` (its spread factors, r, nuisances).

    Attributes
    ----------
    eligible : ndarray of int
        Candidates (indices into ``engine.systematic``) that the nuisances leave testable.
    """

    def __init__(self, engine: Engine, fit: Fit):
        z0, X = engine.whitened(fit, (), fit.nuis)
        A = engine.whitened_candidates(fit)
        if X.shape[1]:
            Q, _ = np.linalg.qr(X)
            A, z0 = A - Q @ (Q.T @ A), z0 - Q @ (Q.T @ z0)
        self.eligible = np.array([j for j, e in enumerate(engine.systematic) if e.name not in engine.confounded],
                                 dtype=int)
        self.K, self.b = A.T @ A, A.T @ z0
        self.lower = engine.lower
        width = np.array([len(c) for c in engine.blocks], dtype=int)
        self._width = width
        #: columns of each candidate, padded with -1 to the widest
        self._cols = np.full((width.size, max(width, default=1)), -1, dtype=int)
        for j, cols in enumerate(engine.blocks):
            self._cols[j, :cols.size] = cols

    def gains(self, sets: np.ndarray) -> np.ndarray:
        """Twice the log-likelihood gain of each set (rows of ``sets``, shape (N, k)) on the scale of k degrees
        of freedom; -inf if not admissible.

        A set is not admissible when its signatures are (nearly) collinear or
        a member fits below its least value (a backlash's h >= 0: ``engine.lower``).
        """
        sets = np.asarray(sets, dtype=int)
        if sets.shape[1] == 0:
            return np.zeros(sets.shape[0])
        width = self._width[sets].sum(axis=1)
        out = np.empty(sets.shape[0])
        for w in np.unique(width):                       # sets with a cyclic error have more columns than members
            rows = width == w
            padded = self._cols[sets[rows]].reshape(int(rows.sum()), -1)
            g = self._column_gains(padded[padded >= 0].reshape(padded.shape[0], w))
            if w > sets.shape[1]:
                g = np.where(np.isfinite(g), chi2_equivalent(np.where(np.isfinite(g), g, 0.0), w, sets.shape[1]),
                             -np.inf)
            out[rows] = g
        return out

    def _column_gains(self, sets: np.ndarray) -> np.ndarray:
        """Twice the log-likelihood gain of each set of signature columns (N, k); -inf if not admissible."""
        Ks = self.K[sets[:, :, None], sets[:, None, :]]
        bs = self.b[sets]
        d = np.sqrt(np.diagonal(Ks, axis1=1, axis2=2))
        ok = np.all(d > 0, axis=1)
        d = np.where(d > 0, d, 1.0)
        ok &= np.linalg.det(Ks / (d[:, :, None] * d[:, None, :])) > _SINGULAR
        Ks = np.where(ok[:, None, None], Ks, np.eye(sets.shape[1]))
        theta = np.linalg.solve(Ks, bs[..., None])[..., 0]
        gain = np.sum(bs * theta, axis=1)
        ok &= ~np.any(theta < self.lower[sets], axis=1)
        return np.where(ok, gain, -np.inf)

    def gain(self, S) -> float:
        """Twice the log-likelihood gain of the set ``S`` (indices)."""
        return float(self.gains(np.array([sorted(S)], dtype=int).reshape(1, -1))[0])

    def all_sets(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Every admissible set of ``k`` eligible candidates and its gain, best first (k <= EXHAUSTIVE)."""
        sets = np.array(list(combinations(self.eligible, k)), dtype=int).reshape(-1, k)
        g = self.gains(sets)
        order = np.argsort(-g)
        keep = np.isfinite(g[order])
        return sets[order][keep], g[order][keep]

    def best(self, S) -> tuple[tuple, float]:
        """The best set of the size of ``S``: exhaustive up to :data:`EXHAUSTIVE`, else exchange moves from ``S``."""
        k = len(S)
        if k == 0:
            return (), 0.0
        if k <= EXHAUSTIVE:
            sets, g = self.all_sets(k)
            if len(sets) and g[0] > self.gain(S):
                return tuple(int(j) for j in sets[0]), float(g[0])
            return tuple(S), self.gain(S)
        S, current = list(S), self.gain(S)
        improved = True
        while improved:
            improved = False
            for pos in range(k):
                outside = [j for j in self.eligible if j not in S]
                trials = np.array([sorted(S[:pos] + [j] + S[pos + 1:]) for j in outside], dtype=int)
                g = self.gains(trials)
                if len(g) and g.max() > current + 1e-9:
                    S, current, improved = list(trials[int(np.argmax(g))]), float(g.max()), True
        return tuple(S), current

    def alternatives(self, S, within: float) -> list[tuple]:
        """Other sets of the size of ``S`` whose gain is within ``within`` of ``S``'s, best first.

        Exhaustive up to :data:`EXHAUSTIVE` members; beyond, the single swaps.
        """
        S = tuple(sorted(S))
        top = self.gain(S)
        if len(S) <= EXHAUSTIVE:
            sets, g = self.all_sets(len(S))
        else:
            sets = np.array([sorted(S[:p] + (j,) + S[p + 1:]) for p in range(len(S))
                             for j in self.eligible if j not in S], dtype=int)
            g = self.gains(sets)
        close = [tuple(int(j) for j in s) for s, v in zip(sets, g) if v >= top - within]
        return [s for s in close if s != S]
