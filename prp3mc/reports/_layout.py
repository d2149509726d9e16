"""Figures laid out once, in inches: fixed margins, no layout engine, one draw.

A layout engine (constrained, tight) measures every label in a first,
draw-disabled pass before the real draw: about half of a figure's cost.
The reports' figures instead fix their margins in inches, sized from what
they hold (:func:`text_inches` measures a string without drawing anything),
so each renders in one pass. A figure of :func:`agg_figure` sits on its own
Agg canvas: pyplot and the matplotlib backend are untouched.
:func:`lighten` drops what costs most and says least.

Not yet replaced by matplotlib's constrained layout: that engine rendered the
paper study's report figures 1.4-1.8x slower (``benchmarks/bench_private.py``),
short of the 2x that would justify this module, but the maps' colour bars and
the legends below them are placed in these margins by hand and would need
redrawing first (issue 23); tests/test_report_layout.py guards the layout meanwhile.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

__all__ = ["Margins", "agg_figure", "fix_layout", "grid", "text_inches", "wrap", "number_inches", "tick_width",
           "title_lines", "set_title", "shift", "lighten", "ROUND_STEPS"]

_POINTS = 72.0
#: Tick steps of matplotlib's default ticks (1, 2, 2.5, 5 times a power of ten), for :func:`lighten`.
ROUND_STEPS = (1, 2, 2.5, 5, 10)


class Margins(NamedTuple):
    """Where a figure's grid of panels sits: (left, right, bottom, top) inches from the figure's edges,
    and the gaps between panels as fractions of a panel's width (``wspace``) and height (``hspace``),
    as :meth:`matplotlib.figure.Figure.subplots_adjust` takes them."""

    left: float
    right: float
    bottom: float
    top: float
    wspace: float = 0.2
    hspace: float = 0.2


def fix_layout(fig, figsize: tuple[float, float], margins):
    """``fig`` resized to ``figsize`` inches, its layout engine off and its panels placed by ``margins``.

    ``margins`` is a :class:`Margins` or the same six numbers. Applies to
    the panels made after this call (``fig.subplots``) and to those already there.
    """
    (w, h), m = figsize, Margins(*margins)
    fig.set_size_inches(figsize)
    fig.set_layout_engine("none")
    fig.subplots_adjust(left=m.left / w, right=1 - m.right / w, bottom=m.bottom / h, top=1 - m.top / h,
                        wspace=m.wspace, hspace=m.hspace)
    return fig


def agg_figure(figsize: tuple[float, float] | None = None, margins=None, *, dpi: float = 100.0):
    """A Figure on its own Agg canvas (no pyplot, no backend switch), laid out by :func:`fix_layout`.

    Without ``figsize`` and ``margins``: an empty figure that the plotting
    function it is handed as ``fig=`` sizes and lays out itself.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = FigureCanvasAgg(Figure(dpi=dpi)).figure
    return fig if figsize is None else fix_layout(fig, figsize, margins)


def grid(panel: tuple[float, float], shape: tuple[int, int], left: float, right: float, bottom: float,
         top: float, wgap: float = 0.0, hgap: float = 0.0) -> tuple[tuple[float, float], Margins]:
    """Figure size and margins of a ``shape`` (rows, columns) grid of ``panel`` (width, height) panels.

    Every length is in inches: the margins around the grid and the gaps
    between its panels (which hold the panels' labels) stay what they are
    whatever the number of panels. Returns ``(figsize, margins)`` for
    :func:`fix_layout` or :func:`agg_figure`.
    """
    (pw, ph), (rows, cols) = panel, shape
    figsize = (left + right + cols * pw + (cols - 1) * wgap, bottom + top + rows * ph + (rows - 1) * hgap)
    return figsize, Margins(left, right, bottom, top, wgap / pw, hgap / ph)


@functools.lru_cache(maxsize=1024)
def text_inches(text: str, fontsize: float = 10.0) -> tuple[float, float]:
    """Width and height (inches) of ``text`` in matplotlib's default font at ``fontsize`` points, lines included.

    Measured with the font's metrics (no figure, no renderer, no drawing);
    a line is 1.2 times the font size, matplotlib's spacing.
    """
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import text_to_path
    prop = FontProperties(size=fontsize)
    lines = text.split("\n")
    width = max(text_to_path.get_text_width_height_descent(line, prop, ismath=False)[0] for line in lines)
    return width / _POINTS, 1.2 * fontsize * len(lines) / _POINTS


def wrap(text: str, width: float, fontsize: float = 10.0) -> str:
    """``text`` broken at spaces into lines at most ``width`` inches wide; its own line breaks are kept
    (a word wider than ``width`` keeps a line of its own)."""
    out: list[str] = []
    for line in text.split("\n"):
        words = line.split(" ")
        out.append(words[0])
        for word in words[1:]:
            if text_inches(f"{out[-1]} {word}", fontsize)[0] <= width:
                out[-1] += f" {word}"
            else:
                out.append(word)
    return "\n".join(out)


def number_inches(value: float, fontsize: float = 10.0) -> float:
    """Width (inches) of ``value`` written as a tick label (``%g``, matplotlib's minus sign)."""
    return text_inches(f"{value:g}".replace("-", "\u2212"), fontsize)[0]


def tick_width(lo: float, hi: float, fontsize: float = 10.0) -> float:
    """Width (inches) of the widest tick label of an axis over [lo, hi] with (at most five, :func:`lighten`) round ticks."""
    from matplotlib.ticker import MaxNLocator
    slack = 1e-9 * abs(hi - lo)
    ticks = [t for t in MaxNLocator(5, steps=ROUND_STEPS).tick_values(lo, hi) if lo - slack <= t <= hi + slack]
    return max(number_inches(t, fontsize) for t in ticks or [lo, hi])


def title_lines(text: str, width: float) -> tuple[str, float]:
    """A figure title (12 pt) wrapped to ``width`` inches, and the inches it takes at the top (:func:`set_title`)."""
    text = wrap(text, width - 0.2, 12)
    return text, 0.08 + text_inches(text, 12)[1]


def set_title(fig, text: str) -> None:
    """``text`` as ``fig``'s title, 0.08 inches below its top edge whatever the figure's height."""
    fig.suptitle(text, y=1.0, va="top").set_transform(fig.transFigure + shift(fig, 0.0, -0.08))


def shift(fig, dx: float, dy: float):
    """A translation by (dx, dy) inches on ``fig``, to add to a transform."""
    from matplotlib.transforms import ScaledTranslation
    return ScaledTranslation(dx, dy, fig.dpi_scale_trans)


def lighten(fig, steps=None) -> None:
    """At most five automatic major ticks per axis and no minor ticks: most of a figure's cost is tick text.

    ``steps``: the tick steps allowed (:class:`matplotlib.ticker.MaxNLocator`'s;
    :data:`ROUND_STEPS` keeps the round ones of matplotlib's default ticks).
    """
    from matplotlib.ticker import AutoLocator, MaxNLocator
    for ax in fig.axes:
        ax.minorticks_off()
        for axis in (ax.xaxis, ax.yaxis):
            if type(axis.get_major_locator()) is AutoLocator:
                axis.set_major_locator(MaxNLocator(5, steps=steps))
