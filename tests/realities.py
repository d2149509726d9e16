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


def thermal_campaign(geometry, poses, n_repeats: int, alpha_T: float, temperature, rng, **kwargs):
    """A campaign of a machine whose lead screws expand with the temperature, made apart from the library.

    The slider error ``alpha_T (T - 20) b_i`` is added by the simulator's
    out-of-library hook with this module's own temperature: ``temperature(s)``
    degrees C at the campaign's time fraction ``s`` (0 at the first
    measurement, 1 at the last, from ``time_s``), which also fills ``temp_C``.
    ``kwargs`` go to the simulator (a planned ``order``, ``approach`` and ``time_s`` among them).

    Returns
    -------
    DataFrame
        The campaign in the file layout.
    """
    def expansion(cmd, b, direction, temp):
        t = np.asarray(kwargs["time_s"], dtype=float) if kwargs.get("time_s") is not None else visit_times(b)
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
