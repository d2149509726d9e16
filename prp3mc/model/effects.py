"""Systematic effects: the library's effect names and the ``[effects]`` table of a budget.

An *effect* is something a model may be missing (docs, *File formats*, and
the discrepancy workflow). Systematic effects add a deterministic pose error
that is linear in one parameter; dispersion effects (spreads) change the law of
one budget input.

=============== ================================================ ===========
effect          what it changes                                  unit
=============== ================================================ ===========
``q_i``         constant offset of parameter q of leg i, q in a, mm or deg
                alpha, beta, gamma, theta, c, e, psi, b
                (``b_i``: encoder zero offset)
``scale_i``     slider error delta b_i = kappa_i b_i             1
``backlash_i``  delta b_i = dir_i h_i / 2, h_i >= 0              mm
``thermal``     delta b_i = alpha_T (temp_C - 20) b_i            1/K
``cyclic_i``    delta b_i = A_i sin(2 pi b_i / p_i + phi_i),     mm
                A_i >= 0, p_i the lead of slider i's screw
                (the geometry's ``lead_mm``)
``spread_q_i``  the law of budget input q_i (q in rho, theta,    mm or deg
                b), scaled about 0 to a new bound
=============== ================================================ ===========

A budget's ``[effects]`` table holds fitted systematic effects
(:class:`SystematicEffect`): each with its value, an optional 95 % interval and
where it came from (the campaign file and its sha256). Spreads are not
effects of that table: a fitted spread is written as the input's new law.
Thermal expansion needs the operating temperature range ``temp_range_C`` the
analyses bound it over.

A cyclic screw error has two parameters, its amplitude A_i (the effect's
value, mm) and its phase phi_i (``phase_deg``). It is linear in its *phasor*
``z = A_i exp(i phi_i)``: ``delta b_i = Im(z exp(2 pi i b_i / p_i)) =
Re(z) sin(2 pi b_i / p_i) + Im(z) cos(2 pi b_i / p_i)``, so wherever effects
are given as ``{name: value}`` (:func:`slider_error`, the simulator, the
discrepancy workflow's values) a cyclic effect's value is its phasor, a
complex number in mm (:func:`phasor`), and two cyclic errors of one screw add
as phasors. It needs the lead p_i of its leg in the geometry.

At an analysis pose (docs, *File formats*), offsets, lead scales and
cyclic screw errors are known shifts of the pose error; a backlash and the thermal expansion have a
driver that is not known there (the approach direction, the temperature), so
they enter as bounded random *factors* (:func:`effect_factors`): backlash_i is
``delta b_i = s h_i / 2`` with s = -1 or +1 equally likely, thermal is the
temperature T uniform over ``temp_range_C``, one T for all three legs.

Fitted effects belong to the machine they were measured on: a budget records
the geometry they were fitted on (:class:`FittedOn`) and refuses another.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from ..errors import BudgetError, ParameterError
from ..kinematics.geometry import Geometry
from ..kinematics.sensitivity import LENGTH_FAMILIES
from .._result import FrozenDict
from .laws import Discrete, Law, Uniform

__all__ = ["EffectKind", "WEIGHT_ONE", "WEIGHT_B", "WEIGHT_WAVE", "Effect", "EFFECT_NAMES", "OFFSET_FAMILIES", "SPREAD_FAMILIES", "T_REF_C", "effect",
           "slider_error", "offset_errors", "SystematicEffect", "effects_from_dict", "EFFECT_LIMITS",
           "effect_factors", "FittedOn", "FIT_TOLERANCE", "phasor", "amplitude_phase", "components",
           "check_leads", "lead_of", "effect_value", "ALL_LEGS", "EffectTerm", "effect_terms", "slider_factor"]

#: Parameters whose constant offset is a library effect (``b``: encoder zero offset).
OFFSET_FAMILIES = ("a", "alpha", "beta", "gamma", "theta", "c", "e", "psi", "b")
#: Budget inputs whose spread is a library effect.
SPREAD_FAMILIES = ("rho", "theta", "b")
#: Reference temperature of the thermal effect, degrees C.
T_REF_C = 20.0
_LEGS = (1, 2, 3)

#: Every effect name of the library, in library order.
EFFECT_NAMES = (tuple(f"{q}_{i}" for q in OFFSET_FAMILIES for i in _LEGS)
                + tuple(f"scale_{i}" for i in _LEGS) + tuple(f"backlash_{i}" for i in _LEGS)
                + ("thermal",) + tuple(f"cyclic_{i}" for i in _LEGS)
                + tuple(f"spread_{q}_{i}" for q in SPREAD_FAMILIES for i in _LEGS))

_PATTERN = re.compile(r"^(?:(spread)_)?([a-z]+)_([123])$")

#: The leg of a term that acts on all three legs at once (thermal expansion).
ALL_LEGS = -1
#: How an effect's pose error per unit of its value depends on the nominal slider position b_i
#: (:attr:`EffectKind.weight`): not at all; proportional to b_i; as sin(2 pi b_i / p_i + phi_i).
WEIGHT_ONE, WEIGHT_B, WEIGHT_WAVE = range(3)


class EffectKind(StrEnum):
    """The kinds of effect of the library, and what every analysis needs to know of each: the one registry.

    A member is its name as a string (``EffectKind.BACKLASH == "backlash"``);
    its attributes say how the analyses take it:

    Attributes
    ----------
    at_pose : str
        How it enters the linear model at an analysis pose
        (:class:`~prp3mc.model.linear.TermLaw`): ``"shift"``, a known constant
        term (offsets, lead scales, cyclic errors); ``"factor"``, a bounded random
        factor whose driver is unknown at a pose (backlash: the approach
        direction; thermal: the temperature); ``"law"``, a new law of a budget
        input, not a term (spreads).
    per_leg : bool
        One effect per leg; False for thermal (one temperature, every leg).
    weight : int
        :data:`WEIGHT_ONE`, :data:`WEIGHT_B` or :data:`WEIGHT_WAVE`: how its
        pose error per unit of value depends on the nominal slider position.
    dof : int
        Real parameters of its pose error: 2 for a cyclic error (its phasor), else 1.
    unit : str or None
        Unit of its value; None where it is the family's (mm or deg).
    term_unit : str or None
        Unit of its term's value X_t (None: :attr:`unit`); thermal's term is T - 20, K.
    reference : float
        Subtracted from its factor to make the term (:data:`T_REF_C` for thermal, else 0).
    needs : str or None
        The campaign column its fit needs, ``{leg}`` standing for the 1-based leg.
    nonnegative : bool
        Its value is >= 0 (a backlash width, a cyclic error's amplitude).
    enters : str
        How the analyses take it, in words (tables).
    compensation : str or None
        How a controller compensates it (the updated model, docs, *File
        formats*); None for a spread.
    uncompensated : str or None
        Why a controller leaves it: always for a spread; for a factor, when
        the controller does not know its driver (the temperature, the
        approach direction). None: always compensable.
    """

    def __new__(cls, value, at_pose, per_leg, weight, dof, unit, term_unit, reference, needs, nonnegative, enters,
                compensation, uncompensated):
        member = str.__new__(cls, value)
        member._value_ = value
        member.at_pose, member.per_leg, member.weight, member.dof = at_pose, per_leg, weight, dof
        member.unit, member.term_unit, member.reference, member.needs = unit, term_unit or unit, reference, needs
        member.nonnegative, member.enters = nonnegative, enters
        member.compensation, member.uncompensated = compensation, uncompensated
        return member

    #          at_pose   per_leg weight       dof unit   term_unit ref      needs       >= 0   enters
    #          compensation; uncompensated
    OFFSET = ("offset", "shift", True, WEIGHT_ONE, 1, None, None, 0.0, None, False, "known shift",
              "load model/geometry.toml into the controller (an encoder zero b_i: shift slider i's zero)", None)
    SCALE = ("scale", "shift", True, WEIGHT_B, 1, "1", None, 0.0, None, False, "known shift",
             "correct slider i's lead (steps per mm) by the factor 1 / (1 + kappa_i)", None)
    BACKLASH = ("backlash", "factor", True, WEIGHT_ONE, 1, "mm", None, 0.0, "dir_{leg}", True,
                "±h/2, approach unknown",
                "with the approach direction known: add dir_i h_i / 2 to slider i's command",
                "the approach direction is not known: bounded as +-h/2")
    THERMAL = ("thermal", "factor", False, WEIGHT_B, 1, "1/K", "K", T_REF_C, "temp_C", False,
               "temperature over temp_range_C",
               "with a temperature sensor: correct every slider's lead by alpha_T (T - 20 degC)",
               "the controller has no temperature sensor: bounded over temp_range_C")
    CYCLIC = ("cyclic", "shift", True, WEIGHT_WAVE, 2, "mm", None, 0.0, None, True, "known shift",
              "a screw error map of slider i: subtract A_i sin(2 pi b_i / p_i + phi_i) from its command", None)
    SPREAD = ("spread", "law", True, WEIGHT_ONE, 1, None, None, 0.0, None, True, "the input's new law",
              None, "a dispersion: random from visit to visit, no controller can predict it")

    @property
    def systematic(self) -> bool:
        """Adds a deterministic pose error (all but spreads)."""
        return self.at_pose != "law"

    @property
    def is_shift(self) -> bool:
        """A known constant term at an analysis pose."""
        return self.at_pose == "shift"

    @property
    def is_factor(self) -> bool:
        """A bounded random factor at an analysis pose (its driver is unknown there)."""
        return self.at_pose == "factor"


@dataclass(frozen=True, slots=True)
class Effect:
    """One effect of the library.

    Attributes
    ----------
    name : str
        Library name, e.g. ``beta_2``, ``backlash_1``, ``spread_b_3``.
    kind : EffectKind
        ``offset``, ``scale``, ``backlash``, ``thermal``, ``cyclic`` or ``spread``
        (a string; its attributes say how the analyses take it).
    family : str or None
        Parameter family (``b`` for the slider effects, the input family of a
        spread; None for ``thermal``).
    leg : int or None
        0-based leg (None for ``thermal``).
    unit : str
        Unit of the effect's value: ``mm``, ``deg``, ``1`` or ``1/K``.
    """

    name: str
    kind: EffectKind
    family: str | None
    leg: int | None
    unit: str

    @property
    def systematic(self) -> bool:
        """True for effects that add a deterministic pose error (all but spreads)."""
        return self.kind.systematic

    @property
    def dof(self) -> int:
        """Parameters of the effect's pose error: 2 for a cyclic error (its phasor), else 1."""
        return self.kind.dof

    @property
    def needs(self) -> tuple[str, ...]:
        """Optional campaign columns the effect needs."""
        if self.kind.needs is None:
            return ()
        return (self.kind.needs.format(leg=None if self.leg is None else self.leg + 1),)

    @property
    def budget_input(self) -> str | None:
        """The budget input a spread changes (None for systematic effects)."""
        return None if self.kind.systematic else f"{self.family}_{self.leg + 1}"

    @property
    def term(self) -> str:
        """Its term's name in a :class:`~prp3mc.model.linear.LinearModel` (``offset_`` before an offset's name)."""
        return f"offset_{self.name}" if self.kind is EffectKind.OFFSET else self.name

    def untestable(self, columns, has_lead, repeats: bool, inputs=None) -> str | None:
        """Why a campaign cannot test the effect, or None when it can.

        Parameters
        ----------
        columns : collection of str
            The campaign's optional columns (``dir_i``, ``temp_C``): a
            backlash and the thermal expansion need their driver's.
        has_lead : sequence of 3 bool
            Whether slider i's screw has a lead (the geometry's ``lead_mm``):
            a cyclic error repeats with it.
        repeats : bool
            Whether the campaign measures some pose twice: a spread is seen
            in the scatter of repeats.
        inputs : collection of str, optional
            The budget's inputs, one of which a spread scales (None: any).
        """
        missing = [column for column in self.needs if column not in columns]
        if missing:
            return f"needs {', '.join(missing)}"
        if self.kind.weight == WEIGHT_WAVE and not has_lead[self.leg]:
            return f"needs lead_mm of leg {self.leg + 1} in the geometry (the lead its screw's error repeats with)"
        if not self.systematic and not repeats:
            return "needs a pose measured twice: a dispersion is seen in the scatter of repeats"
        if not self.systematic and inputs is not None and self.budget_input not in inputs:
            return "needs its budget input"
        return None


#: The kinds whose effects are named ``kind_i`` and act on slider i's position.
_SLIDER_KINDS = (EffectKind.SCALE, EffectKind.BACKLASH, EffectKind.CYCLIC)


def effect(name: str) -> Effect:
    """Parse an effect name of the library; :class:`BudgetError` names the known ones otherwise."""
    if name == EffectKind.THERMAL:
        return Effect(name, EffectKind.THERMAL, None, None, EffectKind.THERMAL.unit)
    m = _PATTERN.match(str(name))
    if m and name in EFFECT_NAMES:
        spread, family, leg = m.group(1), m.group(2), int(m.group(3)) - 1
        own = "mm" if family in LENGTH_FAMILIES else "deg"
        if spread:
            return Effect(name, EffectKind.SPREAD, family, leg, own)
        if family in _SLIDER_KINDS:
            kind = EffectKind(family)
            return Effect(name, kind, "b", leg, kind.unit)
        return Effect(name, EffectKind.OFFSET, family, leg, own)
    raise BudgetError(f"unknown effect {name!r}: the library has "
                      "q_i for q in a, alpha, beta, gamma, theta, c, e, psi, b; scale_i; backlash_i; "
                      "thermal; cyclic_i; spread_rho_i, spread_theta_i, spread_b_i (i = 1, 2, 3)")


def _as_effects(effects) -> list[Effect]:
    return [e if isinstance(e, Effect) else effect(e) for e in effects]


def phasor(amplitude_mm: float, phase_deg: float) -> complex:
    """The phasor ``A exp(i phi)`` (mm) of a cyclic error of amplitude A (mm) and phase phi (deg)."""
    return complex(amplitude_mm * np.exp(1j * np.deg2rad(phase_deg)))


def amplitude_phase(z: complex) -> tuple[float, float]:
    """Amplitude (mm) and phase (deg, in [0, 360)) of a cyclic error's phasor ``z``."""
    return float(abs(z)), float(np.rad2deg(np.angle(z)) % 360.0)


def effect_value(name: str, value) -> float | complex:
    """An effect's value as ``{name: value}`` tables take it: a float, or a cyclic error's phasor (mm).

    A cyclic error may be given as its phasor (complex), its amplitude (phase
    0) or the pair ``(amplitude_mm, phase_deg)``.

    Raises
    ------
    BudgetError
        A value that is not a finite number (or such a pair).
    """
    eff = effect(name)
    try:
        if eff.kind is EffectKind.CYCLIC and isinstance(value, (tuple, list)):
            amplitude, phase = (float(v) for v in value)
            out = phasor(amplitude, phase)
        else:
            out = complex(value) if eff.kind is EffectKind.CYCLIC else float(value)
    except (TypeError, ValueError):
        form = "a phasor, an amplitude or (amplitude_mm, phase_deg)" if eff.kind is EffectKind.CYCLIC else "a number"
        raise BudgetError(f"effect {name!r} takes {form}, got {value!r}") from None
    if not np.isfinite(out):
        raise BudgetError(f"effect {name!r}: value must be finite, got {value!r}")
    return out


def components(effects, values) -> np.ndarray:
    """The real parameters of effects' values, in order: a value, or a phasor's real and imaginary parts.

    Parameters
    ----------
    effects : sequence of str or Effect
    values : sequence of float or complex
        One per effect (a cyclic error's phasor, mm).

    Returns
    -------
    ndarray, shape (sum of the effects' :attr:`Effect.dof`,)
        The coefficients of the effects' signature columns (:func:`~prp3mc.measurement.forward.signatures.signatures`).
    """
    out = []
    for eff, value in zip(_as_effects(effects), values):
        out += [complex(value).real, complex(value).imag] if eff.dof == 2 else [float(value)]
    return np.array(out, dtype=float)


def lead_of(eff: Effect, lead_mm, where: str = "", geometry: str | None = None) -> float:
    """The lead (mm) of the screw whose cyclic error ``eff`` is: ``lead_mm[eff.leg]``.

    ``lead_mm`` (3,), mm, or None: the screws' leads (:attr:`Geometry.lead_mm`, NaN for a leg without);
    ``where`` starts and ``geometry`` (its name) completes the one-line :class:`BudgetError` when there is none.
    """
    lead = np.nan if lead_mm is None else lead_mm[eff.leg]
    if not np.isfinite(lead):
        which = "the geometry" if geometry is None else f"geometry {geometry!r}"
        raise BudgetError(f"{where}{eff.name}: a cyclic screw error repeats with the lead of slider "
                          f"{eff.leg + 1}'s screw, and {which} has no lead_mm for leg {eff.leg + 1}: "
                          "add lead_mm to its [[leg]] table")
    return float(lead)


def check_leads(names, geometry: Geometry, where: str = "") -> None:
    """Refuse cyclic effects among ``names`` whose leg has no ``lead_mm`` in ``geometry`` (one line)."""
    for eff in _as_effects(names):
        if eff.kind.weight == WEIGHT_WAVE:
            lead_of(eff, geometry.lead_mm, where, geometry.name)


def slider_error(values: dict, b: np.ndarray, direction: np.ndarray | None = None,
                 temp_C: np.ndarray | None = None, lead_mm: np.ndarray | None = None) -> np.ndarray:
    """Slider position errors delta b of the slider effects in ``values``.

    Parameters
    ----------
    values : dict of str to float or complex
        Effect name to value (a cyclic error's phasor ``A exp(i phi)``, mm,
        or its amplitude alone for phase 0); effects other than ``b_i``,
        ``scale_i``, ``backlash_i``, ``thermal`` and ``cyclic_i`` are ignored.
    b : ndarray, shape (M, 3)
        Commanded slider positions, mm.
    direction : ndarray, shape (M, 3), optional
        Approach direction of each actuator, +-1 (needed by backlash).
    temp_C : ndarray, shape (M,), optional
        Temperature (needed by thermal).
    lead_mm : ndarray, shape (3,), optional
        Leads of the sliders' screws (needed by cyclic; :attr:`Geometry.lead_mm`).

    Returns
    -------
    ndarray, shape (M, 3)
        delta b, mm.
    """
    out = np.zeros(np.shape(b))
    for eff, value in zip(_as_effects(values), values.values()):
        if eff.kind is EffectKind.OFFSET and eff.family == "b":
            out[:, eff.leg] += value
        elif eff.kind is EffectKind.SCALE:
            out[:, eff.leg] += value * b[:, eff.leg]
        elif eff.kind is EffectKind.BACKLASH:
            if direction is None:
                raise ParameterError(f"{eff.name} needs approach directions dir_{eff.leg + 1}")
            out[:, eff.leg] += 0.5 * value * direction[:, eff.leg]
        elif eff.kind is EffectKind.THERMAL:
            if temp_C is None:
                raise ParameterError("thermal needs temperatures temp_C")
            out += value * (np.asarray(temp_C)[:, None] - T_REF_C) * b
        elif eff.kind is EffectKind.CYCLIC:
            out[:, eff.leg] += np.imag(complex(value) * np.exp(2j * np.pi * b[:, eff.leg] / lead_of(eff, lead_mm)))
    return out


def offset_errors(values: dict) -> dict[str, np.ndarray]:
    """Constant geometric offsets of ``values`` (except ``b_i``) as ``exact_pose_error`` errors (3,) per family."""
    out: dict[str, np.ndarray] = {}
    for eff, value in zip(_as_effects(values), values.values()):
        if eff.kind is EffectKind.OFFSET and eff.family != "b":
            out.setdefault(eff.family, np.zeros(3))[eff.leg] += value
    return out



#: Largest magnitude of an effect's value per unit: beyond it the value is a typing slip
#: (2.5 for 0.0025) or not a small error of this machine.
EFFECT_LIMITS = {"mm": 1000.0, "deg": 720.0, "1": 0.1, "1/K": 1e-3}
#: Operating temperatures a thermal effect may be bounded over, degrees C.
TEMP_LIMITS_C = (-100.0, 300.0)
_KEYS = ("value", "unit", "ci95", "temp_range_C", "campaign", "campaign_sha256", "source", "phase_deg")


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BudgetError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _pair(value, where: str) -> tuple[float, float] | None:
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise BudgetError(f"{where} must be a pair [lo, hi], got {value!r}")
    lo, hi = (_number(v, where) for v in value)
    if not lo <= hi:
        raise BudgetError(f"{where} must have lo <= hi, got {list(value)}")
    return lo, hi


@dataclass(frozen=True, slots=True)
class SystematicEffect:
    """One fitted systematic effect of a budget's ``[effects]`` table.

    Attributes
    ----------
    name : str
        A systematic library name: ``q_i`` offsets, ``scale_i``, ``backlash_i``, ``thermal``, ``cyclic_i``.
    value : float
        In the effect's unit (:attr:`unit`): mm, deg, 1 or 1/K; a backlash is
        its full width h_i >= 0, a cyclic error its amplitude A_i >= 0.
    ci95 : tuple of float or None
        95 % interval of the value, same unit.
    temp_range_C : tuple of float or None
        Operating temperature range, degrees C (thermal only, required there).
    campaign, campaign_sha256 : str or None
        The campaign file the value was fitted on, and its sha256.
    source : str or None
        Free text (a catalogue or a data sheet) for effects written by hand.
    phase_deg : float or None
        Phase phi_i of a cyclic error, degrees (cyclic only, required there).
    """

    name: str
    value: float
    ci95: tuple | None = None
    temp_range_C: tuple | None = None
    campaign: str | None = None
    campaign_sha256: str | None = None
    source: str | None = None
    phase_deg: float | None = None

    def __post_init__(self):
        eff = effect(self.name)
        where = f"effect {self.name!r}"
        if not eff.systematic:
            raise BudgetError(f"{where} is a spread: write it as the input's new law in [inputs], "
                              "not in [effects]")
        value = _number(self.value, f"{where}: value")
        limit = EFFECT_LIMITS[eff.unit]
        if abs(value) > limit:
            raise BudgetError(f"{where}: value {value:g} {eff.unit} is beyond any such effect of this "
                              f"machine (limit ±{limit:g} {eff.unit}); a unit slip?")
        if eff.kind is EffectKind.BACKLASH and value < 0:
            raise BudgetError(f"{where}: a backlash width h must be >= 0 mm, got {value:g}")
        if eff.kind is EffectKind.CYCLIC and value < 0:
            raise BudgetError(f"{where}: a cyclic error's amplitude must be >= 0 mm, got {value:g} "
                              "(a negative one is the phase turned by 180 deg)")
        if eff.kind is EffectKind.CYCLIC and self.phase_deg is None:
            raise BudgetError(f"{where} needs phase_deg, the phase (degrees) of delta b = A sin(2 pi b / lead + phase)")
        if eff.kind is not EffectKind.CYCLIC and self.phase_deg is not None:
            raise BudgetError(f"{where}: phase_deg applies to cyclic_i only")
        phase = None if self.phase_deg is None else _number(self.phase_deg, f"{where}: phase_deg")
        ci = _pair(self.ci95, f"{where}: ci95")
        temps = _pair(self.temp_range_C, f"{where}: temp_range_C")
        if eff.kind is EffectKind.THERMAL:
            if temps is None:
                raise BudgetError(f"{where} needs temp_range_C = [lo, hi], the operating temperatures "
                                  "(degrees C) to bound it over")
            if not (TEMP_LIMITS_C[0] <= temps[0] and temps[1] <= TEMP_LIMITS_C[1]):
                raise BudgetError(f"{where}: temp_range_C {list(temps)} is outside "
                                  f"[{TEMP_LIMITS_C[0]:g}, {TEMP_LIMITS_C[1]:g}] degrees C")
        elif temps is not None:
            raise BudgetError(f"{where}: temp_range_C applies to thermal only")
        for key in ("campaign", "campaign_sha256", "source"):
            if getattr(self, key) is not None and not isinstance(getattr(self, key), str):
                raise BudgetError(f"{where}: {key} must be a string, got {getattr(self, key)!r}")
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "ci95", ci)
        object.__setattr__(self, "temp_range_C", temps)
        object.__setattr__(self, "phase_deg", phase)

    @property
    def effect(self) -> Effect:
        """The library entry (kind, family, leg, unit)."""
        return effect(self.name)

    @property
    def unit(self) -> str:
        return self.effect.unit

    @property
    def model_value(self) -> float | complex:
        """The value as ``{name: value}`` tables take it: the value, a cyclic error's phasor (:func:`phasor`)."""
        return phasor(self.value, self.phase_deg) if self.effect.kind is EffectKind.CYCLIC else self.value

    def to_dict(self) -> dict[str, Any]:
        """The TOML table of the effect (keys left out when unset)."""
        doc: dict[str, Any] = {"value": self.value, "unit": self.unit}
        for key in _KEYS[2:]:
            value = getattr(self, key)
            if value is not None:
                doc[key] = list(value) if isinstance(value, tuple) else value
        return doc


