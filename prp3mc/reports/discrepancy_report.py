"""Figures and the self-contained HTML report of a discrepancy analysis.

Every plotting function takes a
:class:`~prp3mc.measurement.selection.DiscrepancyResult` and ``fig=`` (each
figure has several panels; a new pyplot figure when None) and returns the
Figure; none changes the matplotlib backend. :func:`write_report` writes
``discrepancy.json`` (SPEC §6), ``report.html`` with the figures embedded,
the figures as PNG and SVG, and per-pose / per-measurement tables as CSV;
it draws on its own Agg canvases, outside pyplot.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

import numpy as np

from ..measurement.diagnostics import GAP_CLOSED, Diagnosis
from ..measurement.selection import DiscrepancyResult
from ..output import output_folder, png_data_uri, save_figure, write_json, write_text
from ..units import DEG2ARCSEC, MM2UM

__all__ = ["plot_workspace", "plot_actuators", "plot_temperature", "plot_gap", "plot_candidates",
           "write_report", "render_html"]


def _quiver(ax, d: Diagnosis, title: str, scale: float):
    """Mean residual arrows over the significance of each pose; returns the scatter (for a colour bar)."""
    p = d.poses
    q = -np.log10(np.clip(p["sys_q"].to_numpy(), 1e-12, 1.0))
    sc = ax.scatter(p["x_mm"], p["y_mm"], c=q, cmap="magma_r", vmin=0, vmax=6, s=40, edgecolor="k", lw=0.3)
    ax.quiver(p["x_mm"], p["y_mm"], p["dx_um"], p["dy_um"], angles="xy", scale_units="xy", scale=scale,
              width=0.004, color="tab:blue")
    ax.set(title=title, xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    return sc


def _draw_workspace(result: DiscrepancyResult, fig) -> None:
    axes = fig.subplots(2, 2)
    span = np.ptp(result.campaign.poses[:, :2], axis=0).max() or 1.0
    biggest = max(np.hypot(result.before.poses["dx_um"], result.before.poses["dy_um"]).max(), 1e-9)
    scale = biggest / (0.12 * span)                   # the largest arrow spans 12 % of the region
    for col, (d, label) in enumerate(((result.before, "before"), (result.after, "after"))):
        sc = _quiver(axes[0, col], d, f"Mean residual {label} (arrow: {biggest:.1f} µm = longest before)", scale)
        p = d.poses
        ratio = np.log2(p["disp_ratio"].to_numpy(dtype=float))
        im = axes[1, col].scatter(p["x_mm"], p["y_mm"], c=ratio, cmap="coolwarm", vmin=-1.5, vmax=1.5, s=60,
                                  edgecolor=np.where(p["disp_q"] < 0.05, "k", "none"), lw=1.2)
        axes[1, col].set(title=f"Repeat scatter / predicted {label} (black ring: BH q < 0.05)",
                         xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    fig.colorbar(sc, ax=axes[0, :], label="-log10 q (systematic, BH)")
    cb = fig.colorbar(im, ax=axes[1, :], label="log2 scatter ratio (0: as predicted)")
    cb.set_ticks([-1, 0, 1])


def _draw_actuators(result: DiscrepancyResult, fig) -> None:
    axes = fig.subplots(2, 3, sharey="row")
    for row, (d, label) in enumerate(((result.before, "before"), (result.after, "after"))):
        m = d.measurements
        for i in range(3):
            ax = axes[row, i]
            keys = ["pose"] + ([] if m[f"dir_{i + 1}"].isna().all() else [f"dir_{i + 1}"])
            g = m.groupby(keys, as_index=False)[[f"b_{i + 1}", f"db_eq_{i + 1}_um"]].mean()
            if len(keys) == 1:
                ax.scatter(g[f"b_{i + 1}"], g[f"db_eq_{i + 1}_um"], s=12, color="gray", label="pose mean")
            else:
                for sign, color in ((1, "tab:red"), (-1, "tab:blue")):
                    sel = g[f"dir_{i + 1}"] == sign
                    ax.scatter(g.loc[sel, f"b_{i + 1}"], g.loc[sel, f"db_eq_{i + 1}_um"], s=12, alpha=0.8,
                               color=color, label=f"pose mean, dir_{i + 1} = {sign:+d}")
            ax.legend(loc="upper left", fontsize=7, markerscale=1.5)
            ax.axhline(0.0, color="k", lw=0.6)
            ax.set(title=f"leg {i + 1} {label}", xlabel=f"b_{i + 1} (mm)",
                   ylabel="equivalent slider error (µm)" if i == 0 else None)


def _draw_temperature(result: DiscrepancyResult, fig) -> None:
    axes = fig.subplots(1, 2, sharey=True)
    for ax, (d, label) in zip(axes, ((result.before, "before"), (result.after, "after"))):
        m = d.measurements
        for i in range(3):
            ax.scatter(m["temp_C"], m[f"db_eq_{i + 1}_um"], s=5, alpha=0.4, label=f"leg {i + 1}")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set(title=f"Equivalent slider error vs temperature, {label}", xlabel="temperature (°C)",
               ylabel="µm")
        ax.legend(fontsize=7, markerscale=2)


def _draw_gap(result: DiscrepancyResult, fig) -> None:
    g = result.gap
    ch = g["channels"]
    axes = fig.subplots(1, 2, gridspec_kw={"width_ratios": [2, 1]})
    ax = axes[0]
    labels = ["systematic G_sys\n(library span)", "dispersion G_disp\n(repeat scatter)"]
    keys = ("systematic", "dispersion")
    x = np.arange(2)
    ax.bar(x - 0.18, [ch["before"][k] for k in keys], 0.36, label="before", color="tab:orange")
    ax.bar(x + 0.18, [ch["after"][k] for k in keys], 0.36, label="after", color="tab:green")
    for xi, k in zip(x, keys):
        sd = ch["after"][f"{k}_null_sd"]
        ax.fill_between([xi - 0.45, xi + 0.45], 1 - 2 * sd, 1 + 2 * sd, color="gray", alpha=0.3,
                        label="null level ± 2 sd" if xi == 0 else None)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xticks(x, labels)
    ax.set(ylabel="1 when the model is right", title="channels")
    ax.legend(fontsize=8)
    ax = axes[1]
    ax.bar([0, 1], [max(g["before"], 0.05), max(g["after"], 0.05)], color=["tab:orange", "tab:green"])
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(GAP_CLOSED, color="tab:red", ls="--", lw=0.8, label=f"closed below {GAP_CLOSED:g}")
    ax.set_xticks([0, 1], ["before", "after"])
    ax.set(yscale="log", title="gap " + ("closed" if g["closed"] else "NOT closed") + " (null level 1)")
    ax.legend(fontsize=8)


def _n_steps(result: DiscrepancyResult) -> int:
    steps = result.steps
    return max(int(steps["step"].max()) if len(steps) else 1, 1)


def _draw_candidates(result: DiscrepancyResult, fig, top: int = 15) -> None:
    steps = result.steps
    axes = fig.subplots(1, _n_steps(result), squeeze=False)
    for k in range(axes.shape[1]):
        ax = axes[0, k]
        s = steps[steps["step"] == k + 1].nlargest(top, "lr")
        if s.empty:
            continue
        colors = np.where(s["accepted"], "tab:green", "tab:gray")
        ax.barh(s["candidate"][::-1], np.maximum(s["lr"][::-1], 1e-2), color=colors[::-1])
        ax.axvline(s["threshold"].iloc[0], color="tab:red", ls="--", label="Bonferroni threshold")
        ax.set(xscale="log", xlabel="likelihood ratio", title=f"step {k + 1}")
        ax.legend(fontsize=7)


#: name -> (drawing function, figure size in inches or None when the figure does not apply).
_FIGURES = {
    "workspace": (_draw_workspace, lambda r: (11.0, 9.5)),
    "actuators": (_draw_actuators, lambda r: (13.0, 7.0)),
    "temperature": (_draw_temperature, lambda r: None if r.campaign.temp_C is None else (11.0, 3.8)),
    "gap": (_draw_gap, lambda r: (9.0, 3.8)),
    "candidates": (_draw_candidates, lambda r: (4.2 * _n_steps(r), 4.2)),
}


def _plot(name: str, result: DiscrepancyResult, fig):
    """Draw figure ``name`` into ``fig`` (a new pyplot figure of its size when None); None if it does not apply."""
    draw, size = _FIGURES[name]
    figsize = size(result)
    if figsize is None:
        return None
    if fig is None:
        import matplotlib.pyplot as plt
        fig = plt.figure(figsize=figsize, layout="constrained")
    draw(result, fig)
    return fig


def plot_workspace(result: DiscrepancyResult, *, fig=None):
    """Mean residual per pose (arrows) and its significance, and the repeat-scatter ratio, before and after.

    Parameters
    ----------
    result : DiscrepancyResult
    fig : matplotlib Figure or SubFigure, optional
        Drawn into (2 x 2 panels); a new figure when None.

    Returns
    -------
    Figure
    """
    return _plot("workspace", result, fig)


def plot_actuators(result: DiscrepancyResult, *, fig=None):
    """Residual as an equivalent slider error J_b^-1 r against each slider position, by approach direction.

    ``fig`` (2 x 3 panels) as in :func:`plot_workspace`; returns the Figure.
    """
    return _plot("actuators", result, fig)


def plot_temperature(result: DiscrepancyResult, *, fig=None):
    """Equivalent slider errors against temperature, before and after.

    ``fig`` (1 x 2 panels) as in :func:`plot_workspace`; returns the Figure,
    or None (nothing drawn) if the campaign has no ``temp_C``.
    """
    return _plot("temperature", result, fig)


def plot_gap(result: DiscrepancyResult, *, fig=None):
    """The gap's two channels before and after, each with its null band (± 2 sd), and the gap itself.

    ``fig`` (1 x 2 panels) as in :func:`plot_workspace`; returns the Figure.
    """
    return _plot("gap", result, fig)


def plot_candidates(result: DiscrepancyResult, *, fig=None):
    """Likelihood ratio of the 15 strongest candidates at each selection step, with the Bonferroni threshold.

    ``fig`` (one panel per step) as in :func:`plot_workspace`; returns the Figure.
    """
    return _plot("candidates", result, fig)


def _agg_figure(figsize):
    """A figure of ``figsize`` inches on its own Agg canvas (pyplot and the backend untouched)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


