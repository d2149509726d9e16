"""Variance-based sensitivity of the pose error: Sobol indices and Shapley effects, batched over poses.

The public entry of the Sobol wing: :func:`sobol_indices` runs SALib's
design and estimators (:mod:`~prp3mc.sobol.saltelli`: scrambled Sobol'
points, Saltelli's radial scheme, the Saltelli 2010 first-order and Jansen
total estimators) on the linear model of a budget, for every pose and output
at once, and adds the Shapley effects (:mod:`~prp3mc.sobol.shapley`);
:func:`sobol_converge` doubles N until the intervals are narrow enough. The
closed forms the estimates are tested against live in
:mod:`~prp3mc.sobol.closed_form`, the ranking next to the worst
case in :mod:`~prp3mc.sobol.ranking`.

Intervals: randomised quasi-Monte Carlo. The N base points are split into R
replicates of N / R points, each a Saltelli design of its own independently
scrambled Sobol' sequence; an index is the mean of the R replicates'
estimates and ``S1_conf``, ``ST_conf`` the half-widths of the Student t
intervals ``mean ± t(conf_level, R - 1) sd / sqrt(R)``, whose coverage is
measured in benchmarks/coverage_sobol.py. The standard error is
``se = conf / t(conf_level, R - 1)`` and the interval at any level
``S ± t(level, R - 1) · se`` (:meth:`SobolResult.conf_int`). ``Sh_conf`` is
the Student t half-width over as many batches of random orders.

Dependent inputs: Sobol indices split the variance only when the inputs are
independent. For a budget with a ``[correlation]`` table S1 and ST are not
computed (NaN, with a warning) and the Shapley effects ``Sh`` share the
variance (SPEC §10).
"""

from __future__ import annotations

import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._result import freeze, interval_frame, name_columns, short_repr
from .._rng import MAX_SEED, child_seed, resolve_rng
from .._threads import check_stop, cores, single_threaded_blas
from .._version import __version__
from ..errors import BudgetError, ParameterError, Prp3mcWarning
from ..kinematics.geometry import Geometry
from ..progress import Progress
from ..units import OUTPUTS, RAD2DEG, t_value
from ..model.budget import Budget
from ..model.linear import linear_model
from .saltelli import (combine_replicates, design_factors, feature_sums, linear_sums, model_outputs,
                       replicate_indices, salib_indices, saltelli_design, sample_sums)
from .shapley import shapley_effects

__all__ = ["SobolResult", "sobol_indices", "sobol_converge", "DEPENDENT_NOTE"]

_METHODS = ("auto", "salib", "vectorised")
_U_EDGE = 2.0**-53        # unit samples are clipped into (0, 1): unbounded laws stay finite
#: Why S1 and ST of a correlated budget are not reported (warning, JSON ``reason``, reports).
DEPENDENT_NOTE = ("the budget correlates some inputs: Sobol indices split the variance only for independent "
                  "inputs, so S1 and ST are not computed; the Shapley effects Sh share it")


