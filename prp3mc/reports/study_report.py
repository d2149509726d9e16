"""The study report: one self-contained HTML file plus figures, tables and summary.json.

:func:`write_study` writes, into a fresh folder (atomically, see
:func:`prp3mc.output.output_folder`)::

    report.html            self-contained (figures embedded as PNG data URIs)
    summary.json           summary statistics with standard errors (prp3mc.summary)
    figures/*.png          every figure of the report (and *.svg on request)
    tables/*.csv           summary, worst-case, Monte Carlo and exact-yield grids, Sobol indices and rankings,
                           worst-case contributions, the budget, allocated classes and fronts

The report is built from a :class:`~prp3mc.study.results.StudyResult` only;
it is readable without prp3mc installed. Figures are drawn on figures of
their own with an Agg canvas (:func:`prp3mc.reports.canvas.agg_figure`):
writing a report never touches pyplot or the matplotlib backend. Each is laid
out by matplotlib's constrained layout and drawn in this process or, on
request, on worker processes while the tables are written
(:mod:`prp3mc.reports._render`).
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from ..output import (check_output, figure_formats, output_folder, png_data_uri, table_formats, write_csv,
                      write_json, write_text, write_workbook)
from ..progress import Progress
from ..stackup import QUANTILE_LEVELS
from ..study.results import StudyResult, over_grid, pct_se
from ..study.summary import build_summary
from ..study.sweep import best_configurations, design_frame
from ..units import DEG2ARCSEC, DISPLAY, MM2UM, probability_text
from .canvas import ROUND_STEPS, agg_figure, lighten
from ._render import rendering

__all__ = ["write_study", "render_report", "comparison"]

_MC_PERCENTILE = 99.73


def comparison(result: StudyResult, summary: dict | None = None) -> dict:
    """Which configuration is more accurate, by several criteria, and against published ranges.

    Returns
    -------
    dict
        ``criteria``: list of {criterion, values {config: (value, se)}, best, margin, significant,
        agrees_with_reference}; ``reference_best``: the configuration the
        references rank best (lowest upper bound) or None; ``ranges``: per
        configuration our worst-case range, the reference range (µm) and
        their ratio; ``max_ratio``: for two configurations, the worse one's
        maximum over the better one's, ours and the reference's (None when
        ours is zero: a budget of constant inputs).
    """
    summary = summary or build_summary(result)
    configs = summary["configurations"]
    crit: list[tuple[str, dict]] = []
    for stat in ("max", "mean", "min"):
        crit.append((f"exact worst-case position error, {stat} over the region (µm)",
                     {n: (c["worst_case_position_um"][stat], 0.0) for n, c in configs.items()}))
    key = f"p{_MC_PERCENTILE:g}"
    if all(key in c.get("montecarlo", {}).get("position_um", {}) for c in configs.values()):
        for stat in ("max", "mean"):
            crit.append((f"Monte Carlo {key} of the position error, {stat} over the region (µm)",
                         {n: (c["montecarlo"]["position_um"][key][stat]["value"],
                              c["montecarlo"]["position_um"][key][stat]["se"]) for n, c in configs.items()}))
        crit.append(("Monte Carlo mean position error, mean over the region (µm)",
                     {n: (c["montecarlo"]["position_um"]["mean"]["mean"]["value"],
                          c["montecarlo"]["position_um"]["mean"]["mean"]["se"]) for n, c in configs.items()}))
    refs = {c.name: c.configuration.reference_position_um for c in result.configurations
            if c.configuration.reference_position_um is not None}
    reference_best = min(refs, key=lambda n: refs[n][1]) if len(refs) == len(configs) > 1 else None
    rows = []
    for name, values in crit:
        order = sorted(values, key=lambda n: values[n][0])
        best = order[0]
        margin = values[order[1]][0] - values[best][0] if len(order) > 1 else float("nan")
        se = float(np.hypot(values[best][1], values[order[1]][1])) if len(order) > 1 else 0.0
        rows.append({"criterion": name, "values": values, "best": best, "margin": margin,
                     "significant": bool(margin > 3 * se), "exact": se == 0.0,
                     "agrees_with_reference": None if reference_best is None else best == reference_best})
    ranges = {n: {"ours": (c["worst_case_position_um"]["min"], c["worst_case_position_um"]["max"]),
                  "reference": refs.get(n)} for n, c in configs.items()}
    for r in ranges.values():
        r["ratio"] = None if r["reference"] is None else tuple(o / p if p > 0 else None  # a reference of 0 µm: none
                                                               for o, p in zip(r["ours"], r["reference"]))
    max_ratio = None
    if (reference_best is not None and len(configs) == 2 and ranges[reference_best]["ours"][1] > 0
            and refs[reference_best][1] > 0):
        other = next(n for n in configs if n != reference_best)
        max_ratio = {"ours": ranges[other]["ours"][1] / ranges[reference_best]["ours"][1],
                     "reference": refs[other][1] / refs[reference_best][1], "worse": other}
    return {"criteria": rows, "reference_best": reference_best, "ranges": ranges, "max_ratio": max_ratio}


def _worst_index(c) -> tuple:
    """Grid index of the pose where a configuration's worst-case position error is largest."""
    wc = c.worst_case
    return np.unravel_index(np.argmax(wc.position_mm), wc.position_mm.shape)


