"""Monte Carlo propagation of an error budget through the linear model.

One sample matrix, ``budget.sample(n_samples, seed)``, is shared by all
poses (common random numbers); it is never held whole. Samples are streamed
in blocks, drawn by a compiled kernel in small tiles where every law has a
compiled inverse CDF (the same uniforms as numpy, see :mod:`._sampler`) or
block by block through numpy otherwise; threads start at jumps in the
seed's stream, so memory is bounded whatever ``n_samples`` (a few hundred MB
at 1e9 samples) and the numbers do not depend on the chunking or the
threads. Means and covariances of the pose error are linear images of the
features' sample moments (:class:`prp3mc.model.linear.LinearModel`),
summed in float64 per block and batch, with standard errors from 64 batch
means. The position-error norm and ``|dphi|`` are evaluated per pose and sample
in float32 by the kernel and summarised by EXACT order statistics of those
float32 values (the values a full sort would give), found in streamed passes
(:mod:`._stream`), with distribution-free confidence intervals.
"""

from __future__ import annotations

import math
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._threads import cores
from .._rng import resolve_rng
from .._result import freeze, pose_columns, short_repr
from ..units import OUTPUT_UNITS, POSE_OUTPUTS, RAD2DEG, Z95, z_value
from .._version import __version__
from ..model.budget import Budget
from ..errors import ParameterError, Prp3mcWarning
from ..kinematics.chain import as_poses, inverse_kinematics
from ..kinematics.exact import exact_pose_error
from ..kinematics.geometry import Geometry
from ._kernel import padded_features
from ._stream import Stream, pilot_fraction, select_order_statistics
from ..model.linear import LinearModel, linear_model
from ..progress import Progress

__all__ = ["MonteCarloResult", "monte_carlo", "PERCENTILES", "ci_samples", "MIN_SAMPLES"]

#: Percentiles reported by default (p99.73 is the 3-sigma level of a normal law).
PERCENTILES = (50.0, 95.0, 99.0, 99.73)
_N_BATCHES = 64  # batches of the batch-means standard errors: 64, or fewer of _MIN_BATCH samples
_MIN_BATCH = 16
#: The fewest samples of a Monte Carlo run: two batches, the fewest that give a standard error.
MIN_SAMPLES = 2 * _MIN_BATCH
_PILOT_MIN = 1 << 15  # fewest pilot samples placing the selection windows (see _stream)


