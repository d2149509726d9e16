"""Exact worst case of the linear error model over a budget's bounded support.

Every H_q of eq. (8) is diagonal, so all errors of leg i act through one
scalar: the pose error is ``A^-1 u`` with ``u_i = sum_q h_q,i dq_i``. Each model
term (one per input; a clearance rho_i, zeta_i is the single term
``rho_i cos(zeta_i - omega_i)``) ranges over an interval, so u ranges over a
3-D box and the pose error over its image under A^-1. The position error
therefore fills a planar zonotope with just three generators (the first two
rows of the columns of A^-1, scaled by the half-widths of u), whose vertices
are among the images of the box's 8 corners: a convex function such as the
norm peaks at one of them, so the maximum is exact after 8 evaluations per
pose, with no search. For a scalar output (dx, dy, dphi) the maximum of
``|c + sum_i g_i s_i|`` is ``|c| + sum_i |g_i|``.

A clearance only enters the linear model through the component of its
displacement along E l_i (the component along l_i is taken up by the passive
joint), which is why it adds a segment, not a disc.

A budget's effects are terms of the same kind: a known shift (offset, lead
scale) is a term of zero width that moves the centre, a backlash of leg i
widens u_i's interval by ±h_i/2, and thermal expansion, one temperature for
all legs, moves u along ``alpha_T (h_b,i b_i)_i``: a fourth generator, so the
maximum is over the 16 corners (exact all the same).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._threads import check_stop, cores
from .._result import FrozenDict, freeze, pose_columns, short_repr
from .._version import __version__
from ..errors import InfeasiblePoseError
from ..units import OUTPUT_UNITS, RAD2DEG
from ..model.budget import Budget
from ..kinematics.geometry import Geometry
from ..kinematics.chain import as_poses, nonfinite_pose, pose_array, refusal
from ..kinematics.formulas import cos_range
from ..model.linear import LinearModel, linear_model
from ._kernel import (NONFINITE, REASONS, TERM_COLUMNS, envelope_kernel, generator_signs, kernel_tables,
                        zonotope_maxima, zonotope_scratch)

__all__ = ["WorstCaseResult", "worst_case", "WorstCaseMaxima", "worst_case_maxima", "term_bounds", "QUANTITIES",
           "CORRELATION_NOTE"]

#: What outputs say of the worst case of a correlated budget: it is unchanged, the box.
CORRELATION_NOTE = ("The worst case is the maximum over the box of every input's range: a rank correlation "
                    "(the budget's [correlation] table) leaves each input its full range and every corner of the "
                    "box possible, so it does not change the worst case.")

#: Quantities maximised: the position-error norm, ``|dphi|``, ``|dx|`` and ``|dy|``.
QUANTITIES = ("position", "phi", "x", "y")


class _Maxima:
    """The maxima's accessors shared by :class:`WorstCaseResult` and :class:`WorstCaseMaxima`."""

    __slots__ = ()

    def value(self, quantity: str) -> np.ndarray:
        """The maximum of ``quantity`` (one of :data:`QUANTITIES`)."""
        return {"position": self.position_mm, "phi": self.phi_deg, "x": self.x_mm, "y": self.y_mm}[quantity]

    def to_frame(self) -> pd.DataFrame:
        """Tidy table of the maxima: x_mm, y_mm, phi_deg, output, statistic (``worst_case``), value, unit."""
        cols = pose_columns(self.poses)
        return pd.concat([pd.DataFrame({**cols, "output": q, "statistic": "worst_case",
                                        "value": self.value(q).ravel(), "unit": OUTPUT_UNITS[q]})
                          for q in QUANTITIES], ignore_index=True)


