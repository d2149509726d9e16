"""Gross errors (a lost tracker beam, a mistyped row) found at a stated family-wise false-alarm rate.

Each measurement is compared with what the fitted model predicts for it
*from the other measurements*: with ``W`` the visit-to-visit covariance and
``B = r Sigma`` the repeatable one (:mod:`~prp3mc.measurement.estimation.likelihood`),
the other ``n'`` kept visits of its pose predict its repeatable part by
``K ybar'`` with ``K = B (B + W / n')^-1``, leaving a prediction error of
covariance ``V = W + B - K B``. Its squared Mahalanobis length
``d^2 = e' V^-1 e`` is chi2(3) for a Gaussian error; the budget's laws are
bounded (uniform clearances, encoder counts and plays), so their tails are
lighter and chi2(3) is conservative. A measurement is a gross error when
``d^2`` exceeds the chi2(3) quantile at the Šidák level ``1 - (1 -
rate)^(1/M)`` (a pose visited once is predicted by the model alone, ``V = W + B``): the probability that any of the M measurements of a campaign
without gross errors is flagged is at most ``rate`` (1 % by default).

Flagging is iterated (set aside, refit, test again, so one gross error
cannot mask another); the workflow finally tests every row again under the
model with the named effects, so that rows set aside only because a spread
was not yet in the model come back.
"""

from __future__ import annotations

import numpy as np

from ..forward.signatures import components
from .likelihood import Engine
from .nuisance import NUISANCE_NAMES

__all__ = ["distances", "threshold", "flag", "outlier_rows", "outlier_rule"]

#: Most refits while flagging.
_MAX_ROUNDS = 6


def threshold(n_measurements: int, rate: float) -> float:
    """Squared distance above which one of ``n_measurements`` rows is a gross error (Šidák at ``rate``)."""
    level = -np.expm1(np.log1p(-rate) / n_measurements)
    from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
    return float(chi2.isf(level, 3))


def distances(engine: Engine, keep: np.ndarray, values: dict, factors: dict, r: float) -> np.ndarray:
    """Squared standardised prediction error ``d^2`` of every row of ``engine`` (the whole campaign).

    Parameters
    ----------
    engine : Engine
        On the whole campaign.
    keep : ndarray of bool, shape (M,)
        Rows that predict the others (a kept row is predicted from the other kept rows of its pose).
    values : dict
        Fitted nuisance and systematic values, name -> value (:meth:`Engine.values`; a cyclic error's phasor).
    factors : dict
        Spread factors.
    r : float
        Repeatable fraction.

    Returns
    -------
    ndarray, shape (M,)
    """
    mean, W, B = engine.moments(factors, r)
    resid = engine.err - mean[engine.idx]
    named = [name for name in values if name not in NUISANCE_NAMES]
    for name in values:
        if name in NUISANCE_NAMES:
            resid = resid - values[name] * engine.H[:, :, NUISANCE_NAMES.index(name)]
    if named:
        resid = resid - engine.columns(tuple(engine.sys_index(n) for n in named), ()) @ components(
            named, [values[n] for n in named])
    kept = keep.astype(float)
    total = np.zeros((engine.P, 3))
    np.add.at(total, engine.idx, resid * kept[:, None])
    count = np.bincount(engine.idx, weights=kept, minlength=engine.P)
    others = total[engine.idx] - resid * kept[:, None]
    n_other = count[engine.idx] - kept
    Wm, Bm = W[engine.idx], B[engine.idx]
    has = n_other > 0
    safe = np.where(has, n_other, 1.0)
    # K = B (B + W/n')^-1, symmetric system solved as (B + W/n') K' = B
    K = np.swapaxes(np.linalg.solve(Bm + Wm / safe[:, None, None], Bm), 1, 2)
    K = np.where(has[:, None, None], K, 0.0)
    e = resid - np.einsum("mij,mj->mi", K, others / safe[:, None])
    V = Wm + Bm - K @ Bm
    return np.einsum("mi,mi->m", e, np.linalg.solve(V, e[..., None])[..., 0])


def flag(engine: Engine, fit_kept, rate: float, keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Set gross errors aside, refitting after each round, until no kept row exceeds the threshold.

    Parameters
    ----------
    engine : Engine
        On the whole campaign.
    fit_kept : callable
        ``fit_kept(keep) -> (engine_kept, fit)``: the model fitted to the kept rows.
    rate : float
        Family-wise false-alarm rate.
    keep : ndarray of bool, optional
        Rows kept at the start (all by default); rows once set aside stay aside.

    Returns
    -------
    keep : ndarray of bool, shape (M,)
    d2 : ndarray, shape (M,)
        Every row's ``d^2`` under the last fit.
    """
    keep = np.ones(engine.M, bool) if keep is None else keep.copy()
    limit = threshold(engine.M, rate)
    for _ in range(_MAX_ROUNDS):
        kept_engine, fit = fit_kept(keep)
        d2 = distances(engine, keep, kept_engine.values(fit), fit.factors, fit.r)
        new = keep & (d2 > limit)
        if not new.any():
            break
        keep &= ~new
        if keep.sum() <= 3:
            break
    return keep, d2


def outlier_rows(campaign, keep: np.ndarray, d2: np.ndarray) -> tuple:
    """The ``outliers`` entries: every row set aside (``keep`` False), with its pose id and its standardised
    prediction error ``z = sqrt(d2)`` (:func:`distances`)."""
    return tuple({"row": int(m), "pose_id": str(campaign.pose_id[m]), "z": float(np.sqrt(d2[m]))}
                 for m in np.flatnonzero(~keep))


def outlier_rule(n_measurements: int, limit: float, rate: float) -> dict:
    """The gross-error rule as ``discrepancy.json`` states it: family-wise ``rate`` over ``n_measurements`` rows,
    the per-row level and the threshold ``limit`` of ``d2`` (:func:`threshold`) as a z."""
    return {"family_wise_rate": rate,
            "per_measurement_level": float(-np.expm1(np.log1p(-rate) / n_measurements)),
            "z_threshold": float(np.sqrt(limit)),
            "statistic": "squared standardised error of each measurement predicted from the other visits "
                         "of its pose under the fitted model, chi2(3), Sidak over all rows"}
