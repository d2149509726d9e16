"""Every notebook in notebooks/ is committed executed, its pictures visible, and runs top to bottom again at a
small sample size showing every picture it draws."""

import re
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))

#: A cell draws when its code (imports aside) calls a plotting function: ``plots.x(``, ``.plot*(``,
#: ``sns.x(``, ``plt.x(`` or ``*_figure(``.
DRAWS = re.compile(r"\bplots\.\w+\(|\.plot\w*\(|\bsns\.\w+\(|\bplt\.\w+\(|_figure\(")
IMPORT = re.compile(r"\s*(import|from)\s")
IMAGES = ("image/png", "image/svg+xml")


def draws(cell) -> bool:
    """Whether a code cell calls a plotting function (import lines do not count)."""
    code = "\n".join(line for line in cell.source.splitlines() if not IMPORT.match(line))
    return cell.cell_type == "code" and bool(DRAWS.search(code))


def shows_picture(cell) -> bool:
    return any(kind in out.get("data", {}) for out in cell.get("outputs", []) for kind in IMAGES)


def test_notebooks_found():
    assert {"quickstart.ipynb", "u_vs_delta.ipynb", "tolerance_whatif.ipynb"} <= {p.name for p in NOTEBOOKS}


def test_draw_heuristic():
    code = lambda src: nbformat.v4.new_code_cell(src)  # noqa: E731
    assert draws(code("plots.worst_case_map(wc)")) and draws(code("fig = rep.plot_gap(r)"))
    assert draws(code("x = 1\nplots.compare_maps_figure(res)")) and draws(code("plt.subplots(1, 2)"))
    assert not draws(code("from prp3mc.reports import plots\nimport matplotlib.pyplot as plt"))
    assert not draws(nbformat.v4.new_markdown_cell("plots.worst_case_map(wc)"))
    png = nbformat.v4.new_output("display_data", data={"image/png": "iVBOR", "text/plain": "<Figure>"})
    assert shows_picture(code("") | {"outputs": [png]})
    assert not shows_picture(code("") | {"outputs": [nbformat.v4.new_output("stream", text="hi")]})


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_is_committed_with_its_outputs(path):
    """A reader on GitHub sees the results: every code cell ran, in order, and every drawing cell shows its picture.

    Re-run them after a change: ``jupyter nbconvert --to notebook --execute --inplace notebooks/*.ipynb``
    (the ``notebooks`` extra installs it).
    """
    nb = nbformat.read(path, as_version=4)
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    counts = [cell.get("execution_count") for cell in code]
    assert None not in counts and counts == sorted(counts), f"{path.name}: not executed top to bottom"
    assert not [o for cell in code for o in cell.get("outputs", []) if o.get("output_type") == "error"]
    blank = [i for i, cell in enumerate(nb.cells) if draws(cell) and not shows_picture(cell)]
    assert not blank, f"{path.name}: drawing cells {blank} show no picture"


@pytest.mark.slow  # a Jupyter kernel per notebook and its analyses: 5-25 s each (CI's `pytest -m slow` runs them)
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes_and_shows_its_figures(path, monkeypatch):
    monkeypatch.setenv("PRP3MC_NOTEBOOK_SAMPLES", "4096")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend, as a user has it
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:                      # run afresh: the committed outputs must not count
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    first_code = next(cell for cell in nb.cells if cell.cell_type == "code")
    assert "PRP3MC_NOTEBOOK_SAMPLES" in first_code.source
    NotebookClient(nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    drawing = [i for i, cell in enumerate(nb.cells) if draws(cell)]
    blank = [f"cell {i}: {nb.cells[i].source.strip().splitlines()[-1][:80]}" for i in drawing
             if not shows_picture(nb.cells[i])]
    assert not blank, f"{path.name}: {len(blank)} of {len(drawing)} drawing cells show no picture:\n  " \
        + "\n  ".join(blank)


#: Where a stored output would name this machine's folders (an absolute path), as text.
ABSOLUTE = re.compile(r"(?<![\w.~])/(?:work|home|Users|tmp|root|private|var|mnt)/[\w.-]")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_committed_outputs_name_no_folder_of_the_machine_that_ran_them(path):
    """A stored output shows relative paths only: an absolute one names the folder of whoever executed it."""
    nb = nbformat.read(path, as_version=4)
    root = str(Path(__file__).resolve().parent.parent)
    for i, cell in enumerate(nb.cells):
        for out in cell.get("outputs", []):
            text = out.get("text", "") + "".join(v for k, v in out.get("data", {}).items() if k.startswith("text/"))
            assert root not in text and not ABSOLUTE.search(text), f"{path.name} cell {i}: {text[:200]}"


def test_path_check_sees_a_path():
    assert ABSOLUTE.search("'source': '/work/wt/users/studies/paper_reproduction.toml'")
    assert not ABSOLUTE.search("'source': '../studies/paper_reproduction.toml', 'rate': '2 µm/s'")
