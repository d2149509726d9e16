"""J_q against the exact nonlinear solution of the perturbed chain."""

import numpy as np
import pytest

from prp3mc import exact_pose_error, sensitivity
from prp3mc.errors import ParameterError
from prp3mc.kinematics.exact import linear_pose_error, linearization_error_um
from prp3mc.kinematics.sensitivity import FAMILIES, LENGTH_FAMILIES

from .conftest import random_poses

STEP = 1e-4  # mm or rad


def exact_column(geometry, poses, family, leg):
    """Derivative of the exact pose error w.r.t. parameter ``family`` of ``leg``.

    Central differences at STEP and STEP/2 combined by Richardson
    extrapolation: truncation O(STEP^4), round-off about 1e-14 / STEP.
    """
    def central(h):
        e = np.zeros(3)
        e[leg] = h if family in LENGTH_FAMILIES else np.rad2deg(h)
        col = (exact_pose_error(geometry, poses, {family: e})
               - exact_pose_error(geometry, poses, {family: -e})) / (2 * h)
        col[..., 2] = np.deg2rad(col[..., 2])  # rows in mm and rad
        return col

    return (4 * central(STEP / 2) - central(STEP)) / 3


@pytest.mark.parametrize("family", FAMILIES)
def test_jq_matches_exact_chain(geometry, region, family):
    rng = np.random.default_rng(abs(hash(family)) % 2**32)
    poses = random_poses(region, 25, rng)
    J = sensitivity(geometry, poses).J[family]
    # Relative to the column, floored at the scale of J_b (O(1) mm/mm): J_c and J_e
    # vanish structurally when theta_i = 0, and relative error of a zero means nothing.
    scale = np.abs(sensitivity(geometry, poses).J["b"]).max(axis=(-2, -1))
    for leg in range(3):
        col = exact_column(geometry, poses, family, leg)
        lin = J[..., :, leg]
        ref = np.maximum(np.linalg.norm(lin, axis=-1), scale)
        rel = np.linalg.norm(col - lin, axis=-1) / ref
        assert rel.max() < 1e-6, (family, leg, rel.max())


def test_rho_with_contact_angle(geometry, region):
    """A clearance at contact angle zeta acts through cos(zeta - omega)."""
    rng = np.random.default_rng(3)
    poses = random_poses(region, 10, rng)
    zeta = rng.uniform(0, 360, (10, 3))
    errors = {"rho": np.full(3, 1e-5), "zeta": zeta}
    exact = exact_pose_error(geometry, poses, errors)
    linear = linear_pose_error(geometry, poses, errors)
    np.testing.assert_allclose(exact, linear, rtol=0, atol=1e-6 * np.abs(linear).max())


def test_linearization_error_is_second_order(geometry):
    errors = {"rho": [0.016] * 3, "zeta": [10.0, 100.0, 200.0], "theta": [0.04, -0.04, 0.04],
              "b": [0.025, 0.0, 0.01], "alpha": [0.01, 0.0, -0.02]}
    pose = [5.0, 0.5 * sum(geometry.stroke[0]), 1.0] if geometry.name == "u-shape" else [5.0, 150.0, 1.0]
    full = linearization_error_um(geometry, pose, errors)
    half = linearization_error_um(geometry, pose, {k: np.multiply(v, 0.5) if k != "zeta" else v
                                                   for k, v in errors.items()})
    assert 0 < full < 1.0  # well under a micrometre at the paper's magnitudes
    assert half == pytest.approx(full / 4, rel=0.05)


def test_j_rho_is_a_inverse(geometry):
    s = sensitivity(geometry, [0.0, 130.0, 2.0])
    np.testing.assert_allclose(s.J["rho"], np.linalg.inv(s.A), rtol=0, atol=1e-14)
    np.testing.assert_allclose(s.J["b"], np.linalg.solve(s.A, s.B), rtol=0, atol=1e-14)


def test_tidy_frame(geometry):
    s = sensitivity(geometry, [[0.0, 130.0, 0.0], [10.0, 140.0, 1.0]])
    df = s.to_frame()
    assert len(df) == 2 * 10 * 9
    assert set(df.columns) == {"x_mm", "y_mm", "phi_deg", "output", "family", "leg", "value", "unit"}
    row = df.query("family == 'theta' and output == 'phi' and leg == 2 and x_mm == 10.0")
    assert row["value"].item() == s.J["theta"][1, 2, 1]
    assert row["unit"].item() == "rad/rad"


def test_unknown_error_family(geometry):
    with pytest.raises(ParameterError, match="unknown error family delta"):
        exact_pose_error(geometry, [0.0, 130.0, 0.0], {"delta": [1, 2, 3]})


@pytest.mark.parametrize("family", ["a", "c", "e", "psi", "gamma"])
def test_jq_matches_exact_chain_with_guide_angles(family):
    """With theta_i != 0, k_i and l_i part and J_c, J_e no longer vanish."""
    from prp3mc import Geometry, Region
    g = Geometry.from_preset("u-shape").replace(theta=(3.0, -2.0, 4.0), psi=(170.0, 5.0, 80.0))
    poses = random_poses(Region.from_preset("u-shape"), 20, np.random.default_rng(11), (-3.0, 3.0))
    s = sensitivity(g, poses)
    scale = np.abs(s.J["b"]).max(axis=(-2, -1))
    for leg in range(3):
        lin = s.J[family][..., :, leg]
        assert np.median(np.linalg.norm(lin, axis=-1)) > 1e-3
        ref = np.maximum(np.linalg.norm(lin, axis=-1), 1e-2 * scale)
        rel = np.linalg.norm(exact_column(g, poses, family, leg) - lin, axis=-1) / ref
        assert rel.max() < 1e-6, (family, leg, rel.max())
