"""Every report kind, as written by the command line: it names only files its run wrote, its sections follow
one another, and it reads right in a real browser (headless Chromium: no console errors, no broken image, no
horizontal overflow; screenshots kept for a person to look at)."""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
import pytest

from prp3mc.cli import main

from .browser import chromium, open_report
from .report_checks import dangling_sections, figures_without_files, missing_files, promised_files, section_numbers

#: kind -> the command line writing it into DIR (quick sizes: the checks are about the report, not the numbers)
KINDS = {
    "study": ["study", "paper_reproduction", "--quick", "--seed", "1", "--no-progress"],
    "sweep": ["study", "sweep_example", "--quick", "--seed", "1", "--no-progress", "--formats", "svg,xlsx"],
    "allocation": ["study", "allocation_example", "--quick", "--seed", "1", "--no-progress"],
    "correlated": ["study", "correlated_example", "--quick", "--seed", "1", "--no-progress"],
    "discrepancy": ["discrepancy", "--geometry", "u-shape", "--budget", "paper", "--data", "example",
                    "--instrument-sigma-mm", "0.002", "--instrument-sigma-deg", "0.0005", "--seed", "1",
                    "--no-progress"],
}
#: Where the browser test leaves its screenshots (for a person; also under pytest's tmp folder otherwise).
SHOTS = os.environ.get("PRP3MC_SCREENSHOTS")


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    root = tmp_path_factory.mktemp("reports")
    for kind, argv in KINDS.items():
        assert main([*argv, "--out", str(root / kind)]) == 0, kind
    return root


def _html(reports, kind) -> str:
    return (reports / kind / "report.html").read_text(encoding="utf-8")


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
def test_report_names_only_files_its_run_wrote(reports, kind):
    html = _html(reports, kind)
    named = promised_files(html)
    assert any(n.startswith("figures/") or n.endswith(".json") for n in named)      # the check has something to check
    assert missing_files(html, reports / kind) == []
    ext = "svg" if kind == "sweep" else "png"
    assert figures_without_files(html, reports / kind, ext) == []


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["study", "sweep", "allocation", "correlated"])
def test_sections_are_numbered_one_after_another(reports, kind):
    html = _html(reports, kind)
    numbers = section_numbers(html)
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) >= 4
    assert dangling_sections(html) == []


@pytest.mark.slow
def test_figure_formats_named_as_written(reports):
    study, sweep = _html(reports, "study"), _html(reports, "sweep")
    assert ".svg" not in study and not list((reports / "study" / "figures").glob("*.svg"))
    assert "figures/design_space.svg" in sweep and "figures/design_space.png" not in sweep
    assert not list((reports / "sweep" / "figures").glob("*.png"))


@pytest.mark.slow
def test_sweep_lists_swept_values_and_opens_with_its_design_space(reports):
    html = _html(reports, "sweep")
    assert html.index("Design space</h2>") < html.index('alt="design_space"') < html.index("Summary</h2>")
    assert "with leg.3.a_mm = " in html and "leg.*.e_mm = " in html
    assert "<th>merit</th>" not in html


@pytest.mark.slow
def test_xlsx_has_one_sheet_per_table_with_units_in_headers(reports):
    openpyxl = pytest.importorskip("openpyxl")
    folder = reports / "sweep" / "tables"
    book = openpyxl.load_workbook(folder / "tables.xlsx", read_only=True)
    csvs = sorted(p.stem for p in folder.glob("*.csv"))
    assert sorted(book.sheetnames) == sorted(n[:31] for n in csvs)
    header = [c.value for c in next(book["worstcase_u.04"].iter_rows(max_row=1))]
    assert header[:4] == ["x [mm]", "y [mm]", "phi [deg]", "position [µm]"]
    frame = pd.read_csv(folder / "worstcase_u.04.csv")
    row = [c.value for c in list(book["worstcase_u.04"].iter_rows(min_row=2, max_row=2))[0]]
    assert row == pytest.approx(frame.iloc[0].tolist(), rel=1e-15)


@pytest.mark.slow
def test_summary_csv_carries_the_exceedance(reports):
    import json
    summary = pd.read_csv(reports / "study" / "tables" / "summary.csv")
    doc = json.loads((reports / "study" / "summary.json").read_text())
    for name, c in doc["configurations"].items():
        rows = summary[(summary["configuration"] == name) & (summary["statistic"] == "exceed_0.1mm")]
        assert dict(zip(rows["aggregate"], rows["value"])) == pytest.approx(
            {k: v["value"] for k, v in c["montecarlo"]["exceed"]["probability"].items()}, rel=1e-12)
    assert "P(&gt; 0.1 mm)" in _html(reports, "study")


@pytest.mark.slow
@pytest.mark.skipif(chromium() is None, reason="no Chromium: apt-get install -y chromium (or set CHROMIUM)")
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("width", [1400, 1024])
def test_report_reads_right_in_a_browser(reports, kind, width, tmp_path):
    folder = Path(SHOTS) if SHOTS else tmp_path
    folder.mkdir(parents=True, exist_ok=True)
    page = open_report(reports / kind / "report.html", folder / f"{kind}_{width}.png", width=width)
    assert page.problems == [], page.problems
    assert page.images >= 3 and page.screenshot.stat().st_size > 10_000


def test_checks_see_what_is_missing(tmp_path):
    """The checkers themselves: a named file that is absent, a skipped section and a dangling reference."""
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"x")
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "geometry.toml").write_text("")
    html = ("<h2>1. One</h2><p>see section 3 and <code>figures/a.png</code>, <code>figures/a.svg</code>, "
            "<code>geometry.toml</code>, <code>tables/x.csv</code></p><h2>3. Three</h2>"
            "<img alt='a'><img alt='b'>")
    assert missing_files(html, tmp_path) == ["figures/a.svg", "tables/x.csv"]
    assert section_numbers(html) == [1, 3] and dangling_sections(html) == []
    assert dangling_sections(html.replace("section 3", "section 2")) == ["section 2"]
    assert figures_without_files(html, tmp_path) == ["b"]