def effects_from_dict(doc, source: str) -> FrozenDict:
    """Parse a budget's ``[effects]`` table: name -> :class:`SystematicEffect`.

    Each entry is a table with ``value`` (required) and optional ``unit``
    (checked against the effect's unit), ``ci95``, ``temp_range_C`` (thermal,
    required there), ``phase_deg`` (cyclic, required there), ``campaign``,
    ``campaign_sha256`` and ``source``.
    """
    if not isinstance(doc, dict):
        raise BudgetError(f"{source}: [effects] must be a table of effects, got {doc!r}")
    out = {}
    for name, spec in doc.items():
        where = f"{source}: effect {name!r}"
        try:
            eff = effect(name)
        except BudgetError as exc:
            raise BudgetError(f"{source}: {exc}") from None
        if not isinstance(spec, dict):
            raise BudgetError(f"{where} must be a table such as {{ value = 0.01 }}, got {spec!r}")
        unknown = sorted(set(spec) - set(_KEYS))
        if unknown:
            raise BudgetError(f"{where}: unknown key(s) {', '.join(unknown)} (expected {', '.join(_KEYS)})")
        if "value" not in spec:
            raise BudgetError(f"{where} needs a value")
        if "unit" in spec and spec["unit"] != eff.unit:
            raise BudgetError(f"{where}: unit {spec['unit']!r} is not the effect's unit {eff.unit!r}")
        fields_ = {k: v for k, v in spec.items() if k != "unit"}
        try:
            out[name] = SystematicEffect(name, **fields_)
        except BudgetError as exc:
            raise BudgetError(f"{source}: {exc}") from None
    return FrozenDict(out)


