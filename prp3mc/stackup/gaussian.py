"""Correlated normal inputs as independent terms: the exact series for a budget with ``[correlation]``.

The series (:mod:`.series`) sums the characteristic function of
``Y = s + sum_t c_t X_t`` over independent X_t. A budget's Gaussian copula
(:mod:`prp3mc.model.copula`) makes some factors dependent; when every
correlated factor has a *normal* law, they are jointly normal: the copula's
latent normals Z (correlation R) map to ``X_k = mu_k + sd_k Z_k``, so the
Pearson correlation of the X_k is R itself (the rank correlation of the
table, converted by ``r = 2 sin(pi rho_S / 6)``). Their covariance is
``Sigma = D R D`` (D = diag(sd)), and with lambda the smallest eigenvalue of
R (> 0: the copula refuses a matrix that is not positive definite)

    Sigma = lambda D² + D (R - lambda I) D,

two positive semi-definite parts. So X is, exactly in law, the sum of

- independent normal terms, each factor's own with its sd scaled by
  sqrt(lambda) (in its own leg: the legs keep their Gaussian decay), and
- one Gaussian vector ``G ~ N(0, D (R - lambda I) D)`` independent of them,
  whose contribution to the pose error ``C_K G`` (C_K: the factors' columns)
  is a 3-D Gaussian of covariance ``P = C_K D (R - lambda I) D C_K^T``; with
  ``P = U diag(e) U^T`` it is ``sum_j sqrt(e_j) u_j W_j``, W_j independent
  standard normals: at most three more terms, of all legs (like the thermal
  term), with per-pose columns.

Every term is again an independent scalar with a closed-form characteristic
function, and the Gaussian factor ``exp(-w^T P w / 2)`` that couples the
legs is the product of the three new terms' ``exp(-e_j (u_j . w)^2 / 2)``:
the series, its envelopes (each <= 1 and decreasing) and its bound apply
unchanged. Nothing is approximated; the new terms are normal laws, cut like
the others (their mass past the cut is in the bound).

A correlated factor with another law (uniform, a clearance radius, ...) has
no such decomposition: :func:`gaussian_terms` refuses the budget, naming the
Monte Carlo fallback (:func:`prp3mc.monte_carlo` with a phi tolerance gives
every exceedance with its Wilson interval).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import BudgetError
from ..model.effects import ALL_LEGS
from ..model.laws import Normal
from ..model.linear import TermLaw

__all__ = ["gaussian_terms", "exact_refusal", "GAUSSIAN_TERMS", "FALLBACK"]

#: Names of the (at most three) terms of the correlated Gaussian block, one per principal direction.
GAUSSIAN_TERMS = ("correlated_normal_1", "correlated_normal_2", "correlated_normal_3")
#: How to get the yield of a budget the exact series cannot take.
FALLBACK = ("use Monte Carlo: prp3mc.monte_carlo(..., tolerance_mm=S, tolerance_phi_deg=Z) gives P(position > S), "
            "P(|dphi| > Z) and P(either) with Wilson 95 % intervals; prp3mc yield falls back on it")
_TINY = 1e-13            # eigenvalues of P below this times its trace are rounding: dropped


def exact_refusal(budget) -> str | None:
    """Why the exact series cannot take ``budget``'s correlation (a sentence), or None when it can.

    It can when the budget is independent, or when every correlated factor has
    a normal law (:mod:`prp3mc.stackup.gaussian`).
    """
    copula = budget.copula
    if copula is None:
        return None
    laws = list(budget.factor_laws.values())
    other = [(name, laws[k].kind) for name, k in zip(copula.names, copula.index) if not isinstance(laws[k], Normal)]
    if not other:
        return None
    listed = ", ".join(f"{name} ({kind})" for name, kind in other)
    return (f"budget {budget.name!r} correlates inputs whose law is not normal: {listed}; the exact series takes "
            "correlated inputs only when all of them are normal (then jointly normal)")


def gaussian_terms(budget, term_laws: tuple, legs: tuple, columns: np.ndarray) -> tuple[tuple, tuple, np.ndarray]:
    """The model's terms with the correlated normal factors made independent (exact in law).

    Parameters
    ----------
    budget : Budget
        With or without ``[correlation]``.
    term_laws, legs : tuple (T,)
        :attr:`~prp3mc.model.linear.LinearModel.term_laws` and ``legs``.
    columns : ndarray (N, 3, T)
        Pose error (dx mm, dy mm, dphi rad) per unit of each term.

    Returns
    -------
    term_laws, legs : tuple (T + G,)
        The correlated factors' laws with their sd times sqrt(lambda), then G <= 3 standard normal terms
        of all legs (:data:`GAUSSIAN_TERMS`); unchanged (G = 0) for an independent budget.
    columns : ndarray (N, 3, T + G)
        With the new terms' columns ``sqrt(e_j) u_j`` per pose (zero where e_j vanishes).

    Raises
    ------
    BudgetError
        A correlated factor whose law is not normal (:func:`exact_refusal`), naming the fallback.
    """
    copula = budget.copula
    if copula is None:
        return term_laws, legs, columns
    why = exact_refusal(budget)
    if why is not None:
        raise BudgetError(f"exact yield: {why}; {FALLBACK}")
    term_of = {tl.factors[0]: t for t, tl in enumerate(term_laws) if tl.kind == "factor" and len(tl.factors) == 1}
    terms = [term_of[k] for k in copula.index]
    sd = np.array([term_laws[t].law.sd for t in terms])
    R = copula.latent
    lam = float(np.linalg.eigvalsh(R)[0])
    laws = list(term_laws)
    for t in terms:
        law = laws[t].law
        laws[t] = dataclasses.replace(laws[t], law=Normal(law.mu, law.sd * np.sqrt(lam)))
    rest = sd[:, None] * (R - lam * np.eye(len(terms))) * sd[None, :]       # D (R - lambda I) D, PSD
    CK = columns[:, :, terms]                                                  # (N, 3, K)
    P = np.einsum("nik,kl,njl->nij", CK, rest, CK)
    e, U = np.linalg.eigh(0.5 * (P + np.swapaxes(P, 1, 2)))                   # (N, 3), (N, 3, 3)
    scale = np.trace(P, axis1=1, axis2=2)[:, None]
    e = np.where(e > _TINY * np.maximum(scale, 1e-300), e, 0.0)
    block = U * np.sqrt(e)[:, None, :]                                         # column j: sqrt(e_j) u_j
    keep = np.flatnonzero(e.max(axis=0) > 0)
    laws += [TermLaw(GAUSSIAN_TERMS[j], "factor", ALL_LEGS, law=Normal(0.0, 1.0)) for j in range(keep.size)]
    return tuple(laws), tuple(legs) + (ALL_LEGS,) * keep.size, np.concatenate([columns, block[:, :, keep]], axis=2)
