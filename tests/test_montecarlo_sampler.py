"""The compiled pieces of the Monte Carlo against numpy: sampling, trigonometry, quantiles, selection."""

import numpy as np
import pytest
from numba import njit
from scipy import special

from prp3mc import (Budget, Disc, Discrete, Geometry, Normal, Triangular, TruncNormal, Uniform, linear_model,
                    monte_carlo)
from prp3mc.montecarlo import _sampler
from prp3mc.montecarlo._kernel import feature_key, padded_features, pose_values
from prp3mc.montecarlo._sampler import LANES, draw_features, pcg_lanes, sampler_tables
from prp3mc.montecarlo._select import count_below, order_statistics
from prp3mc.model.budget import SAMPLE_BLOCK
from prp3mc.model.linear import FEATURE_COS, FEATURE_SIN
from prp3mc.model.effects import SystematicEffect

PAPER = Budget.from_preset("paper")
MIXED = PAPER.replace(rho_1=Disc(0.016), theta_2=Triangular(-0.01, 0.03, 0.04), zeta_2=Uniform(-400.0, 200.0),
                      b_3=Discrete((0.0, 0.01, 0.02), (0.6, 0.3, 0.1)), theta_3=TruncNormal(0.0, 0.04, 1.0),
                      b_1=Normal(0.01, 0.003), zeta_3=Uniform(30.0, 75.0))
# effects: known shifts (an offset, a lead scale: the constant feature), backlash (+-h/2), thermal (T - 20 K)
EFFECTS = PAPER.with_effects({"b_2": SystematicEffect("b_2", 0.004), "scale_2": SystematicEffect("scale_2", 1e-4),
                              "backlash_1": SystematicEffect("backlash_1", 0.02),
                              "thermal": SystematicEffect("thermal", 1.2e-5, temp_range_C=(15.0, 30.0))})
POSE = np.array([0.0, 100.0, 0.0])


class OwnUniform(Uniform):
    """A law the compiled sampler does not know (a subclass), sampled through numpy."""


def compiled_features(budget, model, seed, first, n, tile=4 * LANES * 8):
    """Features (n, F) of samples first to first + n drawn by the compiled sampler, tile by tile."""
    tables = sampler_tables(budget, model.feature_ops())
    D = len(budget.factors)
    lanes, consts = pcg_lanes(seed, first, D)
    U, X = np.empty((D, tile)), np.empty((D, tile))
    F = np.empty((model.feature_ops()[0].shape[0], tile))
    out = []
    for t0 in range(0, n, tile):
        m = min(tile, n - t0)
        draw_features(lanes, consts, *tables, m, U, X, F)
        out.append(F[:, :m].T.copy())
    return np.concatenate(out)


@pytest.mark.parametrize("budget", [PAPER, MIXED, EFFECTS], ids=["paper", "every law", "effects"])
def test_compiled_features_equal_numpy_sampling(budget, seed):
    """Same uniforms as Generator(PCG64(seed)).random, same laws, same features, from any first sample."""
    model = linear_model(Geometry.from_preset("u-shape"), budget, POSE)
    n, first = 3000, 2 * SAMPLE_BLOCK - 1000
    ref = model.features(budget.sample(first + n, seed))[first:]
    got = compiled_features(budget, model, seed, first, n)
    scale = np.abs(ref).max(axis=0)
    err = np.abs(got - ref) / scale
    assert np.all(err <= 2e-15), err.max(axis=0)        # cos, sin and the normal quantile: round-off
    ops, _ = model.feature_ops()
    values = ~np.isin(ops[:, 0], [FEATURE_COS, FEATURE_SIN])   # values, T - 20, the constant 1: no trigonometry
    exact = [k for k, law in enumerate(budget.factor_laws.values()) if not isinstance(law, (Normal, TruncNormal))]
    same = values & np.isin(ops[:, 1], exact)
    np.testing.assert_array_equal(got[:, same], ref[:, same])   # the other laws' values bit for bit


def test_unknown_law_samples_through_numpy(seed):
    assert sampler_tables(PAPER.replace(b_2=OwnUniform(0.0, 0.025)), linear_model(
        Geometry.from_preset("u-shape"), PAPER, POSE).feature_ops()) is None
    g = Geometry.from_preset("u-shape")
    own = PAPER.replace(b_2=OwnUniform(0.0, 0.025))
    n = SAMPLE_BLOCK + 5000
    a = monte_carlo(g, own, [POSE, POSE + [10.0, 0.0, 0.5]], n, rng=seed, tolerance_mm=0.05)
    b = monte_carlo(g, PAPER, [POSE, POSE + [10.0, 0.0, 0.5]], n, rng=seed, tolerance_mm=0.05)
    # the same samples: equal up to the round-off of cos and sin in the features
    np.testing.assert_allclose(a.position_pct, b.position_pct, rtol=1e-6)
    np.testing.assert_allclose(a.position_pct_ci, b.position_pct_ci, rtol=1e-6)
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(a.cov, b.cov, rtol=1e-10, atol=1e-22)
    np.testing.assert_allclose(a.position_mean, b.position_mean, rtol=1e-6)


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_same_numbers_for_any_thread_count(workers):
    """Lanes start where each thread's blocks start: the threads change nothing, to the last bit."""
    g = Geometry.from_preset("u-shape")
    poses, n = [POSE, POSE + [-20.0, 10.0, 1.0]], 3 * SAMPLE_BLOCK + 777
    ref = monte_carlo(g, MIXED, poses, n, rng=8, workers=4, tolerance_mm=0.05)
    got = monte_carlo(g, MIXED, poses, n, rng=8, workers=workers, tolerance_mm=0.05, max_chunk_bytes=1 << 14)
    for name in ("mean", "cov", "mean_se", "cov_se", "position_pct", "position_pct_ci", "phi_pct", "position_max",
                 "position_mean", "position_mean_se", "exceed_prob"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)