@dataclass(frozen=True, slots=True, repr=False)
class WorstCaseResult(_Maxima):
    """Exact worst case of the linear model at a batch of poses.

    Attributes
    ----------
    model : LinearModel
        The linear model at the poses (its poses, terms, A^-1, term scales
        and clearance directions).
    term_bounds : ndarray (..., T, 2)
        Interval of every term, mm or deg (the clearance term's is
        pose-dependent when its contact angle is restricted).
    position_mm, phi_deg, x_mm, y_mm : ndarray (...)
        Largest position-error norm, ``|dphi|``, ``|dx|`` and ``|dy|``.
    leg_signs : dict of str to ndarray (..., 3)
        For each quantity, the sign of each leg's u_i (-1 lower end, +1
        upper end of its interval) at the maximiser.
    input_bounds : ndarray (D, 2)
        The interval of every factor used (:attr:`inputs`), mm or deg
        (degrees C for thermal).
    k_sigma : float or None
        How unbounded laws were bounded (mean ± k·sd), if any.
    shared_signs : dict of str to ndarray (..., G)
        For each quantity, the end (-1, +1) of each term of all legs
        (thermal) at the maximiser; G = 0 without such a term.
    term_at, inputs_at, contribution : dict of str to ndarray
        Computed on access from :attr:`signs` (see the properties).
    """

    model: LinearModel
    term_bounds: np.ndarray
    position_mm: np.ndarray
    phi_deg: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    leg_signs: dict
    input_bounds: np.ndarray
    k_sigma: float | None = None
    shared_signs: dict = field(default_factory=dict)
    version: str = __version__

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "terms", "k_sigma")

    @property
    def poses(self) -> np.ndarray:
        """Poses ``[x_mm, y_mm, phi_deg]``, shape (..., 3)."""
        return self.model.poses

    @property
    def terms(self) -> tuple:
        """Model terms (inputs except zeta_i, ``rho_i`` the clearance term; then the budget's effects)."""
        return self.model.terms

    @property
    def inputs(self) -> tuple:
        """The budget's factors (for :attr:`inputs_at`): its inputs, then backlash_i and thermal effects."""
        return self.model.budget.factors

    @property
    def signs(self) -> dict:
        """For each quantity, which end of every term's interval (-1, +1) realises the maximum."""
        legs = np.array(self.model.legs, dtype=int)
        term_sign = np.where(self.model.scale >= 0, 1.0, -1.0)
        out = {}
        for q, ls in self.leg_signs.items():
            s = ls[..., np.maximum(legs, 0)] * term_sign
            for g, t in enumerate(self.model.shared):
                s[..., t] = self.shared_signs[q][..., g]
            out[q] = s
        return out

    @property
    def term_at(self) -> dict:
        """Term values (..., T) at the maximiser of each quantity, mm or deg."""
        mid = self.term_bounds.mean(axis=-1)
        half = 0.5 * (self.term_bounds[..., 1] - self.term_bounds[..., 0])
        return {q: mid + s * half for q, s in self.signs.items()}

    @property
    def contribution(self) -> dict:
        """Each term's part (..., T) of the maximum of each quantity, mm or deg; sums to it.

        For the norm, the projection of the term's error on the maximal error
        vector; for ``|dx|``, ``|dy|``, ``|dphi|``, the term's signed share.
        """
        out = {}
        columns = self.model.columns
        for q, t_val in self.term_at.items():
            err = columns * t_val[..., None, :]                 # (..., 3, T)
            if q == "position":
                total = err[..., :2, :].sum(-1)
                norm = self.position_mm[..., None]
                unit = np.divide(total, norm, out=np.zeros_like(total), where=norm > 0)
                out[q] = np.einsum("...ot,...o->...t", err[..., :2, :], unit)
            else:
                o = {"phi": 2, "x": 0, "y": 1}[q]
                sign = np.where(err[..., o, :].sum(-1) >= 0, 1.0, -1.0)
                out[q] = sign[..., None] * err[..., o, :] * (RAD2DEG if q == "phi" else 1.0)
        return out

    @property
    def inputs_at(self) -> dict:
        """Factor values (..., D) at the maximiser of each quantity, mm or deg (degrees C for thermal).

        A clearance's rho_i and contact angle zeta_i are those realising its
        term's chosen end.
        """
        out = {}
        omega = self.model.omega
        signs = self.signs
        for q, t_val in self.term_at.items():
            x = np.empty(self.poses.shape[:-1] + (len(self.inputs),))
            for t, tl in enumerate(self.model.term_laws):
                if tl.kind == "clearance":
                    k, kz = tl.factors
                    _, (rho_lo, z_lo), (rho_hi, z_hi) = _clearance_interval(
                        self.input_bounds[k], self.input_bounds[kz], omega[..., tl.leg])
                    upper = signs[q][..., t] > 0
                    x[..., k] = np.where(upper, rho_hi, rho_lo)
                    x[..., kz] = np.where(upper, z_hi, z_lo)
                elif tl.kind == "factor":
                    x[..., tl.factors[0]] = t_val[..., t] + tl.reference
            out[q] = x
        return out

    def contributions_frame(self, quantity: str = "position", index: tuple | None = None) -> pd.DataFrame:
        """Per pose and term: the maximiser's term value, its contribution and share of the maximum.

        Columns: x_mm, y_mm, phi_deg, output, term, term_value (mm or deg;
        an effect's own value for a known shift, T - 20 K for thermal),
        contribution (the output's unit), share (of the maximum, 0-1). A
        known shift's contribution is systematic: it is there at every sample.
        ``index`` (indices into ``poses.shape[:-1]``): the rows of that pose only.
        """
        T = len(self.terms)
        at = (lambda a: np.asarray(a)) if index is None else (lambda a: np.asarray(a)[index])
        total = at(self.value(quantity)).reshape(-1, 1)
        contrib = at(self.contribution[quantity]).reshape(-1, T)
        share = np.divide(contrib, total, out=np.zeros_like(contrib), where=total > 0)
        return pd.DataFrame({
            **pose_columns(at(self.poses), repeat=T), "output": quantity, "term": np.tile(self.terms, len(total)),
            "term_value": at(self.term_at[quantity]).reshape(-1, T).ravel(),
            "contribution": contrib.ravel(), "share": share.ravel(),
        })

    def maximizer(self, quantity: str = "position", index=()) -> dict:
        """The inputs (mm, deg) that realise the maximum of ``quantity`` at pose ``index``."""
        values = self.inputs_at[quantity][index]
        return {name: float(v) for name, v in zip(self.inputs, values)}


