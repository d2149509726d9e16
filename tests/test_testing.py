"""prp3mc.testing.assert_summary_close: tolerances from standard errors, exact quantities tight."""

import json

import pytest

from prp3mc.testing import assert_summary_close, load_summary


def summary(**changes):
    doc = {"configurations": {"u-shape": {
        "worst_case_position_um": {"min": 116.87485631895652, "max": 194.63706375672172, "mean": 148.5},
        "montecarlo": {"position_um": {"p99.73": {"max": {"value": 132.0, "se": 0.4}}}},
        "sobol": {"position": {"theta_1": {"kind": "input", "ST": {"value": 0.42, "se": 0.01},
                                           "worst_case_share": None}}}}},
        "metadata": {"seed": 1, "wall_time_s": 3.2}}
    u = doc["configurations"]["u-shape"]
    for path, value in changes.items():
        *keys, last = path.split("__")
        node = u
        for k in keys:
            node = node[k]
        node[last] = value
    return doc


def test_identical_and_metadata_ignored():
    a = summary()
    a["metadata"] = {"seed": 99, "wall_time_s": 1.0, "new": True}
    assert_summary_close(a, summary())


@pytest.mark.parametrize("value, ok", [(132.0 + 2.8, True), (132.0 - 2.8, True), (132.0 + 2.9, False)])
def test_statistic_tolerance_is_n_se_combined(value, ok):
    # tolerance 5 * hypot(0.4, 0.4) = 2.83
    a = summary()
    a["configurations"]["u-shape"]["montecarlo"]["position_um"]["p99.73"]["max"]["value"] = value
    if ok:
        assert_summary_close(a, summary())
    else:
        with pytest.raises(AssertionError, match=r"p99\.73\.max: actual 134\.9 vs golden 132.*> 2\.828"):
            assert_summary_close(a, summary())


def test_n_se_keyword():
    a = summary()
    a["configurations"]["u-shape"]["montecarlo"]["position_um"]["p99.73"]["max"]["value"] = 134.0
    assert_summary_close(a, summary())
    with pytest.raises(AssertionError):
        assert_summary_close(a, summary(), n_se=3.0)


def test_exact_quantities_compared_tightly():
    g = summary()
    assert_summary_close(summary(worst_case_position_um__max=194.63706375672172 * (1 + 1e-11)), g)
    with pytest.raises(AssertionError, match=r"worst_case_position_um\.max: actual .* \(exact, rtol 1e-09\)"):
        assert_summary_close(summary(worst_case_position_um__max=194.63706375672172 * (1 + 1e-7)), g)


def test_every_failure_listed_and_structure_checked():
    a = summary(worst_case_position_um__min=100.0, worst_case_position_um__extra=1.0)
    del a["configurations"]["u-shape"]["worst_case_position_um"]["mean"]
    a["configurations"]["u-shape"]["sobol"]["position"]["theta_1"]["kind"] = "group"
    a["configurations"]["u-shape"]["sobol"]["position"]["theta_1"]["ST"]["value"] = 0.6
    with pytest.raises(AssertionError) as err:
        assert_summary_close(a, summary())
    lines = str(err.value).splitlines()
    assert lines[0] == "5 of 7 summary statistics differ:"
    text = "\n".join(lines)
    for fragment in ("worst_case_position_um.min: actual 100", "worst_case_position_um.mean: missing from actual",
                     "worst_case_position_um.extra: not in golden", "theta_1.kind: actual 'group' != golden 'input'",
                     "theta_1.ST: actual 0.6 vs golden 0.42"):
        assert fragment in text


def test_paths_and_folders(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "summary.json").write_text(json.dumps(summary()))
    (tmp_path / "golden.json").write_text(json.dumps(summary()))
    assert load_summary(tmp_path / "run") == summary()
    assert_summary_close(tmp_path / "run", str(tmp_path / "golden.json"))


def yield_entry(**changes):
    """A study's ``yield`` entry (layout of prp3mc.study.spec.yield_summary), with changes by path."""
    doc = {"spec": {"position_um": 100.0, "phi_arcsec": None, "source": "[spec]"}, "grid": [5, 5],
           "exceed_position_ppm": {"min": 0.0025, "max": 52652.48933525979, "mean": 12116.184873600108},
           "exceed_position_pct": {"min": 2.5e-7, "max": 5.265248933525979, "mean": 1.2116184873600104},
           "exceed_phi_ppm": None, "exceed_phi_pct": None,
           "exceed_any_ppm": {"min": 0.0025, "max": 52652.48933525979, "mean": 12116.184873600108},
           "ppk_min": {"position": 0.5398872164350641, "phi": None, "any": 0.5398872164350641},
           "error_bound_ppm": 0.0008376, "error_bounds_ppm": {"position": 0.0008376, "phi": None, "any": 0.0008376},
           "quantiles_position_um": {"p99.73": {"min": 82.47091962988556, "max": 132.1317441846429, "mean": 102.2}},
           "quantile_error_bounds_position_um": {"p99.73": 2.05e-06},
           "quantiles_phi_arcsec": {"p99.73": {"min": 115.53561495975242, "max": 116.3415, "mean": 115.9}},
           "quantile_error_bounds_phi_arcsec": {"p99.73": 3.0e-05},
           "region": {"max_exceed_position_ppm": 52652.48933525979, "mean_exceed_position_ppm": 12116.184873600107,
                      "area_fraction_above_1ppm": 1.0, "argmax_pose": [40.0, 60.0, 0.0]}}
    for path, value in changes.items():
        *keys, last = path.split("__")
        node = doc
        for k in keys:
            node = node[k]
        node[last] = value
    return {"configurations": {"u-shape": {"yield": doc}}}