@dataclass(frozen=True, slots=True)
class EffectTerm:
    """How one systematic effect of a budget enters the pose error: the one description every analysis reads.

    The effect adds ``coefficient * g(b_i) * X`` to parameter ``family`` of
    leg ``leg`` (of every leg for :data:`ALL_LEGS`), in that family's unit
    (mm or deg), where X is the term's value and g(b_i) is 1, the nominal
    slider position b_i (mm), or ``sin(wavenumber b_i + phase)`` as
    ``weight`` says (:func:`slider_factor`).

    Attributes
    ----------
    name : str
        The term's name (:attr:`Effect.term`).
    effect : Effect
    family : str
        The parameter it changes: the offset's family, ``b`` for the slider effects.
    leg : int
        0-based leg or :data:`ALL_LEGS`.
    coefficient : float
        alpha_T (1/K) for thermal expansion, else 1.
    weight : int
        :data:`WEIGHT_ONE`, :data:`WEIGHT_B` or :data:`WEIGHT_WAVE`.
    wavenumber, phase : float
        2 pi / p_i (rad per mm) and phi_i (rad) of a cyclic error, else 0.
    value : float
        X of a known shift (the effect's value: a cyclic error's amplitude, mm); 0 for a factor.
    reference : float
        For a factor, X is the factor less this (T - 20 for thermal).
    """

    name: str
    effect: Effect
    family: str
    leg: int
    coefficient: float
    weight: int
    wavenumber: float
    phase: float
    value: float
    reference: float

    @property
    def is_shift(self) -> bool:
        """X is known (a shift), not a random factor of the budget."""
        return self.effect.kind.is_shift