def _clearance_interval(rho_bounds, zeta_bounds_deg, omega: np.ndarray):
    """Interval of rho cos(zeta - omega) over the box, and (rho, zeta_deg) at each end.

    Returns ``((lo, hi), (rho_at_lo, zeta_at_lo), (rho_at_hi, zeta_at_hi))``,
    each array shaped like ``omega``.
    """
    rlo, rhi = rho_bounds
    zlo, zhi = zeta_bounds_deg
    if zhi - zlo >= 360.0:  # full circle: the contact can point along -E l_i or +E l_i
        cmin, amin = np.full(np.shape(omega), -1.0), np.full(np.shape(omega), math.pi)
        cmax, amax = np.full(np.shape(omega), 1.0), np.zeros(np.shape(omega))
    else:
        cmin, amin, cmax, amax = cos_range(np.deg2rad(zlo) - omega, np.deg2rad(zhi) - omega)
    rho_hi_end = np.where(cmax >= 0, rhi, rlo)
    rho_lo_end = np.where(cmin <= 0, rhi, rlo)
    to_deg = lambda a: np.mod(np.rad2deg(a + omega), 360.0)  # noqa: E731
    return ((rho_lo_end * cmin, rho_hi_end * cmax), (rho_lo_end, to_deg(amin)), (rho_hi_end, to_deg(amax)))


