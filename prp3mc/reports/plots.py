"""Figures of study results (matplotlib, seaborn styling).

Every plotting function takes result objects and an ``ax=`` (a new pyplot
figure when None) and returns the Figure; the ``*_figure`` functions lay
several panels out on one figure and take ``fig=`` (an empty Figure to draw
into, sized to fit; a new pyplot figure when None). Nothing here switches the
matplotlib backend, so figures show inline in notebooks; reports draw on a
:class:`matplotlib.figure.Figure` of their own. Maps show µm and arcsec.
"""

from __future__ import annotations

import numpy as np

from ..units import DISPLAY

__all__ = ["shared_levels", "region_map", "worst_case_map", "montecarlo_map", "compare_maps_figure",
           "error_histogram", "histograms_figure", "sobol_ranking", "worst_case_shares", "ranking_figure"]

_LABEL = {"position": "position error", "phi": "|δφ|"}
_QUANTITY = {q: (label, DISPLAY[q][1], DISPLAY[q][0]) for q, label in _LABEL.items()}  # (label, unit, scale)


def _axes(ax, figsize=(5.0, 4.2)):
    """``ax``, or the axes of a new pyplot figure (pyplot imported only then)."""
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax


def _figure(fig, figsize):
    """``fig`` resized to ``figsize`` with a constrained layout, or a new pyplot figure of that size."""
    if fig is None:
        import matplotlib.pyplot as plt
        return plt.figure(figsize=figsize, layout="constrained")
    fig.set_size_inches(figsize)
    fig.set_layout_engine("constrained")
    return fig


def shared_levels(*arrays: np.ndarray, n: int = 12) -> np.ndarray:
    """Round contour levels spanning all ``arrays`` (one colour scale for several maps)."""
    from matplotlib.ticker import MaxNLocator
    lo = min(float(np.min(a)) for a in arrays)
    hi = max(float(np.max(a)) for a in arrays)
    if hi - lo < 1e-9 * max(abs(hi), 1.0):  # a constant field still gets a band around it
        lo, hi = lo - max(abs(lo), 1.0) * 0.01, hi + max(abs(hi), 1.0) * 0.01
    return MaxNLocator(n).tick_values(lo, hi)


def region_map(poses: np.ndarray, values: np.ndarray, *, ax=None, levels=None, cmap: str = "viridis",
               title: str = "", mark_extrema: bool = True, unit: str = ""):
    """Filled contour map of ``values`` (ny, nx) over grid ``poses`` (ny, nx, 3), extrema marked.

    Draws on ``ax`` (a new pyplot figure when None); returns the Figure holding it.
    """
    ax = _axes(ax)
    X, Y = poses[..., 0], poses[..., 1]
    levels = shared_levels(values) if levels is None else levels
    ax.contourf(X, Y, values, levels=levels, cmap=cmap, extend="neither")
    if np.ptp(values) > 1e-9 * max(abs(float(np.max(values))), 1.0):
        lines = ax.contour(X, Y, values, levels=levels, colors="k", linewidths=0.5, alpha=0.6)
        ax.clabel(lines, fmt="%g", fontsize=7)
    if mark_extrema:
        for fn, marker, word in ((np.argmax, "X", "max"), (np.argmin, "o", "min")):
            k = np.unravel_index(fn(values), values.shape)
            ax.plot(X[k], Y[k], marker=marker, color="white", mec="k", ms=8, ls="none", clip_on=False, zorder=5,
                    label=f"{word} {values[k]:.1f} {unit} at ({X[k]:g}, {Y[k]:g})")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=7, frameon=False, ncol=1)
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title=title, aspect="equal")
    return ax.figure


def worst_case_map(wc, quantity: str = "position", *, ax=None, levels=None, title: str = ""):
    """Contour map of the exact worst-case ``position`` error (µm) or ``phi`` error (arcsec)."""
    label, unit, f = _QUANTITY[quantity]
    return region_map(wc.poses, f * wc.value(quantity), ax=ax, levels=levels, title=title, unit=unit)


def montecarlo_map(mc, percentile: float = 99.73, quantity: str = "position", *, ax=None, levels=None,
                   title: str = ""):
    """Contour map of a Monte Carlo percentile of the position error (µm) or |δφ| (arcsec)."""
    label, unit, f = _QUANTITY[quantity]
    q = list(mc.percentiles).index(float(percentile))
    values = (mc.position_pct if quantity == "position" else mc.phi_pct)[..., q]
    return region_map(mc.poses, f * values, ax=ax, levels=levels, title=title, cmap="magma", unit=unit)


def compare_maps_figure(results, kind: str = "worstcase", quantity: str = "position",
                        percentile: float = 99.73, *, fig=None):
    """Maps of several configurations side by side on ONE colour scale.

    Parameters
    ----------
    results : sequence of ConfigurationResult
    kind : ``"worstcase"`` or ``"montecarlo"``
    quantity : ``"position"`` or ``"phi"``
    percentile : float
        Monte Carlo percentile shown (``kind="montecarlo"``).
    fig : Figure, optional
        An empty figure to draw into; a new pyplot figure when None.

    Returns
    -------
    Figure
    """
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm
    label, unit, f = _QUANTITY[quantity]
    if kind == "worstcase":
        values = [f * r.worst_case.value(quantity) for r in results]
        what, cmap = f"exact worst-case {label}", "viridis"
    else:
        q = list(results[0].montecarlo.percentiles).index(float(percentile))
        values = [f * (r.montecarlo.position_pct if quantity == "position" else r.montecarlo.phi_pct)[..., q]
                  for r in results]
        what, cmap = f"Monte Carlo p{percentile:g} of the {label}", "magma"
    levels = shared_levels(*values, n=20)
    fig = _figure(fig, (5.2 * len(results) + 1.2, 5.4))
    axes = fig.subplots(1, len(results), squeeze=False)
    for ax, r in zip(axes[0], results):
        if kind == "worstcase":
            worst_case_map(r.worst_case, quantity, ax=ax, levels=levels, title=r.name)
        else:
            montecarlo_map(r.montecarlo, percentile, quantity, ax=ax, levels=levels, title=r.name)
    sm = ScalarMappable(norm=BoundaryNorm(levels, matplotlib.colormaps[cmap].N), cmap=cmap)
    fig.colorbar(sm, ax=axes[0].tolist(), label=f"{label} ({unit})", shrink=0.85)
    fig.suptitle(f"{what}, one colour scale")
    return fig


