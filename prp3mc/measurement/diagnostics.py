"""How model and measurements disagree: per-pose and global tests, and the gap.

Channels and tests
------------------
Whitening the residuals by ``V_p^{-1/2}`` gives vectors z_m with mean 0 and
covariance I when the model is right. Per pose, the *systematic* statistic
is ``B_p = n_p |mean z|^2`` (about chi2(3)) and the *dispersion* statistic
``S_p = sum |z_m - mean z|^2`` (mean 3 (n_p - 1)); their null variances,
which depend on the budget's non-Gaussian laws, come from a parametric
bootstrap of the linear model, and p-values from scaled chi-square laws with
matched mean and variance. Global tests sum them over poses; per-pose tests
are controlled by Benjamini-Hochberg (maps) and Holm (decisions). A spatial
test (neighbouring pose means alike) and a lack-of-fit test (smooth probe
directions outside the library) complete the six tests of
:func:`is_unexplained`.

Gap metric
----------
Two channels, each 1 when the model is right. ``G_sys`` is the energy of the
whitened residuals in the span of the whitened signatures of every visible
systematic candidate not yet in the model, per degree of freedom (the span's
rank): the residuals have covariance I when the model is right, so its mean
is then exactly 1 whatever the error laws, with sd about sqrt(2/df).
``G_disp = sum_p S_p / E[sum_p S_p]`` is the repeat scatter over its null
mean, with the bootstrap null sd. With each standardised, ``z = (G - 1) / sd``,
``gap = (z_sys^2 + z_disp^2) / 2``: about chi2(2)/2 when the model is right
(``null_level`` 1, null sd 1), so both kinds of disagreement weigh alike. The
gap is *closed* when it is at most 5 (0.7 % of null values lie above), the
plain mean squared whitened residual of all measurements (``gap.residual``,
which also sees disagreement outside the library) is within 4 null standard
deviations of 1, and nothing unexplained remains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from .._result import POSE_COLUMNS, freeze
from ..uncertainty.model import linear_model
from ..units import DISPLAY, MM2UM, OUTPUT_UNITS, POSE_OUTPUTS
from .effects import ROW_TO_DEG, spread_budget
from .likelihood import Engine, Fit

__all__ = ["Diagnosis", "diagnose", "gap", "is_unexplained", "UNEXPLAINED_TESTS", "GAP_CLOSED"]

#: ``[mm, mm, deg] -> [µm, µm, arcsec]``: the display scale of the pose error rows in tables.
_DISPLAY = np.array([DISPLAY[o][0] for o in POSE_OUTPUTS])
#: The gap is closed at most at this value (null probability 0.7 % above).
GAP_CLOSED = 5.0
#: The tests of :func:`is_unexplained`, keys of :attr:`Diagnosis.summary`.
UNEXPLAINED_TESTS = ("sys_p", "disp_p", "sys_holm_min", "disp_holm_min", "spatial_p", "lack_of_fit_p")
#: Per-pose statistics of :meth:`Diagnosis.to_frame` besides the mean residual (all dimensionless).
_POSE_STATISTICS = ("sys_stat", "sys_p", "sys_q", "disp_ratio", "disp_p", "disp_q")


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
        Per measurement: pose, residual (µm, arcsec), whitened residual,
        slider positions ``b_1..3`` (mm), ``dir_1..3``, ``temp_C`` and the
        residual as an equivalent slider error ``db_eq_1..3_um`` (J_b^-1 r).
    summary : mapping
        Global tests: ``sys_stat, sys_mean, sys_p``, ``disp_stat, disp_mean,
        disp_p, disp_direction``, ``gap, gap_null_sd``, per-pose Holm minima
        ``sys_holm_min, disp_holm_min``, flagged pose counts (BH 5 %), the
        spatial test ``spatial_z, spatial_p`` and the lack-of-fit test
        ``lack_of_fit_lr, lack_of_fit_df, lack_of_fit_p``.
    """

    poses: pd.DataFrame
    measurements: pd.DataFrame
    summary: dict

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        s = self.summary
        return (f"Diagnosis(poses={len(self.poses)}, measurements={len(self.measurements)}, "
                f"gap={s['gap']:.4g}, sys_p={s['sys_p']:.3g}, disp_p={s['disp_p']:.3g})")

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


