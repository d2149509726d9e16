"""Design sweeps (SPEC §8): the [sweep] table, infeasible and failing combinations, serial versus Dask."""

import functools
import json
import logging
import os
import pickle
import re
import subprocess
import sys
from pathlib import Path

import pytest

from prp3mc import Geometry
from prp3mc.cli import main
from prp3mc.errors import InfeasiblePoseError, Prp3mcError, StudyError
from prp3mc.kinematics.chain import check_poses
from prp3mc.study import runner
from prp3mc.study.distributed import DaskExecutor, parse_scheduler
from prp3mc.study.reader import STUDIES_DIR, Study
from prp3mc.study.runner import run_study
from prp3mc.study.summary import build_summary
from prp3mc.study.sweep import best_configurations, design_frame, expand

HEAD = """\
name = "sw"
seed = 5
outputs = {outputs}

[worstcase]
grid = 9

[montecarlo]
samples = 2048
grid = 3
percentiles = [50, 99.73]

[sobol]
samples = 128
grid = 2
outputs = ["position"]

[[configuration]]
geometry = "u-shape"
"""
SWEEP = HEAD + """
[sweep]
"leg.3.a_mm" = [140, 180, 220]
"leg.*.e_mm" = [10, 20.0]
"""
KEYS = ("leg.3.a_mm", "leg.*.e_mm")


def study(tmp_path, text=SWEEP, outputs='["montecarlo", "sobol"]'):
    path = tmp_path / "sw.toml"
    path.write_text(text.format(outputs=outputs))
    return Study.from_toml(path)


def comparable(summary: dict) -> dict:
    """The summary as JSON, without the wall times (all that may differ between runs)."""
    doc = json.loads(json.dumps(summary))
    for key in ("wall_time_s", "timings_s"):
        doc["metadata"].pop(key)
    return doc


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    s = study(tmp_path_factory.mktemp("sweep"))
    return s, run_study(s, progress=False)


# ----------------------------------------------------------------- the table
def test_sweep_table_expands_the_cartesian_product(tmp_path):
    s = study(tmp_path)
    assert s.sweep == (("leg.3.a_mm", (140, 180, 220)), ("leg.*.e_mm", (10, 20.0)))
    variants = expand(s)
    assert [v.name for v in variants] == [f"u-shape.{k}" for k in range(1, 7)]
    assert [dict(v.parameters) for v in variants][:3] == [
        {"leg.3.a_mm": 140, "leg.*.e_mm": 10}, {"leg.3.a_mm": 140, "leg.*.e_mm": 20.0},
        {"leg.3.a_mm": 180, "leg.*.e_mm": 10}]
    g = expand(s)[3].build().geometry       # a_3 = 180, every e_i = 20
    assert g.a == (140.0, 140.0, 180.0) and g.e == (20.0, 20.0, 20.0)


@pytest.mark.parametrize("table, line, reason", [
    ('"leg.4.a_mm" = [1, 2]', 22, "leg.<1|2|3|*>.<parameter>"),
    ('"leg.1.a" = [1, 2]', 22, "leg.<1|2|3|*>.<parameter>"),
    ('"leg.1.a_mm" = []', 22, "non-empty array of finite numbers"),
    ('"leg.1.a_mm" = [1, "x"]', 22, "non-empty array of finite numbers"),
    ('"leg.1.a_mm" = [1, 1]', 22, "lists a value twice"),
    ('"leg.1.stroke_mm" = [0, 200]', 22, "[lo, hi] pairs"),
    ('"leg.*.e_mm" = [10]\n"leg.2.e_mm" = [20]', 23, "sets leg 2's e again"),
    ("leg.3.a_mm = [200]", 21, 'must be quoted, as "leg.3.a_mm"'),
])
def test_bad_sweep_names_line_and_reason(tmp_path, table, line, reason):
    with pytest.raises(StudyError) as err:
        study(tmp_path, HEAD + "\n[sweep]\n" + table + "\n")
    assert re.search(rf"sw\.toml:{line}: .*{re.escape(reason)}", str(err.value)), str(err.value)


