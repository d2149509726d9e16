"""The paper's method as a cross-check: a global optimiser on the exact model.

The paper finds the worst pose error by running a genetic algorithm at every
pose. Here scipy's differential evolution (the GA analogue) maximises the
position error of the *exact nonlinear* perturbed chain over the budget's box,
one pose at a time, so that its result and its cost can be set against the
exact envelope of :func:`prp3mc.worst_case`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution

from ..model.budget import Budget
from ..kinematics.exact import exact_pose_error
from ..kinematics.geometry import Geometry
from ..kinematics.chain import as_poses, check_poses, inverse_kinematics
from .._rng import resolve_rng

__all__ = ["OptimizerResult", "optimizer_worst_case"]


@dataclass(frozen=True, slots=True)
class OptimizerResult:
    """Best position error found by differential evolution at one pose.

    Attributes
    ----------
    pose : ndarray (3,)
    position_mm : float
        Largest exact position error found, mm.
    inputs : dict of str to float
        The factors (mm, deg; degrees C for thermal) that gave it.
    n_evaluations : int
        Exact-model evaluations used.
    seconds : float
        Wall time.
    seed : int
    """

    pose: np.ndarray
    position_mm: float
    inputs: dict
    n_evaluations: int
    seconds: float
    seed: int


def optimizer_worst_case(geometry: Geometry, budget: Budget, pose, *,
                         rng: "None | int | np.random.Generator" = None,
                         k_sigma: float | None = None, maxiter: int = 300, popsize: int = 20,
                         tol: float = 1e-10) -> OptimizerResult:
    """Maximise the exact position error at ``pose`` with differential evolution.

    The population is evaluated in one vectorised call of the exact solver
    per generation; the result is polished by L-BFGS-B inside the box.

    Parameters
    ----------
    geometry, budget :
    pose : array_like, shape (3,)
        ``[x_mm, y_mm, phi_deg]``.
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7): a seed, a Generator (a seed is
        drawn from it) or None (a fresh seed); the integer seed used is
        recorded in the result.
    k_sigma : float, optional
        Bound for unbounded laws, as in :func:`prp3mc.worst_case`.
    maxiter, popsize, tol :
        Passed to :func:`scipy.optimize.differential_evolution`.
    """
    pose = as_poses(pose)
    if pose.shape != (3,):
        raise ValueError("optimizer_worst_case works on one pose of shape (3,)")
    check_poses(geometry, pose)
    budget.check_geometry(geometry)
    seed, _ = resolve_rng(rng)
    bounds = budget.bounds(k_sigma)
    b, _ = inverse_kinematics(geometry, pose)           # the commanded sliders (lead scale, thermal)
    evaluations = 0

    def negative_error(X):  # X: (D,) or (D, S) with vectorized=True
        nonlocal evaluations
        X2 = np.atleast_2d(np.asarray(X).T)                          # (S, D)
        evaluations += X2.shape[0]
        err = exact_pose_error(geometry, np.broadcast_to(pose, X2.shape[:1] + (3,)),
                               budget.errors(X2, b=b, lead_mm=geometry.lead_mm), check=False)
        value = -np.hypot(err[:, 0], err[:, 1])
        return value if np.ndim(X) > 1 else value[0]

    t0 = time.perf_counter()
    res = differential_evolution(negative_error, bounds, rng=np.random.default_rng(seed), maxiter=maxiter,
                                 popsize=popsize, tol=tol, vectorized=True, updating="deferred",
                                 polish=True)
    seconds = time.perf_counter() - t0
    return OptimizerResult(pose=pose, position_mm=float(-res.fun),
                           inputs=dict(zip(budget.factors, map(float, res.x))),
                           n_evaluations=evaluations, seconds=seconds, seed=seed)
