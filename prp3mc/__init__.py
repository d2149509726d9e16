"""prp3mc: error modelling, Monte Carlo and sensitivity analysis of planar 3-PRP manipulators.

The pose error of a 3-PRP parallel manipulator is, to first order,
``[dx, dy, dphi] = sum_q J_q(pose) dq`` with ``J_q = A^-1 H_q`` (the source
paper's eq. 9). prp3mc computes every J_q batched over workspace grids,
validates it against an exact nonlinear solution of the perturbed chain, and
builds error budgets, Monte Carlo statistics, exact worst-case envelopes and
Sobol indices on top.

Units: mm and degrees at every boundary, radians inside.

The names below are the whole everyday API. Everything else lives in one
package per concept or method, from the ground up: :mod:`prp3mc.kinematics`
(geometry, chain, J_q), :mod:`prp3mc.model` (laws, budgets, effects, the
linear model), the methods side by side (:mod:`prp3mc.montecarlo`,
:mod:`prp3mc.worstcase`, :mod:`prp3mc.stackup` (exact yields), :mod:`prp3mc.sobol`, :mod:`prp3mc.allocation`),
:mod:`prp3mc.measurement` (campaigns and the discrepancy fit),
:mod:`prp3mc.study`, :mod:`prp3mc.reports` (figures and report writers),
:mod:`prp3mc.cli`, :mod:`prp3mc.errors` (every exception type) and
:mod:`prp3mc.testing` (helpers for users' CI).
"""

from __future__ import annotations

import importlib
import warnings

from ._version import __version__
from .errors import Prp3mcError

#: Where each name of the everyday API lives: ``name -> "module"`` or ``name -> "module:attribute"``.
#: The modules are imported on first use (PEP 562), so ``prp3mc discrepancy`` never
#: pays for numba or SALib, and ``import prp3mc`` costs what the names used cost.
_API = {
    "feasible": "kinematics.chain", "forward_kinematics": "kinematics.chain",
    "inverse_kinematics": "kinematics.chain", "exact_pose_error": "kinematics.exact",
    "Geometry": "kinematics.geometry", "Region": "kinematics.geometry",
    "Sensitivity": "kinematics.sensitivity", "sensitivity": "kinematics.sensitivity",
    "Budget": "model.budget", "Catalogue": "model.catalogue",
    **dict.fromkeys(("Disc", "Discrete", "Normal", "Triangular", "TruncNormal", "Uniform"), "model.laws"),
    "LinearModel": "model.linear", "linear_model": "model.linear",
    "MonteCarloResult": "montecarlo.propagation", "monte_carlo": "montecarlo.propagation",
    "WorstCaseResult": "worstcase.envelope", "worst_case": "worstcase.envelope",
    "AllocationResult": "allocation.optimum", "allocate": "allocation.optimum",
    "SobolResult": "sobol.indices", "sobol_indices": "sobol.indices",
    "ShapleyResult": "sobol.shapley", "shapley_effects": "sobol.shapley",
    "sobol_ranking": "sobol.ranking:ranking",
    "exact_yield": "stackup.exceedance", "YieldResult": "stackup.result",
    "Study": "study.reader", "StudyResult": "study.results", "run_study": "study.runner",
    "build_summary": "study.summary",
    "Campaign": "measurement.campaign.data", "read_campaign": "measurement.campaign.data",
    "DiscrepancyResult": "measurement.discrepancy.results", "simulate_campaign": "measurement.campaign.simulate",
    "detectable_effect": "measurement.discrepancy.workflow", "discrepancy": "measurement.discrepancy.workflow",
    "CampaignPlan": "measurement.campaign.plan", "plan_campaign": "measurement.campaign.plan",
}
#: Names that left the everyday API, still served for one release with a DeprecationWarning:
#: ``name -> ("module:attribute", where to find it now)``.
_DEPRECATED = {
    "WorstCase": ("worstcase.envelope:WorstCaseResult", "prp3mc.WorstCase is now prp3mc.WorstCaseResult"),
    "worst_case_maxima": ("worstcase.envelope:worst_case_maxima",
                          "prp3mc.worst_case_maxima is now imported from prp3mc.worstcase.envelope"),
    "WorstCaseMaxima": ("worstcase.envelope:WorstCaseMaxima",
                        "prp3mc.WorstCaseMaxima is now imported from prp3mc.worstcase.envelope"),
}
#: The wings, importable as attributes too (``prp3mc.measurement`` after ``import prp3mc``).
_WINGS = ("kinematics", "model", "montecarlo", "worstcase", "stackup", "sobol", "allocation", "measurement", "study",
          "reports", "cli", "errors", "testing")

__all__ = [
    "__version__", "Prp3mcError",
    # geometry and kinematics
    "Geometry", "Region", "inverse_kinematics", "forward_kinematics", "feasible",
    "sensitivity", "Sensitivity", "exact_pose_error",
    # budgets and their propagation
    "Budget", "Catalogue", "Uniform", "Normal", "TruncNormal", "Triangular", "Disc", "Discrete",
    "linear_model", "LinearModel", "monte_carlo", "MonteCarloResult", "worst_case", "WorstCaseResult",
    "allocate", "AllocationResult",
    "sobol_indices", "SobolResult", "sobol_ranking", "shapley_effects", "ShapleyResult",
    "exact_yield", "YieldResult",
    # studies
    "Study", "StudyResult", "run_study", "build_summary",
    # measurements
    "Campaign", "read_campaign", "simulate_campaign", "discrepancy", "DiscrepancyResult", "detectable_effect",
    "plan_campaign", "CampaignPlan",
]


def __getattr__(name: str):
    """Import the module behind an API name or a wing on first use, and keep it (PEP 562)."""
    if name in _API:
        module, _, attribute = _API[name].partition(":")
        value = getattr(importlib.import_module(f"{__name__}.{module}"), attribute or name)
    elif name in _WINGS:
        value = importlib.import_module(f"{__name__}.{name}")
    elif name in _DEPRECATED:
        where, text = _DEPRECATED[name]
        module, _, attribute = where.partition(":")
        warnings.warn(f"{text} (the old name goes in the next release)", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(f"{__name__}.{module}"), attribute)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__) | set(_WINGS))