# ----------------------------------------------------------------- serial runs
def test_infeasible_combinations_reported_not_fatal(serial):
    s, result = serial
    base = s.configurations[0]
    expected = set()
    for v in expand(s):   # oracle: the combinations whose region leaves the workspace
        g = Geometry.from_preset("u-shape").replace(a=(140, 140, dict(v.parameters)["leg.3.a_mm"]),
                                                    e=(dict(v.parameters)["leg.*.e_mm"],) * 3)
        try:
            check_poses(g, base.region.grid(s.worstcase_grid))
        except InfeasiblePoseError:
            expected.add(v.name)
    assert expected and len(expected) < 6
    assert {k.name for k in result.skipped} == expected
    assert all(k.kind == "infeasible" and "d_3" in k.reason for k in result.skipped)
    summary = build_summary(result)
    assert summary["sweep"]["configurations"] == 6 and summary["sweep"]["failed"] == []
    assert {d["name"] for d in summary["sweep"]["infeasible"]} == expected
    assert all(set(d["parameters"]) == set(KEYS) for d in summary["sweep"]["infeasible"])
    assert set(summary["configurations"]) == {f"u-shape.{k}" for k in range(1, 7)} - expected
    for name, entry in summary["configurations"].items():   # keys exactly as written, values as written
        v = next(v for v in expand(s) if v.name == name)
        assert list(entry["parameters"]) == list(KEYS) and entry["parameters"] == dict(v.parameters)


def test_a_sweep_of_one_value_reproduces_the_study(tmp_path):
    """Common random numbers: a swept configuration equal to the base gives the base's numbers."""
    plain = build_summary(run_study(study(tmp_path, HEAD), progress=False))
    one = build_summary(run_study(study(tmp_path, HEAD + '\n[sweep]\n"leg.3.a_mm" = [180]\n'), progress=False))
    entry = dict(one["configurations"]["u-shape.1"])
    assert entry.pop("parameters") == {"leg.3.a_mm": 180}
    assert entry == plain["configurations"]["u-shape"]


def test_failing_configuration_reported_with_its_parameters(tmp_path, monkeypatch):
    real = runner.worst_case

    def fragile(geometry, *args, **kwargs):
        if geometry.e[0] == 20.0 and geometry.a[2] == 220.0:
            raise ZeroDivisionError("boom")
        return real(geometry, *args, **kwargs)

    monkeypatch.setattr(runner, "worst_case", fragile)
    result = run_study(study(tmp_path, outputs="[]"), progress=False)
    failed = [k for k in result.skipped if k.kind == "failed"]
    assert [(k.name, dict(k.parameters), k.reason) for k in failed] == [
        ("u-shape.6", {"leg.3.a_mm": 220, "leg.*.e_mm": 20.0}, "ZeroDivisionError: boom")]
    assert "u-shape.5" in {c.name for c in result.configurations}
    assert build_summary(result)["sweep"]["failed"][0]["name"] == "u-shape.6"


def test_results_round_trip_through_pickle(serial):
    _, result = serial
    back = pickle.loads(pickle.dumps(result))
    assert comparable(build_summary(back)) == comparable(build_summary(result))
    assert back.skipped == result.skipped and back.study == result.study


