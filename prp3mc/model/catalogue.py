"""Catalogues: named laws of error inputs with their sources (docs, *File formats*).

A budget or a classes file refers to an entry by its dotted key
(``{ catalogue = "bearing_radial_clearance.bore_10_18.CN" }``); the bundled
catalogue is ``prp3mc/data/catalogue.toml`` and a file's ``catalogues = [...]``
adds its own.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path
from typing import Any

from .._toml import load_toml, loads_toml
from ..errors import BudgetError
from .laws import Law, law_from_dict

__all__ = ["Catalogue"]


class Catalogue:
    """Named laws with their sources, read from catalogue TOML files.

    The bundled catalogue holds bearing clearance classes, guide angular
    play and encoder least counts; entries are addressed by dotted keys such
    as ``bearing_radial_clearance.bore_10_18.CN``.
    """

    def __init__(self, entries: dict[str, dict[str, Any]]):
        self.entries = dict(entries)

    @classmethod
    def bundled(cls) -> "Catalogue":
        text = resources.files("prp3mc").joinpath("data/catalogue.toml").read_text(encoding="utf-8")
        return cls(_flatten(loads_toml(text, "bundled catalogue")))

    def extended(self, path: str | os.PathLike) -> "Catalogue":
        """A catalogue with the entries of the file at ``path`` added (or overriding)."""
        return Catalogue({**self.entries, **_flatten(load_toml(path))})

    def with_files(self, paths, base: Path | None, source: str, error: type[Exception] = BudgetError) -> "Catalogue":
        """This catalogue extended by a file's ``catalogues = [paths]`` (relative to ``base``).

        Raises ``error`` naming ``source`` when ``paths`` is not a list of strings.
        """
        if not isinstance(paths, list) or not all(isinstance(q, str) for q in paths):
            raise error(f"{source}: catalogues must be a list of file paths, got {paths!r}")
        catalogue = self
        for path in paths:
            catalogue = catalogue.extended((base or Path(".")) / path)
        return catalogue

    def law(self, key: str, where: str) -> tuple[Law, dict[str, Any]]:
        if not isinstance(key, str) or key not in self.entries:
            raise BudgetError(f"{where}: no catalogue entry {key!r}")
        entry = dict(self.entries[key])
        meta = {k: entry.pop(k) for k in ("applies_to", "unit", "source") if k in entry}
        if "source" not in meta:
            raise BudgetError(f"catalogue entry {key!r} states no source")
        return law_from_dict(entry, f"catalogue entry {key!r}"), meta

    def to_frame(self):
        """The entries as a DataFrame: key, law, parameters, applies_to, unit, source."""
        import pandas as pd
        rows = [{"key": k, **v} for k, v in self.entries.items()]
        return pd.DataFrame(rows)


def _flatten(doc: dict[str, Any], prefix: str = "") -> dict[str, dict[str, Any]]:
    out = {}
    for key, value in doc.items():
        name = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict) and "law" in value:
            out[name] = value
        elif isinstance(value, dict):
            out.update(_flatten(value, name))
    return out
