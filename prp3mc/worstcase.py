"""Exact worst case of the linear error model over a budget's bounded support.

Every term t_k of the model (one per input; a clearance rho_i, zeta_i is the
single term rho_i cos(zeta_i - omega_i)) ranges over an interval
[lo_k, hi_k], so the position error ``c + sum_k g_k s_k`` with
``s_k in [-1, 1]`` fills a 2-D zonotope: a Minkowski sum of segments. A convex
function (the norm) peaks at a vertex, and a planar zonotope with T
generators has at most 2T vertices, found exactly by sorting the generators
by angle (no search). For a scalar output (dx, dy, dphi) the maximum of
``|c + sum g_k s_k|`` is ``|c| + sum |g_k|``.

A clearance only enters the linear model through the component of its
displacement along E l_i (the component along l_i is taken up by the passive
joint), which is why it adds a segment, not a disc.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ._version import __version__
from .budget import Budget, parse_input
from .geometry import Geometry
from .model import LinearModel, linear_model

__all__ = ["WorstCase", "worst_case", "QUANTITIES"]

#: Quantities maximised: the position-error norm, |dphi|, |dx| and |dy|.
QUANTITIES = ("position", "phi", "x", "y")
_RAD2DEG = 180.0 / math.pi


@dataclass(frozen=True, slots=True)
class WorstCase:
    """Exact worst case of the linear model at a batch of poses.

    Attributes
    ----------
    poses : ndarray (..., 3)
    terms : tuple of str
        Model terms (inputs except zeta_i; ``rho_i`` is the clearance term).
    inputs : tuple of str
        Budget input names (for :attr:`inputs_at`).
    term_bounds : ndarray (..., T, 2)
        Interval of every term, mm or deg (the clearance term's is
        pose-dependent when its contact angle is restricted).
    position_mm, phi_deg, x_mm, y_mm : ndarray (...)
        Largest position-error norm, |dphi|, |dx| and |dy|.
    term_at : dict of str to ndarray (..., T)
        Term values at the maximiser of each quantity.
    inputs_at : dict of str to ndarray (..., d)
        Input values (mm, deg) at the maximiser; for a clearance, rho_i and
        the contact angle zeta_i that realise it.
    contribution : dict of str to ndarray (..., T)
        Each term's part of the maximum (mm or deg), summing to it: for the
        norm, the projection of the term's error on the maximal error vector.
    k_sigma : float or None
        How unbounded laws were bounded (mean ± k·sd), if any.
    """

    poses: np.ndarray
    terms: tuple
    inputs: tuple
    term_bounds: np.ndarray
    position_mm: np.ndarray
    phi_deg: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    term_at: dict
    inputs_at: dict
    contribution: dict
    k_sigma: float | None = None
    version: str = __version__

    def value(self, quantity: str) -> np.ndarray:
        """The maximum of ``quantity`` (one of :data:`QUANTITIES`)."""
        return {"position": self.position_mm, "phi": self.phi_deg, "x": self.x_mm, "y": self.y_mm}[quantity]

    def to_frame(self) -> pd.DataFrame:
        """Tidy table of the maxima: x_mm, y_mm, phi_deg, quantity, value, unit."""
        flat = self.poses.reshape(-1, 3)
        frames = []
        for q, unit in zip(QUANTITIES, ("mm", "deg", "mm", "mm")):
            frames.append(pd.DataFrame({"x_mm": flat[:, 0], "y_mm": flat[:, 1], "phi_deg": flat[:, 2],
                                        "quantity": q, "value": self.value(q).ravel(), "unit": unit}))
        return pd.concat(frames, ignore_index=True)

    def contributions_frame(self, quantity: str = "position") -> pd.DataFrame:
        """Per pose and term: the maximiser's term value, its contribution and share of the maximum."""
        flat = self.poses.reshape(-1, 3)
        n, T = flat.shape[0], len(self.terms)
        total = self.value(quantity).reshape(n, 1)
        contrib = self.contribution[quantity].reshape(n, T)
        share = np.divide(contrib, total, out=np.zeros_like(contrib), where=total > 0)
        idx = np.repeat(np.arange(n), T)
        return pd.DataFrame({
            "x_mm": flat[idx, 0], "y_mm": flat[idx, 1], "phi_deg": flat[idx, 2],
            "quantity": quantity, "term": np.tile(self.terms, n),
            "term_value": self.term_at[quantity].reshape(n, T).ravel(),
            "contribution": contrib.ravel(), "share": share.ravel(),
        })

    def maximizer(self, quantity: str = "position", index=()) -> dict:
        """The inputs (mm, deg) that realise the maximum of ``quantity`` at pose ``index``."""
        values = self.inputs_at[quantity][index]
        return {name: float(v) for name, v in zip(self.inputs, values)}


