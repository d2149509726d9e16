"""Exact first-order and total Sobol indices and Shapley effects of the linear outputs δx, δy, δφ.

δx, δy and δφ are linear in independent terms: values of the
inputs and of the effects' random factors (backlash_i, thermal), and
rho_i cos(zeta_i - omega_i) for a clearance; known shifts add no variance. A term's part of
Var(E[y | X_s]) for an input set s is its column squared times
Var(x) (a value term, s holding x), Var(rho) E[c]^2 (s = {rho}),
E[rho]^2 Var(c) (s = {zeta}) or Var(rho c) (both), with c = cos(zeta - omega)
and the moments of zeta by quadrature of its ppf
(:func:`~prp3mc.model.laws.angle_moments`); first-order and total
indices of any input or group follow by summing over terms. These are the
oracle the estimates of :func:`~prp3mc.sobol.indices.sobol_indices` are
tested against. Shapley effects (:func:`analytic_shapley`) add up over
independent terms; a block of correlated normal factors is jointly normal,
with closed-form conditional variances.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .._result import pose_columns
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from ..units import POSE_OUTPUTS
from ..model.budget import Budget
from ..model.laws import Normal, angle_moments
from ..model.linear import LinearModel, linear_model
from .saltelli import Factors, design_factors

__all__ = ["analytic_indices", "analytic_shapley"]


def _cos_moments(zeta_law, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E[cos(zeta - omega)] and E[cos^2(zeta - omega)], zeta in degrees, by quadrature of its ppf."""
    ec, es, ecc, ess, ecs = angle_moments(zeta_law)
    co, so = np.cos(omega), np.sin(omega)
    return co * ec + so * es, co**2 * ecc + 2 * co * so * ecs + so**2 * ess


def _term_parts(model: LinearModel, t: int, inputs: tuple):
    """The factors of term t and Var(E[term | factors s]) for every subset s of them (an (...)-array or 0).

    A value term has one factor (its variance); a clearance rho cos(zeta - omega)
    two: Var(rho) E[c]^2 (s = {rho}), E[rho]^2 Var(c) (s = {zeta}), Var(rho c) (both).
    """
    laws = model.budget.factor_laws
    tl = model.term_laws[t]
    if tl.kind == "clearance":
        term, zeta = (inputs[k] for k in tl.factors)
        rho_law = laws[term]
        ec, ecc = _cos_moments(laws[zeta], model.omega[..., model.legs[t]])     # (...)
        r1, r2 = rho_law.mean, rho_law.var + rho_law.mean**2
        return frozenset([term, zeta]), {frozenset(): 0.0, frozenset([term]): rho_law.var * ec**2,
                                         frozenset([zeta]): r1**2 * (ecc - ec**2),
                                         frozenset([term, zeta]): r2 * ecc - r1**2 * ec**2}
    term = inputs[tl.factors[0]]
    return frozenset([term]), {frozenset(): 0.0, frozenset([term]): laws[term].var}


def _analytic_arrays(model: LinearModel, factors: Factors) -> tuple[np.ndarray, np.ndarray]:
    """Exact S1 and ST, shape (..., 3, K), of dx, dy, dphi for the factors (independent ones).

    Each term t contributes V_t(s) = Var(E[term_t | inputs s]) times its
    column squared; S1(g) = sum_t V_t(g & in_t) / V and
    ST(g) = sum_t [V_t(in_t) - V_t(in_t - g)] / V. Known shifts (offsets,
    scales) have no variance and no part.
    """
    d = factors.masks.shape[1]
    inputs = factors.names[:d]
    shape = model.poses.shape[:-1]
    first = np.zeros(shape + (3, len(factors.names)))
    total = np.zeros_like(first)
    V = np.zeros(shape + (3,))
    columns = model.columns
    for t, tl in enumerate(model.term_laws):
        if tl.kind == "shift":
            continue
        col2 = columns[..., :, t] ** 2                                      # (..., 3)
        members, parts = _term_parts(model, t, inputs)
        full = np.asarray(parts[members])[..., None] * col2
        V += full
        for k, mask in enumerate(factors.masks):
            g = frozenset(np.array(inputs)[mask])
            first[..., k] += np.asarray(parts[members & g])[..., None] * col2
            total[..., k] += full - np.asarray(parts[members - g])[..., None] * col2
    V = np.where(V > 0, V, np.inf)[..., None]
    return first / V, total / V


def _gaussian_shapley(cov: np.ndarray) -> np.ndarray:
    """Matrices W (g, g, g) with Sh_i Var(y) = c^T W_i c for y = c . X, X normal with covariance ``cov``.

    The game's value of a set S is Var(E[y | X_S]) = c^T Q_S c with
    Q_S = cov[:, S] cov[S, S]^-1 cov[S, :]; W_i sums the Shapley weights
    |S|! (g - |S| - 1)! / g! times Q_{S + i} - Q_S over the 2^(g - 1) sets S without i.
    """
    g = cov.shape[0]
    Q = np.zeros((1 << g, g, g))
    for mask in range(1, 1 << g):
        S = [i for i in range(g) if mask >> i & 1]
        Q[mask] = cov[:, S] @ np.linalg.solve(cov[np.ix_(S, S)], cov[S, :])
    W = np.zeros((g, g, g))
    size = np.array([bin(mask).count("1") for mask in range(1 << g)])
    weight = np.array([math.factorial(k) * math.factorial(g - k - 1) / math.factorial(g) if k < g else 0.0
                       for k in range(g + 1)])
    for i in range(g):
        without = np.array([mask for mask in range(1 << g) if not mask >> i & 1])
        W[i] = np.einsum("s,sfg->fg", weight[size[without]], Q[without | 1 << i] - Q[without])
    return W


