"""The gap out of sample: cross-validation by pose.

An effect fitted to a campaign always shrinks the gap measured on that
campaign; only measurements left out of the fit show whether the model
improved. The campaign's poses are dealt at random into K folds (5, or one
per pose when fewer). For each fold, the nuisances (registration, drift),
the named systematic values and spread factors are fitted again on the
other folds (the repeatable fraction, one number of the whole campaign,
keeps its whole-campaign value: refitting it too doubled the cost), and the
poses of the fold are *predicted*:
their residuals under those fitted values, whitened by the covariance the
training fit implies plus the uncertainty of its estimates (so that they are
standard normal when the model is right). The seven channels of the verdict
(:mod:`~prp3mc.measurement.verdict.diagnostics`) are then computed on the held-out
residuals of all poses, with no degree of freedom taken off, and give the
held-out gap, before (budget and nuisances only) and after (the named
effects too).

The named *set* is the one selected on the whole campaign: each fold refits
it, it does not select again (selection costs about half a second per fold).
The held-out gap therefore judges the fitted values out of sample, not the
selection; residuals of different folds are treated as independent (they
share training measurements, a small correlation).
"""

from __future__ import annotations

import numpy as np

from ..._rng import child_seed
from .diagnostics import diagnose, gap_value
from ..estimation.likelihood import Engine, Fit

__all__ = ["held_out_gap", "held_out_fits", "N_FOLDS"]

#: Folds of the cross-validation (fewer when the campaign has fewer poses).
N_FOLDS = 5
#: Stream key of the folds' random assignment under the analysis seed.
_STREAM_FOLDS = 1616


def _folds(n_poses: int, seed: int) -> np.ndarray:
    """Fold of each pose (P,): a random deal of the poses into min(N_FOLDS, P) folds of (nearly) equal size."""
    k = min(N_FOLDS, n_poses)
    order = np.random.default_rng(child_seed(seed, _STREAM_FOLDS)).permutation(n_poses)
    fold = np.empty(n_poses, dtype=int)
    fold[order] = np.arange(n_poses) % k
    return fold


def _train_fit(train: Engine, fit: Fit, engine: Engine) -> tuple[Fit, list]:
    """``fit``'s model (nuisances, named systematic set, spreads; ``r`` kept) refitted on the training engine.

    Returns the fit and the names of its systematic columns (named effects the
    training poses cannot see are left out).
    """
    names = [engine.systematic[j].name for j in fit.sys]
    known = {e.name: j for j, e in enumerate(train.systematic)}
    names = [n for n in names if n in known]
    factors = {n: f for n, f in fit.factors.items() if n in train.spread_input}
    return train.refit(tuple(known[n] for n in names), factors, r=fit.r, nuis=fit.nuis), names


def _predicted(engine: Engine, trained: Fit, names: list, rows: np.ndarray, poses: np.ndarray,
               z: np.ndarray, resid: np.ndarray, Lw: np.ndarray, Lb: np.ndarray) -> None:
    """Fill the held-out rows' residuals and whitened residuals, and their poses' whitening, in place.

    The residual of a held-out measurement is its error less the budget
    mean, the nuisances and the named values of the training fit; it is
    whitened by the training fit's ``W`` and ``Vbar`` and then by
    ``(I + A C A')^-1/2`` (``A``: the whitened columns of the fitted values,
    ``C``: their covariance), which accounts for the estimates' own error.
    """
    state = engine.fit((), trained.factors, trained.r, nuis=())          # whitening at the training state
    X = engine.columns(tuple(engine.sys_index(n) for n in names), trained.nuis)     # (M, 3, k)
    r = state.resid - X @ trained.theta                          # error less budget mean, nuisances, effects
    held = np.zeros_like(r)
    held[rows] = r[rows]
    zk = engine.whiten(held, state.Lw, state.Lb)
    index = np.concatenate([(3 * rows[:, None] + np.arange(3)).ravel(),
                            (3 * engine.M + 3 * poses[:, None] + np.arange(3)).ravel()])
    zk = zk[index]
    if trained.theta.size:
        Xk = np.zeros_like(X)
        Xk[rows] = X[rows]
        A = engine.whiten(Xk, state.Lw, state.Lb)[index]
        s, V = np.linalg.eigh(trained.theta_cov)
        U = A @ (V * np.sqrt(np.clip(s, 0.0, None)))
        Q, sv, _ = np.linalg.svd(U, full_matrices=False)
        zk = zk + Q @ ((1.0 / np.sqrt(1.0 + sv**2) - 1.0) * (Q.T @ zk))
    z[index] = zk
    resid[rows] = r[rows]
    Lw[poses], Lb[poses] = state.Lw[poses], state.Lb[poses]


