"""A study's [allocation] table: its errors, its run against direct allocate calls, its summary and report."""

import dataclasses
import json
import re

import pytest

from prp3mc import allocate
from prp3mc._rng import child_seed
from prp3mc.cli import main
from prp3mc.errors import StudyError
from prp3mc.reports.study_report import _tables, render_report, write_study
from prp3mc.study.allocation import ALLOCATION_STREAM, allocation_summary
from prp3mc.study.reader import Study
from prp3mc.study.runner import run_study
from prp3mc.study.summary import build_summary
from prp3mc.testing import assert_summary_close, load_summary
from prp3mc.allocation.optimum import allocation_front, front_records

from .test_study import GOLDEN, regenerate

STUDY = """\
name = "alloc"
seed = 5
budget = "paper"
outputs = []

[worstcase]
grid = 5

[allocation]
classes = "example"
spec_position_um = 80.0
spec_phi_arcsec = 120.0
front = true

[[configuration]]
geometry = "u-shape"

[[configuration]]
name = "delta"
geometry = "delta-shape"
region = { x_mm = [-20, 20], y_mm = [140, 180] }
"""

WITHOUT = STUDY.split("[allocation]")[0] + "[[configuration]]" + STUDY.split("[[configuration]]", 1)[1]
NORMAL_CLASSES = """\
[b]
classes = [{ name = "gauss", law = "normal", mu = 0.0, sd = 0.001, cost = 1.0 }]
"""


def study_file(tmp_path, text=STUDY):
    path = tmp_path / "alloc.toml"
    path.write_text(text)
    (tmp_path / "normal.toml").write_text(NORMAL_CLASSES)
    (tmp_path / "bad.toml").write_text(NORMAL_CLASSES.replace("mu =", "mean ="))
    return path


def _edit(old, new):
    assert old in STUDY
    return STUDY.replace(old, new, 1)


# (study text, text of the line the error must name, reason)
BAD = [
    (_edit("front = true", "front = true\nspec_pos_um = 3"), "spec_pos_um",
     "unknown key 'spec_pos_um' in [allocation]"),
    (_edit("spec_position_um = 80.0", 'spec_position_um = "80"'), "spec_position_um",
     "allocation.spec_position_um must be a finite number"),
    (_edit("spec_phi_arcsec = 120.0", "spec_phi_arcsec = -1.0"), "spec_phi_arcsec", "must be > 0"),
    (_edit("spec_position_um = 80.0\nspec_phi_arcsec = 120.0\n", ""), "[allocation]", "needs spec_position_um"),
    (_edit("front = true", "front = true\nspec_percentile = 100"), "spec_percentile", "must lie in (0, 100)"),
    (_edit("spec_position_um = 80.0", "spec_percentile = 99.73"), "spec_percentile", "give spec_position_um too"),
    (_edit("front = true", "front = true\nsamples = 5000"), "samples", "give spec_percentile too"),
    (_edit("front = true", "front = true\nspec_percentile = 99\nsamples = 1"), "samples", "at least 2"),
    (_edit("front = true", "front = true\nspec_percentile = 99\nsamples = 2.5"), "samples", "must be an integer"),
    (_edit('classes = "example"', 'classes = "missing.toml"'), "classes", "classes 'missing.toml'"),
    (_edit('classes = "example"', 'classes = "premium"'), "classes", "unknown classes preset 'premium'"),
    (_edit('classes = "example"', "classes = 3"), "classes", "allocation.classes must be a string"),
    (_edit('classes = "example"\n', ""), "[allocation]", "needs classes"),
    (_edit('classes = "example"', 'classes = "normal.toml"'), "classes", "set [worstcase] k_sigma"),
    (_edit('classes = "example"', 'classes = "bad.toml"'), "classes", "bad.toml: [b] class 1 ('gauss'): normal law"),
    (_edit("front = true", 'front = "yes"'), "front", "allocation.front must be true or false"),
    (_edit("front = true", "front = true\ngrid = 1"), "grid", "allocation.grid must be an integer n >= 2"),
    (_edit("front = true", 'front = true\nconfigurations = ["u-shape", "nope"]'), "configurations",
     "no configuration named 'nope'"),
    (_edit("front = true", "front = true\nconfigurations = []"), "configurations", "distinct configuration names"),
    (_edit("front = true", 'front = true\nconfigurations = ["delta", "delta"]'), "configurations",
     "distinct configuration names"),
    (WITHOUT.replace("outputs = []", "outputs = []\nallocation = 3"), "allocation = 3", "allocation must be a table"),
]


