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