def held_out_fits(engine: Engine, states: dict, seed: int) -> tuple[dict, int]:
    """The held-out residuals of each model state, as model states with nothing fitted.

    Parameters
    ----------
    engine : Engine
        The campaign's kept rows (gross errors set aside).
    states : dict
        Label -> the model state (:class:`~prp3mc.measurement.estimation.likelihood.Fit`)
        fitted on the whole campaign.
    seed : int
        The analysis seed (the folds are dealt from a child stream of it).

    Returns
    -------
    fits : dict
        Label -> a :class:`~prp3mc.measurement.estimation.likelihood.Fit` whose ``z``
        are the whitened held-out residuals of every pose (standard normal
        when the model is right), ``resid`` the residuals, ``Lw, Lb`` each
        pose's whitening; its spread factors and ``r`` are the whole
        campaign's, and it has no fitted values.
    folds : int
    """
    fold = _folds(engine.P, seed)
    k = int(fold.max()) + 1
    fold_rows = fold[engine.idx]
    pieces = {label: (np.zeros(3 * engine.M + 3 * engine.P), np.zeros((engine.M, 3)),
                      np.zeros((engine.P, 3, 3)), np.zeros((engine.P, 3, 3))) for label in states}
    for f in range(k):
        train_keep = engine.keep.copy()
        train_keep[engine.rows[fold_rows == f]] = False
        train = engine.with_rows(train_keep)
        rows, poses = np.flatnonzero(fold_rows == f), np.flatnonzero(fold == f)
        for label, fit in states.items():
            trained, names = _train_fit(train, fit, engine)
            _predicted(engine, trained, names, rows, poses, *pieces[label])
    fits = {label: Fit(sys=(), factors=dict(fit.factors), r=fit.r, nuis=(), theta=np.zeros(0),
                       theta_cov=np.zeros((0, 0)), loglik=float("nan"), z=pieces[label][0], resid=pieces[label][1],
                       Lw=pieces[label][2], Lb=pieces[label][3], k_between=0.0)
            for label, fit in states.items()}
    return fits, k


def held_out_gap(engine: Engine, states: dict, seed: int) -> dict:
    """The gap of each model state measured on poses left out of its fit (see the module notes).

    Parameters
    ----------
    engine : Engine
        The campaign's kept rows (gross errors set aside).
    states : dict
        Label (``before``, ``after``) -> ``(fit, null)``: the model state
        fitted on the whole campaign and its null variances
        (:func:`~prp3mc.measurement.verdict.diagnostics.null_variances`).
    seed : int
        The analysis seed (the folds are dealt from a child stream of it).

    Returns
    -------
    dict
        ``{label: gap}`` for every state, ``deciding_channel`` of the last,
        ``folds`` and ``method``.
    """
    fits, k = held_out_fits(engine, {label: fit for label, (fit, _) in states.items()}, seed)
    out: dict = {}
    channel = None
    for label, (_, null) in states.items():
        out[label], channel = gap_value(diagnose(engine, fits[label], null=null, fitted=False))
    out.update(deciding_channel=channel, folds=k,
               method=f"cross-validation by pose: the poses dealt at random into {k} folds; each fold's poses "
                      "predicted by the model (nuisances, the named effects' values and spreads) refitted on the "
                      "other folds, the named set as selected and the repeatable fraction as fitted on the whole "
                      "campaign; the gap's seven channels on all held-out residuals")
    return out
