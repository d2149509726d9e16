"""The exact yield of the linear model against a position and orientation spec: :func:`exact_yield`."""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from scipy import special

from .._threads import check_stop, cores
from ..errors import NoExactYieldError, Prp3mcWarning, SpecError
from ..kinematics.chain import as_poses
from ..kinematics.geometry import Geometry
from ..limits import DEFAULT_TARGET, TARGET_RANGE
from ..model.budget import Budget
from ..model.linear import linear_model
from ..units import DEG2ARCSEC, DEG2RAD, MM2UM, RAD2DEG, spec_value
from ._special import special_args
from .characteristic import UNIFORM, term_table
from .conditional import CONDITIONAL_METHOD, independent_legs, joint_exceedance
from .enumeration import ENUMERATION_METHOD, all_discrete, discrete_yield
from .gaussian import gaussian_terms
from .lattice import LEVELS, channel, leg_powers, support_max
from .result import QUANTILE_LEVELS, YieldResult
from .series import batch_series

__all__ = ["exact_yield", "METHOD", "DEFAULT_TARGET", "TARGET_RANGE"]

METHOD = ("exact distribution of the linear model: Fourier series of its characteristic function (the "
          "product of the terms' closed forms) on a lattice whose periods keep the support off the spec's "
          "region, truncated with a rigorous bound (decreasing envelopes of every term, analytic tails); "
          "error bound = truncation + floating point (1e-13 per coefficient) + normal laws' mass past their cut")
#: What the method adds for a budget whose correlated inputs are all normal (:mod:`.gaussian`).
GAUSSIAN_METHOD = ("; the correlated inputs (all normal, so jointly normal) enter exactly as independent normal "
                   "terms: each input's own with sd x sqrt(smallest eigenvalue of the copula's correlation), and "
                   "the rest of their covariance as at most three standard normal terms along its principal "
                   "directions in the pose error")
#: Decay power every leg's envelopes need before the joint (3-D) series is tried: the paper's legs (three
#: uniform-like laws, power 3) would need ~1e12 lattice points for 1e-9; a leg with a normal law has power inf.
_JOINT_POWER = 6.0
#: Decay power every leg's envelopes need before P(either) is found by conditioning on two legs (each leg's
#: CDF series then needs at most ~1e5 terms for 1e-12; the paper's legs have power 3).
_LEG_POWER = 2.5
#: Poses at most at which :func:`exact_yield` conditions on two legs for P(either) by default (a 21 x 21 grid
#: is 441; about 0.1 to 0.3 s a pose).
JOINT_POSES = 1000
#: Tightest channel target P(either) by conditioning asks for, as a power of 1/4 of the target (4^-5: ~1e-12 for
#: the default 1e-9, the floor of TARGET_RANGE).
_TIGHTEN = 5
_CHUNK = 64                      # poses per task of the thread pool


