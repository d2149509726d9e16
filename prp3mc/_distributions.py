"""The chi-squared and normal tail functions of the analyses, without importing scipy.stats.

Each is what ``scipy.stats`` computes, the same numbers bit for bit
(tests/test_distributions.py holds them to it): the scipy.special kernel its
``chi2`` and ``norm`` evaluate inside the support (``chi2._sf`` is
``chdtrc``, ``_isf`` is ``chdtri``, ``_ppf`` is ``2 gammaincinv(df/2, p)``,
the log tails the log of ``chdtrc`` (``chdtr``) beyond the median and
``log1p`` of minus the other tail before it; ``norm.logsf(x)`` is
``log_ndtr(-x)``), and the values its wrappers give at the ends of the support
and outside it. :func:`bh_adjusted` is ``false_discovery_control(p,
method="bh")`` of a 1-D array. Importing scipy.stats costs about half a
second, a tenth of what ``prp3mc discrepancy`` takes in all.
"""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["chi2_sf", "chi2_isf", "chi2_ppf", "chi2_logsf", "chi2_logcdf", "norm_logsf", "bh_adjusted", "chi2_equivalent"]


def _tail(x, df, kernel, below: float, above: float):
    """``kernel(df, x)`` inside (0, inf), ``below`` at x <= 0, ``above`` at x = inf, NaN for NaN or df <= 0."""
    x, df = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(df, dtype=np.float64))
    with np.errstate(invalid="ignore"):
        inside = (df > 0) & (x > 0) & (x < np.inf)
    out = np.where(x <= 0, below, above)
    out[np.isnan(x) | ~(df > 0)] = np.nan
    if inside.any():
        with np.errstate(divide="ignore"):
            out[inside] = kernel(df[inside], x[inside])
    return out[()] if out.ndim == 0 else out


def _quantile(q, df, kernel, at_0: float, at_1: float):
    """``kernel(df, q)`` inside (0, 1), ``at_0`` and ``at_1`` at the ends, NaN outside or for df <= 0."""
    q, df = np.broadcast_arrays(np.asarray(q, dtype=np.float64), np.asarray(df, dtype=np.float64))
    out = np.full(q.shape, np.nan)
    ok = df > 0
    out[ok & (q == 0)], out[ok & (q == 1)] = at_0, at_1
    inside = ok & (q > 0) & (q < 1)
    if inside.any():
        out[inside] = kernel(df[inside], q[inside])
    return out[()] if out.ndim == 0 else out


def chi2_sf(x, df):
    """``scipy.stats.chi2.sf(x, df)``."""
    return _tail(x, df, special.chdtrc, 1.0, 0.0)


def _log_tail(df, x, upper: bool):
    """Log of the upper (or lower) tail: the log of the tail in its far half, else log1p of minus the other."""
    median = _chi2_quantile(df, 0.5)
    far = x > median if upper else x < median
    near = ~far
    out = np.empty_like(x)
    tail, other = (special.chdtrc, special.chdtr) if upper else (special.chdtr, special.chdtrc)
    out[far] = np.log(tail(df[far], x[far]))
    out[near] = np.log1p(-other(df[near], x[near]))
    return out


def _chi2_quantile(df, p):
    return 2 * special.gammaincinv(df / 2, p)


def chi2_logsf(x, df):
    """``scipy.stats.chi2.logsf(x, df)``."""
    return _tail(x, df, lambda d, v: _log_tail(d, v, True), 0.0, -np.inf)


def chi2_logcdf(x, df):
    """``scipy.stats.chi2.logcdf(x, df)``."""
    return _tail(x, df, lambda d, v: _log_tail(d, v, False), -np.inf, 0.0)


def chi2_isf(q, df):
    """``scipy.stats.chi2.isf(q, df)``."""
    return _quantile(q, df, special.chdtri, np.inf, 0.0)


def chi2_ppf(q, df):
    """``scipy.stats.chi2.ppf(q, df)``."""
    return _quantile(q, df, _chi2_quantile, 0.0, np.inf)


def norm_logsf(x):
    """``scipy.stats.norm.logsf(x)``."""
    x = np.asarray(x, dtype=np.float64)
    out = np.where(x == -np.inf, 0.0, -np.inf)
    out[np.isnan(x)] = np.nan
    inside = np.isfinite(x)
    out[inside] = special.log_ndtr(-x[inside])
    return out[()] if out.ndim == 0 else out


def bh_adjusted(p) -> np.ndarray:
    """Benjamini-Hochberg adjusted p-values (q-values) of a 1-D array of p-values.

    ``scipy.stats.false_discovery_control(p, method="bh")``: sorted p times
    m / rank, made monotone from the largest down, in the original order, clipped to [0, 1].

    Raises
    ------
    ValueError
        A p-value outside [0, 1].
    """
    p = np.asarray(p, dtype=np.float64)
    if not np.all(p == np.clip(p, 0.0, 1.0)):
        raise ValueError("p-values must lie between 0 and 1")
    if p.size <= 1:
        return p
    order = np.argsort(p, kind="stable")
    q = p[order] * (p.size / np.arange(1, p.size + 1, dtype=np.float64))
    np.minimum.accumulate(q[::-1], out=q[::-1])
    out = np.empty_like(q)
    out[order] = q
    return np.clip(out, 0.0, 1.0)


def chi2_equivalent(x, df, k=1):
    """The chi2(``k``) value with the upper tail of chi2(``df``) at ``x``: ``chi2.isf(chi2.sf(x, df), k)``.

    Puts likelihood ratios with different degrees of freedom on one scale (a
    two-parameter effect's LR on that of one-parameter effects) with their
    p-values kept. Far in the tail, where the p-value underflows, the
    chi-square tails' leading terms ``-x/2 + (df/2 - 1) log(x/2) - lgamma(df/2)``
    are equated instead (monotone in ``x``). Identity when ``df == k``.
    """
    x, df, k = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(df, dtype=np.float64),
                                   np.asarray(k, dtype=np.float64))
    out = np.array(x, dtype=np.float64, copy=True)
    todo = (df != k) & (x > 0)
    if todo.any():
        xs, d, kk = x[todo], df[todo], k[todo]
        logp = np.asarray(chi2_logsf(xs, d), dtype=np.float64)
        y = np.empty_like(xs)
        near = logp > -600.0
        y[near] = special.chdtri(kk[near], np.exp(logp[near]))
        far = ~near
        if far.any():
            target = (-xs[far] / 2 + (d[far] / 2 - 1) * np.log(xs[far] / 2) - special.gammaln(d[far] / 2)
                      + special.gammaln(kk[far] / 2))
            yf = xs[far].copy()
            for _ in range(4):                       # y = -2 target + (k - 2) log(y / 2), a contraction here
                yf = -2.0 * target + (kk[far] - 2.0) * np.log(yf / 2.0)
            y[far] = yf
        out[todo] = y
    return out[()] if out.ndim == 0 else out
