"""Figures and the self-contained HTML report of a discrepancy analysis.

Every plotting function takes a
:class:`~prp3mc.measurement.discrepancy.results.DiscrepancyResult` and ``fig=`` (each
figure has several panels; a new pyplot figure when None) and returns the
Figure; none changes the matplotlib backend. :func:`write_report` writes
``discrepancy.json``, ``report.html`` with the figures embedded,
the figures as PNG (SVG too on request), per-pose / per-measurement
tables as CSV and the updated model in ``model/``
(:mod:`~prp3mc.measurement.discrepancy.updated`); it draws on its own Agg canvases, outside pyplot, laid out
by matplotlib's constrained layout (:func:`~prp3mc.reports.canvas.agg_figure`), here or on worker processes
on request (:mod:`~prp3mc.reports._render`), and writes the JSON, tables and model files meanwhile.

The report shows what the measurement carries besides the machine: the
instrument's registration and drift (``nuisance``), the measurements set
aside as gross errors (``outliers``, also marked on the workspace figure)
and what changes without them, the repeatable fraction of the budget
(``repeatability``), and ISO 9283 pose accuracy and repeatability per pose,
measured next to predicted (:mod:`~prp3mc.measurement.campaign.iso9283`).
"""

from __future__ import annotations

import functools
import os
from importlib import resources
from pathlib import Path

import numpy as np

from ..measurement.verdict.diagnostics import Diagnosis
from ..measurement.campaign.iso9283 import ISO_STATISTICS, N_MC
from ..measurement.discrepancy.results import DiscrepancyResult
from ..output import output_folder, png_data_uri, write_json, write_text
from ..units import DEG2ARCSEC, MM2UM
from .canvas import agg_figure, lighten
from ._render import rendering

__all__ = ["plot_workspace", "plot_actuators", "plot_temperature", "plot_gap", "plot_candidates", "plot_iso9283",
           "write_report", "report_document"]

#: Resolution of the report's figures (dots per inch); one render per figure.
DPI = 90