def _shapley_arrays(model: LinearModel, factors: Factors) -> np.ndarray:
    """Exact Shapley effects (..., 3, K) of dx, dy, dphi; groups sum their members'.

    Terms of independent factors are independent games, whose Shapley values
    add up: a value term's variance goes to its factor, a clearance's is
    shared as (V(own) + V(both) - V(other)) / 2. The value terms of the
    copula's factors (all normal: then jointly normal) form one game of
    normal factors (:func:`_gaussian_shapley`).
    """
    budget = model.budget
    d = factors.masks.shape[1]
    inputs = factors.names[:d]
    laws = budget.factor_laws
    joint = set(budget.copula.names) if budget.copula is not None else set()
    other = sorted(name for name in joint if not isinstance(laws[name], Normal))
    if other:
        raise BudgetError(f"no closed form for Shapley effects with the correlated non-normal factor(s) "
                          f"{', '.join(other)}: estimate them (shapley_effects)")
    shape = model.poses.shape[:-1]
    Sh = np.zeros(shape + (3, d))
    V = np.zeros(shape + (3,))
    columns = model.columns
    normal_cols = {}
    for t, tl in enumerate(model.term_laws):
        if tl.kind == "shift":
            continue
        col = columns[..., :, t]
        if tl.kind == "factor" and inputs[tl.factors[0]] in joint:
            normal_cols[tl.factors[0]] = col
            continue
        members, parts = _term_parts(model, t, inputs)
        col2 = col**2
        V += np.asarray(parts[members])[..., None] * col2
        for name in members:
            other_ = members - {name}
            share = 0.5 * (parts[frozenset([name])] + parts[members] - parts[other_]) if other_ else parts[members]
            Sh[..., inputs.index(name)] += np.asarray(share)[..., None] * col2
    if normal_cols:
        idx = sorted(normal_cols)
        C = np.stack([normal_cols[k] for k in idx], axis=-1)                  # (..., 3, g)
        cov = budget.covariance()[np.ix_(idx, idx)]
        Sh[..., idx] += np.einsum("...of,ifg,...og->...oi", C, _gaussian_shapley(cov), C)
        V += np.einsum("...of,fg,...og->...o", C, cov, C)
    V = np.where(V > 0, V, np.inf)[..., None]
    return (Sh / V) @ factors.masks.T.astype(float)


def analytic_indices(geometry: Geometry, budget: Budget, poses, groups: dict | None = None) -> pd.DataFrame:
    """Exact first-order and total indices of the linear outputs x, y, phi.

    The inputs are independent and the outputs sums of terms, so the indices
    are variance shares; a clearance term rho cos(zeta - omega) is the one
    place where two inputs interact. For zeta uniform over the full circle
    this gives S1_rho = 0, S1_zeta = c^2 E[rho]^2 / 2 / V,
    ST_rho = c^2 Var(rho) / 2 / V and ST_zeta = S_clearance = c^2 E[rho^2] / 2 / V;
    any law of zeta is handled by quadrature of its ppf.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
    groups : dict, optional
        User groups, as for :func:`~prp3mc.sobol.indices.sobol_indices`.

    Returns
    -------
    DataFrame
        x_mm, y_mm, phi_deg, output, name, kind, S1, ST.
    """
    factors = design_factors(budget, groups)
    model = linear_model(geometry, budget, poses)
    S1, ST = _analytic_arrays(model, factors)
    n, K = int(np.prod(model.poses.shape[:-1], dtype=int)), len(factors.names)
    return pd.DataFrame({
        **pose_columns(model.poses, 3 * K),
        "output": np.tile(np.repeat(POSE_OUTPUTS, K), n), "name": np.tile(factors.names, 3 * n),
        "kind": np.tile(factors.kinds, 3 * n), "S1": S1.reshape(-1), "ST": ST.reshape(-1),
    })


def analytic_shapley(geometry: Geometry, budget: Budget, poses, groups: dict | None = None) -> pd.DataFrame:
    """Exact Shapley effects of the linear outputs x, y, phi.

    Exact where the budget's factors are independent, or correlated only
    among normal laws (a Gaussian copula over normal marginals is a joint
    normal law, whose conditional variances are closed form; all 2^g subsets
    of its g factors are enumerated). A group's effect is the sum of its
    members'. Correlated factors of other laws have no closed form:
    :class:`~prp3mc.errors.BudgetError`.

    Returns
    -------
    DataFrame
        x_mm, y_mm, phi_deg, output, name, kind, Sh.
    """
    factors = design_factors(budget, groups)
    model = linear_model(geometry, budget, poses)
    Sh = _shapley_arrays(model, factors)
    n, K = int(np.prod(model.poses.shape[:-1], dtype=int)), len(factors.names)
    return pd.DataFrame({
        **pose_columns(model.poses, 3 * K),
        "output": np.tile(np.repeat(POSE_OUTPUTS, K), n), "name": np.tile(factors.names, 3 * n),
        "kind": np.tile(factors.kinds, 3 * n), "Sh": Sh.reshape(-1),
    })
