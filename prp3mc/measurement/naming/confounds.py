"""What a campaign cannot tell apart: effects from the nuisances, and from each other (``confounded``).

From the design
---------------
Whitened by the budget's covariance (:mod:`~prp3mc.measurement.estimation.likelihood`),
each candidate's signature is a vector ``g``; the nuisances fitted in every
model (registration, drift) span ``X``. The share of ``g`` that ``X``
takes is ``R^2 = 1 - |P g|^2 / |g|^2`` (``P`` projects out ``X``), and
``VIF = 1 / (1 - R^2)`` is how much more information the effect needs than
if the nuisances were known (its detectable value grows by ``sqrt(VIF)``).
An effect is confounded with a nuisance block when ``VIF >=``
:data:`VIF_LIMIT` (``R^2 >= 0.9``, the usual rule); it is listed with the
block(s) that take it (one alone, or both when neither alone does). Two
effects are confounded with each other when their signatures, the
nuisances projected out, correlate by ``|r|`` with ``1 / (1 - r^2) >=
VIF_LIMIT``; such effects are grouped (connected components).

From the data
-------------
The design says what *could* be confused; the data say whether it was.
The drift is fitted in every model, so it takes whatever grows with time.
Every effect that changes between visits of a pose (thermal expansion,
backlash) and is not named is fitted *instead of* the drift: one that the
data show plainly then (its likelihood ratio passes the naming threshold)
and that explains the campaign as well as the drift does (twice the
log-likelihood within the chi2(1) 99 % quantile) is a cause the campaign
cannot tell from an instrument drift, such as thermal expansion while the
temperature follows time (:func:`drift_alternatives`). A named effect with
aliases is explained only up to its alias set. Either makes the verdict
*ambiguous* (:func:`ambiguities`).
"""

from __future__ import annotations

import numpy as np

from ...model.effects import EffectKind
from ..forward.signatures import effect
from ..estimation.likelihood import Engine, Fit, chi2_equivalent
from ..estimation.nuisance import DRIFT, NUISANCE_NAMES, REGISTRATION

__all__ = ["design_confounds", "drift_alternatives", "ambiguities", "VIF_LIMIT", "ADVICE"]

#: Variance inflation at and above which an effect counts as confounded (R^2 >= 0.9).
VIF_LIMIT = 10.0
#: The chi2(1) 99 % quantile: two fits within it explain the data as well (the aliases' criterion).
_Q = 6.634896601021214
#: What would separate an effect from each nuisance, and effects from each other.
ADVICE = {
    "registration": "spread the poses over the whole region and every slider's stroke and vary the orientation "
                    "phi as widely as the workspace allows; or register the instrument on a reference artefact "
                    "and analyse with --no-registration",
    "drift": "visit the poses in random order and revisit a reference pose (one with the sliders near zero) "
             "through the campaign; a drift is then measured apart from the machine",
    "thermal": "let the temperature cycle (heat and cool, or measure at several temperatures out of time order) "
               "rather than rise steadily with time",
    "each other": "add poses and orientations where their signatures differ (prp3mc plan chooses them)",
}


def _blocks(engine: Engine) -> dict:
    """Fitted nuisance blocks: label -> columns of ``engine.H``."""
    blocks = {"registration": [j for j in engine.nuisance if NUISANCE_NAMES[j] in REGISTRATION],
              "drift": [j for j in engine.nuisance if NUISANCE_NAMES[j] in DRIFT]}
    return {k: v for k, v in blocks.items() if v}