def _outlier_rows(result: DiscrepancyResult) -> np.ndarray:
    """0-based rows the analysis set aside as gross errors."""
    return np.array([int(o["row"]) for o in result.outliers], dtype=int)


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
    axes = fig.subplots(2, 2, sharex=True, sharey=True)
    span = np.ptp(result.campaign.poses[:, :2], axis=0).max() or 1.0
    biggest = max(np.hypot(result.before.poses["dx_um"], result.before.poses["dy_um"]).max(), 1e-9)
    scale = biggest / (0.12 * span)                   # the largest arrow spans 12 % of the region
    for col, (d, label) in enumerate(((result.before, "before"), (result.after, "after"))):
        sc = _quiver(axes[0, col], d, f"Mean residual, {label} (longest before: {biggest:.1f} µm)", scale)
        p = d.poses
        ratio = np.log2(p["disp_ratio"].to_numpy(dtype=float))
        im = axes[1, col].scatter(p["x_mm"], p["y_mm"], c=ratio, cmap="coolwarm", vmin=-1.5, vmax=1.5, s=60,
                                  edgecolor=np.where(p["disp_q"] < 0.05, "k", "none"), lw=1.2)
        axes[1, col].set(title=f"Repeat scatter / predicted, {label}",
                         xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    rows = _outlier_rows(result)
    if rows.size:
        poses, counts = np.unique(result.campaign.pose_index[rows], return_counts=True)
        xy = result.campaign.poses[poses, :2]
        for ax in axes[0]:
            ax.scatter(xy[:, 0], xy[:, 1], s=90 + 40 * counts, marker="X", color="tab:red", edgecolor="w", lw=0.6,
                       zorder=5, label=f"gross error set aside ({rows.size} measurement{'s' * (rows.size > 1)})")
        axes[0, 0].legend(loc="lower left", fontsize=7, framealpha=0.8)
    for ax in axes.flat:
        ax.label_outer()
    fig.colorbar(sc, ax=axes[0, :], label="-log10 q (systematic, BH)")
    cb = fig.colorbar(im, ax=axes[1, :], label="log2 scatter ratio (0: as predicted)")
    cb.set_ticks([-1, 0, 1])


def _draw_actuators(result: DiscrepancyResult, fig) -> None:
    axes = fig.subplots(2, 3, sharex="col", sharey="row")
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
            if row == 0:
                ax.legend(loc="upper left", fontsize=7, markerscale=1.5)
            ax.axhline(0.0, color="k", lw=0.6)
            ax.set(title=f"leg {i + 1} {label}", xlabel=f"b_{i + 1} (mm)" if row == 1 else None,
                   ylabel="equivalent slider error (µm)" if i == 0 else None)


def _draw_temperature(result: DiscrepancyResult, fig) -> None:
    axes = fig.subplots(1, 2, sharey=True)
    for ax, (d, label) in zip(axes, ((result.before, "before"), (result.after, "after"))):
        m = d.measurements
        for i in range(3):
            ax.scatter(m["temp_C"], m[f"db_eq_{i + 1}_um"], s=5, alpha=0.4, label=f"leg {i + 1}")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set(title=f"Equivalent slider error vs temperature, {label}", xlabel="temperature (°C)",
               ylabel="µm" if ax is axes[0] else None)
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
    ax.axhline(g["closed_at"], color="tab:red", ls="--", lw=0.8, label=f"closed at <= {g['closed_at']:.2g}")
    ax.set_xticks([0, 1], ["before", "after"])
    ax.set(yscale="log", title="gap " + ("closed" if g["closed"] else
                                         f"NOT closed ({g['deciding_channel'].replace('_', ' ')})"))
    ax.legend(fontsize=8)


def _draw_iso9283(result: DiscrepancyResult, fig) -> None:
    per = result.iso9283_poses
    axes = fig.subplots(1, 4)
    for ax, (stat, unit) in zip(axes, ISO_STATISTICS.items()):
        f, shown = (MM2UM, "µm") if unit == "mm" else (DEG2ARCSEC, "arcsec")
        rows = per[per["statistic"] == stat].dropna(subset=["measured", "predicted"]).sort_values("predicted")
        pred, meas, sd = (f * rows[k].to_numpy() for k in ("predicted", "measured", "predicted_sd"))
        rank = np.arange(len(rows))
        ax.fill_between(rank, np.maximum(pred - 2 * sd, 0), pred + 2 * sd, color="tab:green", alpha=0.25, lw=0,
                        label="model ± 2 sd")
        ax.plot(rank, pred, color="tab:green", lw=1.2, label="model")
        out = meas > pred + 2 * sd
        ax.scatter(rank[~out], meas[~out], s=12, color="tab:blue", label="measured")
        ax.scatter(rank[out], meas[out], s=16, color="tab:red", label="measured, above the band")
        ax.set(ylim=(0, None), title=f"{stat.replace('_phi', ' φ')} ({shown})", xlabel="pose, by predicted value")
    axes[0].legend(loc="best", fontsize=7)


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
    "iso9283": (_draw_iso9283, lambda r: None if r.iso9283_poses is None else (13.0, 3.9)),
}
#: Figures of the report, in its order (the gap and the candidates are tables there: quicker to read and to write).
_REPORT_FIGURES = ("workspace", "iso9283", "actuators", "temperature")


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
    lighten(fig)
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


def plot_iso9283(result: DiscrepancyResult, *, fig=None):
    """ISO 9283 AP, RP, AP_phi and RP_phi per pose: measured against predicted, with the model's ± 2 sd band.

    Points above the diagonal are poses worse than the model predicts; the
    band is how far a campaign of this size strays when the model is right.
    The figures are the analysis's own (``result.iso9283_poses``). ``fig``
    (1 x 4 panels) as in :func:`plot_workspace`; returns the Figure.
    """
    return _plot("iso9283", result, fig)


