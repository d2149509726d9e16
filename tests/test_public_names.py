"""The everyday API's names: one result protocol, and the names that left it still served for one release."""

import warnings

import pytest

import prp3mc
from prp3mc.worstcase import envelope


def test_results_are_named_so_and_the_compiled_maxima_left_the_everyday_api():
    """The classes the entries return end in ``Result`` (the worst case's too); the compiled maxima
    live in their package only."""
    assert {"WorstCaseResult", "MonteCarloResult", "SobolResult", "AllocationResult", "StudyResult"} <= set(
        prp3mc.__all__)
    assert not {"WorstCase", "worst_case_maxima", "WorstCaseMaxima"} & set(prp3mc.__all__)
    assert prp3mc.worst_case(prp3mc.Geometry.from_preset("u-shape"), prp3mc.Budget.from_preset("paper"),
                             prp3mc.Region.from_preset("u-shape").grid(1)).__class__.__name__ == "WorstCaseResult"


@pytest.mark.parametrize("owner, name, now", [
    (prp3mc, "WorstCase", envelope.WorstCaseResult),
    (prp3mc, "worst_case_maxima", envelope.worst_case_maxima),
    (prp3mc, "WorstCaseMaxima", envelope.WorstCaseMaxima),
    (envelope, "WorstCase", envelope.WorstCaseResult),
])
def test_former_names_warn_and_still_work(owner, name, now):
    with pytest.warns(DeprecationWarning, match="next release"):
        assert getattr(owner, name) is now


def test_current_names_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert prp3mc.WorstCaseResult is envelope.WorstCaseResult
        from prp3mc.worstcase.envelope import worst_case_maxima  # noqa: F401
    with pytest.raises(AttributeError):
        envelope.NoSuchName


def test_the_analyses_take_preset_names_as_exact_yield_and_allocate_do():
    """monte_carlo, worst_case and sobol_indices('u-shape', 'paper', ...) raised AttributeError ('str' object has
    no attribute 'check_geometry' / 'bounds' / 'groups'); exact_yield and allocate take names. Same numbers."""
    import numpy as np
    from prp3mc import Budget, Geometry, monte_carlo, sobol_indices, worst_case
    g, b, pose = Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0.0, 100.0, 0.0]
    assert worst_case("u-shape", "paper", pose).position_mm == worst_case(g, b, pose).position_mm
    by_name, by_object = (monte_carlo(*gb, pose, 2048, rng=3, percentiles=(50.0,)) for gb in (("u-shape", "paper"),
                                                                                              (g, b)))
    assert np.array_equal(by_name.position_pct, by_object.position_pct)
    by_name, by_object = (sobol_indices(*gb, pose, 256, rng=3, replicates=2) for gb in (("u-shape", "paper"), (g, b)))
    assert np.array_equal(by_name.ST, by_object.ST, equal_nan=True)
