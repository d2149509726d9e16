"""Monte Carlo against closed forms, brute force and its own confidence intervals."""

import json
import warnings

import numpy as np
import pytest

from prp3mc import Budget, Geometry, Uniform, linear_model, monte_carlo
from prp3mc.errors import ParameterError, Prp3mcWarning
from prp3mc.cli import main
from prp3mc.montecarlo.propagation import ci_samples

from .conftest import random_poses

PAPER = Budget.from_preset("paper")
N_SE = 5.0  # |estimate - truth| < 5 standard errors: fails with probability ~6e-7 per comparison


def test_moments_agree_with_closed_forms(geometry, region, seed):
    poses = random_poses(region, 8, np.random.default_rng(seed))
    r = monte_carlo(geometry, PAPER, poses, 200_000, rng=seed)
    mean, cov = linear_model(geometry, PAPER, poses).moments()
    assert np.all(np.abs(r.mean - mean) < N_SE * r.mean_se)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    assert np.all(np.abs(r.std - std) < N_SE * r.std_se)
    assert np.all(np.abs(r.cov - cov) < N_SE * r.cov_se + 1e-18)
    # the encoder errors are one-sided: the mean is not zero
    assert np.all(np.abs(mean[:, :2]).max(axis=-1) > 10 * r.mean_se[:, :2].max(axis=-1))


def test_other_laws_closed_forms(geometry, seed):
    from prp3mc import Disc, Discrete, Triangular, TruncNormal
    budget = PAPER.replace(rho_1=Disc(0.016), theta_2=Triangular(-0.01, 0.03, 0.04),
                           b_3=Discrete((0.0, 0.01, 0.02), (0.6, 0.3, 0.1)), theta_3=TruncNormal(0.0, 0.04, 1.0),
                           zeta_2=Uniform(0.0, 90.0))
    pose = np.array([0.0, 100.0, 1.0]) if geometry.name == "u-shape" else np.array([0.0, 160.0, 1.0])
    r = monte_carlo(geometry, budget, pose, 200_000, rng=seed)
    mean, cov = linear_model(geometry, budget, pose).moments()
    assert np.all(np.abs(r.mean - mean) < N_SE * r.mean_se)
    assert np.all(np.abs(r.std - np.sqrt(np.diag(cov))) < N_SE * r.std_se)


def test_percentiles_equal_brute_force_on_same_samples(geometry, region, seed):
    """Streaming order statistics equal numpy's percentiles of the same samples."""
    poses = region.grid(3)
    r = monte_carlo(geometry, PAPER, poses, 30_001, rng=seed, tolerance_mm=0.08, max_chunk_bytes=1 << 18)
    E = linear_model(geometry, PAPER, poses).evaluate(PAPER.sample(30_001, seed))
    pos = np.hypot(E[..., 0], E[..., 1])
    phi = np.rad2deg(np.abs(E[..., 2]))
    ref = np.moveaxis(np.percentile(pos, r.percentiles, axis=-1), 0, -1)
    np.testing.assert_allclose(r.position_pct, ref, rtol=2e-6)  # float32 evaluation inside
    np.testing.assert_allclose(r.phi_pct, np.moveaxis(np.percentile(phi, r.percentiles, axis=-1), 0, -1), rtol=2e-6)
    np.testing.assert_allclose(r.position_max, pos.max(-1), rtol=2e-6)
    np.testing.assert_allclose(r.position_mean, pos.mean(-1), rtol=1e-6)
    # the kernel evaluates in float32: samples within its rounding of the tolerance may fall either side
    near = np.count_nonzero(np.abs(pos - 0.08) <= 1e-6 * 0.08, axis=-1)
    assert np.all(np.abs(r.exceed_prob * 30_001 - np.count_nonzero(pos > 0.08, axis=-1)) <= near + 1e-9)
    np.testing.assert_allclose(r.mean[..., :2], E[..., :2].mean(-2), rtol=1e-9, atol=1e-15)
    lo, hi = r.position_pct_ci[..., 0], r.position_pct_ci[..., 1]
    assert np.all((lo <= r.position_pct) & (r.position_pct <= hi))


