"""The updated model: the named effects as a geometry and a budget every command reads.

A discrepancy analysis ends with the model the campaign supports
(docs, *File formats*):

- **the budget** (``model/budget.toml``): the fitted spreads as the inputs'
  new laws, and in its ``[effects]`` table every systematic error of the
  machine *relative to what its controller commands*: geometric offsets,
  encoder zeros ``b_i``, lead-screw scales, backlash, thermal expansion,
  cyclic screw errors (amplitude and ``phase_deg``), each with its value,
  95 % interval and the campaign (file name and sha256) it was fitted on. Effects the input budget already held carry
  over; one named again has its correction added to the old value.
- **the geometry** (``model/geometry.toml``): the identified geometry, the
  input geometry with the fitted geometric offsets applied, which is the
  geometry to load into the controller to compensate them. The budget's
  effects are relative to the controller that commanded the campaign, so
  the pair describes the machine as that controller drives it: a new
  campaign of the same machine and controller, checked against the pair,
  names nothing.
- **the compensated budget** (``model/budget_compensated.toml``): the budget
  once a controller compensates what it can (offsets, scales, thermal
  expansion with a temperature sensor, backlash with the approach direction
  known), those effects removed from ``[effects]``. Compensation is taken
  as exact at the fitted values; each compensated effect's interval less
  its value is listed beside it as the residual uncertainty (it is not in
  the file). What stays is non-compensable: the budget's random errors, the
  fitted spreads, and effects whose driver the controller lacks.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..._result import freeze, short_repr
from ...kinematics.geometry import Geometry
from ...provenance import sha256_file
from ...model.budget import Budget
from ...model.effects import EffectKind, SystematicEffect, offset_errors
from ..campaign.data import Campaign
from ..forward.signatures import effect, spread_budget

__all__ = ["UpdatedModel", "updated_model", "base_name", "MODEL_FILES"]

#: The files of the updated model, in ``DIR/model/``.
MODEL_FILES = {"geometry": "geometry.toml", "budget": "budget.toml", "compensated": "budget_compensated.toml"}
#: Added to the name of an identified geometry (once).
_SUFFIX = " identified"


def base_name(name: str) -> str:
    """A geometry's name without the suffix the updated model adds (``u-shape identified`` -> ``u-shape``)."""
    return name.removesuffix(_SUFFIX)


