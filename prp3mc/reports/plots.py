"""Figures of study results (matplotlib).

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

__all__ = ["is_constant", "shared_levels", "region_map", "worst_case_map", "montecarlo_map", "compare_maps_figure",
           "error_histogram", "histograms_figure", "ecdf_steps", "error_ecdf", "ecdf_figure", "sobol_ranking",
           "worst_case_shares", "ranking_figure"]

_LABEL = {"position": "position error", "phi": "|δφ|"}
_QUANTITY = {q: (label, DISPLAY[q][1], DISPLAY[q][0]) for q, label in _LABEL.items()}  # (label, unit, scale)
#: A field whose range is below this fraction of its magnitude is drawn as a constant.
CONSTANT_RTOL = 1e-9
#: Maps share one colour scale only when every varying panel spans at least this fraction of it.
MIN_SCALE_FRACTION = 0.25
#: Steps an ECDF is drawn with at most (:func:`ecdf_steps`): 1 / ECDF_STEPS is below a pixel of a report figure.
ECDF_STEPS = 2048


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


def is_constant(values: np.ndarray, rtol: float = CONSTANT_RTOL) -> bool:
    """Whether a field is constant up to round-off: its range is at most ``rtol`` of its magnitude."""
    v = np.asarray(values, dtype=float)
    return float(np.ptp(v)) <= rtol * max(float(np.max(np.abs(v))), np.finfo(float).tiny)


def shared_levels(*arrays: np.ndarray, n: int = 12) -> np.ndarray:
    """Round contour levels spanning all ``arrays`` (one colour scale for several maps)."""
    from matplotlib.ticker import MaxNLocator
    lo = min(float(np.min(a)) for a in arrays)
    hi = max(float(np.max(a)) for a in arrays)
    if is_constant(np.array([lo, hi])):  # a constant field still gets a band around it
        lo, hi = lo - max(abs(lo), 1.0) * 0.01, hi + max(abs(hi), 1.0) * 0.01
    return MaxNLocator(n).tick_values(lo, hi)


def region_map(poses: np.ndarray, values: np.ndarray, *, ax=None, levels=None, cmap: str = "viridis",
               title: str = "", mark_extrema: bool = True, unit: str = ""):
    """Filled contour map of ``values`` (ny, nx) over grid ``poses`` (ny, nx, 3), extrema marked.

    A constant field (:func:`is_constant`) is filled in one colour and
    labelled "constant: value unit", with neither contour lines nor extrema.
    Draws on ``ax`` (a new pyplot figure when None); returns the Figure holding it.
    """
    ax = _axes(ax)
    X, Y = poses[..., 0], poses[..., 1]
    levels = shared_levels(values) if levels is None else levels
    ax.contourf(X, Y, values, levels=levels, cmap=cmap, extend="neither")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title=title, aspect="equal")
    if is_constant(values):
        ax.text(0.5, 0.5, f"constant: {float(np.mean(values)):.4g} {unit}".rstrip(), transform=ax.transAxes,
                ha="center", va="center", fontsize=11, bbox={"boxstyle": "round", "fc": "white", "ec": "0.6"})
        return ax.figure
    lines = ax.contour(X, Y, values, levels=levels, colors="k", linewidths=0.5, alpha=0.6)
    ax.clabel(lines, lines.levels[::max(1, len(lines.levels) // 8)], fmt="%g", fontsize=7)
    if mark_extrema:
        for fn, marker, word in ((np.argmax, "X", "max"), (np.argmin, "o", "min")):
            k = np.unravel_index(fn(values), values.shape)
            ax.plot(X[k], Y[k], marker=marker, color="white", mec="k", ms=8, ls="none", clip_on=False, zorder=5,
                    label=f"{word} {values[k]:.4g} {unit} at ({X[k]:.4g}, {Y[k]:.4g})")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=7, frameon=False, ncol=1)
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


def _share_scale(values, share_scale) -> bool:
    """Whether maps of ``values`` go on one colour scale (``"auto"``: when no varying panel gets too little of it)."""
    if share_scale != "auto":
        return bool(share_scale)
    span = max(float(np.max(v)) for v in values) - min(float(np.min(v)) for v in values)
    return all(np.ptp(v) >= MIN_SCALE_FRACTION * span for v in values if not is_constant(v))


def compare_maps_figure(results, kind: str = "worstcase", quantity: str = "position",
                        percentile: float = 99.73, *, fig=None, share_scale="auto"):
    """Maps of several configurations side by side, on one colour scale where that helps.

    Parameters
    ----------
    results : sequence of ConfigurationResult
    kind : ``"worstcase"`` or ``"montecarlo"``
    quantity : ``"position"`` or ``"phi"``
    percentile : float
        Monte Carlo percentile shown (``kind="montecarlo"``).
    fig : Figure, optional
        An empty figure to draw into; a new pyplot figure when None.
    share_scale : ``"auto"``, True or False
        One colour scale for all panels, or one per panel. ``"auto"`` shares
        it unless a varying panel would span less than
        :data:`MIN_SCALE_FRACTION` of it (it would show in one or two
        colours); the title says which. Constant panels are labelled so.

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
    shared = _share_scale(values, share_scale)
    constant = [is_constant(v) for v in values]
    fig = _figure(fig, ((5.2 if shared else 5.8) * len(results) + 1.2, 5.4))
    axes = fig.subplots(1, len(results), squeeze=False)[0]
    common = shared_levels(*values, n=20)
    for ax, r, v, flat in zip(axes, results, values, constant):
        levels = common if shared else shared_levels(v, n=20)
        if kind == "worstcase":
            worst_case_map(r.worst_case, quantity, ax=ax, levels=levels, title=r.name)
        else:
            montecarlo_map(r.montecarlo, percentile, quantity, ax=ax, levels=levels, title=r.name)
        if not shared and not flat:
            sm = ScalarMappable(norm=BoundaryNorm(levels, matplotlib.colormaps[cmap].N), cmap=cmap)
            fig.colorbar(sm, ax=ax, label=f"{label} ({unit})", shrink=0.85)
    if all(constant):
        fig.suptitle(f"{what}: constant over each region")
    elif shared:
        sm = ScalarMappable(norm=BoundaryNorm(common, matplotlib.colormaps[cmap].N), cmap=cmap)
        fig.colorbar(sm, ax=axes.tolist(), label=f"{label} ({unit})", shrink=0.85)
        fig.suptitle(f"{what}, one colour scale")
    else:
        fig.suptitle(f"{what}, each panel on its own colour scale (their ranges differ too much to share one)")
    return fig