def error_histogram(samples, index: int, quantity: str = "position", *, ax=None, bins: int = 80,
                    percentile: float = 99.73, label: str | None = None, color=None):
    """Histogram of the Monte Carlo error at one pose with its exact worst case marked.

    Parameters
    ----------
    samples : PoseSamples
    index : int
        Which of its poses.
    quantity : ``"position"`` (µm) or ``"phi"`` (|δφ|, arcsec)
    percentile : float
        Also marked (dotted).

    Returns
    -------
    Figure
        The figure holding ``ax`` (a new pyplot figure when ``ax`` is None).
    """
    import seaborn as sns
    ax = _axes(ax)
    name, unit, f = _QUANTITY[quantity]
    values = f * (samples.position_mm if quantity == "position" else samples.phi_deg)[index]
    worst = f * (samples.worst_position_mm if quantity == "position" else samples.worst_phi_deg)[index]
    label = samples.labels[index] if label is None else label
    sns.histplot(x=values, bins=bins, stat="density", element="step", fill=True, alpha=0.25, ax=ax,
                 label=label, color=color)
    color = ax.get_lines()[-1].get_color() if ax.get_lines() and color is None else color
    p = float(np.percentile(values, percentile))
    ax.axvline(worst, ls="--", lw=1.5, color=color, label=f"worst case {worst:.1f} {unit}")
    ax.axvline(p, ls=":", lw=1.2, color=color, label=f"p{percentile:g} {p:.1f} {unit}")
    ax.set(xlabel=f"{name} ({unit})", ylabel="density")
    ax.legend(fontsize=7)
    return ax.figure


def histograms_figure(results, quantity: str = "position", percentile: float = 99.73, *, fig=None):
    """Error histograms at each configuration's chosen poses, worst case marked; one row per configuration.

    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    import matplotlib
    n_cols = max(len(r.samples.labels) for r in results)
    fig = _figure(fig, (4.2 * n_cols, 3.2 * len(results)))
    axes = fig.subplots(len(results), n_cols, squeeze=False, sharex=True)
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for row, r in zip(axes, results):
        s = r.samples
        for k, ax in enumerate(row):
            if k >= len(s.labels):
                ax.set_visible(False)
                continue
            error_histogram(s, k, quantity, ax=ax, percentile=percentile, color=colors[k % len(colors)])
            x, y, phi = s.poses[k]
            ax.set_title(f"{r.name}: {s.labels[k]}\n(x={x:g}, y={y:g} mm, φ={phi:g}°)", fontsize=9)
    fig.suptitle(f"Monte Carlo {_QUANTITY[quantity][0]} at chosen poses ({results[0].samples.n_samples} samples)")
    return fig


def sobol_ranking(frame, *, ax=None, title: str = ""):
    """First-order and total Sobol indices with their 95 % intervals, ranked by ST.

    Parameters
    ----------
    frame : DataFrame
        :func:`prp3mc.uncertainty.ranking.ranking` (columns name, kind, S1, S1_conf, ST, ST_conf).

    Returns
    -------
    Figure
        The figure holding ``ax`` (a new pyplot figure when ``ax`` is None).
    """
    ax = _axes(ax, figsize=(5.0, 0.32 * len(frame) + 1.2))
    y = np.arange(len(frame))
    h = 0.38
    ax.barh(y - h / 2, frame["ST"], height=h, xerr=frame["ST_conf"], label="total ST", color="#4c72b0",
            error_kw={"lw": 1, "capsize": 2})
    ax.barh(y + h / 2, frame["S1"], height=h, xerr=frame["S1_conf"], label="first order S1", color="#dd8452",
            error_kw={"lw": 1, "capsize": 2})
    labels = [f"{n} (group)" if k == "group" else n for n, k in zip(frame["name"], frame["kind"])]
    ax.set_yticks(y, labels)
    ax.invert_yaxis()
    ax.set(xlabel="Sobol index (95 % CI)", title=title)
    ax.legend(fontsize=7, loc="lower right")
    return ax.figure


def worst_case_shares(frame, *, ax=None, title: str = "worst-case contribution"):
    """Each input's or group's share (%) of the worst case, in the order of ``frame``; returns the Figure."""
    ax = _axes(ax, figsize=(3.5, 0.32 * len(frame) + 1.2))
    y = np.arange(len(frame))
    ax.barh(y, 100 * frame["worst_case_share"], color="#55a868")
    ax.set_yticks(y, frame["name"])
    ax.invert_yaxis()
    ax.set(xlabel="share of the worst case (%)", title=title)
    return ax.figure


def ranking_figure(frame, title: str = "", *, fig=None):
    """Sobol ranking with CIs next to the worst-case shares, rows aligned.

    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    fig = _figure(fig, (10, 0.34 * len(frame) + 1.6))
    a, b = fig.subplots(1, 2, width_ratios=(3, 2))
    sobol_ranking(frame, ax=a, title="Sobol indices")
    worst_case_shares(frame, ax=b)
    fig.suptitle(title)
    return fig