def _cos_range(lo: np.ndarray, hi: np.ndarray):
    """Min and max of cos over [lo, hi] (rad, hi - lo < 2 pi) and the arguments attaining them."""
    two_pi = 2 * math.pi
    has_max = np.ceil(lo / two_pi) * two_pi <= hi
    arg_max = np.where(has_max, np.ceil(lo / two_pi) * two_pi,
                       np.where(np.cos(lo) >= np.cos(hi), lo, hi))
    has_min = np.ceil((lo - math.pi) / two_pi) * two_pi + math.pi <= hi
    arg_min = np.where(has_min, np.ceil((lo - math.pi) / two_pi) * two_pi + math.pi,
                       np.where(np.cos(lo) <= np.cos(hi), lo, hi))
    return np.cos(arg_min), arg_min, np.cos(arg_max), arg_max


def _term_bounds(model: LinearModel, bounds: np.ndarray):
    """Term intervals (..., T, 2) and, per clearance term, (rho, zeta_deg) at each end."""
    shape = model.poses.shape[:-1]
    names = model.budget.names
    T = len(model.terms)
    tb = np.empty(shape + (T, 2))
    ends = {}
    for t, term in enumerate(model.terms):
        family, leg = parse_input(term)
        k = names.index(term)
        if family != "rho":
            tb[..., t, :] = bounds[k]
            continue
        rlo, rhi = bounds[k]
        zlo, zhi = bounds[names.index(f"zeta_{leg + 1}")]
        omega = model.omega[..., leg]
        if zhi - zlo >= 360.0:
            cmin, amin = np.full(shape, -1.0), np.full(shape, math.pi)
            cmax, amax = np.full(shape, 1.0), np.zeros(shape)
        else:
            cmin, amin, cmax, amax = _cos_range(np.deg2rad(zlo) - omega, np.deg2rad(zhi) - omega)
        rho_hi_end = np.where(cmax >= 0, rhi, rlo)
        rho_lo_end = np.where(cmin <= 0, rhi, rlo)
        tb[..., t, 0] = rho_lo_end * cmin
        tb[..., t, 1] = rho_hi_end * cmax
        to_deg = lambda a: np.mod(np.rad2deg(a + omega), 360.0)  # noqa: E731
        ends[t] = ((rho_lo_end, to_deg(amin)), (rho_hi_end, to_deg(amax)))
    return tb, ends


def _zonotope_max_norm(center: np.ndarray, gens: np.ndarray):
    """Max of |c + sum_k s_k g_k| over s in [-1, 1]^T, exactly, batched.

    Parameters
    ----------
    center : (..., 2)
    gens : (..., T, 2)

    Returns
    -------
    value : (...)
    signs : (..., T) of ±1 attaining it
    """
    flip = (gens[..., 1] < 0) | ((gens[..., 1] == 0) & (gens[..., 0] < 0))
    g = np.where(flip[..., None], -gens, gens)                     # upper half-plane
    order = np.argsort(np.arctan2(g[..., 1], g[..., 0]), axis=-1)
    gs = np.take_along_axis(g, order[..., None], axis=-2)
    T = gs.shape[-2]
    # vertex j (j = 0..T): the first j sorted generators at +1, the rest at -1; and mirror images
    cum = np.concatenate([np.zeros(gs.shape[:-2] + (1, 2)), np.cumsum(gs, axis=-2)], axis=-2)
    base = center[..., None, :] - gs.sum(axis=-2)[..., None, :]
    verts = base + 2 * cum                                         # (..., T+1, 2)
    mirror = 2 * center[..., None, :] - verts
    allv = np.concatenate([verts, mirror], axis=-2)
    norms = np.hypot(allv[..., 0], allv[..., 1])
    best = np.argmax(norms, axis=-1)
    value = np.take_along_axis(norms, best[..., None], -1)[..., 0]
    j = best % (T + 1)
    mirrored = best > T
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(T) * np.ones_like(order), axis=-1)
    s_sorted = np.where(rank < j[..., None], 1.0, -1.0)
    s_sorted = np.where(mirrored[..., None], -s_sorted, s_sorted)
    signs = np.where(flip, -s_sorted, s_sorted)
    return value, signs


