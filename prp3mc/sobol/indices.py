"""Variance-based (Sobol) sensitivity indices of the pose error, batched over poses.

The public entry of the Sobol wing: :func:`sobol_indices` runs SALib's
design and estimators (:mod:`~prp3mc.sobol.saltelli`: scrambled Sobol'
points, Saltelli's radial scheme, the Saltelli 2010 first-order and Jansen
total estimators with a bootstrap) on the linear model of a budget, for every
pose and output at once; :func:`sobol_converge` doubles N until the intervals
are narrow enough. The closed forms the estimates are tested against live in
:mod:`~prp3mc.sobol.closed_form`, the ranking next to the worst
case in :mod:`~prp3mc.sobol.ranking`.

Intervals. As SALib, a result carries half-widths ``S1_conf`` and ``ST_conf``
at its ``conf_level``: ``z(conf_level)`` times the standard deviation of the
bootstrap estimates. That standard deviation is the standard error,
``se = conf / z(conf_level)``, and the interval at any level is
``S ± z(level) · se`` (:meth:`SobolResult.conf_int`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._result import freeze, interval_frame, pose_columns, short_repr
from .._rng import MAX_SEED, resolve_rng
from .._threads import cores, single_threaded_blas
from .._version import __version__
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from ..progress import Progress
from ..units import OUTPUTS, RAD2DEG, z_value
from ..model.budget import Budget
from ..model.linear import linear_model
from .saltelli import (design_factors, feature_sums, linear_indices, model_outputs, resample_weights,
                       salib_indices, saltelli_design, sample_indices)

__all__ = ["SobolResult", "sobol_indices", "sobol_converge"]

_METHODS = ("auto", "salib", "vectorised")
_U_EDGE = 2.0**-53        # unit samples are clipped into (0, 1): unbounded laws stay finite
_STATISTICS = ("S1", "ST")


@dataclass(frozen=True, slots=True, repr=False)
class SobolResult:
    """First-order and total Sobol indices with bootstrap intervals, per pose.

    Shapes: ``...`` is the batch shape of ``poses``; O outputs, K names.
    Read-only: arrays cannot be written, ``groups`` is a read-only mapping.

    Attributes
    ----------
    poses : ndarray (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    n_samples : int
        Base sample size N (a power of two); the model ran N (d + 2 + G) times.
    seed : int
        Seed of SALib's scrambled Sobol' sampler.
    outputs : tuple of str
        Among ``x``, ``y``, ``phi``, ``position``.
    names : tuple of str
        The budget's factors (its inputs, then the random factors of its
        effects: ``backlash_i``, ``thermal``), then the groups.
    kinds : tuple of str
        ``input``, ``effect`` or ``group`` per name.
    groups : mapping of str to tuple of str
        Members of every group.
    S1, S1_conf, ST, ST_conf : ndarray (..., O, K)
        Indices and the half-widths of their ``conf_level`` intervals (SALib's
        ``z(conf_level)`` times the bootstrap standard deviation). NaN for the
        names in ``constant``.
    num_resamples : int
    conf_level : float
    bootstrap_seed : int
        Seed of the bootstrap resampling (SALib's ``seed``): ``seed + 1``,
        because SALib ignores a seed of 0.
    method : str
        ``salib`` or ``vectorised`` (the path that ran).
    constant : tuple of str
        Names whose inputs are all constant (zero-width laws): a constant
        input has no variance to share, so its indices are undefined (NaN),
        not 0.
    version : str
    wall_time_s : float
    """

    poses: np.ndarray
    n_samples: int
    seed: int
    outputs: tuple
    names: tuple
    kinds: tuple
    groups: dict
    S1: np.ndarray
    S1_conf: np.ndarray
    ST: np.ndarray
    ST_conf: np.ndarray
    num_resamples: int
    conf_level: float
    bootstrap_seed: int
    method: str
    constant: tuple = ()
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "S1", "n_samples", "seed", "method")

    def _keys(self) -> dict:
        """Pose, output, name and kind columns, one row per pose, output and name (C order of S1)."""
        n = int(np.prod(self.poses.shape[:-1], dtype=int))
        O, K = len(self.outputs), len(self.names)
        return {**pose_columns(self.poses, O * K), "output": np.tile(np.repeat(self.outputs, K), n),
                "name": np.tile(self.names, n * O), "kind": np.tile(self.kinds, n * O)}

    def to_frame(self) -> pd.DataFrame:
        """Tidy table, one row per pose, output and name.

        Columns ``x_mm, y_mm, phi_deg, output, name, kind, S1, S1_conf, ST,
        ST_conf`` (indices and half-widths are dimensionless). The indices
        stay side by side, as SALib and ``prp3mc sobol --json`` report them;
        :meth:`conf_int` gives the same numbers in the long form
        (``statistic``, ``value``, ``se``, ``ci_low``, ``ci_high``, ``level``).
        """
        return pd.DataFrame({**self._keys(),
                             **{key: getattr(self, key).reshape(-1) for key in ("S1", "S1_conf", "ST", "ST_conf")}})

    def se(self, statistic: str) -> np.ndarray:
        """Bootstrap standard error of ``S1`` or ``ST``, (..., O, K): the half-width over ``z(conf_level)``."""
        if statistic not in _STATISTICS:
            raise BudgetError(f"no standard error for {statistic!r} (known: {', '.join(_STATISTICS)})")
        return getattr(self, f"{statistic}_conf") / z_value(self.conf_level)

    def conf_int(self, level: float = 0.95) -> pd.DataFrame:
        """Normal intervals ``S ± z(level) · se`` of every index, in the long form.

        Parameters
        ----------
        level : float
            Confidence level in (0, 1); at ``level == conf_level`` the
            interval is ``S ± S1_conf`` (or ``ST_conf``), SALib's.

        Returns
        -------
        DataFrame
            x_mm, y_mm, phi_deg, output, name, kind, statistic (``S1``, ``ST``),
            value, unit (``1``), se, ci_low, ci_high, level; one row per pose,
            output, name and statistic.
        """
        if not 0.0 < level < 1.0:
            raise BudgetError(f"level must lie in (0, 1), got {level}")
        z = z_value(level)
        frames = []
        for statistic in _STATISTICS:
            value, se = getattr(self, statistic).reshape(-1), self.se(statistic).reshape(-1)
            frame = pd.DataFrame({**self._keys(), "statistic": statistic, "value": value, "unit": "1", "se": se})
            frames.append(interval_frame(frame, value - z * se, value + z * se, level))
        return pd.concat(frames, ignore_index=True)

    def metadata(self) -> dict:
        return {"prp3mc_version": self.version, "seed": self.seed, "n_samples": self.n_samples,
                "num_resamples": self.num_resamples, "conf_level": self.conf_level,
                "bootstrap_seed": self.bootstrap_seed, "method": self.method,
                "wall_time_s": self.wall_time_s}


def _check_power_of_two(n: int, what: str) -> int:
    n = int(n)
    if n < 2 or n & (n - 1):
        raise BudgetError(f"{what} must be a power of two >= 2 (Sobol' sequences), got {n}")
    return n


def sobol_indices(geometry: Geometry, budget: Budget, poses, n_samples: int, *,
                  rng: "None | int | np.random.Generator" = None,
                  groups: dict | None = None, outputs=OUTPUTS, num_resamples: int = 100,
                  conf_level: float = 0.95, method: str = "auto", progress: bool | None = None,
                  max_chunk_bytes: int = 256 << 20, workers: int | None = None) -> SobolResult:
    """First-order and total Sobol indices of the pose error through SALib, batched over poses.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``; one sample matrix serves all of them.
    n_samples : int
        Base sample size N, a power of two; the model runs N (d + 2 + G)
        times per pose (d factors: inputs and the backlash_i, thermal effects; G groups).
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7). The integer seed used (drawn
        from a Generator, fresh for None) seeds SALib's scrambled Sobol'
        sampler; the bootstrap uses ``seed + 1``. Both are recorded.
    groups : dict of str to list of str, optional
        User groups (per leg, per error family...) in addition to the
        budget's groups (``clearance_i`` = rho_i, zeta_i always).
    outputs : sequence of str
        Among ``x``, ``y``, ``phi`` (δφ) and ``position`` (the norm of δx, δy).
    num_resamples : int
        Bootstrap resamples for the intervals.
    conf_level : float
        Level of the intervals, in (0, 1).
    method : {"auto", "salib", "vectorised"}
        ``salib`` calls ``SALib.analyze.sobol.analyze`` per pose, output and
        problem; ``vectorised`` computes the same estimators with the same
        bootstrap resamples for all poses at once (equal to SALib's numbers
        to round-off); ``auto`` is ``vectorised``.
    progress : bool, optional
        Progress on stderr (default: when stderr is a terminal).
    max_chunk_bytes : int
        Memory for one chunk of poses (the run streams over chunks).
    workers : int, optional
        Threads over chunks of poses (default: CPU count).

    Returns
    -------
    SobolResult
        Indices of shape (..., O, K): K names are the inputs, then the groups.

    Examples
    --------
    >>> from prp3mc import Geometry, Budget
    >>> r = sobol_indices(Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0, 100, 0],
    ...                   1024, rng=1)
    >>> r.ST.shape, r.names[-1]
    ((4, 15), 'clearance_3')
    """
    t0 = time.perf_counter()
    n_samples = _check_power_of_two(n_samples, "the Sobol base sample size N")
    outputs = tuple(outputs)
    unknown = [o for o in outputs if o not in OUTPUTS]
    if unknown or not outputs or len(set(outputs)) < len(outputs):
        raise BudgetError(f"bad outputs {list(outputs)}: choose distinct ones among {', '.join(OUTPUTS)}")
    if method not in _METHODS:
        raise BudgetError(f"unknown method {method!r} (known: {', '.join(_METHODS)})")
    if int(num_resamples) < 2:
        raise BudgetError(f"the bootstrap needs at least 2 resamples, got {num_resamples}")
    if not 0.0 < conf_level < 1.0:
        raise BudgetError(f"conf_level must lie in (0, 1), got {conf_level}")
    seed, _ = resolve_rng(rng)
    seed = seed % MAX_SEED             # leaves room for the bootstrap seed, seed + 1
    num_resamples, bootstrap_seed = int(num_resamples), seed + 1
    factors = design_factors(budget, groups)
    model = linear_model(geometry, budget, poses)                  # validates every pose
    shape = model.poses.shape[:-1]
    n_poses = int(np.prod(shape, dtype=int))
    if method == "auto":   # the vectorised estimators, at one pose too: 10 times faster than SALib's analyze
        method = "vectorised"

    U = saltelli_design(budget, factors, n_samples, seed)
    F = model.features(budget.ppf(np.clip(U.reshape(-1, len(budget.factors)), _U_EDGE, 1.0 - _U_EDGE)))
    del U
    K, O = len(factors.names), len(outputs)
    z = z_value(conf_level)
    coef = model.coef.reshape((n_poses,) + model.coef.shape[-2:])
    coef = coef * np.array([1.0, 1.0, RAD2DEG])[:, None]          # dphi in deg
    linear = [i for i, o in enumerate(outputs) if o != "position" and method == "vectorised"]
    sampled = [i for i in range(O) if i not in linear]
    if method == "vectorised":
        weights = resample_weights(n_samples, num_resamples, bootstrap_seed)
        with single_threaded_blas():      # R x N x F^2 products: one BLAS thread is faster, see prp3mc._threads
            fs = feature_sums(F.reshape(K + 2, n_samples, -1), factors, weights)
    per_pose = 8 * n_samples * (K + 2) * (3 + 2 * len(sampled)) + 8 * n_samples * len(sampled) * (4 + 2 * K)
    chunk = max(1, min(n_poses, max_chunk_bytes // per_pose))
    res = np.empty((4, n_poses, O, K))

    def work(start: int) -> int:
        sl = slice(start, min(n_poses, start + chunk))
        p = sl.stop - sl.start
        if linear:
            c = coef[sl][:, [OUTPUTS.index(outputs[i]) for i in linear]].reshape(p * len(linear), -1)
            res[:, sl, linear] = np.stack(linear_indices(c, fs, n_samples, z)).reshape(4, p, -1, K)
        if sampled:
            Y = model_outputs(coef[sl], F, tuple(outputs[i] for i in sampled)).reshape(-1, K + 2, n_samples)
            parts = (sample_indices(Y, factors, weights, n_samples, z) if method == "vectorised"
                     else salib_indices(Y, factors, num_resamples, conf_level, bootstrap_seed))
            res[:, sl, sampled] = np.stack(parts).reshape(4, p, -1, K)
        return p

    threads = 1 if method == "salib" else (workers or cores())
    with (single_threaded_blas(), Progress(n_poses, "sobol", progress) as bar,
          ThreadPoolExecutor(max_workers=threads) as pool):
        for done in pool.map(work, range(0, n_poses, chunk)):     # chunks of poses, not poses
            bar.update(done)
    constant = tuple(name for name, mask in zip(factors.names, factors.masks)
                     if all(law.var == 0 for law, inside in zip(budget.factor_laws.values(), mask) if inside))
    res[..., [factors.names.index(name) for name in constant]] = np.nan  # undefined, not 0
    S1, S1_conf, ST, ST_conf = (a.reshape(shape + (O, K)) for a in res)
    return SobolResult(poses=model.poses, n_samples=n_samples, seed=seed, outputs=outputs,
                       names=factors.names, kinds=factors.kinds, groups=factors.groups,
                       S1=S1, S1_conf=S1_conf, ST=ST, ST_conf=ST_conf, num_resamples=num_resamples,
                       conf_level=float(conf_level), bootstrap_seed=bootstrap_seed, method=method,
                       constant=constant, wall_time_s=time.perf_counter() - t0)



def sobol_converge(geometry: Geometry, budget: Budget, poses, *, target_width: float = 0.05,
                   n_start: int = 1024, n_max: int = 2**16,
                   rng: "None | int | np.random.Generator" = None, which: str = "ST",
                   min_index: float = 0.05, **kwargs) -> tuple[SobolResult, pd.DataFrame]:
    """Double N until the widest interval of the indices that matter is below ``target_width``.

    An index matters where its ST exceeds ``min_index`` (any pose and
    output); an interval's width is its full width, 2 x the half-width.
    The seed is kept, so each run extends the previous Sobol' points.

    Parameters
    ----------
    geometry, budget, poses
        As for :func:`sobol_indices`.
    target_width : float
        Largest acceptable full interval width.
    n_start, n_max : int
        First and largest N, powers of two.
    rng : None, int or numpy.random.Generator
        As in :func:`sobol_indices`; one seed serves every run, so each run
        extends the previous Sobol' points.
    which : {"ST", "S1", "both"}
        The intervals checked.
    min_index : float
    **kwargs
        Passed to :func:`sobol_indices` (groups, outputs, method, ...).

    Returns
    -------
    result : SobolResult
        The last run (the converged one unless N reached ``n_max``).
    history : DataFrame
        n_samples, max_width, n_indices (that matter), converged, wall_time_s;
        ``history["converged"].iloc[-1]`` says whether the target was met.
    """
    n = _check_power_of_two(n_start, "n_start")
    n_max = _check_power_of_two(n_max, "n_max")
    if n > n_max:
        raise BudgetError(f"n_start = {n} exceeds n_max = {n_max}")
    if which not in ("ST", "S1", "both"):
        raise BudgetError(f"which must be 'ST', 'S1' or 'both', got {which!r}")
    if not target_width > 0:
        raise BudgetError(f"target_width must be > 0, got {target_width}")
    seed, _ = resolve_rng(rng)
    rows = []
    while True:
        result = sobol_indices(geometry, budget, poses, n, rng=seed, **kwargs)
        matters = result.ST > min_index
        conf = {"ST": result.ST_conf, "S1": result.S1_conf,
                "both": np.maximum(result.ST_conf, result.S1_conf)}[which]
        width = float(2 * conf[matters].max()) if matters.any() else 0.0
        done = width < target_width
        rows.append({"n_samples": n, "max_width": width, "n_indices": int(matters.sum()),
                     "converged": done, "wall_time_s": result.wall_time_s})
        if done or n >= n_max:
            return result, pd.DataFrame(rows)
        n *= 2