def _at_pose(samples, index: int, quantity: str):
    """(label, unit, Monte Carlo errors (n,), exact worst case) of ``quantity`` at pose ``index``, in µm or arcsec."""
    name, unit, f = _QUANTITY[quantity]
    values = f * (samples.position_mm if quantity == "position" else samples.phi_deg)[index]
    worst = f * (samples.worst_position_mm if quantity == "position" else samples.worst_phi_deg)[index]
    return name, unit, values, float(worst)


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
    import matplotlib
    from matplotlib.colors import to_rgba
    ax = _axes(ax)
    name, unit, values, worst = _at_pose(samples, index, quantity)
    label = samples.labels[index] if label is None else label
    density, edges = np.histogram(values, bins=bins, density=True)
    steps = ax.stairs(density, edges, fill=True, label=label, **({} if color is None else {"color": color}))
    color = steps.get_facecolor()                   # the axes' next colour when none is given
    steps.set(facecolor=to_rgba(color, 0.25), edgecolor=to_rgba(color, 1.0),
              linewidth=matplotlib.rcParams["patch.linewidth"])
    p = float(np.percentile(values, percentile))
    ax.axvline(worst, ls="--", lw=1.5, color=color, label=f"worst case {worst:.4g} {unit}")
    ax.axvline(p, ls=":", lw=1.2, color=color, label=f"p{percentile:g} {p:.4g} {unit}")
    ax.set_ylabel("density")
    shown = any(t.get_visible() for t in ax.get_xticklabels())     # hidden inside a column of shared x axes
    ax.set_xlabel(f"{name} ({unit})", visible=shown)
    ax.legend(fontsize=7)
    return ax.figure