def worst_case(geometry: Geometry, budget: Budget, poses, *, k_sigma: float | None = None,
               check: bool = True) -> WorstCase:
    """Exact maxima of the linear pose error over the budget's box, batched.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    k_sigma : float, optional
        Bound unbounded laws (normal) as mean ± k_sigma·sd; without it such
        a budget is refused.

    Returns
    -------
    WorstCase

    Examples
    --------
    >>> from prp3mc import Geometry, Budget, worst_case
    >>> wc = worst_case(Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0, 100, 0])
    >>> round(1000 * float(wc.position_mm))  # µm
    140
    """
    bounds = budget.bounds(k_sigma)
    model = linear_model(geometry, budget, poses, check=check)
    tb, ends = _term_bounds(model, bounds)
    mid = 0.5 * (tb[..., 0] + tb[..., 1])                            # (..., T)
    half = 0.5 * (tb[..., 1] - tb[..., 0])
    cols = model.columns                                             # (..., 3, T)
    center = np.einsum("...ot,...t->...o", cols, mid)
    gens = cols * half[..., None, :]                                 # (..., 3, T)

    pos, s_pos = _zonotope_max_norm(center[..., :2], np.swapaxes(gens[..., :2, :], -1, -2))
    signs = {"position": s_pos}
    values = {"position": pos}
    for o, q in ((2, "phi"), (0, "x"), (1, "y")):
        sc = np.where(center[..., o] >= 0, 1.0, -1.0)
        signs[q] = sc[..., None] * np.where(gens[..., o, :] >= 0, 1.0, -1.0)
        values[q] = np.abs(center[..., o]) + np.abs(gens[..., o, :]).sum(-1)

    term_at, contribution, inputs_at = {}, {}, {}
    names = budget.names
    for q, s in signs.items():
        t_val = mid + s * half
        term_at[q] = t_val
        err = cols * t_val[..., None, :]                             # (..., 3, T)
        if q == "position":
            total = err[..., :2, :].sum(-1)
            unit = np.divide(total, pos[..., None], out=np.zeros_like(total), where=pos[..., None] > 0)
            contribution[q] = np.einsum("...ot,...o->...t", err[..., :2, :], unit)
        else:
            o = {"phi": 2, "x": 0, "y": 1}[q]
            sign = np.where(err[..., o, :].sum(-1) >= 0, 1.0, -1.0)
            contribution[q] = sign[..., None] * err[..., o, :] * (_RAD2DEG if q == "phi" else 1.0)
        x = np.empty(model.poses.shape[:-1] + (len(names),))
        for t, term in enumerate(model.terms):
            k = names.index(term)
            if t in ends:
                (rho_lo, z_lo), (rho_hi, z_hi) = ends[t]
                upper = s[..., t] > 0
                x[..., k] = np.where(upper, rho_hi, rho_lo)
                x[..., names.index(f"zeta_{parse_input(term)[1] + 1}")] = np.where(upper, z_hi, z_lo)
            else:
                x[..., k] = t_val[..., t]
        inputs_at[q] = x
    return WorstCase(poses=model.poses, terms=model.terms, inputs=names, term_bounds=tb,
                     position_mm=pos, phi_deg=values["phi"] * _RAD2DEG, x_mm=values["x"],
                     y_mm=values["y"], term_at=term_at, inputs_at=inputs_at,
                     contribution=contribution, k_sigma=k_sigma)
