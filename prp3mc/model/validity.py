"""Is the linear error model valid for this budget? A cheap probe against the exact chain.

The analyses (worst case, Monte Carlo, Sobol) propagate the budget through
the linear model ``J_q dq``. For small errors it agrees with the exactly
perturbed chain (:func:`~prp3mc.kinematics.exact.exact_pose_error`) to second
order; for a budget large against the links it does not, and every figure
built on it is off by as much. :func:`linearity_departure` measures that
departure at a few probe poses with the budget's inputs (and its effects'
factors; its known shifts as they are) near the corners of their box;
:func:`check_linearity` warns when it exceeds about 1 %.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import ConvergenceError, LinearityWarning
from ..kinematics.chain import as_poses, feasible, inverse_kinematics
from ..kinematics.exact import exact_pose_error, linear_pose_error
from ..kinematics.geometry import Geometry
from .budget import Budget

__all__ = ["linearity_departure", "check_linearity", "LINEARITY_TOLERANCE"]

#: Relative departure of the linear model from the exact chain that triggers a warning.
LINEARITY_TOLERANCE = 0.01
_CORNER = 0.001       # probes at the 0.1 % and 99.9 % quantiles of every input (zeta: anywhere)
_PROBE_SEED = 0       # fixed probes: the check is deterministic, not part of any analysis' randomness


def _probe_inputs(budget: Budget, n_samples: int) -> np.ndarray:
    """Factors near the corners of the budget's box, shape (n_samples, D), mm / deg (degrees C)."""
    u = np.random.default_rng(_PROBE_SEED).random((n_samples, len(budget.factors)))
    corner = np.array([not name.startswith("zeta_") for name in budget.factors])
    u[:, corner] = np.where(u[:, corner] < 0.5, _CORNER, 1.0 - _CORNER)
    return budget.ppf(u)


#: Linear errors below this (mm, rad) are round-off, not errors: an output that small (say the |dphi| of
#: equal slider offsets, 1e-19 rad) is not compared with the exact chain's own round-off (5e-16 rad).
_ROUND_OFF = 1e-12


def linearity_departure(geometry: Geometry, budget: Budget, poses, *, n_poses: int = 3,
                        n_samples: int = 32) -> float:
    """Largest relative departure of the linear model from the exact chain at probe poses.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
        Poses of the analysis; ``n_poses`` of them, spread over the batch, are probed.
    n_poses, n_samples : int
        Probe poses and input draws near the box corners per pose.

    Returns
    -------
    float
        ``max |exact - linear| / max |linear|`` over the probes, separately for
        the position error (mm) and dphi, the larger of the two; ``inf`` if
        the exact chain cannot be closed at a probe. Only feasible poses are
        probed (0 if there is none: the analysis refuses them, naming why).
    """
    budget.check_geometry(geometry)
    flat = as_poses(poses).reshape(-1, 3)
    flat = flat[feasible(geometry, flat)]   # the analysis refuses the others, naming why
    if not flat.size:
        return 0.0
    idx = np.unique(np.linspace(0, flat.shape[0] - 1, min(n_poses, flat.shape[0])).round().astype(int))
    b, _ = inverse_kinematics(geometry, flat[idx], check=False)
    errors = budget.errors(_probe_inputs(budget, n_samples), b=b, lead_mm=geometry.lead_mm)
    probes = np.broadcast_to(flat[idx, None, :], (len(idx), n_samples, 3))
    linear = linear_pose_error(geometry, probes, errors, check=False)
    try:
        with np.errstate(all="ignore"):
            exact = exact_pose_error(geometry, probes, errors, check=False)
    except ConvergenceError:
        return float("inf")
    if not np.all(np.isfinite(exact)):
        return float("inf")
    worst = 0.0
    for diff, size in ((np.hypot(*(exact - linear)[..., :2].transpose(2, 0, 1)), np.hypot(linear[..., 0], linear[..., 1])),
                       (np.abs(exact - linear)[..., 2], np.abs(linear[..., 2]))):
        scale = size.max(axis=-1)
        ok = scale > _ROUND_OFF
        if ok.any():
            worst = max(worst, float((diff.max(axis=-1)[ok] / scale[ok]).max()))
    return worst


def check_linearity(geometry: Geometry, budget: Budget, poses, *, tolerance: float = LINEARITY_TOLERANCE) -> float:
    """:func:`linearity_departure`, with a :class:`~prp3mc.errors.LinearityWarning` above ``tolerance``.

    Returns the departure; call it once per analysis.
    """
    departure = linearity_departure(geometry, budget, poses)
    if not departure <= tolerance:
        figure = "the exact chain does not close" if not np.isfinite(departure) else f"{100 * departure:.3g} %"
        warnings.warn(f"budget {budget.name!r} is too large for the linear error model: it departs from the "
                      f"exact chain by {figure} at probe poses (tolerance {100 * tolerance:g} %)",
                      LinearityWarning, stacklevel=2)
    return departure
