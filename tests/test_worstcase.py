"""The exact envelope: never exceeded, attained, and equal to independent computations."""

import itertools
import json

import numpy as np
import pytest

from prp3mc import Budget, Discrete, Normal, Triangular, TruncNormal, Uniform, exact_pose_error, linear_model, worst_case
from prp3mc.errors import BudgetError
from prp3mc.kinematics.exact import linear_pose_error
from prp3mc.cli import main
from prp3mc.worstcase.crosscheck import optimizer_worst_case

from .conftest import random_poses

PAPER = Budget.from_preset("paper")


def brute_force(geometry, budget, poses, n_zeta=24):
    """Max over every vertex of the input box, each clearance at full size on a contact-angle grid.

    Independent of the 8-corner derivation: enumerates 2^(inputs) vertices and
    a joint grid of contact angles, using only linear_pose_error.
    """
    names, bounds = budget.names, budget.bounds()
    clear = [n for n in names if n.startswith("rho_")]
    plain = [n for n in names if not n.startswith(("rho_", "zeta_"))]
    zgrid = np.zeros((1, 0))                                         # (Z, n_clear)
    if clear:
        axes = np.meshgrid(*[np.linspace(0.0, 360.0, n_zeta + 1)[:-1]] * len(clear), indexing="ij")
        zgrid = np.stack(axes, -1).reshape(-1, len(clear))
    P = np.broadcast_to(poses[:, None, :], (len(poses), len(zgrid), 3))
    best = {q: np.zeros(len(poses)) for q in ("position", "phi")}
    for ends in itertools.product((0, 1), repeat=len(plain)):
        errors = {}
        for name, end in zip(plain, ends):
            family, leg = name.rsplit("_", 1)
            errors.setdefault(family, np.zeros(3))[int(leg) - 1] = bounds[names.index(name)][end]
        if clear:
            errors["rho"] = np.array([bounds[names.index(n)][1] for n in clear])
            errors["zeta"] = zgrid
        e = linear_pose_error(geometry, P, errors)
        best["position"] = np.maximum(best["position"], np.hypot(e[..., 0], e[..., 1]).max(-1))
        best["phi"] = np.maximum(best["phi"], np.abs(e[..., 2]).max(-1))
    return best


def test_equals_brute_force_on_theta_b_budget(geometry, region):
    """With clearances left out, the vertex enumeration is exhaustive and exact."""
    budget = Budget({k: v for k, v in PAPER.inputs.items() if k.startswith(("theta", "b_"))})
    poses = random_poses(region, 6, np.random.default_rng(1))
    wc = worst_case(geometry, budget, poses)
    bf = brute_force(geometry, budget, poses)
    np.testing.assert_allclose(wc.position_mm, bf["position"], rtol=1e-12)
    np.testing.assert_allclose(wc.phi_deg, bf["phi"], rtol=1e-12)


def test_clearance_scan_never_beats_envelope(geometry, region):
    poses = random_poses(region, 3, np.random.default_rng(2))
    budget = Budget({k: v for k, v in PAPER.inputs.items() if not k.startswith("theta")})
    wc = worst_case(geometry, budget, poses)
    bf = brute_force(geometry, budget, poses)
    assert np.all(bf["position"] <= wc.position_mm * (1 + 1e-12))
    assert np.all(bf["position"] >= 0.99 * wc.position_mm)  # a 30-degree scan gets close


def test_random_inputs_never_exceed_envelope(geometry, region, seed):
    rng = np.random.default_rng(seed)
    poses = random_poses(region, 20, rng)
    wc = worst_case(geometry, PAPER, poses)
    X = PAPER.sample(20_000, rng)
    E = linear_model(geometry, PAPER, poses).evaluate(X)             # (20, n, 3)
    tol = 1 + 1e-12
    assert np.all(np.hypot(E[..., 0], E[..., 1]).max(-1) <= wc.position_mm * tol)
    assert np.all(np.abs(E[..., 0]).max(-1) <= wc.x_mm * tol)
    assert np.all(np.abs(E[..., 1]).max(-1) <= wc.y_mm * tol)
    assert np.all(np.rad2deg(np.abs(E[..., 2])).max(-1) <= wc.phi_deg * tol)


@pytest.mark.parametrize("quantity", ["position", "phi", "x", "y"])
def test_maximising_inputs_reproduce_the_maximum(geometry, region, quantity):
    poses = random_poses(region, 10, np.random.default_rng(4))
    wc = worst_case(geometry, PAPER, poses)
    X = wc.inputs_at[quantity]                                       # (10, d)
    for p in range(len(poses)):  # independent path: linear_pose_error, one pose at a time
        errors = {k: v[0] for k, v in PAPER.errors(X[p:p + 1]).items()}
        errors["zeta"] = X[p, [PAPER.names.index(f"zeta_{i}") for i in (1, 2, 3)]]
        e = linear_pose_error(geometry, poses[p], errors)
        value = {"position": np.hypot(e[0], e[1]), "phi": abs(e[2]), "x": abs(e[0]), "y": abs(e[1])}[quantity]
        assert value == pytest.approx(wc.value(quantity)[p], rel=1e-10)
    for q in ("position", "x", "y"):
        np.testing.assert_allclose(wc.contribution[q].sum(-1), wc.value(q), rtol=1e-12)
    X_pos = wc.inputs_at["position"]
    lo, hi = PAPER.bounds().T
    assert np.all((X_pos >= lo - 1e-12) & (X_pos <= hi + 1e-12))