@dataclass(frozen=True, slots=True, repr=False)
class MonteCarloResult:
    """Summaries of the pose error per pose, each with its uncertainty.

    Shapes: ``...`` is the batch shape of ``poses``. Position quantities are
    in mm and orientation quantities in degrees.

    Attributes
    ----------
    poses : ndarray (..., 3)
    n_samples, seed : int
    mean, mean_se : ndarray (..., 3)
        Mean of (dx mm, dy mm, dphi deg) and its standard error.
    std, std_se : ndarray (..., 3)
    cov, cov_se : ndarray (..., 3, 3)
        Covariance of (dx mm, dy mm, dphi deg) and its standard error.
    percentiles : tuple of float
    position_pct, phi_pct : ndarray (..., Q)
        Percentiles of the position-error norm (mm) and of ``|dphi|`` (deg).
    position_pct_ci, phi_pct_ci : ndarray (..., Q, 2)
        Distribution-free 95 % confidence intervals (order statistics).
    position_max, phi_max : ndarray (...)
        Largest sampled values.
    position_mean, position_mean_se : ndarray (...)
        Mean position-error norm (mm) and its standard error.
    tolerance_mm : float or None
    exceed_prob, exceed_ci : ndarray (...), (..., 2)
        P(position error > tolerance) with a Wilson 95 % interval.
    tolerance_phi_deg : float or None
    exceed_phi_prob, exceed_phi_ci : ndarray (...), (..., 2)
        P(``|dphi|`` > tolerance_phi_deg) with a Wilson 95 % interval (None without that tolerance).
    exceed_any_prob, exceed_any_ci : ndarray (...), (..., 2)
        P(position error > tolerance_mm or ``|dphi|`` > tolerance_phi_deg) with a Wilson 95 % interval (None
        unless both tolerances are given).
    linearization : DataFrame or None
        Exact-vs-linear comparison at a subset of poses, if asked for.
    version : str
    wall_time_s : float
    """

    poses: np.ndarray
    n_samples: int
    seed: int
    mean: np.ndarray
    mean_se: np.ndarray
    std: np.ndarray
    std_se: np.ndarray
    cov: np.ndarray
    cov_se: np.ndarray
    percentiles: tuple
    position_pct: np.ndarray
    position_pct_ci: np.ndarray
    phi_pct: np.ndarray
    phi_pct_ci: np.ndarray
    position_max: np.ndarray
    phi_max: np.ndarray
    position_mean: np.ndarray
    position_mean_se: np.ndarray
    tolerance_mm: float | None = None
    exceed_prob: np.ndarray | None = None
    exceed_ci: np.ndarray | None = None
    tolerance_phi_deg: float | None = None
    exceed_phi_prob: np.ndarray | None = None
    exceed_phi_ci: np.ndarray | None = None
    exceed_any_prob: np.ndarray | None = None
    exceed_any_ci: np.ndarray | None = None
    linearization: pd.DataFrame | None = None
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "n_samples", "seed", "percentiles", "tolerance_mm")

    def to_frame(self) -> pd.DataFrame:
        """Tidy table of every statistic per pose, with its 95 % interval.

        Columns: x_mm, y_mm, phi_deg, output, statistic, value, unit, se,
        ci_low, ci_high, level, method. ``phi`` percentiles and maxima are
        of ``|dphi|``; ``method`` says how the interval was made ("normal" from
        batch-means standard errors, "order statistics" distribution-free,
        "wilson" for exceedance, "none" for the sample maximum).
        """
        return self.conf_int(0.95)

    def conf_int(self, level: float = 0.95, statistic: str | None = None) -> pd.DataFrame:
        """Confidence intervals at ``level`` as a tidy DataFrame (columns as :meth:`to_frame`).

        Parameters
        ----------
        level : float
            Confidence level in (0, 1).
        statistic : str, optional
            Keep only this statistic (``"mean"``, ``"std"``, ``"p95"``, ``"max"``,
            ``"exceed"``...).

        Notes
        -----
        Means and standard deviations: normal intervals from batch-means
        standard errors at any level. Percentiles: the run's distribution-free
        95 % order-statistic interval at ``level=0.95``; at other levels a
        normal interval whose standard error is read off that interval
        (``method`` says which). Exceedance: a Wilson interval at ``level``.
        """
        z = z_value(level)
        cols = pose_columns(self.poses)
        n = cols["x_mm"].size
        rows = []

        def add(stat, output, unit, value, se=None, ci=None, method="normal"):
            value = np.asarray(value, dtype=float).reshape(n)
            se = np.full(n, np.nan) if se is None else np.asarray(se, dtype=float).reshape(n)
            if ci is None:
                ci = np.stack([value - z * se, value + z * se], -1)
            ci = np.asarray(ci, dtype=float).reshape(n, 2)
            rows.append(pd.DataFrame({**cols, "output": output, "statistic": stat, "value": value, "unit": unit,
                                      "se": se, "ci_low": ci[:, 0], "ci_high": ci[:, 1], "level": level,
                                      "method": method}))

        for o, name in enumerate(POSE_OUTPUTS):
            unit = OUTPUT_UNITS[name]
            add("mean", name, unit, self.mean[..., o], self.mean_se[..., o])
            add("std", name, unit, self.std[..., o], self.std_se[..., o])
        add("mean", "position", "mm", self.position_mean, self.position_mean_se)
        for q, p in enumerate(self.percentiles):
            for output, est, ci, unit in (("position", self.position_pct, self.position_pct_ci, "mm"),
                                          ("phi", self.phi_pct, self.phi_pct_ci, "deg")):
                ci_q = ci[..., q, :]
                if level == 0.95:
                    add(f"p{p:g}", output, unit, est[..., q], (ci_q[..., 1] - ci_q[..., 0]) / (2 * Z95), ci=ci_q,
                        method="order statistics")
                else:
                    add(f"p{p:g}", output, unit, est[..., q], (ci_q[..., 1] - ci_q[..., 0]) / (2 * Z95))
        for output, mx, unit in (("position", self.position_max, "mm"), ("phi", self.phi_max, "deg")):
            add("max", output, unit, mx, ci=np.stack([mx, mx], -1), method="none")
        for output, prob in (("position", self.exceed_prob), ("phi", self.exceed_phi_prob),
                             ("any", self.exceed_any_prob)):
            if prob is not None:
                add("exceed", output, "1", prob, ci=_wilson(prob * self.n_samples, self.n_samples, z), method="wilson")
        frame = pd.concat(rows, ignore_index=True)
        if statistic is not None:
            if statistic not in set(frame["statistic"]):
                raise KeyError(f"no statistic {statistic!r}; choose from {sorted(set(frame['statistic']))}")
            frame = frame[frame["statistic"] == statistic].reset_index(drop=True)
        return frame

    def metadata(self) -> dict:
        return {"prp3mc_version": self.version, "seed": self.seed, "n_samples": self.n_samples,
                "wall_time_s": self.wall_time_s}


