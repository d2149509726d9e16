"""The README and the documentation pages say what runs: their commands, examples and links.

The site itself is built with warnings as errors by the README's test command
(``sphinx-build -W``), which checks the links between its pages; these tests
check what GitHub shows without a build, and run the examples.
"""

import json
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")
GUIDE = sorted((ROOT / "docs" / "guide").glob("*.md"))
#: Pages read on GitHub: every relative link in them must name a file of the checkout.
READ_ON_GITHUB = [ROOT / "README.md", ROOT / "benchmarks" / "README.md"]
#: Examples slower than the default run's ~2 s per test (they run with ``pytest -m slow``).
HEAVY = ("prp3mc.sensitivity(", "1_000_000", "prp3mc.allocate(", "simulate_campaign(")


def command_after(marker: str) -> str:
    """The command in the fenced block right after ``marker`` (the line .ci/run reads)."""
    lines = README.splitlines()
    k = lines.index(marker)
    assert lines[k + 1].startswith("```"), f"no fenced block after {marker}"
    return lines[k + 2]


def test_the_two_commands_come_first_and_ci_runs_the_test_command():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert "<!-- test-command -->" in ci
    first = README.splitlines()[:15]
    assert "<!-- main-command -->" in first and "<!-- test-command -->" in first
    assert "prp3mc study paper_reproduction" in command_after("<!-- main-command -->")
    test = command_after("<!-- test-command -->")
    assert "python -m pytest &&" in test and "pytest -m slow" in test
    assert re.search(r"sphinx-build -W .*\bdocs docs/_build/html$", test), "the docs build with warnings as errors"
    assert "docs]" in test, "the test command installs the docs extra"


def blocks(path: Path, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", path.read_text(encoding="utf-8"), re.S)


EXAMPLES = [pytest.param(path, k, b, id=f"{path.name}-{k}",
                         marks=[pytest.mark.slow] if any(h in b for h in HEAVY) else [])
            for path in [ROOT / "README.md", *GUIDE] for k, b in enumerate(blocks(path, "python"))]


@pytest.mark.parametrize("path, k, block", EXAMPLES)
def test_python_examples_run(path, k, block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    if "golden.json" in block:  # the pinning example: a golden made with another seed
        import prp3mc
        study = prp3mc.Study.load("quick").reduced()
        (tmp_path / "golden.json").write_text(json.dumps(prp3mc.build_summary(prp3mc.run_study(study, rng=7))))
    if "openturns" in block:
        pytest.importorskip("openturns")
    if "xarray" in block:
        pytest.importorskip("xarray")
    exec(compile(block, str(path), "exec"), {})


def command_lines():
    """Every ``prp3mc ...`` line of the README's and the guide's shell blocks, optional [...] parts left out."""
    for path in [ROOT / "README.md", *GUIDE]:
        for block in blocks(path, "bash"):
            for line in block.splitlines():
                line = line.split("#")[0].strip()
                if line.startswith("prp3mc ") or line.startswith(".venv/bin/prp3mc "):
                    yield pytest.param(re.sub(r"\[[^]]*\]", "", line), id=f"{path.name}:{line[:40]}")


@pytest.mark.parametrize("line", list(command_lines()))
def test_command_lines_parse(line):
    """The commands shown exist and take the options shown (parsed, not run)."""
    from prp3mc.cli import build_parser

    argv = shlex.split(line)[1:]
    args = build_parser(argv[0]).parse_args(argv)
    assert args.command == argv[0]


def links(path: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    return [t for t in re.findall(r"\]\(([^)\s]+)\)", text) if not re.match(r"[a-z]+:", t)]


@pytest.mark.parametrize("path", READ_ON_GITHUB, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_name_files_of_the_checkout(path):
    found = links(path)
    assert found
    for target in found:
        file = (path.parent / target.split("#")[0]).resolve()
        assert file.exists(), f"{path.name} links to {target}, which does not exist"
        assert ROOT in file.parents, target


def test_readme_links_every_guide_page():
    linked = {(ROOT / t.split("#")[0]).resolve() for t in links(ROOT / "README.md")}
    assert set(GUIDE) - linked - {ROOT / "docs" / "guide" / "index.md"} == set()