_CAPTIONS = {
    "workspace": "Top: mean residual (measured minus predicted) per commanded pose, arrows in µm; colour is "
                 "the significance of the pose's systematic disagreement (-log10 of the Benjamini-Hochberg "
                 "q-value); red crosses: poses with measurements set aside as gross errors. Bottom: repeat scatter "
                 "relative to the predicted scatter (red: larger, blue: smaller; black ring: BH q < 0.05).",
    "actuators": "Residuals mapped to an equivalent slider error J_b^-1 r, averaged per pose "
                 "and approach direction, against the slider position: a zero offset shows as a shift, a lead error as "
                 "a slope, backlash as a split between red and blue.",
    "temperature": "Equivalent slider errors against temperature: a thermal expansion shows as a trend.",
    "gap": "Left: two of the verdict's channels before and after the named effects, G_sys (whitened residual "
           "energy in the span of the library's systematic signatures per degree of freedom) and G_disp (repeat "
           "scatter over its predicted mean), both 1 when the model is right; grey: null level ± 2 sd. Right: the "
           "gap, the strongest of the seven channels (-ln p less ln 7, null level at most 1), and where it closes.",
    "candidates": "Evidence for each candidate effect at each step; green was accepted. Bars beyond the red "
                  "line pass the likelihood-ratio test corrected for the number of candidates.",
    "iso9283": "ISO 9283 pose accuracy (AP) and repeatability (RP) of every commanded pose, position and "
               "orientation: measured (registration and drift removed, gross errors set aside) against what the "
               "corrected model predicts for the same number of visits (green line), poses ordered by the "
               "prediction. The green band is where 95 % of campaigns of this size fall if the model is right; "
               "red points, above it, are poses worse than the model says.",
}


def _report_figure(name: str, result: DiscrepancyResult):
    """Figure ``name`` of the report on its own Agg canvas (rendered where saved)."""
    return _plot(name, result, agg_figure(_FIGURES[name][1](result), dpi=DPI))


def _table(frame) -> str:
    return frame.to_html(index=False, float_format=lambda v: f"{v:.3g}", classes="table", border=0)


def _top_candidates(steps, top: int = 5):
    """The ``top`` strongest candidates of every selection step, with the step's threshold."""
    if steps.empty:
        return steps
    cols = [c for c in ("step", "candidate", "lr", "threshold", "estimate", "accepted") if c in steps.columns]
    return steps.sort_values(["step", "lr"], ascending=[True, False]).groupby("step").head(top)[cols]


def _iso_summary(iso: dict) -> list[dict]:
    """The largest ISO 9283 figures, measured and predicted, in µm and arcsec, for the report's table."""
    rows = []
    for stat, unit in ISO_STATISTICS.items():
        key = f"{stat}_{unit}"
        f, shown = (MM2UM, "µm") if unit == "mm" else (DEG2ARCSEC, "arcsec")
        m, p = iso["measured"][key], iso["predicted"][key]
        rows.append({"name": stat.replace("_phi", " φ"), "unit": shown,
                     "measured": None if m is None else f * m, "predicted": None if p is None else f * p})
    return rows


