"""Shapley effects of the pose error: variance shares that stay defined for dependent inputs.

The Shapley effect of factor i on an output Y (Owen 2014; Song, Nelson and
Staum 2016) is its Shapley value in the game whose cost of a set J of factors
is c(J) = E[Var(Y | ``X_-J``)], the variance left when all but J are known::

    Sh_i = 1/d sum over J not holding i of C(d - 1, |J|)^-1 [c(J + i) - c(J)] / Var(Y).

The effects are >= 0 and sum to 1 over the factors whatever the dependence
between them (SPEC §10), where Sobol indices lose their meaning. For
independent factors an additive output has Sh_i = S1_i = ST_i, and an
interaction is shared equally by its factors (Sh = (S1 + ST) / 2 for two).
A group's effect is the sum of its members' (so the effects of the inputs and
those of disjoint groups both sum to 1).

Estimator: random permutations (Song, Nelson and Staum 2016, Algorithm 1,
with N_O = 1 outer and N_I = 3 inner draws, the allocation they show to
minimise the variance for a given number of model runs), with common random
numbers along each order. For each of m random orders of the d factors: one
outer draw x and three fresh draws w_h; for j = 1 .. d, with J the first j
factors of the order, three inner draws keep x's values of ``X_-J`` and draw X_J
given them from w_h. The sample variance of the three outputs is an unbiased
estimate of c(J) (each j on its own is Song's draw; sharing x and w between
the j of one order only correlates them), and c(empty) = 0; at j = d all
factors are drawn afresh, which estimates Var(Y). The increments
c(J_j) - c(J_j-1) go to the order's j-th factor; the effect is the mean
increment over the orders over the mean Var(Y), and as each order's increments
sum to its Var(Y) estimate the effects sum to 1 exactly. Consecutive sets of
an order differ in one factor and share their draws, so a small factor's
increment is estimated closely (paper budget, 4096 orders: fresh draws per
set gave half-widths 0.015-0.03 for every effect; the common numbers 0.0015-0.003
for the smallest and about 0.012 for the largest).
The exact-permutation variant (every one of the 2^d sets) costs (2^d - 2) x 3
runs per outer draw: 12 to 16 factors make that 12 000 to 200 000 runs
before the first is averaged, where random orders spread the same runs over
more outer draws.

Conditional draws are exact: a budget's factors are independent or joined by
a Gaussian copula (:mod:`~prp3mc.model.copula`), so X_J given ``X_-J`` is
the image of the latent normals Z_J given ``Z_-J``, drawn by Matheron's rule
(w + K (z - w) with w a fresh draw of Z and K the kriging gain).

Intervals: the orders are drawn in B batches from independent streams. The
estimate is the ratio of the pooled mean increment to the pooled variance;
its standard error the batch-means one of the linearised ratio, and the
interval Student t with B - 1 degrees of freedom (coverage measured in
benchmarks/coverage_sobol.py).

Linear outputs (dx, dy, dphi = c . f of the model's features f): every
estimate is a quadratic form in c of pose-independent sums of feature
products, so all poses cost a few contractions; the position norm is
evaluated per pose and draw.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import special

from .._result import freeze, interval_frame, name_columns, short_repr
from .._rng import child_seed, resolve_rng
from .._threads import single_threaded_blas
from .._version import __version__
from ..errors import ParameterError
from ..kinematics.geometry import Geometry
from ..progress import Progress
from ..units import OUTPUTS, POSE_OUTPUTS, RAD2DEG, t_value
from ..model.budget import Budget
from ..model.copula import U_EDGE
from ..model.linear import linear_model
from .saltelli import design_factors

__all__ = ["ShapleyResult", "shapley_effects", "N_INNER"]

#: Inner draws per outer draw (Song, Nelson and Staum 2016: 3 minimises the variance per model run).
N_INNER = 3


@dataclass(frozen=True, slots=True, repr=False)
class ShapleyResult:
    """Shapley effects with Student t intervals over batches of random orders, per pose.

    Shapes: ``...`` is the batch shape of ``poses``; O outputs, K names.

    Attributes
    ----------
    poses : ndarray (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    n_permutations : int
        Random orders of the factors (all batches).
    seed : int
    outputs : tuple of str
    names : tuple of str
        The budget's factors, then the groups.
    kinds : tuple of str
        ``input``, ``effect`` or ``group`` per name.
    groups : mapping of str to tuple of str
    Sh, Sh_conf : ndarray (..., O, K)
        Effects and the half-widths of their ``conf_level`` intervals. NaN for
        the names in ``constant``.
    batches : int
    conf_level : float
    correlated : bool
        Whether the budget correlates some of its factors.
    constant : tuple of str
        Names whose factors are all constant (no variance to share).
    n_runs : int
        Model evaluations per pose.
    version : str
    wall_time_s : float
    """

    poses: np.ndarray
    n_permutations: int
    seed: int
    outputs: tuple
    names: tuple
    kinds: tuple
    groups: dict
    Sh: np.ndarray
    Sh_conf: np.ndarray
    batches: int
    conf_level: float
    correlated: bool
    constant: tuple = ()
    n_runs: int = 0
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "Sh", "n_permutations", "seed")

    def _keys(self) -> dict:
        return name_columns(self.poses, self.outputs, self.names, self.kinds)

    def to_frame(self) -> pd.DataFrame:
        """Tidy table, one row per pose, output and name: x_mm, y_mm, phi_deg, output, name, kind, Sh, Sh_conf."""
        return pd.DataFrame({**self._keys(), "Sh": self.Sh.reshape(-1), "Sh_conf": self.Sh_conf.reshape(-1)})

    def se(self) -> np.ndarray:
        """Standard error of ``Sh`` (..., O, K): the half-width over ``t(conf_level, batches - 1)``."""
        return self.Sh_conf / t_value(self.conf_level, self.batches - 1)

    def conf_int(self, level: float = 0.95) -> pd.DataFrame:
        """Student t intervals ``Sh ± t(level, batches - 1) se`` in the long form (statistic ``Sh``)."""
        if not 0.0 < level < 1.0:
            raise ParameterError(f"level must lie in (0, 1), got {level}")
        value, se = self.Sh.reshape(-1), self.se().reshape(-1)
        half = t_value(level, self.batches - 1) * se
        frame = pd.DataFrame({**self._keys(), "statistic": "Sh", "value": value, "unit": "1", "se": se})
        return interval_frame(frame, value - half, value + half, level)

    def metadata(self) -> dict:
        return {"prp3mc_version": self.version, "seed": self.seed, "n_permutations": self.n_permutations,
                "batches": self.batches, "conf_level": self.conf_level,
                "n_runs": self.n_runs, "wall_time_s": self.wall_time_s}


# ---------------------------------------------------------------- draws
def _latent(budget: Budget, rng: np.random.Generator, shape: tuple) -> np.ndarray:
    """Latent standard normals (..., D) of the budget's factors, the copula's block correlated."""
    z = rng.standard_normal(shape + (len(budget.factors),))
    if budget.copula is not None:
        idx = list(budget.copula.index)
        z[..., idx] = z[..., idx] @ budget.copula.chol.T
    return z


def _values(budget: Budget, z: np.ndarray) -> np.ndarray:
    """Factor values (n, D) of latent normals z (n, D)."""
    return budget.marginal_ppf(np.clip(special.ndtr(z), U_EDGE, 1.0 - U_EDGE))


def _order_draws(budget: Budget, players: np.ndarray, m: int, rng: np.random.Generator):
    """Random orders of the players and, per order and position j = 1 .. d, the inner draws.

    Returns
    -------
    perms : ndarray (m, d) int
        Orders, as indices into ``players``.
    X : ndarray (m * d * N_INNER, D)
        Row (order p, position j, inner h): ``X_-J`` of the order's outer draw and X_J drawn given it
        from the order's h-th fresh draw, J the factors of the first j positions of order p.
        Every position of an order shares its outer and fresh draws (common random numbers):
        consecutive sets differ in one factor, so their costs' difference is estimated closely.
    """
    d, D = players.size, len(budget.factors)
    perms = rng.permuted(np.tile(np.arange(d), (m, 1)), axis=1)
    first = np.zeros((m, d, D), dtype=bool)                             # factor in J, per (order, j)
    first[..., players] = np.cumsum(np.eye(d, dtype=np.int8)[perms], axis=1) > 0
    z_out = _latent(budget, rng, (m, 1))
    w = _latent(budget, rng, (m, 1, N_INNER))
    z = np.where(first[:, :, None, :], w, z_out[:, :, None, :])         # (m, d, N_INNER, D)
    copula = budget.copula
    if copula is not None:                                              # Matheron's rule on the correlated block
        idx = list(copula.index)
        k = len(idx)
        free = first[..., idx]                                          # (m, d, k)
        masks, inv = np.unique(~free.reshape(-1, k), axis=0, return_inverse=True)
        gains = copula.conditional_gains(masks)[inv.reshape(-1)].reshape(m, d, k, k)
        zo, wb = z_out[..., idx], w[..., idx]                           # (m, 1, k), (m, 1, N_INNER, k)
        cond = wb + np.einsum("pjab,pjhb->pjha", gains, (zo[:, :, None, :] - wb))
        z[..., idx] = np.where(free[:, :, None, :], cond, zo[:, :, None, :])
    return perms, _values(budget, z.reshape(-1, D))


# ---------------------------------------------------------------- per-batch sums
def _linear_batch(c: np.ndarray, F_in: np.ndarray, perms: np.ndarray):
    """Mean increments (M, d) per player, variances (M,) and mean squares (M,) of linear outputs
    c (M, F), one batch; F_in (m, d, N_INNER, F) features of the draws of :func:`_order_draws`.

    The cost of a set is c^T S c with S the inner sample covariance of the features, so every
    player's increments sum to one matrix G_i: + S where i completes the set, - S where it joins next.
    """
    m, d = perms.shape
    nF = F_in.shape[-1]
    E = F_in - F_in.mean(axis=2, keepdims=True)
    G = np.zeros((d, nF, nF))
    for i in range(d):
        plus = E[perms == i].reshape(-1, nF)                            # c(J) where i is the last of J
        minus = E[:, :-1][perms[:, 1:] == i].reshape(-1, nF)            # c(J) just before i joins
        G[i] = (plus.T @ plus - minus.T @ minus) / (N_INNER - 1)
    last = E[:, -1].reshape(-1, nF)                                     # all factors drawn afresh: Var(Y)
    A = np.einsum("mf,ifg,mg->mi", c, G, c, optimize=True) / m
    V = np.einsum("mf,fg,mg->m", c, last.T @ last, c) / (m * (N_INNER - 1))
    full = F_in[:, -1].reshape(-1, nF)
    return A, V, np.einsum("mf,fg,mg->m", c, full.T @ full, c) / full.shape[0]


def _sampled_batch(Y_in: np.ndarray, perms: np.ndarray):
    """Mean increments (M, d), variances (M,) and mean squares (M,) of outputs Y_in (M, m, d, N_INNER), one batch."""
    m, d = perms.shape
    M = Y_in.shape[0]
    cost = np.concatenate([np.zeros((M, m, 1)), Y_in.var(axis=-1, ddof=1)], axis=-1)
    step = np.diff(cost, axis=-1)                                       # (M, m, d), by position
    pos = np.argsort(perms, axis=1)                                     # position of each player
    A = np.take_along_axis(step, np.broadcast_to(pos, (M, m, d)), axis=-1).mean(axis=1)
    return A, cost[..., -1].mean(axis=1), np.square(Y_in[:, :, -1]).mean(axis=(1, 2))


def _combine(A: np.ndarray, V: np.ndarray, level: np.ndarray, conf_level: float):
    """Pooled ratio estimates and t half-widths from per-batch mean increments A (M, K, B), variances V (M, B)."""
    B = V.shape[-1]
    Vbar = V.mean(axis=-1)
    flat = Vbar <= 1e-24 * level.mean(axis=-1)
    Vsafe = np.where(flat, 1.0, Vbar)
    Sh = A.mean(axis=-1) / Vsafe[:, None]
    lin = (A - Sh[..., None] * V[:, None, :]) / Vsafe[:, None, None]
    half = t_value(conf_level, B - 1) * lin.std(axis=-1, ddof=1) / np.sqrt(B)
    return np.where(flat[:, None], 0.0, Sh), np.where(flat[:, None], 0.0, half)


# ---------------------------------------------------------------- entry
def shapley_effects(geometry: Geometry, budget: Budget, poses, n_permutations: int, *,
                    rng: "None | int | np.random.Generator" = None, groups: dict | None = None,
                    outputs=OUTPUTS, batches: int = 16, conf_level: float = 0.95,
                    progress: bool | None = None,
                    max_chunk_bytes: int = 256 << 20) -> ShapleyResult:
    """Shapley effects of the pose error, batched over poses (random-permutation estimator).

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        Independent or correlated (its ``[correlation]`` table) factors.
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``; one set of draws serves all of them.
    n_permutations : int
        Random orders of the factors, at least ``2 * batches``; rounded up to
        a multiple of ``batches``. The model runs ``3 d n_permutations`` times
        per pose (d factors that vary).
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7); batch b draws from
        ``child_seed(seed, b)``, so results do not depend on chunking.
    groups : dict of str to list of str, optional
        User groups in addition to the budget's (``clearance_i`` always);
        a group's effect is the sum of its members'.
    outputs : sequence of str
        Among ``x``, ``y``, ``phi`` (δφ) and ``position`` (the norm of δx, δy).
    batches : int
        Independent batches of orders for the intervals (>= 2).
    conf_level : float
        Level of the Student t intervals.
    progress : bool, optional
        Progress on stderr (default: when stderr is a terminal).
    max_chunk_bytes : int
        Memory for one chunk of poses of the position output.

    Returns
    -------
    ShapleyResult
        Effects of shape (..., O, K): K names are the factors, then the groups.
    """
    t0 = time.perf_counter()
    outputs = tuple(outputs)
    unknown = [o for o in outputs if o not in OUTPUTS]
    if unknown or not outputs or len(set(outputs)) < len(outputs):
        raise ParameterError(f"bad outputs {list(outputs)}: choose distinct ones among {', '.join(OUTPUTS)}")
    batches = int(batches)
    if batches < 2:
        raise ParameterError(f"Shapley intervals need at least 2 batches, got {batches}")
    if int(n_permutations) < 2 * batches:
        raise ParameterError(f"Shapley effects need at least 2 orders per batch ({2 * batches} for {batches} "
                          f"batches), got {n_permutations}")
    if not 0.0 < conf_level < 1.0:
        raise ParameterError(f"conf_level must lie in (0, 1), got {conf_level}")
    seed, _ = resolve_rng(rng)
    factors = design_factors(budget, groups)
    model = linear_model(geometry, budget, poses)
    shape = model.poses.shape[:-1]
    n_poses = int(np.prod(shape, dtype=int))
    laws = list(budget.factor_laws.values())
    D = len(laws)
    players = np.array([k for k in range(D) if laws[k].var > 0], dtype=int)
    d = players.size
    m_b = -(-int(n_permutations) // batches)
    coef = model.coef.reshape((n_poses,) + model.coef.shape[-2:]) * np.array([1.0, 1.0, RAD2DEG])[:, None]
    O, K = len(outputs), len(factors.names)
    linear = [i for i, o in enumerate(outputs) if o != "position"]
    sampled = [i for i, o in enumerate(outputs) if o == "position"]
    A = np.zeros((batches, n_poses, O, d))
    V = np.zeros((batches, n_poses, O))
    level = np.zeros((batches, n_poses, O))
    rows = m_b * d * N_INNER
    chunk = max(1, min(n_poses, max_chunk_bytes // (8 * 3 * max(rows, 1))))
    with single_threaded_blas(), Progress(batches, "shapley", progress) as bar:
        for b in range(batches if d else 0):                             # no factor varies: nothing to share
            gen = np.random.default_rng(child_seed(seed, b))
            perms, X_in = _order_draws(budget, players, m_b, gen)
            F_in = model.features(X_in).reshape(m_b, d, N_INNER, -1)
            if linear:
                c = coef[:, [POSE_OUTPUTS.index(outputs[i]) for i in linear]].reshape(n_poses * len(linear), -1)
                a, v, lev = _linear_batch(c, F_in, perms)
                A[b][:, linear] = a.reshape(n_poses, len(linear), d)
                V[b][:, linear] = v.reshape(n_poses, len(linear))
                level[b][:, linear] = lev.reshape(n_poses, len(linear))
            for start in range(0, n_poses if sampled else 0, chunk):
                sl = slice(start, min(n_poses, start + chunk))
                xy = coef[sl, :2]
                y_in = np.hypot(*np.einsum("pof,nf->opn", xy, F_in.reshape(-1, F_in.shape[-1])))
                a, v, lev = _sampled_batch(y_in.reshape(-1, m_b, d, N_INNER), perms)
                A[b, sl, sampled[0]], V[b, sl, sampled[0]], level[b, sl, sampled[0]] = a, v, lev
            bar.update(1)
    member = factors.masks[:, players].astype(float)                    # (K, d): players of each name
    A_names = np.einsum("bpoi,ki->pokb", A, member)
    Sh, half = _combine(A_names.reshape(n_poses * O, K, batches), np.moveaxis(V, 0, -1).reshape(n_poses * O, batches),
                        np.moveaxis(level, 0, -1).reshape(n_poses * O, batches), conf_level)
    constant = tuple(name for name, mask in zip(factors.names, factors.masks)
                     if not np.any(mask[players]))
    cidx = [factors.names.index(name) for name in constant]
    Sh, half = Sh.reshape(shape + (O, K)), half.reshape(shape + (O, K))
    Sh[..., cidx] = np.nan
    half[..., cidx] = np.nan
    return ShapleyResult(poses=model.poses, n_permutations=m_b * batches, seed=seed,
                         outputs=outputs, names=factors.names, kinds=factors.kinds, groups=factors.groups,
                         Sh=Sh, Sh_conf=half, batches=batches, conf_level=float(conf_level),
                         correlated=budget.correlated, constant=constant, n_runs=batches * rows,
                         wall_time_s=time.perf_counter() - t0)
