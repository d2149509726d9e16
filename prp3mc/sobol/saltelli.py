"""Saltelli's design and SALib's Sobol estimators, vectorised over poses and outputs.

Internal to :mod:`prp3mc.sobol.indices`, which is the public entry.

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

Replicates. The design is drawn R times with independent scramblings
(randomised quasi-Monte Carlo); each replicate gives its own estimates, the
reported index is their mean and its interval the Student t interval over
the R replicates (:func:`combine_replicates`). A bootstrap over the points of
one scrambled Sobol' design treats them as independent draws and overstates
the error of the design 10-26 fold (benchmarks/coverage_sobol.py).

Estimators (as ``SALib.analyze.sobol``, per replicate): the output of each
SALib problem is centred on its own mean, then
``S1 = mean(B (AB - A)) / var([A, B])`` (Saltelli 2010) and
``ST = mean((A - AB)^2) / 2 / var([A, B])`` (Jansen). SALib analyses one
output of one pose for one problem per call; the vectorised path computes the
same numbers for all poses and outputs at once from sums over the N rows of
the per-row quantities a, a^2, b, b^2 and, per factor, (b - delta_k) D_k and
D_k^2 (D_k = AB_k - A, delta_k the centre of k's SALib problem). For the
linear outputs δx, δy, δφ = c . f (f the model's sample features) those sums
are quadratic forms in c of pose-independent sums of feature products, so
only the position norm needs per-pose, per-sample work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import BudgetError
from ..units import POSE_OUTPUTS, t_value
from ..model.budget import Budget

__all__ = ["Factors", "design_factors", "saltelli_design", "model_outputs", "FeatureSums", "feature_sums",
           "linear_sums", "sample_sums", "replicate_indices", "combine_replicates", "salib_indices"]


# ---------------------------------------------------------------- factors and design
@dataclass(frozen=True, slots=True)
class Factors:
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


def design_factors(budget: Budget, groups: dict | None) -> Factors:
    """The budget's factors, then its groups and the user's ``groups`` (validated by :class:`Budget`).

    The factors are the inputs (kind ``input``) and the random factors of
    the budget's effects, ``backlash_i`` and ``thermal`` (kind ``effect``).
    """
    extra = {}
    for gname, members in (groups or {}).items():
        if isinstance(members, str):
            raise BudgetError(f"group {gname!r}: expected a list of inputs, got the string {members!r}")
        extra[str(gname)] = tuple(members)
    user = {k: v for k, v in budget.groups.items() if not k.startswith("clearance_")}
    clash = next((k for k in extra if k in user and set(extra[k]) != set(user[k])), None)
    if clash is not None:
        raise BudgetError(f"group {clash!r} is defined twice: the budget has {', '.join(user[clash])}, the request "
                          f"{', '.join(extra[clash])}: name one otherwise")
    merged = Budget(budget.inputs, groups={**user, **extra}, effects=budget.effects).groups  # validates them
    inputs = budget.factors
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
    kinds = ("input",) * len(budget.names) + ("effect",) * (d - len(budget.names)) + ("group",) * len(merged)
    return Factors(names=names, kinds=kinds,
                    groups={k: tuple(v) for k, v in merged.items()}, masks=masks, problem=problem)


def _salib_problem(inputs: tuple, members: tuple = ()) -> dict:
    """SALib problem on the unit cube; ``members`` become one group named ``__group__``."""
    problem = {"num_vars": len(inputs), "names": list(inputs), "bounds": [[0.0, 1.0]] * len(inputs)}
    if members:
        problem["groups"] = ["__group__" if name in members else name for name in inputs]
    return problem


def saltelli_design(budget: Budget, factors: Factors, n_samples: int, seed: int) -> np.ndarray:
    """Unit samples of SALib's sobol sampler rearranged as [A, B, AB_1..AB_K], shape (K + 2, N, d).

    SALib's sampler (``calc_second_order=False``, ``scramble=True``) draws
    ``scipy.stats.qmc.Sobol(2 d, scramble=True, seed=seed).random(N)`` and
    copies, row by row in Python, its first d columns as A and its last d
    as B (rows 0 and d + 1 of each block of d + 2), on the unit cube
    unscaled. A and B are taken from that sequence directly: the same
    numbers, without the loop over N (d + 2) rows. AB_k takes the columns of
    factor k from B, as SALib's sampler does for the problem that makes k
    one factor.
    """
    from scipy.stats import qmc
    d = len(budget.factors)
    base = qmc.Sobol(d=2 * d, scramble=True, seed=seed).random(n_samples)
    A, B = base[:, :d], base[:, d:]
    AB = np.where(factors.masks[:, None, :], B, A)
    return np.concatenate([A[None], B[None], AB], axis=0)


def model_outputs(coef: np.ndarray, F: np.ndarray, outputs: tuple) -> np.ndarray:
    """Outputs (p, O, n) for model coefficients (p, 3, F) and sample features F (n, F).

    The pose errors are ``coef @ features``, :meth:`LinearModel.evaluate` as
    one matrix product laid out for the estimators; the position-error norm
    is that of (dx, dy).
    """
    p = coef.shape[0]
    rows = [r for r in range(3) if POSE_OUTPUTS[r] in outputs or (r < 2 and "position" in outputs)]
    E = (coef[:, rows].reshape(p * len(rows), -1) @ F.T).reshape(p, len(rows), -1)
    error = {POSE_OUTPUTS[r]: E[:, j] for j, r in enumerate(rows)}
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
def _constant(var: np.ndarray, mean_square: np.ndarray) -> np.ndarray:
    """Outputs that do not vary over A and B (variance below 1e-24 of their mean square): indices 0."""
    return var <= 1e-24 * mean_square


def _problem_shift(sum_A: np.ndarray, sum_B: np.ndarray, sum_AB: np.ndarray, factors: Factors,
                   n_samples: int) -> np.ndarray:
    """Mean of each factor's SALib problem, (..., K), from row sums over A, B (...) and AB_k (..., K).

    SALib centres the output of a problem on its own rows: A, B and the AB
    of that problem's factors.
    """
    n_rows = 2 + factors.problem.sum(axis=1)
    return ((sum_A + sum_B)[..., None] + sum_AB @ factors.problem.T) / (n_samples * n_rows)


def replicate_indices(s: np.ndarray, level: np.ndarray, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """SALib's S1 and ST of every replicate from its sums over the design rows.

    Parameters
    ----------
    s : ndarray (M, 4 + 2K, R)
        Per replicate, sums of a, a^2, b, b^2 (the A and B outputs, centred on
        their mean), then per factor k of (b - delta_k) D_k and D_k^2, with
        D_k = AB_k - A and delta_k the centre of k's SALib problem.
    level : ndarray (M, R)
        Mean square of the uncentred A and B outputs.
    n_samples : int
        Rows N of each replicate's A (and B).

    Returns
    -------
    S1, ST : ndarray (M, K, R)
        ``S1 = mean((b - delta) D) / var`` (Saltelli 2010), ``ST = mean(D^2) / 2 / var``
        (Jansen), var that of [A, B]; 0 for an output constant over A and B.
    """
    K = (s.shape[1] - 4) // 2
    mean = (s[:, 0] + s[:, 2]) / (2 * n_samples)
    var = (s[:, 1] + s[:, 3]) / (2 * n_samples) - mean**2           # var([A, B]), (M, R)
    flat = _constant(var, level)[:, None, :]
    var = np.where(flat, 1.0, var[:, None, :])
    S1 = np.where(flat, 0.0, s[:, 4:4 + K] / n_samples / var)
    ST = np.where(flat, 0.0, 0.5 * s[:, 4 + K:] / n_samples / var)
    return S1, ST


def combine_replicates(S: np.ndarray, conf_level: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the replicates' estimates S (..., R) and the half-width of its Student t interval.

    The replicates are independent and identically distributed (independent
    scramblings), so ``mean ± t(conf_level, R - 1) sd / sqrt(R)`` covers the
    index at ``conf_level`` as R estimates of a normal law would.
    """
    R = S.shape[-1]
    return S.mean(axis=-1), t_value(conf_level, R - 1) * S.std(axis=-1, ddof=1) / np.sqrt(R)


