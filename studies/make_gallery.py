"""Redraw the gallery of the README and the docs' studies page: four figures of the bundled ``quick`` study's report, as small PNGs.

    .venv/bin/python studies/make_gallery.py        # writes studies/gallery/*.png (a few seconds of analyses)

The figures are those of ``prp3mc study quick --out DIR`` (same functions,
same seed), drawn at a lower resolution so that each file stays well under
150 kB.
"""

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from prp3mc.reports import plots
from prp3mc.study.reader import Study
from prp3mc.study.runner import run_study

GALLERY = Path(__file__).resolve().parent / "gallery"
DPI = 72


def _canvas() -> Figure:
    return FigureCanvasAgg(Figure()).figure


def main() -> None:
    result = run_study(Study.load("quick"), progress=False)
    res = list(result.configurations)
    figures = {
        "worstcase_position": plots.compare_maps_figure(res, "worstcase", "position", fig=_canvas()),
        "montecarlo_phi": plots.compare_maps_figure(res, "montecarlo", "phi", 99.73, fig=_canvas()),
        "ecdf_position": plots.ecdf_figure(res, "position", 99.73, fig=_canvas()),
        "sobol_u-shape_position": plots.ranking_figure(result["u-shape"].ranking["position"], "u-shape: position",
                                                       fig=_canvas()),
    }
    GALLERY.mkdir(exist_ok=True)
    for name, fig in figures.items():
        path = GALLERY / f"{name}.png"
        fig.savefig(path, dpi=DPI, pil_kwargs={"optimize": True})
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} kB)")


if __name__ == "__main__":
    main()
