"""Figures of the exact yield against a spec: the exceedance curve on a log axis.

Drawn on the axes they are handed; no pyplot unless none is given.
"""

from __future__ import annotations

import numpy as np

from ..units import DEG2ARCSEC, MM2UM

__all__ = ["exceedance_plot", "EXCEEDANCE_FLOOR"]

#: The smallest probability an exceedance curve shows (1e-9: below it, the engine's error bound).
EXCEEDANCE_FLOOR = 1e-9
_NAMES = {"position": ("position error", "µm", MM2UM), "phi": ("|δφ|", "arcsec", DEG2ARCSEC)}


def exceedance_plot(curve, *, ax=None, title: str = ""):
    """P(output > s) against s on a log axis, 1 down to 1e-9: exact, Monte Carlo points, the spec line.

    Parameters
    ----------
    curve : prp3mc.study.spec.ExceedanceCurve
        The exact curve (with its error bound), the Monte Carlo points with their
        95 % Wilson intervals (a point with no sample beyond s is drawn at its
        interval's upper end, marked ▽), the spec and the worst case at the pose.
    ax : matplotlib Axes, optional
    title : str

    Returns
    -------
    Figure
    """
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots(figsize=(8.8, 3.8), layout="constrained")
    name, unit, scale = _NAMES[curve.output]
    s = scale * np.asarray(curve.s)
    exact = np.where(curve.exact > 0, curve.exact, np.nan)       # a log axis has no zero
    ax.semilogy(s, exact, color="C0", lw=1.6, label="exact (error bound ≤ %.1g)" % float(np.max(curve.bound)))
    if curve.mc_s is not None:
        ms, p, ci = scale * np.asarray(curve.mc_s), np.asarray(curve.mc_p), np.asarray(curve.mc_ci)
        seen = p > 0
        lo, hi = np.maximum(ci[:, 0], EXCEEDANCE_FLOOR), ci[:, 1]
        ax.errorbar(ms[seen], p[seen], yerr=[p[seen] - lo[seen], hi[seen] - p[seen]], fmt="o", ms=3.5,
                    color="C1", capsize=2, lw=1, label=f"Monte Carlo, 95 % interval ({curve.n_samples} samples)")
        if (~seen).any():
            ax.plot(ms[~seen], hi[~seen], "v", ms=4.5, color="C1", mfc="none",
                    label="Monte Carlo: none beyond, 95 % upper bound")
    ax.axvline(scale * curve.spec, color="C3", ls="--", lw=1.2, label=f"spec {scale * curve.spec:.4g} {unit}")
    if np.isfinite(curve.worst):
        ax.axvline(scale * curve.worst, color="0.4", ls=":", lw=1.2,
                   label=f"worst case {scale * curve.worst:.4g} {unit}")
    ax.set_ylim(EXCEEDANCE_FLOOR, 1.5)
    ax.set_yticks([1e-9, 1e-6, 1e-3, 1.0], ["1e-9", "1e-6", "1e-3", "1"])
    ax.set_xlim(s.min(), s.max() * 1.02)
    ax.set(xlabel=f"{name} s ({unit})", ylabel=f"P({name} > s)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7, frameon=False, loc="upper left", bbox_to_anchor=(1.02, 1.0))   # right of the curve
    x, y, phi = curve.pose
    ax.set_title(f"{title + ': ' if title else ''}{name} at x = {x:.4g}, y = {y:.4g} mm, φ = {phi:.4g}°",
                 fontsize=10)
    return ax.figure
