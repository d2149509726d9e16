"""Campaigns as a real instrument delivers them, for the discrepancy tests and the rates script.

Each reality transforms the measured columns of a simulated campaign:
registration (rigid machine-to-instrument transform), linear drift over the
campaign (writes ``time_s``), gross errors on a fraction of rows, and a
share of the budget's variance that repeats at every visit of a pose.
"""

import numpy as np

from prp3mc import Budget, Geometry, Region
from prp3mc.measurement.campaign import MEAS_COLUMNS, Campaign
from prp3mc.measurement.effects import signatures
from prp3mc.measurement.simulate import simulate_campaign
from prp3mc.uncertainty.model import linear_model

SIGMA = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
BUDGET = Budget.from_preset("paper")


def campaign_poses(preset: str, vary_phi: bool) -> np.ndarray:
    """The 7 x 7 grid of the preset's region, phi cycling -4, 0, 4 deg if ``vary_phi``."""
    poses = Region.from_preset(preset).grid(7).reshape(-1, 3)
    if vary_phi:
        poses[:, 2] = np.tile([-4.0, 0.0, 4.0], 17)[:49]
    return poses


def _with_measured(c: Campaign, measured: np.ndarray, **columns) -> Campaign:
    frame = c.to_frame()
    for k, col in enumerate(MEAS_COLUMNS):
        frame[col] = measured[:, k]
    for name, values in columns.items():
        frame[name] = values
    return Campaign.from_frame(frame, None, c.source, c.metadata)


def registered(c: Campaign, dx_mm: float, dy_mm: float, dphi_deg: float) -> Campaign:
    """Measured poses seen by an instrument rotated by dphi about its origin, then shifted by (dx, dy)."""
    a = np.deg2rad(dphi_deg)
    x, y, phi = c.measured.T
    m = np.stack([np.cos(a) * x - np.sin(a) * y + dx_mm, np.sin(a) * x + np.cos(a) * y + dy_mm, phi + dphi_deg], 1)
    return _with_measured(c, m)


def drifted(c: Campaign, dx_mm: float, dy_mm: float, dphi_deg: float, duration_s: float = 3600.0) -> Campaign:
    """A drift growing linearly from 0 at the first row to (dx, dy, dphi) at the last; writes time_s."""
    s = np.linspace(0.0, 1.0, c.n_measurements)
    return _with_measured(c, c.measured + s[:, None] * np.array([dx_mm, dy_mm, dphi_deg]),
                          time_s=s * duration_s)


def with_outliers(c: Campaign, fraction: float, size_mm: float, rng) -> tuple[Campaign, np.ndarray]:
    """Rows (a share ``fraction``, at least one) moved ``size_mm`` in a random planar direction; and those rows."""
    rng = np.random.default_rng(rng)
    rows = np.sort(rng.choice(c.n_measurements, max(1, round(fraction * c.n_measurements)), replace=False))
    angle = rng.uniform(0, 2 * np.pi, rows.size)
    m = c.measured.copy()
    m[rows, 0] += size_mm * np.cos(angle)
    m[rows, 1] += size_mm * np.sin(angle)
    return _with_measured(c, m), rows


def repeating(geometry: Geometry, poses, n_repeats: int, r: float, rng, effects=None, **kwargs) -> Campaign:
    """A campaign whose budget errors repeat with share ``r`` of their variance at every visit of a pose.

    Two simulated campaigns without instrument noise give a per-pose draw
    (the first visit of each pose) and per-visit draws; the errors combine
    as ``mu + sqrt(r) (e_pose - mu) + sqrt(1 - r) (e_visit - mu)``, then
    systematic ``effects`` (through their linear signatures) and noise are added.
    """
    rng = np.random.default_rng(rng)
    quiet = {"instrument_sigma_mm": 0.0, "instrument_sigma_deg": 0.0}
    visits = simulate_campaign(geometry, BUDGET, poses, n_repeats, rng=rng, **quiet, **kwargs)
    once = simulate_campaign(geometry, BUDGET, poses, 1, rng=rng, **quiet, **kwargs)
    mu, _ = linear_model(geometry, BUDGET, visits.poses).moments()
    first = {pid: e for pid, e in zip(once.pose_id, once.error)}
    e_pose = np.array([first[p] for p in visits.pose_id])
    mean = mu[visits.pose_index]
    err = mean + np.sqrt(r) * (e_pose - mean) + np.sqrt(1 - r) * (visits.error - mean)
    if effects:
        G = signatures(geometry, visits.poses, visits.pose_index, list(effects), visits.direction, visits.temp_C)
        err = err + G @ np.array(list(effects.values()))
    noise = rng.standard_normal(err.shape) * np.array([SIGMA["instrument_sigma_mm"]] * 2
                                                       + [SIGMA["instrument_sigma_deg"]])
    return _with_measured(visits, visits.commanded + err + noise)