def _line_of(text, marker):
    """Line (1-based) of the first line starting with ``marker``, from the [allocation] header on."""
    lines = text.splitlines()
    start = lines.index("[allocation]") if "[allocation]" in lines else 0
    return next(k for k, row in enumerate(lines[start:], start + 1) if row.startswith(marker))


@pytest.mark.parametrize("text, marker, reason", BAD)
def test_allocation_mistakes_name_line_and_reason(tmp_path, text, marker, reason):
    path = study_file(tmp_path, text)
    with pytest.raises(StudyError) as err:
        Study.load(path)
    message = str(err.value)
    assert message.startswith(f"{path}:{_line_of(text, marker)}: "), message
    assert reason in message and "\n" not in message, message


def test_allocation_parsed_with_defaults(tmp_path):
    s = Study.load(study_file(tmp_path))
    a = s.allocation
    assert a.classes.name == "example" and a.classes_source == "example"
    assert (a.spec_position_um, a.spec_phi_arcsec, a.spec_percentile) == (80.0, 120.0, None)
    assert a.grid is None and a.front and a.configurations is None and a.front_output == "position"
    assert a.applies_to("u-shape") and a.applies_to("delta")
    assert Study.load(study_file(tmp_path, WITHOUT)).allocation is None
    big = dataclasses.replace(a, grid=(41, 31), samples=100_000)
    assert big.reduced().grid == (21, 21) and big.reduced().samples == 1 << 14
    assert dataclasses.replace(s, allocation=big).reduced().allocation.grid == (21, 21)


# ----------------------------------------------------------------- running: the same as a direct call
def _direct(config, study, seed):
    """allocate and allocation_front called directly on the configuration's region grid."""
    a = study.allocation
    poses = config.region.grid(a.grid or study.worstcase_grid)
    kw = dict(spec_position_um=a.spec_position_um, spec_phi_arcsec=a.spec_phi_arcsec, k_sigma=study.k_sigma)
    direct = allocate(config.geometry, a.classes_source, poses, spec_percentile=a.spec_percentile,
                      n_samples=a.samples, rng=child_seed(seed, ALLOCATION_STREAM), **kw)
    side = {"spec_phi_arcsec": a.spec_phi_arcsec} if a.spec_position_um is not None else {}
    output = "position" if a.spec_position_um is not None else "phi"
    front = allocation_front(config.geometry, a.classes_source, poses, output=output, k_sigma=study.k_sigma,
                             **side) if a.front else None
    return direct, front


def _check_against_direct(result):
    summary = build_summary(result)
    for c in result.configurations:
        entry = summary["configurations"][c.name].get("allocation")
        if not result.study.allocation.applies_to(c.name):
            assert entry is None and c.allocation is None
            continue
        direct, front = _direct(c.configuration, result.study, result.seed)
        expected = allocation_summary(direct, front)
        assert_summary_close({"a": entry}, {"a": expected}, n_se=0.0, rtol_exact=1e-9)
        assert entry["choice"] == dict(direct.choice) and entry["cost"] == direct.cost
        assert entry["worst_case_position_um"] == 1e3 * direct.worst_case_position_mm
        assert entry["binding_poses"] == direct.to_dict()["binding_poses"]
        if front is not None:
            assert entry["front"] == front_records(front) and len(entry["front"]) >= 1
        json.dumps(entry, allow_nan=False)
    return summary


def test_study_allocation_equals_direct_allocate(tmp_path):
    result = run_study(study_file(tmp_path), progress=False)
    summary = _check_against_direct(result)
    u = summary["configurations"]["u-shape"]["allocation"]
    assert u["feasible"] and u["worst_case_position_um"] <= 80.0 and u["worst_case_phi_arcsec"] <= 120.0
    assert u["binding"] in ("position", "phi") and u["binding_poses"]
    costs = [p["cost"] for p in u["front"]]
    assert costs == sorted(costs) and u["cost"] in costs             # the choice lies on the front
    assert summary["metadata"]["allocation_seed"] == child_seed(5, ALLOCATION_STREAM)
    assert summary["metadata"]["allocation_grid"] == [5, 5]
    c = result["u-shape"]
    assert c.analyses == ("worstcase", "allocation") and "allocation" in result.timings_s
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.allocation = None
    with pytest.raises(TypeError):
        c.allocation.choice["rho_1"] = "C2"
    assert not c.allocation.position_mm.flags.writeable


