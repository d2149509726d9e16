"""Monte Carlo propagation of an error budget through the linear model.

One sample matrix is shared by all poses (common random numbers). Means and
covariances of the pose error are linear images of the sample moments of the
model's features (:class:`prp3mc.uncertainty.model.LinearModel`), so they are computed
once for all poses; their standard errors come from 64 batch means. The
position-error norm and |dphi| are evaluated per pose and sample in float32,
streamed in pose chunks of bounded memory, and summarised by exact order
statistics with distribution-free confidence intervals.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._rng import resolve_rng
from .._result import freeze, pose_columns, short_repr
from ..units import OUTPUT_UNITS, POSE_OUTPUTS, RAD2DEG, Z95, z_value
from .._version import __version__
from .budget import Budget
from ..errors import BudgetError
from ..kinematics.exact import exact_pose_error
from ..kinematics.geometry import Geometry
from .model import LinearModel, linear_model
from ..progress import Progress

__all__ = ["MonteCarloResult", "monte_carlo", "PERCENTILES"]

#: Percentiles reported by default (p99.73 is the 3-sigma level of a normal law).
PERCENTILES = (50.0, 95.0, 99.0, 99.73)
_N_BATCHES = 64
_BLOCK = 1 << 15  # samples per block of the pose-error evaluation (fits in cache)


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
        Percentiles of the position-error norm (mm) and of |dphi| (deg).
    position_pct_ci, phi_pct_ci : ndarray (..., Q, 2)
        Distribution-free 95 % confidence intervals (order statistics).
    position_max, phi_max : ndarray (...)
        Largest sampled values.
    position_mean, position_mean_se : ndarray (...)
        Mean position-error norm (mm) and its standard error.
    tolerance_mm : float or None
    exceed_prob, exceed_ci : ndarray (...), (..., 2)
        P(position error > tolerance) with a Wilson 95 % interval.
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
        of |dphi|; ``method`` says how the interval was made ("normal" from
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
        if self.exceed_prob is not None:
            add("exceed", "position", "1", self.exceed_prob,
                ci=_wilson(self.exceed_prob * self.n_samples, self.n_samples, z), method="wilson")
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
    half = Z95 * np.sqrt(n * q * (1 - q))
    ci_lo = np.clip(np.floor(n * q - half).astype(int) - 1, 0, n - 1)
    ci_hi = np.clip(np.ceil(n * q + half).astype(int) - 1, 0, n - 1)
    return h, lo_rank, hi_rank, np.stack([ci_lo, ci_hi], -1)


def _order_statistics(rows: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """Exact order statistics of each row at sorted 0-based ``ranks``; rows are reordered in place.

    ``np.partition`` with many kth re-partitions large ranges for each; here
    ranks are taken in clusters in ascending order, each cluster by one
    partition of the remaining part of the row and one of the (shrinking)
    rest, then a sort of the few values in between: about half the work.
    One loop iteration handles a whole row of samples.
    """
    ranks = np.asarray(ranks)
    n = rows.shape[-1]
    gaps = np.flatnonzero(np.diff(ranks) > max(64, n // 1000)) + 1
    clusters = np.split(ranks, gaps)
    out = np.empty((rows.shape[0], len(ranks)), rows.dtype)
    for i, row in enumerate(rows):
        start, j = 0, 0
        for cl in clusters:
            r0, r1 = int(cl[0]), int(cl[-1])
            seg = row[start:]
            seg.partition(r0 - start)
            if r1 > r0:
                rest = row[r0 + 1:]
                rest.partition(r1 - r0 - 1)
                row[r0 + 1:r1 + 1].sort()
            out[i, j:j + len(cl)] = row[cl]
            j += len(cl)
            start = r1 + 1
    return out


def _wilson(k: np.ndarray, n: int, z: float = Z95) -> np.ndarray:
    """Wilson score interval (..., 2) of a proportion k / n at normal quantile ``z``."""
    p = k / n
    denom = 1 + z**2 / n
    centre = (p + z**2 / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z**2 / (4 * n * n)) / denom
    return np.stack([centre - half, centre + half], -1)


def _feature_moments(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean and covariance of the features overall and per batch (float64)."""
    n = F.shape[0]
    edges = np.linspace(0, n, _N_BATCHES + 1).astype(int)
    means, covs = [], []
    for a, b in zip(edges[:-1], edges[1:]):  # 64 batches: a loop over batches, not samples
        Fb = F[a:b]
        means.append(Fb.mean(axis=0))
        covs.append(np.cov(Fb, rowvar=False, ddof=1).reshape(F.shape[1], F.shape[1]))
    mean = F.mean(axis=0)
    cov = np.cov(F, rowvar=False, ddof=1).reshape(F.shape[1], F.shape[1])
    return mean, cov, np.array(means), np.array(covs)


