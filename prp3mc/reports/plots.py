"""Figures of study results (matplotlib).

Every plotting function takes result objects and an ``ax=`` (a new pyplot
figure when None) and returns the Figure; the ``*_figure`` functions lay
several panels out on one figure and take ``fig=`` (an empty Figure to draw
into, sized to fit; a new pyplot figure when None). Nothing here switches the
matplotlib backend, so figures show inline in notebooks; reports draw on a
:class:`matplotlib.figure.Figure` of their own. Maps show µm and arcsec.

The ``*_figure`` functions size their figure from what it holds (panels,
names, titles wrapped to its width) and leave the placing to matplotlib's
constrained layout, the same in a report and in a notebook.
"""

from __future__ import annotations

import numpy as np

from ..units import DISPLAY
from .canvas import ROUND_STEPS, lighten, text_width, wrap

__all__ = ["is_constant", "within_noise", "noise_range", "shared_levels", "region_map", "worst_case_map", "montecarlo_map", "compare_maps_figure",
           "error_histogram", "histograms_figure", "ecdf_steps", "error_ecdf", "ecdf_figure", "sobol_ranking",
           "worst_case_shares", "ranking_figure", "contributors_pareto", "correlation_heatmap"]

_LABEL = {"position": "position error", "phi": "|δφ|"}
_QUANTITY = {q: (label, DISPLAY[q][1], DISPLAY[q][0]) for q, label in _LABEL.items()}  # (label, unit, scale)
#: A field whose range is below this fraction of its magnitude is drawn as a constant.
CONSTANT_RTOL = 1e-9
#: Maps share one colour scale only when every varying panel spans at least this fraction of it.
MIN_SCALE_FRACTION = 0.25
#: Steps an ECDF is drawn with at most (:func:`ecdf_steps`): 1 / ECDF_STEPS is below a pixel of a report figure.
ECDF_STEPS = 2048
#: Width of a map panel, inches (a region's map keeps its aspect inside it).
MAP_INCHES = 3.6
#: How far below a map's axes its legend (extrema, binding poses) starts, inches: under the tick labels and x label.
LEGEND_DROP = 0.55


def _axes(ax, figsize=(5.0, 4.2)):
    """``ax``, or the axes of a new pyplot figure (pyplot imported only then)."""
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax


def _figure(fig, figsize):
    """``fig`` (a new pyplot figure when None) resized to ``figsize`` inches, laid out by matplotlib's constrained
    layout."""
    if fig is None:
        import matplotlib.pyplot as plt
        return plt.figure(figsize=figsize, layout="constrained")
    fig.set_size_inches(figsize)
    fig.set_layout_engine("constrained")
    return fig


def legend_below(ax, **kwargs):
    """A legend centred under ``ax``, :data:`LEGEND_DROP` inches below it (under its x tick labels and label);
    the figure's layout makes room for it."""
    from matplotlib.transforms import ScaledTranslation
    below = ax.transAxes + ScaledTranslation(0.0, -LEGEND_DROP, ax.figure.dpi_scale_trans)
    return ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=below, fontsize=7,
                     frameon=False, ncol=1, **kwargs)


def is_constant(values: np.ndarray, rtol: float = CONSTANT_RTOL) -> bool:
    """Whether a field is constant up to round-off: its range is at most ``rtol`` of its magnitude."""
    v = np.asarray(values, dtype=float)
    return float(np.ptp(v)) <= rtol * max(float(np.max(np.abs(v))), np.finfo(float).tiny)


def noise_range(n: int, level: float = 0.95) -> float:
    """The ``level`` quantile of the range of ``n`` independent standard normal variables.

    ``P(R <= w) = n ∫ φ(x) (Φ(x + w) − Φ(x))^(n−1) dx``, integrated on a
    grid and solved for ``w`` (2.77 for n = 2, i.e. 1.96·√2; 5.6 for 49).
    """
    from scipy.optimize import brentq
    from scipy.special import ndtr
    if n < 2:
        return 0.0
    x = np.linspace(-9.0, 9.0, 4001)
    pdf = np.exp(-0.5 * x * x) / np.sqrt(2 * np.pi)

    def cdf(w):
        return n * np.trapezoid(pdf * (ndtr(x + w) - ndtr(x)) ** (n - 1), x) - level
    return float(brentq(cdf, 1e-6, 20.0, xtol=1e-6))