def _systematic_gap(engine: Engine, fit: Fit) -> tuple[float, float, int]:
    """Whitened residual energy in the span of the library's systematic signatures, per dof.

    The residual ``z`` of ``fit`` is projected on the span of every visible
    systematic candidate not in the model (orthogonalised to those in it):
    when the model is right ``z`` has covariance I, so the squared norm of
    the projection has mean exactly ``df`` (its rank) whatever the error law.
    Returns (value, null sd ~ sqrt(2/df), df).
    """
    A = fit.Gw.reshape(-1, len(engine.systematic))
    scale = np.linalg.norm(A, 2) if A.size else 0.0
    if fit.sys:
        Q, _ = np.linalg.qr(A[:, list(fit.sys)])
        A = A - Q @ (Q.T @ A)
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    Ur = U[:, sv > 1e-8 * scale]
    df = Ur.shape[1]
    if df == 0:
        return 1.0, 0.0, 0
    proj = Ur.T @ fit.z.ravel()
    return float(proj @ proj / df), float(np.sqrt(2.0 / df)), int(df)


def _scaled_chi2_sf(t, mean, var, upper=True):
    c = var / (2.0 * mean)
    nu = 2.0 * mean**2 / var
    return stats.chi2.sf(t / c, nu) if upper else stats.chi2.cdf(t / c, nu)


def _bh(p: np.ndarray) -> np.ndarray:
    return stats.false_discovery_control(p, method="bh")


def _holm_min(p: np.ndarray) -> float:
    return float(min(1.0, np.min(np.sort(p) * (p.size - np.arange(p.size)))))


