"""Regression checks on study summaries, for prp3mc's tests and users' CI.

>>> from prp3mc.testing import assert_summary_close
>>> golden = {"worst_um": 140.0, "p99_um": {"value": 120.0, "se": 0.5}}
>>> assert_summary_close({"worst_um": 140.0, "p99_um": {"value": 121.0, "se": 0.5}}, golden)
>>> assert_summary_close({"worst_um": 140.1, "p99_um": {"value": 125.0, "se": 0.5}}, golden)
Traceback (most recent call last):
...
AssertionError: 2 of 2 summary statistics differ:
  worst_um: actual 140.1 != golden 140 (exact, rtol 1e-09)
  p99_um: actual 125 vs golden 120: |diff| 5 > 3.536 (5 SE; se 0.5, 0.5)
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from .stackup import OUTPUTS, ppk
from .units import PPM

__all__ = ["assert_summary_close", "load_summary"]


def load_summary(summary: "dict | str | os.PathLike") -> dict:
    """A summary dict, or the ``summary.json`` file (or folder holding one) it is read from."""
    if isinstance(summary, dict):
        return summary
    path = Path(summary)
    if path.is_dir():
        path = path / "summary.json"
    return json.loads(path.read_text(encoding="utf-8"))


def _is_stat(x: Any) -> bool:
    return isinstance(x, dict) and set(x) == {"value", "se"}


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def assert_summary_close(actual: "dict | str | os.PathLike", golden: "dict | str | os.PathLike", *,
                         n_se: float = 5.0, rtol_exact: float = 1e-9, atol_exact: float = 1e-12,
                         ignore: tuple = ("metadata", "inputs", "versions", "warnings")) -> None:
    """Assert that two study summaries agree within their statistical uncertainty.

    Walks both nested dicts (``summary.json`` layout, see
    :mod:`prp3mc.study.summary`). A ``{"value", "se"}`` pair is a statistic: it
    passes if ``|a - g| <= n_se * sqrt(se_a**2 + se_g**2)``. A plain number is
    exact: it passes if ``|a - g| <= rtol_exact * max(|a|, |g|) + atol_exact``.
    Strings, booleans and the set of keys must be equal.

    A ``yield`` entry's figures are exact only to their reported error
    bounds, which a change of the computation (not of the model) may move:
    an exceedance (ppm, %, the region's largest and mean) passes within the
    sum of both sides' bounds of its channel (``error_bounds_ppm``), a
    position quantile within the sum of both sides'
    ``quantile_error_bounds_position_um`` (a quantile of ``|dphi|``: of
    ``quantile_error_bounds_phi_arcsec``, where both sides report it), and a
    least Ppk within what the exceedance's tolerance allows it. The bounds
    themselves are the computation's guarantee, not a figure of the model:
    each passes when it is finite and non-negative on both sides (null on
    both for a channel without a spec), or is reported by one side only.

    Parameters
    ----------
    actual, golden : dict, or path of a summary.json (or of the folder holding it)
    n_se : float
        Tolerance of statistics in combined standard errors. With the
        default 5 a correct model fails by chance with probability ~6e-7 per
        statistic.
    rtol_exact, atol_exact : float
        Tolerance of exact quantities.
    ignore : tuple of str
        Top-level keys not compared, present or not on either side (what a
        run was made from and how: files, seeds, versions, times, and the
        warnings it gave).

    Raises
    ------
    AssertionError
        Listing every path that differs, with both values and the tolerance.
    """
    failures: list[str] = []
    actual, golden = load_summary(actual), load_summary(golden)

    def walk(a: Any, g: Any, path: str, extra: "float | dict" = 0.0) -> None:
        if isinstance(a, dict) and isinstance(g, dict) and "error_bounds_ppm" in g and "error_bounds_ppm" in a:
            bounds, extra = _yield_tolerances(a, g)
            for key in bounds:
                if key not in a or key not in g:          # a bound one version reports and another does not
                    continue
                if not (_bound_ok(a[key]) and _bound_ok(g[key]) and _same_nulls(a[key], g[key])):
                    failures.append(f"{path}.{key}: actual {a.get(key)!r}, golden {g.get(key)!r}: an error bound "
                                    "must be finite and non-negative on both sides (null on both)")
            a = {k: v for k, v in a.items() if k not in bounds}
            g = {k: v for k, v in g.items() if k not in bounds}
        if _is_stat(g) and _is_stat(a):
            tol = n_se * math.hypot(a["se"], g["se"])
            tol = max(tol, rtol_exact * max(abs(a["value"]), abs(g["value"])) + atol_exact)
            diff = abs(a["value"] - g["value"])
            if not diff <= tol:
                failures.append(f"{path}: actual {a['value']:.6g} vs golden {g['value']:.6g}: |diff| {diff:.4g} "
                                f"> {tol:.4g} ({n_se:g} SE; se {a['se']:.4g}, {g['se']:.4g})")
        elif isinstance(g, dict) and isinstance(a, dict):
            for key in g:
                where = f"{path}.{key}" if path else key
                if not path and key in ignore:
                    continue
                if key not in a:
                    failures.append(f"{where}: missing from actual")
                else:
                    walk(a[key], g[key], where, extra.get(key, 0.0) if isinstance(extra, dict) else extra)
            failures.extend(f"{path}.{key}: not in golden" if path else f"{key}: not in golden"
                            for key in a if key not in g and (path or key not in ignore))
        elif isinstance(g, list) and isinstance(a, list):
            if len(a) != len(g):
                failures.append(f"{path}: length {len(a)} != golden {len(g)}")
            for k, (x, y) in enumerate(zip(a, g)):
                walk(x, y, f"{path}[{k}]", extra)
        elif _number(g) and _number(a):
            if not abs(a - g) <= rtol_exact * max(abs(a), abs(g)) + atol_exact + extra:
                within = f"within {extra:.4g} (both error bounds), " if extra else ""
                failures.append(f"{path}: actual {a:.10g} != golden {g:.10g} (exact, {within}rtol {rtol_exact:g})")
        elif a != g or type(a) is not type(g):
            failures.append(f"{path}: actual {a!r} != golden {g!r}")

    walk(actual, golden, "")
    if failures:
        n = _count(golden, ignore)
        raise AssertionError(f"{len(failures)} of {n} summary statistics differ:\n  " + "\n  ".join(failures))


_BOUND_KEYS = ("error_bound_ppm", "error_bounds_ppm", "quantile_error_bounds_position_um",
               "quantile_error_bounds_phi_arcsec")


def _bound_ok(x: Any) -> bool:
    """An error bound (or a dict of them) finite and non-negative, or null."""
    if isinstance(x, dict):
        return all(_bound_ok(v) for v in x.values())
    return x is None or (_number(x) and math.isfinite(x) and x >= 0.0)


def _same_nulls(a: Any, b: Any) -> bool:
    """Null in the same places (a channel without a spec has no bound on either side)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_nulls(a[k], b[k]) for k in a)
    return (a is None) == (b is None)


