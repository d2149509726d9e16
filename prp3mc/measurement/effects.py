"""The library of candidate model effects and their signatures.

An *effect* is something the model may be missing. Systematic effects add a
deterministic pose error that is linear in one parameter, its *signature*
through the sensitivity matrices J_q; dispersion effects change the spread of
one budget input.

======================= ====================================== ===========
effect                  what it changes                         unit
======================= ====================================== ===========
``q_i`` (q in a, alpha, constant offset of parameter q of leg i  mm or deg
beta, gamma, theta, c,  (``b_i``: encoder zero offset)
e, psi, b)
``scale_i``             slider error delta b_i = kappa_i b_i    1
``backlash_i``          delta b_i = dir_i h_i / 2, h_i >= 0     mm
``thermal``             delta b_i = alpha_T (temp_C - 20) b_i   1/K
``spread_q_i`` (q in    the law of budget input q_i, scaled      mm or deg
rho, theta, b)          about 0 to a new bound
======================= ====================================== ===========

A spread's value is the input's new *bound*: the largest ``|value|`` of the
scaled law's support (the upper bound of a one-sided law such as U[0, 0.025],
the half-range of a symmetric one such as U[-0.04, 0.04]); for an unbounded
law, the largest ``|mean ± 3 sd|``.

Signatures are pose errors ``[dx mm, dy mm, dphi deg]`` per unit of the
effect's value, one per measurement, since backlash and thermal effects vary
between repeats of a pose.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..uncertainty.budget import Budget
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from ..kinematics.chain import inverse_kinematics
from ..kinematics.sensitivity import LENGTH_FAMILIES, sensitivity
from ..units import DEG2RAD, RAD2DEG

__all__ = ["Effect", "EFFECT_NAMES", "OFFSET_FAMILIES", "SPREAD_FAMILIES", "effect", "library",
           "signatures", "slider_error", "offset_errors", "spread_reference", "spread_budget",
           "T_REF_C", "ROW_TO_DEG"]

#: Parameters whose constant offset is a library effect (``b``: encoder zero offset).
OFFSET_FAMILIES = ("a", "alpha", "beta", "gamma", "theta", "c", "e", "psi", "b")
#: Budget inputs whose spread is a library effect.
SPREAD_FAMILIES = ("rho", "theta", "b")
#: Reference temperature of the thermal effect, degrees C.
T_REF_C = 20.0
_LEGS = (1, 2, 3)
#: Scale of the rows of a pose error or of J_q, ``[mm, mm, rad] -> [mm, mm, deg]``.
ROW_TO_DEG = np.array([1.0, 1.0, RAD2DEG])
ROW_TO_DEG.flags.writeable = False

#: Every effect name of the library, in library order.
EFFECT_NAMES = (tuple(f"{q}_{i}" for q in OFFSET_FAMILIES for i in _LEGS)
                + tuple(f"scale_{i}" for i in _LEGS) + tuple(f"backlash_{i}" for i in _LEGS)
                + ("thermal",) + tuple(f"spread_{q}_{i}" for q in SPREAD_FAMILIES for i in _LEGS))

_PATTERN = re.compile(r"^(?:(spread)_)?([a-z]+)_([123])$")


@dataclass(frozen=True, slots=True)
class Effect:
    """One effect of the library.

    Attributes
    ----------
    name : str
        Library name, e.g. ``beta_2``, ``backlash_1``, ``spread_b_3``.
    kind : str
        ``offset``, ``scale``, ``backlash``, ``thermal`` or ``spread``.
    family : str or None
        Parameter family (``b`` for the slider effects, the input family of a
        spread; None for ``thermal``).
    leg : int or None
        0-based leg (None for ``thermal``).
    unit : str
        Unit of the effect's value: ``mm``, ``deg``, ``1`` or ``1/K``.
    """

    name: str
    kind: str
    family: str | None
    leg: int | None
    unit: str

    @property
    def systematic(self) -> bool:
        """True for effects that add a deterministic pose error (all but spreads)."""
        return self.kind != "spread"

    @property
    def needs(self) -> tuple[str, ...]:
        """Optional campaign columns the effect needs."""
        if self.kind == "backlash":
            return (f"dir_{self.leg + 1}",)
        if self.kind == "thermal":
            return ("temp_C",)
        return ()

    @property
    def budget_input(self) -> str | None:
        """The budget input a spread changes (None for systematic effects)."""
        return f"{self.family}_{self.leg + 1}" if self.kind == "spread" else None


def effect(name: str) -> Effect:
    """Parse an effect name of the library; :class:`BudgetError` names the known ones otherwise."""
    if name == "thermal":
        return Effect("thermal", "thermal", None, None, "1/K")
    m = _PATTERN.match(str(name))
    if m and name in EFFECT_NAMES:
        spread, family, leg = m.group(1), m.group(2), int(m.group(3)) - 1
        if spread:
            unit = "mm" if family in LENGTH_FAMILIES else "deg"
            return Effect(name, "spread", family, leg, unit)
        if family in ("scale", "backlash"):
            return Effect(name, family, "b", leg, "1" if family == "scale" else "mm")
        return Effect(name, "offset", family, leg, "mm" if family in LENGTH_FAMILIES else "deg")
    raise BudgetError(f"unknown effect {name!r}: the library has "
                      "q_i for q in a, alpha, beta, gamma, theta, c, e, psi, b; scale_i; backlash_i; "
                      "thermal; spread_rho_i, spread_theta_i, spread_b_i (i = 1, 2, 3)")


def library(budget: Budget | None = None, has_dir=(True, True, True), has_temp: bool = True) -> tuple[Effect, ...]:
    """The effects a campaign can test.

    Backlash of leg i needs a ``dir_i`` column, ``thermal`` needs ``temp_C``,
    and a spread needs its input in ``budget`` (all spreads if None).
    """
    out = []
    for name in EFFECT_NAMES:
        eff = effect(name)
        if eff.kind == "backlash" and not has_dir[eff.leg]:
            continue
        if eff.kind == "thermal" and not has_temp:
            continue
        if eff.kind == "spread" and budget is not None and eff.budget_input not in budget.inputs:
            continue
        out.append(eff)
    return tuple(out)


def _as_effects(effects) -> list[Effect]:
    return [e if isinstance(e, Effect) else effect(e) for e in effects]


def slider_error(values: dict, b: np.ndarray, direction: np.ndarray | None = None,
                 temp_C: np.ndarray | None = None) -> np.ndarray:
    """Slider position errors delta b of the slider effects in ``values``.

    Parameters
    ----------
    values : dict of str to float
        Effect name to value; effects other than ``b_i``, ``scale_i``,
        ``backlash_i`` and ``thermal`` are ignored.
    b : ndarray, shape (M, 3)
        Commanded slider positions, mm.
    direction : ndarray, shape (M, 3), optional
        Approach direction of each actuator, +-1 (needed by backlash).
    temp_C : ndarray, shape (M,), optional
        Temperature (needed by thermal).

    Returns
    -------
    ndarray, shape (M, 3)
        delta b, mm.
    """
    out = np.zeros(np.shape(b))
    for eff, value in zip(_as_effects(values), values.values()):
        if eff.kind == "offset" and eff.family == "b":
            out[:, eff.leg] += value
        elif eff.kind == "scale":
            out[:, eff.leg] += value * b[:, eff.leg]
        elif eff.kind == "backlash":
            if direction is None:
                raise BudgetError(f"{eff.name} needs approach directions dir_{eff.leg + 1}")
            out[:, eff.leg] += 0.5 * value * direction[:, eff.leg]
        elif eff.kind == "thermal":
            if temp_C is None:
                raise BudgetError("thermal needs temperatures temp_C")
            out += value * (np.asarray(temp_C)[:, None] - T_REF_C) * b
    return out


def offset_errors(values: dict) -> dict[str, np.ndarray]:
    """Constant geometric offsets of ``values`` (except ``b_i``) as ``exact_pose_error`` errors (3,) per family."""
    out: dict[str, np.ndarray] = {}
    for eff, value in zip(_as_effects(values), values.values()):
        if eff.kind == "offset" and eff.family != "b":
            out.setdefault(eff.family, np.zeros(3))[eff.leg] += value
    return out


def signatures(geometry: Geometry, poses: np.ndarray, pose_index: np.ndarray, effects,
               direction: np.ndarray | None = None, temp_C: np.ndarray | None = None) -> np.ndarray:
    """Linear pose-error signatures of systematic effects, one per measurement.

    Parameters
    ----------
    geometry : Geometry
    poses : ndarray, shape (P, 3)
        Distinct commanded poses ``[x_mm, y_mm, phi_deg]``.
    pose_index : ndarray of int, shape (M,)
        Pose of each measurement.
    effects : sequence of str or Effect, length K
        Systematic effects.
    direction : ndarray, shape (M, 3), optional
    temp_C : ndarray, shape (M,), optional

    Returns
    -------
    ndarray, shape (M, 3, K)
        ``[dx mm, dy mm, dphi deg]`` per unit of each effect's value.
    """
    effs = _as_effects(effects)
    s = sensitivity(geometry, poses, check=False)
    b, _ = inverse_kinematics(geometry, poses, check=False)
    Jb = s.J["b"] * ROW_TO_DEG[:, None]                        # (P, 3 rows, 3 legs) per mm
    bm = b[pose_index]                                         # (M, 3)
    out = np.empty((len(pose_index), 3, len(effs)))
    for k, eff in enumerate(effs):
        if eff.kind == "offset":
            col = s.J[eff.family][:, :, eff.leg] * ROW_TO_DEG
            if eff.family not in LENGTH_FAMILIES:
                col = col * DEG2RAD
            out[:, :, k] = col[pose_index]
            continue
        unit_db = slider_error({eff.name: 1.0}, bm, direction, temp_C)     # (M, 3) mm per unit
        out[:, :, k] = np.einsum("mol,ml->mo", Jb[pose_index], unit_db)
    return out


def spread_reference(budget: Budget, eff: Effect | str) -> float:
    """Current bound of the input a spread effect changes (see the module notes), its unit."""
    eff = eff if isinstance(eff, Effect) else effect(eff)
    law = budget.inputs.get(eff.budget_input)
    if law is None:
        raise BudgetError(f"{eff.name}: the budget has no input {eff.budget_input}")
    lo, hi = law.bounds(3.0)
    ref = float(max(abs(lo), abs(hi)))
    if not ref > 0:
        raise BudgetError(f"{eff.name}: input {eff.budget_input} has a zero law; it cannot be scaled")
    return ref


def spread_budget(budget: Budget, values: dict) -> Budget:
    """``budget`` with the inputs of the spread effects in ``values`` scaled to their new bounds."""
    laws = {}
    for eff, value in zip(_as_effects(values), values.values()):
        if eff.kind != "spread":
            continue
        if not value >= 0:
            raise BudgetError(f"{eff.name}: a spread bound must be >= 0, got {value}")
        laws[eff.budget_input] = budget.inputs[eff.budget_input].scaled(value / spread_reference(budget, eff))
    return budget.replace(**laws) if laws else budget