def exact_yield(geometry, budget, poses, *, spec_position_um: float, spec_phi_arcsec: float | None = None,
                quantiles: bool = True, target: float = DEFAULT_TARGET, workers: int | None = None,
                joint: bool | None = None) -> YieldResult:
    """The exact distribution of the linear model's pose error against a spec, at a batch of poses.

    For each pose: P(``|(dx, dy)|`` > S), P(``|dphi|`` > Z), P(either), and the
    quantiles p99.73, p99.9937, p99.9999 of the position error and of ``|dphi|``,
    each with a guaranteed bound of its error; no sampling. The budget's
    inputs are independent, or correlated (``[correlation]``) between normal
    laws only (then jointly normal: :mod:`prp3mc.stackup.gaussian` makes them
    independent terms of the same joint law); its ``[effects]`` enter as in
    the other analyses (known shifts, backlash ±h/2 with probability 1/2
    each, one temperature uniform over its range). Every law prp3mc has is
    exact: uniform, normal, truncated normal, triangular, discrete classes,
    and the clearance rho cos(zeta - omega) with any radius law (the contact
    angle uniform over whole turns). A budget of discrete classes only has no
    density: its finitely many values are enumerated (:mod:`.enumeration`).

    Method (:mod:`prp3mc.stackup`): P(Y in D) for a channel Y of the pose
    error (dphi, the position, or both) and its spec region D (an interval, a
    disc, a cylinder) is the Fourier series of Y's characteristic function,
    ``prod_t phi_t(c_t . w)`` in closed form, on a lattice whose periods keep
    Y's support away from D (so the periodised density equals the density
    on D); it is summed over the lattice points a rigorous bound says matter,
    and the bound on everything left out (decreasing envelopes of every
    term's ``|phi_t|``, analytic power-law tails) is the reported error, with
    floating point and the mass of normal laws past their cut. Quantiles solve
    P(z) = p on the same series; their bracket P(z) = p -/+ bound bounds their error.

    P(either) needs the 3-D series, which converges in time only when every
    leg's characteristic function decays fast (a normal law in each leg, say).
    Otherwise, when every random term is of one leg but for a shared
    temperature (no correlated directions) and every leg has a density whose
    series converges, it is ``P_pos + P_phi - P(both out)``, the last by
    conditioning on two legs (and on the temperature's interval) and
    integrating the third through its CDF (:mod:`.conditional`): a rigorous
    bracket refined on cells, second order in their size where the integrand
    is smooth (first order elsewhere), so its bound meets the target where
    P(both out) is small (below ~6e-8) and stays above it where both specs
    bind together (2.2e-8 to 8.5e-4 for P(both out) on the paper's budget at
    the default cells, by the spec and pose: a warning says so). Else it is the midpoint of
    ``[max(P_pos, P_phi), P_pos + P_phi]`` with the half-width (plus both
    bounds) as its bound, flagged in ``bracketed_any``: the bound holds, but
    exceeds the target (a warning says so).

    Parameters
    ----------
    geometry : Geometry or str
        A Geometry, preset name or TOML path.
    budget : Budget or str
        A Budget, preset name or TOML path.
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``; poses out of stroke or near a singularity are refused.
    spec_position_um : float
        S, µm: the position error ``|(dx, dy)|`` must stay within it.
    spec_phi_arcsec : float, optional
        Z, arcsec: ``|dphi|`` must stay within it.
    quantiles : bool
        Compute the quantiles too (the most time-consuming part on grids).
    target : float
        Bound of the absolute error of every probability (default 1e-9, i.e. 1e-3 ppm); in [1e-12, 1e-2]
        (:data:`TARGET_RANGE`).
    workers : int, optional
        Threads (default: the CPU count).
    joint : bool, optional
        Find P(either) by conditioning where the 3-D series does not serve (about 0.1 to 0.3 s a pose): True
        always, False never (the bracket), None (default) when at most ``JOINT_POSES`` (1000) poses need it.

    Raises
    ------
    SpecError
        A spec or target out of range.
    BudgetError
        A budget with ``[correlation]`` between inputs not all normal (the message names the Monte Carlo
        fallback, :func:`prp3mc.monte_carlo` with ``tolerance_phi_deg``).
    NoExactYieldError
        A budget whose position has no 2-D density (one leg random; legs of discrete classes beside
        continuous ones), of discrete classes only with more than 2^20 combinations, or whose series needs
        more than 2^23 terms for the target (a subclass of BudgetError; ``prp3mc yield`` falls back on
        Monte Carlo).

    Returns
    -------
    YieldResult

    Examples
    --------
    >>> from prp3mc import exact_yield
    >>> r = exact_yield("u-shape", "paper", [0.0, 100.0, 0.0], spec_position_um=100.0)
    >>> round(float(r.exceed_position) * 1e6, 1), bool(r.error_bound < 1e-9)
    (1159.9, True)
    """
    t0 = time.perf_counter()
    S_um = spec_value("spec_position_um", spec_position_um)
    Z_as = None if spec_phi_arcsec is None else spec_value("spec_phi_arcsec", spec_phi_arcsec)
    lo, hi = TARGET_RANGE
    if isinstance(target, bool) or not isinstance(target, (int, float)) or not lo <= target <= hi:
        raise SpecError(f"target must be a probability in [{lo:g}, {hi:g}] (below {lo:g} floating point alone "
                        f"exceeds it), got {target!r}")
    geometry, budget = Geometry.load(geometry), Budget.load(budget)
    model = linear_model(geometry, budget, as_poses(poses, nonempty=True))
    shape = model.poses.shape[:-1]
    laws, legs, C = gaussian_terms(budget, model.term_laws, model.legs,
                                   model.columns.reshape(-1, 3, len(model.terms)))    # correlated normals: exact
    T = len(laws)
    n_normal = sum(1 for tl in laws if tl.law is not None and tl.law.kind == "normal" and tl.kind == "factor")
    share = 0.01 * target / max(n_normal, 1)        # mass of one normal law past its cut
    k_normal = math.sqrt(2.0) * float(special.erfcinv(share))
    table = term_table(laws, k_normal)
    C = np.ascontiguousarray(C)
    Ainv = model.Ainv.reshape(-1, 3, 3)
    N = C.shape[0]
    S, Z = S_um / MM2UM, (None if Z_as is None else Z_as / DEG2ARCSEC * DEG2RAD)
    legs = np.array(legs)
    levels = np.array(LEVELS if quantiles else (), dtype=float)
    if all_discrete(table):
        return _enumerated(model, shape, C, table, S, Z, levels, budget, target, t0)
    mean, cov = _moments(C, table)
    run = _Runner(table, workers, target, budget.name)

    # position
    pos, z1, zs, sure_pos = _sized("position", C, Ainv, legs, table, share, np.full(N, S), quantiles)
    lam2 = np.linalg.eigvalsh(cov[:, :2, :2])[:, -1]
    z0 = np.hypot(mean[:, 0], mean[:, 1])[:, None] + np.sqrt(-2.0 * np.log1p(-levels) * lam2[:, None])
    p_pos, b_pos, n_pos, s_pos, q_pos, qe_pos = run(pos, z1, np.zeros(N), zs, levels, z0, "the position error",
                                                    sure=sure_pos)
    # orientation
    p_phi = b_phi = q_phi = qe_phi = None
    n_phi = np.zeros(N, np.int64)
    phi = None
    sure_phi = np.zeros(N, dtype=bool)
    if quantiles or Z is not None:
        phi, z1, zs, sure_phi = _sized("phi", C, Ainv, legs, table, share, np.full(N, Z if Z is not None else 0.0),
                                       quantiles)
        z0 = np.abs(mean[:, 2])[:, None] + np.sqrt(cov[:, 2, 2])[:, None] * special.ndtri(0.5 + 0.5 * levels)
        p_phi, b_phi, n_phi, s_phi, q_phi, qe_phi = run(phi, z1, np.zeros(N), zs, levels, z0, "|dphi|",
                                                        sure=sure_phi)
    e_pos = np.clip(1.0 - p_pos, 0.0, 1.0)
    e_phi = None if Z is None else np.clip(1.0 - p_phi, 0.0, 1.0)
    # either: the joint series where it converges; else the bracket [max(P_pos, P_phi), P_pos + P_phi]
    bracketed = np.zeros(N, dtype=bool)
    conditioned = np.zeros(N, dtype=bool)
    n_any = n_pos
    if Z is None:
        e_any, b_any = e_pos, b_pos
    else:
        e_any, b_any, n_any, bracketed = _either(run, C, Ainv, legs, table, share, S, Z, e_pos, b_pos, e_phi, b_phi,
                                                  sure_pos | sure_phi)
        if joint or (joint is None and np.count_nonzero(bracketed) <= JOINT_POSES):
            e_any, b_any, bracketed, conditioned = _conditioned(
                _Either(e_any, b_any, bracketed, conditioned), C=C, Ainv=Ainv, legs=legs, table=table, share=share,
                S=S, Z=Z, target=target, position=(e_pos, b_pos), phi=(e_phi, b_phi), workers=run.workers)
    above = np.maximum(b_pos, b_phi if b_phi is not None else 0.0) > target
    if np.any(above):
        warnings.warn(Prp3mcWarning(
            f"exact yield: the error bound exceeds the target {target:g} at {int(above.sum())} of {N} pose(s) "
            f"(largest {float(np.max(np.maximum(b_pos, b_phi if b_phi is not None else 0.0))):.3g})"), stacklevel=2)
    coarse = conditioned & (b_any > target)
    if np.any(coarse):
        warnings.warn(Prp3mcWarning(
            f"exact yield: P(position or phi out of spec) by conditioning on two legs exceeds the target {target:g} "
            f"at {int(coarse.sum())} of {N} pose(s) (bound up to {float(b_any[coarse].max()):.3g}: its cells' "
            "budget is spent); the bound holds"), stacklevel=2)
    loose = bracketed & (b_any > target)
    if np.any(loose):
        warnings.warn(Prp3mcWarning(
            f"exact yield: P(position or phi out of spec) is bracketed by [max, sum] of the two exceedances at "
            f"{int(loose.sum())} of {N} pose(s) (bound up to {float(b_any.max()):.3g}; the joint series does not "
            "converge in time when a leg has few continuous laws); each channel's own exceedance keeps its "
            "bound"), stacklevel=2)
    rest = ~coarse & ~loose & (b_any > target)      # the 3-D series' bound, or two channels' bounds summed
    if Z is not None and np.any(rest):
        warnings.warn(Prp3mcWarning(
            f"exact yield: the error bound of P(position or phi out of spec) exceeds the target {target:g} at "
            f"{int(rest.sum())} of {N} pose(s) (largest {float(b_any[rest].max()):.3g}); the bound holds"),
            stacklevel=2)
    worst_pos, worst_phi = _worst(pos, phi, C, legs, table)
    rss_pos, rss_phi = _rss(C, table)

    def shaped(a, tail=()):
        return None if a is None else a.reshape(shape + tail)

    Q = levels.size
    return YieldResult(
        poses=model.poses, spec_position_mm=S, spec_phi_deg=None if Z is None else Z * RAD2DEG,
        exceed_position=shaped(e_pos), bound_position=shaped(b_pos),
        exceed_phi=shaped(e_phi), bound_phi=None if Z is None else shaped(b_phi),
        exceed_any=shaped(e_any), bound_any=shaped(b_any),
        levels=QUANTILE_LEVELS if quantiles else (),
        quantile_position_mm=shaped(q_pos, (Q,)) if quantiles else None,
        quantile_position_err_mm=shaped(qe_pos, (Q,)) if quantiles else None,
        quantile_phi_deg=shaped(q_phi * RAD2DEG, (Q,)) if quantiles else None,
        quantile_phi_err_deg=shaped(qe_phi * RAD2DEG, (Q,)) if quantiles else None,
        worst_position_mm=shaped(worst_pos), worst_phi_deg=shaped(worst_phi * RAD2DEG),
        rss_position_mm=shaped(rss_pos), rss_phi_deg=shaped(rss_phi * RAD2DEG),
        bracketed_any=shaped(bracketed),
        lattice_points={"position": shaped(n_pos), "phi": shaped(n_phi), "any": shaped(n_any)},
        target=float(target), method=METHOD + (GAUSSIAN_METHOD if budget.correlated else "")
        + (CONDITIONAL_METHOD if conditioned.any() else ""),
        wall_time_s=time.perf_counter() - t0)


