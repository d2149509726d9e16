"""How model and measurements disagree: per-pose and global tests, one verdict, and the gap.

Channels and tests
------------------
Whitening (:mod:`~prp3mc.measurement.estimation.likelihood`) gives, when the model is
right, standardised pose means ``zb_p`` (covariance I) and visit deviations
``zw`` (covariance I within each pose), with the fitted repeatable fraction,
the nuisances profiled out and gross errors set aside. Per pose, the
*systematic* statistic is ``B_p = |zb_p|^2`` (about chi2(3)) and the
*dispersion* statistic ``S_p = sum |zw|^2`` (mean 3 (n_p - 1)); their null
variances, which depend on the budget's non-Gaussian laws, come from a
parametric bootstrap of the linear model, and p-values from scaled
chi-square laws with matched mean and variance.

The verdict uses seven channels, each with a p-value: ``library`` (the
whitened residual energy in the span of every testable systematic candidate
not in the model, chi2 with its rank), ``systematic`` (sum of B_p),
``dispersion`` (sum of S_p, two-sided), ``systematic_pose`` and
``dispersion_pose`` (the per-pose tests, Holm), ``spatial`` (neighbouring
pose means alike) and ``lack_of_fit`` (smooth probe directions outside the
library).

The gap
-------
``gap = max(0, max_c(-ln p_c) - ln 7)``: each ``-ln p_c`` is Exp(1) when the
model is right, so ``P(gap > x) <= exp(-x)`` (null level at most 1) and the
gap grows like ``z^2 / 2`` with the strongest channel's standardised
deviation ``z``. The gap is *closed* at most at ``-ln alpha_unexplained``
(3.0 at 5 %), and exactly then nothing is unexplained: the verdict and the
gap are one decision (Bonferroni over the seven channels), never a closed
gap beside "unexplained".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..._result import POSE_COLUMNS, freeze
from ...model.linear import linear_model
from ...units import DISPLAY, MM2UM, OUTPUT_UNITS, POSE_OUTPUTS
from ..forward.signatures import ROW_TO_DEG, spread_budget
from ..estimation.likelihood import Engine, Fit

__all__ = ["Diagnosis", "diagnose", "null_variances", "gap", "gap_value", "verdict", "CHANNELS", "VERDICTS"]

#: ``[mm, mm, deg] -> [µm, µm, arcsec]``: the display scale of the pose error rows in tables.
_DISPLAY = np.array([DISPLAY[o][0] for o in POSE_OUTPUTS])
#: The channels of the verdict (their log p-values are ``log_p_<channel>`` in :attr:`Diagnosis.summary`).
CHANNELS = ("library", "systematic", "dispersion", "systematic_pose", "dispersion_pose", "spatial", "lack_of_fit")
#: Per-pose statistics of :meth:`Diagnosis.to_frame` besides the mean residual (all dimensionless).
_POSE_STATISTICS = ("sys_stat", "sys_p", "sys_q", "disp_ratio", "disp_p", "disp_q")
_LN2 = float(np.log(2.0))
#: The states of the verdict, the first that holds (:func:`verdict`).
VERDICTS = ("beyond the linear model", "unexplained", "ambiguous", "explained", "nothing missing")


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """How model and measurements disagree, for one model state.

    Attributes
    ----------
    poses : DataFrame
        Per pose: ``pose_id, x_mm, y_mm, phi_deg, n``, mean residual
        ``dx_um, dy_um, dphi_arcsec``, systematic statistic ``sys_stat``
        with ``sys_p`` and its BH q-value ``sys_q``; dispersion ratio
        ``disp_ratio`` (observed / predicted repeat scatter, 1 when right)
        with ``disp_p`` (two-sided), ``disp_q`` and ``disp_direction``.
    measurements : DataFrame
        Per kept measurement: ``row`` (0-based data row), pose, residual
        (µm, arcsec, nuisances removed), whitened residual, slider positions
        ``b_1..3`` (mm), ``dir_1..3``, ``temp_C`` and the residual as an
        equivalent slider error ``db_eq_1..3_um`` (J_b^-1 r).
    summary : mapping
        Global tests: ``sys_stat, sys_mean, sys_p``, ``disp_stat, disp_mean,
        disp_null_sd, disp_p, disp_direction``, the total ``gap`` (chi2 per
        dof of all residuals) with ``gap_null_sd``, the library channel
        ``library_stat, library_df``, per-pose Holm minima ``sys_holm_min,
        disp_holm_min``, flagged pose counts (BH 5 %), the spatial test
        ``spatial_z, spatial_p``, the lack-of-fit test ``lack_of_fit_lr,
        lack_of_fit_df, lack_of_fit_p``, and ``log_p_<channel>`` for each of
        :data:`CHANNELS`.
    """

    poses: pd.DataFrame
    measurements: pd.DataFrame
    summary: dict

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        s = self.summary
        return (f"Diagnosis(poses={len(self.poses)}, measurements={len(self.measurements)}, "
                f"sys_p={s['sys_p']:.3g}, disp_p={s['disp_p']:.3g})")

    def to_frame(self) -> pd.DataFrame:
        """Tidy per-pose table in boundary units.

        Columns ``pose_id, x_mm, y_mm, phi_deg, n`` (the commanded pose and
        its number of measurements), ``output``, ``statistic``, ``value``,
        ``unit``: the mean residual (``statistic`` ``mean_residual``,
        ``output`` x, y, phi; mm, mm, deg) and the per-pose tests
        ``sys_stat, sys_p, sys_q, disp_ratio, disp_p, disp_q`` (unit 1;
        ``output`` None: they are of the whole pose error).
        """
        p = self.poses
        keys = p[["pose_id", *POSE_COLUMNS, "n"]]
        parts = [keys.assign(output=o, statistic="mean_residual", value=p[col] / _DISPLAY[k], unit=OUTPUT_UNITS[o])
                 for k, (o, col) in enumerate(zip(POSE_OUTPUTS, ("dx_um", "dy_um", "dphi_arcsec")))]
        parts += [keys.assign(output=None, statistic=stat, value=p[stat].astype(float), unit="1")
                  for stat in _POSE_STATISTICS]
        return pd.concat(parts, ignore_index=True)


def _span_energy(Z: np.ndarray, A: np.ndarray, X: np.ndarray) -> tuple[float, int]:
    """Energy of the columns' vector ``Z`` in the span of ``A`` orthogonalised to ``X``, and that span's rank."""
    if X.shape[1]:
        Q, _ = np.linalg.qr(X)
        A = A - Q @ (Q.T @ A)
    if A.shape[1] == 0:
        return 0.0, 0
    ev, V = np.linalg.eigh(A.T @ A)
    keep = ev > 1e-12 * max(ev.max(), 1e-300)
    proj = (V[:, keep].T @ (A.T @ Z)) / np.sqrt(ev[keep])
    return float(proj @ proj), int(keep.sum())


def _chi2_logsf(x, df):
    """log of the chi2(df) upper tail; far in the tail, where it underflows, the Wilson-Hilferty normal law."""
    from scipy.stats import chi2, norm  # imported when used: prp3mc --help imports this module
    out = np.asarray(chi2.logsf(x, df), dtype=float)
    far = ~np.isfinite(out)
    if far.any():
        x, df = np.broadcast_to(x, out.shape)[far], np.broadcast_to(df, out.shape)[far]
        h = 2.0 / (9.0 * df)
        out[far] = norm.logsf(((x / df) ** (1.0 / 3.0) - 1.0 + h) / np.sqrt(h))
    return out if out.ndim else float(out)


def _scaled_chi2_logsf(t, mean, var, upper=True):
    from scipy.stats import chi2
    c = var / (2.0 * mean)
    nu = 2.0 * mean**2 / var
    return _chi2_logsf(t / c, nu) if upper else chi2.logcdf(t / c, nu)


#: log of the smallest normal double: a p-value that underflows (a statistic of exactly zero, as perfect
#: measurements give the lower tail) is reported at this floor, so that every score stays finite.
_LOG_P_FLOOR = float(np.log(np.finfo(float).tiny))


def _two_sided(t, mean, var):
    """log of the two-sided p-value of a scaled chi-square statistic (floored at :data:`_LOG_P_FLOOR`)."""
    lower = np.maximum(_scaled_chi2_logsf(t, mean, var, False), _LOG_P_FLOOR)
    return np.minimum(0.0, _LN2 + np.minimum(_scaled_chi2_logsf(t, mean, var), lower))


def _holm_log_min(log_p: np.ndarray) -> float:
    s = np.sort(log_p)
    return float(min(0.0, np.min(s + np.log(s.size - np.arange(s.size)))))


def null_variances(engine: Engine, fit: Fit, n_boot: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bootstrap variances (P,) of B_p, S_p and B_p + S_p under the fitted model.

    The repeatable part is drawn once per pose and replicate, the rest at
    every visit: ``mu + sqrt(r) (e_pose - mu) + sqrt(1 - r) (e_visit - mu)``.
    """
    bud = spread_budget(engine.budget.without_effects(), {n: f * engine.spread_ref[n] for n, f in fit.factors.items()})
    model = linear_model(engine.model_geometry, bud, engine.model_poses, check=False)
    mean = engine.moments(fit.factors, fit.r)[0]
    coef = model.coef[engine.idx]
    F = model.features(bud.sample(n_boot * engine.M, rng)).reshape(n_boot, engine.M, -1)
    e = (np.einsum("mof,rmf->rmo", coef, F) * ROW_TO_DEG - mean[engine.idx]) * np.sqrt(1.0 - fit.r)
    if fit.r > 0:
        Fp = model.features(bud.sample(n_boot * engine.P, rng)).reshape(n_boot, engine.P, -1)
        e_pose = np.einsum("pof,rpf->rpo", model.coef, Fp) * ROW_TO_DEG - mean
        e += np.sqrt(fit.r) * e_pose[:, engine.idx]
    e += rng.standard_normal(e.shape) * np.sqrt(np.diagonal(engine.noise))
    zbar = engine.pose_mean(e, axis=1)
    zw = np.einsum("mij,rmj->rmi", fit.Lw[engine.idx], e - zbar[:, engine.idx])
    zb = np.einsum("pij,rpj->rpi", fit.Lb, zbar)
    B, S = _pose_stats(engine, zw, zb)
    return B.var(0, ddof=1), S.var(0, ddof=1), (B + S).var(0, ddof=1)