@pytest.mark.parametrize("path, value, ok", [
    # an exceedance of 0.0025 ppm, both bounds 0.0008376 ppm: within 0.0016752 of each other
    ("exceed_position_ppm__min", 0.0025 + 0.0016, True),
    ("exceed_position_ppm__min", 0.0025 + 0.0017, False),
    ("exceed_position_pct__min", 2.5e-7 + 1.6e-7, True),
    ("exceed_position_pct__min", 2.5e-7 + 1.7e-7, False),
    ("region__max_exceed_position_ppm", 52652.48933525979 + 0.0016, True),
    ("region__max_exceed_position_ppm", 52652.48933525979 + 0.01, False),
    ("quantiles_position_um__p99.73__max", 132.1317441846429 + 4.0e-6, True),
    ("quantiles_position_um__p99.73__max", 132.1317441846429 + 4.5e-6, False),
    ("region__area_fraction_above_1ppm", 0.96, False),
    ("quantiles_phi_arcsec__p99.73__min", 115.53561495975242 + 5.9e-5, True),
    ("quantiles_phi_arcsec__p99.73__min", 115.53561495975242 + 6.2e-5, False),
])
def test_yield_figures_within_both_error_bounds(path, value, ok):
    a = yield_entry(**{path: value})
    if ok:
        assert_summary_close(a, yield_entry())
    else:
        with pytest.raises(AssertionError, match=path.replace("__", r"\.").split(r"\.")[-1]):
            assert_summary_close(a, yield_entry())


def test_yield_ppk_follows_its_exceedance():
    # P = 52652 ppm moved by 0.0016 ppm: Ppk moves by about 0.0016e-6 / (3 phi(Phi^-1(1 - P))) ~ 4.7e-9
    from statistics import NormalDist
    p = 52652.48933525979 + 0.0016
    moved = NormalDist().inv_cdf(1 - p * 1e-6) / 3
    assert abs(moved - 0.5398872164350641) > 1e-9 * 0.54           # beyond the plain rtol
    assert_summary_close(yield_entry(exceed_position_ppm__max=p, exceed_any_ppm__max=p, ppk_min__position=moved,
                                     ppk_min__any=moved), yield_entry())
    with pytest.raises(AssertionError, match=r"ppk_min\.position"):
        assert_summary_close(yield_entry(ppk_min__position=0.5398872164350641 + 1e-7), yield_entry())


@pytest.mark.parametrize("path, value, ok", [
    ("error_bounds_ppm__position", 0.0002, True),          # a computation's guarantee, not the model's figure
    ("error_bound_ppm", 0.0031, True),
    ("error_bounds_ppm__position", float("inf"), False),
    ("error_bounds_ppm__position", -1e-9, False),
    ("error_bounds_ppm__phi", 0.001, False),               # a bound where the golden has no spec
    ("quantile_error_bounds_position_um__p99.73", float("nan"), False),
])
def test_yield_bounds_must_be_finite_not_equal(path, value, ok):
    a = yield_entry(**{path: value})
    if path == "error_bounds_ppm__position" and ok:
        a["configurations"]["u-shape"]["yield"]["exceed_position_ppm"]["min"] += 0.0009     # within 0.0002 + 0.0008376
    if ok:
        assert_summary_close(a, yield_entry())
    else:
        with pytest.raises(AssertionError, match="an error bound must be finite and non-negative"):
            assert_summary_close(a, yield_entry())


def test_a_bound_one_version_does_not_report_is_not_a_difference():
    # a golden pinned before the summary carried the phi quantiles' bounds: those compare to rtol_exact
    golden = yield_entry()
    del golden["configurations"]["u-shape"]["yield"]["quantile_error_bounds_phi_arcsec"]
    assert_summary_close(yield_entry(), golden)
    with pytest.raises(AssertionError, match=r"quantiles_phi_arcsec\.p99\.73\.min"):
        assert_summary_close(yield_entry(**{"quantiles_phi_arcsec__p99.73__min": 115.5357}), golden)