def within_noise(values: np.ndarray, se: np.ndarray, level: float = 0.95) -> bool:
    """Whether a field of Monte Carlo estimates varies no more than their noise alone would make it vary.

    The field is taken as constant when its range is at most
    :func:`noise_range` ``(n) × max(se)``: the ``level`` quantile of the
    range of ``n`` independent estimates of one value, each with the largest
    standard error. A field that varies less cannot be told from a constant
    one at this sample size (for two poses the rule is range <= 1.96·√2·se,
    the two-sided 95 % test of their difference). Estimates that share their
    draws (common random numbers across poses) scatter less than independent
    ones, so the rule errs towards calling a field constant: it states what
    the run cannot resolve, not that the true field is flat.

    Parameters
    ----------
    values, se : ndarray, same shape
        Per-pose estimates and their standard errors (same unit).
    """
    v, s = np.asarray(values, dtype=float).ravel(), np.asarray(se, dtype=float).ravel()
    if not np.all(np.isfinite(s)) or float(s.max()) <= 0.0:
        return False
    return float(np.ptp(v)) <= noise_range(v.size, level) * float(s.max())


def _with_se(value: float, se: float) -> str:
    """``value ± se`` to the decimal of the standard error's first digit (``115.9 ± 0.2``)."""
    decimals = max(0, -int(np.floor(np.log10(se)))) if se > 0 else 3
    return f"{value:.{decimals}f} ± {round(se, decimals):.{decimals}f}"


def shared_levels(*arrays: np.ndarray, n: int = 12) -> np.ndarray:
    """Round contour levels spanning all ``arrays`` (one colour scale for several maps)."""
    from matplotlib.ticker import MaxNLocator
    lo = min(float(np.min(a)) for a in arrays)
    hi = max(float(np.max(a)) for a in arrays)
    if is_constant(np.array([lo, hi])):  # a constant field still gets a band around it
        lo, hi = lo - max(abs(lo), 1.0) * 0.01, hi + max(abs(hi), 1.0) * 0.01
    return MaxNLocator(n).tick_values(lo, hi)


def region_map(poses: np.ndarray, values: np.ndarray, *, ax=None, levels=None, cmap: str = "viridis",
               title: str = "", mark_extrema: bool = True, unit: str = "", se: np.ndarray | None = None):
    """Filled contour map of ``values`` (ny, nx) over grid ``poses`` (ny, nx, 3), extrema marked.

    A constant field (:func:`is_constant`) is filled in one colour and
    labelled "constant: value unit", with neither contour lines nor extrema;
    so is a field of estimates with standard errors ``se`` that varies no
    more than their noise (:func:`within_noise`), labelled "constant within
    Monte Carlo noise: mean ± largest se unit". The contour lines carry no
    labels (the colour bar reads them; labels along close lines overlapped).
    Draws on ``ax`` (a new pyplot figure when None); returns the Figure holding it.
    """
    ax = _axes(ax)
    X, Y = poses[..., 0], poses[..., 1]
    noise = se is not None and not is_constant(values) and within_noise(values, se)
    flat = is_constant(values) or noise
    levels = shared_levels(values) if levels is None else levels
    ax.contourf(X, Y, np.full_like(values, np.mean(values)) if noise else values, levels=levels, cmap=cmap,
                extend="neither")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    ax.set_title(title)
    if flat:
        text = (f"constant within Monte Carlo noise:\n{_with_se(float(np.mean(values)), float(np.max(se)))} {unit}"
                if noise else f"constant: {float(np.mean(values)):.4g} {unit}")
        ax.text(0.5, 0.5, text.rstrip(), transform=ax.transAxes, ha="center", va="center", fontsize=10,
                bbox={"boxstyle": "round", "fc": "white", "ec": "0.6"})
        return ax.figure
    ax.contour(X, Y, values, levels=levels, colors="k", linewidths=0.5, alpha=0.6)
    if mark_extrema:
        for fn, marker, word in ((np.argmax, "X", "max"), (np.argmin, "o", "min")):
            k = np.unravel_index(fn(values), values.shape)
            ax.plot(X[k], Y[k], marker=marker, color="white", mec="k", ms=8, ls="none", clip_on=False, zorder=5,
                    label=f"{word} {values[k]:.4g} {unit} at ({X[k]:.4g}, {Y[k]:.4g})")
        legend_below(ax)
    return ax.figure