def _sized(which: str, C, Ainv, legs, table, share: float, spec: np.ndarray, quantiles: bool):
    """Channel ``which`` with its lattice sized for the spec (N,) (0: none, the quantiles alone) and, with
    ``quantiles``, for the support's maximum. A spec at or above that maximum is *sure* (P(``|Y|`` > spec) is 0,
    but for the normal laws' mass past their cut): its lattice is sized by the support alone, not by the
    spec, which may be any size. Returns (channel, z1 the largest radius served, zs the radius the
    series evaluates (<= z1), sure (N,))."""
    ch = channel(which, C, Ainv, legs, table, spec, alias_one=share)
    sure = (spec > 0) & (spec >= ch.zmax * (1 + 1e-12))
    z1 = np.where(sure, ch.zmax, np.maximum(spec, ch.zmax) if quantiles else spec)
    if not np.array_equal(z1, spec):
        ch = channel(which, C, Ainv, legs, table, z1, alias_one=share)
    return ch, z1, np.where(sure | (spec <= 0), z1, spec), sure


def _enumerated(model, shape, C, table, S, Z, levels, budget, target, t0) -> YieldResult:
    """:func:`exact_yield` of a budget of discrete classes only (:mod:`.enumeration`): exact, no series."""
    e = discrete_yield(C, table, S, Z, levels, budget.name)
    N, Q = C.shape[0], levels.size
    rss_pos, rss_phi = _rss(C, table)
    bound = np.full(shape, e["bound"])

    def shaped(a, tail=()):
        return a.reshape(shape + tail)

    return YieldResult(
        poses=model.poses, spec_position_mm=S, spec_phi_deg=None if Z is None else Z * RAD2DEG,
        exceed_position=shaped(e["e_pos"]), bound_position=bound,
        exceed_phi=None if Z is None else shaped(e["e_phi"]), bound_phi=None if Z is None else bound,
        exceed_any=shaped(e["e_any"]), bound_any=bound,
        levels=QUANTILE_LEVELS if Q else (),
        quantile_position_mm=shaped(e["q_pos"], (Q,)) if Q else None,
        quantile_position_err_mm=shaped(e["qe_pos"], (Q,)) if Q else None,
        quantile_phi_deg=shaped(e["q_phi"] * RAD2DEG, (Q,)) if Q else None,
        quantile_phi_err_deg=shaped(e["qe_phi"] * RAD2DEG, (Q,)) if Q else None,
        worst_position_mm=shaped(e["worst_pos"]), worst_phi_deg=shaped(e["worst_phi"] * RAD2DEG),
        rss_position_mm=shaped(rss_pos), rss_phi_deg=shaped(rss_phi * RAD2DEG),
        bracketed_any=np.zeros(shape, dtype=bool),
        lattice_points={k: np.full(shape, e["combinations"], np.int64) for k in ("position", "phi", "any")},
        target=float(target), method=ENUMERATION_METHOD, wall_time_s=time.perf_counter() - t0)