def _pose_stats(engine: Engine, zw: np.ndarray, zb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose systematic B_p and dispersion S_p of whitened residuals (..., M, 3) and (..., P, 3)."""
    S = engine.pose_mean(np.sum(zw**2, axis=-1), axis=zw.ndim - 2) * engine.n
    return np.sum(zb**2, axis=-1), S


def _neighbour_edges(poses: np.ndarray, k: int = 4) -> np.ndarray:
    """Undirected edges (E, 2) joining each pose to its k nearest (coordinates scaled by their range)."""
    P = poses.shape[0]
    if P < 2:
        return np.zeros((0, 2), dtype=int)
    span = np.ptp(poses, axis=0)
    x = poses / np.where(span > 0, span, 1.0)
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    near = np.argsort(d, axis=1)[:, :min(k, P - 1)]
    pairs = np.stack([np.repeat(np.arange(P), near.shape[1]), near.ravel()], axis=1)
    return np.unique(np.sort(pairs, axis=1), axis=0)


def _probe_basis(engine: Engine) -> np.ndarray:
    """Smooth lack-of-fit directions (M, 3, Q), [mm, mm, deg] per unit.

    Quadratic polynomials of the commanded pose for each output, cubic
    Legendre terms of each slider position along its J_b column, and a
    linear temperature trend per output: structure a missing effect outside
    the library is likely to leave behind.
    """
    c = engine.campaign
    lo, span = c.poses.min(0), np.ptp(c.poses, axis=0)
    u = np.where(span > 0, 2.0 * (c.commanded - lo) / np.where(span > 0, span, 1.0) - 1.0, 0.0)
    ones = np.ones(c.n_measurements)
    terms = [ones, *u.T] + [u[:, a] * u[:, b] for a in range(3) for b in range(a, 3)]
    if c.temp_C is not None:
        terms.append(c.temp_C - c.temp_C.mean())
    cols = [np.einsum("m,o->mo", t, np.eye(3)[o]) for t in terms for o in range(3)]
    bm = engine.b_pose[c.pose_index]
    bspan = np.ptp(bm, axis=0)
    v = np.where(bspan > 0, 2.0 * (bm - bm.min(0)) / np.where(bspan > 0, bspan, 1.0) - 1.0, 0.0)
    for i in range(3):
        for poly in (0.5 * (3 * v[:, i] ** 2 - 1), 0.5 * (5 * v[:, i] ** 3 - 3 * v[:, i])):
            cols.append(engine.Jb[c.pose_index][:, :, i] * poly[:, None])
    return np.stack(cols, axis=-1)


def _spatial_z(engine: Engine, fit: Fit, model_cols: np.ndarray) -> float:
    """Standardised sum over neighbouring poses of the products of their standardised mean residuals.

    ``S = zb' E zb`` with ``E`` half the neighbour adjacency (per output).
    The fit makes ``zb = R_b eps`` with ``R = I - QQ'`` (Q: orthonormal
    basis of the fitted columns), so under the model ``E[S] = tr(E R_bb)``
    and, for Gaussian errors, ``Var[S] = 2 tr((E R_bb)^2)``.
    """
    edges = _neighbour_edges(engine.campaign.poses)
    if not len(edges):
        return 0.0
    adj = np.zeros((engine.P, engine.P))
    adj[edges[:, 0], edges[:, 1]] = adj[edges[:, 1], edges[:, 0]] = 0.5
    E = np.kron(adj, np.eye(3))
    R = np.eye(3 * engine.P)
    if model_cols.shape[1]:
        Q, _ = np.linalg.qr(model_cols)
        Qb = Q[3 * engine.M:]
        R = R - Qb @ Qb.T
    ER = E @ R
    u = fit.zb.ravel()
    return float((u @ E @ u - np.trace(ER)) / np.sqrt(2.0 * np.trace(ER @ ER)))


def diagnose(engine: Engine, fit: Fit, n_boot: int = 0, rng=None, *, null: tuple | None = None,
             fitted: bool = True) -> Diagnosis:
    """Every test of the module notes for the model state ``fit``.

    Parameters
    ----------
    engine : Engine
    fit : Fit
    n_boot : int
        Bootstrap replicates of the null variances (unless ``null`` is given).
    rng : numpy.random.Generator
        Randomness of the bootstrap.
    null : tuple of 3 ndarray of shape (P,), optional
        Null variances of B_p, S_p and B_p + S_p (:func:`null_variances`) computed before.
    fitted : bool
        Whether ``fit``'s values, spread factors and ``r`` were fitted to
        these residuals (their degrees of freedom are then taken off);
        False for residuals of measurements left out of the fit.
    """
    from scipy.stats import false_discovery_control, norm
    c = engine.campaign
    vB, vS, vT = null_variances(engine, fit, n_boot, rng) if null is None else null
    B, S = _pose_stats(engine, fit.zw, fit.zb)
    n = engine.n
    mB, mS = np.full(engine.P, 3.0), 3.0 * (n - 1)
    sys_logp = _scaled_chi2_logsf(B, mB, vB)
    has_rep = n > 1
    disp_logp = np.zeros(engine.P)
    ratio = np.full(engine.P, np.nan)
    ratio[has_rep] = S[has_rep] / mS[has_rep]
    disp_logp[has_rep] = _two_sided(S[has_rep], mS[has_rep], vS[has_rep])
    n_par = fit.theta.size + (len(fit.factors) + 1) * fitted   # values, spreads and r
    gB_mean = 3.0 * engine.P - fit.k_between
    gS_mean = mS.sum() - (fit.theta.size - fit.k_between) - (len(fit.factors) + 1) * fitted
    gB_var = vB.sum() * gB_mean / (3.0 * engine.P)
    gS_var = vS[has_rep].sum() * gS_mean / max(mS.sum(), 1.0) if has_rep.any() else 0.0
    dof = 3.0 * engine.M - n_par
    model_cols = engine.whitened(fit, fit.sys, fit.nuis)[1]
    testable = [j for j, e in enumerate(engine.systematic) if j not in fit.sys and e.name not in engine.confounded]
    lib_stat, lib_df = _span_energy(fit.z, engine.whitened_candidates(fit)[:, engine.cols_of(testable)], model_cols)
    probes = engine.whiten(_probe_basis(engine), fit.Lw, fit.Lb)
    lof_stat, lof_df = _span_energy(fit.z, probes, model_cols)
    summary = {
        "sys_stat": float(B.sum()), "sys_mean": float(gB_mean),
        "disp_stat": float(S.sum()), "disp_mean": float(gS_mean),
        "disp_null_sd": float(np.sqrt(gS_var) / max(gS_mean, 1.0)),
        "disp_direction": "as predicted",
        "gap": float((B.sum() + S.sum()) / dof), "gap_null_sd": float(np.sqrt(vT.sum()) / dof),
        "library_stat": lib_stat, "library_df": lib_df,
        "lack_of_fit_lr": lof_stat, "lack_of_fit_df": lof_df,
        "log_p_library": float(_chi2_logsf(lib_stat, lib_df)) if lib_df else 0.0,
        "log_p_systematic": float(_scaled_chi2_logsf(B.sum(), gB_mean, gB_var)),
        "log_p_dispersion": 0.0,
        "log_p_systematic_pose": _holm_log_min(sys_logp),
        "log_p_dispersion_pose": _holm_log_min(disp_logp[has_rep]) if has_rep.any() else 0.0,
        "log_p_lack_of_fit": float(_chi2_logsf(lof_stat, lof_df)) if lof_df else 0.0,
    }
    moran = _spatial_z(engine, fit, model_cols)
    summary.update(spatial_z=moran, log_p_spatial=float(norm.logsf(moran)))
    if has_rep.any() and gS_mean > 0:
        summary["log_p_dispersion"] = float(_two_sided(S.sum(), gS_mean, gS_var))
        summary["disp_direction"] = "larger" if S.sum() > gS_mean else "smaller"
    sys_p, disp_p = np.exp(sys_logp), np.exp(disp_logp)
    for key, name in (("sys_p", "systematic"), ("disp_p", "dispersion"), ("spatial_p", "spatial"),
                      ("lack_of_fit_p", "lack_of_fit"), ("library_p", "library"),
                      ("sys_holm_min", "systematic_pose"), ("disp_holm_min", "dispersion_pose")):
        summary[key] = float(np.exp(summary[f"log_p_{name}"]))
    sys_q, disp_q = false_discovery_control(sys_p, method="bh"), np.ones(engine.P)
    if has_rep.any():
        disp_q[has_rep] = false_discovery_control(disp_p[has_rep], method="bh")
    summary["n_poses_sys_flagged"] = int(np.sum(sys_q < 0.05))
    summary["n_poses_disp_flagged"] = int(np.sum(disp_q < 0.05))
    mean_resid = engine.pose_mean(fit.resid) * _DISPLAY
    poses = pd.DataFrame({
        "pose_id": list(c.pose_labels), "x_mm": c.poses[:, 0], "y_mm": c.poses[:, 1], "phi_deg": c.poses[:, 2],
        "n": n.astype(int), "dx_um": mean_resid[:, 0], "dy_um": mean_resid[:, 1],
        "dphi_arcsec": mean_resid[:, 2], "sys_stat": B, "sys_p": sys_p, "sys_q": sys_q,
        "disp_ratio": ratio, "disp_p": disp_p, "disp_q": disp_q,
        "disp_direction": np.where(~has_rep, "n/a", np.where(S > mS, "larger", "smaller")),
    })
    b, Jb = engine.b_pose, engine.Jb
    db = np.linalg.solve(Jb[engine.idx], fit.resid[..., None])[..., 0]
    meas = pd.DataFrame({"row": engine.rows, "pose_id": c.pose_id, "pose": engine.idx})
    for k, name in enumerate(("dx_um", "dy_um", "dphi_arcsec")):
        meas[name] = _DISPLAY[k] * fit.resid[:, k]
    for k, name in enumerate(("zx", "zy", "zphi")):
        meas[name] = fit.zw[:, k]
    for i in range(3):
        meas[f"b_{i + 1}"] = b[engine.idx, i]
        meas[f"dir_{i + 1}"] = c.direction[:, i] if c.has_dir[i] else np.nan
        meas[f"db_eq_{i + 1}_um"] = MM2UM * db[:, i]
    meas["temp_C"] = c.temp_C if c.temp_C is not None else np.nan
    return Diagnosis(poses=poses, measurements=meas, summary=summary)


def gap_value(diag: Diagnosis) -> tuple[float, str]:
    """The gap of one diagnosis (module notes) and the channel that sets it."""
    scores = {ch: -diag.summary[f"log_p_{ch}"] for ch in CHANNELS}
    worst = max(scores, key=scores.get)
    return max(0.0, scores[worst] - float(np.log(len(CHANNELS)))), worst


def gap(before: Diagnosis, after: Diagnosis, alpha_unexplained: float) -> dict:
    """The gap document of ``discrepancy.json``: the gap before and after the named effects, and the verdict.

    ``closed`` is true exactly when the model with the named effects
    leaves nothing unexplained (every channel within its Bonferroni level).
    """
    closed_at = float(-np.log(alpha_unexplained))
    channels = {}
    for state, diag in (("before", before), ("after", after)):
        s = diag.summary
        g_sys = s["library_stat"] / s["library_df"] if s["library_df"] else 1.0
        channels[state] = {
            **{ch: {"log_p": s[f"log_p_{ch}"], "score": -s[f"log_p_{ch}"]} for ch in CHANNELS},
            "systematic": g_sys, "systematic_null_sd": float(np.sqrt(2.0 / s["library_df"])) if s["library_df"] else 0.0,
            "dispersion": s["disp_stat"] / max(s["disp_mean"], 1.0), "dispersion_null_sd": s["disp_null_sd"],
        }
    g_before, _ = gap_value(before)
    g_after, worst = gap_value(after)
    return {
        "metric": "max(0, max over the verdict's 7 channels of -ln p - ln 7): each -ln p is Exp(1) when the model "
                  "is right, so P(gap > x) <= exp(-x) (null level at most 1); the channels are the library span, "
                  "the pose means, the repeat scatter, the per-pose tests of both (Holm), the spatial and the "
                  "lack-of-fit tests, all on residuals with nuisances profiled out and gross errors set aside; "
                  "closed at <= -ln(alpha_unexplained), which is exactly when nothing is unexplained",
        "before": float(g_before), "after": float(g_after), "null_level": 1.0, "null_sd": 1.0, "closed_at": closed_at,
        "closed": bool(g_after <= closed_at), "deciding_channel": worst, "channels": channels,
        "residual": {"metric": "mean squared whitened residual per degree of freedom (chi2/dof of all "
                               "measurements under the model's predicted mean and covariance)",
                     "before": before.summary["gap"], "after": after.summary["gap"], "null_level": 1.0,
                     "null_sd_before": before.summary["gap_null_sd"], "null_sd": after.summary["gap_null_sd"]},
    }


def verdict(gap_doc: dict, named, linearity: dict, ambiguities: list, confounded=()) -> dict:
    """The analysis's one verdict: ``{"state", "text"}``, the first of :data:`VERDICTS` that holds.

    ``beyond the linear model``: the linearity guard refused to name
    (:mod:`~prp3mc.measurement.naming.identify`); ``unexplained``: the gap is not
    closed; ``ambiguous``: it is closed, but by a cause the campaign cannot
    tell from another or from the instrument's drift (``ambiguities``,
    :func:`~prp3mc.measurement.confounds.ambiguities`); ``explained``: named
    effects close it; ``nothing missing``: it is closed without one. The
    last two say which effects the design cannot tell from the drift
    (``confounded`` entries with ``drift``), which may hide in it.
    """
    if linearity["guard"] != "ok":
        return {"state": VERDICTS[0], "text": f"beyond the linear model: {linearity['why']}; {linearity['advice']}"}
    if not gap_doc["closed"]:
        channel = gap_doc["deciding_channel"].replace("_", " ")
        return {"state": VERDICTS[1], "text": f"unexplained disagreement remains ({channel}) that no effect of the "
                                              "library explains"}
    if ambiguities:
        return {"state": VERDICTS[2], "text": "the cause is ambiguous: " + "; ".join(ambiguities)}
    names = {e.name for e in named}
    hidden = [n for c in confounded if "drift" in c["with"] for n in c["effects"] if n not in names]
    caveat = f"; this campaign cannot tell {', '.join(hidden)} from a drift (see confounded)" if hidden else ""
    if named:
        return {"state": VERDICTS[3], "text": "explained by " + ", ".join(e.name for e in named) + caveat}
    return {"state": VERDICTS[4], "text": "the model misses nothing this campaign can see" + caveat}
