"""Correlated inputs: a budget's ``[correlation]`` table as a Gaussian copula (SPEC §10).

A budget may give rank (Spearman) correlations between its factors, or
between groups of them named in ``[groups]``::

    [groups]
    bearings = ["rho_1", "rho_2", "rho_3"]

    [correlation]
    bearings = 0.8              # every pair inside the group
    "theta_1,theta_2" = 0.5     # one pair
    "bearings,b_1" = -0.2       # every member of the group with b_1

They are realised by a Gaussian copula over each factor's own law: latent
standard normals Z with correlation matrix R, X_k = F_k^-1(Phi(Z_k)). For a
continuous law the rank correlation of X_i and X_j is that of Z_i and Z_j,
rho_S = (6 / pi) arcsin(r / 2), so the latent correlation of a pair is
r = 2 sin(pi rho_S / 6) (:func:`latent_from_spearman`); a discrete law's ties
make its realised rank correlation smaller in magnitude. The marginal laws
are unchanged.

Contact angles ``zeta_i`` cannot be correlated: an angle on the circle has no
rank order (correlate the clearance size ``rho_i``). Keeping them independent
also keeps the linear model's moments exact: a clearance's features
rho cos zeta and rho sin zeta covary with other features only through rho.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.polynomial.hermite_e import hermegauss
from scipy import integrate, special

from ..errors import BudgetError
from .laws import Discrete, Law, Normal, Triangular, Uniform

__all__ = ["GaussianCopula", "latent_from_spearman", "spearman_from_latent", "parse_correlation", "U_EDGE",
           "pair_covariance"]

#: Uniforms are kept in [U_EDGE, 1 - U_EDGE] on their way through the latent normals, so that
#: unbounded laws stay finite (1 - 2^-53 is the largest double below 1).
U_EDGE = 2.0**-53
_PD_TOL = 1e-10          # smallest eigenvalue of an admissible latent correlation matrix


def latent_from_spearman(rho_s):
    """Latent normal correlation ``r = 2 sin(pi rho_S / 6)`` of a rank (Spearman) correlation."""
    return 2.0 * np.sin(np.pi * np.asarray(rho_s, dtype=float) / 6.0)


def spearman_from_latent(r):
    """Rank correlation ``rho_S = (6 / pi) arcsin(r / 2)`` of a Gaussian copula with correlation ``r``."""
    return 6.0 / np.pi * np.arcsin(np.asarray(r, dtype=float) / 2.0)


@dataclass(frozen=True, slots=True)
class GaussianCopula:
    """The Gaussian copula of the correlated factors of a budget.

    Attributes
    ----------
    index : tuple of int
        Positions of the correlated factors among the budget's factors (increasing).
    names : tuple of str
        Their names.
    spearman : ndarray, shape (k, k)
        Rank correlations (1 on the diagonal, 0 for pairs not given).
    latent : ndarray, shape (k, k)
        Correlation matrix R of the latent normals, ``2 sin(pi spearman / 6)``.
    chol : ndarray, shape (k, k)
        Lower Cholesky factor of ``latent``.
    """

    index: tuple
    names: tuple
    spearman: np.ndarray
    latent: np.ndarray
    chol: np.ndarray

    def correlate(self, u: np.ndarray) -> np.ndarray:
        """Independent uniforms (n, D) made dependent: ``Phi(L Phi^-1(u))`` on the correlated columns.

        The other columns are returned unchanged; the correlated ones are kept
        in [U_EDGE, 1 - U_EDGE].
        """
        out = np.array(u, dtype=float)
        z = special.ndtri(np.clip(out[:, self.index], U_EDGE, 1.0 - U_EDGE))
        out[:, self.index] = np.clip(special.ndtr(z @ self.chol.T), U_EDGE, 1.0 - U_EDGE)
        return out

    def conditional_gains(self, given: np.ndarray) -> np.ndarray:
        """Kriging gains of the latent normals given some of them (Matheron's rule).

        Parameters
        ----------
        given : ndarray of bool, shape (M, k)
            Which latent coordinates are held fixed, per case.

        Returns
        -------
        ndarray, shape (M, k, k)
            ``K`` with ``w + K (z - w)`` distributed as Z given Z_given = z_given
            when w is a fresh draw of Z: K = R[:, g] R[g, g]^-1 on the given
            columns g, zero on the others (so K is the identity on the given rows).
        """
        given = np.asarray(given, dtype=bool)
        P = given[:, None, :] & given[:, :, None]
        eye = np.eye(self.latent.shape[0])
        M = np.where(P, self.latent, eye)                       # R[g, g], padded with the identity
        rhs = np.where(given[:, :, None], self.latent[None].swapaxes(-1, -2), 0.0)   # columns R[g, :]^T
        gains = np.linalg.solve(M, rhs).swapaxes(-1, -2)       # R[:, g] R[g, g]^-1, (M, k, k)
        return np.where(given[:, None, :], gains, 0.0)

    def covariance(self, laws: list) -> np.ndarray:
        """Covariance (D, D) of the factors' values whose laws are ``laws`` (all D factors).

        The diagonal holds each law's variance; a pair of correlated factors
        its covariance under the copula (:func:`pair_covariance`); other pairs 0.
        """
        cov = np.diag([law.var for law in laws])
        for a in range(len(self.index)):
            for b in range(a):
                r = self.latent[a, b]
                if r != 0.0:
                    i, j = self.index[a], self.index[b]
                    cov[i, j] = cov[j, i] = pair_covariance(laws[i], laws[j], r)
        return cov


# ---------------------------------------------------------------- the table
def _names_of(key: str) -> list[str]:
    return [part.strip() for part in key.split(",")]


def parse_correlation(table, factors: tuple, groups: dict, where: str = "[correlation]"):
    """Check a ``[correlation]`` table and build its copula.

    Parameters
    ----------
    table : dict of str to float
        Keys ``"a,b"`` (two factors or groups: every member of one with every
        member of the other) or ``"g"`` (one group: every pair inside it);
        values are rank correlations in (-1, 1).
    factors : tuple of str
        The budget's factors (:attr:`Budget.factors`).
    groups : dict of str to tuple of str
        The budget's user groups.
    where : str
        Prefix of the error messages.

    Returns
    -------
    GaussianCopula or None
        None for an empty table.

    Raises
    ------
    BudgetError
        One line naming the key: an unknown name, a contact angle, a value
        outside (-1, 1), a pair given twice, or a set of correlations that no
        joint law has (the latent matrix not positive definite: the pair
        whose removal raises its smallest eigenvalue most is named, with its key).
    """
    if not isinstance(table, dict):
        raise BudgetError(f"{where} must be a table of \"input,input\" = rank correlation, got {table!r}")
    seen: dict[tuple[int, int], str] = {}
    keyed: list[tuple[str, float, list[tuple[int, int]]]] = []
    for key, value in table.items():
        at = f"{where} {key!r}"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise BudgetError(f"{at}: a rank correlation must be a finite number, got {value!r}")
        if not -1.0 < value < 1.0:
            raise BudgetError(f"{at} = {value:g}: a rank correlation must lie strictly between -1 and 1 "
                              "(±1 would make the two one input)")
        names = _names_of(str(key))
        if len(names) not in (1, 2) or not all(names):
            raise BudgetError(f"{at}: a key is \"input,input\", \"group,input\", \"group,group\" or one group name")
        sets = []
        for name in names:
            if name in groups:
                members = tuple(groups[name])
            elif name in factors:
                members = (name,)
            else:
                raise BudgetError(f"{at}: {name!r} is neither an input of the budget nor a group of [groups] "
                                  f"(inputs: {', '.join(factors)}{'; groups: ' + ', '.join(groups) if groups else ''})")
            angles = [m for m in members if m.startswith("zeta_")]
            if angles:
                raise BudgetError(f"{at}: {angles[0]} is a contact angle, a direction on the circle with no rank "
                                  f"order: correlate the clearance size rho_{angles[0][-1]} instead")
            sets.append(members)
        if len(names) == 1:
            if names[0] not in groups:
                raise BudgetError(f"{at}: one name correlates the members of a group; {names[0]!r} is an input "
                                  "(write \"input,input\")")
            pairs = [(a, b) for i, a in enumerate(sets[0]) for b in sets[0][i + 1:]]
        else:
            pairs = [(a, b) for a in sets[0] for b in sets[1]]
        idx = []
        for a, b in pairs:
            if a == b:
                raise BudgetError(f"{at}: {a} is on both sides (an input is perfectly correlated with itself)")
            pair = tuple(sorted((factors.index(a), factors.index(b))))
            if pair in seen:
                first = seen[pair]
                again = "twice" if first == key else f"again (already by {first!r})"
                raise BudgetError(f"{at}: the pair {a},{b} is given {again}")
            seen[pair] = str(key)
            idx.append(pair)
        keyed.append((str(key), float(value), idx))
    if not seen:
        return None
    index = tuple(sorted({k for pair in seen for k in pair}))
    pos = {k: n for n, k in enumerate(index)}
    spearman = np.eye(len(index))
    value_of = {}
    for key, value, idx in keyed:
        for i, j in idx:
            spearman[pos[i], pos[j]] = spearman[pos[j], pos[i]] = value
            value_of[(i, j)] = value
    latent = latent_from_spearman(spearman)
    np.fill_diagonal(latent, 1.0)
    low = float(np.linalg.eigvalsh(latent)[0])
    if low <= _PD_TOL:                     # name the pair whose removal raises the smallest eigenvalue most

        def without(pair):
            m = latent.copy()
            m[pos[pair[0]], pos[pair[1]]] = m[pos[pair[1]], pos[pair[0]]] = 0.0
            return float(np.linalg.eigvalsh(m)[0])

        i, j = max(seen, key=without)
        raise BudgetError(f"{where} {seen[(i, j)]!r}: no joint law has these rank correlations together (the "
                          f"latent correlation matrix is not positive definite, smallest eigenvalue {low:.3g}; "
                          f"pairs not given are uncorrelated); the pair {factors[i]},{factors[j]} = "
                          f"{value_of[(i, j)]:g} is the one whose removal helps most: weaken it, or give the pairs "
                          "it leaves at 0")
    return GaussianCopula(index=index, names=tuple(factors[k] for k in index), spearman=spearman, latent=latent,
                          chol=np.linalg.cholesky(latent))


# ---------------------------------------------------------------- moments under the copula
_GH_X, _GH_W = hermegauss(64)
_GH_W = _GH_W / math.sqrt(2.0 * math.pi)              # E[g(W)] = sum w g(x), W standard normal
_Z_MAX = 8.5                                            # |z| beyond it: probability below 2e-17


def _thresholds(law: Law) -> np.ndarray:
    """Latent values where the law's ppf(Phi(z)) jumps or kinks (discrete classes, triangular mode)."""
    if isinstance(law, Discrete):
        return special.ndtri(np.cumsum(law.weights)[:-1])
    if isinstance(law, Triangular) and law.lo < law.mode < law.hi:
        return special.ndtri(np.array([(law.mode - law.lo) / (law.hi - law.lo)]))
    return np.zeros(0)


def _latent_ppf(law: Law, z: np.ndarray) -> np.ndarray:
    return law.ppf(np.clip(special.ndtr(z), U_EDGE, 1.0 - U_EDGE))


def _smoothed(law: Law, mu: float, s: float) -> float:
    """E[F^-1(Phi(mu + s W))], W standard normal: exact for uniform, normal and discrete laws."""
    if isinstance(law, Normal):
        return law.mu + law.sd * mu
    if isinstance(law, Uniform):
        return law.lo + (law.hi - law.lo) * float(special.ndtr(mu / math.sqrt(1.0 + s * s)))
    if isinstance(law, Discrete):
        t = np.concatenate([[-np.inf], _thresholds(law), [np.inf]])
        p = np.diff(special.ndtr((t - mu) / s))
        return float(np.dot(p, law.values))
    return float(np.dot(_GH_W, _latent_ppf(law, mu + s * _GH_X)))


def pair_covariance(law_i: Law, law_j: Law, r: float) -> float:
    """Covariance of two factors joined by a Gaussian copula of latent correlation ``r`` (``|r| < 1``).

    ``E[g_i(Z_i) g_j(Z_j)]`` with ``g = F^-1 o Phi`` is written as the
    expectation over Z_i of g_i(Z_i) times E[g_j(r Z_i + s W)], s = sqrt(1 - r^2):
    the inner expectation exact for uniform, normal and discrete laws (64-point
    Gauss-Hermite otherwise), the outer one adaptive quadrature split where
    either law jumps. Closed forms it reproduces: r sd_i sd_j for two normal
    laws, rho_S sd_i sd_j for two uniform laws.
    """
    if isinstance(law_i, Normal) and isinstance(law_j, Normal):
        return r * law_i.sd * law_j.sd
    s = math.sqrt(max(0.0, 1.0 - r * r))
    points = np.concatenate([_thresholds(law_i), _thresholds(law_j) / r if r != 0 else np.zeros(0)])
    points = np.unique(points[np.abs(points) < _Z_MAX])

    mi, mj = law_i.mean, law_j.mean

    def integrand(z):                                   # centred, so nothing cancels
        return math.exp(-0.5 * z * z) / math.sqrt(2 * math.pi) * (float(_latent_ppf(law_i, np.array(z))) - mi) \
            * (_smoothed(law_j, r * z, s) - mj)

    value, _ = integrate.quad(integrand, -_Z_MAX, _Z_MAX, points=points if points.size else None, limit=400,
                              epsabs=1e-10 * math.sqrt(law_i.var * law_j.var), epsrel=1e-8)
    return value
