"""Rewrite the golden summaries of the bundled studies (run at reduced size).

    .venv/bin/python tests/golden/regenerate.py

Each ``<study>.json`` is ``summary.json`` of ``Study.load(<study>).reduced()``
run with :data:`GOLDEN_SEED`, without the run's wall times. Regenerate only
when a change of the model is intended, and say why in the commit: the tests
compare reduced runs with other seeds against these files
(``prp3mc.testing.assert_summary_close``), so a change that moves a statistic
by more than its standard errors allow fails them.
"""

from pathlib import Path

from prp3mc.output import write_json
from prp3mc.study.reader import Study, bundled_studies
from prp3mc.study.runner import run_study
from prp3mc.study.summary import build_summary

GOLDEN_DIR = Path(__file__).resolve().parent
GOLDEN_SEED = 12345


def golden_summary(name: str, seed: int = GOLDEN_SEED, budget=None) -> dict:
    """Summary of the reduced bundled study ``name`` (wall times dropped, and ``inputs`` and ``versions``: the
    comparisons skip them, and they name the folder and the machine that wrote the file)."""
    summary = build_summary(run_study(Study.load(name).reduced(), rng=seed, progress=False, budget=budget))
    for key in ("wall_time_s", "timings_s", "source"):
        summary["metadata"].pop(key)
    for key in ("inputs", "versions"):
        summary.pop(key)
    return summary


def main() -> None:
    for name in bundled_studies():
        path = GOLDEN_DIR / f"{name}.json"
        write_json(path, golden_summary(name))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
