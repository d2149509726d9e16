"""A Monte Carlo map that varies no more than its noise is called constant at the stated rate, and says so."""

import numpy as np
import pytest

from prp3mc.reports.plots import noise_range, region_map, within_noise
from prp3mc.units import Z95


def test_noise_range_is_the_range_quantile():
    """Two estimates: 1.96·√2 (the two-sided test of a difference); many: the sampled range's 95 % quantile."""
    assert noise_range(2) == pytest.approx(Z95 * np.sqrt(2), abs=1e-4)
    rng = np.random.default_rng(0)
    ranges = np.ptp(rng.standard_normal((200_000, 49)), axis=1)
    q = np.quantile(ranges, 0.95)
    se = np.sqrt(0.95 * 0.05 / 200_000) / 0.1     # quantile se ~ sqrt(p(1-p)/n) / density (density near 0.1)
    assert noise_range(49) == pytest.approx(q, abs=4 * se)


def test_a_constant_field_is_called_constant_at_the_nominal_rate():
    """Over 4000 noisy constant fields (any seed): the rate is 95 % within 4 binomial standard errors."""
    rng = np.random.default_rng()
    n, trials = 49, 4000
    se = rng.uniform(0.1, 0.3)
    hits = sum(within_noise(116 + se * rng.standard_normal(n), np.full(n, se)) for _ in range(trials))
    assert abs(hits / trials - 0.95) <= 4 * np.sqrt(0.95 * 0.05 / trials)


def test_a_trend_of_ten_standard_errors_is_not_noise():
    rng = np.random.default_rng()
    n = 49
    field = np.linspace(0, 10, n) + rng.standard_normal(n)
    assert not within_noise(field, np.ones(n))
    assert not within_noise(np.zeros(n), np.zeros(n))              # no noise: nothing is within it


def test_map_label_says_constant_within_noise():
    import matplotlib
    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    x, y = np.meshgrid(np.linspace(-40, 40, 5), np.linspace(60, 140, 5))
    poses = np.stack([x, y, np.zeros_like(x)], axis=-1)
    values = 115.9 + 0.05 * np.random.default_rng(1).standard_normal(x.shape)
    ax = Figure().subplots()
    region_map(poses, values, ax=ax, unit="arcsec", se=np.full(x.shape, 0.2))
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["constant within Monte Carlo noise:\n115.9 ± 0.2 arcsec"]
    ax = Figure().subplots()
    region_map(poses, values, ax=ax, unit="arcsec")                    # no standard errors: a varying map
    assert not any("constant" in t.get_text() for t in ax.texts)