def _null_variances(engine: Engine, fit: Fit, n_boot: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bootstrap variances (P,) of B_p, S_p and B_p + S_p under the fitted model."""
    bud = spread_budget(engine.budget, {n: f * engine.spread_ref[n] for n, f in fit.factors.items()})
    model = linear_model(engine.geometry, bud, engine.campaign.poses, check=False)
    mean, _ = engine.moments(fit.factors)
    X = bud.sample(n_boot * engine.M, rng)
    F = model.features(X).reshape(n_boot, engine.M, -1)
    e = np.einsum("mof,rmf->rmo", model.coef[engine.idx], F) * ROW_TO_DEG
    e += rng.standard_normal(e.shape) * np.sqrt(np.diagonal(engine.noise))
    z = np.einsum("mij,rmj->rmi", fit.Linv[engine.idx], e - mean[engine.idx])
    B, S = _pose_stats(engine, z)
    return B.var(0, ddof=1), S.var(0, ddof=1), (B + S).var(0, ddof=1)


def _pose_stats(engine: Engine, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose systematic B_p and dispersion S_p of whitened residuals z (..., M, 3)."""
    zbar = np.einsum("pm,...mi->...pi", engine.pose_mean_op, z)
    B = engine.n * np.sum(zbar**2, axis=-1)
    total = np.einsum("pm,...m->...p", engine.pose_mean_op, np.sum(z**2, axis=-1)) * engine.n
    return B, total - B


def _lack_of_fit(engine: Engine, fit: Fit) -> dict:
    """LR test of the smooth probe directions added to the fitted model (chi2 with their rank)."""
    Pw = np.einsum("mij,mjq->miq", fit.Linv[engine.idx], engine.probes).reshape(3 * engine.M, -1)
    if fit.sys:
        Q, _ = np.linalg.qr(fit.Gw[:, :, list(fit.sys)].reshape(3 * engine.M, -1))
        Pw = Pw - Q @ (Q.T @ Pw)
    U, sv, _ = np.linalg.svd(Pw, full_matrices=False)
    U = U[:, sv > 1e-8 * sv.max()]
    lr = float(np.sum((U.T @ fit.z.ravel()) ** 2))
    return {"lack_of_fit_lr": lr, "lack_of_fit_df": int(U.shape[1]),
            "lack_of_fit_p": float(stats.chi2.sf(lr, U.shape[1]))}


def diagnose(engine: Engine, fit: Fit, n_boot: int, rng) -> Diagnosis:
    c = engine.campaign
    vB, vS, vT = _null_variances(engine, fit, n_boot, rng)
    B, S = _pose_stats(engine, fit.z)
    n = engine.n
    mB, mS = np.full(engine.P, 3.0), 3.0 * (n - 1)
    sys_p = _scaled_chi2_sf(B, mB, vB)
    has_rep = n > 1
    disp_p = np.ones(engine.P)
    ratio = np.full(engine.P, np.nan)
    ratio[has_rep] = S[has_rep] / mS[has_rep]
    up = _scaled_chi2_sf(S[has_rep], mS[has_rep], vS[has_rep])
    lo = _scaled_chi2_sf(S[has_rep], mS[has_rep], vS[has_rep], upper=False)
    disp_p[has_rep] = np.minimum(1.0, 2.0 * np.minimum(up, lo))
    k_sys = len(fit.sys)
    n_spread = len(fit.factors)
    gB_mean = 3.0 * engine.P - fit.k_between
    gS_mean = mS.sum() - (k_sys - fit.k_between) - n_spread
    gB_var = vB.sum() * gB_mean / (3.0 * engine.P)
    gS_var = vS[has_rep].sum() * gS_mean / max(mS.sum(), 1.0) if has_rep.any() else 0.0
    dof = 3.0 * engine.M - k_sys - n_spread
    summary = {
        "sys_stat": float(B.sum()), "sys_mean": float(gB_mean),
        "sys_p": float(_scaled_chi2_sf(B.sum(), gB_mean, gB_var)),
        "disp_stat": float(S.sum()), "disp_mean": float(gS_mean),
        "disp_null_sd": float(np.sqrt(gS_var) / max(gS_mean, 1.0)),
        "disp_p": 1.0, "disp_direction": "as predicted",
        "gap": float((B.sum() + S.sum()) / dof), "gap_null_sd": float(np.sqrt(vT.sum()) / dof),
        "sys_holm_min": _holm_min(sys_p), "disp_holm_min": _holm_min(disp_p[has_rep]) if has_rep.any() else 1.0,
    }
    u = np.sqrt(n)[:, None] * np.einsum("pm,mi->pi", engine.pose_mean_op, fit.z)
    if len(engine.edges):
        moran = float(np.sum(u[engine.edges[:, 0]] * u[engine.edges[:, 1]]) / np.sqrt(3.0 * len(engine.edges)))
        summary.update(spatial_z=moran, spatial_p=float(stats.norm.sf(moran)))
    else:
        summary.update(spatial_z=0.0, spatial_p=1.0)
    summary.update(_lack_of_fit(engine, fit))
    if has_rep.any() and gS_mean > 0:
        up, low = (_scaled_chi2_sf(S.sum(), gS_mean, gS_var, u) for u in (True, False))
        summary["disp_p"] = float(min(1.0, 2.0 * min(up, low)))
        summary["disp_direction"] = "larger" if S.sum() > gS_mean else "smaller"
    sys_q, disp_q = _bh(sys_p), np.ones(engine.P)
    if has_rep.any():
        disp_q[has_rep] = _bh(disp_p[has_rep])
    summary["n_poses_sys_flagged"] = int(np.sum(sys_q < 0.05))
    summary["n_poses_disp_flagged"] = int(np.sum(disp_q < 0.05))
    mean_resid = engine.pose_mean_op @ fit.resid * _DISPLAY
    poses = pd.DataFrame({
        "pose_id": list(c.pose_labels), "x_mm": c.poses[:, 0], "y_mm": c.poses[:, 1], "phi_deg": c.poses[:, 2],
        "n": n.astype(int), "dx_um": mean_resid[:, 0], "dy_um": mean_resid[:, 1],
        "dphi_arcsec": mean_resid[:, 2], "sys_stat": B, "sys_p": sys_p, "sys_q": sys_q,
        "disp_ratio": ratio, "disp_p": disp_p, "disp_q": disp_q,
        "disp_direction": np.where(~has_rep, "n/a", np.where(S > mS, "larger", "smaller")),
    })
    b, Jb = engine.b_pose, engine.Jb
    db = np.linalg.solve(Jb[engine.idx], fit.resid[..., None])[..., 0]
    meas = pd.DataFrame({"pose_id": c.pose_id, "pose": engine.idx})
    for k, name in enumerate(("dx_um", "dy_um", "dphi_arcsec")):
        meas[name] = _DISPLAY[k] * fit.resid[:, k]
    for k, name in enumerate(("zx", "zy", "zphi")):
        meas[name] = fit.z[:, k]
    for i in range(3):
        meas[f"b_{i + 1}"] = b[engine.idx, i]
        meas[f"dir_{i + 1}"] = c.direction[:, i] if c.has_dir[i] else np.nan
        meas[f"db_eq_{i + 1}_um"] = MM2UM * db[:, i]
    meas["temp_C"] = c.temp_C if c.temp_C is not None else np.nan
    return Diagnosis(poses=poses, measurements=meas, summary=summary)



def is_unexplained(after: Diagnosis, alpha_unexplained: float) -> bool:
    """Whether any of the six tests of :data:`UNEXPLAINED_TESTS` rejects (Bonferroni at ``alpha_unexplained``)."""
    s = after.summary
    return bool(min(s[t] for t in UNEXPLAINED_TESTS) < alpha_unexplained / len(UNEXPLAINED_TESTS))


def gap(engine: Engine, base: Fit, fit: Fit, before: Diagnosis, after: Diagnosis, unexplained: bool) -> dict:
    """The gap document of ``discrepancy.json``: the two channels before and after, closed or not.

    Parameters
    ----------
    engine : Engine
    base, fit : Fit
        The model state without effects and with the named effects.
    before, after : Diagnosis
        Their diagnoses.
    unexplained : bool
        Whether disagreement remains that no candidate explains (:func:`is_unexplained`).
    """
    s = after.summary
    channels = {}
    for state, diag, state_fit in (("before", before, base), ("after", after, fit)):
        g_sys, sd_sys, df_sys = _systematic_gap(engine, state_fit)
        summ = diag.summary
        g_disp = summ["disp_stat"] / max(summ["disp_mean"], 1.0)
        sd_disp = summ["disp_null_sd"]
        z_sys = (g_sys - 1.0) / sd_sys if sd_sys > 0 else 0.0
        z_disp = (g_disp - 1.0) / sd_disp if sd_disp > 0 else 0.0
        channels[state] = {"value": 0.5 * (z_sys**2 + z_disp**2), "systematic": g_sys,
                           "systematic_null_sd": sd_sys, "systematic_df": df_sys, "systematic_z": z_sys,
                           "dispersion": g_disp, "dispersion_null_sd": sd_disp, "dispersion_z": z_disp}
    residual_closed = abs(s["gap"] - 1.0) <= 4.0 * s["gap_null_sd"]
    g_after = channels["after"]["value"]
    closed = bool(not unexplained and residual_closed and g_after <= GAP_CLOSED)
    return {
        "metric": "(z_sys^2 + z_disp^2) / 2, the mean squared standardised deviation of the two channels from "
                  "their null level: z_sys for G_sys, the whitened residual energy in the span of the library's "
                  "systematic signatures per degree of freedom, z_disp for G_disp, the repeat scatter over its "
                  "predicted mean (both G are 1 when the model is right); about chi2(2)/2 then, so null level 1, "
                  "null sd 1; closed at <= 5 (null probability 0.7 % above)",
        "before": channels["before"]["value"], "after": g_after, "null_level": 1.0, "null_sd": 1.0,
        "closed": closed, "channels": channels,
        "residual": {"metric": "mean squared whitened residual per degree of freedom (chi2/dof of all "
                               "measurements under the model's predicted mean and covariance)",
                     "before": before.summary["gap"], "after": s["gap"], "null_level": 1.0,
                     "null_sd_before": before.summary["gap_null_sd"], "null_sd": s["gap_null_sd"]},
        "systematic": {"before": before.summary["sys_stat"] / (3.0 * engine.P),
                       "after": s["sys_stat"] / s["sys_mean"], "null_level": 1.0},
        "dispersion": {"before": before.summary["disp_stat"] / max(before.summary["disp_mean"], 1.0),
                       "after": s["disp_stat"] / max(s["disp_mean"], 1.0), "null_level": 1.0},
    }