def test_restricted_contact_angle():
    """A clearance whose contact angle is confined gives a pose-dependent interval."""
    from prp3mc import Geometry
    g = Geometry.from_preset("u-shape")
    budget = Budget({"rho_1": Uniform(0.005, 0.016), "zeta_1": Uniform(30.0, 75.0)})
    pose = np.array([10.0, 100.0, 2.0])
    wc = worst_case(g, budget, pose)
    zeta = np.linspace(30.0, 75.0, 4501)
    best = 0.0
    for rho in (0.005, 0.016):
        e = linear_pose_error(g, np.broadcast_to(pose, (len(zeta), 3)), {"rho": np.stack([np.full_like(zeta, rho), 0 * zeta, 0 * zeta], -1),
                                        "zeta": np.stack([zeta, 0 * zeta, 0 * zeta], -1)})
        best = max(best, np.hypot(e[:, 0], e[:, 1]).max())
    assert float(wc.position_mm) == pytest.approx(best, rel=1e-6)
    at = wc.maximizer("position")
    assert 30.0 <= at["zeta_1"] <= 75.0


def test_other_laws_and_k_sigma(geometry):
    budget = PAPER.replace(theta_1=Triangular(-0.02, 0.0, 0.05), b_2=Discrete((0.0, 0.01), (0.5, 0.5)),
                           theta_3=TruncNormal(0.0, 0.03, 1.0))
    wc = worst_case(geometry, budget, [0.0, 130.0, 0.0])
    assert wc.maximizer("position")["theta_1"] in (-0.02, 0.05)
    assert wc.maximizer("position")["b_2"] in (0.0, 0.01)
    normal = PAPER.replace(theta_2=Normal(0.0, 0.01))
    with pytest.raises(BudgetError, match="theta_2.*k_sigma"):
        worst_case(geometry, normal, [0.0, 130.0, 0.0])
    wc3 = worst_case(geometry, normal, [0.0, 130.0, 0.0], k_sigma=3.0)
    same = worst_case(geometry, PAPER.replace(theta_2=Uniform(-0.03, 0.03)), [0.0, 130.0, 0.0])
    assert wc3.k_sigma == 3.0 and float(wc3.position_mm) == pytest.approx(float(same.position_mm), rel=1e-14)


def test_batches_and_chunks_agree(geometry, region):
    grid = region.grid(13)
    whole = worst_case(geometry, PAPER, grid, chunk=10**6)
    chunked = worst_case(geometry, PAPER, grid, chunk=7, workers=2)
    np.testing.assert_allclose(whole.position_mm, chunked.position_mm, rtol=1e-14)
    single = worst_case(geometry, PAPER, grid[3, 5])
    assert float(single.position_mm) == whole.position_mm[3, 5]


def test_exact_model_at_the_maximiser_is_close(geometry, region):
    """The nonlinear chain at the envelope's maximising inputs differs by far less than 1 %."""
    poses = random_poses(region, 5, np.random.default_rng(5))
    wc = worst_case(geometry, PAPER, poses)
    X = wc.inputs_at["position"]
    e = exact_pose_error(geometry, poses, PAPER.errors(X) | {
        "zeta": X[:, [PAPER.names.index(f"zeta_{i}") for i in (1, 2, 3)]]})
    np.testing.assert_allclose(np.hypot(e[:, 0], e[:, 1]), wc.position_mm, rtol=1e-3)


def test_optimizer_does_not_beat_envelope_by_more_than_nonlinearity(geometry):
    pose = [5.0, 100.0, 0.0] if geometry.name == "u-shape" else [5.0, 160.0, 0.0]
    r = optimizer_worst_case(geometry, PAPER, pose, rng=3, maxiter=60)
    env = float(worst_case(geometry, PAPER, pose).position_mm)
    assert r.position_mm <= env * (1 + 1e-3)
    assert r.position_mm >= 0.95 * env
    assert r.seed == 3 and r.n_evaluations > 0


def test_cli_worstcase_json(capsys):
    assert main(["worstcase", "--geometry", "delta-shape", "--budget", "paper", "--pose", "0", "160", "0",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    from prp3mc import Geometry
    wc = worst_case(Geometry.from_preset("delta-shape"), PAPER, [0.0, 160.0, 0.0])
    assert doc["position_mm"] == float(wc.position_mm) and doc["phi_deg"] == float(wc.phi_deg)


@pytest.mark.parametrize("argv, message", [
    (["--budget", "nope"], "unknown budget preset 'nope'"),
    (["--budget", "paper", "--pose", "0", "400", "0"], "stroke"),
])
def test_cli_worstcase_bad_input(capsys, argv, message):
    base = ["worstcase", "--geometry", "u-shape", "--pose", "0", "100", "0"]
    assert main(base + argv) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