def term_bounds(model: LinearModel, bounds: np.ndarray) -> np.ndarray:
    """Interval of every model term, shape (..., T, 2), mm or deg; ``bounds`` (D, 2) of the factors."""
    tb = np.empty(model.poses.shape[:-1] + (len(model.terms), 2))
    for t, tl in enumerate(model.term_laws):
        if tl.kind == "factor":
            tb[..., t, :] = bounds[tl.factors[0]] - tl.reference
            continue
        if tl.kind == "shift":
            tb[..., t, :] = tl.value
            continue
        k, kz = tl.factors
        leg = tl.leg
        zeta = bounds[kz]
        if zeta[1] - zeta[0] >= 360.0:  # no need for omega itself
            tb[..., t, 0], tb[..., t, 1] = -bounds[k][1], bounds[k][1]
        else:
            (lo, hi), _, _ = _clearance_interval(bounds[k], zeta, model.omega[..., leg])
            tb[..., t, 0], tb[..., t, 1] = lo, hi
    return tb


def _maxima(model: LinearModel, tb: np.ndarray):
    """Maxima and the sign (-1, +1) of each generator realising them, for flat poses (N,).

    Returns ``values`` (position mm, |dphi| rad, |dx| mm, |dy| mm), each (N,),
    and ``signs``, each (N, 3 + G): each leg's u_i, then each term of all legs.
    """
    mid = 0.5 * (tb[..., 0] + tb[..., 1])                            # (N, T)
    half = 0.5 * (tb[..., 1] - tb[..., 0])
    onehot = (np.array(model.legs)[:, None] == np.arange(3)).astype(float)   # (T, 3); none for all-leg terms
    scale = model.scale
    u_mid = (scale * mid) @ onehot                                   # (N, 3)
    u_half = (np.abs(scale) * half) @ onehot
    shared = list(model.shared)
    ext = np.ascontiguousarray(np.moveaxis(model.weights[..., :, shared] * half[..., None, shared], -1, -2))
    u_mid += np.einsum("nit,nt->ni", model.weights[..., :, shared], mid[..., shared])
    N = u_mid.shape[0]
    values, codes = np.empty((4, N)), np.empty((4, N), dtype=np.int16)
    Ai = np.ascontiguousarray(np.moveaxis(model.Ainv, 0, -1))          # (3, 3, N): poses last
    zonotope_maxima(Ai, np.ascontiguousarray(u_mid.T), np.ascontiguousarray(u_half.T),
                    np.ascontiguousarray(np.moveaxis(ext, 0, -1)), values, codes, 0, N,
                    zonotope_scratch(3 + len(shared), N))
    order = ("position", "phi", "x", "y")
    return dict(zip(order, values)), dict(zip(order, generator_signs(codes, 3 + len(shared)).astype(float)))


def worst_case(geometry: "Geometry | str", budget: "Budget | str", poses, *, k_sigma: float | None = None,
               check: bool = True, workers: int | None = None, chunk: int = 16384) -> WorstCaseResult:
    """Exact maxima of the linear pose error over the budget's box, batched.

    Parameters
    ----------
    geometry : Geometry or str
        A Geometry, preset name or TOML path.
    budget : Budget or str
        A Budget, preset name or TOML path.
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    k_sigma : float, optional
        Bound unbounded laws (normal) as mean ± k_sigma·sd; without it such
        a budget is refused.
    workers, chunk : int
        Large batches are split into chunks of ``chunk`` poses evaluated on
        ``workers`` threads (default: CPU count); numpy releases the GIL.

    Returns
    -------
    WorstCaseResult

    Examples
    --------
    >>> from prp3mc import Geometry, Budget, worst_case
    >>> wc = worst_case(Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0, 100, 0])
    >>> round(1000 * float(wc.position_mm))  # µm
    140
    """
    geometry, budget = Geometry.load(geometry), Budget.load(budget)
    bounds = budget.bounds(k_sigma)
    poses = as_poses(poses)
    flat = poses.reshape(-1, 3) if poses.ndim > 1 else poses[None]

    def run(sl: slice):
        check_stop()
        model = linear_model(geometry, budget, flat[sl], check=check)
        tb = term_bounds(model, bounds)
        values, signs = _maxima(model, tb)
        return model, tb, values, signs

    n = flat.shape[0]
    slices = [slice(a, min(n, a + chunk)) for a in range(0, n, chunk)]
    if len(slices) == 1:
        parts = [run(slices[0])]
    else:
        with ThreadPoolExecutor(max_workers=workers or cores()) as pool:
            parts = list(pool.map(run, slices))
    shape = poses.shape[:-1]

    def join(get, tail=()):
        arrs = [get(p) for p in parts]
        return (arrs[0] if len(arrs) == 1 else np.concatenate(arrs)).reshape(shape + tail)

    T = len(parts[0][0].terms)
    G = len(parts[0][0].shared)
    model = dataclasses.replace(parts[0][0], poses=poses, Ainv=join(lambda p: p[0].Ainv, (3, 3)),
                                weights=join(lambda p: p[0].weights, (3, T)),
                                cos_omega=join(lambda p: p[0].cos_omega, (3,)),
                                sin_omega=join(lambda p: p[0].sin_omega, (3,)))
    signs = {q: join(lambda p, q=q: p[3][q], (3 + G,)) for q in QUANTITIES}
    return WorstCaseResult(
        model=model, term_bounds=join(lambda p: p[1], (T, 2)),
        position_mm=join(lambda p: p[2]["position"]), phi_deg=join(lambda p: p[2]["phi"]) * RAD2DEG,
        x_mm=join(lambda p: p[2]["x"]), y_mm=join(lambda p: p[2]["y"]),
        leg_signs={q: s[..., :3] for q, s in signs.items()}, input_bounds=bounds,
        k_sigma=k_sigma, shared_signs={q: s[..., 3:] for q, s in signs.items()})


