import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from prp3mc import Geometry, Region, feasible, forward_kinematics, inverse_kinematics, sensitivity
from prp3mc.errors import InfeasiblePoseError
from prp3mc.kinematics.chain import Limits, check_poses, jacobian, jacobians
from prp3mc.kinematics.sensitivity import FAMILIES

from .conftest import PRESETS


def pose_in(preset):
    r = Region.from_preset(preset)
    return st.tuples(st.floats(*r.x_mm), st.floats(*r.y_mm), st.floats(-5.0, 5.0))


@pytest.mark.parametrize("preset", PRESETS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_fk_inverts_ik(preset, data):
    g = Geometry.from_preset(preset)
    pose = np.array(data.draw(pose_in(preset)))
    b, d = inverse_kinematics(g, pose)
    assert np.all(d > 0)
    np.testing.assert_allclose(forward_kinematics(g, b), pose, rtol=0, atol=1e-9)


def test_ik_reproduces_closure(geometry, region):
    """T = a i + b j + c k + d l + e m holds for every leg (eq. 1)."""
    poses = region.grid(7)
    b, d = inverse_kinematics(geometry, poses)
    phi = np.deg2rad(poses[..., 2])[..., None]
    u = lambda t: np.stack([np.cos(t), np.sin(t)], -1)  # noqa: E731
    r = lambda k: geometry.rad(k)  # noqa: E731
    i, j = u(r("alpha") + 0 * phi), u(r("alpha") + r("beta") + 0 * phi)
    k = u(r("alpha") + r("beta") + r("gamma") + phi)
    l, m = u(r("alpha") + r("beta") + r("gamma") + phi + r("theta")), u(phi + r("psi"))
    T = (r("a")[:, None] * i + b[..., None] * j + r("c")[:, None] * k + d[..., None] * l
         + r("e")[:, None] * m)
    np.testing.assert_allclose(T, np.broadcast_to(poses[..., None, :2], T.shape), atol=1e-10)


@pytest.mark.parametrize("shape", [(), (4,), (3, 2)])
def test_batch_equals_loop(geometry, region, shape):
    rng = np.random.default_rng(7)
    from .conftest import random_poses
    poses = random_poses(region, int(np.prod(shape, dtype=int)), rng).reshape(shape + (3,))
    b, d = inverse_kinematics(geometry, poses)
    A, B = jacobians(geometry, poses)
    s = sensitivity(geometry, poses)
    for idx in np.ndindex(shape):
        b1, d1 = inverse_kinematics(geometry, poses[idx])
        A1, B1 = jacobians(geometry, poses[idx])
        s1 = sensitivity(geometry, poses[idx])
        np.testing.assert_allclose(b[idx], b1, rtol=1e-14, atol=1e-12)
        np.testing.assert_allclose(A[idx], A1, rtol=1e-14, atol=1e-12)
        np.testing.assert_allclose(B[idx], B1, rtol=1e-14, atol=1e-12)
        for q in FAMILIES:
            np.testing.assert_allclose(s.J[q][idx], s1.J[q], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(forward_kinematics(geometry, b), poses, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(angle=st.floats(-180.0, 180.0), data=st.data())
def test_base_rotation_rotates_jacobians(angle, data):
    g = Geometry.from_preset("delta-shape")
    x, y, phi = data.draw(pose_in("delta-shape"))
    c, s_ = np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))
    R = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    turned = np.array([c * x - s_ * y, s_ * x + c * y, phi + angle])
    s0 = sensitivity(g, [x, y, phi])
    s1 = sensitivity(g.rotated(angle), turned)
    for q in FAMILIES:
        scale = max(np.abs(s0.J[q]).max(), np.abs(s0.J["b"]).max())  # J_c, J_e can be 0
        np.testing.assert_allclose(s1.J[q], R @ s0.J[q], rtol=0, atol=1e-10 * scale)


def test_jacobian_is_a_inverse_b(geometry):
    A, B = jacobians(geometry, [0.0, 150.0, 2.0])
    np.testing.assert_allclose(jacobian(geometry, [0.0, 150.0, 2.0]), np.linalg.solve(A, B), rtol=1e-12, atol=1e-15)


def test_whole_regions_feasible_within_5_deg(geometry, region):
    for phi in (-5.0, 0.0, 5.0):
        grid = region.grid(41)
        grid[..., 2] = phi
        assert feasible(geometry, grid).all()


def test_delta_corner_leaves_stroke_at_minus_10_deg():
    g = Geometry.from_preset("delta-shape")
    with pytest.raises(InfeasiblePoseError, match="leg 1's stroke"):
        check_poses(g, [-40.0, 200.0, -10.0])


@pytest.mark.parametrize("pose, limits, message", [
    ([0.0, 300.0, 0.0], Limits(), r"leg 1's stroke: b_1 = 300 mm > 200 mm"),
    ([0.0, 160.0, 0.0], Limits(), r"d_3 = -10 mm <= 0 on leg 3"),
    ([np.nan, 100.0, 0.0], Limits(), "NaN"),
    ([0.0, 100.0, 5.0], Limits(min_transmission=0.999), "serial singularity of leg 1"),
    ([0.0, 100.0, 0.0], Limits(max_condition=1.2), "parallel singularity"),
])
def test_refused_poses_name_leg_and_limit(pose, limits, message):
    g = Geometry.from_preset("u-shape")
    with pytest.raises(InfeasiblePoseError, match=message):
        check_poses(g, pose, limits)
    assert not feasible(g, pose, limits)


def test_bad_pose_shape():
    with pytest.raises(InfeasiblePoseError, match="shape"):
        inverse_kinematics(Geometry.from_preset("u-shape"), [1.0, 2.0])