def _order_ranks(n: int, percentiles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ranks (0-based) for linear-interpolated percentiles and their 95 % intervals."""
    q = np.asarray(percentiles) / 100.0
    h = q * (n - 1)
    lo_rank = np.floor(h).astype(int)
    hi_rank = np.minimum(lo_rank + 1, n - 1)
    return h, lo_rank, hi_rank, np.clip(_ci_ranks(n, q), 0, n - 1)


def _ci_ranks(n: int, q) -> np.ndarray:
    """Ranks (0-based, not clipped to 0 .. n - 1) of the ends of the 95 % intervals (..., 2) of quantiles ``q``."""
    half = Z95 * np.sqrt(n * q * (1 - q))
    return np.stack([np.floor(n * q - half).astype(int) - 1, np.ceil(n * q + half).astype(int) - 1], -1)


def ci_samples(percentile: float) -> int | None:
    """The fewest samples whose order statistics hold both ends of the 95 % interval of ``percentile``
    (the ranks of :func:`_order_ranks`, neither clipped to the sample's extremes); None for the minimum
    and the maximum, whose intervals no sample bounds. 1419 for p99.73, 381 for p99."""
    q = float(percentile) / 100.0
    if not 0.0 < q < 1.0:
        return None
    v = Z95 * math.sqrt(q * (1.0 - q))
    # sqrt(n) at which n q + v sqrt(n) reaches n, and n q - v sqrt(n) reaches 1
    s = max(v / (1 - q), (v + math.sqrt(v * v + 4 * q)) / (2 * q))
    n = max(2, int(s * s) - 2)                   # from just below the closed form, the first n that holds
    while not (0 <= (ranks := _ci_ranks(n, q))[0] and ranks[1] <= n - 1):
        n += 1
    return n


def _wilson(k: np.ndarray, n: int, z: float = Z95) -> np.ndarray:
    """Wilson score interval (..., 2) of a proportion k / n at normal quantile ``z``."""
    p = k / n
    denom = 1 + z**2 / n
    centre = (p + z**2 / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z**2 / (4 * n * n)) / denom
    return np.stack([centre - half, centre + half], -1)


def monte_carlo(geometry: "Geometry | str", budget: "Budget | str", poses, n_samples: int, *,
                rng: "None | int | np.random.Generator" = None,
                percentiles=PERCENTILES, tolerance_mm: float | None = None, tolerance_phi_deg: float | None = None,
                exact_check_poses: int = 0, exact_check_samples: int = 2000,
                progress: bool | None = None, max_chunk_bytes: int = 256 << 20,
                workers: int | None = None) -> MonteCarloResult:
    """Propagate ``budget`` through the linear model at ``poses`` by Monte Carlo.

    Parameters
    ----------
    geometry : Geometry or str
        A Geometry, preset name or TOML path.
    budget : Budget or str
        A Budget, preset name or TOML path.
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    n_samples : int
        Samples of the budget, shared by all poses.
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7): a seed, a Generator (a seed is
        drawn from it) or None (a fresh seed). The integer seed used is
        recorded in the result as ``seed``.
    percentiles : sequence of float
        Percentiles of the position-error norm and of ``|dphi|``.
    tolerance_mm : float, optional
        Report P(position error > tolerance_mm).
    tolerance_phi_deg : float, optional
        Report P(``|dphi|`` > tolerance_phi_deg), and with ``tolerance_mm`` P(either): the Monte Carlo
        counterpart of :func:`prp3mc.exact_yield`, for budgets it cannot take (correlated inputs with
        laws other than normal).
    exact_check_poses : int
        Push the first ``exact_check_samples`` samples through the exact
        nonlinear model at this many poses (spread over the batch) and report
        the largest and RMS difference from the linear model.
    progress : bool, optional
        Progress bar on stderr (default: when stderr is a terminal).
    max_chunk_bytes : int
        Memory for the values kept around the wanted ranks per chunk of poses
        (the run streams over pose chunks; a smaller limit costs passes, never accuracy).
    workers : int, optional
        Threads, each streaming a range of sample blocks (default: CPU count).

    Returns
    -------
    MonteCarloResult
    """
    t0 = time.perf_counter()
    geometry, budget = Geometry.load(geometry), Budget.load(budget)
    poses = as_poses(poses, nonempty=True)
    n_samples = int(n_samples)
    if n_samples < MIN_SAMPLES:
        raise ParameterError(f"Monte Carlo needs at least {MIN_SAMPLES} samples (its standard errors come from "
                          f"batches of {_MIN_BATCH} or more), got {n_samples}")
    n_batches = min(_N_BATCHES, n_samples // _MIN_BATCH)
    if tolerance_mm is not None and not (math.isfinite(tolerance_mm) and tolerance_mm >= 0):
        raise ParameterError(f"tolerance must be a finite length >= 0 mm, got {tolerance_mm}")
    if tolerance_phi_deg is not None and not (math.isfinite(tolerance_phi_deg) and tolerance_phi_deg >= 0):
        raise ParameterError(f"tolerance_phi_deg must be a finite angle >= 0 deg, got {tolerance_phi_deg}")
    tols = (tolerance_mm, None if tolerance_phi_deg is None else math.radians(tolerance_phi_deg))
    pct = tuple(float(p) for p in percentiles)
    if not all(0.0 <= p <= 100.0 for p in pct):
        raise ParameterError(f"percentiles must lie in [0, 100], got {pct}")
    short = [(p, need) for p in pct if (need := ci_samples(p)) is None or n_samples < need]
    if short:
        warnings.warn(Prp3mcWarning(
            "with " + f"{n_samples} samples the 95 % interval of " + ", ".join(
                f"p{p:g} ({'no sample count bounds it' if need is None else f'needs {need}'})" for p, need in short)
            + " reaches the sample's extreme value: it bounds that percentile on one side only"), stacklevel=2)
    seed, _ = resolve_rng(rng)
    model = linear_model(geometry, budget, poses)
    batch_shape = model.poses.shape[:-1]
    C = model.coef.reshape((-1, 3, model.coef.shape[-1]))
    n_poses, n_feat = C.shape[0], C.shape[2]
    h, r_lo, r_hi, r_ci = _order_ranks(n_samples, pct)
    ranks = np.unique(np.concatenate([r_lo, r_hi, r_ci.ravel()]))
    pilot_m = min(n_samples, max(_PILOT_MIN, n_samples >> 10))
    window_values = max(64, max_chunk_bytes // 16)
    per_pose = 2 * 4 * 1.3 * n_samples * pilot_fraction(ranks, n_samples, pilot_m) + (16 << 10)
    chunk = max(1, min(n_poses, int(max_chunk_bytes // per_pose)))
    n_threads = workers or cores()
    stream = Stream(model, budget, seed, n_samples, n_batches, n_threads)
    n_seg = stream.seg_start.size
    sums = {"S1": np.zeros((n_seg, n_feat)), "S2": np.zeros((n_seg, n_feat, n_feat))}
    C32 = np.zeros((n_poses, 3, padded_features(n_feat)), np.float32)  # the kernels' feature count
    C32[..., :n_feat] = C
    stats = np.empty((n_poses, 2, len(ranks)))
    vmax = np.empty((n_poses, 2))
    exceed = np.zeros((n_poses, 3))
    possum = np.zeros((n_poses, n_seg))
    S1, S2 = sums["S1"], sums["S2"]
    with Progress(n_poses, "montecarlo", progress) as bar, ThreadPoolExecutor(max_workers=n_threads) as pool:
        pilot = stream.pilot(pilot_m)
        for start in range(0, n_poses, chunk):
            sl = slice(start, min(n_poses, start + chunk))
            sums["possum"] = possum[sl]
            stats[sl], vmax[sl], exceed[sl] = select_order_statistics(
                stream, C32[sl], ranks, pilot, tols, sums, pool, window_values)
            sums.pop("S1", None), sums.pop("S2", None)  # feature sums: on the first chunk's first pass
            bar.update(sl.stop - sl.start)
    mom = stream.moments(S1, S2)
    deg = np.array([1.0, 1.0, RAD2DEG])
    mean = np.einsum("pof,f->po", C, mom.mean) * deg
    cov = np.einsum("pof,fg,pqg->poq", C, mom.cov, C) * np.outer(deg, deg)
    bm = np.einsum("pof,bf->pbo", C, mom.batch_means) * deg
    bc = np.einsum("pof,bfg,pqg->pboq", C, mom.batch_covs, C) * np.outer(deg, deg)
    mean_se = bm.std(axis=1, ddof=1) / math.sqrt(n_batches)
    cov_se = bc.std(axis=1, ddof=1) / math.sqrt(n_batches)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    var_se = np.diagonal(cov_se, axis1=-2, axis2=-1)
    std_se = np.divide(var_se, 2 * std, out=np.zeros_like(std), where=std > 0)

    bsum = np.zeros((n_poses, n_batches))
    np.add.at(bsum.T, stream.seg_batch, possum.T)
    pos_mean = bsum.sum(axis=-1) / n_samples
    pos_mean_se = (bsum / np.diff(stream.batch_edges)).std(axis=-1, ddof=1) / math.sqrt(n_batches)
    frac = h - np.floor(h)
    i_lo, i_hi, i_ci = np.searchsorted(ranks, r_lo), np.searchsorted(ranks, r_hi), np.searchsorted(ranks, r_ci)
    scale = np.array([1.0, RAD2DEG])[None, :, None]
    lo, hi = stats[..., i_lo] * scale, stats[..., i_hi] * scale
    pct_values = lo + frac * (hi - lo)  # (P, 2, Q)
    ci_values = stats[..., i_ci] * scale[..., None]  # (P, 2, Q, 2)
    vmax = vmax * scale[..., 0]
    Q = len(pct)

    shape = batch_shape
    given = (tolerance_mm is not None, tolerance_phi_deg is not None,
             tolerance_mm is not None and tolerance_phi_deg is not None)
    probs = [(exceed[:, o] / n_samples).reshape(shape) if given[o] else None for o in range(3)]
    cis = [_wilson(exceed[:, o], n_samples).reshape(shape + (2,)) if given[o] else None for o in range(3)]
    lin = _linearization(model, budget, seed, exact_check_poses, exact_check_samples) if exact_check_poses else None
    return MonteCarloResult(
        poses=model.poses, n_samples=n_samples, seed=seed,
        mean=mean.reshape(shape + (3,)), mean_se=mean_se.reshape(shape + (3,)),
        std=std.reshape(shape + (3,)), std_se=std_se.reshape(shape + (3,)),
        cov=cov.reshape(shape + (3, 3)), cov_se=cov_se.reshape(shape + (3, 3)),
        percentiles=pct,
        position_pct=pct_values[:, 0].reshape(shape + (Q,)), position_pct_ci=ci_values[:, 0].reshape(shape + (Q, 2)),
        phi_pct=pct_values[:, 1].reshape(shape + (Q,)), phi_pct_ci=ci_values[:, 1].reshape(shape + (Q, 2)),
        position_max=vmax[:, 0].reshape(shape), phi_max=vmax[:, 1].reshape(shape),
        position_mean=pos_mean.reshape(shape), position_mean_se=pos_mean_se.reshape(shape),
        tolerance_mm=tolerance_mm, exceed_prob=probs[0], exceed_ci=cis[0],
        tolerance_phi_deg=tolerance_phi_deg, exceed_phi_prob=probs[1], exceed_phi_ci=cis[1],
        exceed_any_prob=probs[2], exceed_any_ci=cis[2],
        linearization=lin,
        wall_time_s=time.perf_counter() - t0,
    )


def _linearization(model: LinearModel, budget: Budget, seed: int, n_poses: int, n_samples: int) -> pd.DataFrame:
    """Exact minus linear pose error for the first samples at spread-out poses."""
    flat = model.poses.reshape(-1, 3)
    idx = np.unique(np.linspace(0, flat.shape[0] - 1, min(n_poses, flat.shape[0])).round().astype(int))
    X = budget.sample(n_samples, seed)
    errors = budget.errors(X, b=inverse_kinematics(model.geometry, flat[idx], check=False)[0],
                           lead_mm=model.geometry.lead_mm)
    poses = np.broadcast_to(flat[idx, None, :], (len(idx), X.shape[0], 3))
    exact = exact_pose_error(model.geometry, poses, errors, check=False)
    sub = linear_model(model.geometry, budget, flat[idx], check=False)
    lin = sub.evaluate(X)
    lin[..., 2] *= RAD2DEG
    diff = exact - lin
    dpos_um = 1e3 * np.hypot(diff[..., 0], diff[..., 1])
    dphi_arcsec = 3600.0 * np.abs(diff[..., 2])
    return pd.DataFrame({
        "x_mm": flat[idx, 0], "y_mm": flat[idx, 1], "phi_deg": flat[idx, 2], "n_samples": X.shape[0],
        "position_max_um": dpos_um.max(-1), "position_rms_um": np.sqrt((dpos_um**2).mean(-1)),
        "phi_max_arcsec": dphi_arcsec.max(-1), "phi_rms_arcsec": np.sqrt((dphi_arcsec**2).mean(-1)),
        "position_p99_linear_um": 1e3 * np.percentile(np.hypot(lin[..., 0], lin[..., 1]), 99, axis=-1),
    })