def _pose_grid(results, fig, draw, title: str, panel=(4.2, 3.2)):
    """One row per configuration, one panel per chosen pose: ``draw(samples, k, ax, color)`` fills each."""
    import matplotlib
    n_cols = max(len(r.samples.labels) for r in results)
    fig = _figure(fig, (panel[0] * n_cols, panel[1] * len(results)))
    axes = fig.subplots(len(results), n_cols, squeeze=False, sharex=True)
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for row, r in zip(axes, results):
        s = r.samples
        for k, ax in enumerate(row):
            if k >= len(s.labels):
                ax.set_visible(False)
                continue
            draw(s, k, ax, colors[k % len(colors)])
            x, y, phi = s.poses[k]
            ax.set_title(f"{r.name}: {s.labels[k]}\n(x={x:.4g}, y={y:.4g} mm, φ={phi:.4g}°)", fontsize=9)
    fig.suptitle(f"{title} ({results[0].samples.n_samples} samples)")
    return fig


def histograms_figure(results, quantity: str = "position", percentile: float = 99.73, *, fig=None):
    """Error histograms at each configuration's chosen poses, worst case marked; one row per configuration.

    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    def draw(s, k, ax, color):
        error_histogram(s, k, quantity, ax=ax, percentile=percentile, color=color)
    return _pose_grid(results, fig, draw, f"Monte Carlo {_QUANTITY[quantity][0]} at chosen poses")


def ecdf_steps(values: np.ndarray, max_steps: int = ECDF_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Order statistics of ``values`` (n,) and weights whose ECDF is theirs, with at most ``max_steps`` steps.

    Returns ``(x, weights)`` for ``Axes.ecdf(x, weights=weights)``: all
    values with unit weights when n <= ``max_steps``; else the minimum and
    about ``max_steps`` evenly spaced order statistics x_(k) (the maximum
    included), each weighted by the number of samples since the previous
    one. The drawn ECDF equals the sample's at every kept x_(k), (k + 1) / n,
    and lies within 1 / ``max_steps`` of it in between: below a pixel of a
    report figure, at a fraction of the cost of drawing n steps.
    """
    values = np.asarray(values, dtype=float).ravel()
    n = values.size
    if n <= max_steps:
        return values, np.ones(n)
    keep = np.unique(np.round(np.linspace(0, n - 1, max_steps + 1)).astype(np.intp))   # 0 and n - 1 included
    x = np.sort(values)[keep]
    return x, np.diff(keep, prepend=-1).astype(float)


def error_ecdf(samples, index: int, quantity: str = "position", *, ax=None, percentile: float = 99.73,
               label: str | None = None, color=None, max_steps: int = ECDF_STEPS):
    """Empirical CDF of the Monte Carlo error at one pose, its percentile (dot) and exact worst case (dashed).

    Parameters as :func:`error_histogram`; the y axis is the fraction of
    assemblies whose error is at most x. ``max_steps``: steps drawn at most
    (:func:`ecdf_steps`; exact below that many samples). Returns the Figure holding ``ax``.
    """
    ax = _axes(ax)
    name, unit, values, worst = _at_pose(samples, index, quantity)
    x, weights = ecdf_steps(values, max_steps)
    line = ax.ecdf(x, weights=weights, color=color, label=samples.labels[index] if label is None else label)
    color = line.get_color()
    p = float(np.percentile(values, percentile))
    ax.plot([p], [percentile / 100], marker="o", ms=4, color=color, ls="none",
            label=f"p{percentile:g} {p:.4g} {unit}")
    ax.axvline(worst, ls="--", lw=1.5, color=color, label=f"worst case {worst:.4g} {unit}")
    ax.axhline(percentile / 100, ls=":", lw=0.8, color="0.5")
    ax.set(xlabel=f"{name} ({unit})", ylabel="fraction of assemblies at most x", ylim=(0, 1.02))
    ax.legend(fontsize=7, loc="lower right")
    return ax.figure


