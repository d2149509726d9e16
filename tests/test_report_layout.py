"""matplotlib's constrained layout lays the study report's figures out so that they hold what they show.

Each figure is laid out by matplotlib (prp3mc.reports.canvas.agg_figure). Drawn here for small studies that
vary what the margins must hold: two configurations, one of them over a
wide region, with long names; a budget of constant inputs (constant fields, no extrema,
undefined Sobol indices), a sweep (the design-space figure, its best three
configurations; slow), an allocation (its map and Pareto front) and a spec (the exceedance curves; slow). In every
figure, every panel with its tick labels, labels, title and legend, and the
figure's title, lies inside the canvas, and no two of them overlap.
"""

from __future__ import annotations

import itertools

import pytest

from prp3mc.reports.study_report import _figures
from prp3mc.study.reader import Study
from prp3mc.study.runner import run_study

from .test_study import SMALL, _replace
from .test_study_allocation import STUDY as ALLOCATION
from .test_sweep import SWEEP

ZERO_BUDGET = 'name = "zero"\n[inputs]\n' + "".join(
    f'theta_{i} = {{ law = "uniform", lo = 0, hi = 0 }}\n' for i in (1, 2, 3))
STUDIES = {
    "wide region, long names": SMALL.replace("{ x_mm = [-20, 20], y_mm = [140, 180] }", "{ x_mm = [-60, 60], y_mm = [150, 190] }")
    .replace('outputs = ["position"]', 'outputs = ["position", "phi"]\ngroups = { all_three_encoder_angles = '
             '["theta_1", "theta_2", "theta_3"] }').replace('name = "delta"', 'name = "delta-shape, a wide region"'),
    "constant budget": _replace('budget = "paper"', 'budget = "zero.toml"').replace("grid = 9", "grid = 3", 1),
    "sweep": SWEEP.format(outputs='["montecarlo", "sobol"]'),
    "spec": SMALL + "\n[spec]\nposition_um = 80\n",            # the exceedance curves (slow: the exact yield)
    "allocation": ALLOCATION,
}


def _parts(fig):
    """(axes index or None, what, window extent in pixels) of everything laid out on ``fig``.

    The figure's title; for every visible axes, its frame, title, x and y
    axis (tick labels and label), legend and the texts not clipped to it
    (contour labels are).
    """
    renderer = fig.canvas.get_renderer()
    parts = [(None, "figure title", fig._suptitle.get_window_extent(renderer))] if fig._suptitle else []
    for k, ax in enumerate(ax for ax in fig.axes if ax.get_visible()):
        named = [("frame", ax), ("title", ax.title), ("x axis", ax.xaxis), ("y axis", ax.yaxis),
                 ("legend", ax.get_legend()),
                 *(("text " + t.get_text(), t) for t in ax.texts if not (t.get_clip_on() and t.get_clip_box()))]
        for what, artist in named:
            box = None if artist is None or not artist.get_visible() else artist.get_window_extent(renderer) \
                if what != "x axis" and what != "y axis" else artist.get_tightbbox(renderer)
            if box is not None and box.width > 0 and box.height > 0:
                parts.append((k, f"{what} of axes {k} ({ax.get_title()!r})", box))
    return parts


@pytest.fixture(scope="module", params=[pytest.param(k, marks=pytest.mark.slow) if k in ("sweep", "spec") else k
                                        for k in STUDIES])
def figures(request, tmp_path_factory):
    folder = tmp_path_factory.mktemp("layout")
    (folder / "zero.toml").write_text(ZERO_BUDGET)
    (folder / "study.toml").write_text(STUDIES[request.param])
    return _figures(run_study(Study.load(folder / "study.toml"), progress=False))


def test_every_figure_laid_out_by_matplotlib_inside_its_canvas_without_overlaps(figures):
    from matplotlib.layout_engine import ConstrainedLayoutEngine
    assert figures
    for name, _, draw in figures:
        fig = draw()
        assert isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine), name    # no hand layout
        fig.set_dpi(150)                                        # the report's resolution (pixels as saved)
        fig.canvas.draw()
        canvas = fig.bbox.padded(1.0)                           # a pixel of rounding
        parts = _parts(fig)
        for _, what, box in parts:
            assert canvas.containsx(box.x0) and canvas.containsx(box.x1), (name, what, box, fig.bbox)
            assert canvas.containsy(box.y0) and canvas.containsy(box.y1), (name, what, box, fig.bbox)
        for (k, a, box_a), (j, b, box_b) in itertools.combinations(parts, 2):
            if k == j and k is not None and "frame" in a + b:
                continue                     # inside its own axes: a legend, a label, a tick label at its edge
            overlap = box_a.intersection(box_a, box_b)
            assert overlap is None or min(overlap.width, overlap.height) <= 1.0, (name, a, b)