def test_serial_sweep_never_imports_dask(tmp_path):
    path = tmp_path / "sw.toml"
    path.write_text(SWEEP.format(outputs="[]"))
    code = ("import sys; from prp3mc.study.runner import run_study; import prp3mc.cli.study; "
            f"r = run_study({str(path)!r}, progress=False); assert r.configurations; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_scheduler_errors_are_one_line(tmp_path, capsys, monkeypatch):
    path = tmp_path / "sw.toml"
    path.write_text(SWEEP.format(outputs="[]"))
    assert parse_scheduler("local:3") == ("local", 3)
    with pytest.raises(Prp3mcError, match="local:N"):
        parse_scheduler("local:0")
    with pytest.raises(Prp3mcError, match="would start 1000 worker processes"):   # not 1000 Pythons on a laptop
        parse_scheduler("local:1000")
    assert main(["study", str(path), "--out", str(tmp_path / "o"), "--scheduler", "lan:2"]) != 0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "tcp://HOST:PORT" in err
    monkeypatch.setitem(sys.modules, "distributed", None)   # as if Dask were not installed
    assert main(["study", str(path), "--out", str(tmp_path / "o"), "--scheduler", "local:2"]) != 0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "pip install 'prp3mc[dask]'" in err
    assert not (tmp_path / "o").exists()


def test_design_frame_and_figure(serial):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from prp3mc.reports.sweep_plots import design_space_figure, merit_plot, merits
    _, result = serial
    frame = design_frame(result)
    assert list(frame.columns[1:3]) == list(KEYS)
    assert merits(frame) == [("worstcase", "position", "worst_case"), ("worstcase", "phi", "worst_case"),
                             ("montecarlo", "position", "p99.73"), ("montecarlo", "phi", "p99.73"),
                             ("sobol", "position", "ST_top")]
    worst = frame.query("statistic == 'worst_case' and output == 'position'").set_index("configuration")["value"]
    for c in result.configurations:
        assert worst[c.name] == c.worst_case.position_mm.max()
    best = best_configurations(frame)
    assert best[0] == worst.idxmin() and len(best) == 3
    fig = design_space_figure(frame, best=best, fig=FigureCanvasAgg(Figure()).figure)
    assert isinstance(fig, Figure) and len(fig.axes) == 5 * 2
    ax = FigureCanvasAgg(Figure()).figure.subplots()
    assert merit_plot(frame, "leg.3.a_mm", merits(frame)[0], best=best, ax=ax) is ax.figure


def test_cli_writes_a_design_space_section(tmp_path, capsys):
    path = tmp_path / "sw.toml"
    path.write_text(SWEEP.format(outputs="[]"))
    assert main(["study", str(path), "--out", str(tmp_path / "out")]) == 0
    assert "configurations ran, best: u-shape." in capsys.readouterr().out
    html = (tmp_path / "out" / "report.html").read_text()
    assert "Design space" in html and "Combinations that did not run" in html and "leg.3.a_mm = 140" in html
    assert (tmp_path / "out" / "figures" / "design_space.png").exists()
    assert (tmp_path / "out" / "tables" / "design_space.csv").exists()


def test_bundled_sweep_example_reads():
    s = Study.load("sweep_example")
    assert s.sweep and len(expand(s)) == 12
    assert Study.load(STUDIES_DIR / "sweep_example.toml") == s


# ----------------------------------------------------------------- on Dask
@pytest.fixture(scope="module")
def cluster():
    import distributed  # in the test extra, so that CI runs these
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, memory_limit="1GiB",
                                  dashboard_address=None, scheduler_kwargs={"dashboard_address": ":0"},
                                  silence_logs=logging.ERROR) as c:
        yield c.scheduler_address


@pytest.mark.slow  # starts a LocalCluster of two worker processes (the module's Dask tests share it)
def test_dask_gives_the_serial_summary(serial, cluster):
    s, result = serial
    on_dask = run_study(s, progress=False, scheduler=cluster)
    assert on_dask.scheduler == cluster
    assert comparable(build_summary(on_dask)) == comparable(build_summary(result))


def _die_once(marker: str, fn, plan, variant):
    """Kill the worker process the first time configuration 4 runs (a worker lost mid-sweep)."""
    if variant.index == 3 and not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    return fn(plan, variant)


class _KillOnce(DaskExecutor):
    def map(self, fn, tasks):
        return super().map(functools.partial(_die_once, self.marker, fn), tasks)


@pytest.mark.slow  # a worker process killed and restarted by the cluster
def test_a_dead_worker_costs_a_retry_not_the_sweep(serial, cluster, tmp_path):
    s, result = serial
    executor = _KillOnce(cluster)
    executor.marker = str(tmp_path / "killed")
    with executor:
        survived = run_study(s, progress=False, scheduler=executor)
    assert (tmp_path / "killed").exists()      # the worker did die
    assert comparable(build_summary(survived)) == comparable(build_summary(result))


@pytest.mark.slow
def test_cli_local_cluster_writes_the_serial_summary(tmp_path, capsys):
    path = tmp_path / "sw.toml"
    path.write_text(SWEEP.format(outputs='["montecarlo"]'))
    for out, extra in (("serial", []), ("dask", ["--scheduler", "local:2"])):
        assert main(["study", str(path), "--out", str(tmp_path / out), *extra]) == 0
    a, b = (json.loads((tmp_path / out / "summary.json").read_text()) for out in ("serial", "dask"))
    assert comparable(a) == comparable(b)
    assert "local:2" in (tmp_path / "dask" / "report.html").read_text()