def _page(result: DiscrepancyResult, doc: dict | None):
    """All of the HTML report but its figures (template compiled, tables made): a function of the figures."""
    import jinja2
    text = resources.files("prp3mc.reports").joinpath("templates/discrepancy.html.j2").read_text(encoding="utf-8")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    top = result.before.poses.nlargest(8, "sys_stat")[
        ["pose_id", "x_mm", "y_mm", "phi_deg", "n", "dx_um", "dy_um", "dphi_arcsec", "sys_q", "disp_ratio"]]
    per = result.iso9283_poses
    worst = per[per["statistic"] == "RP"].nlargest(8, "measured")[["pose_id", "x_mm", "y_mm", "phi_deg", "n"]]
    wide = per.pivot(index="pose_id", columns="statistic", values=["measured", "predicted"])
    for stat, unit in ISO_STATISTICS.items():
        f, shown = (MM2UM, "µm") if unit == "mm" else (DEG2ARCSEC, "arcsec")
        for which in ("measured", "predicted"):
            worst[f"{stat} {which[:4]}. ({shown})"] = f * wide.loc[worst["pose_id"], (which, stat)].to_numpy()
    template = env.from_string(text)
    context = dict(
        r=result, doc=doc if doc is not None else result.to_dict(), captions=_CAPTIONS, mm2um=MM2UM,
        deg2arcsec=DEG2ARCSEC, top_poses=_table(top), gap=result.gap,
        channel=result.gap["deciding_channel"].replace("_", " "), steps=_table(_top_candidates(result.steps)),
        before=result.before.summary, after=result.after.summary,
        nuisance=list(result.nuisance), drift_test=result.drift_test, registration_fitted=result.registration,
        confounded=list(result.confounded_with_registration), outliers=list(result.outliers),
        outlier_rule=result.outlier_rule, with_outliers=result.with_outliers, repeatability=result.repeatability,
        iso_n_mc=N_MC, iso_rows=_iso_summary(result.iso9283), iso_worst=_table(worst))
    return lambda figures, formats=("png",), written=(): template.render(figures=figures, formats=formats,
                                                                         written=written, **context)


def report_document(result: DiscrepancyResult, inputs: dict | None = None, warnings=None) -> dict:
    """``discrepancy.json``: the result's document with more ``inputs`` and the ``warnings`` given.

    ``inputs`` is merged into the document's; ``warnings`` (the messages a
    command gave while it ran, which include the budget's) replace the
    result's own when given and not empty.
    """
    doc = result.to_dict()
    doc["inputs"] = doc["inputs"] | dict(inputs or {})
    if warnings:
        doc["warnings"] = list(warnings)
    return doc


def write_report(result: DiscrepancyResult, folder: str | os.PathLike, force: bool = False,
                 formats: tuple = ("png",), inputs: dict | None = None, warnings=None,
                 workers: int = 1) -> Path:
    """Write ``discrepancy.json``, ``report.html``, figures, tables and ``model/`` into ``folder`` (atomically).

    Parameters
    ----------
    result : DiscrepancyResult
    folder : path
    force : bool
        Replace an existing folder.
    formats : tuple of str
        Figure files written besides the embedded PNG: ``"png"`` and/or
        ``"svg"`` (an SVG costs another render of every figure).
    inputs : dict, optional
        More of what the analysis ran on, merged into ``discrepancy.json``'s
        ``inputs`` (the command line adds the geometry and budget files' sha256).
    warnings : list of str, optional
        The warnings a command gave (see :func:`report_document`); the report shows them.
    workers : int, optional
        Processes drawing the figures (:func:`prp3mc.reports._render.rendering`;
        1, the default, draws them here). The files are the same either way.

    Returns
    -------
    Path
        The folder.
    """
    doc = report_document(result, inputs, warnings)
    figures = [(name, functools.partial(_report_figure, name, result)) for name in _REPORT_FIGURES
               if _FIGURES[name][1](result) is not None]
    with output_folder(folder, force) as tmp:
        with rendering(figures, tmp, formats, workers, DPI) as pngs:
            write_json(tmp / "discrepancy.json", doc)   # while the figures are drawn
            result.model.write(tmp / "model")
            for label, d in (("before", result.before), ("after", result.after)):
                d.poses.to_csv(tmp / f"poses_{label}.csv", index=False)
                d.measurements.to_csv(tmp / f"measurements_{label}.csv", index=False)
            result.steps.to_csv(tmp / "selection_steps.csv", index=False)
            result.iso9283_poses.to_csv(tmp / "iso9283_per_pose.csv", index=False)
            page = _page(result, doc)
            uris = {name: png_data_uri(png) for (name, _), png in zip(figures, pngs)}
        written = ["report.html", *sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())]
        write_text(tmp / "report.html", page(uris, tuple(formats), written))
    return Path(folder)
