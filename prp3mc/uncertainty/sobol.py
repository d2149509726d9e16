"""Variance-based (Sobol) sensitivity indices of the pose error, next to the worst case.

Design. SALib's ``sobol`` sampler (scrambled Sobol' sequence, Saltelli's
radial scheme, ``calc_second_order=False``) on the unit cube gives, for a base
sample size N, two independent matrices A and B (N x d) and, for each input j,
AB_j = A with column j taken from B. The budget's ``ppf`` maps the unit sample
to the inputs, so every law works. A group g (``clearance_i`` = rho_i, zeta_i,
or a user group) needs AB_g = A with all of g's columns taken from B, which
is exactly what SALib's sampler builds for a problem whose ``groups`` make g
one factor and every other input a factor of its own. All factors (inputs
and groups) therefore share A and B: the model is evaluated once on
[A, B, AB_1..AB_d, AB_g1..AB_gG], N (d + 2 + G) rows, for every pose in one
vectorised pass per chunk of poses, and the per-input and per-group indices
come from the same evaluations. The per-input indices are those of SALib's
problem without groups, a group's those of the problem that groups g alone.

Estimators (as ``SALib.analyze.sobol``): the output of each SALib problem is
centred and scaled by its own mean and standard deviation, then
``S1 = mean(B (AB - A)) / var([A, B])`` (Saltelli 2010) and
``ST = mean((A - AB)^2) / 2 / var([A, B])`` (Jansen), with a bootstrap of
``num_resamples`` resamples of the N rows; the interval half-width is
``z * sd`` of the bootstrap estimates. SALib analyses one output of one pose
for one problem per call (0.6 s for d = 12, N = 8192, R = 100: hours for a
21 x 21 grid); the vectorised path computes the same numbers for all poses
and outputs at once. Every statistic is a weighted sum over the N rows, the
weights being the multiplicities of each bootstrap resample (the indices
SALib draws from the same seed) or all ones for the estimate, so they are
one matrix product of the (R + 1) x N weight matrix with the per-row
quantities a, a^2, b, b^2 and, per factor, (b - delta_k) D_k and D_k^2
(D_k = AB_k - A, delta_k the centre of k's SALib problem). For the linear
outputs δx, δy, δφ = c . f (f the model's sample features) those sums are
quadratic forms in c of pose-independent weighted sums of feature products,
so only the position norm needs per-pose, per-sample work.

Closed form. δx, δy and δφ are linear in independent terms: values of the
inputs, and rho_i cos(zeta_i - omega_i) for a clearance. A term's part of
Var(E[y | X_s]) for an input set s is its column squared times
Var(x) (a value term, s holding x), Var(rho) E[c]^2 (s = {rho}),
E[rho]^2 Var(c) (s = {zeta}) or Var(rho c) (both), with c = cos(zeta - omega)
and the moments of zeta by quadrature of its ppf; first-order and total
indices of any input or group follow by summing over terms.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import integrate, stats

from .._rng import resolve_rng
from .._version import __version__
from .budget import Budget, parse_input
from .laws import angle_moments
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from .model import LinearModel, linear_model
from ..progress import Progress
from .worstcase import WorstCase

__all__ = ["SobolResult", "sobol_indices", "analytic_indices", "ranking", "sobol_converge", "OUTPUTS"]

#: Outputs: δx (mm), δy (mm), δφ (deg) and the position-error norm (mm).
OUTPUTS = ("x", "y", "phi", "position")
_UNITS = {"x": "mm", "y": "mm", "phi": "deg", "position": "mm"}
_METHODS = ("auto", "salib", "vectorised")
_SALIB_MAX_POSES = 1      # method="auto" hands a single pose to SALib itself
_U_EDGE = 2.0**-53        # unit samples are clipped into (0, 1): unbounded laws stay finite
_RAD2DEG = 180.0 / math.pi


@dataclass(frozen=True, slots=True)
class SobolResult:
    """First-order and total Sobol indices with bootstrap intervals, per pose.

    Shapes: ``...`` is the batch shape of ``poses``; O outputs, K names.

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
        The budget's inputs, then the groups.
    kinds : tuple of str
        ``input`` or ``group`` per name.
    groups : dict of str to tuple of str
        Members of every group.
    S1, S1_conf, ST, ST_conf : ndarray (..., O, K)
        Indices and the half-widths of their ``conf_level`` intervals.
    num_resamples : int
    conf_level : float
    bootstrap_seed : int
        Seed of the bootstrap resampling (SALib's ``seed``): ``seed + 1``,
        because SALib ignores a seed of 0.
    method : str
        ``salib`` or ``vectorised`` (the path that ran).
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
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def to_frame(self) -> pd.DataFrame:
        """Tidy table: x_mm, y_mm, phi_deg, output, name, kind, S1, S1_conf, ST, ST_conf."""
        flat = self.poses.reshape(-1, 3)
        n, O, K = flat.shape[0], len(self.outputs), len(self.names)
        pose = np.repeat(np.arange(n), O * K)
        return pd.DataFrame({
            "x_mm": flat[pose, 0], "y_mm": flat[pose, 1], "phi_deg": flat[pose, 2],
            "output": np.tile(np.repeat(self.outputs, K), n), "name": np.tile(self.names, n * O),
            "kind": np.tile(self.kinds, n * O),
            **{key: getattr(self, key).reshape(-1) for key in ("S1", "S1_conf", "ST", "ST_conf")},
        })

    def metadata(self) -> dict:
        return {"prp3mc_version": self.version, "seed": self.seed, "n_samples": self.n_samples,
                "num_resamples": self.num_resamples, "conf_level": self.conf_level,
                "bootstrap_seed": self.bootstrap_seed, "method": self.method,
                "wall_time_s": self.wall_time_s}


# ---------------------------------------------------------------- factors and design
@dataclass(frozen=True, slots=True)
class _Factors:
    """Inputs and groups as factors of Saltelli's design.

    ``masks`` (K, d): the inputs each factor takes from B. ``problem`` (K, K):
    the factors of the SALib problem that reports factor k (all inputs for an
    input; for a group, the group and the inputs outside it).
    """

    names: tuple
    kinds: tuple
    groups: dict
    masks: np.ndarray
    problem: np.ndarray


def _factors(budget: Budget, groups: dict | None) -> _Factors:
    """The budget's inputs, then its groups and the user's ``groups`` (validated by :class:`Budget`)."""
    extra = {}
    for gname, members in (groups or {}).items():
        if isinstance(members, str):
            raise BudgetError(f"group {gname!r}: expected a list of inputs, got the string {members!r}")
        extra[str(gname)] = tuple(members)
    user = {k: v for k, v in budget.groups.items() if not k.startswith("clearance_")}
    merged = Budget(budget.inputs, groups={**user, **extra}).groups  # validates the groups
    inputs = budget.names
    d = len(inputs)
    names = inputs + tuple(merged)
    masks = np.zeros((len(names), d), dtype=bool)
    masks[np.arange(d), np.arange(d)] = True
    for k, members in enumerate(merged.values(), start=d):
        masks[k, [inputs.index(m) for m in members]] = True
    problem = np.zeros((len(names), len(names)), dtype=bool)
    problem[:d, :d] = True
    for k in range(d, len(names)):
        problem[k, k] = True
        problem[k, :d] = ~masks[k]
    return _Factors(names=names, kinds=("input",) * d + ("group",) * len(merged),
                    groups={k: tuple(v) for k, v in merged.items()}, masks=masks, problem=problem)


def _salib_problem(inputs: tuple, members: tuple = ()) -> dict:
    """SALib problem on the unit cube; ``members`` become one group named ``__group__``."""
    problem = {"num_vars": len(inputs), "names": list(inputs), "bounds": [[0.0, 1.0]] * len(inputs)}
    if members:
        problem["groups"] = ["__group__" if name in members else name for name in inputs]
    return problem


def _design(budget: Budget, factors: _Factors, n_samples: int, seed: int) -> np.ndarray:
    """Unit samples of SALib's sobol sampler rearranged as [A, B, AB_1..AB_K], shape (K + 2, N, d).

    A and B come from SALib's own matrix (rows 0 and d + 1 of each block of
    d + 2); AB_k takes the columns of factor k from B, as SALib's sampler
    does for the problem that makes k one factor.
    """
    from SALib.sample import sobol as sobol_sample
    d = len(budget)
    U = sobol_sample.sample(_salib_problem(budget.names), n_samples, calc_second_order=False,
                            scramble=True, seed=seed).reshape(n_samples, d + 2, d)
    A, B = U[:, 0], U[:, d + 1]
    AB = np.where(factors.masks[:, None, :], B, A)
    return np.concatenate([A[None], B[None], AB], axis=0)


def _outputs(coef: np.ndarray, F: np.ndarray, outputs: tuple) -> np.ndarray:
    """Outputs (p, O, n) for model coefficients (p, 3, F) and sample features F (n, F).

    The pose errors are ``coef @ features``, :meth:`LinearModel.evaluate` as
    one matrix product laid out for the estimators; the position-error norm
    is that of (dx, dy).
    """
    p = coef.shape[0]
    rows = [r for r in range(3) if OUTPUTS[r] in outputs or (r < 2 and "position" in outputs)]
    E = (coef[:, rows].reshape(p * len(rows), -1) @ F.T).reshape(p, len(rows), -1)
    error = {OUTPUTS[r]: E[:, j] for j, r in enumerate(rows)}
    Y = np.empty((p, len(outputs), F.shape[0]))
    for i, o in enumerate(outputs):
        if o == "position":
            np.multiply(error["x"], error["x"], out=Y[:, i])
            Y[:, i] += error["y"] * error["y"]
            np.sqrt(Y[:, i], out=Y[:, i])
        else:
            Y[:, i] = error[o]
    return Y


# ---------------------------------------------------------------- estimators
def _resample_weights(n_samples: int, num_resamples: int, bootstrap_seed: int) -> np.ndarray:
    """Row 0 all ones (the estimate), then the multiplicity of each row in each resample, (R + 1, N).

    The resamples are SALib's: ``default_rng(seed).integers(N, size=(N, R))``.
    """
    r = np.random.default_rng(bootstrap_seed).integers(n_samples, size=(n_samples, num_resamples))
    counts = np.bincount((r + n_samples * np.arange(num_resamples)).ravel(),
                         minlength=n_samples * num_resamples).reshape(num_resamples, n_samples)
    return np.concatenate([np.ones((1, n_samples)), counts], axis=0)


def _constant(var: np.ndarray, mean_square: np.ndarray) -> np.ndarray:
    """Outputs that do not vary over A and B (variance below 1e-24 of their mean square): indices 0."""
    return var <= 1e-24 * mean_square


def _problem_shift(sum_A: np.ndarray, sum_B: np.ndarray, sum_AB: np.ndarray, factors: _Factors,
                   n_samples: int) -> np.ndarray:
    """Mean of each factor's SALib problem, (..., K), from row sums over A, B (...) and AB_k (..., K).

    SALib centres the output of a problem on its own rows: A, B and the AB
    of that problem's factors.
    """
    n_rows = 2 + factors.problem.sum(axis=1)
    return ((sum_A + sum_B)[..., None] + sum_AB @ factors.problem.T) / (n_samples * n_rows)


def _finish(s: np.ndarray, level: np.ndarray, n_samples: int, z: float):
    """SALib's indices and half-widths from weighted sums over the design rows.

    Parameters
    ----------
    s : ndarray (M, 4 + 2K, R + 1)
        Sums of a, a^2, b, b^2 (the A and B outputs, centred on their mean),
        then per factor k of (b - delta_k) D_k and D_k^2, with D_k = AB_k - A and
        delta_k the centre of k's SALib problem; column 0 with unit weights
        (the estimate), the others with each bootstrap resample's weights.
    level : ndarray (M,)
        Mean square of the uncentred A and B outputs.

    Returns
    -------
    S1, S1_conf, ST, ST_conf : ndarray (M, K)
        ``S1 = mean((b - delta) D) / var`` (Saltelli 2010), ``ST = mean(D^2) / 2 / var``
        (Jansen); half-widths ``z`` times the sd of the resampled estimates.
    """
    K = (s.shape[1] - 4) // 2
    mean = (s[:, 0] + s[:, 2]) / (2 * n_samples)
    var = (s[:, 1] + s[:, 3]) / (2 * n_samples) - mean**2           # var([A, B]), (M, R + 1)
    flat = _constant(var[:, 0], level)
    var = np.where(flat[:, None], 1.0, var)[:, None, :]
    out = []
    for S in (s[:, 4:4 + K] / n_samples / var, 0.5 * s[:, 4 + K:] / n_samples / var):
        est, conf = S[..., 0], z * S[..., 1:].std(axis=-1, ddof=1)
        out += [np.where(flat[:, None], 0.0, est), np.where(flat[:, None], 0.0, conf)]
    return tuple(out)


def _sample_sums(Y: np.ndarray, factors: _Factors, weights: np.ndarray):
    """Weighted sums for :func:`_finish` from outputs Y (M, K + 2, N) = [A, B, AB_1..AB_K]; any output."""
    M, K2, N = Y.shape
    K = K2 - 2
    c0 = Y[:, :2].mean(axis=(-2, -1))
    level = np.square(Y[:, :2]).mean(axis=(-2, -1))
    sums = Y.sum(axis=-1) - N * c0[:, None]                         # of the centred rows
    delta = _problem_shift(sums[:, 0], sums[:, 1], sums[:, 2:], factors, N)
    Q = np.empty((M, 4 + 2 * K, N))                                 # a, a^2, b, b^2, (b - d_k) D_k, D_k^2
    for row, src in ((0, 0), (2, 1)):
        np.subtract(Y[:, src], c0[:, None], out=Q[:, row])
        np.square(Q[:, row], out=Q[:, row + 1])
    D = Q[:, 4 + K:]
    np.subtract(Y[:, 2:], Y[:, :1], out=D)
    BD = Q[:, 4:4 + K]
    np.subtract(Q[:, 2, None, :], delta[..., None], out=BD)
    BD *= D
    np.square(D, out=D)
    return (Q.reshape(-1, N) @ weights.T).reshape(M, 4 + 2 * K, -1), level


@dataclass(frozen=True, slots=True)
class _FeatureSums:
    """Weighted sums over the design rows of products of the centred sample features.

    A linear output ``y = c . f`` has every sum :func:`_finish` needs as a
    quadratic or linear form in c of these pose-independent sums, so the
    outputs dx, dy, dphi of all poses cost a few small contractions. ``D_k``
    (features of AB_k minus those of A) vanishes outside the features of
    factor k (``cols[k]``), which keeps the sums small.
    """

    mean: np.ndarray            # (F,) feature means over the A and B rows
    second: np.ndarray          # (F, F) mean of f f^T over the A and B rows
    A: np.ndarray               # (R + 1, F)
    AA: np.ndarray              # (R + 1, F, F)
    B: np.ndarray
    BB: np.ndarray
    shift: np.ndarray           # (F, K): delta_k = c . shift[:, k]
    cols: tuple                 # per factor: the features D_k touches
    BD: tuple                   # per factor: (R + 1, F, |cols|), sums of b D_k^T
    D: tuple                    # per factor: (R + 1, |cols|)
    DD: tuple                   # per factor: (R + 1, |cols|, |cols|)


def _feature_sums(Fd: np.ndarray, factors: _Factors, weights: np.ndarray) -> _FeatureSums:
    """:class:`_FeatureSums` from the design's features Fd (K + 2, N, F)."""
    N, nf = Fd.shape[1:]
    AB = Fd[:2].reshape(2 * N, nf)
    mean = AB.mean(axis=0)
    FA, FB = Fd[0] - mean, Fd[1] - mean

    def wsum(*factors_):                                            # sum_n w_rn prod(factors)[n, ...]
        prod = factors_[0] if len(factors_) == 1 else \
            factors_[0][:, :, None] * factors_[1][:, None, :]
        return (weights @ prod.reshape(N, -1)).reshape(weights.shape[:1] + prod.shape[1:])

    cols, BD, D, DD, sum_AB = [], [], [], [], []
    for k in range(len(factors.names)):                             # a handful of factors
        Dk = Fd[2 + k] - Fd[0]
        idx = np.flatnonzero(np.any(Dk != 0.0, axis=0))
        Dk = Dk[:, idx]
        cols.append(idx)
        BD.append(wsum(FB, Dk))
        D.append(wsum(Dk))
        DD.append(wsum(Dk, Dk))
        sum_AB.append(FA.sum(axis=0))                               # features of AB_k, summed
        sum_AB[-1][idx] += D[-1][0]
    GA, GB = wsum(FA), wsum(FB)
    shift = _problem_shift(GA[0], GB[0], np.stack(sum_AB, axis=-1), factors, N)
    return _FeatureSums(mean=mean, second=AB.T @ AB / (2 * N), A=GA, AA=wsum(FA, FA), B=GB,
                        BB=wsum(FB, FB), shift=shift, cols=tuple(cols), BD=tuple(BD), D=tuple(D),
                        DD=tuple(DD))


def _linear_sums(c: np.ndarray, fs: _FeatureSums):
    """Weighted sums for :func:`_finish` of linear outputs ``c . f``, c (M, F)."""
    def quad(G, u, v):                                              # u^T G_r v per row and resample
        return np.einsum("mf,rfg,mg->mr", u, G, v, optimize=True)

    delta = c @ fs.shift                                            # (M, K)
    rows = [c @ fs.A.T, quad(fs.AA, c, c), c @ fs.B.T, quad(fs.BB, c, c)]
    bd, dd = [], []
    for k, idx in enumerate(fs.cols):
        ck = c[:, idx]
        bd.append(quad(fs.BD[k], c, ck) - delta[:, k, None] * (ck @ fs.D[k].T))
        dd.append(quad(fs.DD[k], ck, ck))
    level = np.einsum("mf,fg,mg->m", c, fs.second, c)
    return np.stack(rows + bd + dd, axis=1), level


def _indices_salib(Y: np.ndarray, factors: _Factors, num_resamples: int, conf_level: float,
                   bootstrap_seed: int):
    """SALib's ``sobol.analyze`` on every row of Y (M, K + 2, N): one call per row and problem.

    The reference path (a Python loop over poses and outputs). Outputs
    constant over A and B get 0 (SALib would divide by a zero sd).
    """
    from SALib.analyze import sobol as sobol_analyze
    M, K2, N = Y.shape
    d = factors.masks.shape[1]
    inputs = factors.names[:d]
    out = [np.zeros((M, K2 - 2)) for _ in range(4)]
    calls = [(_salib_problem(inputs), list(range(d)), slice(0, d), slice(0, d))]
    for k in range(d, len(factors.names)):
        problem = _salib_problem(inputs, tuple(np.array(inputs)[factors.masks[k]]))
        order = list(pd.unique(np.array(problem["groups"])))       # SALib's factor order
        pos = order.index("__group__")
        calls.append((problem, [k if g == "__group__" else inputs.index(g) for g in order],
                      slice(pos, pos + 1), slice(k, k + 1)))
    flat = _constant(Y[:, :2].var(axis=(-2, -1)), np.square(Y[:, :2]).mean(axis=(-2, -1)))
    for m in np.flatnonzero(~flat):
        for problem, cols, take, put in calls:
            y = np.concatenate([Y[m, :1], Y[m, 2 + np.array(cols)], Y[m, 1:2]], axis=0)  # [A, AB.., B]
            res = sobol_analyze.analyze(problem, y.T.ravel(), calc_second_order=False,
                                        num_resamples=num_resamples, conf_level=conf_level,
                                        seed=bootstrap_seed, print_to_console=False)
            for arr, key in zip(out, ("S1", "S1_conf", "ST", "ST_conf")):
                arr[m, put] = np.asarray(res[key])[take]
    return tuple(out)


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
        times per pose (d inputs, G groups).
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
        to round-off); ``auto`` uses SALib for a single pose.
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
    seed = seed % (2**63 - 1)          # leaves room for the bootstrap seed, seed + 1
    num_resamples, bootstrap_seed = int(num_resamples), seed + 1
    factors = _factors(budget, groups)
    model = linear_model(geometry, budget, poses)                  # validates every pose
    shape = model.poses.shape[:-1]
    n_poses = int(np.prod(shape, dtype=int))
    if method == "auto":
        method = "salib" if n_poses <= _SALIB_MAX_POSES else "vectorised"

    U = _design(budget, factors, n_samples, seed)
    F = model.features(budget.ppf(np.clip(U.reshape(-1, len(budget)), _U_EDGE, 1.0 - _U_EDGE)))
    del U
    K, O = len(factors.names), len(outputs)
    z = float(stats.norm.ppf(0.5 + conf_level / 2))
    coef = model.coef.reshape((n_poses,) + model.coef.shape[-2:])
    coef = coef * np.array([1.0, 1.0, _RAD2DEG])[:, None]          # dphi in deg
    linear = [i for i, o in enumerate(outputs) if o != "position" and method == "vectorised"]
    sampled = [i for i in range(O) if i not in linear]
    if method == "vectorised":
        weights = _resample_weights(n_samples, num_resamples, bootstrap_seed)
        fs = _feature_sums(F.reshape(K + 2, n_samples, -1), factors, weights)
    per_pose = 8 * n_samples * (K + 2) * (3 + 2 * len(sampled)) + 8 * n_samples * len(sampled) * (4 + 2 * K)
    chunk = max(1, min(n_poses, max_chunk_bytes // per_pose))
    res = np.empty((4, n_poses, O, K))

    def work(start: int) -> int:
        sl = slice(start, min(n_poses, start + chunk))
        p = sl.stop - sl.start
        if linear:
            c = coef[sl][:, [OUTPUTS.index(outputs[i]) for i in linear]].reshape(p * len(linear), -1)
            res[:, sl, linear] = np.stack(_finish(*_linear_sums(c, fs), n_samples, z)).reshape(4, p, -1, K)
        if sampled:
            Y = _outputs(coef[sl], F, tuple(outputs[i] for i in sampled)).reshape(-1, K + 2, n_samples)
            parts = (_finish(*_sample_sums(Y, factors, weights), n_samples, z) if method == "vectorised"
                     else _indices_salib(Y, factors, num_resamples, conf_level, bootstrap_seed))
            res[:, sl, sampled] = np.stack(parts).reshape(4, p, -1, K)
        return p

    threads = 1 if method == "salib" else (workers or os.cpu_count() or 1)
    with Progress(n_poses, "sobol", progress) as bar, ThreadPoolExecutor(max_workers=threads) as pool:
        for done in pool.map(work, range(0, n_poses, chunk)):     # chunks of poses, not poses
            bar.update(done)
    S1, S1_conf, ST, ST_conf = (a.reshape(shape + (O, K)) for a in res)
    return SobolResult(poses=model.poses, n_samples=n_samples, seed=seed, outputs=outputs,
                       names=factors.names, kinds=factors.kinds, groups=factors.groups,
                       S1=S1, S1_conf=S1_conf, ST=ST, ST_conf=ST_conf, num_resamples=num_resamples,
                       conf_level=float(conf_level), bootstrap_seed=bootstrap_seed, method=method,
                       wall_time_s=time.perf_counter() - t0)


# ---------------------------------------------------------------- closed form
def _cos_moments(zeta_law, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E[cos(zeta - omega)] and E[cos^2(zeta - omega)], zeta in degrees, by quadrature of its ppf."""
    ec, es, ecc, ess, ecs = angle_moments(zeta_law)
    co, so = np.cos(omega), np.sin(omega)
    return co * ec + so * es, co**2 * ecc + 2 * co * so * ecs + so**2 * ess


def _analytic_arrays(model: LinearModel, factors: _Factors) -> tuple[np.ndarray, np.ndarray]:
    """Exact S1 and ST, shape (..., 3, K), of dx, dy, dphi for the factors.

    Each term t contributes V_t(s) = Var(E[term_t | inputs s]) times its
    column squared; S1(g) = sum_t V_t(g & in_t) / V and
    ST(g) = sum_t [V_t(in_t) - V_t(in_t - g)] / V.
    """
    laws = model.budget.inputs
    d = factors.masks.shape[1]
    inputs = factors.names[:d]
    shape = model.poses.shape[:-1]
    first = np.zeros(shape + (3, len(factors.names)))
    total = np.zeros_like(first)
    V = np.zeros(shape + (3,))
    for t, term in enumerate(model.terms):
        family, leg = parse_input(term)
        col2 = model.columns[..., :, t] ** 2                                # (..., 3)
        if family == "rho":
            zeta = f"zeta_{leg + 1}"
            rho_law = laws[term]
            ec, ecc = _cos_moments(laws[zeta], model.omega[..., leg])      # (...)
            r1, r2 = rho_law.mean, rho_law.var + rho_law.mean**2
            parts = {frozenset(): 0.0, frozenset([term]): rho_law.var * ec**2,
                     frozenset([zeta]): r1**2 * (ecc - ec**2), frozenset([term, zeta]): r2 * ecc - r1**2 * ec**2}
        else:
            parts = {frozenset(): 0.0, frozenset([term]): laws[term].var}
        members = max(parts, key=len)
        full = np.asarray(parts[members])[..., None] * col2
        V += full
        for k, mask in enumerate(factors.masks):
            g = frozenset(np.array(inputs)[mask])
            first[..., k] += np.asarray(parts[members & g])[..., None] * col2
            total[..., k] += full - np.asarray(parts[members - g])[..., None] * col2
    V = np.where(V > 0, V, np.inf)[..., None]
    return first / V, total / V


def analytic_indices(geometry: Geometry, budget: Budget, poses, groups: dict | None = None) -> pd.DataFrame:
    """Exact first-order and total indices of the linear outputs x, y, phi.

    The inputs are independent and the outputs sums of terms, so the indices
    are variance shares; a clearance term rho cos(zeta - omega) is the one
    place where two inputs interact. For zeta uniform over the full circle
    this gives S1_rho = 0, S1_zeta = c^2 E[rho]^2 / 2 / V,
    ST_rho = c^2 Var(rho) / 2 / V and ST_zeta = S_clearance = c^2 E[rho^2] / 2 / V;
    any law of zeta is handled by quadrature of its ppf.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
    poses : array_like, shape (..., 3)
    groups : dict, optional
        User groups, as for :func:`sobol_indices`.

    Returns
    -------
    DataFrame
        x_mm, y_mm, phi_deg, output, name, kind, S1, ST.
    """
    factors = _factors(budget, groups)
    model = linear_model(geometry, budget, poses)
    S1, ST = _analytic_arrays(model, factors)
    flat = model.poses.reshape(-1, 3)
    n, K = flat.shape[0], len(factors.names)
    pose = np.repeat(np.arange(n), 3 * K)
    return pd.DataFrame({
        "x_mm": flat[pose, 0], "y_mm": flat[pose, 1], "phi_deg": flat[pose, 2],
        "output": np.tile(np.repeat(OUTPUTS[:3], K), n), "name": np.tile(factors.names, 3 * n),
        "kind": np.tile(factors.kinds, 3 * n), "S1": S1.reshape(-1), "ST": ST.reshape(-1),
    })


# ---------------------------------------------------------------- ranking next to the worst case
def _term_map(result: SobolResult, wc: WorstCase) -> np.ndarray:
    """(K, T) map of worst-case terms to names; a row of NaN where a name has no contribution.

    A clearance term rho_i cos(zeta_i - omega_i) belongs to a name holding both
    rho_i and zeta_i (clearance_i); rho_i and zeta_i alone, and groups that
    split a clearance, get NaN.
    """
    T = len(wc.terms)
    out = np.zeros((len(result.names), T))
    for k, name in enumerate(result.names):
        members = set(result.groups.get(name, (name,)))
        for t, term in enumerate(wc.terms):
            family, leg = parse_input(term)
            needs = {term, f"zeta_{leg + 1}"} if family == "rho" else {term}
            if needs <= members:
                out[k, t] = 1.0
            elif needs & members:
                out[k] = np.nan
                break
    return out


def ranking(sobol_result: SobolResult, worst_case_result: WorstCase, output: str = "position",
            index=None) -> pd.DataFrame:
    """Sobol indices of every input and group next to its share of the worst case.

    Parameters
    ----------
    sobol_result : SobolResult
    worst_case_result : WorstCase
        At the same poses and for the same budget.
    output : {"position", "x", "y", "phi"}
        The Sobol output, and the worst-case quantity it is ranked against.
    index : int or tuple, optional
        A pose of the batch; None aggregates over all poses (a region).

    Returns
    -------
    DataFrame
        One row per input and group, sorted by ST descending: output, name,
        kind, S1, S1_conf, ST, ST_conf, worst_case_contribution (mm, or deg
        for phi), worst_case_share. A group's contribution is the sum of its
        terms' contributions at the maximising vertex. The clearance term
        rho_i cos(zeta_i - omega_i) carries rho_i and zeta_i together, so its
        contribution is reported on ``clearance_i`` and rho_i, zeta_i (and
        any group holding only one of them) show NaN.

        For a region (``index=None``): S1 and ST are means over the poses,
        S1_conf and ST_conf the largest half-widths, ST_min and ST_max the
        range of ST; the worst-case contribution and share are those at the
        pose where the worst case of ``output`` is largest (the pose that
        sets the region's guarantee; its pose is in ``df.attrs["worst_pose"]``),
        worst_case_share_max the largest share over the poses.
    """
    r, wc = sobol_result, worst_case_result
    if output not in r.outputs:
        raise BudgetError(f"output {output!r} is not in the Sobol result (has {', '.join(r.outputs)})")
    if r.poses.shape != wc.poses.shape or not np.allclose(r.poses, wc.poses):
        raise BudgetError("ranking needs the Sobol result and the worst case at the same poses")
    if tuple(wc.inputs) != tuple(r.names[:len(wc.inputs)]):
        raise BudgetError("ranking needs the Sobol result and the worst case of the same budget")
    o = r.outputs.index(output)
    contrib = np.einsum("...t,kt->...k", wc.contribution[output], _term_map(r, wc))    # (..., K)
    total = wc.value(output)[..., None]
    share = np.divide(contrib, total, out=np.zeros_like(contrib), where=total > 0)
    share = np.where(np.isnan(contrib), np.nan, share)
    idx = {"S1": r.S1[..., o, :], "S1_conf": r.S1_conf[..., o, :], "ST": r.ST[..., o, :],
           "ST_conf": r.ST_conf[..., o, :]}
    frame = {"output": output, "name": list(r.names), "kind": list(r.kinds)}
    if index is not None or r.poses.ndim == 1:
        at = () if index is None else index
        frame.update({key: value[at] for key, value in idx.items()})
        frame.update(worst_case_contribution=contrib[at], worst_case_share=share[at])
        df = pd.DataFrame(frame)
        df.attrs["pose"] = r.poses[at].tolist()
    else:
        K = len(r.names)
        flat = {key: value.reshape(-1, K) for key, value in idx.items()}
        worst = int(np.argmax(wc.value(output).reshape(-1)))
        frame.update(S1=flat["S1"].mean(0), S1_conf=flat["S1_conf"].max(0), ST=flat["ST"].mean(0),
                     ST_conf=flat["ST_conf"].max(0), ST_min=flat["ST"].min(0), ST_max=flat["ST"].max(0),
                     worst_case_contribution=contrib.reshape(-1, K)[worst],
                     worst_case_share=share.reshape(-1, K)[worst],
                     worst_case_share_max=share.reshape(-1, K).max(0))
        df = pd.DataFrame(frame)
        df.attrs["worst_pose"] = r.poses.reshape(-1, 3)[worst].tolist()
    df.attrs["unit"] = _UNITS[output]
    return df.sort_values("ST", ascending=False, kind="stable").reset_index(drop=True)


# ---------------------------------------------------------------- convergence
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
