"""Shared fixtures: the reference geometries and random poses in their test regions."""

import numpy as np
import pytest

from prp3mc import Geometry, Region

PRESETS = ("u-shape", "delta-shape")


@pytest.fixture(params=PRESETS)
def preset(request) -> str:
    return request.param


@pytest.fixture
def geometry(preset) -> Geometry:
    return Geometry.from_preset(preset)


@pytest.fixture
def region(preset) -> Region:
    return Region.from_preset(preset)


def random_poses(region: Region, n: int, rng, phi_deg=(-5.0, 5.0)) -> np.ndarray:
    """``n`` poses uniform over ``region`` with phi uniform in ``phi_deg``; shape (n, 3)."""
    return np.stack([rng.uniform(*region.x_mm, n), rng.uniform(*region.y_mm, n),
                     rng.uniform(*phi_deg, n)], axis=-1)