def effect_terms(effects: dict, lead_mm=None) -> tuple[EffectTerm, ...]:
    """The terms of a budget's systematic ``effects`` (name -> :class:`SystematicEffect`), in library order.

    ``lead_mm`` (3,), mm: the screws' leads (:attr:`Geometry.lead_mm`), needed by cyclic errors.
    """
    out = []
    for name in (n for n in EFFECT_NAMES if n in effects):
        eff = effects[name]
        e, kind = eff.effect, eff.effect.kind
        wave = (0.0, 0.0)
        if kind.weight == WEIGHT_WAVE:
            wave = (2.0 * math.pi / lead_of(e, lead_mm), math.radians(eff.phase_deg))
        out.append(EffectTerm(e.term, e, e.family or "b", e.leg if kind.per_leg else ALL_LEGS,
                              eff.value if kind is EffectKind.THERMAL else 1.0, kind.weight, *wave,   # alpha_T (T - 20)
                              eff.value if kind.is_shift else 0.0, kind.reference))
    return tuple(out)


def slider_factor(term: EffectTerm, b: np.ndarray) -> np.ndarray | float:
    """g(b) of ``term``: 1, ``b`` or ``sin(wavenumber b + phase)``, shaped like the slider positions ``b`` (mm)."""
    if term.weight == WEIGHT_B:
        return b
    if term.weight == WEIGHT_WAVE:
        return np.sin(term.wavenumber * b + term.phase)
    return 1.0


