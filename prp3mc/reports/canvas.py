"""The figure every report draws on: its own Agg canvas, matplotlib's constrained layout, few ticks.

Matplotlib places the panels, labels, legends and colour bars
(``layout="constrained"``); what is left here is choosing a figure's size
from what it holds (:func:`text_width`, :func:`wrap`: estimates by character
count, generous, for sizing only) and the ticks (:func:`lighten`).
"""

from __future__ import annotations

import textwrap

__all__ = ["agg_figure", "lighten", "ROUND_STEPS", "text_width", "wrap"]

#: Tick steps of matplotlib's default ticks (1, 2, 2.5, 5 times a power of ten), for :func:`lighten`.
ROUND_STEPS = (1, 2, 2.5, 5, 10)
#: Width of a character of matplotlib's default font (DejaVu Sans), ems: its widest lower-case letters (m, w)
#: are wider, its average narrower; enough for the widths that size a figure.
_EM = 0.6


def agg_figure(figsize: tuple[float, float] | None = None, *, dpi: float = 100.0, layout: str = "constrained"):
    """A Figure of ``figsize`` inches on its own Agg canvas (no pyplot, no backend switch), laid out by ``layout``.

    Without ``figsize``: the plotting function it is handed as ``fig=`` sizes it.
    ``layout="compressed"`` for a single map (fixed aspect): constrained
    layout places such an axes as if it filled its cell, and its title can
    end a pixel or two beyond the figure's edge.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    return FigureCanvasAgg(Figure(figsize=figsize, dpi=dpi, layout=layout)).figure


def text_width(text: str, fontsize: float = 10.0) -> float:
    """Width (inches) ``text`` takes at most at ``fontsize`` points, its longest line by character count."""
    return max(len(line) for line in str(text).split("\n")) * _EM * fontsize / 72.0


def wrap(text: str, width: float, fontsize: float = 10.0) -> str:
    """``text`` broken at spaces into lines at most ``width`` inches wide (:func:`text_width`); its own line
    breaks are kept, and a word longer than a line keeps a line of its own."""
    chars = max(1, int(width * 72.0 / (_EM * fontsize)))
    return "\n".join(textwrap.fill(line, chars, break_long_words=False, break_on_hyphens=False) or line
                     for line in text.split("\n"))


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