class _Runner:
    """Runs :func:`~.series.batch_series` over a channel's poses in chunks on a pool of threads."""

    def __init__(self, table, workers, target, budget: str):
        self.table, self.target, self.budget = table, target, budget
        self.workers = workers or cores()
        self.tab, self.sp = table.arrays(), special_args()

    def __call__(self, ch, z1, z2, zs, levels, z0, what: str, fallback: bool = False, sure=None):
        """The series of channel ``ch`` at every pose: (P(Y in D), bound, points, status, quantiles,
        their bounds). A ``sure`` pose (its spec covers the whole support, :func:`_sized`) has P = 1, exactly
        but for the mass of the normal laws past their cut, which is its bound; without quantiles its series
        is not summed. A pose the series cannot serve raises (what: the quantity, for the message), or
        keeps its status (2, 3) when the caller has a ``fallback``."""
        N = z1.size
        out = (np.empty(N), np.empty(N), np.empty(N, np.int64), np.empty(N, np.int64),
               np.empty((N, levels.size)), np.empty((N, levels.size)))
        sure = np.zeros(N, bool) if sure is None else sure
        skip = sure if levels.size == 0 else np.zeros(N, bool)
        z0 = np.ascontiguousarray(np.broadcast_to(z0, (N, levels.size)))
        t = self.table
        args = (ch.d, t.kind, t.par, t.env, self.tab, self.sp, ch.grp, ch.mu, ch.snu, ch.Q, ch.Vinv, ch.mnorm, ch.ab,
                ch.lam, np.ascontiguousarray(z1), np.ascontiguousarray(z2), np.ascontiguousarray(zs), self.target,
                ch.alias, levels, z0, ch.zmax, ch.ok & ~skip, *out)
        starts = range(0, N, _CHUNK)
        if self.workers == 1 or N <= _CHUNK:
            batch_series(0, N, *args)
        else:
            with ThreadPoolExecutor(max_workers=self.workers) as pool:
                list(pool.map(lambda s: check_stop() or batch_series(s, min(N, s + _CHUNK), *args), starts))
        p, b, n, status = out[:4]
        p[sure], b[sure] = 1.0, ch.alias[sure]
        n[skip], status[skip] = 0, 0
        for code, why in ((2, "fewer legs with a continuous law, whose terms decay, than it has dimensions: it "
                              "has no density"),
                          (3, f"the series needs more than 2^23 terms for the target {self.target:g} (too few "
                              "continuous laws for it): a larger target, or")):
            if np.any(status == code) and not fallback:
                raise NoExactYieldError(f"exact yield: {what} of budget {self.budget!r} at "
                                        f"{int(np.sum(status == code))} pose(s): {why}; use Monte Carlo")
        return out