def effect_factors(effects: dict) -> dict[str, Law]:
    """The random factors of a budget's effects, in library order: name -> law.

    ``backlash_i``: the slider error delta b_i itself, -h_i/2 or +h_i/2 with
    probability 1/2 each (mm); ``thermal``: the temperature T, uniform over
    ``temp_range_C`` (degrees C). Offsets, scales and cyclic errors have no random factor.
    """
    out: dict[str, Law] = {}
    for name in EFFECT_NAMES:
        eff = effects.get(name)
        if eff is None:
            continue
        if eff.effect.kind is EffectKind.BACKLASH:
            out[name] = Discrete((-0.5 * eff.value, 0.5 * eff.value), (0.5, 0.5))
        elif eff.effect.kind is EffectKind.THERMAL:
            out[name] = Uniform(*eff.temp_range_C)
    return out


#: Largest difference of a leg parameter between the geometry a budget's effects were fitted on and
#: the geometry the budget is used with: more than fitted offsets of that machine could explain.
FIT_TOLERANCE = {"mm": 1.0, "deg": 1.0}
_FIT_KEYS = tuple(f"{k}_{'mm' if k in LENGTH_FAMILIES else 'deg'}"
                  for k in ("a", "alpha", "beta", "gamma", "theta", "c", "e", "psi"))


