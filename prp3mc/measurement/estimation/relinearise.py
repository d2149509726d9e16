"""The model linearised about an estimate of the machine, on the exact perturbed chain (Gauss-Newton).

The likelihood engine (:mod:`~prp3mc.measurement.estimation.likelihood`) is linear in
the systematic effects: a measurement's pose error is ``known + G theta``.
At the nominal geometry ``known`` is the budget's ``[effects]`` through
their signatures and ``G`` the signatures ``J_q``: right to first order,
which a guide or base angle error of a degree or two already leaves behind
(its second-order pose error is tens of µm against a 2 µm instrument).

A :class:`Point` linearises the exact chain about an estimate ``theta_0``
of the named effects instead: with ``E(v)`` the exact pose error of the
machine carrying the systematic effects ``v`` (the budget's plus the
corrections) when commanded by its controller's geometry,

    E(beta + theta) ~ E(beta + theta_0) + G_0 (theta - theta_0),

so ``known = E(beta + theta_0) - G_0 theta_0`` and ``G = G_0 = dE/dtheta``
at ``theta_0``, by central differences of the exact chain (every candidate
at once, one batched Newton solve). The budget's moments are taken at the
machine the point describes (its geometry, the poses it reaches). Refitting
at the new estimate and linearising again is Gauss-Newton on the exact
chain (:func:`~prp3mc.measurement.discrepancy.workflow.discrepancy` iterates it).

The controller commands the sliders by nominal inverse kinematics of *its*
geometry: the analysis geometry less the budget's geometric offsets (a
budget's ``[effects]`` are relative to the controller that commanded the
campaign, README *The updated model*).

:func:`remainder` measures how far the exact chain departs from a linear
model at a value (the whitened energy of the difference, in units of the
log-likelihood ratio); :func:`curvature` does so across each named effect's
interval, where a Wald interval needs the model linear.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ConvergenceError, InfeasiblePoseError, NonlinearityError
from ...kinematics.chain import inverse_kinematics
from ...kinematics.exact import exact_pose_error
from ...kinematics.geometry import Geometry
from ...model.budget import Budget
from ..campaign.data import Campaign
from ..campaign.iso9283 import pose_means
from ...model.effects import EffectKind, components
from ..forward.signatures import effect, library, offset_errors, slider_error

__all__ = ["Point", "linearise", "exact_errors", "candidates", "controller_geometry"]

#: Central-difference step per unit of an effect's value: small against any value the campaign can
#: resolve, large against the Newton solve's round-off (1e-13 mm).
_STEP = {"mm": 1e-3, "deg": 1e-3, "1": 1e-5, "1/K": 1e-7}
_FAILURES = (ConvergenceError, InfeasiblePoseError, np.linalg.LinAlgError)


def controller_geometry(geometry: Geometry, budget: Budget) -> Geometry:
    """The geometry the campaign's controller commanded with: ``geometry`` less the budget's geometric offsets."""
    offsets = offset_errors({n: e.value for n, e in budget.effects.items()})
    if not offsets:
        return geometry
    return geometry.replace(**{f: np.subtract(getattr(geometry, f), d) for f, d in offsets.items()})


@dataclass(frozen=True, slots=True)
class Point:
    """The exact chain linearised about an estimate of the systematic effects.

    Attributes
    ----------
    values : dict
        The estimate ``theta_0``: systematic effect name -> value (a
        correction to the budget's value when it holds the effect), its unit
        (a cyclic error's phasor, mm, complex).
    geometry : Geometry
        The machine at the estimate (analysis geometry, the estimate's offsets applied).
    poses : ndarray, shape (P, 3)
        The poses the machine reaches at the estimate, mean over each pose's visits, ``[mm, mm, deg]``.
    known : ndarray, shape (M, 3)
        ``E(beta + theta_0) - G theta_0``: the linearised model's pose error with every correction at 0.
    names : tuple of str
        The effects whose signatures ``G`` holds, one column each (a cyclic error two: its phasor's parts).
    G : ndarray, shape (M, 3, C)
        ``dE/dtheta`` at the estimate, ``[mm, mm, deg]`` per unit of each column.
    exact : ndarray, shape (M, 3)
        ``E(beta + theta_0)``.
    """

    values: dict
    geometry: Geometry
    poses: np.ndarray
    known: np.ndarray
    names: tuple
    G: np.ndarray
    exact: np.ndarray

    def signatures(self, names) -> np.ndarray:
        """Signature columns (M, 3, c) of the effects ``names`` at the point, as :func:`signatures` lays them out."""
        return self.G[:, :, _columns(self.names, names)]

    def predict(self, values: dict) -> np.ndarray:
        """The linearised pose error (M, 3) at corrections ``values`` (name -> value; absent ones 0)."""
        return self.known + self.G @ components(self.names, [values.get(n, 0.0) for n in self.names])


def _columns(names, wanted) -> list[int]:
    """Columns of the effects ``wanted`` among the columns of ``names`` (one per effect, two for a cyclic one)."""
    start = np.cumsum([0] + [effect(n).dof for n in names])
    where = {n: k for k, n in enumerate(names)}
    return [int(c) for n in wanted for c in range(start[where[n]], start[where[n] + 1])]


def candidates(geometry: Geometry, budget: Budget, campaign: Campaign) -> list[str]:
    """The systematic effects of the library the campaign can test (before the visibility check)."""
    has_lead = tuple(bool(np.isfinite(p)) for p in geometry.lead_mm)
    return [e.name for e in library(budget, campaign.has_dir, campaign.temp_C is not None, has_lead) if e.systematic]


class _Chain:
    """``E(v)``: the exact pose error of the campaign's measurements for systematic values ``v``, batched.

    A value set is a row of coefficients over the columns of ``names`` (the
    budget's effects and the candidates; a cyclic error's phasor has two):
    offsets turn the chain's parameters, slider effects add their ``delta b``
    (linear in the column's coefficient) to the commanded sliders.
    """

    def __init__(self, geometry: Geometry, budget: Budget, campaign: Campaign, names):
        self.controller = controller_geometry(geometry, budget)
        self.campaign, self.budget = campaign, budget
        self.names = tuple(names)
        units = [(n, u) for n in self.names for u in ((1.0, 1j) if effect(n).dof == 2 else (1.0,))]
        b, _ = inverse_kinematics(self.controller, campaign.commanded, check=False)
        self.families = sorted({f for n, u in units for f in offset_errors({n: u})})
        self.offset_dir = np.zeros((len(units), len(self.families), 3))          # (C, F, 3) per unit
        self.slider_dir = np.zeros((len(units), campaign.n_measurements, 3))     # (C, M, 3) mm per unit
        for k, (name, unit) in enumerate(units):
            for family, v in offset_errors({name: unit}).items():
                self.offset_dir[k, self.families.index(family)] = v
            self.slider_dir[k] = slider_error({name: unit}, b, campaign.direction, campaign.temp_C,
                                              geometry.lead_mm)

    def coefficients(self, values: dict) -> np.ndarray:
        """The coefficient row (C,) of the budget's effects plus the corrections ``values``."""
        total = {n: e.model_value for n, e in self.budget.effects.items()}
        for n, v in values.items():
            total[n] = total.get(n, 0.0) + v
        return components(self.names, [total.get(n, 0.0) for n in self.names])

    def __call__(self, coef: np.ndarray) -> np.ndarray:
        """Exact pose errors (S, M, 3) of the value sets ``coef`` (S, C).

        Raises
        ------
        NonlinearityError
            The chain does not close (or is singular) at some value set.
        """
        coef = np.atleast_2d(coef)
        errors = {f: np.einsum("sk,kl->sl", coef, self.offset_dir[:, j])[:, None, :]
                  for j, f in enumerate(self.families)}
        errors["b"] = np.einsum("sk,kml->sml", coef, self.slider_dir)
        poses = np.broadcast_to(self.campaign.commanded, (coef.shape[0],) + self.campaign.commanded.shape)
        try:
            out = exact_pose_error(self.controller, poses, errors, check=False)
        except _FAILURES as exc:
            raise NonlinearityError(f"the exact chain cannot be solved at the estimate ({exc})") from None
        if not np.all(np.isfinite(out)):
            raise NonlinearityError("the exact chain cannot be solved at the estimate (non-finite pose)")
        return out


def linearise(geometry: Geometry, budget: Budget, campaign: Campaign, values: dict, names) -> Point:
    """The exact chain linearised about the corrections ``values`` (see the module notes).

    Parameters
    ----------
    geometry, budget
        What the campaign is analysed with.
    campaign : Campaign
        Every row (an engine on some rows takes its rows of the point).
    values : dict
        Systematic effect name -> value at the point (corrections to the budget's effects; a cyclic
        error's phasor, complex).
    names : sequence of str
        Systematic candidates whose signatures the point carries (:func:`candidates`).

    Returns
    -------
    Point

    Raises
    ------
    NonlinearityError
        The exact chain cannot be evaluated at or about the estimate.
    """
    names = tuple(dict.fromkeys([*names, *values, *budget.effects]))
    chain = _Chain(geometry, budget, campaign, names)
    c0 = chain.coefficients(values)
    steps = np.array([_STEP[effect(n).unit] for n in names for _ in range(effect(n).dof)])
    C = c0.size
    E = chain(np.concatenate([c0[None], c0 + np.diag(steps), c0 - np.diag(steps)]))
    G = np.moveaxis((E[1:C + 1] - E[C + 1:]) / (2.0 * steps[:, None, None]), 0, 2)    # (M, 3, C)
    theta = components(names, [values.get(n, 0.0) for n in names])
    reached = pose_means(campaign.commanded + E[0], campaign.pose_index, campaign.n_poses)
    offsets = offset_errors({n: v for n, v in values.items() if effect(n).kind == EffectKind.OFFSET})
    machine = geometry.replace(name=geometry.name,
                               **{f: np.add(getattr(geometry, f), d) for f, d in offsets.items()})
    return Point(values=dict(values), geometry=machine, poses=reached, known=E[0] - G @ theta, names=names,
                 G=G, exact=E[0])


def exact_errors(geometry: Geometry, budget: Budget, campaign: Campaign, value_sets: list[dict]) -> np.ndarray:
    """``E(beta + v)`` (S, M, 3) for each correction set ``v`` of ``value_sets``."""
    names = tuple(dict.fromkeys([n for v in value_sets for n in v] + list(budget.effects)))
    chain = _Chain(geometry, budget, campaign, names)
    return chain(np.stack([chain.coefficients(v) for v in value_sets]))
