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

from .._result import freeze, short_repr
from ..units import DEG2RAD, RAD2DEG
from .budget import Budget, parse_input
from .laws import angle_moments
from ..kinematics.geometry import Geometry
from ..kinematics.chain import as_poses, frame, validated_frame
from ..kinematics.sensitivity import LENGTH_FAMILIES, h_entries

__all__ = ["LinearModel", "linear_model", "FEATURE_VALUE", "FEATURE_COS", "FEATURE_SIN"]

#: Feature codes of :meth:`LinearModel.feature_ops`: input a's value; X_a cos(X_b deg); X_a sin(X_b deg).
FEATURE_VALUE, FEATURE_COS, FEATURE_SIN = range(3)


@dataclass(frozen=True, slots=True, repr=False)
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
    legs : tuple of int
        The (0-based) leg of every term.
    Ainv : ndarray, shape (..., 3, 3)
        A^-1 at the poses.
    scale : ndarray, shape (..., T)
        Every term's entry h_q,i of H_q, per unit (mm or deg) of the term.
        Since every H_q is diagonal, the pose error is ``A^-1 u`` with
        ``u_i = sum over the terms t of leg i of scale_t * term_t``.
    cos_omega, sin_omega : ndarray, shape (..., 3)
        Worst contact direction omega_i of each leg's clearance (that of E l_i).
    """

    geometry: Geometry
    budget: Budget
    poses: np.ndarray
    terms: tuple
    legs: tuple
    Ainv: np.ndarray
    scale: np.ndarray
    cos_omega: np.ndarray
    sin_omega: np.ndarray
    _plan: tuple

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "geometry", "budget", "poses", "terms")

    @property
    def columns(self) -> np.ndarray:
        """Pose error (dx mm, dy mm, dphi rad) per unit of each term, shape (..., 3, T)."""
        return self.Ainv[..., :, list(self.legs)] * self.scale[..., None, :]

    @property
    def omega(self) -> np.ndarray:
        """Worst contact direction of each leg's clearance, rad, shape (..., 3)."""
        return np.arctan2(self.sin_omega, self.cos_omega)

    @property
    def coef(self) -> np.ndarray:
        """Coefficients of the sample features (see :meth:`features`), shape (..., 3, F)."""
        cols = []
        columns = self.columns
        for t, (kind, _) in enumerate(self._plan):
            col = columns[..., t]
            if kind == "value":
                cols.append(col)
            else:
                _, leg = parse_input(self.terms[t])
                cols += [col * self.cos_omega[..., leg, None], col * self.sin_omega[..., leg, None]]
        return np.stack(cols, axis=-1)

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

    def feature_ops(self) -> np.ndarray:
        """How :meth:`features` makes each feature from the inputs, for compiled samplers.

        Returns
        -------
        ndarray, shape (F, 3), int64
            Rows ``(op, a, b)``: ``FEATURE_VALUE`` is input a's value,
            ``FEATURE_COS`` / ``FEATURE_SIN`` are X_a cos(X_b) / X_a sin(X_b)
            with X_b in degrees (b unused for a value).
        """
        rows = []
        for kind, idx in self._plan:
            if kind == "value":
                rows.append((FEATURE_VALUE, idx, idx))
            else:
                rows += [(FEATURE_COS, idx[0], idx[1]), (FEATURE_SIN, idx[0], idx[1])]
        return np.array(rows, dtype=np.int64).reshape(-1, 3)

    def evaluate(self, X: np.ndarray, dtype=np.float64) -> np.ndarray:
        """Pose errors for every pose and sample, shape (..., n, 3): dx mm, dy mm, dphi rad."""
        F = self.features(X).astype(dtype, copy=False)
        return np.einsum("...of,nf->...no", self.coef.astype(dtype, copy=False), F, optimize=True)

    def feature_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact mean (F,) and covariance (F, F) of the sample features (see :meth:`features`).

        Non-clearance features are independent inputs; a clearance's features
        (rho cos zeta, rho sin zeta) have moments E[rho^k] times the
        trigonometric moments of zeta (:func:`~prp3mc.uncertainty.laws.angle_moments`).
        """
        laws = list(self.budget.inputs.values())
        fmean, blocks = [], []
        for kind, idx in self._plan:
            if kind == "value":
                fmean.append(laws[idx].mean)
                blocks.append(np.array([[laws[idx].var]]))
            else:
                rho, zeta = laws[idx[0]], laws[idx[1]]
                ec, es, ecc, ess, ecs = angle_moments(zeta)
                r1, r2 = rho.mean, rho.var + rho.mean**2
                m = np.array([r1 * ec, r1 * es])
                fmean.extend(m)
                blocks.append(r2 * np.array([[ecc, ecs], [ecs, ess]]) - np.outer(m, m))
        nf = len(fmean)
        fcov = np.zeros((nf, nf))
        pos = 0
        for block in blocks:
            k = block.shape[0]
            fcov[pos:pos + k, pos:pos + k] = block
            pos += k
        return np.array(fmean), fcov

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact mean (..., 3) and covariance (..., 3, 3) of the pose error (dx mm, dy mm, dphi deg)."""
        fmean, fcov = self.feature_moments()
        deg = np.array([1.0, 1.0, RAD2DEG])
        mean = np.einsum("...of,f->...o", self.coef, fmean) * deg
        cov = np.einsum("...of,fg,...qg->...oq", self.coef, fcov, self.coef) * np.outer(deg, deg)
        return mean, cov

    def term_values(self, X: np.ndarray) -> np.ndarray:
        """Value of every term per pose and sample, shape (..., n, T), boundary units."""
        X = np.asarray(X, dtype=float)
        out = np.empty(self.poses.shape[:-1] + (X.shape[0], len(self.terms)))
        for t, (kind, idx) in enumerate(self._plan):
            if kind == "value":
                out[..., t] = X[:, idx]
            else:
                _, leg = parse_input(self.terms[t])
                zeta = np.deg2rad(X[:, idx[1]])
                out[..., t] = X[:, idx[0]] * (np.cos(zeta) * self.cos_omega[..., leg, None]
                                              + np.sin(zeta) * self.sin_omega[..., leg, None])
        return out


def linear_model(geometry: Geometry, budget: Budget, poses, *, check: bool = True) -> LinearModel:
    """Build the :class:`LinearModel` of ``budget`` at ``poses`` (..., 3).

    Poses out of stroke, with d_i <= 0 or near a singularity are refused
    (:class:`~prp3mc.errors.InfeasiblePoseError`) unless ``check=False``.
    """
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses) if check else frame(geometry, poses)
    names = budget.names
    terms, legs, scales, plan = [], [], [], []
    h = {}
    for k, name in enumerate(names):
        family, leg = parse_input(name)
        if family == "zeta":
            continue
        if family not in h:
            h[family] = h_entries(geometry, fr, family)
        terms.append(name)
        legs.append(leg)
        scales.append(h[family][leg] * (1.0 if family in LENGTH_FAMILIES else DEG2RAD))
        plan.append(("clearance", (k, names.index(f"zeta_{leg + 1}"))) if family == "rho" else ("value", k))
    return LinearModel(geometry=geometry, budget=budget, poses=poses, terms=tuple(terms), legs=tuple(legs),
                       Ainv=np.moveaxis(fr.Ainv, (0, 1), (-2, -1)), scale=np.stack(scales, axis=-1),
                       cos_omega=np.moveaxis(-fr.tr.sl, 0, -1), sin_omega=np.moveaxis(fr.tr.cl, 0, -1),
                       _plan=tuple(plan))
