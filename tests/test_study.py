"""Studies: the file format and its errors, the report folder, the worst-case ranges, golden regression."""

import base64
import dataclasses
import functools
import hashlib
import importlib.util
import json
import re
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from prp3mc import Budget, Geometry, Region, sensitivity
from prp3mc.cli import main
from prp3mc.errors import IncompleteBudgetWarning, Prp3mcWarning, StudyError, UnknownPresetError
from prp3mc.reports import plots
from prp3mc.reports.study_report import comparison, write_study
from prp3mc.study.summary import build_summary
from prp3mc.sobol.ranking import ranking
from prp3mc.worstcase.envelope import worst_case
from prp3mc.study.reader import STUDIES_DIR, Study, bundled_studies
from prp3mc.study.runner import run_study
from prp3mc.testing import assert_summary_close, load_summary

GOLDEN = Path(__file__).parent / "golden"
_spec = importlib.util.spec_from_file_location("golden_regenerate", GOLDEN / "regenerate.py")
regenerate = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(regenerate)

SMALL = """\
name = "small"
seed = 3
budget = "paper"

[worstcase]
grid = 9

[montecarlo]
samples = 4096
grid = 3
percentiles = [50, 99]
tolerance_mm = 0.08

[sobol]
samples = 256
grid = 2
outputs = ["position"]

[[configuration]]
geometry = "u-shape"
reference_position_um = [110, 150]

[[configuration]]
name = "delta"
geometry = "delta-shape"
region = { x_mm = [-20, 20], y_mm = [140, 180] }
reference_position_um = [70, 95]
"""