@dataclass(frozen=True, slots=True, repr=False)
class WorstCaseMaxima(_Maxima):
    """The maxima of :class:`WorstCaseResult` alone, for grids too large to keep the model (see
    :func:`worst_case_maxima`): the kernel's two output arrays, read through named views.

    Attributes
    ----------
    poses : ndarray (..., 3)
    maxima : ndarray (4, ...)
        Rows :attr:`position_mm`, :attr:`phi_deg`, :attr:`x_mm`, :attr:`y_mm`.
    codes : ndarray (4, ...), int16
        For each quantity, the end of each of the 3 + ``n_shared`` generators at the
        maximum, one bit each (unpacked on access by :attr:`leg_signs` and :attr:`shared_signs`).
    n_shared : int
        Terms of all legs (thermal): generators after the legs' three.
    input_bounds : ndarray (D, 2)
    k_sigma : float or None
    """

    poses: np.ndarray
    maxima: np.ndarray
    codes: np.ndarray
    n_shared: int
    input_bounds: np.ndarray
    k_sigma: float | None = None
    version: str = __version__

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "k_sigma")

    position_mm = property(lambda self: self.maxima[0], doc="Largest position-error norm at each pose (...), mm.")
    phi_deg = property(lambda self: self.maxima[1], doc="Largest ``|dphi|`` at each pose (...), deg.")
    x_mm = property(lambda self: self.maxima[2], doc="Largest ``|dx|`` at each pose (...), mm.")
    y_mm = property(lambda self: self.maxima[3], doc="Largest ``|dy|`` at each pose (...), mm.")

    @property
    def leg_signs(self) -> FrozenDict:
        """As :attr:`WorstCaseResult.leg_signs`: quantity to the legs' ends (..., 3), int8, unpacked on each access."""
        return FrozenDict(zip(QUANTITIES, generator_signs(self.codes, 3 + self.n_shared)[..., :3]))

    @property
    def shared_signs(self) -> FrozenDict:
        """As :attr:`WorstCaseResult.shared_signs`: quantity to the ends (..., G) of the terms of all legs, int8,
        unpacked on each access."""
        return FrozenDict(zip(QUANTITIES, generator_signs(self.codes, 3 + self.n_shared)[..., 3:]))


#: The last (geometry, budget, k_sigma) of :func:`worst_case_maxima` and its kernel tables: a loop of
#: small batches (an allocation search, a sweep) finds them by identity, without hashing either. One
#: tuple, replaced whole: a thread reads a consistent one.
_last: list = [(None, None, None, None)]


