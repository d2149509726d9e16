"""The linear error model of a budget at a batch of poses.

For an input q_i the pose error is ``J_q[:, i] * dq_i``; for a clearance
(rho_i, zeta_i) it is ``J_rho[:, i] * rho_i cos(zeta_i - omega_i)`` with
omega_i the direction of E l_i. Writing the cosine as
``cos(omega) rho cos(zeta) + sin(omega) rho sin(zeta)`` makes the error
linear in *features* of the samples with pose-dependent coefficients, so a
whole batch of poses x samples is one matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .budget import Budget, parse_input
from .geometry import Geometry
from .kinematics import as_poses, chain, check_poses
from .sensitivity import LENGTH_FAMILIES, clearance_angle_rad, sensitivity

__all__ = ["LinearModel", "linear_model"]


@dataclass(frozen=True, slots=True)
class LinearModel:
    """Linear error model of ``budget`` at ``poses``.

    Attributes
    ----------
    geometry : Geometry
    budget : Budget
    poses : ndarray, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    terms : tuple of str
        One term per input except the zeta_i: its name (``rho_i`` stands for
        the clearance term rho_i cos(zeta_i - omega_i)).
    columns : ndarray, shape (..., 3, T)
        Pose error (dx mm, dy mm, dphi rad) per unit of each term, the term
        in its boundary unit (mm or deg).
    omega : ndarray, shape (..., 3)
        Worst contact direction of each leg's clearance, rad.
    coef : ndarray, shape (..., 3, F)
        Coefficients of the sample features (see :meth:`features`).
    """

    geometry: Geometry
    budget: Budget
    poses: np.ndarray
    terms: tuple
    columns: np.ndarray
    omega: np.ndarray
    coef: np.ndarray
    _plan: tuple

    def features(self, X: np.ndarray) -> np.ndarray:
        """Sample features, shape (n, F), from input samples X (n, d) in mm / deg.

        Non-clearance inputs are their value; a clearance contributes
        rho cos(zeta) and rho sin(zeta) (zeta in degrees in X).
        """
        X = np.asarray(X, dtype=float)
        cols = []
        for kind, idx in self._plan:
            if kind == "value":
                cols.append(X[:, idx])
            else:
                rho, zeta = X[:, idx[0]], np.deg2rad(X[:, idx[1]])
                cols.extend([rho * np.cos(zeta), rho * np.sin(zeta)])
        return np.stack(cols, axis=1)

    def evaluate(self, X: np.ndarray, dtype=np.float64) -> np.ndarray:
        """Pose errors for every pose and sample, shape (..., n, 3): dx mm, dy mm, dphi rad."""
        F = self.features(X).astype(dtype, copy=False)
        return np.einsum("...of,nf->...no", self.coef.astype(dtype, copy=False), F, optimize=True)

    def term_values(self, X: np.ndarray) -> np.ndarray:
        """Value of every term per pose and sample, shape (..., n, T), boundary units."""
        X = np.asarray(X, dtype=float)
        out = np.empty(self.poses.shape[:-1] + (X.shape[0], len(self.terms)))
        for t, (kind, idx) in enumerate(self._plan):
            if kind == "value":
                out[..., t] = X[:, idx]
            else:
                _, leg = parse_input(self.terms[t])
                omega = self.omega[..., leg, None]
                out[..., t] = X[:, idx[0]] * np.cos(np.deg2rad(X[:, idx[1]]) - omega)
        return out


def linear_model(geometry: Geometry, budget: Budget, poses, *, check: bool = True) -> LinearModel:
    """Build the :class:`LinearModel` of ``budget`` at ``poses`` (..., 3)."""
    poses = as_poses(poses)
    if check:
        check_poses(geometry, poses)
    s = sensitivity(geometry, poses, check=False)
    omega = clearance_angle_rad(chain(geometry, np.deg2rad(poses[..., 2])))
    names = budget.names
    terms, columns, coefs, plan = [], [], [], []
    for k, name in enumerate(names):
        family, leg = parse_input(name)
        if family == "zeta":
            continue
        col = s.J[family][..., :, leg]
        if family not in LENGTH_FAMILIES:
            col = col * (np.pi / 180.0)  # per degree
        terms.append(name)
        columns.append(col)
        if family == "rho":
            plan.append(("clearance", (k, names.index(f"zeta_{leg + 1}"))))
            coefs += [col * np.cos(omega[..., leg, None]), col * np.sin(omega[..., leg, None])]
        else:
            plan.append(("value", k))
            coefs.append(col)
    return LinearModel(geometry=geometry, budget=budget, poses=poses, terms=tuple(terms),
                       columns=np.stack(columns, axis=-1), omega=omega,
                       coef=np.stack(coefs, axis=-1), _plan=tuple(plan))