def study_file(tmp_path, text=SMALL, name="small.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


# ----------------------------------------------------------------- the file
def test_bundled_studies():
    assert {"paper_reproduction", "quick"} <= set(bundled_studies())
    s = Study.load("paper_reproduction")
    assert [c.name for c in s.configurations] == ["u-shape", "delta-shape"]
    assert s.budget.names == Budget.from_preset("paper").names
    for c in s.configurations:
        assert c.geometry == Geometry.from_preset(c.name)
        assert c.region == Region.from_preset(c.name) and c.region.phi_deg == 0.0
    assert s.outputs == ("montecarlo", "sobol") and s.worstcase_grid == (201, 201)
    assert Study.load(STUDIES_DIR / "quick.toml") == Study.load("quick")


def test_small_study_parsed(tmp_path):
    s = Study.load(study_file(tmp_path))
    assert s.name == "small" and s.seed == 3 and s.mc_grid == (3, 3) and s.percentiles == (50.0, 99.0)
    assert [c.name for c in s.configurations] == ["u-shape", "delta"]
    assert s.configurations[1].region.x_mm == (-20.0, 20.0)
    r = s.reduced()
    assert r.mc_samples == 4096 and r.worstcase_grid == (9, 9)
    assert Study.load("paper_reproduction").reduced().mc_samples == 1 << 14


def _replace(old, new):
    assert old in SMALL
    return SMALL.replace(old, new, 1)


BAD = [
    (_replace("seed = 3", "seed = "), 2, "malformed TOML"),
    (_replace('budget = "paper"', 'budget = "paper"\nsamples = 10'), 4, "unknown key 'samples' in the study"),
    (_replace("grid = 3", "grid = 3\nsample = 5"), 11, "unknown key 'sample' in [montecarlo]"),
    (_replace("samples = 4096", 'samples = "many"'), 9, "montecarlo.samples must be an integer"),
    (_replace("samples = 256", "samples = 300"), 15, "must be a power of two"),
    (_replace("grid = 9", "grid = 1"), 6, "worstcase.grid must be an integer n >= 2"),
    (_replace("percentiles = [50, 99]", "percentiles = [99, 50]"), 11, "percentiles must be increasing"),
    (_replace('outputs = ["position"]', 'outputs = ["pos"]'), 17, "sobol outputs must be"),
    (_replace('geometry = "delta-shape"', 'geometry = "w-shape"'), 25, "unknown geometry preset 'w-shape'"),
    (_replace('budget = "paper"', 'budget = "missing.toml"'), 3, "budget 'missing.toml'"),
    (_replace("region = { x_mm = [-20, 20], y_mm = [140, 180] }", 'region = "square"'), 26,
     "unknown region preset 'square'"),
    (_replace('geometry = "delta-shape"', 'geometry = "delta-shape"\nphi_deg = -30.0'), 26,
     "the test region leaves the workspace"),
    (_replace('geometry = "u-shape"', 'geometry = "u-shape"\nposes = [[0, 300, 0]]'), 21, "leaves leg"),
    (_replace('geometry = "u-shape"', 'geometry = "u-shape"\nposes = [[0, 100]]'), 21, "poses must be"),
    (_replace('name = "delta"', 'name = "u-shape"'), 24, "used twice"),
    (_replace("reference_position_um = [70, 95]", "reference_position_um = [95, 70]"), 27,
     "reference_position_um must be [lo, hi]"),
    (_replace('name = "delta"', 'nme = "delta"'), 24, "unknown key 'nme' in configuration 2"),
    (SMALL.split("[[configuration]]")[0], 1, "at least one [[configuration]]"),
]


@pytest.mark.parametrize("text, line, reason", BAD)
def test_mistakes_name_line_and_reason(tmp_path, text, line, reason):
    path = study_file(tmp_path, text)
    with pytest.raises(StudyError) as err:
        Study.load(path)
    message = str(err.value)
    assert message.startswith(f"{path}:{line}: "), message
    assert reason in message and "\n" not in message


def test_unknown_study_name():
    with pytest.raises(UnknownPresetError, match="bundled: .*paper_reproduction"):
        Study.load("no_such_study")


# ----------------------------------------------------------------- running and the report folder
def test_cli_writes_report_folder(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["study", str(study_file(tmp_path)), "--out", str(out), "--no-progress"]) == 0
    note = capsys.readouterr().out
    assert re.search(r"wrote .*report\.html in [\d.]+ s .*u-shape [\d.]+-[\d.]+ µm, delta [\d.]+-[\d.]+ µm", note)
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["configurations"]) == {"u-shape", "delta"}
    u = summary["configurations"]["u-shape"]
    assert set(u["worst_case_position_um"]) == {"min", "max", "mean"}
    assert set(u["montecarlo"]["position_um"]["p99"]["max"]) == {"value", "se"}
    assert u["montecarlo"]["exceed"]["tolerance_mm"] == 0.08
    assert set(u["sobol"]["position"]["clearance_1"]) == {"kind", "S1", "ST", "Sh", "worst_case_share"}
    meta = summary["metadata"]
    assert meta["seed"] == 3 and meta["montecarlo_samples"] == 4096 and meta["wall_time_s"] > 0
    inputs = summary["inputs"]   # what the run was made from
    path = study_file(tmp_path)
    assert inputs["study"] == {"name": "small", "file": str(path.resolve()),
                               "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    assert inputs["budget"] == {"name": "paper", "preset": "paper"}
    assert inputs["configurations"]["delta"]["geometry"] == {"name": "delta-shape", "preset": "delta-shape"}
    assert inputs["configurations"]["delta"]["region"]["x_mm"] == [-20.0, 20.0]
    assert inputs["seed"] == 3 and inputs["montecarlo_samples"] == 4096 and inputs["sobol_grid"] == [2, 2]
    assert set(summary["versions"]) == {"prp3mc", "python", "numpy", "scipy", "pandas", "SALib", "numba", "matplotlib"}
    html = (out / "report.html").read_text()
    assert re.search(r"<h2>\d+\. Run</h2>", html) and inputs["study"]["sha256"] in html and "SALib" in html
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", html)  # base64 may spell anything
    assert not re.search(r"\d um\b|\(um\)", text) and "SPEC" not in text  # µm, and no internal references
    assert {"ecdf_position", "ecdf_phi"} <= {p.stem for p in (out / "figures").glob("*.png")}
    images = re.findall(r'<img src="([^"]+)"', html)
    pngs = sorted(p.stem for p in (out / "figures").glob("*.png"))
    assert len(images) == len(pngs) >= 8 and all(src.startswith("data:image/png;base64,") for src in images)
    first = base64.b64decode(images[0].split(",", 1)[1])      # the embedded PNG is the written file
    assert first in [(out / "figures" / f"{p}.png").read_bytes() for p in pngs]
    assert "href=" not in html and "<script" not in html  # self-contained
    assert "holds by" in html or "does not hold" in html
    for table in ("summary", "budget", "worstcase_u-shape", "montecarlo_delta", "sobol_delta",
                  "ranking_u-shape_position", "contributions_delta"):
        assert (out / "tables" / f"{table}.csv").is_file()


def test_cli_refuses_existing_folder_without_force(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    path = study_file(tmp_path, _replace("seed = 3", "seed = 3\noutputs = []"))  # worst case only
    assert main(["study", str(path), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists" in err and "--force" in err
    assert (out / "keep.txt").read_text() == "mine"
    assert main(["study", str(path), "--out", str(out), "--force", "--no-progress"]) == 1  # not an output
    assert "not an earlier prp3mc output" in capsys.readouterr().err and (out / "keep.txt").exists()
    (out / "summary.json").write_text("{}")                         # an earlier run's
    assert main(["study", str(path), "--out", str(out), "--force", "--no-progress"]) == 0
    assert not (out / "keep.txt").exists() and (out / "report.html").is_file()
    figures = {p.suffix for p in (out / "figures").iterdir()}
    assert figures == {".png"}                                      # one format by default
    both = tmp_path / "both"                                        # SVG on request, one per PNG
    assert main(["study", str(path), "--out", str(both), "--no-progress", "--formats", "png,svg"]) == 0
    pngs = sorted(p.stem for p in (both / "figures").glob("*.png"))
    assert sorted(p.stem for p in (both / "figures").glob("*.svg")) == pngs and len(pngs) == 4   # maps, Pareto charts
    assert main(["study", str(path), "--out", str(tmp_path / "o"), "--formats", "png,pdf"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "png, svg" in err and not (tmp_path / "o").exists()


def _line_figure(k):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = FigureCanvasAgg(Figure(figsize=(2, 1.5), layout="constrained")).figure
    fig.subplots().plot(np.arange(5) ** k, label=f"power {k}")
    return fig


def test_figures_drawn_on_worker_processes_are_those_drawn_here(tmp_path):
    """rendering() on worker processes (where the system forks) and in this process: the same files and bytes."""
    from prp3mc.reports._render import _can_fork, rendering
    figures = [(f"f{k}", functools.partial(_line_figure, k)) for k in range(3)]
    written = {}
    for where, workers in (("here", 1), ("there", 2)):
        (tmp_path / where).mkdir()
        with rendering(figures, tmp_path / where, ("png", "svg"), workers) as pngs:
            returned = list(pngs)
        assert returned == [(tmp_path / where / f"f{k}.png").read_bytes() for k in range(3)]
        written[where] = returned
    assert written["here"] == written["there"]
    assert {p.name for p in (tmp_path / "there").iterdir()} == {f"f{k}.{e}" for k in range(3) for e in ("png", "svg")}
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert not _can_fork()                # never forks while another thread runs (a notebook kernel)
    finally:
        stop.set()
        other.join()


def test_cli_bad_study_one_line(tmp_path, capsys):
    path = study_file(tmp_path, BAD[3][0])
    assert main(["study", str(path), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}:9:" in err and not (tmp_path / "o").exists()


def test_seed_recorded_and_reproducible(tmp_path):
    study = Study.load(study_file(tmp_path, _replace("seed = 3\n", "")))
    a, b = run_study(study, progress=False), run_study(study, progress=False)
    assert a.seed != b.seed
    again = run_study(study, rng=a.seed, progress=False)
    np.testing.assert_array_equal(again["delta"].montecarlo.position_pct, a["delta"].montecarlo.position_pct)


def test_results_follow_the_result_protocol(tmp_path):
    result = run_study(Study.load(study_file(tmp_path)), progress=False)
    u = result["u-shape"]
    for obj in (result, u, u.samples):
        assert len(repr(obj)) < 200 and "\n" not in repr(obj), repr(obj)
    with pytest.raises(ValueError, match="read-only"):
        u.samples.position_mm[0, 0] = 0.0
    with pytest.raises(TypeError):
        result.timings_s["worstcase"] = 0.0
    with pytest.raises(TypeError):
        u.ranking["position"] = None
    frame = result.to_frame()
    assert set(frame["unit"]) == {"mm", "deg"} and set(frame["output"]) == {"position", "phi"}
    assert {"statistic", "value", "se"} <= set(frame.columns)
    worst = frame.query("configuration == 'u-shape' and statistic == 'worst_case' and output == 'position'")
    assert dict(zip(worst["aggregate"], worst["value"])) == pytest.approx(
        {"min": u.worst_case.position_mm.min(), "max": u.worst_case.position_mm.max(),
         "mean": u.worst_case.position_mm.mean()}, rel=1e-12)
    samples = u.samples.to_frame()
    assert set(samples["unit"]) == {"mm", "deg"} and {"x_mm", "y_mm", "phi_deg"} <= set(samples.columns)
    drawn = samples.query("output == 'position' and statistic == 'sample'")["value"].to_numpy()
    np.testing.assert_array_equal(drawn, u.samples.position_mm.ravel())


# ----------------------------------------------------------------- worst-case ranges, independently
def _brute_force_position(geometry, budget, poses):
    """Max position error over every vertex of the budget box, from the Jacobians of `sensitivity`.

    Terms: theta_i (deg), b_i (mm) and the clearance rho_i cos(zeta_i - omega_i) in [-rho_max, rho_max]
    acting along the worst direction, J_rho = A^-1 (SPEC §1). 2^9 vertices.
    """
    s = sensitivity(geometry, poses)
    hi = dict(zip(budget.names, budget.bounds()))
    cols, ranges = [], []
    for fam, scale in (("theta", np.pi / 180), ("b", 1.0), ("rho", 1.0)):
        for i in range(3):
            cols.append(s.J[fam][..., :2, i] * scale)
            lo_, hi_ = hi[f"{fam}_{i + 1}"]
            ranges.append((-hi_, hi_) if fam == "rho" else (lo_, hi_))
    G = np.stack(cols, axis=-1)                                         # (..., 2, 9)
    signs = np.array(np.meshgrid(*[[0, 1]] * 9, indexing="ij")).reshape(9, -1).T   # (512, 9)
    R = np.array(ranges)
    V = np.where(signs == 1, R[:, 1], R[:, 0])                          # (512, 9)
    rows = [np.einsum("xot,vt->xvo", G_row, V) for G_row in G]         # a row of poses at a time (memory)
    return np.stack([np.hypot(e[..., 0], e[..., 1]).max(-1) for e in rows])


def test_paper_worst_case_ranges_match_brute_force():
    study = Study.load("paper_reproduction")
    result = run_study(dataclasses.replace(study, outputs=()), progress=False)  # the full 201 x 201 grid
    for c in result.configurations:
        poses = c.configuration.region.grid(study.worstcase_grid)
        brute = _brute_force_position(c.configuration.geometry, study.budget, poses)
        wc = c.worst_case.position_mm
        np.testing.assert_allclose([wc.min(), wc.max()], [brute.min(), brute.max()], rtol=1e-9)
    ranges = {c.name: (1e3 * c.worst_case.position_mm.min(), 1e3 * c.worst_case.position_mm.max())
              for c in result.configurations}
    # the documented figures (README, report): U about 117-195 um, Delta about 114-136 um
    np.testing.assert_allclose(ranges["u-shape"], (116.87, 194.64), atol=0.01)
    np.testing.assert_allclose(ranges["delta-shape"], (114.12, 136.06), atol=0.01)


# ----------------------------------------------------------------- golden regression
@pytest.mark.parametrize("name", ["paper_reproduction", "quick"])
@pytest.mark.parametrize("seed", [1, 2024])
def test_golden_summary_any_seed(name, seed):
    golden = load_summary(GOLDEN / f"{name}.json")
    assert golden["metadata"]["seed"] == regenerate.GOLDEN_SEED != seed
    assert_summary_close(regenerate.golden_summary(name, seed=seed), golden)


def test_golden_correlated_summary():
    """The bundled correlated study: Shapley effects, Monte Carlo of the copula and the realised rank correlations
    within their standard errors of the pinned run's, every exact figure (worst case, latent correlations) equal."""
    golden = load_summary(GOLDEN / "correlated_example.json")
    with pytest.warns(Prp3mcWarning, match="correlates some inputs"):
        summary = regenerate.golden_summary("correlated_example", seed=3)
    assert_summary_close(summary, golden)
    assert golden["correlation"]["analyses"]["shapley"]["respects"] and "Sh" in \
        golden["configurations"]["u-shape"]["sobol"]["position"]["theta_1"]


@pytest.mark.parametrize("name", ["paper_reproduction", "quick"])
def test_golden_summary_catches_guide_play_10_percent(name):
    golden = load_summary(GOLDEN / f"{name}.json")
    perturbed = Study.load(name).budget.scaled(1.1, "theta")
    with pytest.raises(AssertionError) as err:
        assert_summary_close(regenerate.golden_summary(name, seed=7, budget=perturbed), golden)
    failing = str(err.value).splitlines()[1:]
    assert any(".worst_case_position_um.max" in f for f in failing)
    # not only the exact worst case: the Monte Carlo statistics see it beyond their standard errors too
    assert sum(".montecarlo.position_um." in f for f in failing) >= 10


# ----------------------------------------------------------------- what the summary says about its run
def test_inputs_name_files_and_their_hashes(tmp_path):
    Budget.from_preset("paper").to_toml(tmp_path / "b.toml")
    Geometry.from_preset("u-shape").to_toml(tmp_path / "g.toml")
    text = _replace('budget = "paper"', 'budget = "b.toml"').replace('geometry = "u-shape"', 'geometry = "g.toml"')
    study = dataclasses.replace(Study.load(study_file(tmp_path, text)), outputs=())
    summary = build_summary(run_study(study, progress=False))
    sha = lambda name: hashlib.sha256((tmp_path / name).read_bytes()).hexdigest()  # noqa: E731
    assert summary["inputs"]["budget"] == {"name": "paper", "file": str((tmp_path / "b.toml").resolve()),
                                           "sha256": sha("b.toml")}
    geometries = summary["inputs"]["configurations"]
    assert geometries["u-shape"]["geometry"]["sha256"] == sha("g.toml")
    assert geometries["delta"]["geometry"] == {"name": "delta-shape", "preset": "delta-shape"}
    # a budget replaced in code is not the file's: named, and said so
    what_if = build_summary(run_study(study, progress=False, budget=study.budget.scaled(1.1, "theta")))
    budget = what_if["inputs"]["budget"]
    assert budget["note"].startswith("not as the study file") and "sha256" not in budget
    # run metadata never fails a regression check, whichever side has it
    golden = {k: v for k, v in summary.items() if k not in ("inputs", "versions", "metadata")}
    assert_summary_close(summary, golden)
    assert_summary_close(golden, summary)


def test_constant_input_has_undefined_sobol_indices_in_the_summary(tmp_path):
    """A zero-width input: S1 and ST are null with the reason, never NaN, and summary.json is written."""
    from prp3mc import Uniform
    from prp3mc.output import dumps_json
    constant = Budget.from_preset("paper").replace(theta_2=Uniform(0.0, 0.0))
    study = dataclasses.replace(Study.load(study_file(tmp_path)), budget=constant)
    summary = build_summary(run_study(study, progress=False))
    entry = summary["configurations"]["u-shape"]["sobol"]["position"]["theta_2"]
    assert entry["S1"] is None and entry["ST"] is None and "constant input" in entry["reason"]
    assert set(summary["configurations"]["u-shape"]["sobol"]["position"]["theta_1"]["S1"]) == {"value", "se"}
    assert "reason" not in summary["configurations"]["u-shape"]["sobol"]["position"]["theta_1"]
    assert json.loads(dumps_json(summary))["configurations"]["delta"]["sobol"]["position"]["theta_2"]["S1"] is None


def test_incomplete_budget_is_recorded_in_summary_and_report(tmp_path, capsys):
    """A budget with inputs missing for some legs: warned once, recorded in summary.json, shown in the report."""
    Budget.from_preset("paper").to_toml(tmp_path / "cut.toml")
    text = (tmp_path / "cut.toml").read_text()
    (tmp_path / "cut.toml").write_text(text[:text.index("[inputs.theta_3]")])
    path = study_file(tmp_path, _replace('budget = "paper"', 'budget = "cut.toml"\noutputs = []'))
    out = tmp_path / "out"
    assert main(["study", str(path), "--out", str(out), "--no-progress"]) == 0
    assert capsys.readouterr().err.count("warning: ") == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["inputs"]["budget"]["missing_inputs"] == ["b_3", "theta_3"]
    assert len(summary["warnings"]) == 1 and "no law for b_3, theta_3 (other legs have one)" in summary["warnings"][0]
    html = (out / "report.html").read_text()
    assert "<b>Warnings</b>" in html and "no law for b_3, theta_3" in html
    # a summary built in Python records its budget's own warning; a complete budget has none
    with pytest.warns(IncompleteBudgetWarning):
        study = Study.load(path)
    assert build_summary(run_study(study, progress=False))["warnings"] == list(study.budget.warnings)
    assert "warnings" not in build_summary(run_study(Study.load(study_file(tmp_path, _replace(
        "seed = 3", "seed = 3\noutputs = []"), name="complete.toml")), progress=False))


def test_budget_of_constant_inputs_runs_to_a_report(tmp_path, capsys):
    """Every input zero-width: worst case 0 everywhere, no family share of it, Sobol undefined, said so."""
    (tmp_path / "zero.toml").write_text('name = "zero"\n[inputs]\n' + "".join(
        f'theta_{i} = {{ law = "uniform", lo = 0, hi = 0 }}\n' for i in (1, 2, 3)))
    text = _replace('budget = "paper"', 'budget = "zero.toml"').replace("grid = 9", "grid = 3", 1)
    out = tmp_path / "out"
    assert main(["study", str(study_file(tmp_path, text)), "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["configurations"]["u-shape"]["worst_case_position_um"]["max"] == 0.0
    assert summary["configurations"]["u-shape"]["sobol"]["position"]["theta_1"]["S1"] is None
    assert "Undefined, so not drawn, for theta_1, theta_2, theta_3" in (out / "report.html").read_text()


# ----------------------------------------------------------------- honest pictures
def _fake_config(name, values, x=(-40, 40), y=(60, 140)):
    """What compare_maps_figure reads of a ConfigurationResult: a name and a worst case on a grid."""
    ny, nx = values.shape
    poses = np.stack([*np.meshgrid(np.linspace(*x, nx), np.linspace(*y, ny)), np.zeros((ny, nx))], axis=-1)
    return SimpleNamespace(name=name, worst_case=SimpleNamespace(poses=poses, value=lambda q: values / 3600))


def _figure():
    from matplotlib.figure import Figure
    return Figure()


def test_ecdf_steps_follow_the_sample_ecdf_within_one_step(seed):
    values = np.random.default_rng(seed).gamma(2.0, size=100_003)
    n, steps = values.size, 1000
    x, weights = plots.ecdf_steps(values, steps)
    assert len(x) <= steps + 1 and weights.sum() == n and x[0] == values.min() and x[-1] == values.max()
    drawn = np.cumsum(weights) / n
    ordered = np.sort(values)
    np.testing.assert_allclose(drawn, np.searchsorted(ordered, x, side="right") / n, rtol=1e-12)  # exact there
    between = drawn[np.searchsorted(x, ordered, side="right") - 1]                 # the drawn step at each value
    assert np.max(np.arange(1, n + 1) / n - between) <= 1.0 / steps + 1e-12
    few, ones = plots.ecdf_steps(values[:50], steps)                                 # small samples: every value
    np.testing.assert_array_equal(few, values[:50])
    assert (ones == 1).all()


def test_constant_field_says_so_without_extrema():
    flat = np.full((5, 6), 155.13247841458747) * (1 + 1e-13 * np.arange(30).reshape(5, 6))  # round-off only
    config = _fake_config("u-shape", flat)
    fig = plots.worst_case_map(config.worst_case, "phi", ax=_figure().subplots())
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.texts] == ["constant: 155.1 arcsec"]
    assert ax.get_legend() is None and not ax.get_lines()          # no max/min markers
    varying = _fake_config("u-shape", flat + np.arange(6))
    ax = plots.worst_case_map(varying.worst_case, "phi", ax=_figure().subplots()).axes[0]
    assert not any(t.get_text().startswith("constant") for t in ax.texts)
    assert [t.get_text()[:3] for t in ax.get_legend().get_texts()] == ["max", "min"]
    fig = plots.compare_maps_figure([config, _fake_config("delta", flat + 55)], "worstcase", "phi", fig=_figure())
    assert "constant over each region" in fig.get_suptitle() and len(fig.axes) == 2   # no colour bar


@pytest.mark.parametrize("spread, shared", [(20.0, True), (1.5, False)])
def test_colour_scale_shared_only_when_no_panel_is_left_in_one_colour(spread, shared):
    ramp = np.linspace(0, 1, 6)[None, :] * np.ones((5, 1))
    configs = [_fake_config("u-shape", 115 + spread * ramp), _fake_config("delta", 115 + 17 * ramp)]
    fig = plots.compare_maps_figure(configs, "worstcase", "phi", fig=_figure())
    colour_bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(colour_bars) == (1 if shared else 2)
    assert ("one colour scale" in fig.get_suptitle()) == shared
    assert ("its own colour scale" in fig.get_suptitle()) != shared


def test_ranking_figure_one_basis_each_ranking_in_its_own_order(tmp_path):
    result = run_study(Study.load(study_file(tmp_path)), progress=False)
    frame = result["u-shape"].ranking["position"]
    assert frame.attrs["n_poses"] == 4
    basis, column = plots.ranking_basis(frame)
    assert basis == "mean over the 4 poses" and column == "worst_case_share_mean"
    sobol_ax, wc_ax = plots.ranking_figure(frame, fig=_figure()).axes
    assert basis in sobol_ax.get_title() and basis in wc_ax.get_title()
    shares = frame.dropna(subset=[column]).set_index("name")[column]
    drawn = [t.get_text().removesuffix(" (group)") for t in wc_ax.get_yticklabels()]
    assert drawn == list(shares.sort_values(ascending=False).index)                # ranked by its own share
    assert [t.get_text().removesuffix(" (group)") for t in sobol_ax.get_yticklabels()] == list(frame["name"])
    # the mean share is the mean over the poses of the per-pose shares
    c = result["u-shape"]
    wc = worst_case(c.configuration.geometry, result.study.budget, c.sobol.poses)
    per_pose = [ranking(c.sobol, wc, "position", index=k).set_index("name")["worst_case_share"]
                for k in np.ndindex(c.sobol.poses.shape[:-1])]
    np.testing.assert_allclose(shares, sum(per_pose)[shares.index] / len(per_pose), rtol=1e-12)

    ecdf = plots.ecdf_figure(list(result.configurations), "position", fig=_figure())
    ax = ecdf.axes[0]
    worst = 1e3 * c.samples.worst_position_mm[0]
    assert any(np.allclose(line.get_xdata(), worst) for line in ax.get_lines())   # the worst case, dashed
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(label.startswith("worst case") and label.endswith("µm") for label in labels)


def test_reference_range_from_zero_has_no_ratio_and_renders(tmp_path):
    """A published range starting at 0 µm: its ratio is undefined (said so), never a division by zero."""
    path = study_file(tmp_path, _replace("reference_position_um = [70, 95]", "reference_position_um = [0, 95]")
                      .replace("seed = 3", "seed = 3\noutputs = []"))
    result = run_study(Study.load(path), progress=False)
    cmp = comparison(result)
    assert cmp["ranges"]["delta"]["ratio"][0] is None and cmp["ranges"]["delta"]["ratio"][1] > 0
    write_study(result, tmp_path / "out", workers=1)
    assert "– (paper: 0)" in (tmp_path / "out" / "report.html").read_text()


@pytest.mark.parametrize("line, bad", [('name = "small"', 'name = "a/b"'), ('name = "small"', 'name = "x\\u0000y"'),
                                       ('name = "small"', 'name = ".."'), ('name = "delta"', 'name = ""'),
                                       ('name = "delta"', 'name = "../../escape"')])
def test_names_that_name_files_are_checked_up_front(tmp_path, line, bad):
    """A study's and a configuration's names make file names: a separator, a control character or an
    empty name is refused at its line before any analysis runs (they failed after it, or with a traceback)."""
    with pytest.raises(StudyError, match=r"small.toml:\d+: .*name must be a name for files"):
        Study.load(study_file(tmp_path, SMALL.replace(line, bad)))