def _r2(engine: Engine, A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Share of each candidate's whitened signature (columns ``A``, by ``engine.blocks``) in the span of ``X``,
    (C,): for a cyclic error's two columns, the largest share of a combination of them."""
    if X.shape[1] == 0:
        return np.zeros(len(engine.blocks))
    Q, _ = np.linalg.qr(X)
    return 1.0 - engine.kept_share(A, A - Q @ (Q.T @ A))


def _time_temperature_r(engine: Engine) -> float | None:
    """Correlation of the temperature with time over the kept rows (None without temperatures)."""
    t = engine.campaign.temp_C
    if t is None or np.ptp(t) == 0:
        return None
    s = engine.H[:, 0, 3]                              # the drift's time fraction of each row
    return float(np.corrcoef(t, s)[0, 1]) if np.ptp(s) > 0 else None


def _vif(r2: float) -> float:
    """Variance inflation of a share ``r2``, at most 1e12 (an exact confound)."""
    return float(1.0 / max(1.0 - r2, 1e-12))


def _vif_text(vif: float) -> str:
    return f"{vif:.3g}" if vif < 1e6 else "> 1e6"


def design_confounds(engine: Engine, effects=None) -> list[dict]:
    """The campaign's confounds from its design (module notes), in library order.

    Parameters
    ----------
    engine : Engine
    effects : collection of str, optional
        Only the confounds that involve these effects (a nuisance entry
        lists only them; a group is kept when it holds one). Default: all.

    Returns
    -------
    list of dict
        ``{"effects", "with", "why", "advice", "vif", "source": "design"}``: the effects confounded with
        one nuisance block (``vif``: name -> variance inflation), then each group of effects confounded
        with each other (``with``: the others of the group; ``r``: the least and largest ``|r|``).
    """
    fit = engine.fit((), {}, 0.0)
    A = engine.whitened_candidates(fit)
    Xall = engine.whitened(fit, (), tuple(range(engine.H.shape[2])))[1]
    blocks = _blocks(engine)
    limit = 1.0 - 1.0 / VIF_LIMIT
    r2 = {label: _r2(engine, A, Xall[:, cols]) for label, cols in blocks.items()}
    r2_all = _r2(engine, A, Xall[:, list(engine.nuisance)])
    temp_r = _time_temperature_r(engine)
    groups: dict = {}                                    # (with, thermal) -> [(name, r2)]
    for j, e in enumerate(engine.systematic):
        if r2_all[j] < limit or (effects is not None and e.name not in effects):
            continue
        alone = [b for b in blocks if r2[b][j] >= limit]
        with_ = tuple([max(alone, key=lambda b: r2[b][j])] if alone else blocks)
        groups.setdefault((with_, e.kind == EffectKind.THERMAL), []).append((e.name, float(r2_all[j])))
    out = []
    for (with_, thermal), members in groups.items():
        names, shares = [m[0] for m in members], np.array([m[1] for m in members])
        span = " and ".join(with_)
        vifs = {n: _vif(v) for n, v in members}
        exact = [n for n in names if n in engine.confounded]
        share = (f"{100 * shares.min():.1f} %" if shares.min() == shares.max() else
                 f"{100 * shares.min():.1f} to {100 * shares.max():.1f} %")
        low, high = _vif_text(min(vifs.values())), _vif_text(max(vifs.values()))
        why = (f"{share} of {'its signature' if len(names) == 1 else 'their signatures'} over this campaign "
               f"lie{'s' if len(names) == 1 else ''} in the span of the {span} (variance inflation "
               f"{low}{'' if low == high else ' to ' + high}: the detectable value grows by its square root)")
        if exact:
            why += f"; {', '.join(exact)} exactly so: never tested"
        advice = [ADVICE[b] for b in with_]
        if thermal and temp_r is not None:
            why = f"the temperature follows time (r = {temp_r:.2f}): " + why
            advice.append(ADVICE["thermal"])
        out.append({"effects": names, "with": list(with_), "why": why, "advice": "; ".join(advice),
                    "vif": vifs, "source": "design"})
    groups = _effect_groups(engine, A, Xall[:, list(engine.nuisance)])
    return out + [g for g in groups if effects is None or set(g["effects"] + g["with"]) & set(effects)]


def _effect_groups(engine: Engine, A: np.ndarray, X: np.ndarray) -> list[dict]:
    """Groups of effects whose signatures, the nuisances projected out, correlate at ``VIF_LIMIT`` or more."""
    if X.shape[1]:
        Q, _ = np.linalg.qr(X)
        A = A - Q @ (Q.T @ A)
    norm = np.linalg.norm(A, axis=0)
    owner = np.repeat(np.arange(len(engine.blocks)), [len(c) for c in engine.blocks])
    U = A / np.where(norm > 0, norm, 1.0)
    column_corr = np.abs(U.T @ U)                        # a candidate's correlation: its columns' largest
    corr = np.zeros((len(engine.blocks),) * 2)
    np.maximum.at(corr, (owner[:, None], owner[None, :]), column_corr)
    testable = np.flatnonzero(np.array([e.name not in engine.confounded and norm[engine.blocks[j]].max() > 0
                                        for j, e in enumerate(engine.systematic)]))
    corr = corr[np.ix_(testable, testable)]
    linked = corr >= np.sqrt(1.0 - 1.0 / VIF_LIMIT)
    label = np.arange(testable.size)
    for _ in range(testable.size):                       # connected components by label propagation
        new = np.array([label[linked[k]].min() for k in range(testable.size)])
        if np.array_equal(new, label):
            break
        label = new
    out = []
    for root in np.unique(label):
        members = np.flatnonzero(label == root)
        if members.size < 2:
            continue
        names = [engine.systematic[testable[k]].name for k in members]
        sub = corr[np.ix_(members, members)]
        r_min = float(sub[np.triu_indices(members.size, 1)].min())
        r_max = float(sub[np.triu_indices(members.size, 1)].max())
        same = " (identical signatures)" if r_min > 1 - 1e-6 else ""
        out.append({"effects": names[:1], "with": names[1:],
                    "why": f"their signatures over this campaign, the nuisances fitted, correlate by |r| = "
                           f"{r_min:.3f} to {r_max:.3f}{same}: the data name one of them, not which",
                    "advice": ADVICE["each other"], "r": [r_min, r_max], "source": "design"})
    return out


def _time_varying(engine: Engine) -> np.ndarray:
    """Candidates (indices) whose signature changes between visits of a pose (thermal, backlash): only such
    an effect can take a drift's place, which grows within each pose's visits."""
    within = engine.G - engine.pose_mean(engine.G)[engine.idx]
    varies = np.sum(within**2, axis=(0, 1)) > 1e-12 * np.sum(engine.G**2, axis=(0, 1))      # per column
    return np.array([j for j, cols in enumerate(engine.blocks) if varies[cols].any()], dtype=int)


def drift_alternatives(engine: Engine, fit: Fit, alpha: float) -> list[tuple[str, float, float, float]]:
    """Effects the data show as plainly as a drift, when no drift is fitted (module notes).

    An effect that changes between visits of a pose (:func:`_time_varying`), not in ``fit``, is fitted
    *instead of* the drift: it is an alternative when it fits the campaign as well as ``fit`` does with its
    drift (twice the log-likelihood within the chi2(1) 99 % quantile) and explains something there (its
    likelihood ratio against the model without it and without a drift passes the naming threshold,
    chi2(1) at ``alpha`` over the testable candidates).

    Returns
    -------
    list of (name, value, lr_as_drift, lr_shown)
        Each alternative, its value fitted without a drift, ``2 (loglik(fit) - loglik(effect, no drift))``
        and its likelihood ratio without a drift.
    """
    from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
    no_drift = tuple(j for j in fit.nuis if NUISANCE_NAMES[j] not in DRIFT)
    K = sum(e.name not in engine.confounded for e in engine.systematic) + len(engine.spreads)
    threshold = float(chi2.isf(alpha / max(K, 1), 1))
    without = None
    out = []
    for j in _time_varying(engine):
        e = engine.systematic[j]
        if j in fit.sys or e.name in engine.confounded:
            continue
        trial = engine.refit(fit.sys + (int(j),), fit.factors, start_r=fit.r, nuis=no_drift)
        as_drift = 2.0 * (fit.loglik - trial.loglik)
        if as_drift > _Q:
            continue
        without = without or engine.refit(fit.sys, fit.factors, start_r=fit.r, nuis=no_drift)
        shown = chi2_equivalent(2.0 * (trial.loglik - without.loglik), e.dof)
        if shown > threshold:
            out.append((e.name, engine.values(trial)[e.name], float(as_drift), float(shown)))
    return out


def ambiguities(engine: Engine, fit: Fit, named, drift_test: dict, alpha: float) -> tuple[list[dict], list[str]]:
    """The confounds the data show (module notes) and the verdict's reasons to call the cause ambiguous.

    Parameters
    ----------
    engine, fit
        The named model.
    named : sequence of NamedEffect
    drift_test : dict
        The drift's likelihood-ratio test (``significant``, ``values``).
    alpha : float
        The workflow's naming level.

    Returns
    -------
    confounds : list of dict
        ``{"effects", "with", "why", "advice", "source": "data", ...}``.
    reasons : list of str
        One line per ambiguity (empty: the cause is not ambiguous).
    """
    confounds, reasons = [], []
    for e in named:
        if e.aliases:
            reasons.append(f"{e.name} is named, but the campaign cannot tell it from {', '.join(e.aliases)}")
    drift = ", ".join(f"{n} = {1e3 * v:.3g} µm" if not n.endswith("phi") else f"{n} = {3600 * v:.3g} arcsec"
                      for n, v in drift_test["values"].items())
    shown = "shown by the data" if drift_test["significant"] else "not significant with the drift fitted"
    for name, value, as_drift, lr in drift_alternatives(engine, fit, alpha):
        unit = effect(name).unit
        size = abs(value) if isinstance(value, complex) else value        # a cyclic error: its amplitude
        confounds.append({
            "effects": [name], "with": ["drift"],
            "why": f"{name} = {size:.4g} {unit} explains the data without a drift (likelihood ratio {lr:.3g}) "
                   f"as well as the drift fitted ({drift}; {shown}) does: twice the log-likelihood "
                   f"{as_drift:.3g} below, within {_Q:.3g}",
            "advice": ADVICE["thermal"] if effect(name).kind == EffectKind.THERMAL else ADVICE["drift"],
            "value": float(size), "unit": unit, "lr": lr, "lr_as_drift": as_drift, "source": "data"})
        reasons.append(f"the drift fitted may be {name} = {size:.4g} {unit}: the campaign cannot tell them apart")
    return confounds, reasons
