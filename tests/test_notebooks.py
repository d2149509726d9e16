"""Every notebook in notebooks/ runs top to bottom at a small sample size."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))


def test_notebooks_found():
    assert {"quickstart.ipynb", "u_vs_delta.ipynb", "tolerance_whatif.ipynb"} <= {p.name for p in NOTEBOOKS}


SLOW_NOTEBOOKS = {"discrepancy_walkthrough"}  # runs the whole discrepancy workflow (~10 s idle)


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW_NOTEBOOKS else p
                                  for p in NOTEBOOKS], ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    monkeypatch.setenv("PRP3MC_NOTEBOOK_SAMPLES", "4096")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    assert all(not cell.get("outputs") for cell in nb.cells if cell.cell_type == "code"), \
        f"{path.name} is saved with outputs: clear them"
    first_code = next(cell for cell in nb.cells if cell.cell_type == "code")
    assert "PRP3MC_NOTEBOOK_SAMPLES" in first_code.source
    NotebookClient(nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
