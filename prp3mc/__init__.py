"""prp3mc: error modelling, Monte Carlo and sensitivity analysis of planar 3-PRP manipulators.

The pose error of a 3-PRP parallel manipulator is, to first order,
``[dx, dy, dphi] = sum_q J_q(pose) dq`` with ``J_q = A^-1 H_q`` (the source
paper's eq. 9). prp3mc computes every J_q batched over workspace grids,
validates it against an exact nonlinear solution of the perturbed chain, and
builds error budgets, Monte Carlo statistics, exact worst-case envelopes and
Sobol indices on top.

Units: mm and degrees at every boundary, radians inside.
"""

from .errors import (
    BudgetError, CampaignError, ConvergenceError, GeometryError, InfeasiblePoseError,
    InputFileError, Prp3mcError, StudyError, UnknownPresetError,
)
from .kinematics.exact import exact_pose_error, linear_pose_error, linearization_error_um
from .kinematics.geometry import Geometry, Region
from .kinematics.chain import (
    Limits, check_poses, feasible, forward_kinematics, inverse_kinematics, jacobian, jacobians,
)
from .kinematics.sensitivity import FAMILIES, Sensitivity, sensitivity
from ._version import __version__
from .uncertainty.budget import Budget, Catalogue
from .uncertainty.laws import Discrete, Disc, Normal, Triangular, TruncNormal, Uniform
from .uncertainty.model import LinearModel, linear_model
from .uncertainty.montecarlo import MonteCarloResult, monte_carlo
from .uncertainty.worstcase import WorstCase, worst_case
from .uncertainty.allocation import AllocationResult, allocate
from .uncertainty.sobol import SobolResult, analytic_indices, ranking as sobol_ranking, sobol_converge, sobol_indices
from .study.runner import Study, StudyResult, run_study
from .reports.study_report import write_study
from .study.summary import build_summary
from .measurement.campaign import Campaign, read_campaign, simulate_campaign
from .measurement.effects import EFFECT_NAMES, Effect, effect
from .measurement.discrepancy import DiscrepancyResult, detectable_effect, discrepancy, predict
from .reports.discrepancy_report import write_report as write_discrepancy_report

__all__ = [
    "__version__",
    "Geometry", "Region", "Limits",
    "inverse_kinematics", "forward_kinematics", "jacobians", "jacobian", "check_poses", "feasible",
    "FAMILIES", "Sensitivity", "sensitivity",
    "exact_pose_error", "linear_pose_error", "linearization_error_um",
    "Budget", "Catalogue", "Uniform", "Normal", "TruncNormal", "Triangular", "Disc", "Discrete",
    "LinearModel", "linear_model", "MonteCarloResult", "monte_carlo",
    "WorstCase", "worst_case",
    "AllocationResult", "allocate",
    "SobolResult", "sobol_indices", "analytic_indices", "sobol_ranking", "sobol_converge",
    "Study", "StudyResult", "run_study", "write_study", "build_summary",
    "Campaign", "read_campaign", "simulate_campaign", "EFFECT_NAMES", "Effect", "effect",
    "DiscrepancyResult", "discrepancy", "predict", "detectable_effect", "write_discrepancy_report",
    "Prp3mcError", "GeometryError", "UnknownPresetError", "InputFileError", "InfeasiblePoseError",
    "ConvergenceError", "BudgetError", "StudyError", "CampaignError",
]
