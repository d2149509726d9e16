"""An effect the discrepancy workflow added to the model, with its interval and evidence."""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from ..._result import freeze, thawed

__all__ = ["NamedEffect", "LEVEL", "EFFECT_COLUMNS"]

#: Level of the intervals the workflow computes (``ci95``).
LEVEL = 0.95
EFFECT_COLUMNS = ["name", "value", "unit", "ci_low", "ci_high", "level", "aliases", "identified", "lr"]


@dataclass(frozen=True, slots=True)
class NamedEffect:
    """An effect the workflow added to the model.

    Attributes
    ----------
    name : str
    value : float
        In ``unit``.
    unit : str
    ci95 : (float, float)
    aliases : tuple of str
        Effects the campaign cannot tell apart from this one; if any, the
        effect is *not* identified (one of the set is missing).
    evidence : mapping
        ``lr`` (of removing it from the final model), ``threshold``,
        ``p_bonferroni``, ``n_candidates``, ``step``, ``delta_bic``,
        ``identified``, ``alias_fits`` (value and ci95 of each alias),
        ``alternative_sets`` (other sets of the same size that fit as well)
        and, for spreads, ``budget_value`` and ``direction``; for an effect
        the budget's ``[effects]`` already holds, ``value`` is the correction
        to it and the evidence has ``budget_effect`` (the budget's value)
        and ``total`` (a cyclic error: the corrections add as phasors, and
        ``total_phase_deg`` and ``total_ci95`` come with it). A cyclic error
        has ``phasor_mm`` (real and imaginary parts of A exp(i phi)) and
        ``phasor_cov_mm2``, and ``lr_df2``, its likelihood ratio before it
        is put on the chi2(1) scale of ``lr``.
    phase_deg : float or None
        A cyclic error's phase phi_i, degrees (its value is the amplitude A_i).
    """

    name: str
    value: float
    unit: str
    ci95: tuple
    aliases: tuple
    evidence: dict
    phase_deg: float | None = None

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        lo, hi = self.ci95
        return (f"NamedEffect(name={self.name!r}, value={self.value:.6g}, unit={self.unit!r}, "
                f"ci95=[{lo:.6g}, {hi:.6g}], identified={self.evidence['identified']})")

    def row(self) -> dict:
        """The effect as one row of :data:`EFFECT_COLUMNS`."""
        return {"name": self.name, "value": self.value, "unit": self.unit, "ci_low": self.ci95[0],
                "ci_high": self.ci95[1], "level": LEVEL, "aliases": ", ".join(self.aliases),
                "identified": self.evidence["identified"], "lr": self.evidence["lr"]}

    def to_frame(self) -> pd.DataFrame:
        """One row: ``name, value, unit, ci_low, ci_high, level, aliases, identified, lr``."""
        return pd.DataFrame([self.row()], columns=EFFECT_COLUMNS)

    def to_dict(self) -> dict:
        """The effect's entry in ``discrepancy.json``."""
        doc = {"name": self.name, "value": self.value, "unit": self.unit, "ci95": list(self.ci95)}
        if self.phase_deg is not None:
            doc["phase_deg"] = self.phase_deg
        return doc | {"aliases": list(self.aliases), "evidence": thawed(self.evidence)}