def sample_sums(Y: np.ndarray, factors: Factors) -> tuple[np.ndarray, np.ndarray]:
    """Sums for :func:`replicate_indices` from outputs Y (M, K + 2, N) = [A, B, AB_1..AB_K]; any output.

    Returns the sums (M, 4 + 2K) and the mean square of the A and B outputs (M,).
    """
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
    return Q.sum(axis=-1), level


@dataclass(frozen=True, slots=True)
class FeatureSums:
    """Sums over the design rows (of one replicate) of products of the centred sample features.

    A linear output ``y = c . f`` has every sum :func:`replicate_indices` needs
    as a quadratic or linear form in c of these pose-independent sums, so the
    outputs dx, dy, dphi of all poses cost a few small contractions. ``D_k``
    (features of AB_k minus those of A) vanishes outside the features of
    factor k (``cols[k]``), which keeps the sums small.
    """

    mean: np.ndarray            # (F,) feature means over the A and B rows
    second: np.ndarray          # (F, F) mean of f f^T over the A and B rows
    A: np.ndarray               # (F,)
    AA: np.ndarray              # (F, F)
    B: np.ndarray
    BB: np.ndarray
    shift: np.ndarray           # (F, K): delta_k = c . shift[:, k]
    cols: tuple                 # per factor: the features D_k touches
    BD: tuple                   # per factor: (F, |cols|), sums of b D_k^T
    D: tuple                    # per factor: (|cols|,)
    DD: tuple                   # per factor: (|cols|, |cols|)


