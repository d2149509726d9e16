"""ISO 9283 pose accuracy and repeatability, measured on a campaign and predicted by the model.

For a commanded pose visited ``n`` times, ISO 9283 (sections 7.2.1, 7.2.2)
takes the barycentre of the attained positions and defines

- pose accuracy ``AP``: the distance between the barycentre and the
  commanded position; ``AP_phi = |mean(phi) - phi_cmd|``;
- pose repeatability ``RP = l_bar + 3 S_l``, with ``l_j`` the distance of
  attained position ``j`` from the barycentre, ``l_bar`` their mean and
  ``S_l`` their sample standard deviation (``n - 1``); ``RP_phi = 3 S_phi``
  (the standard reports ``± 3 S_phi``).

*Measured* figures come from a campaign's pose errors. *Predicted* figures
are what ISO 9283 would report on the same campaign (same poses, same number
of visits) if the model were right: the expected value of each figure when
the visits of pose ``p`` are Gaussian, ``e = mu_p + u_p + w_pj`` with
``mu_p`` the predicted mean error, ``u_p ~ N(0, R_p)`` a part that repeats at
every visit of the pose and ``w_pj ~ N(0, S_p)`` the visit-to-visit scatter
(instrument noise included). ``l_bar + 3 S_l`` has no closed form for an
elliptic scatter, so every predicted figure is computed by a seeded Monte
Carlo of ``n_mc`` such campaigns (the seed is recorded); its standard error
is ``predicted_sd / sqrt(n_mc)``. With few visits the expected ``AP``
exceeds ``|mu_p|``: the barycentre of ``n`` visits scatters too.

The *largest* figure over the poses is compared like for like: the measured
largest is the maximum of noisy per-pose figures, so the predicted largest
is the expected maximum over the poses of each simulated campaign, not the
maximum of the per-pose expectations (which would sit below it by the
scatter of the figures, the more so the more poses and the fewer visits).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from ..._rng import child_seed, resolve_rng
from ...errors import CampaignError
from .data import Campaign

__all__ = ["iso9283_figures", "ISO_STATISTICS", "N_MC", "pose_means"]

#: The four ISO 9283 figures per pose and their units.
ISO_STATISTICS = {"AP": "mm", "RP": "mm", "AP_phi": "deg", "RP_phi": "deg"}
#: Simulated campaigns behind the predicted figures (default of :func:`iso9283_figures`).
N_MC = 4000
#: Key of each figure in the ``iso9283`` entry of ``discrepancy.json``.
_KEYS = {"AP": "AP_mm", "RP": "RP_mm", "AP_phi": "AP_phi_deg", "RP_phi": "RP_phi_deg"}


def pose_means(values: np.ndarray, pose_index: np.ndarray, n_poses: int) -> np.ndarray:
    """Mean of ``values`` (M, k) over the rows of each pose, shape (P, k); NaN for a pose without rows."""
    count = np.bincount(pose_index, minlength=n_poses).astype(float)
    sums = np.stack([np.bincount(pose_index, values[:, k], n_poses) for k in range(values.shape[1])], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / count[:, None]


def _figures(errors: np.ndarray) -> np.ndarray:
    """ISO 9283 figures of visits ``errors`` (..., n, 3) of one pose each: (..., 4) ``AP, RP, AP_phi, RP_phi``."""
    bary = errors.mean(axis=-2)
    n = errors.shape[-2]
    l_dist = np.hypot(*np.moveaxis(errors[..., :2] - bary[..., None, :2], -1, 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        s_l = l_dist.std(axis=-1, ddof=1) if n > 1 else np.full(l_dist.shape[:-1], np.nan)
        s_phi = errors[..., 2].std(axis=-1, ddof=1) if n > 1 else np.full(l_dist.shape[:-1], np.nan)
    return np.stack([np.hypot(bary[..., 0], bary[..., 1]), l_dist.mean(axis=-1) + 3.0 * s_l,
                     np.abs(bary[..., 2]), 3.0 * s_phi], axis=-1)


def _measured(campaign: Campaign, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Measured figures per pose (P, 4) and visit counts (P,), from the rows kept."""
    P = campaign.n_poses
    idx, err = campaign.pose_index[keep], campaign.error[keep]
    n = np.bincount(idx, minlength=P)
    bary = pose_means(err, idx, P)
    dev = err - bary[idx]
    l_dist = np.hypot(dev[:, 0], dev[:, 1])
    l_bar = pose_means(l_dist[:, None], idx, P)[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        s_l = np.sqrt(np.bincount(idx, (l_dist - l_bar[idx]) ** 2, P) / (n - 1))
        s_phi = np.sqrt(np.bincount(idx, dev[:, 2] ** 2, P) / (n - 1))
    s_l[n < 2], s_phi[n < 2] = np.nan, np.nan
    return np.stack([np.hypot(bary[:, 0], bary[:, 1]), l_bar + 3.0 * s_l, np.abs(bary[:, 2]), 3.0 * s_phi],
                    axis=-1), n


def _sqrt_psd(cov: np.ndarray) -> np.ndarray:
    """A square root ``L`` with ``L L^T = cov`` of symmetric positive semi-definite (..., 3, 3) matrices."""
    w, v = np.linalg.eigh(cov)
    return v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


def _predicted(mean: np.ndarray, scatter: np.ndarray, repeat: np.ndarray, n: np.ndarray, n_mc: int,
               seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulated figures of ``n_mc`` campaigns, by Monte Carlo.

    Pose ``p`` draws from its own stream ``child_seed(seed, p)``, so a
    pose's numbers do not depend on the other poses.

    Returns
    -------
    expected, spread : ndarray, shape (P, 4)
        Mean and standard deviation of each pose's figures between campaigns.
    largest : ndarray, shape (n_mc, 4)
        Each simulated campaign's largest figure over the poses (NaN where no pose defines it).
    """
    L_s, L_r = _sqrt_psd(scatter), _sqrt_psd(repeat)
    sims = np.full((len(n), n_mc, 4), np.nan)
    for p in np.flatnonzero(n > 0):
        gen = np.random.default_rng(child_seed(seed, int(p)))
        shift = mean[p] + gen.standard_normal((n_mc, 3)) @ L_r[p].T                    # (n_mc, 3)
        visits = shift[:, None, :] + gen.standard_normal((n_mc, int(n[p]), 3)) @ L_s[p].T
        sims[p] = _figures(visits)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)                                   # all-NaN columns
        expected, spread = np.nanmean(sims, axis=1), np.nanstd(sims, axis=1, ddof=1)
        largest = np.nanmax(sims, axis=0)
    return expected, spread, largest


def _by_key(values: np.ndarray) -> dict:
    """The four figures ``values`` (4,) under their JSON keys (None where undefined)."""
    return {_KEYS[name]: float(v) if np.isfinite(v) else None for name, v in zip(ISO_STATISTICS, values)}


def _largest(values: np.ndarray) -> dict:
    """The largest of each figure over the poses (P, 4) (None where no pose defines it), JSON keys."""
    return _by_key(np.array([np.nanmax(c) if np.isfinite(c).any() else np.nan for c in values.T]))


def iso9283_figures(campaign: Campaign, predicted_mean, predicted_scatter_cov, *, predicted_repeat_cov=None,
                    keep=None, n_mc: int = N_MC, rng: "None | int | np.random.Generator" = None) -> dict:
    """ISO 9283 pose accuracy and repeatability per pose, measured and predicted (see the module notes).

    Parameters
    ----------
    campaign : Campaign
        Its pose errors ``measured - commanded`` are the attained poses
        (already in the machine's frame: correct a fitted registration first).
    predicted_mean : array_like, shape (P, 3)
        Predicted mean pose error of each of the campaign's poses, ``[mm, mm, deg]``.
    predicted_scatter_cov : array_like, shape (P, 3, 3)
        Predicted visit-to-visit covariance of the pose error (instrument
        noise included), ``[mm, mm, deg]`` squared.
    predicted_repeat_cov : array_like, shape (P, 3, 3), optional
        Predicted covariance of the part of the error that repeats at every
        visit of a pose (zero when None): it moves the barycentre, not the scatter.
    keep : array_like of bool, shape (M,), optional
        Measurements used (e.g. outliers set aside); all when None.
    n_mc : int
        Simulated campaigns for the predicted figures.
    rng : None, int or numpy.random.Generator
        Randomness of that Monte Carlo; the integer seed is recorded.

    Returns
    -------
    dict
        ``measured``: the largest ``AP_mm, RP_mm, AP_phi_deg, RP_phi_deg``
        over the poses (None if no pose has two visits for an RP);
        ``predicted``: the expected largest (see the module notes) and
        ``predicted_sd`` its spread between campaigns, same keys; ``per_pose``: a tidy DataFrame with columns
        ``pose_id, x_mm, y_mm, phi_deg, n, statistic`` (``AP``, ``RP``,
        ``AP_phi``, ``RP_phi``), ``measured``, ``predicted``,
        ``predicted_sd`` (the spread of the measured figure between
        campaigns of this size if the model is right) and ``unit`` (mm,
        deg); ``seed``, ``n_mc`` and ``method``.

    Raises
    ------
    CampaignError
        Shapes that do not match the campaign, or ``n_mc < 2``.
    """
    seed, _ = resolve_rng(rng)
    P = campaign.n_poses
    mean = np.asarray(predicted_mean, dtype=float)
    scatter = np.asarray(predicted_scatter_cov, dtype=float)
    repeat = np.zeros((P, 3, 3)) if predicted_repeat_cov is None else np.asarray(predicted_repeat_cov, dtype=float)
    for name, value, shape in (("predicted_mean", mean, (P, 3)), ("predicted_scatter_cov", scatter, (P, 3, 3)),
                               ("predicted_repeat_cov", repeat, (P, 3, 3))):
        if value.shape != shape:
            raise CampaignError(f"{name} must have shape {shape} (the campaign's {P} poses), got {value.shape}")
    keep = np.ones(campaign.n_measurements, bool) if keep is None else np.asarray(keep, dtype=bool)
    if keep.shape != (campaign.n_measurements,):
        raise CampaignError(f"keep must have one flag per measurement ({campaign.n_measurements}), got {keep.shape}")
    n_mc = int(n_mc)
    if n_mc < 2:
        raise CampaignError(f"n_mc must be at least 2, got {n_mc}")
    measured, n = _measured(campaign, keep)
    predicted, spread, largest = _predicted(mean, scatter, repeat, n, n_mc, seed)
    names = list(ISO_STATISTICS)
    per_pose = pd.DataFrame({
        "pose_id": np.repeat(campaign.pose_labels, 4),
        "x_mm": np.repeat(campaign.poses[:, 0], 4), "y_mm": np.repeat(campaign.poses[:, 1], 4),
        "phi_deg": np.repeat(campaign.poses[:, 2], 4), "n": np.repeat(n, 4),
        "statistic": np.tile(names, P), "measured": measured.ravel(), "predicted": predicted.ravel(),
        "predicted_sd": spread.ravel(), "unit": np.tile([ISO_STATISTICS[s] for s in names], P)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)                                   # all-NaN columns
        expected_largest, sd_largest = np.nanmean(largest, axis=0), np.nanstd(largest, axis=0, ddof=1)
    return {"measured": _largest(measured), "predicted": _by_key(expected_largest),
            "predicted_sd": _by_key(sd_largest), "per_pose": per_pose, "seed": seed, "n_mc": n_mc,
            "method": "measured: ISO 9283 on the campaign; predicted: expected ISO 9283 figures of Gaussian "
                      f"visits with the model's mean and covariance, Monte Carlo of {n_mc} campaigns "
                      "(the largest over the poses: the expected largest of each simulated campaign)"}