_CAPTIONS = {
    "workspace": "Top: mean residual (measured minus predicted) per commanded pose, arrows in µm; colour is "
                 "the significance of the pose's systematic disagreement (-log10 of the Benjamini-Hochberg "
                 "q-value). Bottom: repeat scatter relative to the predicted scatter (red: larger, blue: smaller).",
    "actuators": "Residuals mapped to an equivalent slider error J_b^-1 r, averaged per pose "
                 "and approach direction, against the slider position: a zero offset shows as a shift, a lead error as "
                 "a slope, backlash as a split between red and blue.",
    "temperature": "Equivalent slider errors against temperature: a thermal expansion shows as a trend.",
    "gap": "Left: the two channels before and after the named effects, G_sys (whitened residual energy in the "
           "span of the library's systematic signatures per degree of freedom) and G_disp (repeat scatter over "
           "its predicted mean), both 1 when the model is right; grey: null level ± 2 sd. Right: the gap, "
           "(z_sys^2 + z_disp^2)/2 of the standardised channels, 1 when the model is right.",
    "candidates": "Evidence for each candidate effect at each step; green was accepted. Bars beyond the red "
                  "line pass the likelihood-ratio test corrected for the number of candidates.",
}


def render_html(result: DiscrepancyResult, figures: dict) -> str:
    """The HTML report; ``figures`` maps figure names to data URIs."""
    import jinja2
    text = resources.files("prp3mc.reports").joinpath("templates/discrepancy.html.j2").read_text(encoding="utf-8")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    top = result.before.poses.nlargest(8, "sys_stat")[
        ["pose_id", "x_mm", "y_mm", "phi_deg", "n", "dx_um", "dy_um", "dphi_arcsec", "sys_q", "disp_ratio"]]
    return env.from_string(text).render(
        r=result, doc=result.to_dict(), figures=figures, captions=_CAPTIONS, mm2um=MM2UM, deg2arcsec=DEG2ARCSEC,
        top_poses=top.to_html(index=False, float_format=lambda v: f"{v:.3g}", classes="table", border=0),
        before=result.before.summary, after=result.after.summary)


def write_report(result: DiscrepancyResult, folder: str | os.PathLike, force: bool = False) -> Path:
    """Write ``discrepancy.json``, ``report.html``, figures and tables into ``folder`` (atomically).

    Returns
    -------
    Path
        The folder.
    """
    with output_folder(folder, force) as tmp:
        write_json(tmp / "discrepancy.json", result.to_dict())
        uris = {}
        for name, (draw, size) in _FIGURES.items():
            figsize = size(result)
            if figsize is None:
                continue
            fig = _agg_figure(figsize)
            draw(result, fig)
            uris[name] = png_data_uri(save_figure(fig, tmp, name, ("png", "svg")))
        write_text(tmp / "report.html", render_html(result, uris))
        for label, d in (("before", result.before), ("after", result.after)):
            d.poses.to_csv(tmp / f"poses_{label}.csv", index=False)
            d.measurements.to_csv(tmp / f"measurements_{label}.csv", index=False)
        result.steps.to_csv(tmp / "selection_steps.csv", index=False)
    return Path(folder)