def _either(run, C, Ainv, legs, table, share, S, Z, e_pos, b_pos, e_phi, b_phi, sure):
    """P(position > S or ``|dphi|`` > Z) and its bound, per pose: the 3-D series of the cylinder where it is
    certified, else the Fréchet bracket ``[max(P_pos, P_phi), P_pos + P_phi]`` (its midpoint, the half-width
    plus both channels' bounds as the bound), whichever bound is smaller. Where a channel is ``sure`` (its
    exceedance 0 but for its bound) the bracket is the other channel's exceedance, with both bounds: no
    series, not flagged bracketed. The joint series converges slowly
    when a leg has few continuous laws (its characteristic function decays slowly along that leg's axis):
    it is tried only when every leg's envelopes decay at least as ``n^-_JOINT_POWER`` (e.g. a normal law in each
    leg), at the first pose and, if that fails, at no other. Returns (P, bound, points, bracketed)."""
    N = e_pos.size
    lo, hi = np.maximum(e_pos, e_phi), np.minimum(1.0, e_pos + e_phi)
    e_br, b_br = 0.5 * (lo + hi), 0.5 * (hi - lo) + b_pos + b_phi
    e_any, b_any, n_any = e_br.copy(), b_br.copy(), np.zeros(N, np.int64)
    todo = np.flatnonzero(~sure)
    if todo.size == 0:
        return e_any, b_any, n_any, np.zeros(N, dtype=bool)
    if not np.all(leg_powers(table, C[:1], legs, 1.0 / 3.0) >= _JOINT_POWER):
        return e_any, b_any, n_any, ~sure
    if todo.size < N:
        e_sub, b_sub, n_sub, br_sub = _either(run, C[todo], Ainv[todo], legs, table, share, S, Z, e_pos[todo],
                                              b_pos[todo], e_phi[todo], b_phi[todo], np.zeros(todo.size, bool))
        e_any[todo], b_any[todo], n_any[todo] = e_sub, b_sub, n_sub
        bracketed = np.zeros(N, dtype=bool)
        bracketed[todo] = br_sub
        return e_any, b_any, n_any, bracketed
    both = channel("both", C, Ainv, legs, table, np.full(N, S), np.full(N, Z), alias_one=share)
    probe = run(_subset(both, slice(0, 1)), np.full(1, S), np.full(1, Z), np.full(1, S), np.zeros(0),
                np.zeros((1, 0)), "the pose error", fallback=True)
    if probe[3][0] <= 1 and N > 1:
        p_both, b_both, n_both, status = run(both, np.full(N, S), np.full(N, Z), np.full(N, S), np.zeros(0),
                                             np.zeros((N, 0)), "the pose error", fallback=True)[:4]
    else:
        p_both, b_both, n_both, status = (a[:1] for a in probe[:4])
    k = p_both.size
    series = (status <= 1) & (b_both < b_br[:k])
    e_any[:k] = np.where(series, np.clip(1.0 - p_both, 0.0, 1.0), e_br[:k])
    b_any[:k] = np.where(series, b_both, b_br[:k])
    n_any[:k] = n_both
    return e_any, b_any, n_any, ~np.pad(series, (0, N - k))