@dataclass(frozen=True, slots=True)
class UpdatedModel:
    """The model a campaign supports, and what a controller can compensate of it.

    Attributes
    ----------
    geometry : Geometry
        The identified geometry (input geometry, fitted geometric offsets applied).
    budget : Budget
        Fitted spreads as new laws; every systematic effect in ``effects``.
    compensated : Budget
        ``budget`` without the compensable effects.
    entries : tuple of mapping
        One per effect of the model (named by this campaign or carried over):
        ``name, kind, value, unit, ci95, named`` (by this campaign),
        ``compensable`` and ``how`` (compensable: how a controller does it,
        and ``residual95``, the interval less the value) or ``why`` (not);
        ``phase_deg`` for a cyclic error, and ``aliases`` (each one's value,
        unit and interval) for a named effect the campaign cannot tell from
        others: the files hold the named one.
    """

    geometry: Geometry
    budget: Budget
    compensated: Budget
    entries: tuple

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "geometry", "budget", "compensated")

    @property
    def compensable(self) -> tuple:
        """The entries a controller compensates."""
        return tuple(e for e in self.entries if e["compensable"])

    @property
    def non_compensable(self) -> tuple:
        """The entries no controller compensates (spreads, effects whose driver it lacks)."""
        return tuple(e for e in self.entries if not e["compensable"])

    def to_dict(self) -> dict:
        """The ``model`` entry of ``discrepancy.json``: files, compensable and non-compensable effects."""
        return {"files": {k: f"model/{v}" for k, v in MODEL_FILES.items()},
                "geometry": self.geometry.name, "budget": self.budget.name,
                "compensable": [dict(e) for e in self.compensable],
                "non_compensable": [dict(e) for e in self.non_compensable],
                "compensation": "taken as exact at the fitted values: the compensated budget leaves the "
                                "compensable effects out, and residual95 (ci95 less the value) is the residual "
                                "uncertainty of each"}

    def write(self, folder: str | os.PathLike) -> Path:
        """Write ``geometry.toml``, ``budget.toml`` and ``budget_compensated.toml`` into ``folder``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.geometry.to_toml(folder / MODEL_FILES["geometry"])
        self.budget.to_toml(folder / MODEL_FILES["budget"])
        self.compensated.to_toml(folder / MODEL_FILES["compensated"])
        return folder


def _campaign_record(campaign: Campaign) -> tuple[str, str | None]:
    """File name and sha256 of the campaign (its source label and None when it is not a file)."""
    path = Path(campaign.source)
    return (path.name, sha256_file(path)) if path.is_file() else (campaign.source, None)


def _compensable(kind: EffectKind, knows: dict) -> tuple[bool, str]:
    """Whether a controller compensates an effect of ``kind``, and how (or why not): a factor only when the
    controller ``knows`` its driver (kind -> bool)."""
    if not kind.systematic or (kind.is_factor and not knows[kind]):
        return False, kind.uncompensated
    return True, kind.compensation


def _aliases(named) -> dict:
    """``{"aliases": {name: {value, unit, ci95}}}`` of a named effect the campaign cannot tell from others (the
    model files hold the named one), or ``{}``."""
    if named is None or not named.aliases:
        return {}
    fits = named.evidence["alias_fits"]
    return {"aliases": {a: {k: fits[a][k] for k in ("value", "unit", "ci95")} for a in named.aliases}}


def updated_model(geometry: Geometry, budget: Budget, named_effects, campaign: Campaign, *,
                  temperature_sensor: bool = True, approach_known: bool = True) -> UpdatedModel:
    """The updated model of a discrepancy analysis (see the module notes).

    Parameters
    ----------
    geometry, budget
        What the campaign was analysed with.
    named_effects : sequence of NamedEffect
        The named effects: systematic values are corrections to the
        budget's ``[effects]`` (the effect itself when the budget lacks it),
        spreads the inputs' new bounds.
    campaign : Campaign
        The campaign (its file name and sha256 are recorded with each
        effect; its temperature range becomes thermal's ``temp_range_C``
        unless the budget states one).
    temperature_sensor, approach_known : bool
        Whether the controller reads the temperature and knows its approach
        directions (thermal expansion and backlash are compensable only then).

    Returns
    -------
    UpdatedModel
    """
    source, sha = _campaign_record(campaign)
    spreads = {e.name: e.value for e in named_effects if not effect(e.name).systematic}
    new_budget = spread_budget(budget, spreads)
    knows = {EffectKind.THERMAL: temperature_sensor, EffectKind.BACKLASH: approach_known}   # the factors' drivers
    effects, named = {}, set()
    for e in named_effects:
        eff = effect(e.name)
        if not eff.systematic:
            continue
        named.add(e.name)
        old = budget.effects.get(e.name)
        base = old.value if old is not None else 0.0
        temps = None
        if eff.kind is EffectKind.THERMAL:
            temps = old.temp_range_C if old is not None else (float(np.min(campaign.temp_C)),
                                                               float(np.max(campaign.temp_C)))
        if eff.dof == 2:     # a cyclic error's amplitude and phase: a correction adds as a phasor (evidence's total)
            ev = e.evidence
            value, phase, ci = ((ev["total"], ev["total_phase_deg"], tuple(ev["total_ci95"])) if old is not None
                                else (e.value, e.phase_deg, e.ci95))
            effects[e.name] = SystematicEffect(e.name, value, ci95=ci, phase_deg=phase, campaign=source,
                                               campaign_sha256=sha)
            continue
        effects[e.name] = SystematicEffect(e.name, base + e.value, ci95=(base + e.ci95[0], base + e.ci95[1]),
                                           temp_range_C=temps, campaign=source, campaign_sha256=sha)
    offsets = offset_errors({e.name: e.value for e in named_effects if effect(e.name).systematic})
    name = geometry.name if geometry.name.endswith(_SUFFIX) else geometry.name + _SUFFIX
    new_geometry = geometry.replace(name=name, **{f: np.add(getattr(geometry, f), d) for f, d in offsets.items()})
    updated = new_budget.with_effects(effects, name=f"{budget.name} updated", fitted_on=new_geometry)
    entries, kept = [], {}
    for e in named_effects:
        if not effect(e.name).systematic:
            ok, text = _compensable(EffectKind.SPREAD, knows)
            entries.append({"name": e.name, "kind": EffectKind.SPREAD, "value": e.value, "unit": e.unit,
                            "ci95": list(e.ci95), "named": True, "compensable": ok, "why": text,
                            **_aliases(e)})
    for key, eff in updated.effects.items():
        kind = eff.effect.kind
        ok, text = _compensable(kind, knows)
        entry = {"name": key, "kind": kind, "value": eff.value, "unit": eff.unit,
                 "ci95": None if eff.ci95 is None else list(eff.ci95), "named": key in named, "compensable": ok}
        if eff.phase_deg is not None:
            entry["phase_deg"] = eff.phase_deg
        entry.update(_aliases(next((e for e in named_effects if e.name == key), None)))
        if ok:
            entry.update(how=text, residual95=None if eff.ci95 is None else [eff.ci95[0] - eff.value,
                                                                             eff.ci95[1] - eff.value])
        else:
            entry["why"] = text
            kept[key] = eff
        entries.append(entry)
    compensated = updated.without_effects().with_effects(kept, name=f"{budget.name} compensated",
                                                         fitted_on=new_geometry)
    return UpdatedModel(geometry=new_geometry, budget=updated, compensated=compensated, entries=tuple(entries))

