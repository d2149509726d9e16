"""Figures of a design sweep: each figure of merit against each swept parameter.

The input is :func:`prp3mc.study.sweep.design_frame` (one row per
configuration and figure of merit). :func:`merit_plot` draws one merit
against one parameter on an ``ax=``; :func:`design_space_figure` lays out
every merit (rows) against every parameter (columns) on one ``fig=``, so
"which layout?" is one look: every configuration is a dot, the line joins the
best value reachable at each value of the parameter (the other parameters
chosen at their best), the best configurations are marked and named in every
panel. Shown in µm and arcsec. Nothing here switches the matplotlib backend.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..units import DISPLAY
from .canvas import ROUND_STEPS, lighten, text_width
from .plots import _axes, _figure

__all__ = ["merits", "merit_plot", "design_space_figure"]

_MERIT_LABEL = {"worstcase": "exact worst case", "montecarlo": "Monte Carlo", "sobol": "Sobol"}
_BEST_STYLE = ({"marker": "*", "ms": 15, "color": "#c44e52"}, {"marker": "D", "ms": 8, "color": "#dd8452"},
               {"marker": "s", "ms": 8, "color": "#8172b3"})


def merits(frame: pd.DataFrame) -> list[tuple[str, str, str]]:
    """The figures of merit of a design frame, as ``(analysis, output, statistic)`` in table order."""
    keys = frame[["analysis", "output", "statistic"]].drop_duplicates()
    return [tuple(row) for row in keys.itertuples(index=False)]


def _merit_label(analysis: str, output: str, statistic: str) -> tuple[str, float]:
    """Axis label and display factor of a merit."""
    if statistic == "ST_top":
        return f"largest Sobol ST, {'|δφ|' if output == 'phi' else output}", 1.0
    factor, unit = DISPLAY[output]
    what = "position error" if output == "position" else "|δφ|"
    stat = "" if statistic == "worst_case" else f" {statistic}"
    return f"{_MERIT_LABEL[analysis]}{stat} {what},\nmax over region ({unit})", factor


def _positions(values: pd.Series) -> tuple[np.ndarray, list | None]:
    """x positions of parameter values: the values if numeric, else category indices and their labels."""
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return values.to_numpy(dtype=float), None
    labels = sorted({repr(v) for v in values}, key=lambda s: [repr(v) for v in values].index(s))
    index = {s: k for k, s in enumerate(labels)}
    return np.array([index[repr(v)] for v in values], dtype=float), labels


def merit_plot(frame: pd.DataFrame, parameter: str, merit: tuple[str, str, str], *, best: list | None = None,
               ax=None, ylabel: bool = True, legend: bool = False):
    """One figure of merit against one swept parameter, every configuration a dot.

    Parameters
    ----------
    frame : DataFrame
        :func:`prp3mc.study.sweep.design_frame`.
    parameter : str
        A sweep key as written (a column of ``frame``).
    merit : (analysis, output, statistic)
    best : list of str, optional
        Configurations to mark (at most three, best first).
    ax : matplotlib Axes, optional
    ylabel : bool
        Label the y axis.
    legend : bool or "outside"
        Draw the legend of the marked configurations: where it covers the
        fewest points (True), or right of the axes ("outside").

    Returns
    -------
    matplotlib.figure.Figure
    """
    ax = _axes(ax)
    rows, y = _merit_values(frame, merit)
    label = _merit_label(*merit)[0]
    x, ticks = _positions(rows[parameter])
    if merit[2] == "ST_top":  # colour the dots by the input with the largest ST
        for k, name in enumerate(sorted(set(rows["input"]))):
            sel = (rows["input"] == name).to_numpy()
            ax.plot(x[sel], y[sel], "o", color=f"C{k}", ms=5, alpha=0.75, ls="none", label=f"top: {name}")
    else:
        ax.plot(x, y, "o", color="0.55", ms=5, alpha=0.75, ls="none")
        order = np.unique(x)
        envelope = [y[x == v].min() for v in order]
        ax.plot(order, envelope, "-", color="0.25", lw=1.2, label="best at this value")
    for style, name in zip(_BEST_STYLE, best or []):
        sel = (rows["configuration"] == name).to_numpy()
        ax.plot(x[sel], y[sel], ls="none", mec="k", zorder=5, clip_on=False, label=name, **style)
    if ticks is not None:
        ax.set_xticks(range(len(ticks)), ticks, rotation=30, fontsize=7)
    ax.set_xlabel(parameter)
    if ylabel:
        ax.set_ylabel(label, fontsize=8)
    ax.grid(alpha=0.3)
    if legend == "outside":
        ax.legend(fontsize=7, frameon=False, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    elif legend:
        ax.legend(fontsize=7, frameon=False, loc="best")
    return ax.figure


def design_space_figure(frame: pd.DataFrame, *, best: list | None = None, fig=None):
    """Every figure of merit (rows) against every swept parameter (columns) on one figure.

    Parameters
    ----------
    frame : DataFrame
        :func:`prp3mc.study.sweep.design_frame`.
    best : list of str, optional
        Configurations to mark in every panel (at most three, best first).
    fig : matplotlib Figure, optional
        An empty figure to draw into (resized); a new pyplot figure when None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fixed = {"configuration", "analysis", "output", "statistic", "value", "unit", "input"}
    parameters = [c for c in frame.columns if c not in fixed]
    rows = merits(frame)
    # a panel of 2.6 x 1.9 inches, its labels around it (categories slanted at 30° below) and the legends right
    categories = [t for p in parameters for t in (_positions(frame[p])[1] or [])]
    below = 0.55 + (text_width("\n".join(categories), 7) / 2 if categories else 0.0)
    fig = _figure(fig, (len(parameters) * 2.85 + 1.3 + _legend_room(frame, best), len(rows) * (1.9 + below) + 0.2))
    axes = np.atleast_2d(fig.subplots(len(rows), len(parameters), squeeze=False, sharey="row"))
    for i, merit in enumerate(rows):
        for j, parameter in enumerate(parameters):
            merit_plot(frame, parameter, merit, best=best, ax=axes[i, j], ylabel=j == 0,
                       legend="outside" if j == len(parameters) - 1 and (i == 0 or merit[2] == "ST_top") else False)
    lighten(fig, ROUND_STEPS)
    return fig


def _legend_room(frame: pd.DataFrame, best) -> float:
    """Width (inches) of the legends right of the last column: marker, gap and the longest label at 7 pt."""
    labels = ["best at this value", *(best or []), *(f"top: {v}" for v in frame.get("input", pd.Series()).dropna())]
    return 0.55 + text_width("\n".join(map(str, labels)), 7)


def _merit_values(frame: pd.DataFrame, merit) -> tuple[pd.DataFrame, np.ndarray]:
    """The rows of ``frame`` of figure of merit ``merit`` (analysis, output, statistic) and their values as plotted."""
    rows = frame[(frame["analysis"] == merit[0]) & (frame["output"] == merit[1])
                 & (frame["statistic"] == merit[2])].reset_index(drop=True)
    return rows, _merit_label(*merit)[1] * rows["value"].to_numpy(dtype=float)