def ecdf_figure(results, quantity: str = "position", percentile: float = 99.73, *, fig=None):
    """ECDFs of the error at each configuration's chosen poses, worst case dashed; one row per configuration.

    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    def draw(s, k, ax, color):
        error_ecdf(s, k, quantity, ax=ax, percentile=percentile, color=color)
    return _pose_grid(results, fig, draw, f"ECDF of the {_QUANTITY[quantity][0]} at chosen poses, "
                      "exact worst case dashed")


def ranking_basis(frame) -> tuple[str, str]:
    """Where a ranking frame's indices and worst-case shares are taken, and its share column.

    Returns ``(basis, column)``: for a region, ``"mean over the N poses"`` and
    ``worst_case_share_mean`` (both Sobol indices and shares averaged over
    the same poses); for one pose, ``"at (x, y, φ)"`` and ``worst_case_share``.
    """
    if "worst_case_share_mean" in frame:
        return f"mean over the {frame.attrs.get('n_poses', '')} poses".replace("  ", " "), "worst_case_share_mean"
    x, y, phi = frame.attrs.get("pose", (np.nan,) * 3)
    return f"at (x={x:.4g} mm, y={y:.4g} mm, φ={phi:.4g}°)", "worst_case_share"


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
    frame = frame.sort_values("ST", ascending=False, kind="stable")
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


def worst_case_shares(frame, *, ax=None, title: str = "share of the exact worst case", column: str | None = None):
    """Each input's or group's share (%) of the worst case, ranked by that share; returns the Figure.

    ``column``: the share column of ``frame`` (default: :func:`ranking_basis`'s).
    Names without a share of their own (rho_i, zeta_i: their clearance term
    is counted in clearance_i) are listed under the bars, not drawn.
    """
    import textwrap
    column = ranking_basis(frame)[1] if column is None else column
    undefined = frame[frame[column].isna()]["name"].tolist()
    frame = frame.dropna(subset=[column]).sort_values(column, ascending=False, kind="stable")
    ax = _axes(ax, figsize=(3.5, 0.32 * len(frame) + 1.2))
    y = np.arange(len(frame))
    ax.barh(y, 100 * frame[column], color="#55a868")
    ax.set_yticks(y, [f"{n} (group)" if k == "group" else n for n, k in zip(frame["name"], frame["kind"])])
    ax.invert_yaxis()
    xlabel = "share of the worst case (%)"
    if undefined:
        xlabel += "\n" + textwrap.fill(f"no share of their own (counted in their group): {', '.join(undefined)}",
                                        48)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_title(title)
    return ax.figure


def ranking_figure(frame, title: str = "", *, fig=None):
    """Sobol ranking with CIs next to the worst-case shares, each ranked in its own order, on one basis.

    Both panels are taken on the same basis (:func:`ranking_basis`: the mean
    over the poses of a region, or one pose) and say which.
    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    basis, column = ranking_basis(frame)
    fig = _figure(fig, (10, 0.34 * len(frame) + 1.9))
    a, b = fig.subplots(1, 2, width_ratios=(3, 2))
    sobol_ranking(frame, ax=a, title=f"Sobol indices (variance shares),\n{basis}")
    worst_case_shares(frame, ax=b, column=column, title=f"share of the exact worst case,\n{basis}")
    fig.suptitle(title)
    return fig
