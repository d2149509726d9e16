"""The README's Python examples run, and its two commands are the ones CI uses."""

import re
from pathlib import Path

import pytest

README = (Path(__file__).parent.parent / "README.md").read_text(encoding="utf-8")


def test_ci_runs_the_readme_test_command():
    ci = (Path(__file__).parent.parent / ".ci" / "run").read_text(encoding="utf-8")
    assert "<!-- test-command -->" in README and "<!-- test-command -->" in ci
    first = README.splitlines()[:15]
    assert any("prp3mc study paper_reproduction" in line for line in first)
    assert any("python -m pytest" in line for line in first)


#: Blocks run by the slow call: the API tour's million-sample Monte Carlo on 21 x 21 poses (~8 CPU-s), as written.
HEAVY = ("1_000_000",)


@pytest.mark.parametrize("block", [pytest.param(b, marks=pytest.mark.slow) if any(h in b for h in HEAVY) else b
                                   for b in re.findall(r"```python\n(.*?)```", README, re.S)])
def test_python_examples_run(block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    if "golden.json" in block:  # the pinning example: a golden made with another seed
        import json

        import prp3mc
        study = prp3mc.Study.load("quick").reduced()
        (tmp_path / "golden.json").write_text(json.dumps(prp3mc.build_summary(prp3mc.run_study(study, rng=7))))
    exec(compile(block, "README.md", "exec"), {})