def feature_sums(Fd: np.ndarray, factors: Factors) -> FeatureSums:
    """:class:`FeatureSums` from one replicate's design features Fd (K + 2, N, F)."""
    N, nf = Fd.shape[1:]
    AB = Fd[:2].reshape(2 * N, nf)
    mean = AB.mean(axis=0)
    FA, FB = Fd[0] - mean, Fd[1] - mean
    cols, BD, D, DD, sum_AB = [], [], [], [], []
    for k in range(len(factors.names)):                             # a handful of factors
        Dk = Fd[2 + k] - Fd[0]
        idx = np.flatnonzero(np.any(Dk != 0.0, axis=0))
        Dk = Dk[:, idx]
        cols.append(idx)
        BD.append(FB.T @ Dk)
        D.append(Dk.sum(axis=0))
        DD.append(Dk.T @ Dk)
        sum_AB.append(FA.sum(axis=0))                               # features of AB_k, summed
        sum_AB[-1][idx] += D[-1]
    GA, GB = FA.sum(axis=0), FB.sum(axis=0)
    shift = _problem_shift(GA, GB, np.stack(sum_AB, axis=-1), factors, N)
    return FeatureSums(mean=mean, second=AB.T @ AB / (2 * N), A=GA, AA=FA.T @ FA, B=GB, BB=FB.T @ FB,
                       shift=shift, cols=tuple(cols), BD=tuple(BD), D=tuple(D), DD=tuple(DD))


def linear_sums(c: np.ndarray, fs: FeatureSums) -> tuple[np.ndarray, np.ndarray]:
    """Sums for :func:`replicate_indices` (M, 4 + 2K) and mean squares (M,) of linear outputs ``c . f``, c (M, F)."""
    def quad(G, u, v):                                              # u^T G v per row
        return np.einsum("mf,fg,mg->m", u, G, v, optimize=True)

    delta = c @ fs.shift                                            # (M, K)
    rows = [c @ fs.A, quad(fs.AA, c, c), c @ fs.B, quad(fs.BB, c, c)]
    bd, dd = [], []
    for k, idx in enumerate(fs.cols):
        ck = c[:, idx]
        bd.append(quad(fs.BD[k], c, ck) - delta[:, k] * (ck @ fs.D[k]))
        dd.append(quad(fs.DD[k], ck, ck))
    level = np.einsum("mf,fg,mg->m", c, fs.second, c)
    return np.stack(rows + bd + dd, axis=1), level


def salib_indices(Y: np.ndarray, factors: Factors, conf_level: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """SALib's ``sobol.analyze`` estimates S1 and ST (M, K) for every row of Y (M, K + 2, N).

    The reference path (a Python loop over poses, outputs and problems). SALib's
    own bootstrap interval is not used (the replicates give the interval), so
    it runs with two resamples. Outputs constant over A and B get 0 (SALib
    would divide by a zero sd).
    """
    from SALib.analyze import sobol as sobol_analyze
    M, K2, N = Y.shape
    d = factors.masks.shape[1]
    inputs = factors.names[:d]
    out = [np.zeros((M, K2 - 2)) for _ in range(2)]
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
            res = sobol_analyze.analyze(problem, y.T.ravel(), calc_second_order=False, num_resamples=2,
                                        conf_level=conf_level, seed=seed, print_to_console=False)
            for arr, key in zip(out, ("S1", "ST")):
                arr[m, put] = np.asarray(res[key])[take]
    return tuple(out)
