"""The library of candidate model effects and their signatures.

The effect names, their kinds and units live in
:mod:`prp3mc.model.effects` (re-exported here). This module adds
what a campaign needs: which effects it can test, each systematic effect's
*signature* (its linear pose error per unit of value, through the
sensitivity matrices J_q) and the budgets of spread effects.

A spread's value is the input's new *bound*: the largest ``|value|`` of the
scaled law's support (the upper bound of a one-sided law such as U[0, 0.025],
the half-range of a symmetric one such as U[-0.04, 0.04]); for an unbounded
law, the largest ``|mean ± 3 sd|``.

Signatures are pose errors ``[dx mm, dy mm, dphi deg]`` per unit of the
effect's value, one per measurement, since backlash and thermal effects vary
between repeats of a pose. A cyclic screw error has two signature columns,
one per real parameter of its phasor ``z = A exp(i phi)`` (the pose error is
``Re(z)`` times the first plus ``Im(z)`` times the second;
:func:`~prp3mc.model.effects.components`).
"""

from __future__ import annotations

import numpy as np

from ...model.budget import Budget
from ...model.effects import (EFFECT_NAMES, OFFSET_FAMILIES, SPREAD_FAMILIES, T_REF_C, Effect, EffectKind,
                              _as_effects,
                              components, effect, offset_errors, slider_error)
from ...errors import BudgetError, CampaignError
from ...kinematics.geometry import Geometry
from ...kinematics.chain import inverse_kinematics
from ...kinematics.sensitivity import LENGTH_FAMILIES, sensitivity
from ...units import DEG2RAD, RAD2DEG

__all__ = ["Effect", "EFFECT_NAMES", "OFFSET_FAMILIES", "SPREAD_FAMILIES", "effect", "library", "untestable",
           "signatures", "budget_effect_errors", "slider_error", "offset_errors", "spread_reference", "spread_budget",
           "T_REF_C", "ROW_TO_DEG", "components"]

#: Scale of the rows of a pose error or of J_q, ``[mm, mm, rad] -> [mm, mm, deg]``.
ROW_TO_DEG = np.array([1.0, 1.0, RAD2DEG])
ROW_TO_DEG.flags.writeable = False


def untestable(budget: Budget | None = None, has_dir=(True, True, True), has_temp: bool = True,
               has_lead=(True, True, True), spreads: bool = True) -> dict[str, str]:
    """The library effects a campaign cannot test, name -> why (:meth:`Effect.untestable`), in library order.

    Backlash of leg i needs a ``dir_i`` column, ``thermal`` needs ``temp_C``,
    a cyclic screw error of leg i the lead of its screw (``has_lead[i]``: the
    geometry's ``lead_mm``), and a spread needs its input in ``budget`` (all
    spreads if None) and a campaign that measures some pose twice (``spreads``).
    """
    columns = {f"dir_{i + 1}" for i in range(3) if has_dir[i]} | ({"temp_C"} if has_temp else set())
    inputs = None if budget is None else budget.inputs
    why = {name: effect(name).untestable(columns, has_lead, spreads, inputs) for name in EFFECT_NAMES}
    return {name: text for name, text in why.items() if text is not None}


def library(budget: Budget | None = None, has_dir=(True, True, True), has_temp: bool = True,
            has_lead=(True, True, True), spreads: bool = True) -> tuple[Effect, ...]:
    """The effects a campaign can test (the arguments as :func:`untestable`'s), in library order."""
    skip = untestable(budget, has_dir, has_temp, has_lead, spreads)
    return tuple(effect(name) for name in EFFECT_NAMES if name not in skip)


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
    ndarray, shape (M, 3, C)
        ``[dx mm, dy mm, dphi deg]`` per unit of each effect's value; C is
        the sum of the effects' :attr:`~prp3mc.model.effects.Effect.dof`
        (a cyclic error's two columns are per mm of its phasor's real and
        imaginary parts: ``sin`` and ``cos`` of ``2 pi b_i / p_i``).
    """
    effs = _as_effects(effects)
    s = sensitivity(geometry, poses, check=False)
    b, _ = inverse_kinematics(geometry, poses, check=False)
    Jb = s.J["b"] * ROW_TO_DEG[:, None]                        # (P, 3 rows, 3 legs) per mm
    bm = b[pose_index]                                         # (M, 3)
    cols = []
    for eff in effs:
        if eff.kind is EffectKind.OFFSET:                      # a parameter's own sensitivity
            col = s.J[eff.family][:, :, eff.leg] * ROW_TO_DEG
            if eff.family not in LENGTH_FAMILIES:
                col = col * DEG2RAD
            cols.append(col[pose_index])
            continue
        for unit in ((1.0, 1j) if eff.dof == 2 else (1.0,)):
            unit_db = slider_error({eff.name: unit}, bm, direction, temp_C, geometry.lead_mm)   # (M, 3) mm per unit
            cols.append(np.einsum("mol,ml->mo", Jb[pose_index], unit_db))
    return np.stack(cols, axis=2) if cols else np.empty((len(pose_index), 3, 0))


def budget_effect_errors(geometry: Geometry, budget: Budget, campaign) -> np.ndarray:
    """Pose errors of the budget's ``[effects]`` at every measurement, their drivers taken from the campaign.

    A backlash is driven by the campaign's ``dir_i``, thermal expansion by
    its ``temp_C``, a lead-screw scale and a cyclic screw error by the commanded slider positions.

    Parameters
    ----------
    geometry, budget
    campaign : Campaign

    Returns
    -------
    ndarray, shape (M, 3)
        ``[dx mm, dy mm, dphi deg]`` (zeros when the budget has no effects).

    Raises
    ------
    CampaignError
        The budget has an effect whose driver column the campaign lacks.
    BudgetError
        The budget's effects were fitted on another geometry (its ``[fitted_on]``).
    """
    effects = dict(budget.effects)
    if not effects:
        return np.zeros((campaign.n_measurements, 3))
    budget.check_geometry(geometry)
    columns = {f"dir_{i + 1}" for i in range(3) if campaign.has_dir[i]} | (
        {"temp_C"} if campaign.temp_C is not None else set())
    for name, eff in effects.items():
        missing = [col for col in eff.effect.needs if col not in columns]
        if missing:
            fitted = f" (fitted on {eff.campaign})" if eff.campaign else ""
            raise CampaignError(f"{campaign.source}: the budget's effect {name}{fitted} needs column {missing[0]}, "
                                f"which the campaign lacks: record it, or remove {name} from the budget's [effects]")
    G = signatures(geometry, campaign.poses, campaign.pose_index, list(effects), campaign.direction,
                   campaign.temp_C)
    return G @ components(list(effects), [eff.model_value for eff in effects.values()])


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
        if eff.systematic:
            continue
        if not value >= 0:
            raise BudgetError(f"{eff.name}: a spread bound must be >= 0, got {value}")
        laws[eff.budget_input] = budget.inputs[eff.budget_input].scaled(value / spread_reference(budget, eff))
    return budget.replace(**laws) if laws else budget
