"""prp3mc: error modelling, Monte Carlo and sensitivity analysis of planar 3-PRP manipulators.

The pose error of a 3-PRP parallel manipulator is, to first order,
``[dx, dy, dphi] = sum_q J_q(pose) dq`` with ``J_q = A^-1 H_q`` (the source
paper's eq. 9). prp3mc computes every J_q batched over workspace grids,
validates it against an exact nonlinear solution of the perturbed chain, and
builds error budgets, Monte Carlo statistics, exact worst-case envelopes and
Sobol indices on top.

Units: mm and degrees at every boundary, radians inside.

The names below are the whole everyday API. Everything else lives in the
wings, by concept: :mod:`prp3mc.kinematics`, :mod:`prp3mc.uncertainty`,
:mod:`prp3mc.measurement`, :mod:`prp3mc.study`, :mod:`prp3mc.reports`
(figures and report writers), :mod:`prp3mc.errors` (every exception type)
and :mod:`prp3mc.testing` (helpers for users' CI).
"""

from ._version import __version__
from .errors import Prp3mcError
from .kinematics.chain import feasible, forward_kinematics, inverse_kinematics
from .kinematics.exact import exact_pose_error
from .kinematics.geometry import Geometry, Region
from .kinematics.sensitivity import Sensitivity, sensitivity
from .uncertainty.budget import Budget, Catalogue
from .uncertainty.laws import Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from .uncertainty.model import LinearModel, linear_model
from .uncertainty.montecarlo import MonteCarloResult, monte_carlo
from .uncertainty.worstcase import WorstCase, WorstCaseMaxima, worst_case, worst_case_maxima
from .uncertainty.allocation import AllocationResult, allocate
from .uncertainty.sobol import SobolResult, sobol_indices
from .uncertainty.ranking import ranking as sobol_ranking
from .study.reader import Study
from .study.results import StudyResult
from .study.runner import run_study
from .study.summary import build_summary
from .measurement.campaign import Campaign, read_campaign
from .measurement.results import DiscrepancyResult
from .measurement.simulate import simulate_campaign
from .measurement.workflow import detectable_effect, discrepancy

__all__ = [
    "__version__", "Prp3mcError",
    # geometry and kinematics
    "Geometry", "Region", "inverse_kinematics", "forward_kinematics", "feasible",
    "sensitivity", "Sensitivity", "exact_pose_error",
    # budgets and their propagation
    "Budget", "Catalogue", "Uniform", "Normal", "TruncNormal", "Triangular", "Disc", "Discrete",
    "linear_model", "LinearModel", "monte_carlo", "MonteCarloResult", "worst_case", "WorstCase", "worst_case_maxima", "WorstCaseMaxima",
    "allocate", "AllocationResult",
    "sobol_indices", "SobolResult", "sobol_ranking",
    # studies
    "Study", "StudyResult", "run_study", "build_summary",
    # measurements
    "Campaign", "read_campaign", "simulate_campaign", "discrepancy", "DiscrepancyResult", "detectable_effect",
]