def worst_case_map(wc, quantity: str = "position", *, ax=None, levels=None, title: str = ""):
    """Contour map of the exact worst-case ``position`` error (µm) or ``phi`` error (arcsec)."""
    label, unit, f = _QUANTITY[quantity]
    return region_map(wc.poses, f * wc.value(quantity), ax=ax, levels=levels, title=title, unit=unit)


def montecarlo_map(mc, percentile: float = 99.73, quantity: str = "position", *, ax=None, levels=None,
                   title: str = ""):
    """Contour map of a Monte Carlo percentile of the position error (µm) or ``|δφ|`` (arcsec)."""
    label, unit, f = _QUANTITY[quantity]
    values, se = _percentile_field(mc, percentile, quantity)
    return region_map(mc.poses, f * values, ax=ax, levels=levels, title=title, cmap="magma", unit=unit, se=f * se)


def _percentile_field(mc, percentile: float, quantity: str) -> tuple[np.ndarray, np.ndarray]:
    """A Monte Carlo percentile over the grid and its standard errors (from its 95 % intervals), mm or deg."""
    from ..study.results import pct_se
    q = list(mc.percentiles).index(float(percentile))
    pct, ci = ((mc.position_pct, mc.position_pct_ci) if quantity == "position" else (mc.phi_pct, mc.phi_pct_ci))
    return pct[..., q], pct_se(ci[..., q, :])


def _share_scale(values, share_scale, constant) -> bool:
    """Whether maps of ``values`` go on one colour scale (``"auto"``: when no varying panel gets too little of it;
    ``constant``: which panels are drawn as constant)."""
    if share_scale != "auto":
        return bool(share_scale)
    span = max(float(np.max(v)) for v in values) - min(float(np.min(v)) for v in values)
    return all(np.ptp(v) >= MIN_SCALE_FRACTION * span for v, flat in zip(values, constant) if not flat)


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
    label, unit, f = _QUANTITY[quantity]
    if kind == "worstcase":
        values = [f * r.worst_case.value(quantity) for r in results]
        poses = [r.worst_case.poses for r in results]
        what, cmap = f"exact worst-case {label}", "viridis"
        ses = [None] * len(results)
    else:
        fields = [_percentile_field(r.montecarlo, percentile, quantity) for r in results]
        values, ses = [f * v for v, _ in fields], [f * se for _, se in fields]
        poses = [r.montecarlo.poses for r in results]
        what, cmap = f"Monte Carlo p{percentile:g} of the {label}", "magma"
    constant = [is_constant(v) or (se is not None and within_noise(v, se)) for v, se in zip(values, ses)]
    shared = _share_scale(values, share_scale, constant)
    common = shared_levels(*values, n=20)
    levels = [common if shared else shared_levels(v, n=20) for v in values]
    if all(constant):
        title = f"{what}: constant over each region"
    elif shared:
        title = f"{what}, one colour scale"
    else:
        title = f"{what}, each panel on its own colour scale (their ranges differ too much to share one)"
    n = len(results)
    aspect = max(np.ptp(p[..., 1]) / max(np.ptp(p[..., 0]), 1e-300) for p in poses)
    height = MAP_INCHES * float(np.clip(aspect, 0.35, 1.4))
    bars = 0 if all(constant) else 1 if shared else n - sum(constant)       # colour bars right of the maps
    width = n * (MAP_INCHES + 0.9) + 1.0 * bars + 0.2
    names = [wrap(r.name, MAP_INCHES, 12) for r in results]
    title = wrap(title, width - 0.3, 12)
    fig = _figure(fig, (width, height + 0.3 + 0.2 * (title.count("\n") + max(m.count("\n") for m in names))
                        + 0.5 + (0.0 if all(constant) else LEGEND_DROP + 0.5)))
    fig.suptitle(title)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, r, v, name, lv in zip(axes, results, values, names, levels):
        if kind == "worstcase":
            worst_case_map(r.worst_case, quantity, ax=ax, levels=lv, title=name)
        else:
            montecarlo_map(r.montecarlo, percentile, quantity, ax=ax, levels=lv, title=name)
    lighten(fig, ROUND_STEPS)
    if shared and not all(constant):
        _colorbar(list(axes), common, cmap, f"{label} ({unit})")
    elif not shared:
        for ax, lv, flat in zip(axes, levels, constant):
            if not flat:
                _colorbar(ax, lv, cmap, f"{label} ({unit})")
    return fig


