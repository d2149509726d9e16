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
from .exact import exact_pose_error, linear_pose_error, linearization_error_um
from .geometry import Geometry, Region
from .kinematics import (
    Limits, check_poses, feasible, forward_kinematics, inverse_kinematics, jacobian, jacobians,
)
from .sensitivity import FAMILIES, Sensitivity, sensitivity

__version__ = "0.1.0"

__all__ = [
    "__version__",
    "Geometry", "Region", "Limits",
    "inverse_kinematics", "forward_kinematics", "jacobians", "jacobian", "check_poses", "feasible",
    "FAMILIES", "Sensitivity", "sensitivity",
    "exact_pose_error", "linear_pose_error", "linearization_error_um",
    "Prp3mcError", "GeometryError", "UnknownPresetError", "InputFileError", "InfeasiblePoseError",
    "ConvergenceError", "BudgetError", "StudyError", "CampaignError",
]
