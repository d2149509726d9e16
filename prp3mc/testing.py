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
    :mod:`prp3mc.summary`). A ``{"value", "se"}`` pair is a statistic: it
    passes if ``|a - g| <= n_se * sqrt(se_a**2 + se_g**2)``. A plain number is
    exact: it passes if ``|a - g| <= rtol_exact * max(|a|, |g|) + atol_exact``.
    Strings, booleans and the set of keys must be equal.

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

    def walk(a: Any, g: Any, path: str) -> None:
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
                    walk(a[key], g[key], where)
            failures.extend(f"{path}.{key}: not in golden" if path else f"{key}: not in golden"
                            for key in a if key not in g and (path or key not in ignore))
        elif isinstance(g, list) and isinstance(a, list):
            if len(a) != len(g):
                failures.append(f"{path}: length {len(a)} != golden {len(g)}")
            for k, (x, y) in enumerate(zip(a, g)):
                walk(x, y, f"{path}[{k}]")
        elif _number(g) and _number(a):
            if not abs(a - g) <= rtol_exact * max(abs(a), abs(g)) + atol_exact:
                failures.append(f"{path}: actual {a:.10g} != golden {g:.10g} (exact, rtol {rtol_exact:g})")
        elif a != g or type(a) is not type(g):
            failures.append(f"{path}: actual {a!r} != golden {g!r}")

    walk(actual, golden, "")
    if failures:
        n = _count(golden, ignore)
        raise AssertionError(f"{len(failures)} of {n} summary statistics differ:\n  " + "\n  ".join(failures))


def _count(doc: Any, ignore: tuple, top: bool = True) -> int:
    """Number of leaves (statistics, numbers, strings) of a summary."""
    if _is_stat(doc) or not isinstance(doc, (dict, list)):
        return 1
    items = doc.values() if isinstance(doc, dict) else doc
    if isinstance(doc, dict) and top:
        items = [v for k, v in doc.items() if k not in ignore]
    return sum(_count(v, ignore, False) for v in items)