class _Either(NamedTuple):
    """P(position > S or ``|dphi|`` > Z) at N poses: its value and bound (N,), and whether it is the Fréchet
    bracket's midpoint or was found by conditioning on two legs (N,) bool each."""

    exceed: np.ndarray
    bound: np.ndarray
    bracketed: np.ndarray
    conditioned: np.ndarray


def _conditioned(either: _Either, *, C: np.ndarray, Ainv: np.ndarray, legs: np.ndarray, table, share: float,
                 S: float, Z: float, target: float, position: tuple, phi: tuple, workers: int) -> _Either:
    """P(either) by conditioning on two legs (:mod:`.conditional`) at the poses still ``either.bracketed``, where
    the pose error is a sum over independent legs, each with a density whose series converges (every leg's
    envelopes decay at least as ``n^-_LEG_POWER``): ``P_pos + P_phi - J``, J's bracket midpoint, the bound its
    half-width plus both channels' bounds; kept where that bound is below the Fréchet bracket's. J's bracket is
    refined to the target (its half-width to half of it) or its cell budget; where its half-width leaves room
    under the target that the channels' bounds (each up to the target) fill, both channels are summed again at
    the largest of target/4, target/16, ... that fits the room, for P(either) (their own exceedances, reported
    apart, keep theirs).

    Parameters
    ----------
    either : _Either
        P(either) so far (:func:`_either`).
    C, Ainv, legs, table, share
        The pose error per unit of each term (N, 3, T), A^-1 (N, 3, 3), each term's leg (T,), the terms'
        table and the mass of one normal law past its cut.
    S, Z, target : float
        The specs (mm, rad) and the bound's goal.
    position, phi : (ndarray (N,), ndarray (N,))
        Each channel's exceedance and its bound.
    workers : int
        Threads.
    """
    (e_pos, b_pos), (e_phi, b_phi) = position, phi
    e_any, b_any, bracketed, conditioned = either
    todo = np.flatnonzero(bracketed)
    if todo.size == 0:
        return either
    legs_table, shared = _shared_term(table, legs)
    if legs_table is None:
        return either
    kappa, ok = independent_legs(C[todo], Ainv[todo], legs, legs_table)
    ok &= np.all(leg_powers(legs_table, C[todo], legs, 0.0) >= _LEG_POWER, axis=1)
    todo, kappa = todo[ok], kappa[ok]
    if todo.size == 0:
        return either
    J_lo, J_hi = joint_exceedance(C[todo], Ainv[todo], legs, legs_table, kappa, S, Z, target, share, workers=workers,
                                  shared=None if shared is None else (C[todo, :, shared],
                                                                      float(table.lo[shared]),
                                                                      float(table.hi[shared])))
    J_lo = np.maximum(J_lo, 0.0)
    channels = [a[todo] for a in (e_pos, b_pos, e_phi, b_phi)]
    # where J's half-width leaves room under the target but the two channels' bounds (each up to the target)
    # fill it: both channels again, at the largest of target/4, target/16, ... (to 4^-_TIGHTEN) that fits the room
    room = target - 0.5 * (J_hi - J_lo)
    tiers = target * 0.25 ** np.arange(1, _TIGHTEN + 1)
    tiers = tiers[tiers >= TARGET_RANGE[0]]
    fits = 2.0 * tiers[:, None] <= room
    level = np.where(fits.any(axis=0) & (channels[1] + channels[3] > room), fits.argmax(axis=0), -1)
    for k in np.unique(level[level >= 0]):
        _tighten(channels, np.flatnonzero(level == k), todo, C, Ainv, legs, table, share, S, Z, tiers[k], workers)
    ep, bp, eh, bh = channels
    J_hi = np.minimum(J_hi, np.minimum(ep + bp, eh + bh))
    e = np.clip(ep + eh - 0.5 * (J_lo + J_hi), 0.0, 1.0)
    b = 0.5 * (J_hi - J_lo) + bp + bh
    better = np.isfinite(e) & np.isfinite(b) & (b < b_any[todo])
    idx = todo[better]
    e_any, b_any, bracketed, conditioned = e_any.copy(), b_any.copy(), bracketed.copy(), conditioned.copy()
    e_any[idx], b_any[idx] = e[better], b[better]
    bracketed[idx] = False
    conditioned[idx] = True
    return _Either(e_any, b_any, bracketed, conditioned)


