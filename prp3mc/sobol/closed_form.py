"""Exact first-order and total Sobol indices of the linear outputs δx, δy, δφ.

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
tested against.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._result import pose_columns
from ..kinematics.geometry import Geometry
from ..units import POSE_OUTPUTS
from ..model.budget import Budget
from ..model.laws import angle_moments
from ..model.linear import LinearModel, linear_model
from .saltelli import Factors, design_factors

__all__ = ["analytic_indices"]


def _cos_moments(zeta_law, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E[cos(zeta - omega)] and E[cos^2(zeta - omega)], zeta in degrees, by quadrature of its ppf."""
    ec, es, ecc, ess, ecs = angle_moments(zeta_law)
    co, so = np.cos(omega), np.sin(omega)
    return co * ec + so * es, co**2 * ecc + 2 * co * so * ecs + so**2 * ess


def _analytic_arrays(model: LinearModel, factors: Factors) -> tuple[np.ndarray, np.ndarray]:
    """Exact S1 and ST, shape (..., 3, K), of dx, dy, dphi for the factors.

    Each term t contributes V_t(s) = Var(E[term_t | inputs s]) times its
    column squared; S1(g) = sum_t V_t(g & in_t) / V and
    ST(g) = sum_t [V_t(in_t) - V_t(in_t - g)] / V. Known shifts (offsets,
    scales) have no variance and no part.
    """
    laws = model.budget.factor_laws
    d = factors.masks.shape[1]
    inputs = factors.names[:d]
    shape = model.poses.shape[:-1]
    first = np.zeros(shape + (3, len(factors.names)))
    total = np.zeros_like(first)
    V = np.zeros(shape + (3,))
    columns = model.columns
    for t, (kind, *args) in enumerate(model._plan):
        if kind == "shift":
            continue
        col2 = columns[..., :, t] ** 2                                      # (..., 3)
        if kind == "clearance":
            (k, kz), = args
            term, zeta = inputs[k], inputs[kz]
            rho_law = laws[term]
            ec, ecc = _cos_moments(laws[zeta], model.omega[..., model.legs[t]])     # (...)
            r1, r2 = rho_law.mean, rho_law.var + rho_law.mean**2
            parts = {frozenset(): 0.0, frozenset([term]): rho_law.var * ec**2,
                     frozenset([zeta]): r1**2 * (ecc - ec**2), frozenset([term, zeta]): r2 * ecc - r1**2 * ec**2}
        else:
            term = inputs[args[0]]
            parts = {frozenset(): 0.0, frozenset([term]): laws[term].var}
        members = max(parts, key=len)
        full = np.asarray(parts[members])[..., None] * col2
        V += full
        for k, mask in enumerate(factors.masks):
            g = frozenset(np.array(inputs)[mask])
            first[..., k] += np.asarray(parts[members & g])[..., None] * col2
            total[..., k] += full - np.asarray(parts[members - g])[..., None] * col2
    V = np.where(V > 0, V, np.inf)[..., None]
    return first / V, total / V


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
