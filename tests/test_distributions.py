"""prp3mc._distributions gives what scipy.stats gives, bit for bit, without importing it."""

import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from prp3mc import _distributions as D

RNG = np.random.default_rng(0)
#: Points on and off the support, its ends, tiny and huge values, and many ordinary ones.
X = np.concatenate([[0.0, -0.0, -1.0, np.inf, -np.inf, np.nan, 5e-324, 1e-300, 1e-8, 1.0, 3.0, 700.0, 1e300],
                    RNG.exponential(3.0, 500), RNG.exponential(300.0, 200), 10 ** RNG.uniform(-12, 5, 300)])
Q = np.concatenate([[0.0, 1.0, -0.1, 1.1, np.nan, 1e-300, 1 - 1e-16, 0.5], RNG.uniform(0, 1, 500),
                    10 ** RNG.uniform(-15, 0, 300)])
DF = [0.5, 1, 2, 3, 3.7, 6, 24, 147.0, 1e3]


def same(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True) and np.shape(a) == np.shape(b)


@pytest.mark.parametrize("df", DF)
def test_chi2_tails_are_scipy_stats(df):
    assert same(D.chi2_sf(X, df), stats.chi2.sf(X, df))
    assert same(D.chi2_logsf(X, df), stats.chi2.logsf(X, df))
    assert same(D.chi2_logcdf(X, df), stats.chi2.logcdf(X, df))
    assert same(D.chi2_isf(Q, df), stats.chi2.isf(Q, df))
    assert same(D.chi2_ppf(Q, df), stats.chi2.ppf(Q, df))


def test_broadcast_degrees_of_freedom_and_scalars():
    df = RNG.uniform(0.5, 200.0, X.size)
    assert same(D.chi2_logsf(X, df), stats.chi2.logsf(X, df))
    assert same(D.chi2_logcdf(X, df), stats.chi2.logcdf(X, df))
    assert same(D.chi2_sf(X, np.where(df > 100, -1.0, df)), stats.chi2.sf(X, np.where(df > 100, -1.0, df)))
    for x in (0.0, 0.3, 5.0, np.inf):
        assert type(D.chi2_sf(x, 3)) is type(stats.chi2.sf(x, 3)) and same(D.chi2_sf(x, 3), stats.chi2.sf(x, 3))
    assert same(D.chi2_isf(0.01 / 37, 1), stats.chi2.isf(0.01 / 37, 1))


def test_normal_log_tail_is_scipy_stats():
    z = np.concatenate([[0.0, -0.0, np.inf, -np.inf, np.nan, 40.0, -40.0, 1e300, -1e300], RNG.normal(0, 5, 1000)])
    assert same(D.norm_logsf(z), stats.norm.logsf(z))
    assert same(D.norm_logsf(2.5), stats.norm.logsf(2.5))


@pytest.mark.parametrize("m", [1, 2, 3, 10, 49, 200])
def test_benjamini_hochberg_is_scipy_stats(m):
    for trial in range(60):
        p = RNG.uniform(0, 1, m) ** RNG.uniform(0.2, 8)
        if trial % 3 == 0:
            p[RNG.integers(0, m, m // 2)] = p[0]          # ties
        if trial % 5 == 0:
            p[:2] = [0.0, 1.0][:m]
        assert same(D.bh_adjusted(p), stats.false_discovery_control(p, method="bh"))
    with pytest.raises(ValueError, match="between 0 and 1"):
        D.bh_adjusted([0.5, 1.5])


def test_discrepancy_command_does_without_scipy_stats_and_salib():
    """What the command line imports for prp3mc discrepancy (SALib and scipy.stats cost a second together)."""
    code = ("import sys; from prp3mc.cli import build_parser; build_parser('discrepancy'); "
            "print(sorted(m for m in ('scipy.stats', 'SALib') if m in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "[]\n"