def _shared_term(table, legs: np.ndarray) -> tuple:
    """The terms of the legs and the one term of every leg P(either) conditions on: (``table`` with that term
    made constant 0, its index), (``table``, None) without one, (None, None) where the random terms of every
    leg are more than one or not uniform (the temperature, uniform over its range, is one)."""
    every = np.flatnonzero(table.random & (np.asarray(legs) < 0))
    if every.size == 0:
        return table, None
    t = int(every[0])
    if every.size > 1 or table.kind[t] != UNIFORM:
        return None, None
    alone = np.arange(table.kind.size) == t
    return dataclasses.replace(table, kind=np.where(alone, -1, table.kind),
                               constant=np.where(alone, 0.0, table.constant)), t


def _tighten(channels: list, at: np.ndarray, todo: np.ndarray, C, Ainv, legs, table, share: float, S: float,
             Z: float, target: float, workers: int) -> None:
    """Both channels' exceedances and bounds (``channels``: P_pos, its bound, P_phi, its bound, each (n,) over the
    poses ``todo``) summed again at ``target`` at the poses ``todo[at]``, kept where the bound is smaller."""
    run = _Runner(table, workers, target, "")
    n = at.size
    for k, (which, spec) in enumerate((("position", S), ("phi", Z))):
        ch, z1, zs, sure = _sized(which, C[todo[at]], Ainv[todo[at]], legs, table, share, np.full(n, spec), False)
        p, bnd, _, status = run(ch, z1, np.zeros(n), zs, np.zeros(0), np.zeros((n, 0)), which, fallback=True,
                                sure=sure)[:4]
        better = (status <= 1) & np.isfinite(p) & (bnd < channels[2 * k + 1][at])
        channels[2 * k][at] = np.where(better, np.clip(1.0 - p, 0.0, 1.0), channels[2 * k][at])
        channels[2 * k + 1][at] = np.where(better, bnd, channels[2 * k + 1][at])


