"""The campaign layout and instrument of the discrepancy tests.

The realities an instrument adds (registration, drift, gross errors, errors
that repeat) are :func:`~prp3mc.measurement.campaign.simulate.simulate_campaign`'s
keyword arguments.
"""

import numpy as np

from prp3mc import Budget, Region

SIGMA = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
BUDGET = Budget.from_preset("paper")


def campaign_poses(preset: str, vary_phi: bool) -> np.ndarray:
    """The 7 x 7 grid of the preset's region, phi cycling -4, 0, 4 deg if ``vary_phi``."""
    poses = Region.from_preset(preset).grid(7).reshape(-1, 3)
    if vary_phi:
        poses[:, 2] = np.tile([-4.0, 0.0, 4.0], 17)[:49]
    return poses