def test_study_allocation_percentile_spec_some_configurations(tmp_path):
    text = _edit("spec_phi_arcsec = 120.0\nfront = true",
                 'spec_percentile = 99.73\nsamples = 2000\ngrid = [5, 4]\nfront = false\nconfigurations = ["delta"]')
    result = run_study(study_file(tmp_path, text), progress=False)
    summary = _check_against_direct(result)
    d = summary["configurations"]["delta"]["allocation"]
    assert "allocation" not in summary["configurations"]["u-shape"] and "front" not in d
    st = d["statistical"]
    assert st["n_samples"] == 2000 and st["percentile"] == 99.73 and st["percentile_um"]["se"] > 0
    assert st["percentile_um"]["value"] <= st["ci95_high_um"]["value"]
    assert st["confirmed"] and d["feasible"]        # decided exactly; Monte Carlo does not refute it
    assert result["delta"].allocation.poses.shape == (20, 3)
    assert summary["metadata"]["allocation_samples"] == 2000


def test_bundled_allocation_example_runs(tmp_path):
    study = Study.load("allocation_example")
    assert study.allocation is not None and study.allocation.classes.name == "example"
    assert [c.name for c in study.configurations] == ["u-shape", "delta-shape"]
    small = dataclasses.replace(study, worstcase_grid=(6, 6),      # the fronts are checked above
                                allocation=dataclasses.replace(study.allocation, front=False))
    result = run_study(small, progress=False)
    summary = _check_against_direct(result)
    assert all(c["allocation"]["feasible"] for c in summary["configurations"].values())


def test_golden_allocation_example_any_seed():
    """The bundled example's allocations and fronts are exact: the same for any seed, pinned to rtol 1e-9."""
    golden = load_summary(GOLDEN / "allocation_example.json")
    assert golden["metadata"]["seed"] == regenerate.GOLDEN_SEED
    assert {"cost", "choice", "front", "binding_poses"} <= set(golden["configurations"]["u-shape"]["allocation"])
    assert_summary_close(regenerate.golden_summary("allocation_example", seed=8), golden)


def test_init_study_template_allocation_runs_uncommented(tmp_path, capsys):
    path = tmp_path / "study.toml"
    assert main(["init", "study", str(path)]) == 0
    text = path.read_text()
    assert "# [allocation]" in text
    uncommented = re.sub(r"^# (\[allocation\]|[a-z_]+ = )", r"\1", text, flags=re.M)
    path.write_text(uncommented)
    a = Study.load(path).allocation
    assert a.spec_percentile == 99.73 and a.configurations == ("u-shape",) and a.classes_source == "example"


# ----------------------------------------------------------------- the report
def test_report_shows_allocation(tmp_path):
    text = STUDY.split("[[configuration]]\nname")[0]                  # u-shape only
    result = run_study(study_file(tmp_path, text), progress=False)
    report = write_study(result, tmp_path / "out", formats="png,svg")
    html = report.read_text()
    section = html[html.index("Tolerance allocation"):html.index("Budget</h2>")]
    a = result["u-shape"].allocation
    for name, cls in a.choice.items():
        assert f"<td>{name}</td>" in section and f"<td>{cls}</td>" in section
    assert "binding constraint" in section and "worst-case position error" in section
    assert "allocation_u-shape_map" in section and "allocation_u-shape_front" in section
    assert "What each step of cost buys" in section
    out = tmp_path / "out"
    for f in ("figures/allocation_u-shape_map.png", "figures/allocation_u-shape_front.svg",
              "tables/allocation_u-shape.csv", "tables/allocation_front_u-shape.csv"):
        assert (out / f).is_file(), f
    assert_summary_close(out / "summary.json", build_summary(result), n_se=0.0, ignore=("metadata",))


def test_report_unreachable_spec(tmp_path):
    text = STUDY.split("[[configuration]]\nname")[0].replace("spec_position_um = 80.0", "spec_position_um = 1.0")
    text = text.replace("front = true", "front = false")
    result = run_study(study_file(tmp_path, text), progress=False)
    entry = build_summary(result)["configurations"]["u-shape"]["allocation"]
    assert entry["feasible"] is False and entry["worst_case_position_um"] > 1.0
    html = render_report(result, [], _tables(result), build_summary(result))     # no figures: fast
    assert "No choice\nof the menu meets the spec" in html and "closest" in html