@pytest.mark.slow  # a rate over 300 Monte Carlo runs
def test_confidence_intervals_cover_the_truth(seed):
    """95 % intervals of the mean, of p95 and of an exceedance probability cover in 90-99 % of seeds.

    One encoder error b_1 ~ U[0, 0.025] alone: the position error is
    |J_b col 1| * b_1, so every statistic has a closed form.
    """
    g = Geometry.from_preset("u-shape")
    budget = Budget({"b_1": Uniform(0.0, 0.025)})
    pose = np.array([5.0, 90.0, 0.0])
    gain = np.linalg.norm(linear_model(g, budget, pose).columns[:2, 0])
    true_p95, true_mean, tol = 0.95 * 0.025 * gain, 0.0125 * gain, 0.02 * gain
    reps, hits = 300, np.zeros(3)
    rng = np.random.default_rng(seed)
    for _ in range(reps):
        r = monte_carlo(g, budget, pose, 2000, rng=int(rng.integers(2**32)), tolerance_mm=tol)
        lo, hi = r.position_pct_ci[1]
        hits += [lo <= true_p95 <= hi,
                 abs(r.position_mean - true_mean) <= 1.96 * r.position_mean_se,
                 r.exceed_ci[0] <= 0.2 <= r.exceed_ci[1]]
    coverage = hits / reps
    assert np.all((coverage >= 0.90) & (coverage <= 0.99)), coverage


def test_reproducible_and_recorded(geometry, region):
    poses = region.grid(2)
    a = monte_carlo(geometry, PAPER, poses, 5000, rng=11)
    b = monte_carlo(geometry, PAPER, poses, 5000, rng=11, max_chunk_bytes=1 << 16, workers=1)
    np.testing.assert_array_equal(a.position_pct, b.position_pct)
    np.testing.assert_array_equal(a.mean, b.mean)
    c = monte_carlo(geometry, PAPER, poses, 5000)
    d = monte_carlo(geometry, PAPER, poses, 5000, rng=c.seed)
    np.testing.assert_array_equal(c.position_pct, d.position_pct)
    assert a.metadata()["seed"] == 11 and a.metadata()["n_samples"] == 5000
    assert a.metadata()["prp3mc_version"] == __import__("prp3mc").__version__
    frame = a.to_frame()
    assert {"statistic", "output", "value", "se", "ci_low", "ci_high", "level"} <= set(frame.columns)
    assert not frame["value"].isna().any()


def test_linearization_check(geometry, region):
    r = monte_carlo(geometry, PAPER, region.grid(3), 2000, rng=1, exact_check_poses=3, exact_check_samples=500)
    lin = r.linearization
    assert len(lin) == 3
    assert (lin["position_max_um"] < 1.0).all()        # < 1 µm at the paper's magnitudes
    assert (lin["position_max_um"] > 0.0).all()         # but not identically zero


def test_zero_budget_gives_zero_error(geometry):
    budget = Budget({"theta_1": Uniform(0.0, 0.0)})
    r = monte_carlo(geometry, budget, [0.0, 130.0, 0.0], 2048, rng=1)
    assert float(r.position_max) == 0.0 and np.all(r.std == 0.0)


@pytest.mark.parametrize("kwargs, message", [
    ({"n_samples": 1}, "at least 32 samples"),
    ({"n_samples": 31}, "at least 32 samples"),
    ({"tolerance_mm": -1.0}, "tolerance"),
    ({"percentiles": (50, 101)}, "percentiles"),
])
def test_bad_arguments(kwargs, message):
    args = {"n_samples": 100} | kwargs
    with pytest.raises(ParameterError, match=message):
        monte_carlo(Geometry.from_preset("u-shape"), PAPER, [0.0, 100.0, 0.0], **args)


def test_cli_montecarlo_json(capsys):
    argv = ["montecarlo", "--geometry", "u-shape", "--budget", "paper", "--pose", "10", "100", "0",
            "--samples", "20000", "--seed", "3", "--json"]
    assert main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["mean"]) == {"x_mm", "y_mm", "phi_deg"} and set(doc["std"]) == {"x_mm", "y_mm", "phi_deg"}
    assert {"p50", "p95", "p99", "max"} <= set(doc["position_mm"])
    r = monte_carlo(Geometry.from_preset("u-shape"), PAPER, [10.0, 100.0, 0.0], 20000, rng=3)
    assert doc["position_mm"]["p95"] == float(r.position_pct[1]) and doc["seed"] == 3
    assert main(argv) == 0 and json.loads(capsys.readouterr().out) == doc  # same seed, same numbers


