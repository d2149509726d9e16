"""The fused envelope kernel (worst_case_maxima) equals the numpy path of worst_case."""

import numpy as np
import pytest

from prp3mc import Budget, Normal, Uniform, feasible, worst_case
from prp3mc.errors import InfeasiblePoseError
from prp3mc.worstcase import _kernel as _envelope
from prp3mc.worstcase.envelope import QUANTITIES, worst_case_maxima

from .conftest import random_poses

PAPER = Budget.from_preset("paper")
BUDGETS = {
    "paper": (PAPER, None),
    "restricted contact angles": (PAPER.replace(zeta_1=Uniform(30.0, 75.0), zeta_2=Uniform(-200.0, -10.0),
                                                zeta_3=Uniform(100.0, 400.0)), None),
    "one clearance, angles": (Budget({"rho_2": Uniform(0.002, 0.01), "zeta_2": Uniform(170.0, 190.0),
                                      "psi_3": Uniform(-0.01, 0.03), "gamma_1": Uniform(0.0, 0.02),
                                      "alpha_2": Uniform(-0.01, 0.01), "beta_3": Uniform(-0.02, 0.0)}), None),
    "normal bounded at 3 sd": (PAPER.replace(theta_2=Normal(0.001, 0.01), e_1=Normal(0.0, 0.002)), 3.0),
}


@pytest.mark.parametrize("name", BUDGETS)
@pytest.mark.parametrize("theta", [None, (4.0, -7.0, 10.0)])
def test_kernel_equals_numpy_path(geometry, region, name, theta):
    budget, k_sigma = BUDGETS[name]
    geometry = geometry if theta is None else geometry.replace(theta=theta)
    poses = random_poses(region, 60, np.random.default_rng(3), phi_deg=(-3.0, 3.0))
    poses = poses[feasible(geometry, poses)]
    assert len(poses) > 20
    wc = worst_case(geometry, budget, poses, k_sigma=k_sigma)
    mx = worst_case_maxima(geometry, budget, poses, k_sigma=k_sigma)
    for q in QUANTITIES:
        np.testing.assert_allclose(mx.value(q), wc.value(q), rtol=1e-12, atol=0)
        np.testing.assert_array_equal(mx.leg_signs[q], wc.leg_signs[q])
    np.testing.assert_array_equal(mx.input_bounds, wc.input_bounds)


def test_threaded_grid_equals_numpy_path(geometry, region, monkeypatch):
    """A grid in chunks on threads (made small here, ragged at the end), with the shape kept."""
    monkeypatch.setattr(_envelope, "THREADS_FROM", 1000)
    monkeypatch.setattr(_envelope, "CHUNK", 777)
    grid = region.grid(131)
    wc, mx = worst_case(geometry, PAPER, grid), worst_case_maxima(geometry, PAPER, grid)
    assert mx.position_mm.shape == grid.shape[:-1]
    for q in QUANTITIES:
        np.testing.assert_allclose(mx.value(q), wc.value(q), rtol=1e-12, atol=0)
    assert mx.to_frame().shape == wc.to_frame().shape


@pytest.mark.parametrize("move", [(0.0, 1e4, 0.0), (0.0, -1e4, 0.0), (0.0, 0.0, 89.0)])
def test_refuses_like_the_numpy_path(geometry, region, move):
    grid = region.grid(9)
    grid[3, 5] += move
    grid[6, 1] += move
    with pytest.raises(InfeasiblePoseError) as expected:
        worst_case(geometry, PAPER, grid)
    with pytest.raises(InfeasiblePoseError) as got:
        worst_case_maxima(geometry, PAPER, grid)
    assert str(got.value) == str(expected.value)
    assert "at index (32,)" in str(got.value)          # the first bad pose, flat
    one = grid[3, 5]
    with pytest.raises(InfeasiblePoseError, match="at index") as single:
        worst_case_maxima(geometry, PAPER, one)
    with pytest.raises(InfeasiblePoseError) as single_expected:
        worst_case(geometry, PAPER, one)
    assert str(single.value) == str(single_expected.value)
    unchecked = worst_case_maxima(geometry, PAPER, grid, check=False)
    assert unchecked.position_mm.shape == (9, 9)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("column", [0, 1, 2])
@pytest.mark.parametrize("check", [True, False])
def test_refuses_non_finite_poses_like_the_numpy_path(geometry, region, bad, column, check):
    """A pose holding NaN or infinity is named as worst_case names it, limits tested or not, before
    any other refusal (the kernel flags it; nothing is computed from it)."""
    grid = region.grid(7)
    grid[1, 2] += (0.0, 1e4, 0.0)           # refused for its stroke, earlier in the grid
    grid[4, 3, column] = bad
    with pytest.raises(InfeasiblePoseError) as expected:
        worst_case(geometry, PAPER, grid)
    with pytest.raises(InfeasiblePoseError) as got:
        worst_case_maxima(geometry, PAPER, grid, check=check)
    assert str(got.value) == str(expected.value)
    assert "at index (4, 3)" in str(got.value) and "NaN or infinity" in str(got.value)


def test_signs_are_unpacked_from_the_codes_on_access(geometry, region):
    """The result keeps one int16 code per maximum; the signs are read from it, int8, read-only."""
    mx = worst_case_maxima(geometry, PAPER, region.grid(5))
    assert mx.codes.dtype == np.int16 and mx.codes.shape == (4, 5, 5)
    signs = mx.leg_signs["position"]
    assert signs.dtype == np.int8 and signs.shape == (5, 5, 3) and set(np.unique(signs)) <= {-1, 1}
    assert mx.shared_signs["x"].shape == (5, 5, 0)
    for a in (mx.maxima, mx.codes, mx.poses):
        assert not a.flags.writeable