@pytest.mark.parametrize("step", [1, 2])
def test_same_numbers_in_any_calls_of_the_kernel(monkeypatch, step):
    """A worker's pass split into compiled calls of ``step`` blocks (between which it sees a stop request)
    draws the samples of one call: the same numbers to the last bit."""
    from prp3mc.montecarlo import _stream
    g = Geometry.from_preset("u-shape")
    poses, n = [POSE, POSE + [-20.0, 10.0, 1.0]], 5 * SAMPLE_BLOCK + 333
    monkeypatch.setattr(_stream, "STOP_BLOCKS", 1 << 30)
    ref = monte_carlo(g, MIXED, poses, n, rng=3, workers=1, tolerance_mm=0.05)
    monkeypatch.setattr(_stream, "STOP_BLOCKS", step)
    got = monte_carlo(g, MIXED, poses, n, rng=3, workers=1, tolerance_mm=0.05)
    for name in ("mean", "cov", "position_pct", "position_pct_ci", "phi_pct", "position_max", "position_mean",
                 "position_mean_se", "exceed_prob"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)


@njit
def _sincos_rows(t):
    s, c = np.empty_like(t), np.empty_like(t)
    for i in range(t.size):
        s[i], c[i] = _sampler._sincos_deg(t[i])
    return s, c


@njit
def _ndtri_rows(u):
    out = np.empty_like(u)
    for i in range(u.size):
        out[i] = _sampler._ndtri(u[i])
    return out


def test_sine_and_cosine_of_degrees(seed):
    rng = np.random.default_rng(seed)
    t = np.concatenate([rng.uniform(-720.0, 720.0, 100_000), np.arange(-720.0, 721.0, 45.0),
                        np.arange(-720.0, 721.0, 90.0) + 1e-12])
    s, c = _sincos_rows(t)
    r = np.deg2rad(t - 360.0 * np.round(t / 360.0))  # whole turns off exactly first: numpy's own error stays small
    assert np.max(np.abs(s - np.sin(r))) < 5e-16
    assert np.max(np.abs(c - np.cos(r))) < 5e-16
    q = np.arange(-8, 9) * 90.0  # exact at multiples of 90 degrees
    s, c = _sincos_rows(q)
    np.testing.assert_array_equal(s, np.rint(np.sin(np.deg2rad(q))))
    np.testing.assert_array_equal(c, np.rint(np.cos(np.deg2rad(q))))


def test_normal_quantile_equals_scipy(seed):
    rng = np.random.default_rng(seed)
    u = np.concatenate([rng.random(100_000), 10.0 ** -rng.uniform(1.0, 300.0, 10_000),
                        1.0 - 10.0 ** -rng.uniform(1.0, 15.0, 10_000)])
    ref = special.ndtri(u)
    np.testing.assert_allclose(_ndtri_rows(u), ref, rtol=2e-15, atol=1e-300)
    assert _ndtri_rows(np.array([0.0]))[0] == -np.inf and _ndtri_rows(np.array([0.5]))[0] == 0.0


@pytest.mark.parametrize("kind", ["uniform", "ties", "constant", "narrow"])
def test_radix_selection_equals_sorting(kind, seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20_000))
    x = {"uniform": rng.random(n), "ties": rng.integers(0, 7, n) * 0.25, "constant": np.full(n, 0.125),
         "narrow": 1.0 + 1e-6 * rng.random(n)}[kind].astype(np.float32)
    ranks = np.unique(rng.integers(0, n, 9))
    before = x.copy()
    np.testing.assert_array_equal(order_statistics(x, ranks), np.sort(x)[ranks])
    np.testing.assert_array_equal(x, before)
    bounds = np.float32([0.0, 0.3, 1.0, np.inf])
    np.testing.assert_array_equal(count_below(x, bounds), [(x < b).sum() for b in bounds])


@pytest.mark.parametrize("n_features", [1, 3, 10, 13])
def test_padded_features_change_no_value(n_features, seed):
    """The kernels read feature counts rounded up to FEATURE_GROUP (zero features, zero coefficients):
    the norm and |dphi| are those of the unpadded features, to the last bit."""
    rng = np.random.default_rng(seed)
    FT, c = rng.normal(size=(n_features, 3000)).astype(np.float32), rng.normal(size=(3, n_features)).astype(np.float32)
    n_pad = padded_features(n_features)
    assert n_pad % 4 == 0 and n_features <= n_pad < n_features + 4 and len(feature_key(n_features)) == n_pad
    FTp, cp = np.zeros((n_pad, 3000), np.float32), np.zeros((3, n_pad), np.float32)
    FTp[:n_features], cp[:, :n_features] = FT, c
    out = [np.empty(3000, np.float32) for _ in range(4)]
    pose_values(FT, c, out[0], out[1], (0,) * n_features)
    pose_values(FTp, cp, out[2], out[3], feature_key(n_features))
    np.testing.assert_array_equal(out[0], out[2])
    np.testing.assert_array_equal(out[1], out[3])
