"""Error budgets: named error inputs, each with a law, plus Sobol groups.

Inputs are named ``<family>_<leg>`` with the ten error families of the model
(``a, alpha, b, beta, rho, c, gamma, theta, e, psi``) and ``zeta_<leg>``, the
contact angle of clearance ``rho_<leg>``. Lengths are in mm and angles in
degrees. The preset ``paper`` is the source paper's non-compensable budget
(clearances, guide play, encoder least counts; docs, *File formats*).
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._toml import dumps_toml, load_spec, load_toml
from ..output import write_text
from .._result import FrozenDict
from ..errors import BudgetError, IncompleteBudgetWarning, ParameterError, UnknownPresetError
from .catalogue import Catalogue
from .copula import GaussianCopula, parse_correlation
from .laws import Law, law_from_dict
from .effects import (ALL_LEGS, WEIGHT_ONE, FittedOn, SystematicEffect, check_leads, effect_factors, effect_terms,
                      effects_from_dict, slider_factor)
from ..kinematics.geometry import Geometry
from ..kinematics.sensitivity import LENGTH_FAMILIES

__all__ = ["Budget", "Catalogue", "input_unit", "parse_input", "BUDGET_PRESETS", "SANITY_LIMITS"]

_NAME = re.compile(r"^(a|alpha|b|beta|rho|c|gamma|theta|e|psi|zeta)_([123])$")
_FAMILY_ORDER = ("a", "alpha", "b", "beta", "rho", "zeta", "c", "gamma", "theta", "e", "psi")
#: Largest magnitude an error input may take, per unit: an error beyond the machine's own size
#: (links of 100-300 mm) or beyond two turns is a mistake, and it would overflow the results.
#: (A contact angle range may wrap through 0 deg, e.g. zeta from 300 to 400 deg.)
SANITY_LIMITS = {"mm": 1000.0, "deg": 720.0}
SAMPLE_BLOCK = 1 << 16  # samples drawn per block: results do not depend on chunking


def parse_input(name: str) -> tuple[str, int]:
    """Family and 0-based leg of an input name such as ``theta_2``."""
    match = _NAME.match(name)
    if not match:
        raise BudgetError(f"unknown input {name!r}: inputs are <family>_<leg> with family in "
                          "a, alpha, b, beta, rho, c, gamma, theta, e, psi, zeta and leg 1-3")
    return match.group(1), int(match.group(2)) - 1


def _missing_text(missing: tuple[str, ...]) -> str:
    """The warning for inputs a budget names for some legs only."""
    return f"no law for {', '.join(missing)} (other legs have one): taken as exact; a budget cut short?"


def input_unit(name: str) -> str:
    """Boundary unit of an input: ``mm`` or ``deg``."""
    family, _ = parse_input(name)
    return "mm" if family in LENGTH_FAMILIES else "deg"


@dataclass(frozen=True, slots=True)
class Budget:
    """An error budget: inputs, each with a law, Sobol groups and optional rank correlations.

    Parameters
    ----------
    inputs : dict of str to Law
        Input name (``rho_1``, ``theta_2``, ``b_3``, ...) to its law, in the
        input's unit (mm or deg). A clearance ``rho_i`` needs its contact
        angle ``zeta_i``.
    groups : dict of str to tuple of str
        Named groups of inputs for grouped Sobol indices. ``clearance_i`` =
        (rho_i, zeta_i) is always present when rho_i is.
    sources : dict of str to str
        Where an input's law comes from (catalogue entries record theirs).
    name : str
    effects : dict of str to SystematicEffect
        Fitted systematic effects (the ``[effects]`` table: backlash, lead
        scale, thermal expansion, cyclic screw errors, offsets), keyed by
        their library name. Backlash and thermal add random *factors*
        (:attr:`factors`) drawn with the inputs; offsets, scales and cyclic
        errors are known shifts.
    fitted_on : FittedOn, optional
        The geometry the effects were fitted on; a budget that has one
        refuses other geometries (:meth:`check_geometry`).
    correlation : dict of str to float
        The ``[correlation]`` table as written: ``"a,b"`` (factors or user
        groups) or a group's name to a rank (Spearman) correlation in (-1, 1).
        Realised by a Gaussian copula over the factors' own laws
        (:mod:`~prp3mc.model.copula`, :attr:`copula`); empty: every
        factor independent.

    Notes
    -----
    Samples (:meth:`ppf`, :meth:`sample`, :meth:`sample_block`) and
    :meth:`means`, :meth:`variances`, :meth:`bounds` run over the factors:
    the inputs in budget order, then the effects' random factors
    (``backlash_i`` as delta b_i in mm, ``thermal`` as the temperature in
    degrees C). Without such effects the factors are the inputs.
    """

    inputs: dict
    groups: dict = field(default_factory=dict)
    sources: dict = field(default_factory=dict)
    name: str = "custom"
    effects: dict = field(default_factory=dict)
    fitted_on: FittedOn | None = None
    correlation: dict = field(default_factory=dict)
    #: The Gaussian copula of ``correlation`` (None when every factor is independent).
    copula: GaussianCopula | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        if not self.inputs:
            raise BudgetError("a budget needs at least one input")
        inputs = {}
        for key, law in self.inputs.items():
            family, leg = parse_input(key)
            if not isinstance(law, Law):
                raise BudgetError(f"input {key!r}: expected a law, got {law!r}")
            if family == "rho" and law.support[0] < 0:
                raise BudgetError(f"input {key!r}: a clearance cannot be negative (law support {law.support})")
            if law.kind == "disc" and family != "rho":
                raise BudgetError(f"input {key!r}: the disc law is the radial size of a clearance, rho_i only")
            unit = input_unit(key)
            lo, hi = law.span()
            if not max(abs(lo), abs(hi)) <= SANITY_LIMITS[unit]:
                raise BudgetError(f"input {key!r}: values up to {max(abs(lo), abs(hi)):.3g} {unit} are beyond "
                                  f"any error of this machine (limit ±{SANITY_LIMITS[unit]:g} {unit})")
            inputs[key] = law
        for key in inputs:
            family, leg = parse_input(key)
            partner = {"rho": "zeta", "zeta": "rho"}.get(family)
            if partner and f"{partner}_{leg + 1}" not in inputs:
                raise BudgetError(f"input {key!r} needs {partner}_{leg + 1}: a clearance has a size rho "
                                  "and a contact angle zeta")
        for key, eff in dict(self.effects).items():
            if not isinstance(eff, SystematicEffect) or eff.name != key:
                raise BudgetError(f"effect {key!r}: expected a SystematicEffect named {key!r}, got {eff!r}")
        if self.fitted_on is not None and not isinstance(self.fitted_on, FittedOn):
            raise BudgetError(f"fitted_on: expected a FittedOn, got {self.fitted_on!r}")
        factors = tuple(inputs) + tuple(effect_factors(self.effects))
        groups = {f"clearance_{leg + 1}": (f"rho_{leg + 1}", f"zeta_{leg + 1}")
                  for key in inputs for family, leg in [parse_input(key)] if family == "rho"}
        for gname, members in dict(self.groups).items():
            members = tuple(members)
            unknown = [m for m in members if m not in factors]
            if unknown or not members:
                raise BudgetError(f"group {gname!r}: unknown input(s) {', '.join(unknown) or '(empty group)'}")
            if gname in factors:
                raise BudgetError(f"group {gname!r} has the name of an input")
            twice = sorted({m for m in members if members.count(m) > 1})
            if twice:
                raise BudgetError(f"group {gname!r} lists {', '.join(twice)} twice")
            if gname in groups and set(groups[gname]) != set(members):
                raise BudgetError(f"group {gname!r} clashes with the clearance group of that name "
                                  f"({', '.join(groups[gname])}): name it otherwise")
            same = next((g for g, m in groups.items() if g != gname and set(m) == set(members)), None)
            if same is not None and not same.startswith("clearance_"):
                raise BudgetError(f"groups {same!r} and {gname!r} hold the same inputs ({', '.join(members)}): "
                                  "keep one")
            groups[gname] = members
        object.__setattr__(self, "copula", parse_correlation(dict(self.correlation), factors, groups))
        object.__setattr__(self, "inputs", FrozenDict(inputs))
        object.__setattr__(self, "groups", FrozenDict(groups))
        object.__setattr__(self, "sources", FrozenDict(self.sources))
        object.__setattr__(self, "effects", FrozenDict(self.effects))
        object.__setattr__(self, "correlation", FrozenDict({str(k): float(v) for k, v in self.correlation.items()}))

    # ------------------------------------------------------------ access
    @property
    def names(self) -> tuple[str, ...]:
        """Input names in budget order."""
        return tuple(self.inputs)

    def __len__(self) -> int:
        return len(self.inputs)

    @property
    def factor_laws(self) -> FrozenDict:
        """Law of every random factor: the inputs, then the effects' factors (backlash_i, thermal)."""
        extra = effect_factors(self.effects)
        return FrozenDict({**self.inputs, **extra}) if extra else self.inputs

    @property
    def factors(self) -> tuple[str, ...]:
        """Names of the random factors: the inputs, then ``backlash_i`` and ``thermal`` effects."""
        return tuple(self.factor_laws)

    def check_geometry(self, geometry: Geometry) -> None:
        """Refuse a geometry other than the one this budget's effects were fitted on (one line).

        Budgets without effects or without ``fitted_on`` apply to any
        geometry, except that a cyclic screw error needs its leg's
        ``lead_mm`` in the geometry.
        """
        check_leads(self.effects, geometry, f"budget {self.name!r}: effect ")
        if self.fitted_on is None or not self.effects:
            return
        diff = self.fitted_on.difference(geometry)
        if diff is not None:
            raise BudgetError(f"budget {self.name!r} holds effects fitted on geometry {self.fitted_on.name!r}, "
                              f"not on geometry {geometry.name!r}: {diff}; fitted effects belong to the "
                              "machine they were measured on")

    @property
    def correlated(self) -> bool:
        """Whether some factors are correlated (a ``[correlation]`` table)."""
        return self.copula is not None

    @property
    def missing_inputs(self) -> tuple[str, ...]:
        """Inputs of a family the budget names for some legs but not for all (taken as exact)."""
        present = {parse_input(name)[0] for name in self.inputs}
        return tuple(f"{family}_{leg}" for family in _FAMILY_ORDER if family in present
                     for leg in (1, 2, 3) if f"{family}_{leg}" not in self.inputs)

    @property
    def warnings(self) -> tuple[str, ...]:
        """What needs care in this budget, one line each (today: inputs missing for some legs).

        Outputs record these (``"warnings"`` in JSON, a note in reports) besides
        the :class:`~prp3mc.errors.IncompleteBudgetWarning` given when the budget is read.
        """
        return (f"budget {self.name!r}: {_missing_text(self.missing_inputs)}",) if self.missing_inputs else ()

    def replace(self, name: str | None = None, **laws: Law) -> "Budget":
        """A copy with some inputs' laws replaced or added (``theta_1=Uniform(...)``)."""
        return Budget({**self.inputs, **laws}, groups=self._user_groups(),
                      sources={k: v for k, v in self.sources.items() if k not in laws},
                      name=name or self.name, effects=self.effects, fitted_on=self.fitted_on,
                      correlation=self.correlation)

    def _user_groups(self) -> dict:
        return {k: v for k, v in self.groups.items() if not k.startswith("clearance_")}

    def with_effects(self, effects: dict, name: str | None = None,
                     fitted_on: "Geometry | FittedOn | None" = None) -> "Budget":
        """A copy with systematic effects added or replaced (``{name: SystematicEffect}``).

        Parameters
        ----------
        effects : dict of str to SystematicEffect
        name : str, optional
            The copy's name (default: this budget's).
        fitted_on : Geometry or FittedOn, optional
            The geometry the effects were fitted on (recorded as ``[fitted_on]``);
            the copy then refuses any geometry that differs from it by more
            than :data:`~prp3mc.model.effects.FIT_TOLERANCE`. Default:
            this budget's.
        """
        if isinstance(fitted_on, Geometry):
            fitted_on = FittedOn.of(fitted_on)
        return Budget(self.inputs, groups=self._user_groups(), sources=self.sources, name=name or self.name,
                      effects={**self.effects, **effects}, fitted_on=fitted_on or self.fitted_on,
                      correlation=self.correlation)

    def effects_frame(self):
        """One row per effect: effect, kind, value, unit, ci95_low, ci95_high, temp_lo_C, temp_hi_C,
        campaign, campaign_sha256, source, phase_deg (cyclic), and how the analyses take it (``enters``)."""
        import pandas as pd
        rows = [{"effect": k, "kind": e.effect.kind, "value": e.value, "unit": e.unit,
                 "ci95_low": (e.ci95 or (np.nan,) * 2)[0], "ci95_high": (e.ci95 or (np.nan,) * 2)[1],
                 "temp_lo_C": (e.temp_range_C or (np.nan,) * 2)[0], "temp_hi_C": (e.temp_range_C or (np.nan,) * 2)[1],
                 "campaign": e.campaign or "", "campaign_sha256": e.campaign_sha256 or "", "source": e.source or "",
                 "phase_deg": np.nan if e.phase_deg is None else e.phase_deg,
                 "enters": e.effect.kind.enters} for k, e in self.effects.items()]
        return pd.DataFrame(rows)

    def effects_record(self) -> dict:
        """What an output's ``inputs`` record of the effects: ``effects`` (each as in the
        TOML table) and ``fitted_on`` (the geometry's name); empty without effects."""
        if not self.effects:
            return {}
        record: dict[str, Any] = {"effects": {k: eff.to_dict() for k, eff in self.effects.items()}}
        if self.fitted_on is not None:
            record["fitted_on"] = self.fitted_on.name
        return record

    def without_effects(self) -> "Budget":
        """A copy without the ``[effects]`` table (and its ``fitted_on``): the inputs' laws alone.

        Correlations that name an effect's factor (or a group holding one) go with it.
        """
        groups = {k: v for k, v in self._user_groups().items() if set(v) <= set(self.inputs)}
        correlation = {k: v for k, v in self.correlation.items()
                       if all(n in groups or n in self.inputs for n in (p.strip() for p in k.split(",")))}
        return Budget(self.inputs, groups=groups, sources=self.sources, name=self.name, correlation=correlation)

    def scaled(self, factor: float, family: str | None = None) -> "Budget":
        """A copy with the laws of ``family`` (all but zeta if None) scaled about 0 by ``factor``."""
        new = {}
        for key, law in self.inputs.items():
            fam, _ = parse_input(key)
            if fam != "zeta" and (family is None or fam == family):
                new[key] = law.scaled(factor)
        return self.replace(name=f"{self.name} x{factor:g}" if family is None else
                            f"{self.name} {family} x{factor:g}", **new)

    # ------------------------------------------------------------ sampling
    def ppf(self, u: np.ndarray) -> np.ndarray:
        """Map independent uniforms of shape (n, D) to factor values (n, D) in mm / deg (D factors, see
        :attr:`factors`).

        A correlated budget first makes the uniforms of its correlated factors
        dependent through its Gaussian copula (:meth:`GaussianCopula.correlate`);
        then each factor's law maps its column (:meth:`marginal_ppf`).
        """
        u = np.asarray(u, dtype=float)
        laws = self.factor_laws
        if u.ndim != 2 or u.shape[1] != len(laws):
            raise ParameterError(f"expected uniforms of shape (n, {len(laws)}), got {u.shape}")
        return self.marginal_ppf(u if self.copula is None else self.copula.correlate(u))

    def marginal_ppf(self, u: np.ndarray) -> np.ndarray:
        """Each factor's inverse CDF on its column of ``u`` (n, D), without the copula: values (n, D)."""
        laws = self.factor_laws
        ut = np.ascontiguousarray(np.asarray(u, dtype=float).T)  # each law maps one contiguous row
        out = np.empty_like(ut)
        for k, law in enumerate(laws.values()):
            out[k] = law.ppf(ut[k])
        return out.T  # (n, D) whose columns are contiguous

    def sample(self, n: int, rng: "None | int | np.random.Generator" = None) -> np.ndarray:
        """``n`` independent draws of all factors (with their correlations), shape (n, D), mm / deg
        (degrees C for thermal).

        Drawn in blocks of 65536 from one generator, so the same seed gives
        the same samples whatever the caller's chunking.
        """
        rng = np.random.default_rng(rng)
        if n < 1:
            raise ParameterError(f"sample count must be positive, got {n}")
        D = len(self.factor_laws)
        out = np.empty((n, D))
        for start in range(0, n, SAMPLE_BLOCK):
            stop = min(n, start + SAMPLE_BLOCK)
            out[start:stop] = self.ppf(rng.random((stop - start, D)))
        return out

    def sample_block(self, seed: int, k: int, n: int) -> np.ndarray:
        """Block ``k`` of ``sample(n, seed)``: rows ``k * SAMPLE_BLOCK`` to the next block, mm / deg.

        Drawn alone by jumping the PCG64 stream of ``seed`` ahead past the
        blocks before it (one 64-bit draw per uniform), so blocks can be drawn
        in any order or in parallel and still equal :meth:`sample`.
        """
        start = k * SAMPLE_BLOCK
        if not 0 <= start < n:
            raise ParameterError(f"block {k} is outside a sample of {n}")
        D = len(self.factor_laws)
        bits = np.random.PCG64(seed)
        bits.advance(start * D)
        return self.ppf(np.random.Generator(bits).random((min(n - start, SAMPLE_BLOCK), D)))

    def errors(self, X: np.ndarray, b: np.ndarray | None = None,
               lead_mm: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Factor samples ``X`` (n, D) as per-family errors, mm / deg.

        The form :func:`~prp3mc.kinematics.exact.exact_pose_error` takes; a
        family the budget does not name is absent, a leg it does not name is 0.
        Without effects each family's errors are (n, 3). The effects add
        their errors: offsets to their family (``b_i`` to ``b``), backlash
        and, given the nominal slider positions ``b`` (..., 3) (mm) of the
        poses, lead scale, thermal expansion and (with the screws' leads
        ``lead_mm`` (3,), mm: :attr:`Geometry.lead_mm`) cyclic screw errors
        to ``b``, which is then (..., n, 3).
        """
        X = np.asarray(X, dtype=float)
        errors: dict[str, np.ndarray] = {}
        for k, name in enumerate(self.names):
            family, leg = parse_input(name)
            errors.setdefault(family, np.zeros((X.shape[0], 3)))[:, leg] = X[:, k]
        if not self.effects:
            return errors
        factors, n = self.factors, X.shape[0]
        for term in effect_terms(self.effects, lead_mm):            # coefficient g(b) X on its family
            x = term.value if term.is_shift else X[:, factors.index(term.effect.name)] - term.reference
            x = term.coefficient * np.broadcast_to(x, (n,))[:, None]                  # (n, 1)
            if term.weight == WEIGHT_ONE:
                g = np.ones(3)
            elif b is None:
                raise ParameterError("lead scale, thermal and cyclic effects need the nominal slider positions b")
            else:
                g = slider_factor(term, np.asarray(b, dtype=float))[..., None, :]      # (..., 1, 3)
            on_legs = np.full(3, True) if term.leg == ALL_LEGS else np.arange(3) == term.leg
            errors[term.family] = errors.get(term.family, np.zeros((n, 3))) + np.where(on_legs, x * g, 0.0)
        return errors

    def means(self) -> np.ndarray:
        """Mean of every factor (D,)."""
        return np.array([law.mean for law in self.factor_laws.values()])

    def variances(self) -> np.ndarray:
        """Variance of every factor (D,)."""
        return np.array([law.var for law in self.factor_laws.values()])

    def covariance(self) -> np.ndarray:
        """Covariance of the factors (D, D): their variances, and the copula's covariances
        (:meth:`GaussianCopula.covariance`) for correlated pairs."""
        laws = list(self.factor_laws.values())
        return np.diag(self.variances()) if self.copula is None else self.copula.covariance(laws)

    def bounds(self, k_sigma: float | None = None) -> np.ndarray:
        """Worst-case interval of every factor, shape (D, 2), mm / deg (degrees C for thermal).

        Unbounded laws need ``k_sigma`` (mean ± k·sd); otherwise BudgetError.
        """
        out = []
        for key, law in self.factor_laws.items():
            try:
                out.append(law.bounds(k_sigma))
            except BudgetError as exc:
                raise BudgetError(f"input {key!r}: {exc}") from None
        return np.array(out, dtype=float)

    # ------------------------------------------------------------ I/O
    @classmethod
    def from_preset(cls, name: str) -> "Budget":
        """A bundled budget: ``paper`` (the source paper's non-compensable budget)."""
        if name not in BUDGET_PRESETS:
            raise UnknownPresetError(f"unknown budget preset {name!r} (known: {', '.join(BUDGET_PRESETS)})")
        return cls.from_dict(BUDGET_PRESETS[name], source=f"preset {name}")

    @classmethod
    def from_dict(cls, doc: dict[str, Any], source: str = "budget",
                  catalogue: Catalogue | None = None, base: Path | None = None) -> "Budget":
        """Build from the TOML layout.

        ``name``; optional ``catalogues = [paths]`` (relative to the file);
        ``[inputs]`` mapping each input to ``{law = ..., params}`` or
        ``{catalogue = "dotted.key"}``; optional ``[groups]`` name = [inputs];
        optional ``[effects]`` of fitted systematic effects
        (:func:`~prp3mc.model.effects.effects_from_dict`) and
        ``[fitted_on]``, the geometry they were fitted on
        (:class:`~prp3mc.model.effects.FittedOn`); optional
        ``[correlation]`` of rank correlations (:mod:`~prp3mc.model.copula`).
        """
        unknown = sorted(set(doc) - {"name", "inputs", "groups", "catalogues", "effects", "fitted_on", "correlation"})
        if unknown:
            raise BudgetError(f"{source}: unknown key(s) {', '.join(unknown)} "
                              "(expected name, inputs, groups, catalogues, effects, fitted_on, correlation)")
        catalogue = (catalogue or Catalogue.bundled()).with_files(doc.get("catalogues", []), base, source)
        raw = doc.get("inputs")
        if not isinstance(raw, dict) or not raw:
            raise BudgetError(f"{source}: needs an [inputs] table with at least one input")
        inputs, sources = {}, {}
        for key, spec in raw.items():
            where = f"{source}: input {key!r}"
            family, _ = _parse_where(key, source)
            if not isinstance(spec, dict):
                raise BudgetError(f"{where}: {spec!r} is not a law: expected a table such as "
                                  "{ law = \"uniform\", lo = 0, hi = 1 }")
            if "catalogue" in spec:
                if set(spec) != {"catalogue"}:
                    raise BudgetError(f"{where}: a catalogue reference takes no other keys")
                law, meta = catalogue.law(spec["catalogue"], where)
                if meta.get("applies_to") not in (None, family):
                    raise BudgetError(f"{where}: catalogue entry {spec['catalogue']!r} applies to "
                                      f"{meta['applies_to']}, not {family}")
                sources[key] = f"{spec['catalogue']}: {meta['source']}"
            else:
                spec = dict(spec)
                if "source" in spec:
                    sources[key] = str(spec.pop("source"))
                law = law_from_dict(spec, where)
            inputs[key] = law
        groups = doc.get("groups", {})
        if not isinstance(groups, dict) or not all(isinstance(m, list) and all(isinstance(x, str) for x in m)
                                                   for m in groups.values()):
            raise BudgetError(f"{source}: [groups] must map names to lists of inputs")
        name = doc.get("name", "custom")
        if not isinstance(name, str):
            raise BudgetError(f"{source}: name must be a string, got {name!r}")
        effects = effects_from_dict(doc.get("effects", {}), source)
        fitted_on = FittedOn.from_dict(doc["fitted_on"], source) if "fitted_on" in doc else None
        try:
            budget = cls(inputs, groups=groups, sources=sources, name=name, effects=effects, fitted_on=fitted_on,
                         correlation=doc.get("correlation", {}))
        except BudgetError as exc:
            raise BudgetError(f"{source}: {exc}") from None
        if budget.missing_inputs:
            warnings.warn(f"{source}: {_missing_text(budget.missing_inputs)}", IncompleteBudgetWarning, stacklevel=2)
        return budget

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "Budget":
        path = Path(path)
        return cls.from_dict(load_toml(path), source=str(path), base=path.parent)

    @classmethod
    def load(cls, spec: "str | os.PathLike | Budget") -> "Budget":
        """A preset name, a TOML path or a Budget, as the CLI's ``--budget`` takes."""
        return load_spec(cls, spec, BUDGET_PRESETS)

    def to_dict(self) -> dict[str, Any]:
        inputs = {}
        for key, law in self.inputs.items():
            spec = law.to_dict()
            if key in self.sources:
                spec["source"] = self.sources[key]
            inputs[key] = spec
        groups = {k: list(v) for k, v in self.groups.items() if not k.startswith("clearance_")}
        doc: dict[str, Any] = {"name": self.name, "inputs": inputs}
        if groups:
            doc["groups"] = groups
        if self.effects:
            doc["effects"] = {k: eff.to_dict() for k, eff in self.effects.items()}
        if self.fitted_on is not None:
            doc["fitted_on"] = self.fitted_on.to_dict()
        if self.correlation:
            doc["correlation"] = dict(self.correlation)
        return doc

    def to_toml(self, path: str | os.PathLike) -> None:
        write_text(path, dumps_toml(self.to_dict(), header="prp3mc error budget: mm and degrees"))

    def to_frame(self):
        """One row per input: name, family, leg, unit, law, mean, sd, lo, hi, source."""
        import pandas as pd
        rows = []
        for key, law in self.inputs.items():
            family, leg = parse_input(key)
            lo, hi = law.support
            rows.append({"input": key, "family": family, "leg": leg + 1, "unit": input_unit(key),
                         "law": law.kind, "mean": law.mean, "sd": float(np.sqrt(law.var)),
                         "lo": lo, "hi": hi, "source": self.sources.get(key, "")})
        return pd.DataFrame(rows)


def _parse_where(key: str, source: str) -> tuple[str, int]:
    try:
        return parse_input(key)
    except BudgetError as exc:
        raise BudgetError(f"{source}: {exc}") from None


def _paper_budget() -> dict[str, Any]:
    inputs: dict[str, Any] = {}
    for i in (1, 2, 3):
        inputs[f"rho_{i}"] = {"catalogue": "bearing_radial_clearance.paper"}
        inputs[f"zeta_{i}"] = {"law": "uniform", "lo": 0.0, "hi": 360.0}
        inputs[f"theta_{i}"] = {"catalogue": "guide_angular_play.paper"}
        inputs[f"b_{i}"] = {"catalogue": "encoder_least_count.paper"}
    return {"name": "paper", "inputs": inputs}


#: Bundled budgets; ``paper`` is the source paper's non-compensable budget.
BUDGET_PRESETS: dict[str, dict[str, Any]] = {"paper": _paper_budget()}
