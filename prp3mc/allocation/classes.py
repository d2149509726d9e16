"""The menu of tolerance classes an allocation chooses from (the classes file: docs, *File formats*).

A classes file lists, per input family, the classes every leg may take, each
with a law (from the catalogue or written inline) and the user's cost::

    [rho]                  # rho_1, rho_2, rho_3; zeta_i stays uniform on 0-360 deg
    classes = [
      { name = "C2", catalogue = "bearing_radial_clearance.bore_10_18.C2", cost = 4.0 },
      { name = "CN", catalogue = "bearing_radial_clearance.bore_10_18.CN", cost = 1.0 },
    ]
    [theta]
    classes = [{ name = "fine", law = "uniform", lo = -0.01, hi = 0.01, cost = 6.0 }]

Optional top-level keys: ``name`` and ``catalogues = [paths]`` (relative to
the file), as in a budget file. Every leg chooses independently.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from .._result import freeze
from .._toml import load_spec, load_toml, loads_toml
from ..errors import AllocationError, BudgetError, UnknownPresetError
from ..model.budget import Budget, Catalogue
from ..model.laws import Law, Uniform, law_from_dict

__all__ = ["ToleranceClass", "ClassMenu", "ALLOCATABLE", "CLASSES_PRESETS"]

#: Families a classes file may list (zeta_i is the contact angle, always uniform on 0-360 deg).
ALLOCATABLE = ("a", "alpha", "b", "beta", "rho", "c", "gamma", "theta", "e", "psi")
#: Bundled classes files, by preset name.
CLASSES_PRESETS = {"example": "data/classes_example.toml"}
_FULL_TURN = Uniform(0.0, 360.0)


@dataclass(frozen=True, slots=True)
class ToleranceClass:
    """One class of a family: its name, law (mm or deg), the user's cost and where the law comes from."""

    name: str
    law: Law
    cost: float
    source: str = ""

    def __repr__(self) -> str:
        return f"ToleranceClass({self.name!r}, {self.law.kind}, cost={self.cost:g})"


