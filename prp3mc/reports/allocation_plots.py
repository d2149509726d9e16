"""Figures of a tolerance allocation: the cost-accuracy Pareto front and the binding poses.

:func:`allocation_front_plot` takes the tidy front of
:func:`prp3mc.allocation.optimum.allocation_front`;
:func:`allocation_map` the :class:`~prp3mc.allocation.optimum.AllocationResult`
of a gridded region. Both take an ``ax=`` (a new figure when None) and
return the Figure; pyplot is imported lazily and the backend is never
switched. Shows µm and arcsec.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..units import DISPLAY
from .canvas import text_width, wrap
from .plots import legend_below, region_map

__all__ = ["allocation_front_plot", "allocation_map", "class_changes", "labels_points", "MAX_LABELLED"]

#: Points of a front labelled with their class changes at most (beyond, the labels would pile up).
MAX_LABELLED = 15


def labels_points(front: pd.DataFrame, output: str = "position") -> bool:
    """Whether :func:`allocation_front_plot` labels the front's points by default (at most :data:`MAX_LABELLED`)."""
    return int((front["output"] == output).sum()) <= MAX_LABELLED


def class_changes(previous: pd.Series | None, current: pd.Series) -> str:
    """The classes that changed from one front point to the next, as ``input→class`` words."""
    if previous is None:
        return "cheapest"
    changed = [f"{name}→{cls}" for name, cls in current.items() if previous[name] != cls]
    return ", ".join(changed[:3]) + (f" +{len(changed) - 3}" if len(changed) > 3 else "")


def allocation_front_plot(front: pd.DataFrame, output: str = "position", *, spec: float | None = None,
                          chosen_cost: float | None = None, annotate: bool | None = None, ax=None):
    """Step plot of the least cost of every reachable worst case of ``output``.

    Parameters
    ----------
    front : DataFrame
        The tidy front (``point``, ``cost``, ``output``, ``value``, one column per input).
    output : {"position", "phi"}
    spec : float, optional
        The spec, in display units (µm or arcsec), drawn as a horizontal line.
    chosen_cost : float, optional
        Mark the front point of this cost (the allocation's choice).
    annotate : bool, optional
        Label each point with the classes that changed from the previous one
        (default: when the front has at most :data:`MAX_LABELLED` points, :func:`labels_points`).
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    if ax is None:
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6.4, 4.4), layout="constrained")
    fig = ax.figure
    scale, unit = DISPLAY[output]
    rows = front[front["output"] == output].sort_values("point")
    inputs = [c for c in front.columns if c not in ("point", "cost", "output", "statistic", "value", "unit")]
    y = scale * rows["value"].to_numpy()
    ax.step(rows["cost"], y, where="post", color="0.6", lw=1)
    ax.plot(rows["cost"], y, "o", color="C0", ms=4, label="Pareto-optimal choices")
    if annotate or (annotate is None and labels_points(front, output)):
        previous, labels = None, []
        for (_, row), value in zip(rows.iterrows(), y):
            labels.append(class_changes(previous, row[inputs]))
            ax.annotate(labels[-1], (row["cost"], value), xytext=(4, 3), textcoords="offset points", fontsize=6,
                        color="0.3")
            previous = row[inputs]
        _room_right(ax, rows["cost"].to_numpy(dtype=float), labels, 6)
    if spec is not None:
        ax.axhline(spec, color="C3", ls="--", lw=1, label=f"spec {spec:g} {unit}")
    if chosen_cost is not None:
        hit = rows[abs(rows["cost"] - chosen_cost) <= 1e-9 * max(1.0, abs(chosen_cost))]
        if len(hit):
            ax.plot(hit["cost"], scale * hit["value"], "*", color="C3", ms=12, label="least cost within spec")
    label = "position error" if output == "position" else "|δφ|"
    ax.set_xlabel("total cost")
    ax.set_ylabel(f"worst-case {label} over the region ({unit})")
    ax.set_title("What each step of cost buys", fontsize=10)
    ax.legend(fontsize=8, frameon=False)
    return fig


def _room_right(ax, x: np.ndarray, labels: list, fontsize: float) -> None:
    """Widen ``ax``'s x range so that ``labels`` written right of the points ``x`` end inside the axes.

    The axes' width (inches) is taken where the figure's subplot parameters put it (its layout
    then narrows it by its labels' room); a label wider than 0.9 of it is left to stick out.
    """
    width = ax.get_position().width * ax.figure.get_figwidth()
    need = np.array([text_width(t, fontsize) + 6 / 72 for t in labels]) / width     # fractions of the axes
    margin = 0.05 * (np.ptp(x) or 1.0)                                                  # matplotlib's own
    lo, hi = x.min() - margin, x.max() + margin
    fits = need < 0.9
    if fits.any():
        hi = max(hi, float(np.max((x[fits] - need[fits] * lo) / (1 - need[fits]))))
    ax.set_xlim(lo, hi)


def allocation_map(result, shape: tuple, *, ax=None, title: str = ""):
    """Map of the chosen classes' worst case over the region, the binding poses and the spec marked.

    Shows the position error, or ``|δφ|`` when the orientation spec binds; the
    spec's level is drawn as a red contour when it is a worst-case bound.

    Parameters
    ----------
    result : AllocationResult
        Of a gridded region: ``result.poses`` holds ``ny * nx`` poses in grid order.
    shape : (ny, nx)
    ax : matplotlib Axes, optional
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    output = "phi" if result.binding == "phi" else "position"
    scale, unit = DISPLAY[output]
    values = scale * (result.phi_deg if output == "phi" else result.position_mm).reshape(shape)
    poses = result.poses.reshape(*shape, 3)
    fig = region_map(poses, values, ax=ax, mark_extrema=False, unit=unit, title=title)
    ax = fig.axes[0] if ax is None else ax
    spec = {"position": None if result.spec["percentile"] is not None else result.spec["position_mm"],
            "phi": result.spec["phi_deg"]}[output]
    reached = spec is not None and values.min() < scale * spec < values.max()
    if reached:
        ax.contour(poses[..., 0], poses[..., 1], values, levels=[scale * spec], colors="C3", linewidths=1.5,
                   linestyles="--")
    binding = np.asarray(result.binding_poses)
    what = {"position": "worst-case position error", "phi": "worst-case |δφ|",
            "percentile": "Monte Carlo percentile upper bound"}[result.binding]
    ax.plot(binding[:, 0], binding[:, 1], "*", color="C3", mec="k", ms=11, ls="none", clip_on=False, zorder=5,
            label=f"binding: {what} ({len(binding)} pose{'s' if len(binding) != 1 else ''})")
    if reached:
        ax.plot([], [], color="C3", ls="--", lw=1.5, label=f"spec {scale * spec:g} {unit}")
    legend_below(ax)
    label = "position error" if output == "position" else "|δφ|"
    width = ax.get_position().width * fig.get_figwidth() + 0.6
    ax.set_title(wrap(f"{title + ': ' if title else ''}worst-case {label} of the chosen classes ({unit})", width, 10),
                 fontsize=10)
    return fig