@dataclass(frozen=True, slots=True)
class FittedOn:
    """The geometry a budget's effects were fitted on: its name and leg parameters (the fingerprint).

    The TOML table ``[fitted_on]`` holds ``name`` and one list of three
    values (legs 1-3) per parameter: ``a_mm, alpha_deg, beta_deg, gamma_deg,
    theta_deg, c_mm, e_mm, psi_deg`` (strokes do not change the model), and
    ``lead_mm`` when a leg of the geometry has a screw lead (0 for a leg
    without: a cyclic error's phase runs with its leg's lead).

    Attributes
    ----------
    name : str
    legs : dict of str to tuple of 3 float
        Parameter key (as above) to its values for legs 1-3, mm or deg.
    lead : tuple of 3 (float or None)
        Each leg's screw lead, mm, None where the geometry had none (or the
        record is older than leads).
    """

    name: str
    legs: dict
    lead: tuple = (None, None, None)

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise BudgetError(f"fitted_on: name must be a string, got {self.name!r}")
        if set(self.legs) != set(_FIT_KEYS):
            missing = [k for k in _FIT_KEYS if k not in self.legs]
            extra = sorted(set(self.legs) - set(_FIT_KEYS))
            raise BudgetError("fitted_on needs " + ", ".join(_FIT_KEYS)
                              + (f"; missing {', '.join(missing)}" if missing else "")
                              + (f"; unknown {', '.join(extra)}" if extra else ""))
        legs = {}
        for key in _FIT_KEYS:
            values = self.legs[key]
            if not isinstance(values, (list, tuple)) or len(values) != 3:
                raise BudgetError(f"fitted_on: {key} must list three values (legs 1-3), got {values!r}")
            legs[key] = tuple(_number(v, f"fitted_on: {key}") for v in values)
        object.__setattr__(self, "legs", FrozenDict(legs))
        if not isinstance(self.lead, (list, tuple)) or len(self.lead) != 3:
            raise BudgetError(f"fitted_on: lead_mm must list three values (legs 1-3), got {self.lead!r}")
        lead = tuple(None if p is None else _number(p, "fitted_on: lead_mm") for p in self.lead)
        if any(p is not None and p < 0 for p in lead):
            raise BudgetError(f"fitted_on: lead_mm must be >= 0 mm (0: no lead), got {list(self.lead)!r}")
        object.__setattr__(self, "lead", tuple(None if p is None or p == 0 else p for p in lead))

    @classmethod
    def of(cls, geometry: Geometry) -> "FittedOn":
        """The fingerprint of ``geometry``."""
        return cls(geometry.name, {key: getattr(geometry, key.rsplit("_", 1)[0]) for key in _FIT_KEYS},
                   tuple(geometry.lead))

    @classmethod
    def from_dict(cls, doc, source: str) -> "FittedOn":
        """Parse a ``[fitted_on]`` table (errors name ``source``)."""
        if not isinstance(doc, dict):
            raise BudgetError(f"{source}: [fitted_on] must be a table (name and the legs' parameters), got {doc!r}")
        try:
            return cls(doc.get("name", "custom"), {k: v for k, v in doc.items() if k not in ("name", "lead_mm")},
                       doc.get("lead_mm", (None, None, None)))
        except BudgetError as exc:
            raise BudgetError(f"{source}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        doc = {"name": self.name, **{k: list(v) for k, v in self.legs.items()}}
        if any(p is not None for p in self.lead):
            doc["lead_mm"] = [0.0 if p is None else p for p in self.lead]
        return doc

    def difference(self, geometry: Geometry) -> str | None:
        """The largest departure of ``geometry`` beyond :data:`FIT_TOLERANCE`, as text, or None."""
        worst, text = 0.0, None
        for key in _FIT_KEYS:
            unit = key.rsplit("_", 1)[1]
            diff = np.abs(np.subtract(getattr(geometry, key.rsplit("_", 1)[0]), self.legs[key]))
            if unit == "deg":
                diff = np.abs((diff + 180.0) % 360.0 - 180.0)
            leg = int(np.argmax(diff))
            ratio = diff[leg] / FIT_TOLERANCE[unit]
            if ratio > 1.0 and ratio > worst:
                worst = ratio
                text = (f"{key} of leg {leg + 1} is {getattr(geometry, key.rsplit('_', 1)[0])[leg]:g} in "
                        f"{geometry.name!r} and {self.legs[key][leg]:g} in {self.name!r} "
                        f"(more than {FIT_TOLERANCE[unit]:g} {unit} apart)")
        for leg, (fitted, now) in enumerate(zip(self.lead, geometry.lead)):
            if text is None and fitted is not None and now is not None and not np.isclose(fitted, now, rtol=1e-9):
                text = (f"lead_mm of leg {leg + 1} is {now:g} in {geometry.name!r} and {fitted:g} in {self.name!r} "
                        "(a cyclic error's phase runs with the lead it was fitted on)")
        return text