@dataclass(frozen=True, slots=True)
class ClassMenu:
    """Classes per input family; every leg of a listed family chooses one of them.

    Parameters
    ----------
    families : dict of str to tuple of ToleranceClass
        Family (``rho``, ``theta``, ``b``, ...) to its classes, in file order.
    name : str
    """

    families: dict
    name: str = "classes"

    def __post_init__(self):
        if not self.families:
            raise AllocationError("a classes menu needs at least one family")
        for family, classes in self.families.items():
            if family not in ALLOCATABLE:
                raise AllocationError(f"unknown family {family!r}" + (
                    " (zeta_i stays uniform on 0-360 deg)" if family == "zeta" else
                    f" (allocatable: {', '.join(ALLOCATABLE)})"))
            if not classes:
                raise AllocationError(f"[{family}]: empty class list")
            names = [c.name for c in classes]
            if len(set(names)) != len(names):
                raise AllocationError(f"[{family}]: class names must be unique, got {names}")
            for c in classes:
                if not (math.isfinite(c.cost) and c.cost >= 0):
                    raise AllocationError(f"[{family}] class {c.name!r}: cost must be a finite number >= 0, "
                                          f"got {c.cost!r}")
                if family == "rho" and c.law.support[0] < 0:
                    raise AllocationError(f"[rho] class {c.name!r}: a clearance cannot be negative")
        object.__setattr__(self, "families", {f: tuple(c) for f, c in self.families.items()})
        freeze(self)

    def __repr__(self) -> str:
        return f"ClassMenu(name={self.name!r}, families={list(self.families)})"

    @property
    def inputs(self) -> tuple[str, ...]:
        """Input names chosen for, family by family, legs 1-3: ``rho_1, rho_2, rho_3, theta_1, ...``."""
        return tuple(f"{family}_{leg}" for family in self.families for leg in (1, 2, 3))

    def classes_of(self, name: str) -> tuple:
        """The classes input ``name`` (e.g. ``theta_2``) may take."""
        return self.families[name.rsplit("_", 1)[0]]

    def budget(self, choice: dict, fixed: Budget | None = None) -> Budget:
        """The error budget of a choice ``{input: class name}`` (zeta_i uniform on 0-360 deg).

        ``fixed``: a budget whose ``[effects]`` (and ``fitted_on``) and ``[correlation]`` table (with the
        groups it names) the choice's budget takes.
        """
        inputs, sources = {}, {}
        for name in self.inputs:
            if name not in choice:
                raise AllocationError(f"choice names no class for {name}")
            match = [c for c in self.classes_of(name) if c.name == choice[name]]
            if not match:
                raise AllocationError(f"{name}: no class {choice[name]!r}")
            inputs[name] = match[0].law
            sources[name] = f"class {match[0].name}: {match[0].source}"
            if name.startswith("rho_"):
                inputs[f"zeta_{name[-1]}"] = _FULL_TURN
        if fixed is None:
            return Budget(inputs, sources=sources, name=f"{self.name} allocation")
        named = {n.strip() for key in fixed.correlation for n in key.split(",")}
        try:
            return Budget(inputs, groups={g: v for g, v in fixed.groups.items() if g in named}, sources=sources,
                          name=f"{self.name} allocation", effects=fixed.effects, fitted_on=fixed.fitted_on,
                          correlation=fixed.correlation)
        except BudgetError as exc:
            raise AllocationError(f"the classes' budget cannot take budget {fixed.name!r}'s [correlation]: {exc}"
                                  ) from None

    def to_frame(self):
        """One row per family and class: family, name, law, lo, hi, cost, source."""
        import pandas as pd
        rows = [{"family": f, "name": c.name, "law": c.law.kind, "lo": c.law.support[0],
                 "hi": c.law.support[1], "cost": c.cost, "source": c.source}
                for f, classes in self.families.items() for c in classes]
        return pd.DataFrame(rows)

    # ------------------------------------------------------------ reading
    @classmethod
    def from_dict(cls, doc: dict[str, Any], source: str = "classes", catalogue: Catalogue | None = None,
                  base: Path | None = None) -> "ClassMenu":
        """Build from the classes-file layout (see the module docstring)."""
        catalogue = (catalogue or Catalogue.bundled()).with_files(doc.get("catalogues", []), base, source,
                                                                  AllocationError)
        families = {}
        for family, table in doc.items():
            if family in ("name", "catalogues"):
                continue
            where = f"{source}: [{family}]"
            if family not in ALLOCATABLE:
                raise AllocationError(f"{where}: unknown family" + (
                    " (zeta_i stays uniform on 0-360 deg)" if family == "zeta" else
                    f" (allocatable: {', '.join(ALLOCATABLE)})"))
            if not isinstance(table, dict) or set(table) != {"classes"}:
                raise AllocationError(f"{where}: expected exactly one key, classes = [{{name, ..., cost}}, ...]")
            raw = table["classes"]
            if not isinstance(raw, list) or not raw:
                raise AllocationError(f"{where}: empty class list")
            families[family] = tuple(_read_class(spec, family, f"{where} class {k + 1}", catalogue)
                                     for k, spec in enumerate(raw))
        if not families:
            raise AllocationError(f"{source}: no family table ([rho], [theta], [b], ...)")
        try:
            return cls(families, name=str(doc.get("name", Path(source).stem)))
        except AllocationError as exc:
            raise AllocationError(f"{source}: {exc}") from None

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "ClassMenu":
        path = Path(path)
        return cls.from_dict(load_toml(path), source=str(path), base=path.parent)

    @classmethod
    def from_preset(cls, name: str) -> "ClassMenu":
        """A bundled classes file: ``example`` (catalogue classes with illustrative costs)."""
        if name not in CLASSES_PRESETS:
            raise UnknownPresetError(f"unknown classes preset {name!r} (known: {', '.join(CLASSES_PRESETS)})")
        text = resources.files("prp3mc").joinpath(CLASSES_PRESETS[name]).read_text(encoding="utf-8")
        return cls.from_dict(loads_toml(text, f"classes preset {name}"), source=name)

    @classmethod
    def load(cls, spec: "str | os.PathLike | ClassMenu") -> "ClassMenu":
        """A ClassMenu, a bundled preset name or a TOML path (as ``--classes`` takes)."""
        return load_spec(cls, spec, CLASSES_PRESETS)


def _read_class(spec: Any, family: str, where: str, catalogue: Catalogue) -> ToleranceClass:
    if not isinstance(spec, dict):
        raise AllocationError(f"{where}: expected a table {{name = ..., law or catalogue = ..., cost = ...}}")
    spec = dict(spec)
    name = spec.pop("name", None)
    if not isinstance(name, str) or not name:
        raise AllocationError(f"{where}: needs a name")
    where = f"{where} ({name!r})"
    if "cost" not in spec:
        raise AllocationError(f"{where}: missing cost")
    cost = spec.pop("cost")
    if isinstance(cost, bool) or not isinstance(cost, (int, float)) or not math.isfinite(cost) or cost < 0:
        raise AllocationError(f"{where}: cost must be a finite number >= 0, got {cost!r}")
    try:
        if "catalogue" in spec:
            key = spec.pop("catalogue")
            if spec:
                raise AllocationError(f"{where}: a catalogue class takes only name, catalogue and cost")
            if not isinstance(key, str):
                raise AllocationError(f"{where}: catalogue must be a dotted key string")
            law, meta = catalogue.law(key, where)
            if meta.get("applies_to") not in (None, family):
                raise AllocationError(f"{where}: catalogue entry {key!r} applies to {meta['applies_to']}, "
                                      f"not {family}")
            source = f"{key}: {meta['source']}"
        elif "law" in spec:
            source = str(spec.pop("source", "user's law"))
            law = law_from_dict(spec, where)
        else:
            raise AllocationError(f"{where}: needs catalogue = \"dotted.key\" or law = \"uniform\", ...")
    except BudgetError as exc:
        raise AllocationError(str(exc)) from None
    return ToleranceClass(name=name, law=law, cost=float(cost), source=source)
