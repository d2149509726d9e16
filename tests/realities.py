"""The campaign layout and instrument of the discrepancy tests.

The realities an instrument adds (registration, drift, gross errors, errors
that repeat) are :func:`~prp3mc.measurement.campaign.simulate.simulate_campaign`'s
keyword arguments.
"""

import numpy as np

from prp3mc import Budget, Region
from prp3mc.measurement.campaign.simulate import simulate_campaign, visit_times

SIGMA = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
BUDGET = Budget.from_preset("paper")


def campaign_poses(preset: str, vary_phi: bool) -> np.ndarray:
    """The 7 x 7 grid of the preset's region, phi cycling -4, 0, 4 deg if ``vary_phi``."""
    poses = Region.from_preset(preset).grid(7).reshape(-1, 3)
    if vary_phi:
        poses[:, 2] = np.tile([-4.0, 0.0, 4.0], 17)[:49]
    return poses


# ------------------------------------------------------------------ cyclic screw errors, sweeps, outside the library
#: Lead of every slider's screw in the cyclic-error campaigns, mm (a 5 mm ball screw).
LEAD_MM = 5.0


def with_leads(geometry, lead_mm: float = LEAD_MM):
    """``geometry`` with ``lead_mm`` on every leg (what ``cyclic_i`` needs)."""
    return geometry.replace(lead=(lead_mm,) * 3)


def sweep_poses(preset: str, n: int = 15) -> np.ndarray:
    """A laser tracker's sweep: the n x n grid of the preset's region at phi = 0 in serpentine order, (n*n, 3).

    Visit it with ``simulate_campaign(..., n_repeats=1, visit_order="given")``: every pose once, time
    running along the path.
    """
    grid = Region.from_preset(preset).grid(n)                # (ny, nx, 3)
    grid[1::2] = grid[1::2, ::-1]
    return grid.reshape(-1, 3)


def cyclic_error(leg: int, amplitude_mm: float, lead_mm: float = LEAD_MM, phase_deg: float = 30.0):
    """A cyclic screw error of leg ``leg`` (1-3) as a ``slider_error_fn``: for a geometry without ``lead_mm``,
    where it is outside what the workflow can name."""
    def fn(cmd, b, direction, temp):
        out = np.zeros_like(b)
        out[:, leg - 1] = amplitude_mm * np.sin(2 * np.pi * b[:, leg - 1] / lead_mm + np.deg2rad(phase_deg))
        return out
    return fn


def bowed_rail(leg: int, end_mm: float, b_lo: float, b_hi: float):
    """A ``slider_error_fn``: slider ``leg`` (1-3) off by ``end_mm (2 (b - mid) / (b_hi - b_lo))^2``, quadratic
    in b (0 at the middle of [b_lo, b_hi], ``end_mm`` at its ends: give the campaign's range of b).
    First-order equivalents: ``b_i`` and ``scale_i``."""
    def fn(cmd, b, direction, temp):
        out = np.zeros_like(b)
        out[:, leg - 1] = end_mm * (2 * (b[:, leg - 1] - 0.5 * (b_lo + b_hi)) / (b_hi - b_lo)) ** 2
        return out
    return fn


def sagging_guide(geometry, leg: int, tilt_deg: float, d_ref_mm: float = 100.0):
    """A ``pose_error_fn``: leg ``leg``'s passive guide sags as it extends, its angle off by
    ``tilt_deg (d_i / d_ref)^2`` (a cantilever's end slope), through the exact chain.
    First-order equivalent: ``theta_i``."""
    from prp3mc import exact_pose_error
    from prp3mc.kinematics.chain import inverse_kinematics

    def fn(cmd, b, direction, temp):
        _, d = inverse_kinematics(geometry, cmd, check=False)
        theta = np.zeros_like(cmd)
        theta[:, leg - 1] = tilt_deg * (d[:, leg - 1] / d_ref_mm) ** 2
        return exact_pose_error(geometry, cmd, {"theta": theta}, check=False)
    return fn


def thermal_error(alpha_per_K: float):
    """A ``slider_error_fn``: thermal expansion of every slider's screw at the campaign's true temperature."""
    def fn(cmd, b, direction, temp):
        return alpha_per_K * (temp[:, None] - 20.0) * b
    return fn


def saturated(campaign, ceiling_C: float):
    """``campaign`` with its temperature sensor saturating at ``ceiling_C`` (the machine saw the true one)."""
    import dataclasses
    return dataclasses.replace(campaign, temp_C=np.minimum(campaign.temp_C, ceiling_C))


# ------------------------------------------------------------------ temperature following time, or cycled
def thermal_campaign(geometry, poses, n_repeats: int, alpha_T: float, temperature, rng, **kwargs):
    """A campaign of a machine whose lead screws expand with the temperature, made apart from the library.

    The slider error ``alpha_T (T - 20) b_i`` is added by the simulator's
    out-of-library hook with this module's own temperature: ``temperature(s)``
    degrees C at the campaign's time fraction ``s`` (0 at the first
    measurement, 1 at the last, from ``time_s``), which also fills ``temp_C``.
    ``kwargs`` go to the simulator (a campaign template, ``plan``, among them: its ``time_s`` is the time).

    Returns
    -------
    DataFrame
        The campaign in the file layout.
    """
    def expansion(cmd, b, direction, temp):
        plan = kwargs.get("plan")
        t = visit_times(b) if plan is None else np.asarray(plan["time_s"], dtype=float)
        return alpha_T * (temperature((t - t[0]) / (t[-1] - t[0]))[:, None] - 20.0) * b

    c = simulate_campaign(geometry, BUDGET, poses, n_repeats, slider_error_fn=expansion, rng=rng, **SIGMA, **kwargs)
    frame = c.to_frame()
    t = frame["time_s"].to_numpy()
    frame["temp_C"] = temperature((t - t[0]) / (t[-1] - t[0]))
    return frame


def rising(s):
    """A machine warming up: 20 -> 28 degC, steadily with time."""
    return 20.0 + 8.0 * s


def cycled(s):
    """The temperature cycled three times through the campaign between 20 and 28 degC."""
    return 24.0 - 4.0 * np.cos(2.0 * np.pi * 3.0 * s)