def _ppk_tolerance(p_ppm: float, t_ppm: float) -> float:
    """How far the one-sided Ppk (:func:`prp3mc.stackup.ppk`) moves when P (ppm) moves by t_ppm; inf when
    P - t reaches 0 (Ppk then unbounded: null in the summary)."""
    lo, hi = (p_ppm - t_ppm) / PPM, (p_ppm + t_ppm) / PPM
    if lo <= 0.0:
        return math.inf
    return float(ppk(lo) - ppk(hi))


def _yield_tolerances(a: dict, g: dict) -> tuple[tuple, dict]:
    """A ``yield`` entry's bound keys, and the absolute tolerance of each figure (key -> float or dict)."""
    tol: dict = {}
    ba, bg = a.get("error_bounds_ppm") or {}, g.get("error_bounds_ppm") or {}
    for o in OUTPUTS:
        if not (_number(ba.get(o)) and _number(bg.get(o))):
            continue
        t = ba[o] + bg[o]
        tol[f"exceed_{o}_ppm"], tol[f"exceed_{o}_pct"] = t, t * 100.0 / PPM
        worst = (g.get(f"exceed_{o}_ppm") or {}).get("max")
        if _number(worst):
            tol.setdefault("ppk_min", {})[o] = _ppk_tolerance(worst, t)
        if o == "position":
            tol["region"] = {"max_exceed_position_ppm": t, "mean_exceed_position_ppm": t}
    for channel in ("position_um", "phi_arcsec"):
        qa, qg = a.get(f"quantile_error_bounds_{channel}") or {}, g.get(f"quantile_error_bounds_{channel}") or {}
        tol[f"quantiles_{channel}"] = {k: qa[k] + qg[k] for k in qg if _number(qa.get(k)) and _number(qg.get(k))}
    return tuple(k for k in _BOUND_KEYS if k in a or k in g), tol


def _count(doc: Any, ignore: tuple, top: bool = True) -> int:
    """Number of leaves (statistics, numbers, strings) of a summary."""
    if _is_stat(doc) or not isinstance(doc, (dict, list)):
        return 1
    items = doc.values() if isinstance(doc, dict) else doc
    if isinstance(doc, dict) and top:
        items = [v for k, v in doc.items() if k not in ignore]
    return sum(_count(v, ignore, False) for v in items)
