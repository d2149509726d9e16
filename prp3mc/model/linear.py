"""The linear error model of a budget at a batch of poses.

For an input q_i the pose error is ``J_q[:, i] * dq_i``; for a clearance
(rho_i, zeta_i) it is ``J_rho[:, i] * rho_i cos(zeta_i - omega_i)`` with
omega_i the direction of E l_i. Writing the cosine as
``cos(omega) rho cos(zeta) + sin(omega) rho sin(zeta)`` makes the error
linear in *features* of the samples with pose-dependent coefficients, so a
whole batch of poses x samples is one matrix product.

A budget's systematic effects (its ``[effects]`` table) add terms: an offset
q_i is a known shift ``J_q[:, i] * value``, a lead scale the shift
``J_b[:, i] kappa_i b_i`` with b_i from the nominal inverse kinematics, a
cyclic screw error the shift ``J_b[:, i] A_i sin(2 pi b_i / p_i + phi_i)``; a
backlash is the factor delta b_i = ±h_i/2 through ``J_b[:, i]``; thermal
expansion the factor T through ``alpha_T (T - 20) J_b b``, one term of all
three legs. The shifts share one constant feature (1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._result import freeze, short_repr
from ..units import DEG2RAD, RAD2DEG
from .budget import Budget, parse_input
from .laws import Law, angle_moments
from .effects import ALL_LEGS, effect_terms, slider_factor
from ..kinematics.geometry import Geometry
from ..kinematics.chain import as_poses, frame, validated_frame
from ..kinematics.sensitivity import LENGTH_FAMILIES, h_entries

__all__ = ["LinearModel", "TermLaw", "linear_model", "ALL_LEGS", "FEATURE_VALUE", "FEATURE_COS", "FEATURE_SIN", "FEATURE_ONE"]

#: Feature codes of :meth:`LinearModel.feature_ops`: factor a's value less a reference; X_a cos(X_b deg);
#: X_a sin(X_b deg); the constant 1 of the known shifts.
FEATURE_VALUE, FEATURE_COS, FEATURE_SIN, FEATURE_ONE = range(4)


@dataclass(frozen=True, slots=True)
class TermLaw:
    """The scalar X_t a term of a :class:`LinearModel` multiplies: the pose error is ``sum_t columns[..., t] X_t``.

    The X_t of the terms are independent. ``kind`` says what X_t is:

    - ``"factor"``: a factor of the budget less a reference, ``X_t = F - reference``
      with F distributed as ``law`` (mm, deg, or degrees C for thermal, whose
      reference is 20 degrees C);
    - ``"clearance"``: ``X_t = rho cos(zeta - omega_i)`` with rho distributed as
      ``law`` (mm) and the contact angle zeta as ``zeta`` (deg), independent;
      omega_i is the pose's contact direction (:attr:`LinearModel.omega`);
    - ``"shift"``: the known constant ``X_t = value`` (an offset or lead scale).

    Attributes
    ----------
    name : str
        The term (:attr:`LinearModel.terms`).
    kind : str
        ``"factor"``, ``"clearance"`` or ``"shift"``.
    leg : int
        0-based leg, :data:`ALL_LEGS` for a term of all legs (thermal).
    law : Law or None
        The factor's law, or the clearance's radius law; None for a shift.
    reference : float
        Subtracted from a factor (20 for thermal, else 0).
    zeta : Law or None
        The contact angle's law (clearance only).
    value : float
        The shift's value (mm, deg or 1), 0 for the other kinds.
    factors : tuple of int
        Indices into :attr:`Budget.factors <prp3mc.model.budget.Budget.factors>`
        of the factors X_t is made of: ``(k,)`` for a factor, ``(k_rho, k_zeta)``
        for a clearance, ``()`` for a shift.
    """

    name: str
    kind: str
    leg: int
    law: Law | None = None
    reference: float = 0.0
    zeta: Law | None = None
    value: float = 0.0
    factors: tuple = ()


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
        One term per input except the zeta_i (``rho_i`` stands for the
        clearance term rho_i cos(zeta_i - omega_i)), then one per effect of
        the budget in library order: offsets ``offset_q_i`` (the effect
        ``q_i``; the input q_i is another term), ``scale_i`` and
        ``cyclic_i`` (known shifts, the term's value is the effect's value:
        a cyclic error's amplitude A_i), ``backlash_i`` (the
        factor delta b_i, mm) and ``thermal`` (T - 20, K).
    legs : tuple of int
        The (0-based) leg of every term; :data:`ALL_LEGS` for a term of all legs.
    Ainv : ndarray, shape (..., 3, 3)
        A^-1 at the poses.
    weights : ndarray, shape (..., 3, T)
        u per unit (mm, deg, 1 or K) of each term: the pose error is
        ``A^-1 u`` with ``u = sum over the terms t of weights[:, t] * term_t``
        (every H_q is diagonal, so a term of one leg has one non-zero entry,
        h_q,i; thermal has alpha_T h_b,i b_i in every leg).
    cos_omega, sin_omega : ndarray, shape (..., 3)
        Worst contact direction omega_i of each leg's clearance (that of E l_i).
    term_laws : tuple of TermLaw
        What each term's scalar X_t is, its law and its factors, in :attr:`terms` order.
    """

    geometry: Geometry
    budget: Budget
    poses: np.ndarray
    terms: tuple
    legs: tuple
    Ainv: np.ndarray
    weights: np.ndarray
    cos_omega: np.ndarray
    sin_omega: np.ndarray
    term_laws: tuple

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "geometry", "budget", "poses", "terms")

    @property
    def scale(self) -> np.ndarray:
        """Weight of every term on its own leg, shape (..., T); 0 for a term of all legs."""
        legs = np.array(self.legs, dtype=int)
        own = self.weights[..., np.maximum(legs, 0), np.arange(legs.size)]
        return np.where(legs >= 0, own, 0.0)

    @property
    def shared(self) -> tuple[int, ...]:
        """Indices of the terms of all legs (their u is not along one leg's axis)."""
        return tuple(t for t, leg in enumerate(self.legs) if leg == ALL_LEGS)

    @property
    def columns(self) -> np.ndarray:
        """Pose error (dx mm, dy mm, dphi rad) per unit of each term, shape (..., 3, T)."""
        cols = self.Ainv[..., :, [max(leg, 0) for leg in self.legs]] * self.scale[..., None, :]
        for t in self.shared:
            cols[..., :, t] = np.einsum("...ij,...j->...i", self.Ainv, self.weights[..., :, t])
        return cols

    @property
    def term_units(self) -> tuple[str, ...]:
        """Unit of each term's value (:meth:`term_values`): mm or deg for an input (rho_i: mm), the effect
        kind's term unit for an effect (:attr:`EffectKind.term_unit <prp3mc.model.effects.EffectKind>`; K for
        thermal, whose term is T - 20), in :attr:`terms` order."""
        effects = {t.name: t.effect for t in effect_terms(self.budget.effects, self.geometry.lead_mm)}

        def unit(name: str) -> str:
            if name in effects:
                return effects[name].kind.term_unit or effects[name].unit
            return "mm" if parse_input(name)[0] in LENGTH_FAMILIES else "deg"
        return tuple(unit(name) for name in self.terms)

    @property
    def omega(self) -> np.ndarray:
        """Worst contact direction of each leg's clearance, rad, shape (..., 3)."""
        return np.arctan2(self.sin_omega, self.cos_omega)

    @property
    def has_shift(self) -> bool:
        """Whether the budget has known shifts (offsets, scales): the last feature is then the constant 1."""
        return any(tl.kind == "shift" for tl in self.term_laws)

    @property
    def coef(self) -> np.ndarray:
        """Coefficients of the sample features (see :meth:`features`), shape (..., 3, F)."""
        cols = []
        columns = self.columns
        shift = 0.0
        for t, tl in enumerate(self.term_laws):
            col = columns[..., t]
            if tl.kind == "factor":
                cols.append(col)
            elif tl.kind == "shift":
                shift = shift + col * tl.value
            else:
                cols += [col * self.cos_omega[..., tl.leg, None], col * self.sin_omega[..., tl.leg, None]]
        if self.has_shift:
            cols.append(shift)
        return np.stack(cols, axis=-1)

    def features(self, X: np.ndarray) -> np.ndarray:
        """Sample features, shape (n, F), from factor samples X (n, D) in mm / deg (see :attr:`Budget.factors`).

        Non-clearance inputs and backlash factors are their value, thermal
        is T - 20; a clearance contributes rho cos(zeta) and rho sin(zeta)
        (zeta in degrees in X); known shifts add the constant 1 last.
        """
        X = np.asarray(X, dtype=float)
        cols = []
        for tl in self.term_laws:
            if tl.kind == "factor":
                k, = tl.factors
                cols.append(X[:, k] - tl.reference if tl.reference else X[:, k])
            elif tl.kind == "clearance":
                k, kz = tl.factors
                rho, zeta = X[:, k], np.deg2rad(X[:, kz])
                cols.extend([rho * np.cos(zeta), rho * np.sin(zeta)])
        if self.has_shift:
            cols.append(np.ones(X.shape[0]))
        return np.stack(cols, axis=1)

    def feature_ops(self) -> tuple[np.ndarray, np.ndarray]:
        """How :meth:`features` makes each feature from the factors, for compiled samplers.

        Returns
        -------
        ops : ndarray, shape (F, 3), int64
            Rows ``(op, a, b)``: ``FEATURE_VALUE`` is factor a's value less
            its reference, ``FEATURE_COS`` / ``FEATURE_SIN`` are X_a cos(X_b) /
            X_a sin(X_b) with X_b in degrees, ``FEATURE_ONE`` the constant 1
            (a and b unused where they do not apply).
        refs : ndarray, shape (F,)
            The reference subtracted from a value (20 degrees C for thermal, else 0).
        """
        rows, refs = [], []
        for tl in self.term_laws:
            if tl.kind == "factor":
                rows.append((FEATURE_VALUE, tl.factors[0], tl.factors[0]))
                refs.append(tl.reference)
            elif tl.kind == "clearance":
                k, kz = tl.factors
                rows += [(FEATURE_COS, k, kz), (FEATURE_SIN, k, kz)]
                refs += [0.0, 0.0]
        if self.has_shift:
            rows.append((FEATURE_ONE, 0, 0))
            refs.append(0.0)
        return np.array(rows, dtype=np.int64).reshape(-1, 3), np.array(refs, dtype=float)

    def evaluate(self, X: np.ndarray, dtype=np.float64) -> np.ndarray:
        """Pose errors for every pose and sample, shape (..., n, 3): dx mm, dy mm, dphi rad."""
        F = self.features(X).astype(dtype, copy=False)
        return np.einsum("...of,nf->...no", self.coef.astype(dtype, copy=False), F, optimize=True)

    def feature_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact mean (F,) and covariance (F, F) of the sample features (see :meth:`features`).

        A value feature is its factor; a clearance's features (rho cos zeta,
        rho sin zeta) have moments E[rho^k] times the trigonometric moments of
        zeta (:func:`~prp3mc.model.laws.angle_moments`); the constant of
        the shifts has mean 1 and no variance. Features of different factors
        are independent unless the budget correlates their factors; then, as a
        contact angle is never correlated, they covary through the factors'
        covariance (:meth:`Budget.covariance`) times E[cos zeta] or E[sin zeta]
        for a clearance's features.
        """
        fmean, blocks, factor, loading = [], [], [], []
        for tl in self.term_laws:
            if tl.kind == "factor":
                fmean.append(tl.law.mean - tl.reference)
                blocks.append(np.array([[tl.law.var]]))
                factor.append(tl.factors[0])
                loading.append(1.0)
            elif tl.kind == "clearance":
                k = tl.factors[0]
                rho, zeta = tl.law, tl.zeta
                ec, es, ecc, ess, ecs = angle_moments(zeta)
                r1, r2 = rho.mean, rho.var + rho.mean**2
                m = np.array([r1 * ec, r1 * es])
                fmean.extend(m)
                blocks.append(r2 * np.array([[ecc, ecs], [ecs, ess]]) - np.outer(m, m))
                factor += [k, k]
                loading += [ec, es]
        if self.has_shift:
            fmean.append(1.0)
            blocks.append(np.zeros((1, 1)))
        nf = len(fmean)
        fcov = np.zeros((nf, nf))
        if self.budget.copula is not None:           # across the factors the copula correlates
            cov = self.budget.covariance()
            idx, load = np.array(factor, dtype=int), np.array(loading)
            fcov[:idx.size, :idx.size] = np.outer(load, load) * cov[np.ix_(idx, idx)]
        pos = 0
        for block in blocks:                          # within one factor (a clearance: rho with its zeta)
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
        """Value of every term per pose and sample, shape (..., n, T), boundary units (K for thermal)."""
        X = np.asarray(X, dtype=float)
        out = np.empty(self.poses.shape[:-1] + (X.shape[0], len(self.terms)))
        for t, tl in enumerate(self.term_laws):
            if tl.kind == "factor":
                out[..., t] = X[:, tl.factors[0]] - tl.reference
            elif tl.kind == "shift":
                out[..., t] = tl.value
            else:
                k, kz = tl.factors
                zeta = np.deg2rad(X[:, kz])
                out[..., t] = X[:, k] * (np.cos(zeta) * self.cos_omega[..., tl.leg, None]
                                         + np.sin(zeta) * self.sin_omega[..., tl.leg, None])
        return out


def _one_leg(h: np.ndarray, leg: int) -> np.ndarray:
    """Weights (3, ...) of a term of one leg whose h entries (legs first) are ``h``."""
    w = np.zeros_like(h)
    w[leg] = h[leg]
    return w


def linear_model(geometry: Geometry, budget: Budget, poses, *, check: bool = True) -> LinearModel:
    """Build the :class:`LinearModel` of ``budget`` at ``poses`` (..., 3).

    Poses out of stroke, with d_i <= 0 or near a singularity are refused
    (:class:`~prp3mc.errors.InfeasiblePoseError`) unless ``check=False``;
    a budget whose effects were fitted on another geometry is refused
    (:meth:`Budget.check_geometry`).
    """
    budget.check_geometry(geometry)
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses) if check else frame(geometry, poses)
    names, factors = budget.names, budget.factors
    laws = list(budget.factor_laws.values())
    terms, legs, weights, term_laws = [], [], [], []
    h = {}

    def entries(family):
        if family not in h:
            h[family] = h_entries(geometry, fr, family)
        return h[family]

    for k, name in enumerate(names):
        family, leg = parse_input(name)
        if family == "zeta":
            continue
        terms.append(name)
        legs.append(leg)
        weights.append(_one_leg(entries(family) * (1.0 if family in LENGTH_FAMILIES else DEG2RAD), leg))
        if family == "rho":
            kz = names.index(f"zeta_{leg + 1}")
            term_laws.append(TermLaw(name, "clearance", leg, law=laws[k], zeta=laws[kz], factors=(k, kz)))
        else:
            term_laws.append(TermLaw(name, "factor", leg, law=laws[k], factors=(k,)))
    b = fr.b                                                    # nominal slider positions, legs first
    for term in effect_terms(budget.effects, geometry.lead_mm):
        terms.append(term.name)
        legs.append(term.leg)
        unit = term.coefficient * (1.0 if term.family in LENGTH_FAMILIES else DEG2RAD)
        w = entries(term.family) * unit * slider_factor(term, b)
        weights.append(w if term.leg == ALL_LEGS else _one_leg(w, term.leg))
        if term.is_shift:
            term_laws.append(TermLaw(term.name, "shift", term.leg, value=term.value))
        else:
            k = factors.index(term.effect.name)
            term_laws.append(TermLaw(term.name, "factor", term.leg, law=laws[k], reference=term.reference,
                                     factors=(k,)))
    return LinearModel(geometry=geometry, budget=budget, poses=poses, terms=tuple(terms), legs=tuple(legs),
                       Ainv=np.moveaxis(fr.Ainv, (0, 1), (-2, -1)),
                       weights=np.moveaxis(np.stack(weights, axis=-1), 0, -2),
                       cos_omega=np.moveaxis(-fr.tr.sl, 0, -1), sin_omega=np.moveaxis(fr.tr.cl, 0, -1),
                       term_laws=tuple(term_laws))