def _prepared(geometry: Geometry, budget: Budget, k_sigma: float | None) -> tuple:
    """``(bounds, tables, G)`` of :func:`~prp3mc.worstcase._kernel.kernel_tables`, checked and cached."""
    g, b, k, prepared = _last[0]
    if g is geometry and b is budget and k == k_sigma:
        return prepared
    budget.check_geometry(geometry)
    bounds, *tables = kernel_tables(geometry, budget, k_sigma)
    prepared = bounds, tables, int((tables[1][:, TERM_COLUMNS.index("leg")] < 0).sum())
    _last[0] = geometry, budget, k_sigma, prepared
    return prepared


def worst_case_maxima(geometry: Geometry, budget: Budget, poses, *, k_sigma: float | None = None,
                      check: bool = True) -> WorstCaseMaxima:
    """The maxima of :func:`worst_case` from one fused compiled pass over the poses.

    Per pose the kernel computes the inverse kinematics, A^-1, the h entries
    of the budget's terms, the clearance intervals and the 8-corner maxima
    over blocks of poses, on all cores; nothing per pose is kept but the maxima and
    the ends of their generators (42 bytes with the refusal word), so memory is that
    of the poses and the result.
    The values equal :func:`worst_case`'s to round-off (1e-12 relative).

    Parameters
    ----------
    geometry, budget, poses, k_sigma, check
        As :func:`worst_case`; a refused pose raises the same
        :class:`~prp3mc.errors.InfeasiblePoseError`.

    Returns
    -------
    WorstCaseMaxima

    Examples
    --------
    >>> from prp3mc import Geometry, Budget, Region
    >>> from prp3mc.worstcase.envelope import worst_case_maxima
    >>> grid = Region.from_preset("u-shape").grid(11)
    >>> worst_case_maxima(Geometry.from_preset("u-shape"), Budget.from_preset("paper"), grid).position_mm.shape
    (11, 11)
    """
    bounds, tables, G = _prepared(geometry, budget, k_sigma)
    poses = pose_array(poses)
    flat = np.ascontiguousarray(poses.reshape(-1, 3))
    n, shape = flat.shape[0], (4,) + poses.shape[:-1]
    maxima, codes, bad = np.empty(shape), np.empty(shape, dtype=np.int16), np.empty(n, dtype=np.uint16)
    if envelope_kernel(flat, *tables, check, maxima.reshape(4, n), codes.reshape(4, n), bad):
        raise _first_refusal(geometry, poses, flat, bad)
    maxima.setflags(write=False)    # nothing for the result's freeze to copy
    codes.setflags(write=False)
    return WorstCaseMaxima(poses=poses, maxima=maxima, codes=codes,
                           n_shared=G, input_bounds=bounds, k_sigma=k_sigma)


def _first_refusal(geometry: Geometry, poses: np.ndarray, flat: np.ndarray, bad: np.ndarray) -> InfeasiblePoseError:
    """The error :func:`worst_case` raises for the kernel's refusals ``bad`` (N,) at ``flat`` (N, 3):
    a pose holding NaN first (as :func:`~prp3mc.kinematics.chain.as_poses`), then by reason."""
    if (bad & NONFINITE).any():
        return nonfinite_pose(poses)
    r, p = next((r, hit[0]) for r in range(len(REASONS)) if (hit := np.flatnonzero(bad & (0b111 << 3 * r))).size)
    leg = next(i for i in range(3) if bad[p] >> (3 * r + i) & 1)
    return InfeasiblePoseError(refusal(geometry, flat[p], (int(p),), REASONS[r], leg))  # the flat index, as worst_case


def __getattr__(name: str):
    """``WorstCase``, the former name of :class:`WorstCaseResult`, for one release (with a DeprecationWarning)."""
    if name == "WorstCase":
        warnings.warn("WorstCase is now WorstCaseResult (the name WorstCase goes in the next release)",
                      DeprecationWarning, stacklevel=2)
        return WorstCaseResult
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