def _subset(ch, index):
    """Channel ``ch`` at the poses ``index`` (a slice)."""
    return type(ch)(**{f: (v if f == "d" else v[index]) for f, v in vars(ch).items()})


def _moments(C: np.ndarray, table) -> tuple[np.ndarray, np.ndarray]:
    """Mean (N, 3) and covariance (N, 3, 3) of the pose error (mm, mm, rad) from the terms' moments: the
    quantiles' starting guesses. :meth:`~prp3mc.model.linear.LinearModel.moments` gives the same to 3e-16
    (relative; in deg, through the features), but its rounding moves where Newton stops (quantiles by 3e-14)."""
    mean = np.einsum("not,t->no", C, table.mean)
    cov = np.einsum("not,t,nqt->noq", C, table.var, C)
    return mean, cov


def _worst(pos, phi, C, legs, table) -> tuple[np.ndarray, np.ndarray]:
    """The exact worst case of the position (mm) and ``|dphi|`` (rad); NaN where a normal law acts."""
    normal_xy = (np.abs(C[:, :2, :]).max(axis=1) > 0) & table.normal[None, :]
    normal_phi = (np.abs(C[:, 2, :]) > 0) & table.normal[None, :]
    worst_pos = np.where(normal_xy.any(axis=1), np.nan, pos.zmax)
    zmax = (support_max(1, C[:, 2:, :], (C[:, 2, :] @ table.constant)[:, None], legs, table) if phi is None
            else phi.zmax)
    return worst_pos, np.where(normal_phi.any(axis=1), np.nan, zmax)


def _rss(C: np.ndarray, table) -> tuple[np.ndarray, np.ndarray]:
    """RSS stack of the position (mm) and ``|dphi|`` (rad): ``|centre|`` + sqrt(sum_t (``|c_t|`` h_t)²), h_t the
    half-width of term t's interval (3 sd for a normal law)."""
    sd = np.sqrt(table.var)
    half = np.where(table.normal, 3.0 * sd, 0.5 * (table.hi - table.lo))
    half = np.where(table.random, half, 0.0)
    mid = np.where(table.normal, table.mean, 0.5 * (table.hi + table.lo))
    centre = np.einsum("not,t->no", C, mid)
    rss_xy = np.sqrt(np.einsum("not,t->n", C[:, :2, :] ** 2, half ** 2))
    rss_phi = np.sqrt(np.einsum("nt,t->n", C[:, 2, :] ** 2, half ** 2))
    return np.hypot(centre[:, 0], centre[:, 1]) + rss_xy, np.abs(centre[:, 2]) + rss_phi

