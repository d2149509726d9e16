"""``summary.json``: the summary statistics of a study, for regression checks.

Layout (µm and arcsec)::

    {"study": "paper_reproduction",
     "configurations": {
       "u-shape": {
         "worst_case_position_um": {"min": 116.9, "max": 194.6, "mean": 150.3},
         "worst_case_phi_arcsec": {"min": ..., "max": ..., "mean": ...},
         "montecarlo": {
           "position_um": {"p99.73": {"min": {"value": 120.1, "se": 0.4}, "max": {...}, "mean": {...}}, ...,
                           "mean": {"min": ..., "max": ..., "mean": ...}},
           "phi_arcsec": {"p99.73": {...}, ...},
           "std": {"x_um": {...}, "y_um": {...}, "phi_arcsec": {...}},
           "exceed": {"tolerance_mm": 0.1, "probability": {"min": ..., "max": ..., "mean": ...}}},
         "sobol": {"position": {"theta_1": {"kind": "input", "S1": {"value": ..., "se": ...},
                                            "ST": {...}, "worst_case_share": 0.31}, ...}, ...}},
                                            # worst_case_share null where undefined (rho_i, zeta_i alone)
       "delta-shape": {...}},
     "metadata": {"prp3mc_version": ..., "seed": ..., "montecarlo_samples": ..., "wall_time_s": ...}}

A plain number is **exact** (the worst case is a deterministic function of
geometry, budget and grid); a ``{"value", "se"}`` pair is a **statistic** with
its standard error. ``min``/``max``/``mean`` are taken over the analysis'
grid of the configuration's test region. Standard errors: a percentile's
from its distribution-free 95 % interval (half-width / 1.96), at the pose
that gives the min or max; a mean over the grid carries the mean of the
pose-wise standard errors (an upper bound under the common random numbers
all poses share); a Sobol index's is its bootstrap half-width / 1.96.
:func:`prp3mc.testing.assert_summary_close` compares two summaries.
"""

from __future__ import annotations

import numpy as np

from ..units import DEG2ARCSEC, MM2UM, Z95
from .results import ConfigurationResult, StudyResult, over_grid, pct_se

__all__ = ["build_summary"]


def _stat(value, se) -> dict:
    return {"value": float(value), "se": float(se)}


def _over_grid(values: np.ndarray, se: np.ndarray) -> dict:
    """min, max and mean over a grid of a statistic with pose-wise standard errors."""
    return {k: _stat(v, s) for k, (v, s) in over_grid(values, se).items()}


def _exact_or_none(value) -> float | None:
    """An exact number, or None (JSON null) where it is undefined (NaN)."""
    return None if np.isnan(value) else float(value)


def _exact(values: np.ndarray) -> dict:
    return {"min": float(values.min()), "max": float(values.max()), "mean": float(values.mean())}


def _montecarlo(c: ConfigurationResult) -> dict:
    mc = c.montecarlo
    pos = {f"p{p:g}": _over_grid(MM2UM * mc.position_pct[..., q], MM2UM * pct_se(mc.position_pct_ci[..., q, :]))
           for q, p in enumerate(mc.percentiles)}
    pos["mean"] = _over_grid(MM2UM * mc.position_mean, MM2UM * mc.position_mean_se)
    phi = {f"p{p:g}": _over_grid(DEG2ARCSEC * mc.phi_pct[..., q], DEG2ARCSEC * pct_se(mc.phi_pct_ci[..., q, :]))
           for q, p in enumerate(mc.percentiles)}
    std = {key: _over_grid(f * mc.std[..., o], f * mc.std_se[..., o])
           for o, (key, f) in enumerate((("x_um", MM2UM), ("y_um", MM2UM), ("phi_arcsec", DEG2ARCSEC)))}
    out = {"position_um": pos, "phi_arcsec": phi, "std": std}
    if mc.exceed_prob is not None:
        out["exceed"] = {"tolerance_mm": float(mc.tolerance_mm),
                         "probability": _over_grid(mc.exceed_prob, pct_se(mc.exceed_ci))}
    return out


def _sobol(c: ConfigurationResult) -> dict:
    out = {}
    for output, frame in c.ranking.items():
        out[output] = {row.name: {"kind": row.kind,
                                  "S1": _stat(row.S1, row.S1_conf / Z95),
                                  "ST": _stat(row.ST, row.ST_conf / Z95),
                                  "worst_case_share": _exact_or_none(row.worst_case_share)}
                       for row in frame.itertuples(index=False)}
    return out


def build_summary(result: StudyResult) -> dict:
    """The summary of a study run as a JSON-ready dict (layout in the module docstring)."""
    configs = {}
    for c in result.configurations:
        wc = c.worst_case
        doc = {"worst_case_position_um": _exact(MM2UM * wc.position_mm),
               "worst_case_phi_arcsec": _exact(DEG2ARCSEC * wc.phi_deg)}
        if c.montecarlo is not None:
            doc["montecarlo"] = _montecarlo(c)
        if c.sobol is not None:
            doc["sobol"] = _sobol(c)
        configs[c.name] = doc
    return {"study": result.study.name, "configurations": configs, "metadata": result.metadata()}