def _colorbar(ax, levels, cmap: str, label: str):
    """A colour bar of ``levels`` right of ``ax`` (an Axes or a list of them), 85 % of their height."""
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm
    sm = ScalarMappable(norm=BoundaryNorm(levels, matplotlib.colormaps[cmap].N), cmap=cmap)
    fig = ax[0].figure if isinstance(ax, list) else ax.figure
    return fig.colorbar(sm, ax=ax, shrink=0.85, label=label)


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
    quantity : ``"position"`` (µm) or ``"phi"`` (``|δφ|``, arcsec)
    percentile : float
        Also marked (dotted).
    label : str, optional
        The histogram's legend entry (default: the pose's label; ``""``
        none: the figures of several poses name each in its panel's title).

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
    ax.set_xlabel(f"{name} ({unit})", visible=_labelled(ax.xaxis))
    ax.legend(fontsize=7, loc="best")
    return ax.figure


#: A panel of the histogram and ECDF figures with its tick labels and axis labels, inches (width, height).
_POSE_PANEL = (4.0, 3.0)


def _labelled(axis) -> bool:
    """Whether ``axis`` shows its tick labels (not inside a row or column of shared axes): its label goes with them."""
    return axis.get_tick_params().get("labelbottom" if axis.axis_name == "x" else "labelleft", True)


def _pose_grid(results, fig, draw, title: str, sharey: bool = False):
    """One row per configuration, one panel per chosen pose: ``draw(samples, k, ax, color)`` fills each.

    ``sharey``: one y axis per row, labelled on its first panel only (the panels then sit closer).
    """
    import matplotlib
    pw, ph = _POSE_PANEL
    shape = (len(results), max(len(r.samples.labels) for r in results))
    heads = [[wrap(f"{r.name}: {label}", pw, 9) + f"\n(x={x:.4g}, y={y:.4g} mm, φ={phi:.4g}°)"
              for label, (x, y, phi) in zip(r.samples.labels, r.samples.poses)] for r in results]
    head = 9 * 1.2 / 72 * max(h.count("\n") + 1 for row in heads for h in row)     # a panel's title, inches
    width = shape[1] * pw + 0.2
    title = wrap(f"{title} ({results[0].samples.n_samples} samples)", width - 0.3, 12)
    fig = _figure(fig, (width, shape[0] * (ph + head) + 0.3 + 0.2 * (title.count("\n") + 1)))
    axes = fig.subplots(*shape, squeeze=False, sharex=True, sharey=sharey)
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (row, r) in enumerate(zip(axes, results)):
        s = r.samples
        for k, ax in enumerate(row):
            if k >= len(s.labels):
                ax.set_visible(False)
                continue
            if i + 1 < shape[0] and k >= len(results[i + 1].samples.labels):   # nothing below: x labels here
                ax.xaxis.set_tick_params(labelbottom=True)
            draw(s, k, ax, colors[k % len(colors)])
            ax.set_title(heads[i][k], fontsize=9)
    lighten(fig, ROUND_STEPS)
    fig.suptitle(title)
    return fig


def histograms_figure(results, quantity: str = "position", percentile: float = 99.73, *, fig=None):
    """Error histograms at each configuration's chosen poses, worst case marked; one row per configuration.

    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    def draw(s, k, ax, color):
        error_histogram(s, k, quantity, ax=ax, percentile=percentile, color=color, label="")
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
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("fraction of assemblies at most x", visible=_labelled(ax.yaxis))
    ax.set_xlabel(f"{name} ({unit})", visible=_labelled(ax.xaxis))
    ax.legend(fontsize=7, loc="lower right")
    return ax.figure


def ecdf_figure(results, quantity: str = "position", percentile: float = 99.73, *, fig=None):
    """ECDFs of the error at each configuration's chosen poses, worst case dashed; one row per configuration.

    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    def draw(s, k, ax, color):
        error_ecdf(s, k, quantity, ax=ax, percentile=percentile, color=color, label="")
    return _pose_grid(results, fig, draw, f"ECDF of the {_QUANTITY[quantity][0]} at chosen poses, "
                      "exact worst case dashed", sharey=True)


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


def shapley_only(frame) -> bool:
    """Whether a ranking frame has Shapley effects and no Sobol indices (a correlated budget)."""
    return "Sh" in frame and bool(frame["ST"].isna().all()) and bool(frame["Sh"].notna().any())


