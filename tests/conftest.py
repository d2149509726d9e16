"""Shared fixtures: the reference geometries and random poses in their test regions."""

import os

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


@pytest.fixture
def seed(request) -> int:
    """A fresh seed for a test that must pass for any seed; shown in the report when the test fails.

    Set ``PRP3MC_TEST_SEED`` to replay one.
    """
    value = int(os.environ.get("PRP3MC_TEST_SEED", np.random.SeedSequence().entropy % 2**63))
    request.node.prp3mc_seed = value
    return value


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    value = getattr(item, "prp3mc_seed", None)
    if value is not None and report.failed:
        report.sections.append(("prp3mc seed", f"seed = {value}; replay with PRP3MC_TEST_SEED={value}"))
    return report