def monte_carlo(geometry: Geometry, budget: Budget, poses, n_samples: int, *,
                rng: "None | int | np.random.Generator" = None,
                percentiles=PERCENTILES, tolerance_mm: float | None = None,
                exact_check_poses: int = 0, exact_check_samples: int = 2000,
                progress: bool | None = None, max_chunk_bytes: int = 256 << 20,
                workers: int | None = None) -> MonteCarloResult:
    """Propagate ``budget`` through the linear model at ``poses`` by Monte Carlo.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    n_samples : int
        Samples of the budget, shared by all poses.
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7): a seed, a Generator (a seed is
        drawn from it) or None (a fresh seed). The integer seed used is
        recorded in the result as ``seed``.
    percentiles : sequence of float
        Percentiles of the position-error norm and of |dphi|.
    tolerance_mm : float, optional
        Report P(position error > tolerance_mm).
    exact_check_poses : int
        Push the first ``exact_check_samples`` samples through the exact
        nonlinear model at this many poses (spread over the batch) and report
        the largest and RMS difference from the linear model.
    progress : bool, optional
        Progress bar on stderr (default: when stderr is a terminal).
    max_chunk_bytes : int
        Memory for one chunk of poses x samples (the run streams over chunks).
    workers : int, optional
        Threads for the per-pose order statistics (default: CPU count).

    Returns
    -------
    MonteCarloResult
    """
    t0 = time.perf_counter()
    n_samples = int(n_samples)
    if n_samples < 2:
        raise BudgetError(f"Monte Carlo needs at least 2 samples, got {n_samples}")
    if tolerance_mm is not None and not (math.isfinite(tolerance_mm) and tolerance_mm >= 0):
        raise BudgetError(f"tolerance must be a finite length >= 0 mm, got {tolerance_mm}")
    pct = tuple(float(p) for p in percentiles)
    if not all(0.0 <= p <= 100.0 for p in pct):
        raise BudgetError(f"percentiles must lie in [0, 100], got {pct}")
    seed, _ = resolve_rng(rng)
    model = linear_model(geometry, budget, poses)
    batch_shape = model.poses.shape[:-1]
    X = budget.sample(n_samples, seed)
    F = model.features(X)
    del X
    fmean, fcov, bmeans, bcovs = _feature_moments(F)
    C = model.coef.reshape((-1, 3, F.shape[1]))
    deg = np.array([1.0, 1.0, RAD2DEG])
    mean = np.einsum("pof,f->po", C, fmean) * deg
    cov = np.einsum("pof,fg,pqg->poq", C, fcov, C) * np.outer(deg, deg)
    bm = np.einsum("pof,bf->pbo", C, bmeans) * deg
    bc = np.einsum("pof,bfg,pqg->pboq", C, bcovs, C) * np.outer(deg, deg)
    mean_se = bm.std(axis=1, ddof=1) / math.sqrt(_N_BATCHES)
    cov_se = bc.std(axis=1, ddof=1) / math.sqrt(_N_BATCHES)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    var_se = np.diagonal(cov_se, axis1=-2, axis2=-1)
    std_se = np.divide(var_se, 2 * std, out=np.zeros_like(std), where=std > 0)

    # per-pose order statistics, streamed over pose chunks
    FT = np.ascontiguousarray(F.T, dtype=np.float32)
    del F
    n_poses = C.shape[0]
    h, r_lo, r_hi, r_ci = _order_ranks(n_samples, pct)
    kth = np.unique(np.concatenate([r_lo, r_hi, r_ci.ravel(), [n_samples - 1]]))
    Q = len(pct)
    out = {"pos_pct": np.empty((n_poses, Q)), "pos_ci": np.empty((n_poses, Q, 2)),
           "phi_pct": np.empty((n_poses, Q)), "phi_ci": np.empty((n_poses, Q, 2)),
           "pos_max": np.empty(n_poses), "phi_max": np.empty(n_poses),
           "pos_mean": np.empty(n_poses), "pos_mean_se": np.empty(n_poses),
           "exceed": np.zeros(n_poses)}
    chunk = max(1, min(n_poses, int(max_chunk_bytes // (3 * 4 * n_samples))))
    C32 = C.astype(np.float32)
    frac = h - np.floor(h)
    batch_edges = np.linspace(0, n_samples, _N_BATCHES + 1).astype(int)

    i_lo, i_hi = np.searchsorted(kth, r_lo), np.searchsorted(kth, r_hi)
    i_ci, i_max = np.searchsorted(kth, r_ci), np.searchsorted(kth, n_samples - 1)

    def summarise(values: np.ndarray, pct_key: str, ci_key: str, max_key: str, sl: slice, scale: float):
        part = _order_statistics(values, kth).astype(float)  # (p, len(kth))
        lo, hi = part[:, i_lo], part[:, i_hi]
        out[pct_key][sl] = scale * (lo + frac * (hi - lo))
        out[ci_key][sl] = scale * part[:, i_ci]
        out[max_key][sl] = scale * part[:, i_max]

    def work(start: int) -> int:
        sl = slice(start, min(n_poses, start + chunk))
        p = sl.stop - sl.start
        Cp = C32[sl].reshape(p * 3, -1)
        pos = np.empty((p, n_samples), np.float32)
        phi = np.empty((p, n_samples), np.float32)
        for b0 in range(0, n_samples, _BLOCK):  # cache-sized sample blocks
            b1 = min(n_samples, b0 + _BLOCK)
            D = (Cp @ FT[:, b0:b1]).reshape(p, 3, b1 - b0)
            np.square(D, out=D)
            np.add(D[:, 0], D[:, 1], out=pos[:, b0:b1])
            np.sqrt(pos[:, b0:b1], out=pos[:, b0:b1])
            np.sqrt(D[:, 2], out=phi[:, b0:b1])
        bsum = np.add.reduceat(pos, batch_edges[:-1], axis=-1).astype(np.float64)
        out["pos_mean"][sl] = bsum.sum(axis=-1) / n_samples
        out["pos_mean_se"][sl] = (bsum / np.diff(batch_edges)).std(axis=-1, ddof=1) / math.sqrt(_N_BATCHES)
        if tolerance_mm is not None:
            out["exceed"][sl] = np.count_nonzero(pos > tolerance_mm, axis=-1)
        summarise(pos, "pos_pct", "pos_ci", "pos_max", sl, 1.0)
        summarise(phi, "phi_pct", "phi_ci", "phi_max", sl, RAD2DEG)
        return p

    starts = range(0, n_poses, chunk)
    with Progress(n_poses, "montecarlo", progress) as bar, \
            ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        for done in pool.map(work, starts):
            bar.update(done)

    shape = batch_shape
    exceed = exceed_ci = None
    if tolerance_mm is not None:
        exceed = (out["exceed"] / n_samples).reshape(shape)
        exceed_ci = _wilson(out["exceed"], n_samples).reshape(shape + (2,))
    lin = _linearization(model, budget, seed, exact_check_poses, exact_check_samples) if exact_check_poses else None
    return MonteCarloResult(
        poses=model.poses, n_samples=n_samples, seed=seed,
        mean=mean.reshape(shape + (3,)), mean_se=mean_se.reshape(shape + (3,)),
        std=std.reshape(shape + (3,)), std_se=std_se.reshape(shape + (3,)),
        cov=cov.reshape(shape + (3, 3)), cov_se=cov_se.reshape(shape + (3, 3)),
        percentiles=pct,
        position_pct=out["pos_pct"].reshape(shape + (Q,)), position_pct_ci=out["pos_ci"].reshape(shape + (Q, 2)),
        phi_pct=out["phi_pct"].reshape(shape + (Q,)), phi_pct_ci=out["phi_ci"].reshape(shape + (Q, 2)),
        position_max=out["pos_max"].reshape(shape), phi_max=out["phi_max"].reshape(shape),
        position_mean=out["pos_mean"].reshape(shape), position_mean_se=out["pos_mean_se"].reshape(shape),
        tolerance_mm=tolerance_mm, exceed_prob=exceed, exceed_ci=exceed_ci, linearization=lin,
        wall_time_s=time.perf_counter() - t0,
    )


def _linearization(model: LinearModel, budget: Budget, seed: int, n_poses: int, n_samples: int) -> pd.DataFrame:
    """Exact minus linear pose error for the first samples at spread-out poses."""
    flat = model.poses.reshape(-1, 3)
    idx = np.unique(np.linspace(0, flat.shape[0] - 1, min(n_poses, flat.shape[0])).round().astype(int))
    X = budget.sample(n_samples, seed)
    errors = budget.errors(X)
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