def sobol_ranking(frame, *, ax=None, title: str = ""):
    """First-order and total Sobol indices with their 95 % intervals, ranked by ST; for a correlated
    budget (:func:`shapley_only`) its Shapley effects, ranked by Sh.

    Parameters
    ----------
    frame : DataFrame
        :func:`prp3mc.sobol.ranking.ranking` (columns name, kind, S1, S1_conf, ST, ST_conf, and Sh, Sh_conf).

    Returns
    -------
    Figure
        The figure holding ``ax`` (a new pyplot figure when ``ax`` is None).
    """
    shapley = shapley_only(frame)
    frame = frame.sort_values("Sh" if shapley else "ST", ascending=False, kind="stable")
    ax = _axes(ax, figsize=(5.0, 0.32 * len(frame) + 1.2))
    y = np.arange(len(frame))
    h = 0.38
    bars = ((("Sh", "Shapley effect Sh", "#8172b2", 0.0, 2 * h),) if shapley else
            (("ST", "total ST", "#4c72b0", -h / 2, h), ("S1", "first order S1", "#dd8452", h / 2, h)))
    for key, label, color, shift, height in bars:
        ax.barh(y + shift, frame[key], height=height, xerr=frame[f"{key}_conf"], label=label, color=color,
                error_kw={"lw": 1, "capsize": 2})
    ax.set_yticks(y, _bar_labels(frame))
    ax.invert_yaxis()
    ax.set_xlabel(("Shapley effect" if shapley else "Sobol index") + " (95 % CI)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    return ax.figure


def _bar_labels(frame) -> list[str]:
    """The names of a ranking frame's rows as its bar charts label them, groups marked."""
    return [f"{n} (group)" if k == "group" else n for n, k in zip(frame["name"], frame["kind"])]


def _shares_xlabel(undefined: list, width: float) -> str:
    """x label of :func:`worst_case_shares` (8 pt), the names without a share of their own wrapped to ``width`` inches."""
    label = "share of the worst case (%)"
    if undefined:
        label += "\n" + wrap(f"no share of their own (counted in their group): {', '.join(undefined)}", width, 8)
    return label


def worst_case_shares(frame, *, ax=None, title: str = "share of the exact worst case", column: str | None = None):
    """Each input's or group's share (%) of the worst case, ranked by that share; returns the Figure.

    ``column``: the share column of ``frame`` (default: :func:`ranking_basis`'s).
    Names without a share of their own (rho_i, zeta_i: their clearance term
    is counted in clearance_i) are listed under the bars, not drawn.
    """
    column = ranking_basis(frame)[1] if column is None else column
    undefined = frame[frame[column].isna()]["name"].tolist()
    frame = frame.dropna(subset=[column]).sort_values(column, ascending=False, kind="stable")
    ax = _axes(ax, figsize=(3.5, 0.32 * len(frame) + 1.2))
    y = np.arange(len(frame))
    ax.barh(y, 100 * frame[column], color="#55a868")
    ax.set_yticks(y, _bar_labels(frame))
    ax.invert_yaxis()
    ax.set_xlabel(_shares_xlabel(undefined, ax.get_position().width * ax.figure.get_figwidth()), fontsize=8)
    ax.set_title(title, fontsize=10)
    return ax.figure


#: Widths of the two panels of :func:`ranking_figure`, inches (Sobol indices, worst-case shares).
_RANKING_PANELS = (3.8, 2.6)


def ranking_figure(frame, title: str = "", *, fig=None):
    """Sobol ranking with CIs next to the worst-case shares, each ranked in its own order, on one basis.

    Both panels are taken on the same basis (:func:`ranking_basis`: the mean
    over the poses of a region, or one pose) and say which. The figure grows
    with the number of inputs, its margins with their names.
    ``fig``: an empty figure to draw into (a new pyplot figure when None). Returns the Figure.
    """
    basis, column = ranking_basis(frame)
    (wa, wb), shares = _RANKING_PANELS, frame.dropna(subset=[column])
    kind = "Shapley effects (variance shares; correlated inputs)" if shapley_only(frame) else \
        "Sobol indices (variance shares)"
    heads = (wrap(f"{kind},\n{basis}", wa + 0.3, 10),
             wrap(f"share of the exact worst case,\n{basis}", wb + 0.3, 10))
    left = text_width("\n".join(_bar_labels(frame))) + 0.5             # the y tick labels and label of each panel
    middle = text_width("\n".join(_bar_labels(shares))) + 0.3 if len(shares) else 0.3
    xlabel = _shares_xlabel(frame[frame[column].isna()]["name"].tolist(), wb)
    width = left + wa + middle + wb + 0.3
    title = wrap(title, width - 0.3, 12) if title else ""
    lines = (title.count("\n") + 1 if title else 0) + max(h.count("\n") + 1 for h in heads) + xlabel.count("\n")
    fig = _figure(fig, (width, 0.27 * len(frame) + 0.45 + 0.6 + 0.2 * lines))
    a, b = fig.subplots(1, 2, width_ratios=(wa, wb))
    sobol_ranking(frame, ax=a, title=heads[0])
    worst_case_shares(frame, ax=b, column=column, title=heads[1])
    lighten(fig, ROUND_STEPS)
    if title:
        fig.suptitle(title)
    return fig


def contributors_pareto(contributions, *, ax=None, title: str = ""):
    """Pareto chart of a worst case's contributors: shares (%) as bars, largest first, and their running total.

    Parameters
    ----------
    contributions : DataFrame
        :meth:`~prp3mc.worstcase.envelope.WorstCaseResult.contributions_frame` at one pose (``term``, ``share``).
    ax : matplotlib Axes, optional
    title : str

    Returns
    -------
    Figure
    """
    ax = _axes(ax, (6.4, 3.4))
    frame = contributions.sort_values("share", ascending=False, kind="stable")
    share = 100 * frame["share"].to_numpy(dtype=float)
    x = np.arange(share.size)
    ax.bar(x, share, color="C0", width=0.7, label="share of the worst case")
    ax.plot(x, np.cumsum(share), "o-", color="C3", ms=3.5, lw=1.2, label="running total")
    ax.set_xticks(x, frame["term"], rotation=45, ha="right", fontsize=8)
    ax.set(ylim=(0, 105), ylabel="share of the worst case (%)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, frameon=False, loc="center right")         # under the total, over the smallest bars
    ax.set_title(f"{title}: contributors to the worst-case position error" if title else
                 "contributors to the worst-case position error", fontsize=10)
    return ax.figure


#: Side of one cell of :func:`correlation_heatmap`, inches.
_CELL = 0.42


def correlation_heatmap(names, matrix, title: str = "", *, fig=None):
    """Rank correlations between inputs as a heat-map: a diverging colour map centred at 0, each cell labelled.

    Parameters
    ----------
    names : sequence of str
        The inputs, in the order of ``matrix`` (groups expanded into their members).
    matrix : ndarray, shape (k, k)
        Rank (Spearman) correlations, 1 on the diagonal.
    title : str
    fig : Figure, optional
        An empty figure to draw into (a new pyplot figure when None).

    Returns
    -------
    Figure
        Blue for negative, red for positive correlations, white for none; the
        colour scale spans [-1, 1] so that 0 is its centre whatever the values.
    """
    matrix = np.asarray(matrix, dtype=float)
    k = len(names)
    label = text_width("\n".join(names), 9) + 0.15                # the tick labels, left and below
    side = max(k * _CELL, 1.2)
    width = label + side + 1.0                                        # the colour bar with its ticks and label
    title = wrap(title, width - 0.3, 12) if title else ""
    fig = _figure(fig, (width, label + side + 0.2 + (0.2 * (title.count("\n") + 1) if title else 0.0)))
    ax = fig.subplots()
    image = ax.imshow(matrix, cmap="RdBu_r", vmin=-1.0, vmax=1.0, interpolation="nearest")
    ax.set_xticks(np.arange(k), names, rotation=90, fontsize=9)
    ax.set_yticks(np.arange(k), names, fontsize=9)
    ax.tick_params(length=0)
    for i in range(k):
        for j in range(k):
            v = matrix[i, j]
            if v != 0.0:
                ax.text(j, i, "1" if i == j else f"{v:.2f}".replace("-", "\u2212"), ha="center", va="center",
                        fontsize=7 if k > 12 else 8, color="white" if abs(v) > 0.6 else "#222")
    ax.set_xticks(np.arange(k + 1) - 0.5, minor=True)
    ax.set_yticks(np.arange(k + 1) - 0.5, minor=True)
    ax.grid(which="minor", color="white", lw=1)
    ax.tick_params(which="minor", length=0)
    cb = fig.colorbar(image, ax=ax, ticks=[-1, -0.5, 0, 0.5, 1])
    cb.ax.tick_params(labelsize=8)
    cb.set_label("rank correlation (Spearman)", fontsize=8)
    if title:
        fig.suptitle(title)
    return fig