@pytest.mark.parametrize("extra, message", [
    (["--samples", "0"], "positive integer"),
    (["--budget", "missing.toml"], "no such file"),
    (["--tolerance-mm", "nan"], "finite number"),
])
def test_cli_montecarlo_bad_input(capsys, extra, message):
    argv = ["montecarlo", "--geometry", "u-shape", "--budget", "paper", "--pose", "10", "100", "0"] + extra
    code = main(argv)
    err = capsys.readouterr().err
    assert code != 0 and message in err and err.count("\n") == 1


@pytest.mark.parametrize("budget", [PAPER, Budget({"b_1": Uniform(0.0, 0.025), "theta_2": Uniform(0.0, 0.0)})])
def test_streamed_order_statistics_are_exact_in_any_memory(geometry, region, budget, seed):
    """Tiny buffers force the narrowing passes; the order statistics stay those of all samples.

    The second budget has |dphi| = 0 for every sample (a window of one value).
    """
    from prp3mc.montecarlo.propagation import _order_ranks
    poses, n = region.grid(2), 70_000
    small = monte_carlo(geometry, budget, poses, n, rng=seed, max_chunk_bytes=1 << 12, workers=2)
    big = monte_carlo(geometry, budget, poses, n, rng=seed, workers=1)
    for name in ("position_pct", "position_pct_ci", "phi_pct", "phi_pct_ci", "position_max", "mean", "cov"):
        np.testing.assert_array_equal(getattr(small, name), getattr(big, name))
    E = linear_model(geometry, budget, poses).evaluate(budget.sample(n, seed), dtype=np.float32)
    pos = np.sort(np.hypot(E[..., 0], E[..., 1]), axis=-1)
    _, lo, hi, ci = _order_ranks(n, small.percentiles)
    np.testing.assert_allclose(small.position_pct_ci, pos[..., ci], rtol=1e-6)
    assert np.all((pos[..., lo] * (1 - 1e-6) <= small.position_pct) & (small.position_pct <= pos[..., hi] * (1 + 1e-6)))


def test_sample_blocks_equal_the_sample():
    from prp3mc.model.budget import SAMPLE_BLOCK
    n = 2 * SAMPLE_BLOCK + 17
    X = PAPER.sample(n, 5)
    for k in (2, 0, 1):
        np.testing.assert_array_equal(PAPER.sample_block(5, k, n), X[k * SAMPLE_BLOCK:(k + 1) * SAMPLE_BLOCK])
    with pytest.raises(ParameterError, match="outside"):
        PAPER.sample_block(5, 3, n)


@pytest.mark.parametrize("n", [32, 50, 1000])
def test_few_samples_give_finite_standard_errors(n, recwarn):
    """Below 64 x 16 samples the batch-means standard errors use fewer batches of 16 or more: finite, no
    warning (64 batches of 0 or 1 sample gave NaN and a divide warning)."""
    r = monte_carlo(Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0.0, 100.0, 0.0], n, rng=1)
    for name in ("mean_se", "std_se", "cov_se", "position_mean_se"):
        assert np.all(np.isfinite(getattr(r, name))), name
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_an_interval_the_sample_cannot_bound_is_said():
    """p99.73's 95 % interval needs 1419 samples: with fewer its upper end is the sample maximum, and the
    run says so (a warning the JSON outputs record), instead of presenting a bound it is not."""
    assert ci_samples(99.73) == 1419 and ci_samples(50) == 8 and ci_samples(100) is None
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    with pytest.warns(Prp3mcWarning, match=r"p99.73 \(needs 1419\)"):
        monte_carlo(g, b, [0.0, 100.0, 0.0], 1418, rng=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", Prp3mcWarning)
        monte_carlo(g, b, [0.0, 100.0, 0.0], 1419, rng=1)