@dataclass(frozen=True, slots=True, repr=False)
class SobolResult:
    """First-order and total Sobol indices and Shapley effects with their intervals, per pose.

    Shapes: ``...`` is the batch shape of ``poses``; O outputs, K names.
    Read-only: arrays cannot be written, ``groups`` is a read-only mapping.

    Attributes
    ----------
    poses : ndarray (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    n_samples : int
        Base sample size N (a power of two) over all replicates; the model ran
        N (d + 2 + G) times for the Sobol indices.
    seed : int
        Root seed: replicate r scrambles its Sobol' points with
        ``child_seed(seed, 0, r)``, the Shapley draws use ``child_seed(seed, 1)``.
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
        Indices (the mean over the replicates) and the half-widths of their
        ``conf_level`` Student t intervals. NaN for the names in ``constant``,
        and everywhere for a correlated budget (:data:`DEPENDENT_NOTE`).
    Sh, Sh_conf : ndarray (..., O, K) or None
        Shapley effects (:func:`~prp3mc.sobol.shapley.shapley_effects`)
        and their half-widths; None when not asked for.
    replicates : int
        Independent scramblings R (also the Shapley batches).
    conf_level : float
    method : str
        ``salib`` or ``vectorised`` (the path that ran).
    shapley_permutations : int
        Random orders of the Shapley effects (0: not computed).
    correlated : bool
        Whether the budget correlates some of its factors.
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
    replicates: int
    conf_level: float
    method: str
    Sh: np.ndarray | None = None
    Sh_conf: np.ndarray | None = None
    shapley_permutations: int = 0
    correlated: bool = False
    constant: tuple = ()
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "S1", "n_samples", "seed", "method")

    @property
    def statistics(self) -> tuple:
        """The statistics the result holds: ``S1``, ``ST`` and, when computed, ``Sh``."""
        return ("S1", "ST") + (("Sh",) if self.Sh is not None else ())

    def _keys(self) -> dict:
        return name_columns(self.poses, self.outputs, self.names, self.kinds)

    def to_frame(self) -> pd.DataFrame:
        """Tidy table, one row per pose, output and name.

        Columns ``x_mm, y_mm, phi_deg, output, name, kind, S1, S1_conf, ST,
        ST_conf`` and, when computed, ``Sh, Sh_conf`` (dimensionless). The
        indices stay side by side, as SALib and ``prp3mc sobol --json`` report
        them; :meth:`conf_int` gives the same numbers in the long form
        (``statistic``, ``value``, ``se``, ``ci_low``, ``ci_high``, ``level``).
        """
        keys = [k for s in self.statistics for k in (s, f"{s}_conf")]
        return pd.DataFrame({**self._keys(), **{key: getattr(self, key).reshape(-1) for key in keys}})

    def se(self, statistic: str) -> np.ndarray:
        """Standard error of ``S1``, ``ST`` or ``Sh``, (..., O, K): the half-width over ``t(conf_level, R - 1)``."""
        if statistic not in self.statistics:
            raise ParameterError(f"no standard error for {statistic!r} (known: {', '.join(self.statistics)})")
        return getattr(self, f"{statistic}_conf") / t_value(self.conf_level, self.replicates - 1)

    def conf_int(self, level: float = 0.95) -> pd.DataFrame:
        """Student t intervals ``S ± t(level, R - 1) · se`` of every index, in the long form.

        Parameters
        ----------
        level : float
            Confidence level in (0, 1); at ``level == conf_level`` the
            interval is ``S ± S1_conf`` (or ``ST_conf``, ``Sh_conf``).

        Returns
        -------
        DataFrame
            x_mm, y_mm, phi_deg, output, name, kind, statistic (``S1``, ``ST``, ``Sh``),
            value, unit (``1``), se, ci_low, ci_high, level; one row per pose,
            output, name and statistic.
        """
        if not 0.0 < level < 1.0:
            raise ParameterError(f"level must lie in (0, 1), got {level}")
        t = t_value(level, self.replicates - 1)
        frames = []
        for statistic in self.statistics:
            value, se = getattr(self, statistic).reshape(-1), self.se(statistic).reshape(-1)
            frame = pd.DataFrame({**self._keys(), "statistic": statistic, "value": value, "unit": "1", "se": se})
            frames.append(interval_frame(frame, value - t * se, value + t * se, level))
        return pd.concat(frames, ignore_index=True)

    def metadata(self) -> dict:
        return {"prp3mc_version": self.version, "seed": self.seed, "n_samples": self.n_samples,
                "replicates": self.replicates, "conf_level": self.conf_level, "method": self.method,
                "shapley_permutations": self.shapley_permutations, "wall_time_s": self.wall_time_s}


def _check_power_of_two(n: int, what: str) -> int:
    n = int(n)
    if n < 2 or n & (n - 1):
        raise ParameterError(f"{what} must be a power of two >= 2 (Sobol' sequences), got {n}")
    return n


def sobol_indices(geometry: "Geometry | str", budget: "Budget | str", poses, n_samples: int, *,
                  rng: "None | int | np.random.Generator" = None,
                  groups: dict | None = None, outputs=OUTPUTS, replicates: int = 16,
                  conf_level: float = 0.95, method: str = "auto", shapley_permutations: int | None = None,
                  progress: bool | None = None, max_chunk_bytes: int = 256 << 20,
                  workers: int | None = None) -> SobolResult:
    """First-order and total Sobol indices and Shapley effects of the pose error, batched over poses.

    Parameters
    ----------
    geometry : Geometry or str
        A Geometry, preset name or TOML path.
    budget : Budget or str
        A Budget, preset name or TOML path.
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``; one sample matrix serves all of them.
    n_samples : int
        Base sample size N over all replicates, a power of two, at least
        2 R; the model runs N (d + 2 + G) times per pose (d factors: inputs
        and the backlash_i, thermal effects; G groups).
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7). The integer seed used (drawn
        from a Generator, fresh for None) is recorded; replicate r's
        scrambling seed is ``child_seed(seed, 0, r)``.
    groups : dict of str to list of str, optional
        User groups (per leg, per error family...) in addition to the
        budget's groups (``clearance_i`` = rho_i, zeta_i always).
    outputs : sequence of str
        Among ``x``, ``y``, ``phi`` (δφ) and ``position`` (the norm of δx, δy).
    replicates : int
        Independent scramblings R, a power of two >= 2 (default 16): each
        replicate is a Saltelli design of N / R points.
    conf_level : float
        Level of the intervals, in (0, 1).
    method : {"auto", "salib", "vectorised"}
        ``salib`` calls ``SALib.analyze.sobol.analyze`` per replicate, pose,
        output and problem; ``vectorised`` computes the same estimators for
        all poses at once (equal to SALib's numbers to round-off); ``auto``
        is ``vectorised``.
    shapley_permutations : int, optional
        Random orders of the Shapley effects (default N / 2: about as many
        model runs as the Sobol design for a dozen factors); 0 skips them.
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

    Warns
    -----
    Prp3mcWarning
        For a correlated budget (:data:`DEPENDENT_NOTE`): S1 and ST are NaN.

    Examples
    --------
    >>> from prp3mc import Geometry, Budget
    >>> r = sobol_indices(Geometry.from_preset("u-shape"), Budget.from_preset("paper"), [0, 100, 0],
    ...                   1024, rng=1)
    >>> r.ST.shape, r.names[-1]
    ((4, 15), 'clearance_3')
    """
    t0 = time.perf_counter()
    geometry, budget = Geometry.load(geometry), Budget.load(budget)
    n_samples = _check_power_of_two(n_samples, "the Sobol base sample size N")
    replicates = _check_power_of_two(replicates, "the number of replicates")
    if n_samples < 2 * replicates:
        raise ParameterError(f"N = {n_samples} is too small for {replicates} replicates: each needs at least "
                          f"2 points (N >= {2 * replicates})")
    n_rep = n_samples // replicates
    outputs = tuple(outputs)
    unknown = [o for o in outputs if o not in OUTPUTS]
    if unknown or not outputs or len(set(outputs)) < len(outputs):
        raise ParameterError(f"bad outputs {list(outputs)}: choose distinct ones among {', '.join(OUTPUTS)}")
    if method not in _METHODS:
        raise ParameterError(f"unknown method {method!r} (known: {', '.join(_METHODS)})")
    if not 0.0 < conf_level < 1.0:
        raise ParameterError(f"conf_level must lie in (0, 1), got {conf_level}")
    perms = n_samples // 2 if shapley_permutations is None else int(shapley_permutations)
    if perms < 0:
        raise ParameterError(f"shapley_permutations must be >= 0, got {shapley_permutations}")
    seed, _ = resolve_rng(rng)
    seed = seed % (MAX_SEED + 1)
    factors = design_factors(budget, groups)
    model = linear_model(geometry, budget, poses)                  # validates every pose
    shape = model.poses.shape[:-1]
    n_poses = int(np.prod(shape, dtype=int))
    if method == "auto":   # the vectorised estimators, at one pose too (faster: benchmarks/README.md)
        method = "vectorised"
    K, O = len(factors.names), len(outputs)
    res = np.full((4, n_poses, O, K), np.nan)
    if budget.correlated:
        warnings.warn(Prp3mcWarning(f"budget {budget.name!r}: {DEPENDENT_NOTE}"), stacklevel=2)
    else:
        _sobol_replicates(budget, model, factors, outputs, n_rep, replicates, seed, method, conf_level,
                          res, progress, max_chunk_bytes, workers)
    constant = tuple(name for name, mask in zip(factors.names, factors.masks)
                     if all(law.var == 0 for law, inside in zip(budget.factor_laws.values(), mask) if inside))
    res[..., [factors.names.index(name) for name in constant]] = np.nan  # undefined, not 0
    S1, S1_conf, ST, ST_conf = (a.reshape(shape + (O, K)) for a in res)
    Sh = Sh_conf = None
    if perms:
        sh = shapley_effects(geometry, budget, poses, max(perms, 2 * replicates), rng=child_seed(seed, 1),
                             groups=groups, outputs=outputs, batches=replicates, conf_level=conf_level,
                             progress=progress, max_chunk_bytes=max_chunk_bytes)
        Sh, Sh_conf, perms = sh.Sh, sh.Sh_conf, sh.n_permutations
    return SobolResult(poses=model.poses, n_samples=n_samples, seed=seed, outputs=outputs,
                       names=factors.names, kinds=factors.kinds, groups=factors.groups,
                       S1=S1, S1_conf=S1_conf, ST=ST, ST_conf=ST_conf, replicates=replicates,
                       conf_level=float(conf_level), method=method, Sh=Sh, Sh_conf=Sh_conf,
                       shapley_permutations=perms, correlated=budget.correlated,
                       constant=constant, wall_time_s=time.perf_counter() - t0)


def _sobol_replicates(budget, model, factors, outputs, n_rep, replicates, seed, method, conf_level, res,
                      progress, max_chunk_bytes, workers) -> None:
    """Fill ``res`` (4, P, O, K) with S1, S1_conf, ST, ST_conf from R replicated Saltelli designs."""
    n_poses = res.shape[1]
    K, O, R = len(factors.names), len(outputs), replicates
    d = len(budget.factors)
    U = np.stack([saltelli_design(budget, factors, n_rep, child_seed(seed, 0, r)) for r in range(R)])
    F = model.features(budget.ppf(np.clip(U.reshape(-1, d), _U_EDGE, 1.0 - _U_EDGE)))    # (R (K + 2) n, F)
    del U
    coef = model.coef.reshape((n_poses,) + model.coef.shape[-2:])
    coef = coef * np.array([1.0, 1.0, RAD2DEG])[:, None]          # dphi in deg
    linear = [i for i, o in enumerate(outputs) if o != "position" and method == "vectorised"]
    sampled = [i for i in range(O) if i not in linear]
    if linear:
        with single_threaded_blas():
            fs = [feature_sums(Fr, factors) for Fr in F.reshape(R, K + 2, n_rep, -1)]
    per_pose = 8 * n_rep * R * (K + 2) * (3 + 2 * len(sampled)) + 8 * n_rep * R * len(sampled) * (4 + 2 * K)
    chunk = max(1, min(n_poses, max_chunk_bytes // per_pose))

    def finish(sums, level, M):                                   # (M R, 4 + 2K), (M R,) -> 4 (M, K)
        S1, ST = replicate_indices(np.moveaxis(sums.reshape(M, R, -1), 1, -1), level.reshape(M, R), n_rep)
        return (*combine_replicates(S1, conf_level), *combine_replicates(ST, conf_level))

    def work(start: int) -> int:
        check_stop()
        sl = slice(start, min(n_poses, start + chunk))
        p = sl.stop - sl.start
        if linear:
            c = coef[sl][:, [OUTPUTS.index(outputs[i]) for i in linear]].reshape(p * len(linear), -1)
            parts = [linear_sums(c, f) for f in fs]                      # per replicate: (M, 4 + 2K), (M,)
            sums = np.stack([s for s, _ in parts], axis=1).reshape(-1, 4 + 2 * K)
            level = np.stack([lv for _, lv in parts], axis=1).reshape(-1)
            res[:, sl, linear] = np.stack(finish(sums, level, p * len(linear))).reshape(4, p, -1, K)
        if sampled:
            Y = model_outputs(coef[sl], F, tuple(outputs[i] for i in sampled)).reshape(-1, K + 2, n_rep)
            if method == "vectorised":                              # rows (pose, output, replicate)
                parts = finish(*sample_sums(Y, factors), p * len(sampled))
            else:
                est = [salib_indices(Yr, factors, conf_level, child_seed(seed, 2))
                       for Yr in np.moveaxis(Y.reshape(p * len(sampled), R, K + 2, n_rep), 1, 0)]
                S1, ST = (np.stack([e[j] for e in est], axis=-1) for j in (0, 1))
                parts = (*combine_replicates(S1, conf_level), *combine_replicates(ST, conf_level))
            res[:, sl, sampled] = np.stack(parts).reshape(4, p, -1, K)
        return p

    threads = 1 if method == "salib" else (workers or cores())
    with (single_threaded_blas(), Progress(n_poses, "sobol", progress) as bar,
          ThreadPoolExecutor(max_workers=threads) as pool):
        for done in pool.map(work, range(0, n_poses, chunk)):     # chunks of poses, not poses
            bar.update(done)


def sobol_converge(geometry: Geometry, budget: Budget, poses, *, target_width: float = 0.05,
                   n_start: int = 1024, n_max: int = 2**16,
                   rng: "None | int | np.random.Generator" = None, which: str | None = None,
                   min_index: float = 0.05, **kwargs) -> tuple[SobolResult, pd.DataFrame]:
    """Double N until the widest interval of the indices that matter is below ``target_width``.

    An index matters where its ST (Sh when ``which`` is ``"Sh"``) exceeds
    ``min_index`` (any pose and output); an interval's width is its full
    width, 2 x the half-width. The seed is kept, so each run extends the
    previous Sobol' points.

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
    which : {"ST", "S1", "both", "Sh"}, optional
        The intervals checked (default ``"ST"``; ``"Sh"`` for a correlated
        budget, which has no Sobol indices).
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
        raise ParameterError(f"n_start = {n} exceeds n_max = {n_max}")
    which = which or ("Sh" if budget.correlated else "ST")
    if which not in ("ST", "S1", "both", "Sh"):
        raise ParameterError(f"which must be 'ST', 'S1', 'both' or 'Sh', got {which!r}")
    if which != "Sh" and budget.correlated:
        raise BudgetError(f"budget {budget.name!r} correlates inputs: it has no Sobol indices to converge; "
                          "use which='Sh'")
    if which == "Sh" and kwargs.get("shapley_permutations") == 0:
        raise ParameterError("which='Sh' needs the Shapley effects: shapley_permutations must not be 0")
    if not target_width > 0:
        raise ParameterError(f"target_width must be > 0, got {target_width}")
    seed, _ = resolve_rng(rng)
    rows = []
    while True:
        result = sobol_indices(geometry, budget, poses, n, rng=seed, **kwargs)
        matters = (result.Sh if which == "Sh" else result.ST) > min_index
        conf = {"ST": result.ST_conf, "S1": result.S1_conf, "Sh": result.Sh_conf,
                "both": np.maximum(result.ST_conf, result.S1_conf)}[which]
        width = float(2 * conf[matters].max()) if matters.any() else 0.0
        done = width < target_width
        rows.append({"n_samples": n, "max_width": width, "n_indices": int(matters.sum()),
                     "converged": done, "wall_time_s": result.wall_time_s})
        if done or n >= n_max:
            return result, pd.DataFrame(rows)
        n *= 2