def _family_shares(result: StudyResult, contributions: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Share of each error family in the worst case at each configuration's worst pose (%).

    ``contributions``: :func:`_contributions` of every configuration, by name.
    """
    rows = []
    for c in result.configurations:
        frame = contributions[c.name]
        fam = pd.Series(frame["contribution_mm"].to_numpy(), index=[t.rsplit("_", 1)[0] for t in frame["term"]])
        worst = float(c.worst_case.position_mm[_worst_index(c)])
        for f, v in fam.groupby(level=0).sum().items():  # no share of a zero worst case (a budget of constant inputs)
            rows.append({"configuration": c.name, "family": f, "contribution_um": MM2UM * v,
                         "share_pct": 100 * v / worst if worst > 0 else float("nan")})
    return pd.DataFrame(rows)


def _pose_text(pose) -> str:
    """``x = .. mm, y = .. mm, φ = ..°`` of a pose ``[x_mm, y_mm, phi_deg]``, for labels."""
    x, y, phi = pose
    return f"x = {x:.4g} mm, y = {y:.4g} mm, φ = {phi:.4g}°"


def _worst_pose(c) -> str:
    """The pose where a configuration's worst-case position error is largest, for labels."""
    return _pose_text(c.worst_case.poses[_worst_index(c)])


def _contributions(c) -> pd.DataFrame:
    """Worst-case contributions at the configuration's worst pose, largest share first, a unit in every name.

    Columns: the pose (``x_mm``, ``y_mm``, ``phi_deg``), ``output``, ``term``,
    the term's value at the maximum in its unit (``term_value_mm`` for
    lengths, ``term_value_deg`` for angles, ``term_value_other`` with
    ``term_unit_other`` for a temperature or a scale; empty elsewhere),
    ``contribution_mm`` (its projection on the worst error vector) and
    ``share`` (of the worst case, 0-1).
    """
    frame = c.worst_case.contributions_frame("position", _worst_index(c))
    model = c.worst_case.model
    unit = frame["term"].map(dict(zip(model.terms, model.term_units))).fillna("")
    value = frame["term_value"]
    other = ~unit.isin(["mm", "deg"])
    out = frame.drop(columns=["term_value", "contribution", "share"]).assign(
        term_value_mm=value.where(unit == "mm"), term_value_deg=value.where(unit == "deg"))
    if other.any():
        out = out.assign(term_value_other=value.where(other), term_unit_other=unit.where(other, ""))
    out = out.assign(contribution_mm=frame["contribution"], share=frame["share"])
    return out.sort_values("share", ascending=False, kind="stable").reset_index(drop=True)


def _contributions_display(frame: pd.DataFrame) -> pd.DataFrame:
    """Worst-case contributions for the report (largest share first): the term's value in µm or arcsec (or its
    own unit), its contribution in µm and its share in %."""
    out = pd.DataFrame({"term": frame["term"], "value (µm)": MM2UM * frame["term_value_mm"],
                        "value (arcsec)": DEG2ARCSEC * frame["term_value_deg"]})
    if "term_value_other" in frame:
        out = out.assign(**{"value (other)": frame["term_value_other"], "unit (other)": frame["term_unit_other"]})
    return out.assign(**{"contribution (µm)": MM2UM * frame["contribution_mm"], "share (%)": 100 * frame["share"]})


def _grid_frame(c) -> pd.DataFrame:
    wc = c.worst_case
    flat = wc.poses.reshape(-1, 3)
    return pd.DataFrame({"x_mm": flat[:, 0], "y_mm": flat[:, 1], "phi_deg": flat[:, 2],
                         "position_um": MM2UM * wc.position_mm.ravel(),
                         "phi_arcsec": DEG2ARCSEC * wc.phi_deg.ravel(),
                         "x_um": MM2UM * wc.x_mm.ravel(), "y_um": MM2UM * wc.y_mm.ravel()})


def _html_table(df: pd.DataFrame, digits: int = 4) -> str:
    return df.to_html(index=False, border=0, classes="table", float_format=lambda v: f"{v:.{digits}g}",
                      na_rep="")


#: The exact yield's statistics the summary table shows, and how it names them.
_YIELD_SHOWN = {"exceed_ppm": "P(> spec)", **{f"p{lv:g}": f"p{lv:g}" for lv in QUANTILE_LEVELS}, "rss": "RSS stack"}


def _summary_display(frame: pd.DataFrame) -> pd.DataFrame:
    """The summary frame in report units (µm, arcsec): one row per statistic with min, max, mean, se of max."""
    keys = ["configuration", "analysis", "output", "statistic"]
    rows = []
    for key, g in frame.groupby(keys, sort=False):
        by = g.set_index("aggregate")
        if key[1] == "exact_yield":              # the figures the glance does not show in full: P(> spec), quantiles
            if key[3] not in _YIELD_SHOWN:
                continue
            factor, unit = (1.0, "ppm") if key[3] == "exceed_ppm" else DISPLAY[key[2]]
            statistic = _YIELD_SHOWN[key[3]]
        elif key[3].startswith("exceed_"):      # a Monte Carlo probability: % from 1 %, else ppm
            factor, unit = (100.0, "%") if by["value"].max() >= 0.01 else (1e6, "ppm")
            spec = key[3][len("exceed_"):].replace("_or_", " or ")
            statistic = "P(> " + spec.replace("arcsec", " arcsec").replace("mm", " mm") + ")"
        else:
            factor, unit = DISPLAY[key[2]]
            statistic = key[3].replace("_", " ")
        rows.append({"configuration": key[0], "analysis": key[1].replace("_", " "),
                     "output": {"phi": "|δφ|", "any": "position or |δφ|"}.get(key[2], key[2]),
                     "statistic": statistic, "unit": unit,
                     **{a: factor * by.at[a, "value"] for a in ("min", "max", "mean")},
                     "se of max": factor * by.at["max", "se"]})
    return pd.DataFrame(rows)


def _draw(plot, *args, **kwargs):
    """Deferred ``plot(*args, fig=<empty Agg figure>, **kwargs)``: called where the figure is rendered.

    ``plot`` sizes the figure itself.
    """
    return lambda: plot(*args, fig=agg_figure(), **kwargs)


def _draw_axes(plot, size: tuple[float, float], *args, layout: str = "constrained", **kwargs):
    """Deferred ``plot(*args, ax=<the axes of a new Agg figure of size inches, laid out by layout>, **kwargs)``."""
    def draw():
        fig = plot(*args, ax=agg_figure(size, layout=layout).subplots(), **kwargs)
        lighten(fig, ROUND_STEPS)
        return fig
    return draw


def _shown(result: StudyResult) -> list:
    """Configurations drawn in the maps, histograms and Sobol figures: all, or a sweep's best three."""
    if not result.study.sweep:
        return list(result.configurations)
    best = best_configurations(design_frame(result, _MC_PERCENTILE))
    return [c for c in result.configurations if c.name in best]


def _design_figures(result: StudyResult) -> list[tuple[str, str, Callable]]:
    """The design-space view of a sweep (none without a sweep or a result)."""
    if not result.study.sweep or not result.configurations:
        return []
    from .sweep_plots import design_space_figure
    frame = design_frame(result, _MC_PERCENTILE)
    best = best_configurations(frame)
    return [("design_space", "Design space: each figure of merit (rows, maximum over the test region) against "
             "each swept parameter (columns). Dots: configurations; line: the best value reachable at each value "
             f"of the parameter; marked: the best configurations by exact worst case ({', '.join(best)}).",
             _draw(design_space_figure, frame, best=best))]


def _figures(result: StudyResult) -> list[tuple[str, str, Callable]]:
    """(file name, caption, draw) of every figure of the report, in order; ``draw()`` returns the Figure."""
    from . import plots
    res = _shown(result)
    scale = ("Panels share one colour scale when that helps the comparison, else each has its own "
             "(the title says which); a field constant over a region is labelled so, without extrema.")
    figs = _design_figures(result)
    figs += [(f"pareto_{r.name}", f"{r.name}: what builds the worst case at its worst pose ({_worst_pose(r)}): each "
              "term's share of the exact worst-case position error, largest first, and their running total (at this one "
              "pose; the table above compares both rankings as means over the Sobol grid).",
              _draw_axes(plots.contributors_pareto, _PARETO, _contributions(r), title=r.name)) for r in res]
    figs += _exceedance_figures(res)
    figs += [("worstcase_position", "Exact worst-case position error (µm) over each test region (the paper's "
             f"Figs. 4-5, computed exactly). ✕ marks the maximum, ○ the minimum. {scale}",
             _draw(plots.compare_maps_figure, res, "worstcase", "position")),
            ("worstcase_phi", f"Exact worst-case orientation error |δφ| (arcsec). {scale}",
             _draw(plots.compare_maps_figure, res, "worstcase", "phi"))]
    if all(r.montecarlo is not None for r in res):
        pct = _MC_PERCENTILE if _MC_PERCENTILE in res[0].montecarlo.percentiles else res[0].montecarlo.percentiles[-1]
        noise = (" A map that varies no more than its Monte Carlo noise (range within the 95 % quantile of the range "
                 "of as many independent estimates with the largest standard error) is labelled constant within "
                 "Monte Carlo noise, its mean ± that standard error.")
        figs += [("montecarlo_position", f"Monte Carlo p{pct:g} of the position error (µm). {scale}{noise}",
                  _draw(plots.compare_maps_figure, res, "montecarlo", "position", pct)),
                 ("montecarlo_phi", f"Monte Carlo p{pct:g} of |δφ| (arcsec). {scale}{noise}",
                  _draw(plots.compare_maps_figure, res, "montecarlo", "phi", pct)),
                 ("histograms_position", "Distribution of the position error at chosen poses; dashed: the exact "
                  f"worst case at that pose, dotted: p{pct:g}.",
                  _draw(plots.histograms_figure, res, "position", pct)),
                 ("ecdf_position", "ECDF of the position error at the same poses: the fraction of assemblies "
                  f"whose error is at most x; dashed: the exact worst case, dot: p{pct:g}.",
                  _draw(plots.ecdf_figure, res, "position", pct)),
                 ("histograms_phi", "Distribution of |δφ| at the same poses, worst case dashed.",
                  _draw(plots.histograms_figure, res, "phi", pct)),
                 ("ecdf_phi", "ECDF of |δφ| at the same poses, worst case dashed.",
                  _draw(plots.ecdf_figure, res, "phi", pct))]
    for r in res:
        constant = tuple(getattr(r.sobol, "constant", ()))
        undefined = (f" Undefined, so not drawn, for {', '.join(constant)}: a constant input (zero-width law) has "
                     "no variance to share." if constant else "")
        for output, frame in r.ranking.items():
            basis = plots.ranking_basis(frame)[0]
            left = (f"Shapley effects with 95 % Student t intervals over {r.sobol.replicates} batches of random "
                    f"orders (left, ranked by Sh; the budget correlates inputs, so Sobol indices are not defined)"
                    if plots.shapley_only(frame) else
                    f"Sobol indices with 95 % Student t intervals over {r.sobol.replicates} independently "
                    f"scrambled replicates (left, ranked by ST)")
            figs.append((f"sobol_{r.name}_{output}",
                         f"{r.name}, output {output}: {left} and each input's share of the exact worst case "
                         f"(right, ranked by share); both the {basis} of the Sobol grid.{undefined}",
                         _draw(plots.ranking_figure, frame, f"{r.name}: {output}")))
    return figs + _allocation_figures(result) + _correlation_figures(result)


def correlation_order(budget) -> list[str]:
    """The correlated inputs of ``budget`` in the order a heat-map shows them: the members of each user group
    together (groups in the budget's order), then the other correlated inputs in the budget's order."""
    names = budget.copula.names
    order = [m for members in budget.groups.values() for m in members if m in names]
    order = list(dict.fromkeys(order))
    return order + [n for n in names if n not in order]


def _correlation_figures(result: StudyResult) -> list[tuple[str, str, Callable]]:
    """The heat-map of a correlated budget's rank correlations (none for an independent budget)."""
    from .plots import correlation_heatmap
    budget = result.study.budget
    if not budget.correlated:
        return []
    cop = budget.copula
    order = correlation_order(budget)
    at = [cop.names.index(n) for n in order]
    groups = [f"{g} = {', '.join(m)}" for g, m in budget.groups.items() if not g.startswith("clearance_")]
    others = [n for n in budget.factors if n not in cop.names]
    caption = (f"Budget {budget.name}: the Spearman (rank) correlation between its inputs, as its "
               "[correlation] table asks and as a Gaussian copula realises it over each input's own "
               "law (latent normal correlation 2 sin(π ρ/6), the marginal laws unchanged)"
               + (f"; groups expanded into their members ({'; '.join(groups)})" if groups else "")
               + ". Red: positive, blue: negative, white: none; the colour scale spans −1 to 1, centred at 0."
               + (f" Not shown, independent of every other input: {', '.join(others)}." if others else "")
               + " The correlations realised in the Monte Carlo draws are in the table below.")
    return [("correlation", caption,
             _draw(correlation_heatmap, order, cop.spearman[np.ix_(at, at)],
                   f"{budget.name}: rank correlations of the inputs"))]


def _exceedance_figures(results) -> list[tuple[str, str, Callable]]:
    """The exceedance curve of every configuration with an exact yield, per output with a spec."""
    from .yield_plots import exceedance_plot
    figs = []
    for r in results:
        for curve in r.curves:
            what = "position error" if curve.output == "position" else "|δφ|"
            mc = (f" Dots: Monte Carlo at the same pose ({curve.n_samples} samples, the study's draws) with 95 % "
                  "Wilson intervals; ▽ where no sample lies beyond s (the interval's upper end)."
                  if curve.mc_s is not None else "")
            figs.append((f"exceedance_{r.name}_{curve.output}",
                         f"{r.name}: the share of assemblies whose {what} exceeds s, exact (no sampling), at the pose "
                         f"of the Monte Carlo grid where it exceeds the spec most; log axis from 1 to 1e-9. Dashed: "
                         f"the spec, dotted: the exact worst case (nothing exceeds it).{mc}",
                         _draw_axes(exceedance_plot, _EXCEEDANCE, curve, title=r.name)))
    return figs


#: Size (inches) of an exceedance curve (its legend right of the panel).
_EXCEEDANCE = (8.8, 3.8)
#: Size (inches) of a Pareto chart of contributors.
_PARETO = (6.4, 3.4)
#: Size (inches) of an allocation's map (its legend below it) and of its Pareto front.
_ALLOCATION_MAP = (5.2, 5.6)
_ALLOCATION_FRONT = (6.4, 4.4)


def _allocation_figures(result: StudyResult) -> list[tuple[str, str, Callable]]:
    """The binding-pose map and the Pareto front of every configuration's allocation."""
    from .allocation_plots import allocation_front_plot, allocation_map, labels_points
    spec = result.study.allocation
    figs = []
    for c in result.configurations:
        a, front = c.allocation, c.allocation_front
        if a is None:
            continue
        nx, ny = spec.grid or result.study.worstcase_grid
        binding = ("the pose where the Monte Carlo percentile's 95 % upper bound is largest"
                   if a.binding == "percentile" else "the binding poses, dashed red the spec where the map reaches it")
        figs.append((f"allocation_{c.name}_map", f"{c.name}: the exact worst case of the chosen classes over the "
                     f"test region; ★ {binding}.",
                     _draw_axes(allocation_map, _ALLOCATION_MAP, a, (ny, nx), title=c.name, layout="compressed")))
        if front is not None and len(front):
            output = spec.front_output
            limit = spec.spec_phi_arcsec if output == "phi" else (
                spec.spec_position_um if spec.spec_percentile is None else None)
            figs.append((f"allocation_{c.name}_front", f"{c.name}: the least cost of every reachable worst-case "
                         f"{'|δφ|' if output == 'phi' else 'position error'} (the Pareto front); "
                         + ("each point is labelled with the classes that changed from the previous one"
                            if labels_points(front, output) else f"{front['point'].nunique()} points, too many to "
                            "label: the classes that change at each step are in the table below")
                         + "; ★ the chosen classes."
                         + (" The front is of the worst case: the percentile spec is not drawn, and the chosen "
                            "classes are marked only where they lie on it." if limit is None else ""),
                         _draw_axes(allocation_front_plot, _ALLOCATION_FRONT, front, output, spec=limit,
                                    chosen_cost=a.cost if a.feasible else None)))
    return figs


def _summary_frame(result: StudyResult) -> pd.DataFrame:
    """The summary table (:meth:`StudyResult.to_frame`) and, with a Monte Carlo tolerance, the exceedance:
    statistic ``exceed_<T>mm``, P(position error > T) over the grid, unit ``1`` (as ``summary.json``'s ``exceed``);
    where the run stands in for the exact yield with an orientation spec Z also ``exceed_<Z>arcsec`` (output
    ``phi``) and ``exceed_<T>mm_or_<Z>arcsec`` (output ``any``)."""
    rows = []
    for c in result.configurations:
        mc = c.montecarlo
        if mc is None or mc.exceed_prob is None:
            continue
        channels = [("position", f"{mc.tolerance_mm:g}mm", mc.exceed_prob, mc.exceed_ci)]
        if mc.exceed_phi_prob is not None:
            z = f"{DEG2ARCSEC * mc.tolerance_phi_deg:g}arcsec"
            channels += [("phi", z, mc.exceed_phi_prob, mc.exceed_phi_ci),
                         ("any", f"{channels[0][1]}_or_{z}", mc.exceed_any_prob, mc.exceed_any_ci)]
        for output, spec, p, ci in channels:
            for aggregate, (value, se) in over_grid(p, pct_se(ci)).items():
                rows.append((c.name, "montecarlo", output, f"exceed_{spec}", aggregate, value, se, "1"))
    frame = result.to_frame()
    return pd.concat([frame, pd.DataFrame(rows, columns=frame.columns)], ignore_index=True) if rows else frame


def _correlation_frame(correlation: dict, order: list[str]) -> pd.DataFrame:
    """One row per correlated pair of ``summary.json``'s ``correlation`` (asked, latent, realised and its se), in
    the heat-map's ``order`` (:func:`correlation_order`)."""
    rank = {n: k for k, n in enumerate(order)}
    rows = []
    for p in sorted(correlation["pairs"], key=lambda p: sorted(rank[n] for n in p["inputs"])):
        a, b = sorted(p["inputs"], key=rank.get)
        rows.append({"input_a": a, "input_b": b, "spearman": p["spearman"], "latent": p["latent"],
                     "realised": p["realised"]["value"], "realised_se": p["realised"]["se"]})
    return pd.DataFrame(rows)


def _tables(result: StudyResult, summary: dict | None = None) -> dict[str, pd.DataFrame]:
    """Every table of the report, by name; ``summary`` (:func:`build_summary`'s) gives the correlation table."""
    contributions = {c.name: _contributions(c) for c in result.configurations}
    tables = {"summary": _summary_frame(result), "worstcase_families": _family_shares(result, contributions),
              "budget": result.study.budget.to_frame()}
    if result.study.budget.effects:
        tables["effects"] = result.study.budget.effects_frame()
    if summary is not None and "correlation" in summary:
        tables["correlation"] = _correlation_frame(summary["correlation"], correlation_order(result.study.budget))
    if result.study.sweep:
        tables["design_space"] = design_frame(result, _MC_PERCENTILE)
    for c in result.configurations:
        tables[f"worstcase_{c.name}"] = _grid_frame(c)
        tables[f"contributions_{c.name}"] = contributions[c.name]
        if c.montecarlo is not None:
            tables[f"montecarlo_{c.name}"] = c.montecarlo.to_frame()
        if c.yield_ is not None:
            tables[f"yield_{c.name}"] = c.yield_.to_frame()
        if c.sobol is not None:
            tables[f"sobol_{c.name}"] = c.sobol.to_frame()
            for output, frame in c.ranking.items():
                tables[f"ranking_{c.name}_{output}"] = frame
        if c.allocation is not None:
            tables[f"allocation_{c.name}"] = c.allocation.choice_frame()
            if c.allocation_front is not None:
                tables[f"allocation_front_{c.name}"] = c.allocation_front
    return tables


def _poses_text(poses: np.ndarray, n: int = 6) -> str:
    """``(x, y, φ)`` of the first ``n`` poses, and how many more."""
    text = "; ".join(f"({x:g}, {y:g}, {p:g})" for x, y, p in poses[:n])
    return text + (f" and {len(poses) - n} more" if len(poses) > n else "")


def _allocations(result: StudyResult, tables: dict[str, pd.DataFrame]) -> list[dict]:
    """Per configuration with an allocation: its figures, in report units, for the template."""
    from .allocation_plots import class_changes
    out = []
    for c in result.configurations:
        a = c.allocation
        if a is None:
            continue
        choice = tables[f"allocation_{c.name}"].copy()
        factor = np.where(choice["unit"] == "mm", MM2UM, DEG2ARCSEC)
        choice = choice.assign(lo=choice["lo"] * factor, hi=choice["hi"] * factor,
                               unit=np.where(choice["unit"] == "mm", "µm", "arcsec"))
        usage = {"position": a.worst_case_position_mm / a.spec["position_mm"]
                 if a.spec["position_mm"] and a.spec["percentile"] is None else None,
                 "phi": a.worst_case_phi_deg / a.spec["phi_deg"] if a.spec["phi_deg"] else None}
        doc = {"name": c.name, "result": a, "choice": _html_table(choice),
               "position_um": MM2UM * a.worst_case_position_mm, "phi_arcsec": DEG2ARCSEC * a.worst_case_phi_deg,
               "usage": usage, "binding_poses": _poses_text(a.binding_poses), "front": None}
        if a.statistical is not None:
            st = a.statistical
            doc["statistical"] = {"percentile": st["percentile"], "screen_um": MM2UM * st["screen_mm"],
                                  "percentile_um": MM2UM * st["percentile_mm"],
                                  "ci_high_um": MM2UM * st["ci_high_mm"], "n_samples": st["n_samples"],
                                  "confirmed": st["confirmed"]}
        front = c.allocation_front
        if front is not None and len(front):
            inputs = list(a.choice)
            wide = front.pivot_table(index=["point", "cost"], columns="output", values="value").reset_index()
            firsts = front.groupby("point")[inputs].first()
            changed = [class_changes(firsts.iloc[k - 1] if k else None, firsts.iloc[k]) for k in range(len(firsts))]
            doc["front"] = _html_table(pd.DataFrame({
                "cost": wide["cost"], "worst-case position error (µm)": MM2UM * wide["position"],
                "worst-case |δφ| (arcsec)": DEG2ARCSEC * wide["phi"], "classes changed": changed}))
        elif front is not None:
            doc["front"] = ""
        out.append(doc)
    return out


def render_report(result: StudyResult, figures: list[tuple[str, str, str]], tables: dict[str, pd.DataFrame],
                  summary: dict, formats=("png",), table_types=("csv",)) -> str:
    """The report as one HTML string; ``figures`` are (name, caption, data URI); ``formats`` those written per figure.

    A caption names a figure's files (``figures/NAME.png``, ``.svg`` only
    when written) and the Run section lists every file of the folder the
    report describes.
    """
    import jinja2
    env = jinja2.Environment(loader=jinja2.PackageLoader("prp3mc.reports", "templates"),
                             autoescape=jinja2.select_autoescape(["html", "j2"]))
    study = result.study
    meta = result.metadata()
    meta.update(platform=platform.platform(), date=_dt.datetime.now().astimezone().isoformat(timespec="seconds"))
    configs = [{"name": c.name, "geometry": c.configuration.geometry.name,
                "parameters": ", ".join(f"{k} = {v:g}" if isinstance(v, (int, float)) else f"{k} = {v}"
                                        for k, v in c.configuration.parameters),
                "region": f"x ∈ [{c.configuration.region.x_mm[0]:g}, {c.configuration.region.x_mm[1]:g}] mm, "
                          f"y ∈ [{c.configuration.region.y_mm[0]:g}, {c.configuration.region.y_mm[1]:g}] mm, "
                          f"φ = {c.configuration.region.phi_deg:g}°",
                "reference": c.configuration.reference,
                "worst_pose": _worst_pose(c),
                "contributions": _html_table(_contributions_display(tables[f"contributions_{c.name}"]))}
               for c in result.configurations]
    summary_table = _summary_display(tables["summary"])
    families = (tables["worstcase_families"].pivot(index="family", columns="configuration", values="share_pct")
                .rename_axis(columns=None).reset_index())
    meta.update(scheduler=result.scheduler)
    return env.get_template("study_report.html.j2").render(
        study=study, result=result, meta=meta, configs=configs, figures=figures, design=_design(result, tables),
        summary_table=_html_table(summary_table), families=_html_table(families, 3),
        budget_table=_html_table(tables["budget"]), cmp=comparison(result, summary),
        effects_table=_html_table(tables["effects"].drop(columns=["campaign_sha256"])) if "effects" in tables else None,
        summary=summary, mc_percentile=f"p{_MC_PERCENTILE:g}", tables=sorted(tables),
        inputs=summary["inputs"], versions=summary["versions"], allocations=_allocations(result, tables),
        glance=_glance(result, summary), dependence=_dependence(summary, tables),
        formats=tuple(formats), extras=[ext for ext in formats if ext != "png"],
        written=_written(figures, tables, formats, table_types))


def _written(figures, tables: dict, formats, table_types) -> dict[str, list[str]]:
    """The files a report's folder holds, by kind (what the Run section lists)."""
    return {"report": ["report.html", "summary.json"],
            "figures": [f"figures/{name}.{ext}" for name, *_ in figures for ext in formats],
            "tables": [f"tables/{name}.csv" for name in sorted(tables)]
            + (["tables/tables.xlsx"] if "xlsx" in table_types else [])}


def _design(result: StudyResult, tables: dict) -> dict | None:
    """The design-space section of a sweep: its best configurations and what did not run."""
    if not result.study.sweep:
        return None
    frame = tables["design_space"]
    keys = [k for k, _ in result.study.sweep]
    wide = frame.assign(merit=lambda d: [_merit_name(*m) for m in zip(d.analysis, d.output, d.statistic)],
                        shown=lambda d: [v * DISPLAY[o][0] if s != "ST_top" else v
                                         for v, o, s in zip(d.value, d.output, d.statistic)])
    table = (wide.pivot_table(index=["configuration", *keys], columns="merit", values="shown", sort=False)
             .rename_axis(columns=None))                 # else the columns' name shows as an empty column
    first = _merit_name("worstcase", "position", "worst_case")
    table = table.sort_values(first).reset_index() if first in table else table.reset_index()
    tops = frame[frame["statistic"] == "ST_top"].set_index("configuration")["input"]
    if len(tops):
        table["top Sobol input"] = table["configuration"].map(tops.groupby(level=0).first())
    skipped = [{"name": s.name, "kind": s.kind, "reason": s.reason,
                "parameters": ", ".join(f"{k} = {v}" for k, v in s.parameters)} for s in result.skipped]
    return {"table": _html_table(table), "skipped": skipped, "keys": keys, "n_run": len(result.configurations),
            "best": table["configuration"].iloc[0] if len(table) else None}


def _glance(result: StudyResult, summary: dict) -> list[dict]:
    """The answer first, per configuration shown: the worst case, the Monte Carlo p99.73, P(> tolerance) and the
    dominant input by Sobol total index (by Shapley effect for a correlated budget) and by worst-case share
    (sorted contributions at the worst pose below). ``st`` is (name, value, index: ``"ST"`` or ``"Sh"``)."""
    from .plots import ranking_basis, shapley_only
    key = f"p{_MC_PERCENTILE:g}"
    rows = []
    for c in _shown(result):
        s = summary["configurations"][c.name]
        row = {"name": c.name, "worst_um": s["worst_case_position_um"]["max"], "worst_phi": s["worst_case_phi_arcsec"]["max"],
               "p_um": None, "p_se": None, "exceed": None, "tolerance_um": None, "st": None, "share": None}
        mc = s.get("montecarlo", {})
        if key in mc.get("position_um", {}):
            row["p_um"], row["p_se"] = mc["position_um"][key]["max"]["value"], mc["position_um"][key]["max"]["se"]
        if "exceed" in mc:
            p = mc["exceed"]["probability"]["max"]
            row["exceed"] = probability_text(p["value"], se=p["se"])
            row["tolerance_um"] = MM2UM * mc["exceed"]["tolerance_mm"]
        frame = c.ranking.get("position") if c.ranking else None
        if frame is not None and len(frame):
            basis, share = ranking_basis(frame)
            index = "Sh" if shapley_only(frame) else "ST"
            st = frame.dropna(subset=[index]).sort_values(index, ascending=False)
            wc = frame.sort_values(share, ascending=False)
            if len(st):
                row["st"] = (st["name"].iloc[0], float(st[index].iloc[0]), index)
            row["share"] = (wc["name"].iloc[0], float(wc[share].iloc[0]))
            row["basis"] = basis
        if c.yield_ is not None:
            row.update(_yield_glance(c, s["yield"]))
        rows.append(row)
    return rows


def _ppm_text(p_ppm: float, bound_ppm: float) -> str:
    """An exact probability in ppm with its error bound, in ppm too (and the probability in %, from 1 %)."""
    pct = f" ({p_ppm / 1e4:.3g} %)" if p_ppm >= 1e4 else ""
    value = f"{p_ppm:.0f}" if p_ppm >= 100 else f"{p_ppm:.3g}"
    return f"{value} ± {bound_ppm:.2g} ppm{pct}"


def _yield_glance(c, doc: dict) -> dict:
    """The exact yield of a configuration for the first screen: its figures against the spec, and how
    conservative each way of stating the error is, at the pose where the exact p99.73 is largest."""
    y = c.yield_
    bounds = doc["error_bounds_ppm"]
    out = {"spec": doc["spec"], "region": doc["region"],
           "exceed_position": _ppm_text(doc["exceed_position_ppm"]["max"], bounds["position"]),
           "where": _pose_text(doc["region"]["argmax_pose"]), "ppk": doc["ppk_min"]["position"],
           "area_pct": 100 * doc["region"]["area_fraction_above_1ppm"],
           "exceed_phi": None if doc["exceed_phi_ppm"] is None else
           _ppm_text(doc["exceed_phi_ppm"]["max"], bounds["phi"]),
           "exceed_any": None if doc["exceed_phi_ppm"] is None else
           _ppm_text(doc["exceed_any_ppm"]["max"], bounds["any"]),
           "bracketed": int(np.count_nonzero(y.bracketed_any)) if doc["exceed_phi_ppm"] is not None else 0}
    q = y.levels.index(_MC_PERCENTILE) if _MC_PERCENTILE in y.levels else 0
    k = np.unravel_index(np.argmax(y.quantile_position_mm[..., q]), y.exceed_position.shape)
    cons = {"pose": _pose_text(y.poses[k]), "level": f"p{y.levels[q]:g}",
            "worst": MM2UM * float(y.worst_position_mm[k]), "rss": MM2UM * float(y.rss_position_mm[k]),
            "exact": MM2UM * float(y.quantile_position_mm[k][q]),
            "exact_err": MM2UM * float(y.quantile_position_err_mm[k][q]),
            "exact_top": MM2UM * float(y.quantile_position_mm[k][-1]), "top_level": f"p{y.levels[-1]:g}",
            "mc": None}
    mc = c.montecarlo
    if mc is not None and _MC_PERCENTILE in mc.percentiles and mc.position_pct.shape[:-1] == y.exceed_position.shape:
        j = mc.percentiles.index(_MC_PERCENTILE)
        cons["mc"] = MM2UM * float(mc.position_pct[k][j])
        cons["mc_ci"] = tuple(MM2UM * float(v) for v in mc.position_pct_ci[k][j])
    out["conservative"] = cons
    return out


def _dependence(summary: dict, tables: dict) -> dict | None:
    """The section on a correlated budget (None for an independent one): its table, which analyses respected it,
    and the pairs asked and realised (the draws' size and seed)."""
    correlation = summary.get("correlation")
    if correlation is None:
        return None
    names = {"worst_case": "exact worst case", "montecarlo": "Monte Carlo", "shapley": "Shapley effects",
             "sobol": "Sobol indices (S1, ST)", "allocation": "tolerance allocation",
             "yield": "yield against the spec"}
    pairs = tables["correlation"].rename(columns={"input_a": "input", "input_b": "with", "spearman": "asked",
                                                  "latent": "latent normal r", "realised_se": "se"})
    return {"analyses": [{"name": names[k], **v} for k, v in correlation["analyses"].items()],
            "pairs": _html_table(pairs, 3), "n": correlation["realised_from"]["samples"],
            "seed": summary["inputs"]["montecarlo_seed"], "table": correlation["table"]}


def _merit_name(analysis: str, output: str, statistic: str) -> str:
    if statistic == "ST_top":
        return f"largest Sobol ST ({output})"
    what = "position" if output == "position" else "|δφ|"
    stat = "worst case" if statistic == "worst_case" else f"Monte Carlo {statistic}"
    return f"{stat} {what}, max ({DISPLAY[output][1]})"


def write_study(result: StudyResult, out: str | os.PathLike, *, force: bool = False,
                formats=("png",), workers: int = 1, warnings=None, progress: bool | None = False) -> Path:
    """Write the report, figures, tables and summary.json of ``result`` into the folder ``out``.

    ``out`` must not exist unless ``force``; it is replaced atomically.
    ``formats`` (a sequence or ``"png,svg,xlsx"``) are the files written:
    ``png`` and/or ``svg`` per figure (``png`` when none is named; each is
    rendered once and the report embeds the same PNG), and ``xlsx``:
    ``tables.xlsx`` besides the CSV files, one sheet per table
    (:func:`prp3mc.output.write_workbook`). ``progress`` shows the figures
    and tables as they are written (None: when stderr is a terminal). ``workers``: processes drawing the figures
    (:func:`prp3mc.reports._render.rendering`; 1, the default, draws them
    here). ``warnings`` (the
    messages a command gave while it ran, which include the budget's) replace
    the summary's own when given and not empty; the report shows them.
    Returns the path of ``report.html``.
    """
    formats, table_types = figure_formats(formats), table_formats(formats)
    check_output(out, force)
    summary = build_summary(result)
    if warnings:
        summary["warnings"] = list(warnings)
    figures = _figures(result)
    with output_folder(out, force) as tmp, Progress(len(figures) + 2, "report: tables", progress) as bar:
        (tmp / "figures").mkdir()
        (tmp / "tables").mkdir()
        with rendering([(name, draw) for name, _, draw in figures], tmp / "figures", formats, workers) as pngs:
            tables = _tables(result, summary)       # while the figures are drawn
            for name, frame in tables.items():
                write_csv(frame, tmp / "tables" / f"{name}.csv")
            if "xlsx" in table_types:
                write_workbook(tables, tmp / "tables" / "tables.xlsx")
            write_json(tmp / "summary.json", summary)
            bar.update(label="report: figures")
            embedded = []
            for (name, caption, _), png in zip(figures, pngs):
                embedded.append((name, caption, png_data_uri(png)))
                bar.update()
        write_text(tmp / "report.html", render_report(result, embedded, tables, summary, formats, table_types))
        bar.update(label="report")
    return Path(out) / "report.html"
