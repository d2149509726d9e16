"""The predicted distribution of every measurement of a campaign.

Measurement m of commanded pose p is ``measured = commanded + e_m + s_m + n_m``:

- ``e_m`` is the budget's random pose error. Its mean ``mu_p`` is *not*
  zero (encoder errors are one-sided) and its covariance is ``Sigma_p``;
  both are exact moments of the linear model
  (:meth:`prp3mc.LinearModel.moments`), which the exact nonlinear chain
  matches to < 0.1 µm at these magnitudes. A share ``r`` of ``Sigma_p``
  (the repeatable fraction) repeats at every visit of the pose (a clearance
  settling at the same contact under the same load); the rest, ``(1 - r)
  Sigma_p``, is drawn afresh at each visit.
- ``s_m = sum_k theta_k g_k(m)`` are systematic effects of the library, each
  linear in its value through its signature
  (:func:`prp3mc.measurement.forward.signatures.signatures`): those of the budget's
  ``[effects]`` table, with their drivers (approach directions, temperature,
  slider positions) from the campaign, and any added to the model.
- ``n_m`` is instrument noise, N(0, diag(s_mm^2, s_mm^2, s_deg^2)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..._result import freeze, pose_columns, short_repr
from ...errors import BudgetError, ParameterError
from ...kinematics.geometry import Geometry
from ...model.budget import Budget
from ...model.linear import linear_model
from ...units import OUTPUT_UNITS, POSE_OUTPUTS
from ..campaign.data import Campaign
from .signatures import budget_effect_errors, components, effect, signatures, spread_budget

__all__ = ["Prediction", "predict", "noise_cov"]


@dataclass(frozen=True, slots=True)
class Prediction:
    """Predicted distribution of ``measured - commanded`` at the measurements of a campaign.

    Attributes
    ----------
    mean : ndarray, shape (M, 3)
        Expected ``[dx mm, dy mm, dphi deg]`` per measurement (budget mean
        plus systematic effects, the budget's and those added, which may
        differ between repeats).
    cov : ndarray, shape (P, 3, 3)
        Covariance of one measurement per commanded pose: budget plus instrument noise.
    scatter_cov : ndarray, shape (P, 3, 3)
        Visit-to-visit covariance per pose: the budget's part that does not
        repeat, ``(1 - r) Sigma_p``, plus instrument noise.
    pose_index : ndarray of int, shape (M,)
    poses : ndarray, shape (P, 3)
        The commanded poses ``[x_mm, y_mm, phi_deg]``.
    budget : Budget
        The budget, with spread effects applied.
    effects : mapping
        Effects included (systematic values and spreads), name -> value.
    repeatable_fraction : float
        ``r``.
    """

    mean: np.ndarray
    cov: np.ndarray
    scatter_cov: np.ndarray
    pose_index: np.ndarray
    poses: np.ndarray
    budget: Budget
    effects: dict
    repeatable_fraction: float = 0.0

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "mean", "cov", "budget")

    def to_frame(self) -> pd.DataFrame:
        """Tidy table, one row per measurement, output and statistic.

        Columns ``measurement, pose, x_mm, y_mm, phi_deg`` (the commanded
        pose), ``output`` (x, y, phi), ``statistic`` (``mean``, ``std``),
        ``value`` and ``unit`` (mm, deg).
        """
        M = self.mean.shape[0]
        sd = np.sqrt(np.diagonal(self.cov, axis1=-2, axis2=-1))[self.pose_index]
        n_rows = 2 * len(POSE_OUTPUTS)                   # per measurement: mean and std of each output
        return pd.DataFrame({
            "measurement": np.repeat(np.arange(M), n_rows),
            "pose": np.repeat(self.pose_index, n_rows),
            **pose_columns(self.poses[self.pose_index], repeat=n_rows),
            "output": np.tile(np.repeat(POSE_OUTPUTS, 2), M),
            "statistic": np.tile(["mean", "std"], len(POSE_OUTPUTS) * M),
            "value": np.stack([self.mean, sd], axis=-1).ravel(),
            "unit": np.tile(np.repeat([OUTPUT_UNITS[o] for o in POSE_OUTPUTS], 2), M),
        })


#: Largest instrument noise sd accepted, mm or deg (a kilometre: any larger is a unit or typing mistake).
MAX_INSTRUMENT_SIGMA = 1e6


def noise_cov(sigma_mm: float, sigma_deg: float) -> np.ndarray:
    """Instrument noise covariance ``diag(s_mm^2, s_mm^2, s_deg^2)``, shape (3, 3).

    Raises
    ------
    BudgetError
        A standard deviation is negative, not finite, or beyond any instrument
        (above :data:`MAX_INSTRUMENT_SIGMA`: its square would overflow the fit).
    """
    for name, v in (("instrument_sigma_mm", sigma_mm), ("instrument_sigma_deg", sigma_deg)):
        if not (np.isfinite(v) and v >= 0):
            raise ParameterError(f"{name} must be finite and >= 0, got {v}")
        if v > MAX_INSTRUMENT_SIGMA:
            raise ParameterError(f"{name} = {v:g} is beyond any instrument (at most {MAX_INSTRUMENT_SIGMA:g}): "
                                 "give the instrument's noise sd in mm and deg")
    return np.diag([sigma_mm**2, sigma_mm**2, sigma_deg**2])


def predict(geometry: Geometry, budget: Budget, campaign: Campaign, *, effects: dict | None = None,
            instrument_sigma_mm: float = 0.0, instrument_sigma_deg: float = 0.0,
            repeatable_fraction: float = 0.0) -> Prediction:
    """Distribution of ``measured - commanded`` for every measurement of ``campaign``.

    Parameters
    ----------
    geometry, budget
    campaign : Campaign
    effects : dict of str to float, optional
        Library effects added to the model (systematic values, a cyclic
        error's phasor, and spreads); a systematic effect the budget's
        ``[effects]`` already holds adds to its value.
    instrument_sigma_mm, instrument_sigma_deg : float
    repeatable_fraction : float
        Share ``r`` in [0, 1] of the budget's covariance that repeats at every visit of a pose.

    Returns
    -------
    Prediction

    Raises
    ------
    CampaignError
        The budget has an effect whose driver column the campaign lacks.
    BudgetError
        The budget's effects were fitted on another geometry.
    """
    effects = dict(effects or {})
    model_budget = spread_budget(budget, effects)
    if not 0.0 <= repeatable_fraction <= 1.0:
        raise ParameterError(f"repeatable_fraction must lie in [0, 1], got {repeatable_fraction}")
    mean, sigma = linear_model(geometry, model_budget.without_effects(), campaign.poses, check=False).moments()
    noise = noise_cov(instrument_sigma_mm, instrument_sigma_deg)
    systematic = {k: v for k, v in effects.items() if effect(k).systematic}
    m = mean[campaign.pose_index] + budget_effect_errors(geometry, budget, campaign)
    if systematic:
        G = signatures(geometry, campaign.poses, campaign.pose_index, list(systematic),
                       campaign.direction, campaign.temp_C)
        m = m + G @ components(list(systematic), list(systematic.values()))
    return Prediction(mean=m, cov=sigma + noise, scatter_cov=(1.0 - repeatable_fraction) * sigma + noise,
                      pose_index=campaign.pose_index, poses=campaign.poses, budget=model_budget, effects=effects,
                      repeatable_fraction=float(repeatable_fraction))
