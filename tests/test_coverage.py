"""Coverage of the Sobol and Shapley intervals over 50 seeds (the fast version of benchmarks/coverage_sobol.py)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from prp3mc import Geometry

_spec = importlib.util.spec_from_file_location(
    "coverage_sobol", Path(__file__).resolve().parents[1] / "benchmarks" / "coverage_sobol.py")
coverage = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(coverage)

SEEDS = 50


@pytest.mark.slow
@pytest.mark.parametrize("case", coverage.CASES, ids=[c[0] for c in coverage.CASES])
def test_intervals_cover_at_their_nominal_rate(case):
    """Pooled over outputs and names, 95 % intervals cover between the binomial 0.1 % quantile of 50
    seeds (0.84: as if the names were one) and 0.995: the bootstrap they replace covered 99.5-100 %."""
    _, preset, pose, budget = case
    geometry = Geometry.from_preset(preset)
    ref = coverage.references(geometry, budget, pose, 1024, 512)
    est = coverage.run_seeds(geometry, budget, pose, range(1000, 1000 + SEEDS), 1024, 512)
    low = stats.binom.ppf(1e-3, SEEDS, 0.95) / SEEDS
    for stat, (value, conf) in est.items():
        sd = value.std(axis=0, ddof=1)
        varies = np.isfinite(sd) & (sd > 1e-12)
        covered = (np.abs(value - ref[stat]) <= conf)[:, varies]
        rate = covered.mean()
        assert low <= rate <= 0.995, (stat, rate)
        ratio = np.median(np.median(conf[:, varies], axis=0) / (1.96 * sd[varies]))
        assert 0.8 <= ratio <= 1.4, (stat, ratio)                      # about 1.07 for a t interval, R = 16
